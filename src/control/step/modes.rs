//! The mode machine: idle, homing, holding, moving, running strokes, controlled stops,
//! faulted, calibrating — and the setpoint each mode plans per cycle.

use super::sense::Sensed;
use super::{ControlStep, CycleInputs};
use crate::control::calibration::Calibration;
use crate::motion::stroke::StrokeGenerator;
use crate::motion::synchroniser::{Rotation, Synchroniser};
use crate::motion::trajectory::{PointToPoint, Setpoint};
use crate::motion::volume_ratio::Chamber;
use crate::physics::balance::PistonForces;
use crate::physics::port_timing::PortWindow;
use crate::real::{clamp_f32, max_f32, min_f32, sqrt_f32};
use crate::safety::faults::Fault;
use crate::safety::supervisor::LimitFlags;
use crate::sensing::homing::{Homing, HomingStep};
use crate::status::ModeKind;
use crate::units::{PerSection, PhaseDuties};
use core::f32::consts::{PI, TAU};

/// The window over which holding the stopped piston must need (almost) no force before SS1
/// switches the outputs off, s: 50 ms, ten times the force's settling after the stop ramp.
pub const HOLD_RELEASE_S: f32 = 0.05;

/// Time constant of the controlled stop's disturbance observer, s: 2 ms, longer than the
/// differentiator's 1.25 ms window (its acceleration is the noisiest input) and still fast
/// next to the 10–30 ms a stop takes. At 0.5 ms the stop rang after a watchdog reset
/// (`tests/faults_are_caught_and_the_machine_stays_safe.rs`, s12).
pub const DOB_TIME_S: f32 = 2.0e-3;

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

/// How fast the rotation turns to the venting phase before a park, rad/s (half a turn, the
/// farthest, in 0.5 s).
pub const VENT_SPEED_RAD_S: f32 = core::f32::consts::TAU;

/// How long the park holds the piston while the rotation turns to the venting phase, s:
/// half a turn at [`VENT_SPEED_RAD_S`] and 0.25 s for the servo to settle there. The park
/// move's clock starts this far below zero (its path is at rest there).
pub const VENT_TIME_S: f32 = 0.75;

/// `angle_rad` brought into [0, 2π): the one wrap, [`crate::angle::wrap_rad`] (out of line:
/// the stop and vent paths that call it are cold, and a dozen inlined copies cost flash).
#[inline(never)]
fn turn_phase(angle_rad: f32) -> f32 {
    crate::angle::wrap_rad(angle_rad)
}

/// How long the rotation spends in `window` on a turn by `turn_rad` from `phase_rad`, s,
/// driven toward the target at `accel_rad_s2` from its speed `speed_rad_s` (signed, positive
/// forward). Against its speed it first coasts to a stop, deeper into a window it is in, and
/// comes back: that time counts too. 0 for no turn.
fn time_in_window(
    phase_rad: f32,
    turn_rad: f32,
    window: &PortWindow<f32>,
    speed_rad_s: f32,
    accel_rad_s2: f32,
) -> f32 {
    if turn_rad == 0.0 {
        return 0.0;
    }
    let length = turn_rad.abs();
    // Speed along the turn, and the time to have come `s` along it (the later root: against
    // the speed the rotation passes its start again on the way).
    let v0 = if turn_rad > 0.0 {
        speed_rad_s
    } else {
        -speed_rad_s
    };
    let reach = |s: f32| (sqrt_f32(v0 * v0 + 2.0 * accel_rad_s2 * s) - v0) / accel_rad_s2;
    // The window in the turn's own coordinate: where it begins ahead on the path, and how
    // far into it the path begins.
    let (edge_ahead, edge_behind) = if turn_rad > 0.0 {
        (window.open_rad, window.close_rad)
    } else {
        (window.close_rad, window.open_rad)
    };
    let width = window.span_rad();
    let forward = |a: f32, b: f32| {
        if turn_rad > 0.0 {
            turn_phase(b - a)
        } else {
            turn_phase(a - b)
        }
    };
    let ahead = forward(phase_rad, edge_ahead);
    let mut time = 0.0;
    if ahead < length && ahead > 0.0 {
        time += reach(min_f32(ahead + width, length)) - reach(ahead);
    }
    // Inside the window at the start: until the path leaves it.
    let left = forward(phase_rad, edge_behind);
    if forward(edge_ahead, phase_rad) < width && left > 0.0 {
        time += reach(min_f32(left, length));
    }
    time
}

/// What the faulted state still does with the outputs (they are off otherwise).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum FaultedBrake {
    /// Nothing.
    None,
    /// After a watchdog reset: cycles until the velocity estimate is valid, then a controlled
    /// stop in the encoders' own frame ([`ControlStep::boot`]).
    AfterReset(u16),
    /// Both encoders lost: cycles of outputs off left before the windings are
    /// short-circuited (0: shorted; [`ControlStep::brake_without_position`]).
    Blind(u16),
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
        self.limits = LimitFlags::default();
        let measured_force_n = s.force_master_n + s.force_slave_n;
        let dt = self.config.sample_time_s;
        let setpoint = self.next_setpoint(s.raw_m, s.slave_raw_m, measured_force_n, dt);
        self.setpoint = setpoint.map(|(sp, _)| sp);
        setpoint
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

    /// Advances the mode; returns the setpoint (position frame after homing) and the force
    /// limit, or `None` when the outputs must be off.
    pub(super) fn next_setpoint(
        &mut self,
        raw_m: f32,
        slave_raw_m: f32,
        measured_force_n: f32,
        dt: f32,
    ) -> Option<(Setpoint, f32)> {
        let limit = self.config.force_limit_n;
        match &mut self.mode {
            // Calibration drives the outputs itself (`calibration_cycle`).
            Mode::Faulted if !matches!(self.faulted_brake, FaultedBrake::None) => {
                self.faulted_cycle();
                None
            }
            Mode::Idle | Mode::Faulted | Mode::Calibrating(_) => None,
            Mode::Homing(h) => match h.step(raw_m, measured_force_n, dt) {
                HomingStep::Creep {
                    reference_m,
                    force_limit_n,
                    // No zero yet: the position frame is the raw frame.
                } => Some((Setpoint::at_rest(reference_m), force_limit_n)),
                HomingStep::Found { stop_raw_m } => {
                    self.zero_raw_m = Some(stop_raw_m);
                    self.zero_slave_raw_m = slave_raw_m - (raw_m - stop_raw_m);
                    self.differentiator.reset();
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
                    self.turn_to_vent(dt);
                }
                Some((sp, limit))
            }
            Mode::Running(g) => {
                let (sp, dead) = g.step(dt, self.status.position_m);
                let stopped = g.stopped();
                if let Some(d) = dead {
                    self.last_dead_point = Some(d);
                    let generator = g.clone();
                    self.begin_half(&generator);
                }
                if stopped {
                    self.mode = Mode::Holding(Setpoint::at_rest(sp.position_m));
                }
                Some((sp, limit))
            }
            Mode::Stopping { setpoint, then } => {
                let brake = self.stop_decel_mps2;
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
                let mut sp = *setpoint;
                let then = *then;
                // The force the model does not know (an external load, the gas of a chamber
                // whose sensor failed) is estimated and cancelled through the feed-forward:
                // the position loop alone would yield 4 mm to 3 kN, near a head too much.
                sp.acceleration_mps2 -=
                    self.observe_disturbance(measured_force_n, dt) / self.config.moving_mass_kg;
                if v_next == 0.0 {
                    if then == AfterStop::Off && !self.hold_released(dt) {
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
                            elapsed_s: self.vent_delay_s(),
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

    /// The nearest phase where both chambers breathe
    /// ([`crate::physics::port_timing::PortGeometry::venting_phases_rad`]), as a turn of the
    /// rotation from the current reference, rad in [−π, π); `None` for a geometry without one.
    fn vent_turn_rad(&self) -> Option<f32> {
        let phase = turn_phase(self.theta_reference_rad);
        self.config
            .port_geometry
            .venting_phases_rad()
            .iter()
            .flatten()
            // The shorter way round.
            .map(|v| turn_phase(*v - phase + PI) - PI)
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
    fn vent_delay_s(&self) -> f32 {
        match self.vent_turn_rad() {
            Some(_) => -VENT_TIME_S,
            None => 0.0,
        }
    }

    /// One cycle of the park's turn: the rotation reference moves toward the nearest venting
    /// phase at [`VENT_SPEED_RAD_S`] (the target is found again each cycle: the nearest stays
    /// the nearest as the reference approaches it).
    #[cold]
    #[inline(never)]
    fn turn_to_vent(&mut self, dt: f32) {
        if let Some(d) = self.vent_turn_rad() {
            let step = VENT_SPEED_RAD_S * dt;
            self.theta_reference_rad += clamp_f32(d, -step, step);
        }
    }

    /// Both encoders lost (issue #15, `faults.md` #22): nothing tells where the piston is,
    /// so nothing can commutate a braking force. The reaction, chosen by simulation over the
    /// whole stroke cycle (`tests/losing_both_encoders_brakes_without_position.rs`):
    ///
    /// 1. Outputs off (STO) while the winding currents decay into the bus (`L·I_max/V_bus`,
    ///    0.7 ms): shorted at once, a current that was holding the piston against the gas
    ///    would go on pulling it for the windings' `L/R` (10 ms).
    /// 2. Then the windings short-circuited (all six low-side switches on): the back-EMF
    ///    drives braking currents through the windings' resistance, up to ~2.7 kN for both
    ///    sections near 0.4 m/s, ~0.5 kN at 4.1 m/s — a strong damper at low speed.
    /// 3. The rotation, whose own encoder is still good, turns the shorter way to the nearest
    ///    phase where both ports of the chamber ahead (by the last trusted velocity) are
    ///    closed, a ramp inside its sealed arc, and holds there: that chamber becomes a gas
    ///    spring that takes the piston's kinetic energy, and the short circuit damps the
    ///    rebound. A coasting rotation would open the chamber ahead to its intake, or hold it
    ///    on the discharge line (a constant 2.5 kN push back over the whole stroke).
    ///    Except near a dead point, the chamber ahead already discharging: the line's
    ///    pressure, which the sections had to drive the piston against, turns it there, and
    ///    the turn back to seal that chamber (against the rotation's own speed) would leave
    ///    it on the line through the rebound, the line pushing the piston back across the
    ///    stroke (a plant 9 % lighter than the model reached the other head). Then the
    ///    other chamber, ahead after the turn, is sealed: forward, the way the rotation
    ///    already goes, past the dead-point phase where the discharge closes.
    ///
    ///    Which way round: the turn that holds the chamber *behind* on its discharge port
    ///    for the least time (at full servo torque from the rotation's speed now: against
    ///    it, the rotation must stop first), and of those the shortest. As a compressor no
    ///    turn crosses that port, and this is the shortest turn. As an expander the rotation
    ///    runs backwards and the chamber behind is admitting from the line: the shorter turn
    ///    can go back through its admission, the line driving the piston into the head
    ///    (−2.2 mm, 346 bar in the chamber ahead at PR 5.1, before this rule); the turn
    ///    the way the rotation runs cuts the admission off.
    #[cold]
    #[inline(never)]
    pub(super) fn brake_without_position(&mut self) {
        if matches!(self.faulted_brake, FaultedBrake::Blind(_)) {
            return;
        }
        let g = &self.config.port_geometry;
        let ramp = g.ramp_rad;
        let phase = turn_phase(self.theta_reference_rad);
        let toward_b = self.status.velocity_mps >= 0.0;
        // The chamber ahead already discharging: the line turns the piston before its dead
        // point; the chamber to seal is the other one, ahead after the turn (see above).
        let ahead = if toward_b {
            &g.discharge_b
        } else {
            &g.discharge_a
        };
        let discharging =
            turn_phase(phase - ahead.open_rad) < turn_phase(ahead.close_rad - ahead.open_rad);
        let (intake, discharge) = if toward_b != discharging {
            (&g.intake_b, &g.discharge_b)
        } else {
            (&g.intake_a, &g.discharge_a)
        };
        // The chamber behind by the last trusted velocity: a turn that holds it on the
        // discharge line drives the piston on toward the head (see above).
        let behind = if toward_b {
            &g.discharge_a
        } else {
            &g.discharge_b
        };
        // The two arcs between the chamber's windows, each inset by a ramp at both ends:
        // of the turns to either end of either (0 inside one), the one that holds the
        // behind chamber on the line for the least time — the rotation going at full
        // torque from its speed now (against it, it must stop first) — and of those the
        // shortest.
        let speed = self.servo.velocity_rad_s();
        let sc = &self.config.servo;
        let accel = max_f32(sc.torque_full_scale_nm / sc.inertia_kgm2, 1.0);
        let mut best: Option<(f32, f32)> = None;
        for (from, to) in [
            (intake.close_rad, discharge.open_rad),
            (discharge.close_rad, intake.open_rad),
        ] {
            if turn_phase(to - from) <= 2.0 * ramp {
                continue;
            }
            let start = from + ramp;
            let span = turn_phase(to - ramp - start);
            let into = turn_phase(phase - start);
            // Inside the arc: no turn; outside: back to its far end or on to its near one.
            let turns = if into <= span {
                [0.0, 0.0]
            } else {
                [span - into, TAU - into]
            };
            for turn in turns {
                let exposed = time_in_window(phase, turn, behind, speed, accel);
                best = match best {
                    Some((e, b)) if (e, b.abs()) <= (exposed, turn.abs()) => Some((e, b)),
                    _ => Some((exposed, turn)),
                };
            }
        }
        let m = &self.config.motor;
        let decay_s = m.inductance_h * m.current_limit_a / m.bus_voltage_v;
        let cycles = clamp_f32(decay_s / self.config.sample_time_s + 1.0, 1.0, 1000.0) as u16;
        self.faulted_brake = FaultedBrake::Blind(cycles);
        // The phase to turn to once the windings are shorted (SS1's hold timer is free
        // while faulted).
        let turn = best.map_or(0.0, |(_, turn)| turn);
        self.hold_quiet_s = turn_phase(phase + turn);
        self.sealing_turn_rad = turn;
    }

    /// A cycle of the faulted state that still brakes: after a watchdog reset, the wait for
    /// the velocity estimate; after both encoders were lost, the countdown to the short
    /// circuit, and at its end the rotation sent to the sealing phase (once).
    #[cold]
    #[inline(never)]
    pub(super) fn faulted_cycle(&mut self) {
        match self.faulted_brake {
            FaultedBrake::None => {}
            FaultedBrake::AfterReset(_) => self.brake_after_reset(),
            FaultedBrake::Blind(left) => {
                self.faulted_brake = FaultedBrake::Blind(left.saturating_sub(1));
                if left <= 1 && !self.hold_quiet_s.is_nan() {
                    // The shorter way to the target from where the rotation has coasted,
                    // unless the turn decided goes the long way round.
                    let now = turn_phase(self.theta_reference_rad);
                    let mut turn = turn_phase(self.hold_quiet_s - now + PI) - PI;
                    if self.sealing_turn_rad < -PI && turn > 0.0 {
                        turn -= TAU;
                    } else if self.sealing_turn_rad > PI && turn < 0.0 {
                        turn += TAU;
                    }
                    self.theta_reference_rad += turn;
                    self.hold_quiet_s = f32::NAN;
                }
            }
        }
    }

    /// The outputs with no setpoint (not calibrating): off — the current loops reset and
    /// the phase currents watched for an offset — except with both encoders lost once the
    /// currents have decayed: the windings short-circuited (equal duties, zero voltage on
    /// every phase; [`ControlStep::brake_without_position`]).
    #[cold]
    #[inline(never)]
    pub(super) fn outputs_off(&mut self, inputs: &CycleInputs) -> Option<PerSection<PhaseDuties>> {
        self.currents.master.reset();
        self.currents.slave.reset();
        self.load_observer = f32::NAN;
        self.load_n = 0.0;
        self.shares = PerSection::default();
        self.status.force_command_n = 0.0;
        if self.faulted_brake == FaultedBrake::Blind(0) {
            return Some(PerSection::default());
        }
        self.sense_monitor.observe(&inputs.currents);
        None
    }

    /// After a watchdog reset: counts the cycles until the velocity estimate is valid, then
    /// starts the controlled stop (see [`ControlStep::boot`]).
    #[cold]
    #[inline(never)]
    pub(super) fn brake_after_reset(&mut self) {
        let left = match self.faulted_brake {
            FaultedBrake::AfterReset(n) => n,
            _ => 0,
        };
        if left > 0 {
            self.faulted_brake = FaultedBrake::AfterReset(left - 1);
            return;
        }
        self.faulted_brake = FaultedBrake::None;
        if self.faults.contains(Fault::EncoderSignal)
            || self.faults.contains(Fault::EncoderMismatch)
        {
            return;
        }
        self.hold_quiet_s = 0.0;
        self.hold_motor_ns = 0.0;
        self.hold_gas_ns = 0.0;
        self.stop_decel_mps2 = self.stop_deceleration(self.status.position_m, 0.0);
        self.disturbance_n = 0.0;
        self.mode = Mode::Stopping {
            setpoint: Setpoint {
                position_m: self.status.position_m,
                velocity_mps: self.status.velocity_mps,
                acceleration_mps2: 0.0,
            },
            then: AfterStop::Off,
        };
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
        self.hold_quiet_s = 0.0;
        self.hold_motor_ns = 0.0;
        self.hold_gas_ns = 0.0;
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
        self.stop_decel_mps2 = self.stop_deceleration(setpoint.position_m, setpoint.velocity_mps);
        self.disturbance_n = 0.0;
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
        let gas_n = if self.pressures_trusted && self.pressure_bad == 0 {
            self.config
                .cylinder
                .gas_force_n(self.status.pressure_a_pa, self.status.pressure_b_pa)
        } else {
            0.0
        };
        self.hold_quiet_s += dt;
        self.hold_motor_ns += self.status.force_command_n * dt;
        self.hold_gas_ns += gas_n * dt;
        if self.hold_quiet_s < HOLD_RELEASE_S {
            return false;
        }
        let window = self.hold_quiet_s;
        let (motor, gas) = (self.hold_motor_ns / window, self.hold_gas_ns / window);
        self.hold_quiet_s = 0.0;
        self.hold_motor_ns = 0.0;
        self.hold_gas_ns = 0.0;
        let stiction = self.config.friction.static_n;
        motor.abs() <= stiction && gas.abs() <= 0.5 * stiction
    }

    /// The deceleration of a controlled stop from `velocity_mps` at `position_m`: the
    /// braking envelope's `a_brake`, or more when the piston is closer to the head it moves
    /// toward than that needs (a disturbance pushed it past the envelope, which is what
    /// tripped): enough to stop 1 mm short of the minimum clearance with 25 % in hand, up to
    /// `a_brake` per healthy section (`a_brake` is what one section alone guarantees). Without
    /// the zero (after a watchdog reset) the heads' distance is unknown: the most there is.
    pub(super) fn stop_deceleration(&self, position_m: f32, velocity_mps: f32) -> f32 {
        let c = &self.config.supervisor;
        let cap = self.config.allocation.capability;
        let sections = clamp_f32(cap.master, 0.0, 1.0) + clamp_f32(cap.slave, 0.0, 1.0);
        let a_max = c.brake_deceleration_mps2 * max_f32(sections, 1.0);
        if self.zero_raw_m.is_none() {
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

    /// The disturbance observer of a controlled stop: the force on the piston that the model
    /// does not explain, `m·a − (F_motor + F_gas − F_friction(v))`
    /// ([`PistonForces::unexplained_n`]) from the measured acceleration, motor force
    /// (q-currents) and gas force (when the pressures are valid; otherwise the gas is part of
    /// what it estimates), low-passed over [`DOB_TIME_S`]. N, toward +x.
    #[cold]
    #[inline(never)]
    pub(super) fn observe_disturbance(&mut self, motor_force_n: f32, dt: f32) -> f32 {
        let c = &self.config;
        let st = &self.status;
        let gas_n = if self.pressures_trusted && self.pressure_bad == 0 {
            c.cylinder.gas_force_n(st.pressure_a_pa, st.pressure_b_pa)
        } else {
            0.0
        };
        let unexplained =
            PistonForces::known(motor_force_n, gas_n, c.friction.force_n(st.velocity_mps))
                .unexplained_n(c.moving_mass_kg, st.acceleration_mps2);
        if unexplained.is_finite() {
            let alpha = clamp_f32(dt / DOB_TIME_S, 0.0, 1.0);
            self.disturbance_n += alpha * (unexplained - self.disturbance_n);
        }
        // Never more than the sections can push against.
        let limit = c.force_limit_n;
        self.disturbance_n = clamp_f32(self.disturbance_n, -limit, limit);
        self.disturbance_n
    }

    /// Starts the rotation of a new half cycle: where the timed port edge must be crossed
    /// (discharge opening, or expander cut-off) from the measured line pressures.
    pub(super) fn begin_half(&mut self, g: &StrokeGenerator) {
        let (from, to) = g.path_ends_m();
        let rotation = self.rotation;
        let chamber = Synchroniser::timed_chamber(g.direction(), rotation);
        // The chamber's largest volume is where its compression starts (compressor: the
        // stroke's start) or its expansion ends (expander: the stroke's end).
        let reference_x = match rotation {
            Rotation::Compressor => from,
            Rotation::Expander => to,
        };
        let [_, _, suction, discharge] = self.pressures_pa;
        self.planned_discharge_pa = discharge;
        let edge = self.volume_ratio.opening_position_m(
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
        self.synchroniser.begin_half(
            g.direction(),
            rotation,
            x_start,
            to,
            edge,
            self.theta_reference_rad,
        );
    }

    /// The measured rotation crossed the timed edge: in compressor mode the discharge of
    /// `chamber` just opened, and its pressure now says whether it opened on time.
    pub(super) fn edge_crossed(&mut self, chamber: Chamber, rotation: Rotation) {
        if rotation != Rotation::Compressor {
            return;
        }
        let [a, b, _, _] = self.pressures_pa;
        let p = match chamber {
            Chamber::A => a,
            Chamber::B => b,
        };
        self.volume_ratio
            .observe_opening(&self.config.gas, chamber, p, self.planned_discharge_pa);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::port_timing::PortGeometry;

    /// The same time found by stepping the motion through time: the angle at full
    /// acceleration toward the turn from the speed now, and whether it is in the window,
    /// tested directly at each step of 1 µs until the turn is done.
    fn stepped(phase: f32, turn: f32, w: &PortWindow<f32>, speed: f32, accel: f32) -> f32 {
        let (phase, turn, speed, accel) = (
            f64::from(phase),
            f64::from(turn),
            f64::from(speed),
            f64::from(accel),
        );
        let (open, close) = (f64::from(w.open_rad), f64::from(w.close_rad));
        let tau = std::f64::consts::TAU;
        let dir = turn.signum();
        let dt = 1e-6;
        let (mut angle, mut v, mut inside_s) = (0.0f64, speed * dir, 0.0);
        while angle < turn.abs() {
            let at = (phase + dir * angle).rem_euclid(tau);
            if (at - open).rem_euclid(tau) < (close - open).rem_euclid(tau) {
                inside_s += dt;
            }
            v += accel * dt;
            angle += v * dt;
        }
        inside_s as f32
    }

    #[test]
    fn the_time_in_a_window_is_the_stepped_motions() {
        let g = PortGeometry::<f32>::reference();
        let accel = 2500.0;
        // Each way, with and against the speed, from inside the window, before it and past
        // it; the coast before turning round stays well inside the region it starts in.
        let deg = |d: f32| d.to_radians();
        let cases = [
            (deg(327.7), deg(38.3), -34.0),
            (deg(327.7), deg(-225.7), -34.0),
            (deg(250.0), deg(116.0), -34.0),
            (deg(250.0), deg(-148.0), -34.0),
            (deg(250.0), deg(116.0), 34.0),
            (deg(100.0), deg(250.0), 20.0),
            (deg(20.0), deg(-120.0), 0.0),
            (deg(20.0), 0.0, 34.0),
        ];
        for (phase, turn, speed) in cases {
            let w = &g.discharge_a;
            let formula = time_in_window(phase, turn, w, speed, accel);
            let reference = stepped(phase, turn, w, speed, accel);
            println!("φ {phase:.3} turn {turn:+.3} ω {speed:+.0}: {formula:.6} s (stepped {reference:.6} s)");
            assert!(
                (formula - reference).abs() < 2e-5,
                "φ {phase} turn {turn} ω {speed}: {formula} s, stepped {reference} s"
            );
        }
    }
}
