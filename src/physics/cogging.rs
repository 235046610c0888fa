//! Cogging (detent) force of the iron-core linear motor: periodic in position at the magnet
//! pitch, independent of current and speed.
//!
//! One concept, three users: the simulator's plant evaluates [`CoggingParams::force_n`]
//! (the `[effects.cogging]` single harmonic of the model file), the firmware compensates with
//! a calibrated [`HarmonicMap`], and the model-gap workflow fits the same harmonic form.
//! Sign: the force acts on the piston, positive toward +x.

use crate::real::Real;
use crate::reference::effects::cogging;

/// A single-harmonic cogging law `F = A·sin(2π·x/p + φ)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoggingParams<T> {
    /// Amplitude A, N.
    pub amplitude_n: T,
    /// Period p, m (the N–N pitch, 24 mm, on the reference machine).
    pub period_m: T,
    /// Phase φ, rad.
    pub phase_rad: T,
}

impl<T: Real> CoggingParams<T> {
    /// The reference machine: 30 N at the 24 mm pitch (**A**).
    pub fn reference() -> Self {
        CoggingParams {
            amplitude_n: T::of(cogging::AMPLITUDE_N as f32),
            period_m: T::of(cogging::PERIOD_M as f32),
            phase_rad: T::of(cogging::PHASE_RAD as f32),
        }
    }

    /// Cogging force at position `x_m`, N.
    #[inline]
    pub fn force_n(&self, x_m: T) -> T {
        self.amplitude_n * (T::of(2.0) * T::PI * x_m / self.period_m + self.phase_rad).sin()
    }
}

/// Harmonics a [`HarmonicMap`] holds.
pub const MAP_HARMONICS: usize = 4;

/// A calibrated cogging map: `F(x) = Σₖ aₖ·sin(2πk·x/p) + bₖ·cos(2πk·x/p)`, k = 1..=4.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HarmonicMap {
    /// Fundamental period p, m (> 0; a map with p ≤ 0 gives zero force).
    pub period_m: f32,
    /// Sine coefficients a₁..a₄, N.
    pub sin_n: [f32; MAP_HARMONICS],
    /// Cosine coefficients b₁..b₄, N.
    pub cos_n: [f32; MAP_HARMONICS],
}

impl HarmonicMap {
    /// An empty map (no compensation).
    pub const fn none() -> Self {
        HarmonicMap {
            period_m: 0.024,
            sin_n: [0.0; MAP_HARMONICS],
            cos_n: [0.0; MAP_HARMONICS],
        }
    }

    /// True if every coefficient is zero (no compensation).
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.sin_n.iter().chain(&self.cos_n).all(|c| *c == 0.0)
    }

    /// Cogging force the map predicts at `x_m`, N. One sin/cos of the fundamental, then
    /// Clenshaw's recurrence for both series, `yₖ = cₖ + 2·cos θ·yₖ₊₁ − yₖ₊₂` (k = 4..1), so
    /// that `Σ aₖ·sin kθ = y₁(a)·sin θ` and `Σ bₖ·cos kθ = y₁(b)·cos θ − y₂(b)`: two
    /// multiply-adds per harmonic and series, the fewest instructions on the MCU. Always
    /// inlined: it is part of the control step's allocation (the calibration calls that too).
    #[inline(always)]
    pub fn force_n(&self, x_m: f32) -> f32 {
        if self.period_m <= 0.0 {
            return 0.0;
        }
        // No test for an empty map: its zeros sum to exactly 0, and a calibrated machine,
        // the one the step's budget is for, would pay for the test every cycle.
        let (s1, c1) = crate::angle::sin_cos_turns(crate::angle::turns(x_m / self.period_m));
        let two_c = 2.0 * c1;
        let ([a1, a2, a3, a4], [b1, b2, b3, b4]) = (self.sin_n, self.cos_n);
        // y₅ = y₆ = 0: y₄ = c₄ and y₃ = c₃ + 2·cos θ·c₄, written out (a float multiply by a
        // literal zero is not folded away).
        let (ya3, yb3) = (a3 + two_c * a4, b3 + two_c * b4);
        let (ya2, yb2) = (a2 + two_c * ya3 - a4, b2 + two_c * yb3 - b4);
        let ya1 = a1 + two_c * ya2 - ya3;
        let yb1 = b1 + two_c * yb2 - yb3;
        ya1 * s1 + yb1 * c1 - yb2
    }

    /// Least-squares fit of the map to samples `(x_m, force_n)` with fundamental `period_m`
    /// (each harmonic fitted by projection, exact for samples spread evenly over whole
    /// periods). Returns the empty map if there are no samples.
    pub fn fit<I: IntoIterator<Item = (f32, f32)>>(samples: I, period_m: f32) -> HarmonicMap {
        let mut sums_s = [0.0f64; MAP_HARMONICS];
        let mut sums_c = [0.0f64; MAP_HARMONICS];
        let mut n = 0u32;
        for (x, f) in samples {
            let base = core::f64::consts::TAU * f64::from(x) / f64::from(period_m);
            for (k, (ss, sc)) in sums_s.iter_mut().zip(sums_c.iter_mut()).enumerate() {
                let ang = base * (k + 1) as f64;
                *ss += f64::from(f) * libm::sin(ang);
                *sc += f64::from(f) * libm::cos(ang);
            }
            n += 1;
        }
        if n == 0 {
            return HarmonicMap::none();
        }
        let scale = 2.0 / f64::from(n);
        HarmonicMap {
            period_m,
            sin_n: sums_s.map(|v| (v * scale) as f32),
            cos_n: sums_c.map(|v| (v * scale) as f32),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_harmonic_is_summed_as_the_series_says() {
        let map = HarmonicMap {
            period_m: 0.024,
            sin_n: [27.6, 1.4, -0.6, 0.3],
            cos_n: [11.9, -0.9, 0.4, -0.2],
        };
        for i in 0..2000 {
            let x = -0.03 + i as f32 * 1.3e-4;
            let theta = core::f64::consts::TAU * f64::from(x) / 0.024;
            let series: f64 = (0..MAP_HARMONICS)
                .map(|k| {
                    let kt = (k + 1) as f64 * theta;
                    f64::from(map.sin_n[k]) * kt.sin() + f64::from(map.cos_n[k]) * kt.cos()
                })
                .sum();
            let err = f64::from(map.force_n(x)) - series;
            // The sine table's linear interpolation: ≤ (2π/256)²/8 ≈ 7.5e-5 of each
            // coefficient (43 N in all here: 3.2e-3 N).
            assert!(err.abs() < 3.5e-3, "x={x} err={err}");
        }
    }

    #[test]
    fn map_fits_and_reproduces_the_law() {
        let law = CoggingParams::<f64> {
            amplitude_n: 30.0,
            period_m: 0.024,
            phase_rad: 0.7,
        };
        let samples = (0..2400).map(|i| {
            let x = i as f64 * 1e-4; // 10 periods
            (x as f32, law.force_n(x) as f32)
        });
        let map = HarmonicMap::fit(samples, 0.024);
        for i in 0..500 {
            let x = 0.013 + i as f64 * 3.7e-4;
            let err = f64::from(map.force_n(x as f32)) - law.force_n(x);
            assert!(err.abs() < 0.3, "x={x} err={err}");
        }
    }

    #[test]
    fn every_harmonic_of_a_map_is_reproduced() {
        // A map with all four harmonics, against the direct f64 sum of its series; the
        // table sine's 8e-5 bounds the error at about 1e-4 of the coefficients' sum.
        let map = HarmonicMap {
            period_m: 0.024,
            sin_n: [27.6, 1.4, -0.6, 0.3],
            cos_n: [11.9, -0.9, 0.4, -0.2],
        };
        let mut worst = 0.0f64;
        for i in -2000..2000 {
            let x = i as f64 * 7.3e-5;
            let theta = core::f64::consts::TAU * x / 0.024;
            let want: f64 = (1..=MAP_HARMONICS)
                .map(|k| {
                    let kt = k as f64 * theta;
                    f64::from(map.sin_n[k - 1]) * kt.sin() + f64::from(map.cos_n[k - 1]) * kt.cos()
                })
                .sum();
            worst = worst.max((f64::from(map.force_n(x as f32)) - want).abs());
        }
        assert!(worst < 0.01, "worst {worst} N");
    }
}
