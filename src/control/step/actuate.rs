//! The actuate and rotate stages: the position loop with model feed-forward, the force
//! split over the two sections, both sections' current loops in the same cycle, and the
//! servo that turns the piston in step with the stroke.

use super::modes::Mode;
use super::sense::Sensed;
use super::{ControlStep, CycleInputs};
use crate::drive::allocation::allocate;
use crate::drive::servo::RotarySetpoint;
use crate::motion::trajectory::Setpoint;
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
                let force =
                    self.position_loop(&sp, s.position_m, &s.derivatives, s.gas_force_n, limit);
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

    /// Position loop with model feed-forward: total motor force, N, saturated at `limit`.
    /// Always inlined: the calibration calls it too, and a second call site must not take
    /// it out of the step.
    #[inline(always)]
    pub(super) fn position_loop(
        &self,
        sp: &Setpoint,
        position_m: f32,
        d: &Derivatives,
        gas_force_n: f32,
        limit: f32,
    ) -> f32 {
        let c = &self.config;
        let feed_forward = if c.feed_forward {
            c.moving_mass_kg * sp.acceleration_mps2 + c.friction.force_n(sp.velocity_mps)
                - gas_force_n
        } else {
            0.0
        };
        let feedback = c.position_kp_n_per_m * (sp.position_m - position_m)
            + c.position_kd_ns_per_m * (sp.velocity_mps - d.velocity_mps);
        let f = feed_forward + feedback;
        if f.is_nan() {
            0.0
        } else {
            clamp_f32(f, -limit, limit)
        }
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
