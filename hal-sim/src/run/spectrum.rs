//! The largest spectral line of a signal in a band and the noise floor around it: how the
//! run tells a self-excited loop (the paper's 400 Hz, §4) from sensor noise.
//!
//! One Hann-windowed FFT of the mean-removed signal ([`rustfft`]); a bin's amplitude is
//! `2·|X_k|/Σw`, so a sine of amplitude `A` reads `A` at its bin. Each bin's floor is the
//! median amplitude from [`LINE_HALF_WIDTH_HZ`] to [`FLOOR_HALF_WIDTH_HZ`] either side of
//! it: a spectrum that merely falls or rises across the band (the stroke's own error, a
//! ripple swept by the changing speed) sits on its floor, and only a line stands clear of it
//! — one whose frequency wanders by up to ±15 Hz (a limit cycle whose voltage headroom
//! changes with the speed) does not raise its own floor. The line reported is the bin of
//! the band that stands highest above its floor.

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;
use serde::Serialize;
use std::ops::Range;

/// Band searched for the paper's self-excitation, Hz (400 Hz ± 15 %).
pub const LINE_BAND_HZ: (f64, f64) = (340.0, 460.0);

/// Half-width of the neighbourhood whose median amplitude is a bin's noise floor, Hz.
pub const FLOOR_HALF_WIDTH_HZ: f64 = 100.0;

/// Half-width around a bin left out of its floor (the line's own spread), Hz.
pub const LINE_HALF_WIDTH_HZ: f64 = 15.0;

/// Fewest samples analysed (0.1 s at 20 kHz): a shorter record gives no figure.
pub const MIN_SAMPLES: usize = 2000;

/// A line found in a band.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Line {
    /// Frequency of the largest bin in the band, Hz.
    pub hz: f64,
    /// Its amplitude, in the signal's unit.
    pub amplitude: f64,
    /// Median amplitude from ±[`LINE_HALF_WIDTH_HZ`] to ±[`FLOOR_HALF_WIDTH_HZ`] of the line.
    pub floor: f64,
}

impl Line {
    /// Amplitude over the floor.
    pub fn prominence(&self) -> f64 {
        self.amplitude / self.floor.max(f64::MIN_POSITIVE)
    }
}

/// Amplitude spectrum of `x` sampled every `dt_s`: (frequency, amplitude) per bin.
pub fn amplitude_spectrum(x: &[f64], dt_s: f64) -> Vec<(f64, f64)> {
    let n = x.len();
    if n < 2 {
        return Vec::new();
    }
    let mean = x.iter().sum::<f64>() / n as f64;
    let w: Vec<f64> = (0..n)
        .map(|k| 0.5 - 0.5 * (std::f64::consts::TAU * k as f64 / n as f64).cos())
        .collect();
    let wsum: f64 = w.iter().sum();
    let mut buf: Vec<Complex<f64>> = x
        .iter()
        .zip(&w)
        .map(|(v, w)| Complex::new((v - mean) * w, 0.0))
        .collect();
    FftPlanner::new().plan_fft_forward(n).process(&mut buf);
    let df = 1.0 / (n as f64 * dt_s);
    buf.iter()
        .take(n / 2 + 1)
        .enumerate()
        .map(|(k, c)| (k as f64 * df, 2.0 * c.norm() / wsum))
        .collect()
}

/// The amplitude spectrum of one record ([`amplitude_spectrum`]), taken once and searched
/// band by band.
pub struct Spectrum {
    bins: Vec<(f64, f64)>,
}

impl Spectrum {
    /// The spectrum of `x` sampled every `dt_s`, or `None` for a record shorter than
    /// [`MIN_SAMPLES`].
    pub fn of(x: &[f64], dt_s: f64) -> Option<Self> {
        (x.len() >= MIN_SAMPLES).then(|| Spectrum {
            bins: amplitude_spectrum(x, dt_s),
        })
    }

    /// The bin of `band` that stands highest above its floor, and that floor.
    pub fn line_in(&self, band: (f64, f64)) -> Option<Line> {
        let spec = &self.bins;
        let df = spec.get(1).map_or(1.0, |b| b.0);
        let half = (FLOOR_HALF_WIDTH_HZ / df).round().max(2.0) as usize;
        let gap = (LINE_HALF_WIDTH_HZ / df).round().min(half as f64 - 1.0) as usize;
        let mut around = Neighbourhood::default();
        spec.iter()
            .enumerate()
            .filter(|(_, (f, _))| (band.0..=band.1).contains(f))
            .filter_map(|(k, &(hz, amplitude))| {
                let below = k.saturating_sub(half)..k.saturating_sub(gap);
                let above = (k + gap + 1).min(spec.len())..(k + half + 1).min(spec.len());
                spec.get(below.clone())?;
                spec.get(above.clone())?;
                around.move_to(spec, below, above);
                Some(Line {
                    hz,
                    amplitude,
                    floor: around.median()?,
                })
            })
            .max_by(|a, b| a.prominence().total_cmp(&b.prominence()))
    }
}

/// A bin's neighbourhood for its floor: the amplitudes of the bins `below` and `above` it,
/// kept sorted (by `f64::total_cmp`) as the bins advance, so each bin costs the bins that
/// enter and leave, not a selection over the whole neighbourhood.
#[derive(Default)]
struct Neighbourhood {
    sorted: Vec<f64>,
    below: Range<usize>,
    above: Range<usize>,
}

impl Neighbourhood {
    /// Moves to the bins `below` and `above` of `spec` (valid ranges of it).
    fn move_to(&mut self, spec: &[(f64, f64)], below: Range<usize>, above: Range<usize>) {
        let old_below = std::mem::replace(&mut self.below, below.clone());
        let old_above = std::mem::replace(&mut self.above, above.clone());
        for (old, new) in [(old_below, below), (old_above, above)] {
            for i in outside(&old, &new) {
                let v = spec[i].1;
                if let Ok(j) = self.sorted.binary_search_by(|p| p.total_cmp(&v)) {
                    self.sorted.remove(j);
                }
            }
            for i in outside(&new, &old) {
                let v = spec[i].1;
                let j = self
                    .sorted
                    .binary_search_by(|p| p.total_cmp(&v))
                    .unwrap_or_else(|j| j);
                self.sorted.insert(j, v);
            }
        }
    }

    /// The median amplitude (the upper one of an even count), or `None` for no bins.
    fn median(&self) -> Option<f64> {
        self.sorted.get(self.sorted.len() / 2).copied()
    }
}

/// The indices of `a` that are not in `b`: below `b`'s start, and from `b`'s end.
fn outside(a: &Range<usize>, b: &Range<usize>) -> impl Iterator<Item = usize> {
    (a.start..a.end.min(b.start)).chain(a.start.max(b.end)..a.end)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sorted_neighbourhood_gives_the_median_a_selection_gives() {
        let mut noise = crate::plant::noise::Noise::new(11);
        // Repeated values too: ties must leave the same median.
        let spec: Vec<(f64, f64)> = (0..400)
            .map(|k| (k as f64, (noise.normal().abs() * 8.0).round() / 4.0))
            .collect();
        let (half, gap) = (37, 6);
        let mut around = Neighbourhood::default();
        for k in 20usize..380 {
            let below = k.saturating_sub(half)..k.saturating_sub(gap);
            let above = (k + gap + 1).min(spec.len())..(k + half + 1).min(spec.len());
            around.move_to(&spec, below.clone(), above.clone());
            let mut all: Vec<f64> = spec[below]
                .iter()
                .chain(&spec[above])
                .map(|b| b.1)
                .collect();
            let mid = all.len() / 2;
            let (_, m, _) = all.select_nth_unstable_by(mid, f64::total_cmp);
            assert_eq!(
                around.median().map(f64::to_bits),
                Some(m.to_bits()),
                "bin {k}"
            );
        }
    }

    #[test]
    fn a_sine_in_noise_reads_its_frequency_and_amplitude() {
        let dt = 50e-6;
        let mut noise = crate::plant::noise::Noise::new(3);
        let x: Vec<f64> = (0..20_000)
            .map(|k| {
                let t = k as f64 * dt;
                3e-6 * (std::f64::consts::TAU * 410.0 * t).sin() + 1e-6 * noise.normal()
            })
            .collect();
        let line = Spectrum::of(&x, dt).unwrap().line_in(LINE_BAND_HZ).unwrap();
        assert!((line.hz - 410.0).abs() <= 0.05, "{line:?}");
        assert!((line.amplitude - 3e-6).abs() < 0.1e-6, "{line:?}");
        // White noise of σ over N samples: ≈ σ·√(π/N)·√(1.5)… per bin, far below the line.
        assert!(line.prominence() > 50.0, "{line:?}");
        let quiet: Vec<f64> = x
            .iter()
            .enumerate()
            .map(|(k, _)| 1e-6 * ((k * 7919) % 13) as f64)
            .collect();
        assert!(Spectrum::of(&quiet[..100], dt).is_none());
    }
}
