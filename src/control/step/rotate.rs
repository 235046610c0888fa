//! The rotate stage: the servo that turns the piston in step with the stroke (the
//! synchroniser slaves it to the measured stroke, the volume ratio places the timed port
//! edge), and the park's turn to a phase where both chambers vent.

use crate::angle::{wrap_rad_cold, wrap_signed_rad, wrap_signed_rad_cold};
use crate::control::config::ControlConfig;
use crate::drive::servo::{RotarySetpoint, ServoController};
use crate::motion::stroke::{Direction, StrokeGenerator};
use crate::motion::synchroniser::{Rotation, Synchroniser};
use crate::motion::trajectory::Setpoint;
use crate::motion::volume_ratio::{Chamber, VolumeRatio};
use crate::physics::gas::GasProperties;
use crate::physics::port_timing::PortGeometry;
use crate::real::clamp_f32;
use crate::units::DacCode;

/// How fast the rotation turns to the venting phase before a park, rad/s (half a turn, the
/// farthest, in 0.5 s).
pub const VENT_SPEED_RAD_S: f32 = core::f32::consts::TAU;

/// How long the park holds the piston while the rotation turns to the venting phase, s:
/// half a turn at [`VENT_SPEED_RAD_S`] and 0.25 s for the servo to settle there. The park
/// move's clock starts this far below zero (its path is at rest there).
pub const VENT_TIME_S: f32 = 0.75;

/// How long a start holds the piston while the rotation turns to the first stroke's
/// starting phase, s: half a turn, the farthest, at [`VENT_SPEED_RAD_S`] and 0.25 s for the
/// servo to settle there.
pub const START_TURN_TIME_S: f32 = VENT_TIME_S;

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
    /// The same as an angle, `turns·2π`, rad (kept with it: the status reads it every cycle).
    pub turns_rad: f32,
    /// The rotation reference, rad (within the current turn base).
    pub reference_rad: f32,
    /// Speed of the rotation reference, rad/s.
    pub reference_speed_rad_s: f32,
    /// The discharge pressure the current half cycle's opening was planned for, Pa.
    pub planned_discharge_pa: f32,
}

impl RotaryAxis {
    pub(super) fn new(config: &ControlConfig) -> Self {
        RotaryAxis {
            servo: ServoController::new(config.servo),
            synchroniser: Synchroniser::new(config.port_geometry, 0.0),
            volume_ratio: VolumeRatio::new(config.volume_ratio),
            direction: Rotation::Compressor,
            turns: 0,
            turns_rad: 0.0,
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
        // Keep the rotation angles within a few turns of zero (f32 resolution): re-based from
        // two whole turns on. The division is taken only past 12 rad (just under two turns,
        // 4π = 12.57 rad), so the decision is the one the quotient alone would make.
        if self.reference_rad.abs() >= 12.0 {
            let turns = (self.reference_rad / core::f32::consts::TAU) as i32;
            if turns.abs() >= 2 {
                self.servo.rebase(turns);
                self.synchroniser.rebase(turns);
                self.reference_rad -= turns as f32 * core::f32::consts::TAU;
                self.turns = self.turns.saturating_add(turns);
                self.turns_rad = self.turns as f32 * core::f32::consts::TAU;
            }
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
            Direction::TowardA => core::f32::consts::PI,
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

/// The park's turn of the rotation to a phase where both chambers vent.
impl RotaryAxis {
    /// The nearest phase where both chambers breathe
    /// ([`crate::physics::port_timing::PortGeometry::venting_phases_rad`]), as a turn of the
    /// rotation from the current reference, rad in [−π, π); `None` for a geometry without one.
    fn vent_turn_rad(&self, geometry: &PortGeometry<f32>) -> Option<f32> {
        let phase = wrap_rad_cold(self.reference_rad);
        geometry
            .venting_phases_rad()
            .iter()
            .flatten()
            // The shorter way round.
            .map(|v| wrap_signed_rad_cold(*v - phase))
            .fold(None, |best: Option<f32>, d| match best {
                Some(b) if b.abs() <= d.abs() => Some(b),
                _ => Some(d),
            })
    }

    /// Where the park move's clock starts: [`VENT_TIME_S`] below zero, the rotation turning
    /// to a venting phase meanwhile, so the move cannot compress a sealed chamber beyond the
    /// pressure sensors' range; 0 for a geometry with no such phase.
    #[cold]
    #[inline(never)]
    pub(super) fn vent_delay_s(&self, geometry: &PortGeometry<f32>) -> f32 {
        match self.vent_turn_rad(geometry) {
            Some(_) => -VENT_TIME_S,
            None => 0.0,
        }
    }

    /// One cycle of the park's turn: the rotation reference moves toward the nearest venting
    /// phase at [`VENT_SPEED_RAD_S`] (the target is found again each cycle: the nearest stays
    /// the nearest as the reference approaches it).
    #[cold]
    #[inline(never)]
    pub(super) fn turn_to_vent(&mut self, geometry: &PortGeometry<f32>, dt: f32) {
        if let Some(d) = self.vent_turn_rad(geometry) {
            let step = VENT_SPEED_RAD_S * dt;
            self.reference_rad += clamp_f32(d, -step, step);
        }
    }
}
