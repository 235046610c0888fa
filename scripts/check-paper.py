#!/usr/bin/env python3
"""Checks the figures `fpc-sim paper` printed (its paper.json) against the paper's stated
values and the bands docs/paper.md states, one line per check; exits 1 if any fails.

Each check is a *result* of the runs (no input of the model read back): it fails if the
published baseline loses a problem the paper describes, or if ours gains one.

    python3 scripts/check-paper.py out/paper/paper.json
"""
import json
import sys

PAPER_PR = [3.1, 3.7, 4.3, 5.1]


def main(path):
    with open(path, encoding="utf-8") as f:
        fig = json.load(f)
    checks = []

    def check(name, value, lo, hi, unit=""):
        ok = lo <= value <= hi
        checks.append(ok)
        print(f"{'ok  ' if ok else 'FAIL'} {name}: {value:.4g}{unit} (band {lo:g} to {hi:g}{unit})")

    points = fig["points"]
    if [p["pressure_ratio"] for p in points] != PAPER_PR:
        print(f"FAIL the Fig. 3 points: {[p['pressure_ratio'] for p in points]}")
        return 1
    for p in points:
        pr = p["pressure_ratio"]
        ours, published = p["loop_ratio"]
        # Ours reaches the figure's loop ratios; the published drives over-compress.
        check(f"Fig. 3 PR {pr}: ours' loop ratio / the paper's", ours / pr, 0.95, 1.08)
        check(f"Fig. 3 PR {pr}: published loop ratio / the paper's", published / pr, 1.2, 1.6)
        for k, who in enumerate(["ours", "published"]):
            # The electrical account: efficiency plausible, and input above the indicated work.
            check(f"PR {pr} {who}: efficiency", p["efficiency"][k], 0.6, 0.95)
            losses = p["copper_j"][k] + p["bridge_j"][k] + p["servo_j"][k]
            check(f"PR {pr} {who}: losses / electrical input", losses / p["electrical_j"][k], 0.05, 0.4)
        # The section fight is the published drives' alone.
        check(f"PR {pr}: published fight, J per cycle", p["fight_j"][1], 0.01, 5.0, " J")
        check(f"PR {pr}: ours' fight, J per cycle", p["fight_j"][0], 0.0, 0.005, " J")
    top = points[-1]["p_max_mpa"]
    check("Fig. 3 p_max at PR 5.1, ours", top[0], 0.45, 0.6, " MPa")
    check("Fig. 3 p_max at PR 5.1, published (above the figure's 0.5 MPa axis)", top[1], 0.55, 0.9, " MPa")
    for k, who in enumerate(["master", "slave"]):
        check(f"Fig. 4 published {who} section peak (paper 0.8-1.6 kN)", fig["fig4_section_peak_kn"][k], 0.8, 1.6, " kN")
    pub_c, pub_u, ours = fig["fig5_peak_difference_kn"]
    check("Fig. 5 published master - slave peak, compressing (paper: sometimes 0.7 kN)", pub_c, 0.45, 1.0, " kN")
    check("Fig. 5 published master - slave peak, not compressing", pub_u, 0.3, 1.0, " kN")
    check("Fig. 5 ours master - slave peak", ours, 0.0, 0.05, " kN")
    before_c, before_u, mapped = fig["fig6_rms_um"]
    check("Fig. 6 slave - master step a pitch (declared 0.1 mm)", fig["fig6_step_um"], 75.0, 125.0, " µm")
    check("Fig. 6 larger toward B by", fig["fig6_direction_um"], 35.0, 65.0, " µm")
    check("Fig. 6 same pattern without compression (RMS ratio)", before_u / before_c, 0.9, 1.1)
    check("Fig. 6 with the firmware's map, RMS / before", mapped / before_c, 0.0, 0.10)
    unfiltered, sg, _drive = fig["fig7_lag_ms"]
    check("Fig. 7 unfiltered difference late by", unfiltered, 0.0, 0.05, " ms")
    check("Fig. 7 Savitzky-Golay late by", sg, 0.0, 0.05, " ms")
    check("Fig. 7 Savitzky-Golay noise / unfiltered", fig["fig7_rms_mps"][1] / fig["fig7_rms_mps"][0], 0.0, 0.5)
    expected, unf, filt = fig["fig8_kn"]
    check("Fig. 8 unfiltered inertia force off by (paper: to ±10 kN)", unf, 5.0, 40.0, " kN RMS")
    check("Fig. 8 filtered off by / expected peak", filt / expected, 0.0, 0.3)
    tuning = fig["filter_tuning"]
    check("§4.3 tuning: best window - firmware's", tuning["best_window"] - tuning["firmware_window"], -8, 8)
    for k, who in enumerate(["ours", "published"]):
        # Not reproduced (paper ≈ 6 kN): a fall toward 6 kN would change docs/paper.md.
        check(f"Fig. 9 motor force peak, {who} (paper ≈ 6 kN, not reproduced)", fig["fig9_motor_peak_kn"][k], 1.5, 4.0, " kN")
    acc, dec = fig["fig9_motor_work_j"]
    check("Fig. 9 published motor work accelerating / decelerating", acc / dec, 1.0, 2.0)
    cp = fig["closed_port"]
    # §4: "a pressure from 3 to 7 bar was created"; the force replayed open loop (the paper's
    # method) reaches the stop's neighbourhood and the same range without striking a head.
    for k, how in enumerate(["closed loop", "open loop"]):
        check(f"§4 closed ports, {how}: chamber B's peak", cp["peak_bar"][k], 3.0, 7.0, " bar")
        check(f"§4 closed ports, {how}: end - stop", 1e3 * (cp["end_m"][k] - cp["stop_m"]), -5.0, 5.0, " mm")
        check(f"§4 closed ports, {how}: least head clearance", cp["min_clearance_mm"][k], 1.0, 200.0, " mm")
    failed = checks.count(False)
    print(f"{len(checks) - failed} of {len(checks)} checks of the paper's figures hold")
    return 1 if failed else 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: check-paper.py PAPER_JSON")
    sys.exit(main(sys.argv[1]))
