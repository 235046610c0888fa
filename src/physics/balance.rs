//! The force balance on the piston, written once: the equation of motion
//!
//! `m·ẍ = F_motor + (p_A − p_B)·A_eff + F_cog(x) + F_ext − F_fr(ẋ, ω·r)`
//!
//! (`docs/machine.md`; every force toward +x except friction, which opposes the motion). The
//! simulator's plant integrates it, the model-gap workflow and `fpc-sim forces`/`energy`
//! evaluate it along a log (the force the model does not explain), the synthetic runs invert
//! it (the motor force a prescribed motion needs), and the firmware's disturbance observers
//! and feed-forward evaluate it with the forces they know. The laws of the single terms are
//! their own modules ([`super::friction`], [`super::gas`], [`super::cogging`]); this module
//! adds them up.
//!
//! The sum is evaluated in three orders, each for a reason, all here:
//! [`PistonForces::net_n`] as the motor force less the load the motor works against
//! ([`PistonForces::load_n`]: what a controller's feed-forward supplies beyond `m·a`),
//! [`PistonForces::driving_n`], every force but friction, for an integrator that takes
//! friction implicitly through its secant ([`implicit_velocity`]), and
//! [`PistonForces::unexplained_n`] term by term from `m·a` (the rounding order of the
//! controlled stop's observer). They differ by rounding only (a unit test holds them
//! together).

use crate::physics::cogging::CoggingParams;
use crate::physics::friction::FrictionParams;
use crate::physics::gas::Cylinder;
use crate::real::Real;

/// The forces on the piston, N: each toward +x, except friction, positive when it opposes
/// motion toward +x (it is subtracted).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PistonForces<T> {
    /// Both motor sections, `F_master + F_slave`.
    pub motor_n: T,
    /// Gas, `(p_A − p_B)·A_eff`.
    pub gas_n: T,
    /// Cogging.
    pub cogging_n: T,
    /// Anything else that pushes (the heads in contact, an external load).
    pub external_n: T,
    /// Friction (opposing +x motion when positive).
    pub friction_n: T,
}

impl<T: Real> PistonForces<T> {
    /// The forces a controller knows: the motors', the gas and friction (no cogging law, no
    /// external force).
    #[inline(always)]
    pub fn known(motor_n: T, gas_n: T, friction_n: T) -> Self {
        PistonForces {
            motor_n,
            gas_n,
            cogging_n: T::ZERO,
            external_n: T::ZERO,
            friction_n,
        }
    }

    /// The load the motor works against, `F_fr − F_gas − F_cog − F_ext`: the force it must
    /// supply beyond `m·a` (a feed-forward's model term).
    #[inline(always)]
    pub fn load_n(&self) -> T {
        self.friction_n - self.gas_n - self.cogging_n - self.external_n
    }

    /// The net force, `m·ẍ` by the model: the motor force less the load.
    #[inline(always)]
    pub fn net_n(&self) -> T {
        self.motor_n - self.load_n()
    }

    /// Every force but friction, `F_motor + F_gas + F_cog + F_ext`: what an integrator
    /// treating friction implicitly needs ([`implicit_velocity`]).
    #[inline(always)]
    pub fn driving_n(&self) -> T {
        self.motor_n + self.gas_n + self.cogging_n + self.external_n
    }

    /// The force the model does not explain at acceleration `accel_mps2` of a piston of
    /// `mass_kg`: `m·ẍ − F_net`, toward +x. Taken term by term from `m·ẍ`, the motor's
    /// first, the order the controlled stop's disturbance observer has always rounded in
    /// (f32; the absent cogging and external terms subtract exact zeros), so that a stop's
    /// run is the same bit for bit.
    #[inline(always)]
    pub fn unexplained_n(&self, mass_kg: T, accel_mps2: T) -> T {
        mass_kg * accel_mps2 - self.motor_n - self.gas_n - self.cogging_n - self.external_n
            + self.friction_n
    }

    /// The motor force that closes the balance at `accel_mps2` (the other forces as they
    /// are; `motor_n` is not read): `m·ẍ + load`.
    #[inline(always)]
    pub fn motor_needed_n(&self, mass_kg: T, accel_mps2: T) -> T {
        mass_kg * accel_mps2 + self.load_n()
    }
}

/// Where the piston is and how it moves, and what acts on it from outside the laws: the
/// inputs of [`PistonLaws::forces`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PistonState<T> {
    /// Position, m.
    pub x_m: T,
    /// Axial velocity, m/s.
    pub v_mps: T,
    /// Tangential speed of the sliding surface, `ω·r`, m/s (0: no rotation).
    pub tangential_mps: T,
    /// Chamber A pressure, Pa.
    pub pressure_a_pa: T,
    /// Chamber B pressure, Pa.
    pub pressure_b_pa: T,
    /// Both motor sections' force, N.
    pub motor_n: T,
}

/// The laws of the piston's forces with a machine's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PistonLaws<T> {
    /// Moving mass, kg.
    pub mass_kg: T,
    /// The cylinder (the gas force's area).
    pub cylinder: Cylinder<T>,
    /// Friction of the sliding surface.
    pub friction: FrictionParams<T>,
    /// Cogging, if the machine has it.
    pub cogging: Option<CoggingParams<T>>,
}

impl<T: Real> PistonLaws<T> {
    /// Every force at `state` (friction along the sliding velocity `(ẋ, ω·r)`).
    #[inline]
    pub fn forces(&self, state: &PistonState<T>) -> PistonForces<T> {
        PistonForces {
            motor_n: state.motor_n,
            gas_n: self
                .cylinder
                .gas_force_n(state.pressure_a_pa, state.pressure_b_pa),
            cogging_n: self.cogging.map_or(T::ZERO, |c| c.force_n(state.x_m)),
            external_n: T::ZERO,
            friction_n: self
                .friction
                .axial_force_n(state.v_mps, state.tangential_mps),
        }
    }

    /// The force the model does not explain at `state` and acceleration `accel_mps2`, N.
    #[inline]
    pub fn unexplained_n(&self, state: &PistonState<T>, accel_mps2: T) -> T {
        self.forces(state).unexplained_n(self.mass_kg, accel_mps2)
    }
}

/// One semi-implicit Euler step of `m·v̇ = F_driving − k·v` over `dt`, with friction through
/// its secant coefficient `k = F_fr(|u|)/|u| ≥ 0` taken at the new velocity (stable however
/// stiff the friction near a reversal): the new velocity, m/s. `dt_over_m` is `dt/m`.
#[inline]
pub fn implicit_velocity<T: Real>(v_mps: T, driving_n: T, secant_ns_per_m: T, dt_over_m: T) -> T {
    (v_mps + dt_over_m * driving_n) / (T::ONE + dt_over_m * secant_ns_per_m)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn laws() -> PistonLaws<f64> {
        PistonLaws {
            mass_kg: 12.0,
            cylinder: Cylinder::reference(),
            friction: FrictionParams::reference(),
            cogging: Some(CoggingParams::reference()),
        }
    }

    #[test]
    fn the_two_orders_of_the_sum_agree_and_the_inverse_closes_the_balance() {
        let laws = laws();
        let mut worst = 0.0f64;
        for i in 0..2000 {
            let k = i as f64;
            let state = PistonState {
                x_m: 0.001 + 1e-4 * k,
                v_mps: 4.0 * (0.013 * k).sin(),
                tangential_mps: 0.5 * (0.007 * k).cos(),
                pressure_a_pa: 1e5 + 3e5 * (0.011 * k).sin().abs(),
                pressure_b_pa: 1e5 + 2e5 * (0.017 * k).cos().abs(),
                motor_n: 3000.0 * (0.005 * k).sin(),
            };
            let f = laws.forces(&state);
            let by_driving = f.driving_n() - f.friction_n;
            worst = worst.max((f.net_n() - by_driving).abs());
            let a = 50.0 * (0.009 * k).sin();
            let by_net = laws.mass_kg * a - f.net_n();
            worst = worst.max((f.unexplained_n(laws.mass_kg, a) - by_net).abs());
            // The motor force the balance needs at some acceleration leaves nothing unexplained.
            let a = 100.0 * (0.003 * k).cos();
            let closed = PistonForces {
                motor_n: f.motor_needed_n(laws.mass_kg, a),
                ..f
            };
            assert!(closed.unexplained_n(laws.mass_kg, a).abs() < 1e-9, "{i}");
        }
        assert!(worst < 1e-9, "{worst}");
    }

    #[test]
    fn each_term_has_its_sign() {
        let laws = PistonLaws {
            cogging: None,
            ..laws()
        };
        let at = |v_mps: f64, pa: f64, pb: f64, motor_n: f64| {
            laws.forces(&PistonState {
                x_m: 0.1,
                v_mps,
                tangential_mps: 0.0,
                pressure_a_pa: pa,
                pressure_b_pa: pb,
                motor_n,
            })
        };
        // Higher pressure in A pushes toward +x (B); friction opposes the motion.
        assert!(at(0.0, 2e5, 1e5, 0.0).net_n() > 0.0);
        assert!(at(1.0, 1e5, 1e5, 0.0).net_n() < 0.0);
        assert!(at(-1.0, 1e5, 1e5, 0.0).net_n() > 0.0);
        // At rest with equal pressures only the motor acts, and m·a of it is explained.
        let f = at(0.0, 1e5, 1e5, 120.0);
        assert_eq!(f.net_n(), 120.0);
        assert_eq!(f.unexplained_n(12.0, 10.0), 0.0);
    }

    #[test]
    fn the_implicit_step_is_the_balance_at_the_new_velocity() {
        let (m, dt, v, driving, k) = (12.0, 5e-5, 0.3, 800.0, 4.0e3);
        let v1 = implicit_velocity(v, driving, k, dt / m);
        let residual = m * (v1 - v) / dt - (driving - k * v1);
        assert!(residual.abs() < 1e-6, "{residual}");
    }
}
