"""Reference vectors for `fpc-sim derive` (tests/derive_matches_scipy.rs), made once with
scipy and committed; the tests themselves need no Python.

    python3 tests/data/sg_reference/generate.py   # scipy 1.17, numpy 2.4

Writes run.csv (a run log: 150 rows at 10 kHz, a two-tone stroke with 1 um of noise) and
expected.csv: for each (window N, order K, lag L) the derivatives at every row, aligned to
the row's time, with scipy's own edge treatment:
- centred (L = (N-1)/2): savgol_filter(x, N, K, deriv, delta=dt) (mode='interp': the first
  and last (N-1)/2 rows come from a polynomial fitted to the first / last N samples);
- any other L: savgol_coeffs(N, K, deriv, delta, pos=N-1-L, use='dot') dotted with the
  window that ends L samples after the row (pos=N-1 is the causal end point); rows without
  such a window use the first / last N samples, savgol_coeffs(..., pos=row offset) - the
  same 'interp' idea.
"""
import csv
import os

import numpy as np
from scipy.signal import savgol_coeffs, savgol_filter

HERE = os.path.dirname(os.path.abspath(__file__))
DT = 1e-4
ROWS = 150
CONFIGS = [(21, 2, 10), (21, 2, 0), (25, 2, 0), (41, 4, 20), (41, 4, 0), (5, 2, 2), (11, 3, 3)]

rng = np.random.default_rng(20261101)
t = np.round(np.arange(ROWS) * DT, 10)
x = 0.1 + 0.09 * np.sin(2 * np.pi * 7 * t) + 0.004 * np.sin(2 * np.pi * 83 * t + 1.0)
x = x + 1e-6 * rng.standard_normal(ROWS)


def derivative(x, n, k, lag, deriv):
    if k < deriv:
        return np.zeros_like(x)
    if 2 * lag == n - 1:
        return savgol_filter(x, n, k, deriv=deriv, delta=DT)
    out = np.empty_like(x)
    for row in range(len(x)):
        end = row + lag  # newest sample of the window
        if end < n - 1:
            window, pos = x[:n], row
        elif end > len(x) - 1:
            window, pos = x[-n:], row - (len(x) - n)
        else:
            window, pos = x[end - n + 1 : end + 1], n - 1 - lag
        c = savgol_coeffs(n, k, deriv=deriv, delta=DT, pos=pos, use="dot")
        out[row] = np.dot(c, window)
    return out


with open(os.path.join(HERE, "run.csv"), "w", newline="") as f:
    f.write("# source = tests/data/sg_reference/generate.py (scipy reference input)\n")
    f.write("# sample_rate_hz = 10000\n")
    w = csv.writer(f)
    w.writerow(["t_s", "x_m", "x_slave_m", "theta_rad", "f_master_n", "f_slave_n", "p_a_pa", "p_b_pa"])
    for ti, xi in zip(t, x):
        w.writerow([repr(float(ti)), repr(float(xi)), repr(float(xi)), 0, 0, 0, 101325, 101325])

names, cols = [], []
for n, k, lag in CONFIGS:
    for deriv, q in ((1, "v"), (2, "a")):
        names.append(f"{q}_{n}_{k}_{lag}")
        cols.append(derivative(x, n, k, lag, deriv))
with open(os.path.join(HERE, "expected.csv"), "w", newline="") as f:
    f.write("# v_N_K_L (m/s) and a_N_K_L (m/s^2) at each row of run.csv; see generate.py\n")
    w = csv.writer(f)
    w.writerow(names)
    for row in np.array(cols).T:
        w.writerow([f"{v:.12e}" for v in row])
