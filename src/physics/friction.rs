//! Friction of the translating piston: Bo & Pavelescu's Stribeck law (paper Eq. 3).
//!
//! `F_fr = (F_c + (F_s − F_c)·e^{−|v/v_s|^ζ})·sgn(v) + b·v`, positive opposing +x motion
//! (it is subtracted in `m·ẍ = … − F_fr`). One law for the firmware's feed-forward (`f32`),
//! the simulator's plant (`f64`) and the model-gap workflow's regressors.
//!
//! `sgn(v)` is regularised as `tanh(v/v_reg)`: the plant needs a continuous law to integrate
//! and the feed-forward must not chatter on velocity noise around a reversal.

use crate::real::Real;
use crate::reference::friction;

/// Friction parameters, SI. Reference values from `docs/machine.md` (assumed, **A**).
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
            coulomb_n: T::of(friction::COULOMB_N as f32),
            static_n: T::of(friction::STATIC_N as f32),
            stribeck_velocity_mps: T::of(friction::STRIBECK_VELOCITY_MPS as f32),
            stribeck_exponent: T::of(friction::STRIBECK_EXPONENT as f32),
            viscous_ns_per_m: T::of(friction::VISCOUS_NS_PER_M as f32),
            sign_velocity_mps: T::of(1e-3),
        }
    }

    /// Friction force at velocity `v_mps`, N, with the sign of `v` (it opposes motion):
    /// `(F_c + (F_s − F_c)·`[`stribeck_shape`]`)·`[`sign_magnitude`]`·sgn(v) + b·v`.
    ///
    /// Exact zero at rest; the shapes skip their transcendental functions where they are
    /// within 1e-7 of their limits (the firmware evaluates this every cycle).
    #[inline]
    pub fn force_n(&self, v_mps: T) -> T {
        if v_mps == T::ZERO {
            return T::ZERO;
        }
        let speed = v_mps.abs();
        let magnitude = sign_magnitude(speed, self.sign_velocity_mps);
        let sgn = if v_mps > T::ZERO {
            magnitude
        } else {
            -magnitude
        };
        let stribeck =
            match stribeck_term(speed, self.stribeck_velocity_mps, self.stribeck_exponent) {
                Some(shape) => (self.static_n - self.coulomb_n) * shape,
                None => T::ZERO,
            };
        (self.coulomb_n + stribeck) * sgn + self.viscous_ns_per_m * v_mps
    }
}

/// The regularised sign's magnitude at `speed ≥ 0`: `tanh(speed/v_reg)`, exactly 1 from 10
/// regularisation velocities on (where tanh is 1 to 4e-9).
#[inline(always)]
pub fn sign_magnitude<T: Real>(speed: T, sign_velocity_mps: T) -> T {
    let ratio = speed / sign_velocity_mps;
    if ratio >= T::of(10.0) {
        T::ONE
    } else {
        ratio.tanh()
    }
}

/// The Stribeck dip's shape at `speed ≥ 0`: `e^{−(speed/v_s)^ζ}`, exactly 0 where the
/// exponent reaches 16 (the dip below 1.2e-7 of its size, whatever ζ). ζ = 1, the common
/// case, and ζ = 2 take no `powf` (the expensive part on the MCU).
#[inline(always)]
pub fn stribeck_shape<T: Real>(speed: T, stribeck_velocity_mps: T, exponent: T) -> T {
    stribeck_term(speed, stribeck_velocity_mps, exponent).unwrap_or(T::ZERO)
}

/// [`stribeck_shape`], `None` where it is cut to 0 (so that the law can skip the dip's
/// product there too).
#[inline(always)]
fn stribeck_term<T: Real>(speed: T, stribeck_velocity_mps: T, exponent: T) -> Option<T> {
    let ratio = speed / stribeck_velocity_mps;
    let cut = T::of(16.0);
    let shaped = if exponent == T::ONE {
        ratio
    } else if exponent == T::of(2.0) {
        ratio * ratio
    } else {
        ratio.powf(exponent)
    };
    if shaped >= cut {
        None
    } else {
        Some((-shaped).exp())
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

    /// The axial friction of the piston sliding at `v_axial_mps` while its surface moves
    /// at `v_tangential_mps` around the axis: `F(|u|)·v/|u|` ([`Self::sliding_secant`]),
    /// and without rotation the law itself, `F(v)`. N, opposing +x motion when positive.
    #[inline]
    pub fn axial_force_n(&self, v_axial_mps: T, v_tangential_mps: T) -> T {
        if v_tangential_mps == T::ZERO {
            self.force_n(v_axial_mps)
        } else {
            self.sliding_secant(v_axial_mps, v_tangential_mps) * v_axial_mps
        }
    }

    /// The axial share of a unit friction force along the sliding velocity, with the sign
    /// regularised as the law does: `tanh(|u|/v_reg)·v/|u|` (0 at zero slip). The axial
    /// friction is `(F_c + (F_s − F_c)·S(|u|))·d + b·v` with this `d` and the Stribeck shape
    /// `S`: linear in F_c, F_s − F_c and b, as the model-gap fit uses it.
    #[inline]
    pub fn axial_direction(&self, v_axial_mps: T, v_tangential_mps: T) -> T {
        let slip = (v_axial_mps * v_axial_mps + v_tangential_mps * v_tangential_mps).sqrt();
        if slip > T::ZERO {
            sign_magnitude(slip, self.sign_velocity_mps) * v_axial_mps / slip
        } else {
            T::ZERO
        }
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
    fn the_dip_is_cut_only_where_it_is_negligible_whatever_its_exponent() {
        // Each shape against e^{−r^ζ} itself: never more than 1.2e-7 off, for ζ below 1 too
        // (a cut at 16 Stribeck velocities left e^{−4} = 1.8 % of the dip at ζ = 0.5).
        for zeta in [0.3, 0.5, 1.0, 1.7, 2.0, 3.0] {
            let mut worst = 0.0f64;
            for i in 0..20_000 {
                let speed = i as f64 * 1e-3;
                let exact = (-(speed / 0.02f64).powf(zeta)).exp();
                worst = worst.max((stribeck_shape(speed, 0.02, zeta) - exact).abs());
            }
            assert!(worst < 1.2e-7, "ζ = {zeta}: {worst:e}");
        }
        assert!(stribeck_shape(0.5f64, 0.02, 0.5) > 6e-3); // e^{−5}: not cut
        assert_eq!(stribeck_shape(6.0f64, 0.02, 0.5), 0.0);
        assert!((sign_magnitude(0.5e-3f64, 1e-3) - 0.5f64.tanh()).abs() < 1e-15);
        assert_eq!(sign_magnitude(0.01f64, 1e-3), 1.0);
    }

    #[test]
    fn the_axial_friction_is_the_law_without_rotation_and_its_direction_splits_it() {
        let f = FrictionParams::<f64>::reference();
        assert_eq!(f.axial_force_n(0.7, 0.0), f.force_n(0.7));
        // Linear in F_c, F_s − F_c and b along the direction d.
        for (v, t) in [(0.3, 0.4), (-1.5, 0.2), (2e-3, 1e-3), (0.05, 0.0)] {
            let slip = f64::hypot(v, t);
            let d = f.axial_direction(v, t);
            let s = stribeck_shape(slip, f.stribeck_velocity_mps, f.stribeck_exponent);
            let by_parts =
                (f.coulomb_n + (f.static_n - f.coulomb_n) * s) * d + f.viscous_ns_per_m * v;
            assert!((f.axial_force_n(v, t) - by_parts).abs() < 1e-9, "{v} {t}");
        }
        assert_eq!(f.axial_direction(0.0, 0.0), 0.0);
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
