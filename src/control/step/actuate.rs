//! The actuate and rotate stages: the position loop with model feed-forward, the force
//! split over the two sections, both sections' current loops in the same cycle, and the
//! servo that turns the piston in step with the stroke.

use super::modes::Mode;
use super::safe_state::{VENT_SPEED_RAD_S, VENT_TIME_S};
use super::sense::Sensed;
use super::{ControlStep, CycleInputs};
use crate::angle::wrap_signed_rad;
use crate::control::config::ControlConfig;
use crate::drive::allocation::allocate;
use crate::drive::servo::{RotarySetpoint, ServoController};
use crate::motion::stroke::{Direction, StrokeGenerator};
use crate::motion::synchroniser::{Rotation, Synchroniser};
use crate::motion::trajectory::Setpoint;
use crate::motion::volume_ratio::{Chamber, VolumeRatio};
use crate::physics::balance::PistonForces;
use crate::physics::gas::GasProperties;
use crate::physics::motor::Dq;
use crate::real::clamp_f32;
use crate::sensing::differentiator::Derivatives;
use crate::units::{DacCode, PerSection, PhaseDuties, Section};
use core::f32::consts::PI;

/// The rotation's state: the servo, the synchroniser that slaves it to the stroke, the
/// volume ratio that places the port edge, and the reference it tracks.
#[derive(Clone, Debug)]
pub(super) struct RotaryAxis {
    pub servo: ServoController,
    pub synchroniser: Synchroniser,
    pub volume_ratio: VolumeRatio,
    /// Compressor or expander for the next half cycle.
    pub direction: Rotation,
    /// Whole turns the rotation base has moved (status angles are unwrapped with it).
    pub turns: i32,
    /// The rotation reference, rad (within the current turn base).
    pub reference_rad: f32,
    /// Speed of the rotation reference, rad/s.
    pub reference_speed_rad_s: f32,
    /// The discharge pressure the current half cycle's opening was planned for, Pa.
    pub planned_discharge_pa: f32,
}

/// How long a start holds the piston while the rotation turns to the first stroke's
/// starting phase, s: half a turn, the farthest, at [`VENT_SPEED_RAD_S`] and 0.25 s for the
/// servo to settle there.
pub(super) const START_TURN_TIME_S: f32 = VENT_TIME_S;

impl RotaryAxis {
    pub(super) fn new(config: &ControlConfig) -> Self {
        RotaryAxis {
            servo: ServoController::new(config.servo),
            synchroniser: Synchroniser::new(config.port_geometry, 0.0),
            volume_ratio: VolumeRatio::new(config.volume_ratio),
            direction: Rotation::Compressor,
            turns: 0,
            reference_rad: 0.0,
            reference_speed_rad_s: 0.0,
            planned_discharge_pa: f32::NAN,
        }
    }

    /// The rotate stage: the servo follows the rotation reference (while running, the
    /// synchroniser's, locked to `stroke`, the running stroke's setpoint; `None` in every
    /// other mode), the timed port edge is watched, and the angles are kept within a few
    /// turns of zero. `position_m`: the master position, m; `outputs_on`: the servo may
    /// move (otherwise its reference follows the measured angle); `gas` and `last_pa` (the
    /// last valid pressures, chamber A, B, suction, discharge, Pa) judge a discharge opening.
    pub(super) fn rotate(
        &mut self,
        position_m: f32,
        stroke: Option<&Setpoint>,
        outputs_on: bool,
        gas: &GasProperties<f32>,
        last_pa: &[f32; 4],
    ) -> DacCode {
        let servo = if outputs_on {
            let rotary = match stroke {
                Some(sp) => {
                    self.synchroniser
                        .setpoint(position_m, sp.velocity_mps, sp.acceleration_mps2)
                }
                None => RotarySetpoint {
                    angle_rad: self.reference_rad,
                    ..RotarySetpoint::default()
                },
            };
            self.reference_rad = rotary.angle_rad;
            self.reference_speed_rad_s = rotary.velocity_rad_s;
            if let Some(edge) = self.synchroniser.crossed(self.servo.angle_rad()) {
                self.edge_crossed(edge.chamber, edge.rotation, gas, last_pa);
            }
            self.servo.control(&rotary)
        } else {
            self.reference_rad = self.servo.angle_rad();
            self.servo.command(0.0)
        };
        // Keep the rotation angles within a few turns of zero (f32 resolution).
        let turns = (self.reference_rad / core::f32::consts::TAU) as i32;
        if turns.abs() >= 2 {
            self.servo.rebase(turns);
            self.synchroniser.rebase(turns);
            self.reference_rad -= turns as f32 * core::f32::consts::TAU;
            self.turns = self.turns.saturating_add(turns);
        }
        servo
    }

    /// The turn from the rotation reference to the phase a stroke in `direction` starts at
    /// from rest (0 at dead point A, π at dead point B), the shorter way, rad in [−π, π).
    #[cold]
    #[inline(never)]
    pub(super) fn start_turn_rad(&self, direction: Direction) -> f32 {
        let start_phase = match direction {
            Direction::TowardB => 0.0,
            Direction::TowardA => PI,
        };
        wrap_signed_rad(start_phase - self.reference_rad)
    }

    /// One cycle of the turn before the first stroke of `g` (while it waits): the rotation
    /// reference moves toward that stroke's starting phase at [`VENT_SPEED_RAD_S`]. True
    /// once the wait is over (the stroke's half cycle is to begin).
    #[cold]
    #[inline(never)]
    pub(super) fn turn_to_start(&mut self, g: &StrokeGenerator, dt: f32) -> bool {
        if !g.waiting() {
            return true;
        }
        let step = VENT_SPEED_RAD_S * dt;
        self.reference_rad += clamp_f32(self.start_turn_rad(g.direction()), -step, step);
        false
    }

    /// Whether the rotation turns at less than a quarter of its reference's speed.
    #[cold]
    #[inline(never)]
    pub(super) fn stalled(&self) -> bool {
        self.servo.velocity_rad_s().abs() < 0.25 * self.reference_speed_rad_s.abs()
    }

    /// The measured rotation crossed the timed edge: in compressor mode the discharge of
    /// `chamber` just opened, and its pressure (from `last_pa`) now says whether it opened
    /// on time.
    #[cold]
    #[inline(never)]
    fn edge_crossed(
        &mut self,
        chamber: Chamber,
        rotation: Rotation,
        gas: &GasProperties<f32>,
        last_pa: &[f32; 4],
    ) {
        if rotation != Rotation::Compressor {
            return;
        }
        let p = match chamber {
            Chamber::A => last_pa[0],
            Chamber::B => last_pa[1],
        };
        self.volume_ratio
            .observe_opening(gas, chamber, p, self.planned_discharge_pa);
    }
}

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
                let load_n = self.estimator.observe_load(&self.config, s, &model, limit);
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
                self.supervision.limits.force = force.abs() >= limit;
                self.status.force_command_n = force;
                let duties = self.drive_sections(inputs, s, force);
                self.supervision.limits.voltage = self.currents.master.state().voltage_limited
                    || self.currents.slave.state().voltage_limited;
                Some(duties)
            }
            // A calibration drives the outputs itself, at the end of the step.
            None if matches!(self.mode, Mode::Calibrating(_)) => None,
            None => self.outputs_off(inputs),
        }
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
