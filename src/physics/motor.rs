//! The linear motor section: its parameters and the Clarke/Park transforms of its phases.
//!
//! Each of the two iron-core PM sections is a three-phase synchronous motor whose electrical
//! period is the encoder period λ (the N–N magnet pitch, 24 mm). In the rotor (dq) frame,
//! amplitude-invariant, the force is `F = K_f·i_q` and the back-EMF on q is `K_e·v` with
//! `K_e = 2/3·K_f` (power balance `3/2·v_q·i_q = F·v`). The firmware's current loops and the
//! simulator's motor model use these same transforms and parameters.

use crate::real::Real;
use crate::reference::motor;

/// Electrical parameters of one motor section (SI; reference values are assumptions **A**
/// chosen to give 5 kN peak at 62.5 A and 4 m/s under a 560 V bus).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorParams<T> {
    /// Force constant K_f, N/A (q-axis current, amplitude-invariant).
    pub force_constant_n_per_a: T,
    /// Phase resistance, Ω.
    pub resistance_ohm: T,
    /// Synchronous inductance (d = q, iron core with little saliency), H.
    pub inductance_h: T,
    /// Electrical period (N–N pitch), m.
    pub electrical_period_m: T,
    /// DC bus voltage, V.
    pub bus_voltage_v: T,
    /// Peak phase-current limit, A.
    pub current_limit_a: T,
}

impl<T: Real> MotorParams<T> {
    /// Reference section: K_f 80 N/A, R 0.6 Ω, L 6 mH, λ 24 mm, 560 V bus, 62.5 A peak.
    pub fn reference() -> Self {
        MotorParams {
            force_constant_n_per_a: T::of(motor::FORCE_CONSTANT_N_PER_A as f32),
            resistance_ohm: T::of(motor::RESISTANCE_OHM as f32),
            inductance_h: T::of(motor::INDUCTANCE_H as f32),
            electrical_period_m: T::of((2.0 * motor::POLE_PITCH_M) as f32),
            bus_voltage_v: T::of(motor::BUS_VOLTAGE_V as f32),
            current_limit_a: T::of(motor::CURRENT_LIMIT_A as f32),
        }
    }

    /// Back-EMF constant on q, V per m/s (= 2/3·K_f).
    #[inline]
    pub fn back_emf_v_per_mps(&self) -> T {
        T::of(2.0 / 3.0) * self.force_constant_n_per_a
    }

    /// Electrical angular speed at velocity `v_mps`, rad/s.
    #[inline]
    pub fn electrical_speed(&self, v_mps: T) -> T {
        T::of(2.0) * T::PI * v_mps / self.electrical_period_m
    }

    /// Peak phase voltage available with space-vector modulation (V_dc/√3), V.
    #[inline]
    pub fn voltage_limit_v(&self) -> T {
        self.bus_voltage_v * T::of(0.577_350_3)
    }

    /// Copper loss of the section carrying `current`, W: `3/2·R·(i_d² + i_q²)`, the three
    /// phases' `R·Σi_k²` in amplitude-invariant dq.
    #[inline]
    pub fn copper_loss_w(&self, current: Dq<T>) -> T {
        T::of(1.5) * self.resistance_ohm * (current.d * current.d + current.q * current.q)
    }
}

/// A quantity in the stator frame (α, β).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AlphaBeta<T> {
    /// α component.
    pub alpha: T,
    /// β component.
    pub beta: T,
}

/// A quantity in the rotor frame (d, q).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Dq<T> {
    /// Direct (flux) axis.
    pub d: T,
    /// Quadrature (force) axis.
    pub q: T,
}

/// Clarke transform, amplitude-invariant, from three phase values (any common mode drops).
#[inline]
pub fn clarke<T: Real>(abc: [T; 3]) -> AlphaBeta<T> {
    let [a, b, c] = abc;
    AlphaBeta {
        alpha: (T::of(2.0) * a - b - c) * T::of(1.0 / 3.0),
        beta: (b - c) * T::of(0.577_350_3),
    }
}

/// Inverse Clarke: phase values with zero sum.
#[inline]
pub fn inverse_clarke<T: Real>(ab: AlphaBeta<T>) -> [T; 3] {
    let half = T::of(0.5);
    let s = T::of(0.866_025_4);
    [
        ab.alpha,
        -half * ab.alpha + s * ab.beta,
        -half * ab.alpha - s * ab.beta,
    ]
}

/// Park transform with the electrical angle given as (sin θ, cos θ).
#[inline]
pub fn park<T: Real>(ab: AlphaBeta<T>, sin: T, cos: T) -> Dq<T> {
    Dq {
        d: ab.alpha * cos + ab.beta * sin,
        q: -ab.alpha * sin + ab.beta * cos,
    }
}

/// Inverse Park transform.
#[inline]
pub fn inverse_park<T: Real>(dq: Dq<T>, sin: T, cos: T) -> AlphaBeta<T> {
    AlphaBeta {
        alpha: dq.d * cos - dq.q * sin,
        beta: dq.d * sin + dq.q * cos,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transforms_round_trip() {
        let theta: f64 = 0.7;
        let dq = Dq { d: 1.5, q: -2.0 };
        let abc = inverse_clarke(inverse_park(dq, theta.sin(), theta.cos()));
        assert!((abc[0] + abc[1] + abc[2]).abs() < 1e-12);
        let back = park(clarke(abc), theta.sin(), theta.cos());
        assert!((back.d - dq.d).abs() < 1e-6 && (back.q - dq.q).abs() < 1e-6);
    }

    #[test]
    fn copper_loss_is_the_phases_resistive_loss() {
        let m = MotorParams::<f64>::reference();
        let theta: f64 = 1.9;
        let dq = Dq { d: 3.0, q: 20.0 };
        let abc = inverse_clarke(inverse_park(dq, theta.sin(), theta.cos()));
        let phases: f64 = abc.iter().map(|i| m.resistance_ohm * i * i).sum();
        // (The transforms' constants are written to f32 precision.)
        assert!((m.copper_loss_w(dq) - phases).abs() < 1e-6 * phases);
        // 20 A on q alone in 0.6 Ω: 3/2·0.6·400 = 360 W.
        let q_only = m.copper_loss_w(Dq { d: 0.0, q: 20.0 });
        assert!((q_only - 360.0).abs() < 1e-4);
    }
}
