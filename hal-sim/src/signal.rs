//! Signal analysis for the log tools: FFT cross-correlation (time lag), zero-phase
//! Butterworth filtering (`filtfilt`), finite differences, the firmware's own
//! Savitzky–Golay differentiator run offline, and stroke detection.
//!
//! Everything is `f64` on uniformly sampled signals. [`xcorr_lag`] is the paper's method
//! (Fig. 4: FFT of both signals, conjugate product, inverse FFT, peak) with a parabolic
//! sub-sample refinement; the model-gap workflow reuses it for `slave_lag` and
//! `actuator_lag`.

use std::ops::Range;

use fpc::sensing::differentiator::{SavitzkyGolay, SgConfig};
use fpc::sensing::encoder::{EncoderConfig, PositionCounts};
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use std::sync::{Arc, Mutex, OnceLock};

/// The forward and inverse FFTs of length `n`, planned once per process: planning a long
/// transform computes its twiddle factors (as long as a transform itself), and the workflow
/// asks for the same lengths many times.
pub fn fft_pair(n: usize) -> (Arc<dyn Fft<f64>>, Arc<dyn Fft<f64>>) {
    static PLANNER: OnceLock<Mutex<FftPlanner<f64>>> = OnceLock::new();
    let planner = PLANNER.get_or_init(|| Mutex::new(FftPlanner::new()));
    match planner.lock() {
        Ok(mut p) => (p.plan_fft_forward(n), p.plan_fft_inverse(n)),
        // A panic elsewhere while planning: plan anew rather than fail.
        Err(_) => {
            let mut p = FftPlanner::new();
            (p.plan_fft_forward(n), p.plan_fft_inverse(n))
        }
    }
}

/// The default search window of [`xcorr_lag`], s: the delays measured here (drive, current
/// loop, filter and logging delays) are milliseconds, never a stroke (a stroke lasts 50 ms or
/// more), so a periodic signal's next correlation peak, a whole period away, lies outside.
pub const DEFAULT_MAX_LAG_S: f64 = 20e-3;

/// Largest magnitude [`xcorr_lag`] accepts in a signal: the sum of its squares over 10⁹
/// samples stays far from overflow.
pub const MAX_LAG_INPUT: f64 = 1e100;

/// A time shift found by cross-correlation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lag {
    /// How far `b` lags `a`, samples (negative: `b` leads), refined below one sample.
    pub samples: f64,
    /// The same in seconds.
    pub seconds: f64,
    /// Normalised correlation at the peak, −1..1 (near 1: the signals are alike).
    pub correlation: f64,
}

/// How far `b` lags `a`: the lag `k` (|k| ≤ `max_lag_samples`; `None`: the samples of
/// [`DEFAULT_MAX_LAG_S`]) that maximises the correlation coefficient of the overlapping
/// parts, `a[n]` against `b[n+k]` — the global maximum inside that physically bounded window,
/// not a local peak — refined below one sample by a parabola through the peak and its two
/// neighbours.
///
/// The products `Σ a[n]·b[n+k]` for every lag come from one FFT cross-correlation (zero
/// padded, so linear rather than circular: the paper's method); each is then normalised by
/// the overlap's own means and energies (prefix sums). Without that normalisation the
/// shrinking overlap drags the peak of slow signals toward zero lag — the reason the paper
/// cut exactly one period out of its log first.
///
/// On smooth, strongly correlated signals the coefficient is flat near its peak (0.9996 at
/// a millisecond's error on a stroke), so nothing but the global maximum is a defensible
/// estimate; a periodic signal is handled by the window, whose edge must stay below half its
/// period.
pub fn xcorr_lag(
    a: &[f64],
    b: &[f64],
    sample_time_s: f64,
    max_lag_samples: Option<usize>,
) -> Result<Lag, String> {
    let n = a.len().min(b.len());
    if n < 8 {
        return Err(format!("{n} samples: at least 8 needed for a lag"));
    }
    check_lag_inputs(a, b, n, sample_time_s)?;
    // Centred for numerical conditioning; the coefficient itself ignores offsets.
    let centred = |x: &[f64]| {
        let x = x.get(..n).unwrap_or_default();
        let mean = x.iter().sum::<f64>() / n as f64;
        x.iter().map(|v| v - mean).collect::<Vec<f64>>()
    };
    let (a, b) = (centred(a), centred(b));
    let max_lag = lag_window(sample_time_s, max_lag_samples, n);
    let coefficient = Coefficient::new(&a, &b, max_lag);
    let max_lag = max_lag as isize;
    let (k, peak) = (-max_lag..=max_lag)
        .filter_map(|k| Some((k, coefficient.at(k)?)))
        .fold(None::<(isize, f64)>, |best, (k, v)| match best {
            Some((_, b)) if b >= v => best,
            _ => Some((k, v)),
        })
        .ok_or("a signal is constant: no lag can be found")?;
    // A straight line (a time column, a ramp) correlates perfectly at every lag: no peak,
    // no lag.
    let flat = [k - 2, k + 2]
        .iter()
        .filter_map(|&j| coefficient.at(j))
        .any(|v| v >= peak - 1e-12);
    if flat {
        return Err(format!(
            "the correlation has no peak (it is {peak:.12} two samples either side of the best \
             lag too): the signals have no feature to align, such as a straight line"
        ));
    }
    let samples = refine_smoothed(&a, &b, k, sample_time_s);
    Ok(Lag {
        samples,
        seconds: samples * sample_time_s,
        // Rounding can put a perfect match a hair above 1.
        correlation: peak.clamp(-1.0, 1.0),
    })
}

/// Refuses what [`xcorr_lag`] cannot correlate: a value of the first `n` samples of `a` or
/// `b` beyond ±[`MAX_LAG_INPUT`] (or not a number), or a sample time, s, that is not
/// positive.
fn check_lag_inputs(a: &[f64], b: &[f64], n: usize, sample_time_s: f64) -> Result<(), String> {
    // The FFT and the prefix sums of squares must see finite values whose squares summed
    // over the log stay finite: a NaN or an infinity there would become every lag's
    // coefficient.
    for (name, x) in [("first", a), ("second", b)] {
        if let Some(i) = x
            .iter()
            .take(n)
            .position(|v| !(-MAX_LAG_INPUT..=MAX_LAG_INPUT).contains(v))
        {
            return Err(format!(
                "the {name} signal's sample {} is {}: a lag needs finite values within ±{MAX_LAG_INPUT:e}",
                i + 1,
                x.get(i).copied().unwrap_or(f64::NAN)
            ));
        }
    }
    if !(sample_time_s.is_finite() && sample_time_s > 0.0) {
        return Err(format!(
            "sample time {sample_time_s} s: must be a positive number of seconds"
        ));
    }
    Ok(())
}

/// The largest lag [`xcorr_lag`] looks at, samples: `max_lag_samples`, or the samples of
/// [`DEFAULT_MAX_LAG_S`] at `sample_time_s` (at least 1), and never more than `n − 2` (an
/// overlap of two samples).
fn lag_window(sample_time_s: f64, max_lag_samples: Option<usize>, n: usize) -> usize {
    let default_window = (DEFAULT_MAX_LAG_S / sample_time_s).round();
    let default_window = if default_window.is_finite() && default_window >= 1.0 {
        default_window as usize
    } else {
        1
    };
    max_lag_samples.unwrap_or(default_window).min(n - 2)
}

/// The correlation coefficient of two centred signals of equal length at every lag up to
/// a largest one: the products `Σ a[i]·b[i+k]` of one FFT cross-correlation, and the prefix
/// sums that give each overlap's own means and energies.
struct Coefficient {
    /// Samples of each signal.
    n: usize,
    /// Length of the zero-padded transform.
    nfft: usize,
    /// `Σ a[i]·b[i+k]` times `nfft` at index `k` (negative lags from the end).
    products: Vec<Complex<f64>>,
    /// Prefix sums of `a` and `a²` (index i: the sum of the first i samples).
    prefix_a: Vec<(f64, f64)>,
    /// The same of `b`.
    prefix_b: Vec<(f64, f64)>,
}

impl Coefficient {
    /// The coefficient of `a` and `b` (centred, of equal length) for lags up to `max_lag`
    /// samples either way.
    fn new(a: &[f64], b: &[f64], max_lag: usize) -> Self {
        let n = a.len();
        // Zero padding to n + the largest lag looked at (the window and the two samples of the
        // flatness check) keeps the circular correlation linear at every lag used.
        let nfft = (n + max_lag + 3).next_power_of_two();
        let (forward, inverse) = fft_pair(nfft);
        // Both real signals in one complex transform, z = a + i·b, separated by the symmetry
        // of real spectra: A[k] = (Z[k] + Z*[−k])/2, B[k] = (Z[k] − Z*[−k])/2i; then the
        // cross-spectrum A*·B and one inverse transform give Σ a[i]·b[i+k] at every lag.
        let mut z: Vec<Complex<f64>> = a
            .iter()
            .zip(b)
            .map(|(&x, &y)| Complex::new(x, y))
            .chain(std::iter::repeat(Complex::new(0.0, 0.0)))
            .take(nfft)
            .collect();
        forward.process(&mut z);
        // The cross-spectrum in place: bins k and nfft − k read each other, so both are
        // replaced together (one transform's length held, not two).
        let cross = |zk: Complex<f64>, zm: Complex<f64>| {
            let fa = (zk + zm) * 0.5;
            let fb = (zk - zm) * Complex::new(0.0, -0.5);
            fa.conj() * fb
        };
        for k in 0..=nfft / 2 {
            let m = (nfft - k) % nfft;
            let (zk, zm) = (
                z.get(k).copied().unwrap_or_default(),
                z.get(m).copied().unwrap_or_default(),
            );
            if let Some(v) = z.get_mut(k) {
                *v = cross(zk, zm.conj());
            }
            if let Some(v) = z.get_mut(m) {
                *v = cross(zm, zk.conj());
            }
        }
        inverse.process(&mut z);
        Coefficient {
            n,
            nfft,
            products: z,
            prefix_a: prefix_sums(a),
            prefix_b: prefix_sums(b),
        }
    }

    /// The correlation coefficient at lag `k` (`b[n+k]` against `a[n]`); `None` where it
    /// is undefined (an overlap under two samples, or a constant part).
    fn at(&self, k: isize) -> Option<f64> {
        let (n, nfft) = (self.n, self.nfft);
        let shift = k.unsigned_abs();
        let m = n.checked_sub(shift).filter(|m| *m >= 2)?;
        let (a_range, b_range) = if k >= 0 {
            ((0, m), (shift, n))
        } else {
            ((shift, n), (0, m))
        };
        let (sa, saa) = range_sums(&self.prefix_a, a_range.0, a_range.1)?;
        let (sb, sbb) = range_sums(&self.prefix_b, b_range.0, b_range.1)?;
        let at = if k >= 0 { shift } else { nfft - shift };
        let sab = self.products.get(at)?.re / nfft as f64;
        let mf = m as f64;
        let var = (saa - sa * sa / mf) * (sbb - sb * sb / mf);
        (var > 0.0).then(|| (sab - sa * sb / mf) / var.sqrt())
    }
}

/// Prefix sums of `x` and `x²` (index i: the sum of the first i samples).
fn prefix_sums(x: &[f64]) -> Vec<(f64, f64)> {
    let mut s = Vec::with_capacity(x.len() + 1);
    s.push((0.0, 0.0));
    let mut acc = (0.0, 0.0);
    for v in x {
        acc = (acc.0 + v, acc.1 + v * v);
        s.push(acc);
    }
    s
}

/// The sums of `x` and `x²` over samples `from..to`, from their prefix sums `p`.
fn range_sums(p: &[(f64, f64)], from: usize, to: usize) -> Option<(f64, f64)> {
    let (hi, lo) = (p.get(to)?, p.get(from)?);
    Some((hi.0 - lo.0, hi.1 - lo.1))
}

/// The lag `k`, samples, refined below one sample ([`refine_lag`], `k` itself if it cannot
/// be) on `a` and `b` low-passed alike at [`REFINE_BAND`] of the sample rate.
///
/// Refine on both signals low-passed alike (zero phase: the lag is kept): interpolating
/// white noise lowers its variance by up to a third between samples, which would pull
/// the maximum toward half-sample lags.
fn refine_smoothed(a: &[f64], b: &[f64], k: isize, sample_time_s: f64) -> f64 {
    let smooth = |x: &[f64]| match butterworth_lowpass(
        4,
        REFINE_BAND * sample_rate(sample_time_s),
        sample_rate(sample_time_s),
    ) {
        Ok(s) => filtfilt(&s, x),
        Err(_) => x.to_vec(),
    };
    refine_lag(&smooth(a), &smooth(b), k as f64).unwrap_or(k as f64)
}

/// Band of the sub-sample refinement, as a fraction of the sample rate.
const REFINE_BAND: f64 = 0.05;

fn sample_rate(sample_time_s: f64) -> f64 {
    1.0 / sample_time_s
}

/// The Catmull–Rom weights of the samples `x[i−1], x[i], x[i+1], x[i+2]` for the value at
/// `i + f`, `0 ≤ f < 1` (the cubic through them with the centred slopes).
fn catmull_rom_weights(f: f64) -> [f64; 4] {
    let (f2, f3) = (f * f, f * f * f);
    [
        0.5 * (-f + 2.0 * f2 - f3),
        1.0 + 0.5 * (-5.0 * f2 + 3.0 * f3),
        0.5 * (f + 4.0 * f2 - 3.0 * f3),
        0.5 * (f3 - f2),
    ]
}

/// The sub-sample lag near the integer peak `k0`: the `d` within ±1.5 samples of it that
/// maximises the correlation of `b[n]` with `a` interpolated at `n − d`, over one fixed set
/// of `b`'s samples.
///
/// A parabola through three coefficients of the prefix-normalised correlation is not enough
/// on smooth signals: its curvature over one sample is tiny (1 − ρ ≈ 10⁻⁵ at 3 Hz and
/// 5 kHz), while the overlap that changes with each lag tilts it by about 1/n — enough to
/// move the vertex by half a sample. Holding `b`'s samples fixed and interpolating `a`
/// leaves a coefficient whose slope is zero at the true lag.
fn refine_lag(a: &[f64], b: &[f64], k0: f64) -> Option<f64> {
    let n = a.len().min(b.len());
    let margin = k0.abs().ceil() as usize + 4;
    let range = margin..n.checked_sub(margin).filter(|hi| *hi > margin + 8)?;
    let rho = |d: f64| -> f64 {
        // `a` at `i − d` for every `i`: one whole shift and one fraction, so one set of
        // interpolation weights for the whole sum.
        let whole = (-d).floor();
        let w = catmull_rom_weights(-d - whole);
        let whole = whole as isize;
        let (mut sa, mut sb, mut saa, mut sbb, mut sab, mut m) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for i in range.clone() {
            let at = usize::try_from(i as isize + whole - 1).ok();
            let (Some(&[p0, p1, p2, p3]), Some(&y)) = (at.and_then(|k| a.get(k..k + 4)), b.get(i))
            else {
                continue;
            };
            let [w0, w1, w2, w3] = w;
            let x = w0 * p0 + w1 * p1 + w2 * p2 + w3 * p3;
            sa += x;
            sb += y;
            saa += x * x;
            sbb += y * y;
            sab += x * y;
            m += 1.0;
        }
        let var = (saa - sa * sa / m) * (sbb - sb * sb / m);
        if var > 0.0 {
            (sab - sa * sb / m) / var.sqrt()
        } else {
            f64::NEG_INFINITY
        }
    };
    // Golden-section search for the maximum on [k0 − 1.5, k0 + 1.5] (unimodal there: the
    // integer peak is within a sample of the true one).
    let (mut lo, mut hi) = (k0 - 1.5, k0 + 1.5);
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (rho(x1), rho(x2));
    for _ in 0..40 {
        if f1 >= f2 {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - g * (hi - lo);
            f1 = rho(x1);
        } else {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + g * (hi - lo);
            f2 = rho(x2);
        }
    }
    let d = 0.5 * (lo + hi);
    rho(d).is_finite().then_some(d)
}

/// One second-order section, direct form II transposed, `a0 = 1`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Biquad {
    /// Numerator b0, b1, b2.
    pub b: [f64; 3],
    /// Denominator a1, a2.
    pub a: [f64; 2],
}

/// A Butterworth low-pass of even `order` as cascaded biquads (bilinear transform with the
/// cut-off pre-warped, so the −3 dB point is exactly `cutoff_hz`).
pub fn butterworth_lowpass(
    order: usize,
    cutoff_hz: f64,
    sample_rate_hz: f64,
) -> Result<Vec<Biquad>, String> {
    if order == 0 || !order.is_multiple_of(2) || order > 12 {
        return Err(format!("filter order {order}: must be even, 2..=12"));
    }
    if !(cutoff_hz.is_finite() && cutoff_hz > 0.0 && cutoff_hz < 0.5 * sample_rate_hz) {
        return Err(format!(
            "cut-off {cutoff_hz} Hz: must lie between 0 and half the sample rate ({} Hz)",
            0.5 * sample_rate_hz
        ));
    }
    let w0 = 2.0 * std::f64::consts::PI * cutoff_hz / sample_rate_hz;
    let (sin, cos) = w0.sin_cos();
    Ok((0..order / 2)
        .map(|k| {
            // Pole pair k of the analogue prototype: s² + 2·sin(θk)·s + 1, θk = π(2k+1)/2N.
            let theta = std::f64::consts::PI * (2 * k + 1) as f64 / (2 * order) as f64;
            let q = 1.0 / (2.0 * theta.sin());
            let alpha = sin / (2.0 * q);
            let a0 = 1.0 + alpha;
            let b0 = (1.0 - cos) / 2.0 / a0;
            Biquad {
                b: [b0, 2.0 * b0, b0],
                a: [-2.0 * cos / a0, (1.0 - alpha) / a0],
            }
        })
        .collect())
}

/// Runs `x` through `sections` in place, each starting in its steady state for the first
/// sample (so a signal that starts away from zero does not ring).
pub fn lfilter(sections: &[Biquad], x: &mut [f64]) {
    for s in sections {
        let [b0, b1, b2] = s.b;
        let [a1, a2] = s.a;
        let first = x.first().copied().unwrap_or(0.0);
        let gain = (b0 + b1 + b2) / (1.0 + a1 + a2);
        let y0 = gain * first;
        let mut z2 = b2 * first - a2 * y0;
        let mut z1 = b1 * first - a1 * y0 + z2;
        for v in x.iter_mut() {
            let input = *v;
            let y = b0 * input + z1;
            z1 = b1 * input - a1 * y + z2;
            z2 = b2 * input - a2 * y;
            *v = y;
        }
    }
}

/// Zero-phase filtering, as scipy's `filtfilt`: odd extension at both ends, forward pass,
/// backward pass, extension removed. No delay, squared magnitude. The extension is
/// `pad_samples` long (at most the signal's length − 1); [`filtfilt`] picks it.
pub fn filtfilt_padded(sections: &[Biquad], x: &[f64], pad_samples: usize) -> Vec<f64> {
    let n = x.len();
    if n < 2 {
        return x.to_vec();
    }
    let pad = pad_samples.min(n - 1);
    let (first, last) = match (x.first(), x.last()) {
        (Some(&f), Some(&l)) => (f, l),
        _ => return x.to_vec(),
    };
    let mut ext: Vec<f64> = Vec::with_capacity(n + 2 * pad);
    ext.extend(x.iter().skip(1).take(pad).rev().map(|v| 2.0 * first - v));
    ext.extend_from_slice(x);
    ext.extend(x.iter().rev().skip(1).take(pad).map(|v| 2.0 * last - v));
    lfilter(sections, &mut ext);
    ext.reverse();
    lfilter(sections, &mut ext);
    ext.reverse();
    ext.into_iter().skip(pad).take(n).collect()
}

/// [`filtfilt_padded`] with an extension of three time constants of the slowest section
/// (scipy's 3·(order+1) samples leave edge transients when the cut-off is far below the
/// sample rate, as it is at 20 kHz).
pub fn filtfilt(sections: &[Biquad], x: &[f64]) -> Vec<f64> {
    // Pole radius of each section from a2 = r²; time constant 1/(1 − r) samples.
    let slowest = sections
        .iter()
        .map(|s| {
            let r = s.a[1].abs().sqrt().min(1.0 - 1e-12);
            1.0 / (1.0 - r)
        })
        .fold(0.0, f64::max);
    let pad = (3.0 * slowest).ceil() as usize;
    filtfilt_padded(sections, x, pad.max(3 * (2 * sections.len() + 1)))
}

/// Backward difference `(x[i] − x[i−1])/dt` (the paper's Eq. 5, causal); the first value
/// repeats the second.
pub fn backward_difference(x: &[f64], sample_time_s: f64) -> Vec<f64> {
    let d: Vec<f64> = x
        .windows(2)
        .map(|w| (w[1] - w[0]) / sample_time_s)
        .collect();
    d.first().copied().into_iter().chain(d).collect()
}

/// Central difference `(x[i+1] − x[i−1])/2dt` (zero phase); the ends are one-sided.
pub fn central_difference(x: &[f64], sample_time_s: f64) -> Vec<f64> {
    let d: Vec<f64> = x
        .windows(3)
        .map(|w| (w[2] - w[0]) / (2.0 * sample_time_s))
        .collect();
    let head = x.get(..2).map(|w| (w[1] - w[0]) / sample_time_s);
    let tail = x
        .len()
        .checked_sub(2)
        .and_then(|i| x.get(i..))
        .map(|w| (w[1] - w[0]) / sample_time_s);
    head.into_iter()
        .chain(d)
        .chain(tail)
        .take(x.len())
        .collect()
}

/// Second difference `(x[i+1] − 2x[i] + x[i−1])/dt²`, centred; the end values repeat
/// their neighbours.
pub fn second_difference(x: &[f64], sample_time_s: f64) -> Vec<f64> {
    let dt2 = sample_time_s * sample_time_s;
    let d: Vec<f64> = x
        .windows(3)
        .map(|w| (w[2] - 2.0 * w[1] + w[0]) / dt2)
        .collect();
    let (head, tail) = (d.first().copied(), d.last().copied());
    head.into_iter().chain(d).chain(tail).collect()
}

/// `x` delayed by `samples` (fractional: linear interpolation), the first value held
/// before the start.
pub fn delayed(x: &[f64], samples: f64) -> Vec<f64> {
    let first = x.first().copied().unwrap_or(0.0);
    (0..x.len())
        .map(|i| {
            let t = i as f64 - samples;
            if t <= 0.0 {
                return first;
            }
            let k = t.floor() as usize;
            let f = t - k as f64;
            match (x.get(k), x.get(k + 1)) {
                (Some(a), Some(b)) => a + f * (b - a),
                (Some(a), None) => *a,
                _ => first,
            }
        })
        .collect()
}

/// Root mean square of `a − b` over their common length.
pub fn rms_difference(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    if n == 0 {
        return 0.0;
    }
    let sum: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    (sum / n as f64).sqrt()
}

/// Settings of the firmware's Savitzky–Golay differentiator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SgSettings {
    /// Window length N (odd).
    pub window: usize,
    /// Polynomial order.
    pub order: usize,
    /// Evaluation point, samples back from the newest (0 = causal).
    pub lag: usize,
}

/// What is wrong with Savitzky–Golay settings `s`, in words naming the setting by `names`
/// (window, order, lag: flag names or plain words).
pub fn sg_problem(
    e: fpc::sensing::differentiator::SgError,
    s: SgSettings,
    names: [&str; 3],
) -> String {
    use fpc::sensing::differentiator::{SgError, MAX_WINDOW};
    let [window, order, lag] = names;
    match e {
        SgError::Window => format!("{window} {}: must be odd, 3..={MAX_WINDOW}", s.window),
        SgError::Order => format!(
            "{order} {}: must be 1..=4 and less than the window ({})",
            s.order, s.window
        ),
        SgError::Lag => format!(
            "{lag} {}: must be less than the window ({})",
            s.lag, s.window
        ),
        SgError::Scale => {
            "the sample time and encoder resolution give no valid differentiator".into()
        }
    }
}

/// Checks Savitzky–Golay settings for a log of `sample_time_s` as [`firmware_derivatives`]
/// would use them; the error names each setting by `names` (window, order, lag: the flags a
/// tool takes them from) and the accepted range.
pub fn sg_check(
    s: SgSettings,
    sample_time_s: f64,
    encoder_period_m: f64,
    names: [&str; 3],
) -> Result<(), String> {
    let m_per_count = EncoderConfig {
        period_m: encoder_period_m as f32,
        ..EncoderConfig::reference()
    }
    .m_per_count();
    SavitzkyGolay::new(SgConfig {
        window: s.window,
        order: s.order,
        lag: s.lag,
        sample_time_s: sample_time_s as f32,
        m_per_count,
    })
    .map(|_| ())
    .map_err(|e| sg_problem(e, s, names))
}

/// Velocity and acceleration of `x_m` by the firmware's own fixed-point differentiator
/// (`fpc::sensing::differentiator`), fed the position in encoder counts exactly as the control step
/// does. Each output is placed at the sample it estimates (`lag` samples back), so only the
/// differentiator's true delay remains; the last `lag` values repeat the last estimate.
pub fn firmware_derivatives(
    x_m: &[f64],
    sample_time_s: f64,
    encoder_period_m: f64,
    s: SgSettings,
) -> Result<(Vec<f64>, Vec<f64>), String> {
    let m_per_count = EncoderConfig {
        period_m: encoder_period_m as f32,
        ..EncoderConfig::reference()
    }
    .m_per_count();
    let mut sg = SavitzkyGolay::new(SgConfig {
        window: s.window,
        order: s.order,
        lag: s.lag,
        sample_time_s: sample_time_s as f32,
        m_per_count,
    })
    .map_err(|e| sg_problem(e, s, ["window", "order", "lag"]))?;
    let mut v = Vec::with_capacity(x_m.len());
    let mut a = Vec::with_capacity(x_m.len());
    for (i, &x) in x_m.iter().enumerate() {
        let counts = (x / f64::from(m_per_count))
            .round()
            .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
        let d = sg.push(PositionCounts::from_bits(counts));
        if i >= s.lag {
            v.push(f64::from(d.velocity_mps));
            a.push(f64::from(d.acceleration_mps2));
        }
    }
    let (lv, la) = (v.last().copied(), a.last().copied());
    v.resize(x_m.len(), lv.unwrap_or(0.0));
    a.resize(x_m.len(), la.unwrap_or(0.0));
    Ok((v, a))
}

/// The strokes in a log: index ranges from one reversal to the next in which the piston
/// moves one way at more than 5 % of its peak speed, covering at least half the longest
/// stroke's travel. In time order.
pub fn strokes(x_m: &[f64], v_mps: &[f64]) -> Vec<Range<usize>> {
    let n = x_m.len().min(v_mps.len());
    let peak = v_mps.iter().take(n).fold(0.0f64, |m, v| m.max(v.abs()));
    if peak <= 0.0 {
        return Vec::new();
    }
    let threshold = 0.05 * peak;
    let sign = |i: usize| v_mps.get(i).map_or(0.0, |v| v.signum());
    // Maximal runs above the threshold, same sign.
    let mut runs: Vec<(Range<usize>, f64)> = Vec::new();
    let mut i = 0;
    while i < n {
        if v_mps.get(i).is_some_and(|v| v.abs() > threshold) {
            let s = sign(i);
            let start = i;
            while i < n && v_mps.get(i).is_some_and(|v| v * s > threshold) {
                i += 1;
            }
            match runs.last_mut() {
                // A dip below the threshold without reversing continues the same stroke.
                Some((r, rs)) if *rs == s => r.end = i,
                _ => runs.push((start..i, s)),
            }
        } else {
            i += 1;
        }
    }
    // Widen each run to the reversals on both sides.
    let mut out: Vec<Range<usize>> = Vec::new();
    let mut floor = 0;
    for (r, s) in &runs {
        let mut start = r.start;
        while start > floor && v_mps.get(start - 1).is_some_and(|v| v * s > 0.0) {
            start -= 1;
        }
        let mut end = r.end;
        while end < n && v_mps.get(end).is_some_and(|v| v * s > 0.0) {
            end += 1;
        }
        floor = end;
        out.push(start..end);
    }
    let travel = |r: &Range<usize>| match (x_m.get(r.start), x_m.get(r.end.saturating_sub(1))) {
        (Some(a), Some(b)) => (b - a).abs(),
        _ => 0.0,
    };
    let longest = out.iter().map(travel).fold(0.0, f64::max);
    out.into_iter()
        .filter(|r| travel(r) >= 0.5 * longest && r.len() > 2)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sines(n: usize, dt: f64, delay_s: f64) -> Vec<f64> {
        (0..n)
            .map(|i| {
                let t = i as f64 * dt - delay_s;
                (2.0 * std::f64::consts::PI * 3.0 * t).sin()
                    + 0.5 * (2.0 * std::f64::consts::PI * 17.0 * t + 0.3).sin()
                    + 0.2 * (2.0 * std::f64::consts::PI * 41.0 * t + 1.1).sin()
            })
            .collect()
    }

    #[test]
    fn xcorr_finds_integer_and_fractional_lags_both_ways() {
        let dt = 50e-6;
        let a = sines(8000, dt, 0.0);
        for delay in [0.75e-3, -0.75e-3, 0.7725e-3, 0.0] {
            let b = sines(8000, dt, delay);
            let lag = xcorr_lag(&a, &b, dt, None).unwrap();
            assert!((lag.seconds - delay).abs() < 0.01e-3, "{delay}: {lag:?}");
            assert!(lag.correlation > 0.99);
        }
    }

    #[test]
    fn xcorr_refuses_constant_and_short_signals() {
        assert!(xcorr_lag(&[1.0; 100], &sines(100, 1e-3, 0.0), 1e-3, None).is_err());
        assert!(xcorr_lag(&[1.0, 2.0], &[1.0, 2.0], 1e-3, None).is_err());
    }

    #[test]
    fn butterworth_has_unit_dc_gain_and_minus_3_db_at_cutoff() {
        let fs = 20_000.0;
        for order in [2, 4, 6] {
            let s = butterworth_lowpass(order, 500.0, fs).unwrap();
            let gain = |f: f64| {
                let z = Complex::from_polar(1.0, -2.0 * std::f64::consts::PI * f / fs);
                s.iter()
                    .map(|q| {
                        let num = q.b[0] + q.b[1] * z + q.b[2] * z * z;
                        let den = 1.0 + q.a[0] * z + q.a[1] * z * z;
                        (num / den).norm()
                    })
                    .product::<f64>()
            };
            assert!((gain(0.0) - 1.0).abs() < 1e-12);
            assert!((gain(500.0) - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-9);
            // Roll-off of order N: at 10 × the cut-off, below 10^−N.
            assert!(gain(5000.0) < 10f64.powi(-(order as i32)));
        }
        assert!(butterworth_lowpass(3, 500.0, fs).is_err());
        assert!(butterworth_lowpass(4, 12_000.0, fs).is_err());
    }

    #[test]
    fn filtfilt_has_no_delay_and_holds_a_constant() {
        let dt = 50e-6;
        let x = sines(4000, dt, 0.0);
        let s = butterworth_lowpass(4, 200.0, 1.0 / dt).unwrap();
        let y = filtfilt(&s, &x);
        let lag = xcorr_lag(&x, &y, dt, None).unwrap();
        assert!(lag.samples.abs() < 0.05, "{lag:?}");
        let c = filtfilt(&s, &[3.5; 50]);
        assert!(c.iter().all(|v| (v - 3.5).abs() < 1e-12));
    }

    #[test]
    fn differences_of_a_parabola_are_exact() {
        let dt = 1e-3;
        let x: Vec<f64> = (0..20)
            .map(|i| 0.5 * 4.0 * (i as f64 * dt).powi(2))
            .collect();
        let a = second_difference(&x, dt);
        assert!(a.iter().all(|v| (v - 4.0).abs() < 1e-6));
        let v = backward_difference(&x, dt);
        assert!((v[10] - 4.0 * 9.5 * dt).abs() < 1e-9);
        let v = central_difference(&x, dt);
        assert_eq!(v.len(), x.len());
        assert!((v[10] - 4.0 * 10.0 * dt).abs() < 1e-9);
        assert_eq!(
            delayed(&[0.0, 1.0, 2.0, 3.0], 1.5),
            vec![0.0, 0.0, 0.5, 1.5]
        );
    }

    #[test]
    fn firmware_differentiator_tracks_a_ramp() {
        let dt = 50e-6;
        let x: Vec<f64> = (0..400).map(|i| 0.01 + 2.0 * i as f64 * dt).collect();
        let s = SgSettings {
            window: 21,
            order: 2,
            lag: 10,
        };
        let (v, a) = firmware_derivatives(&x, dt, 0.024, s).unwrap();
        assert!(
            v[100..].iter().all(|v| (v - 2.0).abs() < 1e-3),
            "{:?}",
            &v[100..110]
        );
        assert!(a[100..].iter().all(|a| a.abs() < 1.0));
        assert!(firmware_derivatives(&x, dt, 0.024, SgSettings { window: 4, ..s }).is_err());
    }

    #[test]
    fn strokes_run_from_reversal_to_reversal() {
        let dt = 1e-3;
        let x: Vec<f64> = (0..3000)
            .map(|i| 0.1 - 0.09 * (2.0 * std::f64::consts::PI * i as f64 * dt).cos())
            .collect();
        let v = backward_difference(&x, dt);
        let s = strokes(&x, &v);
        assert_eq!(s.len(), 6, "{s:?}");
        for r in &s {
            assert!((r.len() as i64 - 500).abs() <= 2, "{r:?}");
        }
    }

    mod lag_property {
        use super::super::xcorr_lag;
        use proptest::prelude::*;
        use rand::{Rng, SeedableRng};
        use rand_chacha::ChaCha8Rng;
        use std::f64::consts::TAU;

        /// A smooth random shape: a periodic stroke (sine with a few harmonics, period
        /// 0.08–0.4 s, so the next period's peak is a whole stroke away) plus a slow drift
        /// term, evaluated exactly at `t`.
        struct Shape {
            terms: Vec<(f64, f64, f64)>,
        }

        impl Shape {
            fn draw(rng: &mut ChaCha8Rng) -> Self {
                let f0 = 1.0 / rng.random_range(0.08..0.4);
                let mut terms = vec![(1.0, f0, rng.random_range(0.0..TAU))];
                for h in 2..=rng.random_range(2..6usize) {
                    terms.push((
                        rng.random_range(0.0..0.4) / h as f64,
                        f0 * h as f64,
                        rng.random_range(0.0..TAU),
                    ));
                }
                terms.push((rng.random_range(0.0..0.5), rng.random_range(0.1..1.0), 0.3));
                Shape { terms }
            }

            fn at(&self, t: f64) -> f64 {
                self.terms
                    .iter()
                    .map(|(a, f, p)| a * (TAU * f * t + p).sin())
                    .sum()
            }
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(96))]

            /// Lags of 0–3 ms at 5, 10 and 20 kHz on random smooth shapes with white noise
            /// up to 0.5 % of the stroke (a log's 3 N on forces of kN, 1 µm on 0.1 m), 2 s
            /// long: the estimate is within 0.02 ms. (The Cramér–Rao bound for the slowest
            /// shape at 5 kHz and the most noise is 6 µs.)
            #[test]
            fn lag_is_found_within_20_us_on_any_smooth_signal(
                seed in any::<u64>(),
                rate in prop::sample::select(vec![5_000.0f64, 10_000.0, 20_000.0]),
                delay_s in 0.0f64..3e-3,
                noise in 0.0f64..0.005,
            ) {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                let shape = Shape::draw(&mut rng);
                let dt = 1.0 / rate;
                let n = (2.0 / dt) as usize;
                let mut draw = |t: f64| shape.at(t) + noise * rng.random_range(-1.7..1.7);
                let a: Vec<f64> = (0..n).map(|i| draw(i as f64 * dt)).collect();
                let b: Vec<f64> = (0..n).map(|i| draw(i as f64 * dt - delay_s)).collect();
                let lag = xcorr_lag(&a, &b, dt, None).map_err(TestCaseError::fail)?;
                prop_assert!(
                    (lag.seconds - delay_s).abs() < 0.02e-3,
                    "{rate} Hz, {:.4} ms: found {:.4} ms", delay_s * 1e3, lag.seconds * 1e3
                );
            }
        }
    }
}
