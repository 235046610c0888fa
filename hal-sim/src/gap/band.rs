//! The filters the model-gap workflow compares through: the firmware's Savitzky–Golay
//! acceleration filter, the kernel that smooths forces *exactly* as that filter smooths m·ẍ,
//! and the zero-phase low-pass that limits every channel to the analysis band.
//!
//! Why a force kernel: the SG second-derivative filter `h₂` annihilates constants and ramps,
//! so `h₂ = Δ² ⋆ g` for a shorter kernel `g` (Δ² the centred second difference over dt²).
//! Then `h₂ ⋆ x = g ⋆ (Δ²x)`: the firmware's acceleration is the raw second difference
//! smoothed by `g`. Smoothing every force with the same `g` makes the force balance
//! `g ⋆ (m·Δ²x − ΣF)` — the same filter on both sides, so no lag or gain differs between
//! them (the paper's "minimise the phase shift" by construction).
//!
//! Why a band: the acceleration noise of a 2 ms SG window sits at 200–2000 Hz and is ten
//! times the effects looked for (≈ 12 N RMS against a 30 N cogging). Every channel's residual
//! and every candidate's regressor pass the same windowed-sinc low-pass (default 300 Hz:
//! above the cogging frequency at 4 m/s), so fits are unbiased and the noise left is ≈ 5 N.
//! All kernels are symmetric (zero phase) and applied as correlations centred on the sample.

use nalgebra::DMatrix;

/// Longest low-pass kernel, samples (bounds the cost at very low bands).
pub const MAX_LOWPASS_TAPS: usize = 4001;

/// The Savitzky–Golay weights of derivative `deriv` at the centre of a window of `window`
/// samples (odd), polynomial `order`, sample time `dt_s`: `y[i] = Σⱼ w[j]·x[i + j − M]`.
/// These are the weights the firmware's fixed-point differentiator implements (scipy's
/// `savgol_coeffs(window, order, deriv, delta, use='dot')`). `None` for a bad configuration.
pub fn sg_weights(window: usize, order: usize, deriv: usize, dt_s: f64) -> Option<Vec<f64>> {
    if window < 3 || window.is_multiple_of(2) || order >= window || deriv > order {
        return None;
    }
    if !(dt_s.is_finite() && dt_s > 0.0) {
        return None;
    }
    let half = (window / 2) as f64;
    // Least squares on a centred, unit-spaced abscissa: w = row `deriv` of (JᵀJ)⁻¹Jᵀ.
    let j = DMatrix::from_fn(window, order + 1, |r, c| (r as f64 - half).powi(c as i32));
    let jt = j.transpose();
    let normal = (&jt * &j).try_inverse()?;
    let pinv = normal * jt;
    let factorial: f64 = (1..=deriv).map(|k| k as f64).product();
    let scale = factorial / dt_s.powi(deriv as i32);
    Some(pinv.row(deriv).iter().map(|w| w * scale).collect())
}

/// The force kernel `g` of the module header: length `window − 2`, with
/// `h₂[j]·dt² = g[j] − 2g[j−1] + g[j−2]`. Its sum is 1.
pub fn force_kernel(h2: &[f64], dt_s: f64) -> Vec<f64> {
    let n = h2.len().saturating_sub(2);
    let mut g: Vec<f64> = Vec::with_capacity(n);
    let (mut g1, mut g2) = (0.0, 0.0); // g[j−1], g[j−2]
    for &h in h2.iter().take(n) {
        let v = h * dt_s * dt_s + 2.0 * g1 - g2;
        g.push(v);
        g2 = g1;
        g1 = v;
    }
    g
}

/// A zero-phase windowed-sinc (Blackman) low-pass at `cutoff_hz` for `sample_rate_hz`,
/// unit DC gain, ≈ 4 cut-off periods long. A single tap (no filtering) when the cut-off
/// reaches the Nyquist frequency.
pub fn lowpass(cutoff_hz: f64, sample_rate_hz: f64) -> Vec<f64> {
    let fc = cutoff_hz / sample_rate_hz;
    if !(fc.is_finite() && fc > 0.0 && fc < 0.5) {
        return vec![1.0];
    }
    let len = ((4.0 / fc).ceil() as usize | 1).clamp(3, MAX_LOWPASS_TAPS);
    let m = (len - 1) as f64;
    let mut h: Vec<f64> = (0..len)
        .map(|i| {
            let k = i as f64 - m / 2.0;
            let sinc = if k == 0.0 {
                2.0 * fc
            } else {
                (2.0 * std::f64::consts::PI * fc * k).sin() / (std::f64::consts::PI * k)
            };
            let a = 2.0 * std::f64::consts::PI * i as f64 / m;
            sinc * (0.42 - 0.5 * a.cos() + 0.08 * (2.0 * a).cos())
        })
        .collect();
    let sum: f64 = h.iter().sum();
    if sum != 0.0 {
        h.iter_mut().for_each(|v| *v /= sum);
    }
    h
}

/// Full convolution of two kernels (length `a + b − 1`; symmetric in, symmetric out).
pub fn convolve(a: &[f64], b: &[f64]) -> Vec<f64> {
    if a.is_empty() || b.is_empty() {
        return Vec::new();
    }
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, &x) in a.iter().enumerate() {
        for (o, &y) in out.iter_mut().skip(i).zip(b) {
            *o += x * y;
        }
    }
    out
}

/// Computed columns kept for reuse, by a key of the caller's (the bits of a period, the
/// model values a replay reads): the searches of the workflow evaluate the same grid points,
/// and replay the same chambers, again at every selection step. Shared between threads; a
/// clone starts empty. Holds at most [`ColumnCache::CAPACITY`] entries (beyond, new values
/// are computed and not kept). The value is columns unless `V` says otherwise.
pub struct ColumnCache<K = u64, V = Vec<Vec<f64>>> {
    entries: std::sync::Mutex<std::collections::HashMap<K, std::sync::Arc<V>>>,
}

impl<K, V> Default for ColumnCache<K, V> {
    fn default() -> Self {
        ColumnCache {
            entries: std::sync::Mutex::new(std::collections::HashMap::new()),
        }
    }
}

impl<K: Eq + std::hash::Hash, V> ColumnCache<K, V> {
    /// Most entries kept.
    pub const CAPACITY: usize = 1024;

    /// Drops every entry (they are made again when asked for).
    pub fn clear(&self) {
        if let Ok(mut m) = self.entries.lock() {
            m.clear();
        }
    }

    /// The value under `key`, computed by `make` (outside the lock) if not kept yet.
    pub fn get_or_make(&self, key: K, make: impl FnOnce() -> V) -> std::sync::Arc<V> {
        let kept = self.entries.lock().ok().and_then(|m| m.get(&key).cloned());
        if let Some(c) = kept {
            return c;
        }
        let made = std::sync::Arc::new(make());
        if let Ok(mut m) = self.entries.lock() {
            if m.len() < Self::CAPACITY {
                m.entry(key).or_insert_with(|| made.clone());
            }
        }
        made
    }
}

impl<K, V> Clone for ColumnCache<K, V> {
    fn clone(&self) -> Self {
        ColumnCache::default()
    }
}

impl<K, V> std::fmt::Debug for ColumnCache<K, V> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let n = self.entries.lock().map_or(0, |m| m.len());
        write!(f, "ColumnCache({n} entries)")
    }
}

/// Signals shorter than this are filtered directly (the FFT's set-up would dominate).
const FFT_MIN_SAMPLES: usize = 16_384;
/// Kernels shorter than this are applied directly (a direct sum is then as fast).
const FFT_MIN_TAPS: usize = 64;

/// `Σ a[j]·b[j]` over the common length, summed in eight interleaved partial sums (lanes
/// `j mod 8`) that are added pairwise at the end. The order differs from a serial sum only in
/// rounding (≈ 1 ulp per hundred taps); it lets the compiler keep eight independent additions
/// in flight instead of one chain, which makes the 300-tap filters of the workflow about four
/// times faster.
#[inline]
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    const LANES: usize = 8;
    let n = a.len().min(b.len());
    let (a, b) = (
        a.get(..n).unwrap_or_default(),
        b.get(..n).unwrap_or_default(),
    );
    let mut acc = [0.0f64; LANES];
    let (ca, cb) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (xa, xb) in ca.zip(cb) {
        for ((s, p), q) in acc.iter_mut().zip(xa).zip(xb) {
            *s += p * q;
        }
    }
    for ((s, p), q) in acc.iter_mut().zip(ra).zip(rb) {
        *s += p * q;
    }
    let [a0, a1, a2, a3, a4, a5, a6, a7] = acc;
    ((a0 + a4) + (a2 + a6)) + ((a1 + a5) + (a3 + a7))
}

/// A centred, symmetric FIR kernel, applied as a correlation; samples outside the signal
/// count as zero (the callers mask before filtering, so the ends are consistent).
#[derive(Clone, Debug, PartialEq)]
pub struct Kernel {
    taps: Vec<f64>,
}

impl Kernel {
    /// A kernel of odd length (an even one gets a trailing zero).
    pub fn new(mut taps: Vec<f64>) -> Self {
        if taps.len().is_multiple_of(2) {
            taps.push(0.0);
        }
        Kernel { taps }
    }

    /// Half length: samples on each side of the centre.
    pub fn half(&self) -> usize {
        self.taps.len() / 2
    }

    /// The taps.
    pub fn taps(&self) -> &[f64] {
        &self.taps
    }

    /// The filtered value at sample `i`.
    #[inline]
    pub fn at(&self, x: &[f64], i: usize) -> f64 {
        let h = self.half();
        if i >= h && i + h < x.len() {
            // Interior: one slice, no bounds juggling in the loop.
            let window = x.get(i - h..=i + h).unwrap_or_default();
            return dot(window, &self.taps);
        }
        self.taps
            .iter()
            .enumerate()
            .filter_map(|(j, w)| {
                let k = (i + j).checked_sub(h)?;
                x.get(k).map(|v| v * w)
            })
            .sum()
    }

    /// The filtered signal at every sample.
    pub fn apply(&self, x: &[f64]) -> Vec<f64> {
        if x.len() < FFT_MIN_SAMPLES || self.taps.len() < FFT_MIN_TAPS {
            return (0..x.len()).map(|i| self.at(x, i)).collect();
        }
        self.apply_fft(x)
    }

    /// [`Self::apply`] by FFT convolution (overlap–save in blocks, each block on its own
    /// core): the same sums as [`Self::at`], to rounding (≈ 10⁻¹⁵ of the signal's scale),
    /// at a cost that does not grow with the kernel's length.
    fn apply_fft(&self, x: &[f64]) -> Vec<f64> {
        use rayon::prelude::*;
        use rustfft::num_complex::Complex;
        let (n, taps, h) = (x.len(), self.taps.len(), self.half());
        let size = (8 * taps).next_power_of_two().max(4096);
        let step = size - (taps - 1);
        let (forward, inverse) = crate::signal::fft_pair(size);
        // The correlation `y[i] = Σⱼ taps[j]·x[i + j − h]` is the convolution with the
        // reversed taps, read `h` samples on: `y[i] = (rev ∗ x)[i + h]`.
        let mut kernel: Vec<Complex<f64>> = self
            .taps
            .iter()
            .rev()
            .map(|&t| Complex::new(t / size as f64, 0.0))
            .chain(std::iter::repeat(Complex::new(0.0, 0.0)))
            .take(size)
            .collect();
        forward.process(&mut kernel);
        // Block b yields the convolution at m = b·step … b·step + step − 1, from the input
        // samples m − (taps − 1) … m (zero outside the signal).
        let wanted = n + h; // the convolution up to m = n − 1 + h
        let blocks = wanted.div_ceil(step);
        let parts: Vec<Vec<f64>> = (0..blocks)
            .into_par_iter()
            .map(|b| {
                let start = (b * step) as isize - (taps as isize - 1);
                let mut buf: Vec<Complex<f64>> = (0..size as isize)
                    .map(|k| {
                        let v = usize::try_from(start + k).ok().and_then(|i| x.get(i));
                        Complex::new(v.copied().unwrap_or(0.0), 0.0)
                    })
                    .collect();
                forward.process(&mut buf);
                buf.iter_mut().zip(&kernel).for_each(|(a, k)| *a *= k);
                inverse.process(&mut buf);
                buf.into_iter().skip(taps - 1).map(|c| c.re).collect()
            })
            .collect();
        parts.into_iter().flatten().skip(h).take(n).collect()
    }

    /// The filtered signal at the samples `idx` only.
    pub fn apply_at(&self, x: &[f64], idx: &[usize]) -> Vec<f64> {
        idx.iter().map(|&i| self.at(x, i)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sg_weights_differentiate_a_parabola_exactly() {
        let dt = 1e-3;
        let w = sg_weights(21, 2, 2, dt).unwrap();
        let x: Vec<f64> = (0..21).map(|i| 3.0 * (i as f64 * dt).powi(2)).collect();
        let a: f64 = w.iter().zip(&x).map(|(w, x)| w * x).sum();
        assert!((a - 6.0).abs() < 1e-6, "{a}");
        let w1 = sg_weights(21, 2, 1, dt).unwrap();
        let v: f64 = w1.iter().zip(&x).map(|(w, x)| w * x).sum();
        assert!((v - 6.0 * 10.0 * dt).abs() < 1e-9);
        assert!(sg_weights(4, 2, 2, dt).is_none() && sg_weights(5, 2, 3, dt).is_none());
    }

    #[test]
    fn sg_weights_match_the_firmware_differentiator() {
        // Push an impulse of one count through the firmware's own filter (centred): its
        // outputs are the weights times metres per count.
        use fpc::sensing::differentiator::{SavitzkyGolay, SgConfig};
        use fpc::sensing::encoder::PositionCounts;
        let (n, dt, mpc) = (41usize, 50e-6, 1e-6f32);
        let mut sg = SavitzkyGolay::new(SgConfig {
            window: n,
            order: 2,
            lag: n / 2,
            sample_time_s: dt as f32,
            m_per_count: mpc,
        })
        .unwrap();
        let mut out = Vec::new();
        for i in 0..2 * n {
            out.push(
                sg.push(PositionCounts::from_bits(i32::from(i == n)))
                    .acceleration_mps2,
            );
        }
        let w = sg_weights(n, 2, 2, dt).unwrap();
        // Output k (k ≥ n) sees the impulse at window position 2n − 1 − k … as a dot product
        // the impulse at age k − n multiplies weight (n − 1) − (k − n).
        for (j, wj) in w.iter().enumerate() {
            let k = n + (n - 1 - j);
            let fw = f64::from(out[k]) / f64::from(mpc);
            assert!(
                (fw - wj).abs() < 1e-5 * wj.abs().max(1e3),
                "j={j}: {fw} vs {wj}"
            );
        }
    }

    #[test]
    fn force_kernel_reproduces_the_acceleration_filter() {
        let dt = 50e-6;
        let h2 = sg_weights(41, 2, 2, dt).unwrap();
        let g = force_kernel(&h2, dt);
        assert!((g.iter().sum::<f64>() - 1.0).abs() < 1e-9);
        // h₂ ⋆ x == g ⋆ Δ²x on an arbitrary signal.
        let x: Vec<f64> = (0..200)
            .map(|i| ((i * i) as f64 * 0.37).sin() * 1e-3 + (i as f64 * 0.01).cos())
            .collect();
        let d2: Vec<f64> = (0..x.len())
            .map(
                |i| match (i.checked_sub(1).and_then(|k| x.get(k)), x.get(i + 1)) {
                    (Some(a), Some(c)) => (a - 2.0 * x[i] + c) / (dt * dt),
                    _ => 0.0,
                },
            )
            .collect();
        let (kh, kg) = (Kernel::new(h2), Kernel::new(g));
        for i in 30..170 {
            let a = kh.at(&x, i);
            let b = kg.at(&d2, i);
            assert!((a - b).abs() < 1e-6 * a.abs().max(1.0), "{i}: {a} {b}");
        }
    }

    #[test]
    fn the_lane_dot_product_equals_the_serial_sum_within_rounding() {
        for n in [0usize, 1, 7, 8, 9, 305, 4001] {
            let a: Vec<f64> = (0..n).map(|i| ((i * 7919) as f64 * 0.013).sin()).collect();
            let b: Vec<f64> = (0..n)
                .map(|i| ((i * 104_729) as f64 * 0.007).cos())
                .collect();
            let serial: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
            let bound: f64 = a.iter().zip(&b).map(|(x, y)| (x * y).abs()).sum();
            let lanes = dot(&a, &b);
            assert!(
                (lanes - serial).abs() <= 1e-14 * bound.max(1.0),
                "{n}: {lanes} {serial}"
            );
        }
        assert_eq!(dot(&[1.0, 2.0, 3.0], &[4.0, 5.0]), 14.0);
    }

    #[test]
    fn the_fft_filter_equals_the_direct_sums() {
        let fs = 20_000.0;
        for taps in [lowpass(300.0, fs), lowpass(2_000.0, fs), vec![0.5, 0.25]] {
            let k = Kernel::new(taps);
            for n in [1usize, 200, 4_095, 40_000] {
                let x: Vec<f64> = (0..n)
                    .map(|i| ((i * 7919) as f64 * 0.013).sin() * 100.0 + (i as f64 * 1e-3).cos())
                    .collect();
                let fast = k.apply_fft(&x);
                assert_eq!(fast.len(), n);
                for (i, f) in fast.iter().enumerate() {
                    let direct = k.at(&x, i);
                    assert!((f - direct).abs() < 1e-11, "{n} at {i}: {f} {direct}");
                }
            }
        }
    }

    #[test]
    fn lowpass_passes_dc_and_stops_above_the_band() {
        let fs = 20_000.0;
        let k = Kernel::new(lowpass(300.0, fs));
        let gain = |f: f64| {
            let x: Vec<f64> = (0..8000)
                .map(|i| (std::f64::consts::TAU * f * i as f64 / fs).sin())
                .collect();
            let y = k.apply(&x);
            let rms = |v: &[f64]| (v.iter().map(|a| a * a).sum::<f64>() / v.len() as f64).sqrt();
            rms(&y[2000..6000]) / rms(&x[2000..6000])
        };
        assert!((gain(50.0) - 1.0).abs() < 0.01);
        assert!(gain(1000.0) < 0.01);
        assert_eq!(lowpass(20_000.0, fs), vec![1.0]);
    }
}
