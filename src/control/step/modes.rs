//! The mode machine: idle, homing, holding, moving, running strokes, controlled stops,
//! faulted, calibrating — and the setpoint each mode plans per cycle. What a fault's
//! reaction does beyond starting a controlled stop is in `safe_state.rs`.

use super::safe_state::{FaultedBrake, RestTurn};
use super::sense::Sensed;
use super::ControlStep;
use crate::control::calibration::Calibration;
use crate::motion::stroke::StrokeGenerator;
use crate::motion::synchroniser::{Rotation, Synchroniser};
use crate::motion::trajectory::{PointToPoint, Setpoint};
use crate::real::{clamp_f32, max_f32};
use crate::safety::faults::Fault;
use crate::safety::supervisor::LimitFlags;
use crate::sensing::homing::{Homing, HomingStep};
use crate::status::ModeKind;

/// The window over which holding the stopped piston must need (almost) no force before SS1
/// switches the outputs off, s: 50 ms, ten times the force's settling after the stop ramp.
pub const HOLD_RELEASE_S: f32 = 0.05;

/// What follows a controlled stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum AfterStop {
    /// Hold where the piston stopped (operator stop).
    Hold,
    /// Outputs off: the second half of SS1 after a fault.
    Off,
    /// Turn to a phase where both chambers breathe, then move slowly to the park position
    /// and hold there (host lost).
    Park,
}

/// `angle_rad` brought into [0, 2π): the one wrap, [`crate::angle::wrap_rad`] (out of line:
/// the stop and vent paths that call it are cold, and a dozen inlined copies cost flash).
#[inline(never)]
pub(super) fn turn_phase(angle_rad: f32) -> f32 {
    crate::angle::wrap_rad(angle_rad)
}

/// What the position loop is doing.
#[derive(Clone, Debug)]
pub(super) enum Mode {
    Idle,
    Homing(Homing),
    Holding(Setpoint),
    Moving { path: PointToPoint, elapsed_s: f32 },
    Running(StrokeGenerator),
    Stopping { setpoint: Setpoint, then: AfterStop },
    Faulted,
    Calibrating(Calibration),
}

impl ControlStep {
    /// The plan stage: the mode machine advanced one cycle; the setpoint and the force
    /// limit, or `None` with the outputs off.
    pub(super) fn plan(&mut self, s: &Sensed) -> Option<(Setpoint, f32)> {
        self.supervision.limits = LimitFlags::default();
        let measured_force_n = s.force_master_n + s.force_slave_n;
        let dt = self.config.sample_time_s;
        let setpoint = self.next_setpoint(s, measured_force_n, dt);
        self.setpoint = setpoint.map(|(sp, _)| sp);
        setpoint
    }

    /// Whether strokes are running (the pressure plausibility check watches only then).
    #[inline(always)]
    pub(super) fn running(&self) -> bool {
        matches!(self.mode, Mode::Running(_))
    }

    pub(super) fn mode_kind(&self) -> ModeKind {
        match self.mode {
            Mode::Idle => ModeKind::Idle,
            Mode::Homing(_) => ModeKind::Homing,
            Mode::Holding(_) => ModeKind::Holding,
            Mode::Moving { .. } => ModeKind::Moving,
            Mode::Running(_) => ModeKind::Running,
            Mode::Stopping { .. } => ModeKind::Stopping,
            Mode::Faulted => ModeKind::Faulted,
            Mode::Calibrating(_) => ModeKind::Calibrating,
        }
    }

    /// Advances the mode with this cycle's sensing `s`; returns the setpoint (position frame
    /// after homing) and the force limit, or `None` when the outputs must be off.
    pub(super) fn next_setpoint(
        &mut self,
        s: &Sensed,
        measured_force_n: f32,
        dt: f32,
    ) -> Option<(Setpoint, f32)> {
        let (raw_m, slave_raw_m) = (s.raw_m, s.slave_raw_m);
        let limit = self.config.force_limit_n;
        match &mut self.mode {
            // The faulted state may still brake (`safe_state.rs`); the outputs are its own.
            Mode::Faulted => {
                self.faulted_cycle();
                None
            }
            // Calibration drives the outputs itself (`calibration_cycle`).
            Mode::Idle | Mode::Calibrating(_) => None,
            Mode::Homing(h) => match h.step(raw_m, measured_force_n, dt) {
                HomingStep::Creep {
                    reference_m,
                    force_limit_n,
                    // No zero yet: the position frame is the raw frame.
                } => Some((Setpoint::at_rest(reference_m), force_limit_n)),
                HomingStep::Found { stop_raw_m } => {
                    self.sensing.zero_raw_m = Some(stop_raw_m);
                    self.sensing.zero_slave_raw_m = slave_raw_m - (raw_m - stop_raw_m);
                    self.sensing.differentiator.reset();
                    let here = raw_m - stop_raw_m;
                    let path = PointToPoint::new(here, self.config.park_position_m, 0.05);
                    self.mode = Mode::Moving {
                        path,
                        elapsed_s: 0.0,
                    };
                    Some((Setpoint::at_rest(here), limit))
                }
                HomingStep::Failed => {
                    self.latch(Fault::HomingFailed);
                    None
                }
            },
            Mode::Holding(sp) => Some((*sp, limit)),
            Mode::Moving { path, elapsed_s } => {
                *elapsed_s += dt;
                let sp = path.sample(*elapsed_s);
                // A park first turns to a venting phase, the piston at rest.
                let venting = *elapsed_s < 0.0;
                if *elapsed_s >= path.duration_s() {
                    self.mode = Mode::Holding(Setpoint::at_rest(path.target_m()));
                }
                if venting {
                    self.rotary.turn_to_vent(&self.config.port_geometry, dt);
                }
                Some((sp, limit))
            }
            Mode::Running(g) => {
                let waited = g.waiting();
                let (sp, dead) = g.step(dt, self.status.position_m);
                let stopped = g.stopped();
                // The turn before the first stroke (`Command::Start`); that stroke's half
                // cycle begins as the turn ends.
                let started = waited && self.rotary.turn_to_start(g, dt);
                if let Some(d) = dead {
                    self.last_dead_point = Some(d);
                }
                if started || dead.is_some() {
                    let generator = g.clone();
                    self.begin_half(&generator);
                }
                if stopped {
                    self.mode = Mode::Holding(Setpoint::at_rest(sp.position_m));
                }
                Some((sp, limit))
            }
            Mode::Stopping { setpoint, then } => {
                let brake = self.safe.stop_decel_mps2;
                let v = setpoint.velocity_mps;
                let dv = brake * dt;
                let (v_next, a) = if v.abs() <= dv {
                    (0.0, -v / dt)
                } else if v > 0.0 {
                    (v - dv, -brake)
                } else {
                    (v + dv, brake)
                };
                setpoint.position_m += 0.5 * (v + v_next) * dt;
                setpoint.velocity_mps = v_next;
                setpoint.acceleration_mps2 = a;
                let planned = *setpoint;
                let then = *then;
                // With the stop's observer; after a watchdog reset braking on the measured
                // velocity instead of the plan (`safe_state.rs`).
                let sp = self.stop_setpoint(planned, s, measured_force_n, dt);
                if v_next == 0.0 {
                    if then == AfterStop::Off && !(self.turn_to_rest(dt) && self.hold_released(dt))
                    {
                        return Some((sp, limit));
                    }
                    self.mode = match then {
                        AfterStop::Off => Mode::Faulted,
                        AfterStop::Hold => Mode::Holding(Setpoint::at_rest(sp.position_m)),
                        AfterStop::Park => Mode::Moving {
                            path: PointToPoint::new(
                                sp.position_m,
                                self.config.park_position_m,
                                self.config.park_speed_mps,
                            ),
                            elapsed_s: self.rotary.vent_delay_s(&self.config.port_geometry),
                        },
                    };
                    if then == AfterStop::Off {
                        return None;
                    }
                }
                Some((sp, limit))
            }
        }
    }

    /// Starts a controlled stop on the braking deceleration from the measured position and
    /// velocity (not the reference: after a fault the piston may be far from it). Without
    /// outputs on there is nothing to stop: the mode goes straight to its end.
    pub(super) fn begin_stop(&mut self, then: AfterStop) {
        if matches!(self.mode, Mode::Idle | Mode::Homing(_) | Mode::Faulted) {
            self.mode = match then {
                AfterStop::Off => Mode::Faulted,
                AfterStop::Hold | AfterStop::Park => Mode::Idle,
            };
            return;
        }
        self.safe.hold_quiet_s = 0.0;
        self.safe.hold_motor_ns = 0.0;
        self.safe.hold_gas_ns = 0.0;
        self.safe.rest = RestTurn::Unplanned;
        let setpoint = match &self.mode {
            // Already stopping: keep the ramp, take the stronger reaction.
            Mode::Stopping { setpoint, then: t } => {
                let then = if *t == AfterStop::Off { *t } else { then };
                self.mode = Mode::Stopping {
                    setpoint: *setpoint,
                    then,
                };
                return;
            }
            _ => Setpoint {
                position_m: self.status.position_m,
                velocity_mps: self.status.velocity_mps,
                acceleration_mps2: 0.0,
            },
        };
        self.safe.stop_decel_mps2 =
            self.stop_deceleration(setpoint.position_m, setpoint.velocity_mps);
        if matches!(self.safe.brake, FaultedBrake::Zeroing(_)) {
            self.safe.brake = FaultedBrake::None;
        }
        self.estimator.stop_n = 0.0;
        self.mode = Mode::Stopping { setpoint, then };
    }

    /// SS1's end: the piston is at rest and held; the outputs go off only once, averaged
    /// over [`HOLD_RELEASE_S`] (the damping term's velocity noise averages out), holding it
    /// needs no more than the static friction and the measured gas force is below half of
    /// it, so friction alone keeps it still. Released earlier, the gas of a compressed
    /// chamber (or an external load) would throw the piston into a head with nothing to stop
    /// it. Until then it stays held, and a new window starts.
    #[cold]
    #[inline(never)]
    pub(super) fn hold_released(&mut self, dt: f32) -> bool {
        let gas_n = if self.sensing.pressures.usable() {
            self.config
                .cylinder
                .gas_force_n(self.status.pressure_a_pa, self.status.pressure_b_pa)
        } else {
            0.0
        };
        self.safe.hold_quiet_s += dt;
        self.safe.hold_motor_ns += self.status.force_command_n * dt;
        self.safe.hold_gas_ns += gas_n * dt;
        if self.safe.hold_quiet_s < HOLD_RELEASE_S {
            return false;
        }
        let window = self.safe.hold_quiet_s;
        let (motor, gas) = (
            self.safe.hold_motor_ns / window,
            self.safe.hold_gas_ns / window,
        );
        self.safe.hold_quiet_s = 0.0;
        self.safe.hold_motor_ns = 0.0;
        self.safe.hold_gas_ns = 0.0;
        let stiction = self.config.friction.static_n;
        motor.abs() <= stiction && gas.abs() <= 0.5 * stiction
    }

    /// The deceleration of a controlled stop from `velocity_mps` at `position_m`: the
    /// braking envelope's `a_brake`, or more when the piston is closer to the head it moves
    /// toward than that needs (a disturbance pushed it past the envelope, which is what
    /// tripped): enough to stop 1 mm short of the minimum clearance with 25 % in hand, up to
    /// the most the sections in service guarantee. Without the zero (after a watchdog reset)
    /// the heads' distance is unknown: that most.
    ///
    /// The most: `a_brake` per healthy section (what one section alone guarantees), or, when
    /// larger, the healthy sections' peak force less the largest push the gas can give
    /// toward the head — one chamber on the discharge line, the other at suction, by the
    /// last line pressures — over the moving mass (PR 5.1: 10 kN − 2.5 kN, 625 m/s²; one
    /// section 210 m/s²). As a compressor the chamber ahead is a gas spring that helps; as
    /// an expander it exhausts near the dead point and the sections brake the piston alone,
    /// on the envelope's edge: a section lost there, or a control task hung there for the
    /// watchdog's 5 ms, leaves the piston past what `a_brake` stops.
    pub(super) fn stop_deceleration(&self, position_m: f32, velocity_mps: f32) -> f32 {
        let c = &self.config.supervisor;
        let cap = self.config.allocation.capability;
        let sections = clamp_f32(cap.master, 0.0, 1.0) + clamp_f32(cap.slave, 0.0, 1.0);
        let mut a_max = c.brake_deceleration_mps2 * max_f32(sections, 1.0);
        let [_, _, suction, discharge] = self.sensing.pressures.last_pa;
        // (Arguments in this order: a NaN pressure gives a NaN push.)
        let gas_n = max_f32(0.0, discharge - suction) * self.config.cylinder.area_m2;
        let a_force = (self.config.allocation.section_limit_n * sections - gas_n)
            / self.config.moving_mass_kg;
        // (NaN — no line pressure yet — keeps `a_brake` per section.)
        if a_force > a_max {
            a_max = a_force;
        }
        if self.sensing.zero_raw_m.is_none() {
            return a_max;
        }
        let distance = if velocity_mps >= 0.0 {
            c.travel_m - position_m
        } else {
            position_m
        };
        let room = distance - c.min_clearance_m - 1e-3;
        let needed = if room > 1e-4 {
            1.25 * velocity_mps * velocity_mps / (2.0 * room)
        } else {
            a_max
        };
        clamp_f32(needed, c.brake_deceleration_mps2, a_max)
    }

    /// Starts the rotation of a new half cycle: where the timed port edge must be crossed
    /// (discharge opening, or expander cut-off) from the measured line pressures.
    pub(super) fn begin_half(&mut self, g: &StrokeGenerator) {
        let (from, to) = g.path_ends_m();
        let rotation = self.rotary.direction;
        let chamber = Synchroniser::timed_chamber(g.direction(), rotation);
        // The chamber's largest volume is where its compression starts (compressor: the
        // stroke's start) or its expansion ends (expander: the stroke's end).
        let reference_x = match rotation {
            Rotation::Compressor => from,
            Rotation::Expander => to,
        };
        let [_, _, suction, discharge] = self.sensing.pressures.last_pa;
        self.rotary.planned_discharge_pa = discharge;
        let edge = self.rotary.volume_ratio.opening_position_m(
            &self.config.cylinder,
            &self.config.gas,
            chamber,
            reference_x,
            suction,
            discharge,
        );
        // The stroke reference starts where the last one ended; the piston is there too
        // within the dead-point error, and the cam clamps the progress.
        let x_start = from;
        self.rotary.synchroniser.begin_half(
            g.direction(),
            rotation,
            x_start,
            to,
            edge,
            self.rotary.reference_rad,
        );
    }
}
