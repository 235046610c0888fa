//! Both disturbance observers of the force balance on the piston, in one place — the
//! controlled stop's (the force the model does not explain, low-passed; the stop's state) and
//! the running strokes' (a momentum observer whose estimate the drive's feed-forward
//! cancels; the drive's state).

use super::publish::Previous;
use super::sense::Sensed;
use crate::control::config::ControlConfig;
use crate::physics::balance::PistonForces;
use crate::real::{clamp_f32, clamp_or_zero_f32};

/// Time constant of the controlled stop's disturbance observer, s: 2 ms, longer than the
/// differentiator's 1.25 ms window (its acceleration is the noisiest input) and still fast
/// next to the 10–30 ms a stop takes (shorter, the stop rings after a watchdog reset:
/// `tests/faults_are_caught_and_the_machine_stays_safe.rs`, s12).
pub const DOB_TIME_S: f32 = 2.0e-3;

/// The controlled stop's observer: its estimate, N (toward +x).
#[derive(Clone, Debug)]
pub(super) struct StopObserver {
    /// The estimate of the force the model does not explain, N.
    pub n: f32,
}

impl StopObserver {
    pub(super) fn new() -> Self {
        StopObserver { n: 0.0 }
    }

    /// The disturbance observer of a controlled stop: the force on the piston that the model
    /// does not explain, `m·a − (F_motor + F_gas − F_friction(v))`
    /// ([`PistonForces::unexplained_n`]) from the measured acceleration (`st`: the last
    /// cycle's), motor force (q-currents) and gas force (when the pressures are usable;
    /// otherwise the gas is part of what it estimates), low-passed over [`DOB_TIME_S`]. N,
    /// toward +x.
    #[cold]
    #[inline(never)]
    pub(super) fn observe(
        &mut self,
        c: &ControlConfig,
        st: &Previous,
        pressures_usable: bool,
        motor_force_n: f32,
        dt: f32,
    ) -> f32 {
        let gas_n = if pressures_usable {
            c.cylinder.gas_force_n(st.pressure_a_pa, st.pressure_b_pa)
        } else {
            0.0
        };
        let unexplained =
            PistonForces::known(motor_force_n, gas_n, c.friction.force_n(st.velocity_mps))
                .unexplained_n(c.moving_mass_kg, st.acceleration_mps2);
        if unexplained.is_finite() {
            let alpha = clamp_f32(dt / DOB_TIME_S, 0.0, 1.0);
            self.n += alpha * (unexplained - self.n);
        }
        // Never more than the sections can push against.
        let limit = c.force_limit_n;
        self.n = clamp_f32(self.n, -limit, limit);
        self.n
    }
}

/// The running strokes' observer: its state and its estimate as cancelled, N (toward +x).
#[derive(Clone, Debug)]
#[repr(C)]
pub(super) struct LoadObserver {
    /// Its bandwidth times the momentum the known forces and the estimate account for, N
    /// (NaN: restarts next cycle).
    pub state: f32,
    /// The estimate as cancelled, N.
    pub n: f32,
    /// The configuration's products, taken at construction: the bandwidth K times the
    /// sample time T (1), K times the moving mass (kg/s), the slow follow's rate times T (1).
    gain: f32,
    k_mass_kg_s: f32,
    slow_gain: f32,
    /// `disturbance_threshold_n`, N.
    threshold_n: f32,
}

impl LoadObserver {
    pub(super) fn new(c: &ControlConfig) -> Self {
        let k = c.disturbance_bandwidth_rad_s;
        LoadObserver {
            state: f32::NAN,
            n: 0.0,
            gain: k * c.sample_time_s,
            k_mass_kg_s: k * c.moving_mass_kg,
            slow_gain: c.disturbance_slow_rad_s * c.sample_time_s,
            threshold_n: c.disturbance_threshold_n,
        }
    }

    /// The outputs are off: the observer restarts from the next cycle with outputs on.
    pub(super) fn reset(&mut self) {
        self.state = f32::NAN;
        self.n = 0.0;
    }

    /// The running strokes' disturbance observer: the force on the piston that the model
    /// does not explain — an external load, the model's mass or gas-force error — N, toward
    /// +x, within ±`limit`.
    ///
    /// A momentum observer. With the forces the step knows, the balance's net force
    /// `F = F_motor + F_gas − F_fr` ([`PistonForces::net_n`]: the motor's from the measured
    /// q-currents, the rest from `model`, [`model_forces`](super::actuate::model_forces)), and the
    /// momentum they account for, `p̂ ← p̂ + T·(F + d̂)`, the raw estimate is
    /// `d̂ = K·(m·v − p̂)`: it follows the true disturbance d as a first-order lag,
    /// `dd̂/dt = K·(d − d̂)`, whatever the loop commands (K =
    /// `disturbance_bandwidth_rad_s`, 4000 rad/s: τ = 0.25 ms). It uses the velocity
    /// estimate, not the differentiator's acceleration, which lags by half its window.
    ///
    /// What is cancelled is the raw estimate passed through a second, nonlinear lag: at the
    /// full K while the two differ by more than `disturbance_threshold_n` (300 N: a load
    /// step is followed at once, to within 300 N), at `disturbance_slow_rad_s` (250 rad/s)
    /// below it. The raw estimate also carries what the observer sees at the frequencies
    /// of its bandwidth — the velocity estimate's noise times `K·m`, and what looks like
    /// the motor's force ripple (on the reference plant, which has cogging and no
    /// calibrated map: ±100–170 N near 600 Hz at 2.3 m/s, six times the electrical
    /// frequency). Passed on at full bandwidth these would double the force reference's
    /// cycle-to-cycle change, and the voltages a hung control task leaves on the bridges
    /// until the watchdog resets would then drive a far larger current (the current loop's
    /// proportional gain acts on the reference's last step). Slowed below the threshold,
    /// the force reference moves as it does without the observer (`docs/firmware.md`, "The
    /// running observer").
    ///
    /// Ranges and saturation: the raw estimate is limited to ±`limit` (the force limit:
    /// never more than the sections can push against), and the state is set back to the
    /// limited value (`w = K·m·v − d̂`), so a saturated estimate does not wind up and
    /// follows the load down as soon as it drops; the cancelled estimate moves toward the
    /// raw one by at most half the gap per cycle, so it stays within the same bounds. The
    /// motor force integrated is the one measured, not the one commanded, so a force
    /// command held at its limit cannot wind it up either. A NaN input gives a raw estimate
    /// of 0 and the observer restarts from the next cycle; outputs off reset it the same
    /// way (`w` NaN, the estimate 0). State: `w = K·p̂` and the cancelled estimate, both N.
    #[inline(always)]
    pub(super) fn observe(&mut self, s: &Sensed, model: &PistonForces<f32>, limit: f32) -> f32 {
        let gain = self.gain;
        let momentum = self.k_mass_kg_s * s.derivatives.velocity_mps;
        let raw = momentum - self.state;
        // Limited to ±limit, NaN to 0 (clamp_f32 would give −limit).
        let d = clamp_or_zero_f32(raw, -limit, limit);
        let known_n = PistonForces {
            motor_n: s.force_master_n + s.force_slave_n,
            ..*model
        }
        .net_n();
        self.state = momentum - d + gain * (known_n + d);
        let gap = d - self.n;
        let follow = if gap.abs() > self.threshold_n {
            gain
        } else {
            self.slow_gain
        };
        self.n += follow * gap;
        self.n
    }
}

#[cfg(test)]
mod tests {
    use super::super::ControlStep;
    use super::*;
    use crate::sensing::differentiator::Derivatives;

    /// What the observer sees: the velocity estimate and the measured motor force.
    fn sensed(velocity_mps: f32, motor_n: f32) -> Sensed {
        Sensed {
            master: Default::default(),
            slave: Default::default(),
            derivatives: Derivatives {
                velocity_mps,
                acceleration_mps2: 0.0,
            },
            raw_m: 0.1,
            slave_raw_m: 0.1,
            position_m: 0.1,
            pressure_a_pa: 1e5,
            pressure_b_pa: 1e5,
            gas_force_n: 0.0,
            force_master_n: 0.5 * motor_n,
            force_slave_n: 0.5 * motor_n,
        }
    }

    /// `cycles` of a piston at constant speed whose motor pushes `motor_n` (the load is
    /// then `−motor_n`); the last estimate cancelled.
    fn hold(e: &mut LoadObserver, motor_n: f32, cycles: usize) -> f32 {
        let mut d = 0.0;
        for _ in 0..cycles {
            d = e.observe(&sensed(1.0, motor_n), &PistonForces::default(), 10_000.0);
        }
        d
    }

    #[test]
    fn the_observer_finds_a_steady_load_saturates_at_the_limit_and_recovers() {
        let c = ControlConfig::reference();
        let mut e = LoadObserver::new(&c);
        // A 3 kN load toward +x the motor holds: cancelled to within the 300 N threshold in
        // 2 ms (40 cycles), to 1 % in 20 ms.
        let d = hold(&mut e, -3000.0, 40);
        assert!((d - 3000.0).abs() <= 300.0, "{d}");
        let d = hold(&mut e, -3000.0, 360);
        assert!((d - 3000.0).abs() < 30.0, "{d}");
        // 20 kN: the estimate stops at the 10 kN force limit...
        let d = hold(&mut e, -20_000.0, 200);
        assert!(d <= 10_000.0 && d > 9_900.0, "{d}");
        // ...without winding up: the load gone, it follows down at once (within the 300 N
        // threshold in 2 ms) and settles on zero.
        let d = hold(&mut e, 0.0, 40);
        assert!(d.abs() <= 300.0, "{d}");
        let d = hold(&mut e, 0.0, 2000);
        assert!(d.abs() < 1.0, "{d}");
    }

    #[test]
    fn a_nan_input_gives_no_force_and_the_observer_restarts() {
        let c = ControlConfig::reference();
        let mut e = LoadObserver::new(&c);
        hold(&mut e, -3000.0, 40);
        let d = e.observe(
            &sensed(f32::NAN, -3000.0),
            &PistonForces::default(),
            10_000.0,
        );
        assert!(d.is_finite(), "{d}");
        let d = hold(&mut e, -3000.0, 400);
        assert!((d - 3000.0).abs() < 30.0, "{d}");
    }

    #[test]
    fn switched_off_it_estimates_nothing() {
        let mut config = ControlConfig::reference();
        config.disturbance_bandwidth_rad_s = 0.0;
        assert_eq!(hold(&mut LoadObserver::new(&config), -3000.0, 100), 0.0);
    }

    #[test]
    fn out_of_range_observer_gains_are_refused() {
        for k in [-1.0, f32::NAN, 20_000.0] {
            let mut config = ControlConfig::reference();
            config.disturbance_bandwidth_rad_s = k;
            assert!(ControlStep::new(config).is_err(), "{k}");
        }
    }
}
