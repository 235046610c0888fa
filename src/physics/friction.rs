//! Friction of the translating piston: Bo & Pavelescu's Stribeck law (paper Eq. 3).
//!
//! `F_fr = (F_c + (F_s − F_c)·e^{−|v/v_s|^ζ})·sgn(v) + b·v`, positive opposing +x motion
//! (it is subtracted in `m·ẍ = … − F_fr`). One law for the firmware's feed-forward (`f32`),
//! the simulator's plant (`f64`) and the model-gap workflow's regressors.
//!
//! `sgn(v)` is regularised as `tanh(v/v_reg)`: the plant needs a continuous law to integrate
//! and the feed-forward must not chatter on velocity noise around a reversal.

use crate::real::Real;

/// Friction parameters, SI. Reference values from `machine.md` (assumed, **A**).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrictionParams<T> {
    /// Coulomb (sliding) level F_c, N, ≥ 0.
    pub coulomb_n: T,
    /// Static (breakaway) level F_s, N, ≥ F_c for a Stribeck dip (equal: no Stribeck effect).
    pub static_n: T,
    /// Stribeck velocity v_s, m/s, > 0.
    pub stribeck_velocity_mps: T,
    /// Stribeck exponent ζ, > 0 (1 = exponential, 2 = Gaussian).
    pub stribeck_exponent: T,
    /// Viscous coefficient b, N·s/m, ≥ 0.
    pub viscous_ns_per_m: T,
    /// Regularisation velocity of sgn(v), m/s, > 0 (much smaller than v_s).
    pub sign_velocity_mps: T,
}

impl<T: Real> FrictionParams<T> {
    /// The reference machine: F_c 40 N, F_s 60 N, v_s 0.02 m/s, ζ 1, b 25 N·s/m.
    pub fn reference() -> Self {
        FrictionParams {
            coulomb_n: T::of(40.0),
            static_n: T::of(60.0),
            stribeck_velocity_mps: T::of(0.02),
            stribeck_exponent: T::of(1.0),
            viscous_ns_per_m: T::of(25.0),
            sign_velocity_mps: T::of(1e-3),
        }
    }

    /// Friction force at velocity `v_mps`, N, with the sign of `v` (it opposes motion).
    ///
    /// Exact zero at rest; past 10 regularisation velocities tanh is 1 to 4e-9 and past 16
    /// Stribeck velocities the dip is below 1e-7 of its size, so those terms are skipped
    /// there (the firmware evaluates this every cycle).
    #[inline]
    pub fn force_n(&self, v_mps: T) -> T {
        if v_mps == T::ZERO {
            return T::ZERO;
        }
        let speed = v_mps.abs();
        let sign_ratio = speed / self.sign_velocity_mps;
        let magnitude = if sign_ratio >= T::of(10.0) {
            T::ONE
        } else {
            sign_ratio.tanh()
        };
        let sgn = if v_mps > T::ZERO {
            magnitude
        } else {
            -magnitude
        };
        let ratio = speed / self.stribeck_velocity_mps;
        let stribeck = if ratio >= T::of(16.0) {
            T::ZERO
        } else {
            // ζ = 1 is the common case; skip powf there (it is the expensive part on the MCU).
            let shaped = if self.stribeck_exponent == T::ONE {
                ratio
            } else {
                ratio.powf(self.stribeck_exponent)
            };
            (self.static_n - self.coulomb_n) * (-shaped).exp()
        };
        (self.coulomb_n + stribeck) * sgn + self.viscous_ns_per_m * v_mps
    }
}

impl<T: Real> FrictionParams<T> {
    /// The friction of a rotating, translating piston acts along the resultant sliding
    /// velocity u = (v_axial, v_tangential) of its surface; this is the secant F(|u|)/|u|,
    /// N·s/m: times v_axial it is the axial force, times v_tangential the tangential one
    /// (times the radius again for the torque). Zero slip gives the limit at 1 nm/s.
    #[inline]
    pub fn sliding_secant(&self, v_axial_mps: T, v_tangential_mps: T) -> T {
        let slip = (v_axial_mps * v_axial_mps + v_tangential_mps * v_tangential_mps)
            .sqrt()
            .max(T::of(1e-9));
        self.force_n(slip) / slip
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn friction_opposes_motion_and_is_odd() {
        let f = FrictionParams::<f64>::reference();
        for &v in &[1e-4, 1e-2, 0.1, 1.0, 4.0] {
            assert!(f.force_n(v) > 0.0);
            assert!((f.force_n(v) + f.force_n(-v)).abs() < 1e-9);
        }
        assert_eq!(f.force_n(0.0), 0.0);
    }

    #[test]
    fn stribeck_peak_near_zero_and_coulomb_plus_viscous_at_speed() {
        let f = FrictionParams::<f64>::reference();
        // Just past the regularisation: close to F_s.
        assert!((f.force_n(0.005) - 60.0).abs() < 6.0);
        // Far past v_s: F_c + b·v.
        assert!((f.force_n(2.0) - (40.0 + 50.0)).abs() < 1e-6);
    }

    #[test]
    fn a_turning_piston_splits_its_friction_along_the_sliding_velocity() {
        let f = FrictionParams::<f64>::reference();
        // No rotation: the axial force is the law itself.
        assert!((f.sliding_secant(2.0, 0.0) * 2.0 - f.force_n(2.0)).abs() < 1e-9);
        // Turning fast: the axial share falls by v/|u|, the magnitude is the law at |u|.
        let k = f.sliding_secant(0.3, 0.4);
        assert!((k * 0.5 - f.force_n(0.5)).abs() < 1e-9);
        assert!(k * 0.3 < f.force_n(0.3));
    }

    #[test]
    fn f32_and_f64_agree() {
        let f64p = FrictionParams::<f64>::reference();
        let f32p = FrictionParams::<f32>::reference();
        for i in -400..=400 {
            let v = i as f64 * 0.01;
            let a = f64p.force_n(v);
            let b = f64::from(f32p.force_n(v as f32));
            assert!((a - b).abs() < 0.05 + 1e-3 * a.abs(), "v={v} {a} {b}");
        }
    }
}
