//! The actuate and rotate stages: the position loop with model feed-forward, the force
//! split over the two sections, both sections' current loops in the same cycle, and the
//! servo that turns the piston in step with the stroke.

use super::modes::Mode;
use super::sense::Sensed;
use super::{ControlStep, CycleInputs};
use crate::drive::allocation::allocate;
use crate::drive::servo::RotarySetpoint;
use crate::motion::trajectory::Setpoint;
use crate::physics::balance::PistonForces;
use crate::physics::motor::Dq;
use crate::real::clamp_f32;
use crate::sensing::differentiator::Derivatives;
use crate::units::{DacCode, PerSection, PhaseDuties, Section};

impl ControlStep {
    /// The actuate stage: the position loop's force, split over both sections, and both
    /// current loops run in this cycle; with the outputs off the loops are reset and the
    /// phase currents watched for an offset.
    pub(super) fn actuate(
        &mut self,
        inputs: &CycleInputs,
        s: &Sensed,
        setpoint: Option<(Setpoint, f32)>,
    ) -> Option<PerSection<PhaseDuties>> {
        match setpoint {
            Some((sp, limit)) => {
                let model = self.model_forces(&sp, s.gas_force_n);
                let load_n = self.observe_load(s, &model, limit);
                // Cancelled while running strokes only: homing pushes on its end stop on
                // purpose, a controlled stop has its own observer, and holding and moves
                // keep the behaviour they were tuned with.
                let cancel_n = if matches!(self.mode, Mode::Running(_)) {
                    load_n
                } else {
                    0.0
                };
                let force =
                    self.position_loop(&sp, s.position_m, &s.derivatives, &model, cancel_n, limit);
                self.limits.force = force.abs() >= limit;
                self.status.force_command_n = force;
                let duties = self.drive_sections(inputs, s, force);
                self.limits.voltage = self.currents.master.state().voltage_limited
                    || self.currents.slave.state().voltage_limited;
                Some(duties)
            }
            // A calibration drives the outputs itself, at the end of the step.
            None if matches!(self.mode, Mode::Calibrating(_)) => None,
            None => self.outputs_off(inputs),
        }
    }

    /// The rotate stage: the servo follows the rotation reference (while running, the
    /// synchroniser's, locked to the stroke), the timed port edge is watched, and the angles
    /// are kept within a few turns of zero.
    pub(super) fn rotate(
        &mut self,
        s: &Sensed,
        setpoint: Option<(Setpoint, f32)>,
        outputs_on: bool,
    ) -> DacCode {
        let servo = if outputs_on {
            let rotary = match (&self.mode, setpoint) {
                (Mode::Running(_), Some((sp, _))) => {
                    self.synchroniser
                        .setpoint(s.position_m, sp.velocity_mps, sp.acceleration_mps2)
                }
                _ => RotarySetpoint {
                    angle_rad: self.theta_reference_rad,
                    ..RotarySetpoint::default()
                },
            };
            self.theta_reference_rad = rotary.angle_rad;
            self.theta_reference_speed_rad_s = rotary.velocity_rad_s;
            if let Some(edge) = self.synchroniser.crossed(self.servo.angle_rad()) {
                self.edge_crossed(edge.chamber, edge.rotation);
            }
            self.servo.control(&rotary)
        } else {
            self.theta_reference_rad = self.servo.angle_rad();
            self.servo.command(0.0)
        };
        // Keep the rotation angles within a few turns of zero (f32 resolution).
        let turns = (self.theta_reference_rad / core::f32::consts::TAU) as i32;
        if turns.abs() >= 2 {
            self.servo.rebase(turns);
            self.synchroniser.rebase(turns);
            self.theta_reference_rad -= turns as f32 * core::f32::consts::TAU;
            self.turns = self.turns.saturating_add(turns);
        }
        servo
    }

    /// The forces the model knows besides the motors' and inertia: friction at the
    /// reference velocity and the measured gas force (their load,
    /// [`PistonForces::load_n`], is what the motor must supply beyond `m·a`).
    #[inline(always)]
    pub(super) fn model_forces(&self, sp: &Setpoint, gas_force_n: f32) -> PistonForces<f32> {
        PistonForces::known(
            0.0,
            gas_force_n,
            self.config.friction.force_n(sp.velocity_mps),
        )
    }

    /// Position loop with model feed-forward (the motor force the force balance needs for the
    /// setpoint's acceleration against `model`, the forces of [`ControlStep::model_forces`])
    /// and `cancel_n`, an estimated external force (toward +x) to push against: total motor
    /// force, N, saturated at `limit`. Always inlined: the calibration calls it too, and a
    /// second call site must not take it out of the step.
    #[inline(always)]
    pub(super) fn position_loop(
        &self,
        sp: &Setpoint,
        position_m: f32,
        d: &Derivatives,
        model: &PistonForces<f32>,
        cancel_n: f32,
        limit: f32,
    ) -> f32 {
        let c = &self.config;
        let feed_forward = if c.feed_forward {
            model.motor_needed_n(c.moving_mass_kg, sp.acceleration_mps2)
        } else {
            0.0
        };
        let feedback = c.position_kp_n_per_m * (sp.position_m - position_m)
            + c.position_kd_ns_per_m * (sp.velocity_mps - d.velocity_mps);
        let f = feed_forward + feedback - cancel_n;
        if f.is_nan() {
            0.0
        } else {
            clamp_f32(f, -limit, limit)
        }
    }

    /// The running strokes' disturbance observer (issue #15): the force on the piston that
    /// the model does not explain — an external load, the model's mass or gas-force error —
    /// N, toward +x, within ±`limit`.
    ///
    /// A momentum observer. With the forces the step knows, the balance's net force
    /// `F = F_motor + F_gas − F_fr` ([`PistonForces::net_n`]: the motor's from the measured
    /// q-currents, the rest from `model`, [`ControlStep::model_forces`]), and the
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
    /// frequency) — and
    /// passed on at full bandwidth these doubled the force reference's cycle-to-cycle
    /// change: the voltages a hung control task leaves on the bridges for the watchdog's
    /// 3 ms then drive a far larger current (the current loop's proportional gain acts on
    /// the reference's last step), and of 120 hangs around a dead point the worst came
    /// within 0.12 mm of the head (two lags at 3000 rad/s; 0.85 mm without the observer).
    /// Slowed below the threshold, the force reference moves as it did without the
    /// observer (worst of the same 120 hangs 0.78 mm).
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
    fn observe_load(&mut self, s: &Sensed, model: &PistonForces<f32>, limit: f32) -> f32 {
        let c = &self.config;
        let k = c.disturbance_bandwidth_rad_s;
        let gain = k * c.sample_time_s;
        let momentum = k * c.moving_mass_kg * s.derivatives.velocity_mps;
        let raw = momentum - self.load_observer;
        // Limited to ±limit, NaN to 0 (clamp_f32 would give −limit).
        let d = if raw > -limit {
            if raw < limit {
                raw
            } else {
                limit
            }
        } else if raw <= -limit {
            -limit
        } else {
            0.0
        };
        let known_n = PistonForces {
            motor_n: s.force_master_n + s.force_slave_n,
            ..*model
        }
        .net_n();
        self.load_observer = momentum - d + gain * (known_n + d);
        let gap = d - self.load_n;
        let follow = if gap.abs() > c.disturbance_threshold_n {
            gain
        } else {
            c.disturbance_slow_rad_s * c.sample_time_s
        };
        self.load_n += follow * gap;
        self.load_n
    }

    /// Splits the force over both sections and runs both current loops in this cycle.
    pub(super) fn drive_sections(
        &mut self,
        inputs: &CycleInputs,
        s: &Sensed,
        force_n: f32,
    ) -> PerSection<PhaseDuties> {
        let shares = allocate(&self.config.allocation, force_n, s.position_m);
        self.shares = shares;
        let inv_kf = 1.0 / self.config.motor.force_constant_n_per_a;
        let mut out = PerSection::<PhaseDuties>::default();
        for (section, angle) in [
            (Section::Master, s.master.angle),
            (Section::Slave, s.slave.angle),
        ] {
            let reference = Dq {
                d: 0.0,
                q: *shares.get(section) * inv_kf,
            };
            let amps = self
                .config
                .current_sense
                .get(section)
                .amps(inputs.currents.get(section));
            let angle = angle.wrapping_add(*self.config.angle_offset.get(section));
            *out.get_mut(section) = self.currents.get_mut(section).step(
                amps,
                angle,
                reference,
                s.derivatives.velocity_mps,
            );
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::config::ControlConfig;

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
    fn hold(c: &mut ControlStep, motor_n: f32, cycles: usize) -> f32 {
        let mut d = 0.0;
        for _ in 0..cycles {
            d = c.observe_load(&sensed(1.0, motor_n), &PistonForces::default(), 10_000.0);
        }
        d
    }

    #[test]
    fn the_observer_finds_a_steady_load_saturates_at_the_limit_and_recovers() {
        let mut c = ControlStep::new(ControlConfig::reference()).unwrap();
        // A 3 kN load toward +x the motor holds: cancelled to within the 300 N threshold in
        // 2 ms (40 cycles), to 1 % in 20 ms.
        let d = hold(&mut c, -3000.0, 40);
        assert!((d - 3000.0).abs() <= 300.0, "{d}");
        let d = hold(&mut c, -3000.0, 360);
        assert!((d - 3000.0).abs() < 30.0, "{d}");
        // 20 kN: the estimate stops at the 10 kN force limit...
        let d = hold(&mut c, -20_000.0, 200);
        assert!(d <= 10_000.0 && d > 9_900.0, "{d}");
        // ...without winding up: the load gone, it follows down at once (within the 300 N
        // threshold in 2 ms) and settles on zero.
        let d = hold(&mut c, 0.0, 40);
        assert!(d.abs() <= 300.0, "{d}");
        let d = hold(&mut c, 0.0, 2000);
        assert!(d.abs() < 1.0, "{d}");
    }

    #[test]
    fn a_nan_input_gives_no_force_and_the_observer_restarts() {
        let mut c = ControlStep::new(ControlConfig::reference()).unwrap();
        hold(&mut c, -3000.0, 40);
        let d = c.observe_load(
            &sensed(f32::NAN, -3000.0),
            &PistonForces::default(),
            10_000.0,
        );
        assert!(d.is_finite(), "{d}");
        let d = hold(&mut c, -3000.0, 400);
        assert!((d - 3000.0).abs() < 30.0, "{d}");
    }

    #[test]
    fn switched_off_it_estimates_nothing() {
        let mut config = ControlConfig::reference();
        config.disturbance_bandwidth_rad_s = 0.0;
        let mut c = ControlStep::new(config).unwrap();
        assert_eq!(hold(&mut c, -3000.0, 100), 0.0);
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
