//! The plan stage: the mode machine — idle, homing, holding, moving, running strokes,
//! controlled stops, faulted, calibrating — and the setpoint each mode plans per cycle. The
//! stops' own state (SS1's hold and rest turn, the brakes of the faulted state) is
//! [`Stop`](super::safe_state::Stop), which this stage runs.

use super::calibrate::CalibrationState;
use super::publish::Previous;
use super::rotate::RotaryAxis;
use super::safe_state::{stop_deceleration, FaultedBrake, SafeState, Stop, RESET_FIT_SAMPLES};
use super::sense::{PressureMonitor, Sensed};
use crate::control::calibration::Calibration;
use crate::control::config::ControlConfig;
use crate::motion::stroke::{DeadPoint, Direction, StrokeGenerator};
use crate::motion::synchroniser::{Rotation, Synchroniser};
use crate::motion::trajectory::{PointToPoint, Setpoint};
use crate::safety::faults::Fault;
use crate::sensing::differentiator::SavitzkyGolay;
use crate::sensing::homing::{Homing, HomingStep};
use crate::status::ModeKind;

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

/// What the position loop is doing. `repr(u8)`: an explicit tag byte, which a test of the
/// mode reads and compares in two instructions (a niche in a variant's data takes four).
#[derive(Clone, Debug)]
#[repr(u8)]
pub(super) enum Mode {
    Idle,
    Homing(Homing),
    Holding(Setpoint),
    Moving {
        path: PointToPoint,
        elapsed_s: f32,
    },
    Running(StrokeGenerator),
    Stopping {
        setpoint: Setpoint,
        then: AfterStop,
    },
    Faulted,
    Calibrating(Calibration),
    /// A bench operation of the bring-up (the bench build's).
    #[cfg(feature = "bench")]
    Bench(BenchRun),
}

/// A bench operation under way (the bench build's).
#[cfg(feature = "bench")]
#[derive(Clone, Copy, Debug)]
pub(super) struct BenchRun {
    pub op: crate::control::command::BenchOp,
    /// The servo's angle when the operation started, rad.
    pub servo_from_rad: f32,
    /// Control cycles left.
    pub cycles_left: u32,
}

/// The plan stage's state: the mode, the stops', the last dead point, what a host may tune
/// here, and the calibration's bookkeeping.
#[derive(Clone, Debug)]
#[repr(C)]
pub(super) struct Plan {
    pub mode: Mode,
    pub stop: Stop,
    /// The last dead point the running strokes reached.
    pub last_dead_point: Option<DeadPoint>,
    /// Where the piston parks after homing or when the host is lost, m.
    pub park_position_m: f32,
    /// The strokes' dead-point correction gain (the stroke configuration's, until a host
    /// sets another).
    pub dead_point_gain: f32,
    pub calibration: CalibrationState,
}

/// What the plan stage reads besides its own state and the sensed values.
#[derive(Clone, Copy)]
pub(super) struct PlanInputs<'a> {
    pub config: &'a ControlConfig,
    pub previous: &'a Previous,
    /// The latched faults and the sections in service.
    pub safe: &'a SafeState,
    pub pressures: &'a PressureMonitor,
}

/// The sense stage's position frame, which homing sets: the raw master position at the zero
/// (none before homing) and the raw slave position there, m.
pub(super) struct Frame<'a> {
    pub zero_raw_m: &'a mut Option<f32>,
    pub zero_slave_raw_m: &'a mut f32,
    /// The differentiator, restarted in a new frame (and on the first samples after a
    /// watchdog reset).
    pub differentiator: &'a mut SavitzkyGolay,
}

/// The plan of one cycle.
#[derive(Clone, Copy, Debug)]
pub(super) struct Planned {
    /// The setpoint (the position frame after homing) and the force limit, N; `None` with
    /// the outputs off.
    pub setpoint: Option<(Setpoint, f32)>,
    /// With no setpoint: the fault the plan found for the react stage (homing found no end
    /// stop, [`Fault::HomingFailed`]).
    pub fault: Option<Fault>,
    /// A half cycle of the strokes began: the rotate stage starts its rotation
    /// ([`begin_half`]), after the duties are out.
    pub half: Option<HalfStart>,
}

/// A half cycle's stroke, as the rotation's start needs it.
#[derive(Clone, Copy, Debug)]
pub(super) struct HalfStart {
    direction: Direction,
    /// Where the stroke's path starts and ends, m.
    from_m: f32,
    to_m: f32,
}

impl HalfStart {
    /// The half cycle `g` is beginning.
    pub(super) fn of(g: &StrokeGenerator) -> HalfStart {
        let (from_m, to_m) = g.path_ends_m();
        HalfStart {
            direction: g.direction(),
            from_m,
            to_m,
        }
    }
}

impl Plan {
    pub(super) fn new(config: &ControlConfig) -> Self {
        Plan {
            mode: Mode::Idle,
            stop: Stop::new(config),
            last_dead_point: None,
            park_position_m: config.park_position_m,
            dead_point_gain: config.stroke.correction_gain,
            calibration: CalibrationState::new(),
        }
    }

    /// Whether strokes are running (the pressure plausibility check watches only then).
    #[inline(always)]
    pub(super) fn running(&self) -> bool {
        matches!(self.mode, Mode::Running(_))
    }

    /// The mode as the status reports it.
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
            #[cfg(feature = "bench")]
            Mode::Bench(_) => ModeKind::Bench,
        }
    }

    /// The plan stage: the mode advanced one cycle with this cycle's sensing `s`. It turns
    /// the rotation's reference itself where a mode asks for it (`rotary`: a park's turn to
    /// a venting phase, SS1's rest turn, the blind brake's sealing turn; a new half cycle's
    /// timing it returns, [`Planned::half`]), sets the position frame where homing finds the end stop and restarts the
    /// differentiator on the first samples after a watchdog reset (`frame`); a fault it
    /// finds it returns.
    pub(super) fn plan(
        &mut self,
        s: &Sensed,
        x: &PlanInputs,
        rotary: &mut RotaryAxis,
        frame: Frame,
    ) -> Planned {
        let c = x.config;
        let measured_force_n = s.force_master_n + s.force_slave_n;
        let dt = c.sample_time_s;
        let limit = c.force_limit_n;
        let mut fault = None;
        let mut half = None;
        let setpoint = match &mut self.mode {
            // The faulted state may still brake; the outputs are its own.
            Mode::Faulted => {
                let homed = frame.zero_raw_m.is_some();
                self.faulted_cycle(x, homed, rotary, frame.differentiator);
                None
            }
            // Calibration drives the outputs itself (after the rest of the step).
            Mode::Idle | Mode::Calibrating(_) => None,
            // A bench operation drives the outputs itself.
            #[cfg(feature = "bench")]
            Mode::Bench(_) => None,
            Mode::Homing(h) => match h.step(s.raw_m, measured_force_n, dt) {
                HomingStep::Creep {
                    reference_m,
                    force_limit_n,
                    // No zero yet: the position frame is the raw frame.
                } => Some((Setpoint::at_rest(reference_m), force_limit_n)),
                HomingStep::Found { stop_raw_m } => {
                    *frame.zero_raw_m = Some(stop_raw_m);
                    *frame.zero_slave_raw_m = s.slave_raw_m - (s.raw_m - stop_raw_m);
                    frame.differentiator.reset();
                    let here = s.raw_m - stop_raw_m;
                    let path = PointToPoint::new(here, self.park_position_m, 0.05);
                    self.mode = Mode::Moving {
                        path,
                        elapsed_s: 0.0,
                    };
                    Some((Setpoint::at_rest(here), limit))
                }
                HomingStep::Failed => {
                    fault = Some(Fault::HomingFailed);
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
                    rotary.turn_to_vent(&c.port_geometry, dt);
                }
                Some((sp, limit))
            }
            Mode::Running(g) => {
                let waited = g.waiting();
                let (sp, dead) = g.step(dt, x.previous.position_m);
                let stopped = g.stopped();
                // The turn before the first stroke (`Command::Start`); that stroke's half
                // cycle begins as the turn ends.
                let started = waited && rotary.turn_to_start(g, dt);
                if let Some(d) = dead {
                    self.last_dead_point = Some(d);
                }
                if started || dead.is_some() {
                    half = Some(HalfStart::of(g));
                }
                if stopped {
                    self.mode = Mode::Holding(Setpoint::at_rest(sp.position_m));
                }
                Some((sp, limit))
            }
            Mode::Stopping { .. } => {
                let homed = frame.zero_raw_m.is_some();
                self.stopping(s, x, homed, rotary, measured_force_n)
            }
        };
        Planned {
            setpoint,
            fault,
            half,
        }
    }

    /// A cycle of a controlled stop: the plan advanced on the stop's deceleration, its
    /// setpoint ([`Stop::setpoint`]); once at rest what follows — for SS1 only once the
    /// rotation has turned to rest and holding needs no force. Out of line: no running or
    /// holding cycle goes through it.
    #[cold]
    #[inline(never)]
    fn stopping(
        &mut self,
        s: &Sensed,
        x: &PlanInputs,
        homed: bool,
        rotary: &mut RotaryAxis,
        measured_force_n: f32,
    ) -> Option<(Setpoint, f32)> {
        let c = x.config;
        let (dt, limit) = (c.sample_time_s, c.force_limit_n);
        let Mode::Stopping { setpoint, then } = &mut self.mode else {
            return None;
        };
        let brake = self.stop.decel_mps2;
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
        // velocity instead of the plan.
        let (sp, zeroing) = self.stop.setpoint(
            c,
            planned,
            s,
            x.previous,
            x.pressures.usable(),
            x.safe.in_service,
            measured_force_n,
            dt,
        );
        if zeroing {
            if let Mode::Stopping { setpoint, .. } = &mut self.mode {
                *setpoint = sp;
            }
        }
        if v_next == 0.0 {
            if then == AfterStop::Off
                && !(self.stop.rest_turn(
                    c,
                    &mut rotary.reference_rad,
                    x.previous.position_m,
                    homed,
                    x.safe.faults.contains(Fault::RotationSync),
                    dt,
                ) && self
                    .stop
                    .hold_released(c, x.previous, x.pressures.usable(), dt))
            {
                return Some((sp, limit));
            }
            self.mode = match then {
                AfterStop::Off => Mode::Faulted,
                AfterStop::Hold => Mode::Holding(Setpoint::at_rest(sp.position_m)),
                AfterStop::Park => Mode::Moving {
                    path: PointToPoint::new(sp.position_m, self.park_position_m, c.park_speed_mps),
                    elapsed_s: rotary.vent_delay_s(&c.port_geometry),
                },
            };
            if then == AfterStop::Off {
                return None;
            }
        }
        Some((sp, limit))
    }

    /// A cycle of the faulted state ([`Stop::faulted_cycle`]); after a watchdog reset, once
    /// the first samples are in (and no encoder fault is latched), the controlled stop in
    /// the encoders' own frame from the velocity fitted to them.
    #[cold]
    #[inline(never)]
    fn faulted_cycle(
        &mut self,
        x: &PlanInputs,
        homed: bool,
        rotary: &mut RotaryAxis,
        differentiator: &mut SavitzkyGolay,
    ) {
        if !self.stop.faulted_cycle(&mut rotary.reference_rad) {
            return;
        }
        if x.safe.faults.contains(Fault::EncoderSignal)
            || x.safe.faults.contains(Fault::EncoderMismatch)
        {
            return;
        }
        let first = differentiator.restart_on_line(RESET_FIT_SAMPLES);
        let position_m = x.previous.position_m;
        let decel = stop_deceleration(
            x.config,
            x.safe.in_service,
            &x.pressures.last_pa,
            homed,
            position_m,
            0.0,
        );
        let setpoint = self
            .stop
            .start_after_reset(decel, position_m, first.velocity_mps);
        self.mode = Mode::Stopping {
            setpoint,
            then: AfterStop::Off,
        };
    }

    /// Starts a controlled stop on the braking deceleration from the measured position and
    /// velocity (`previous`, not the reference: after a fault the piston may be far from
    /// it). Without outputs on there is nothing to stop: the mode goes straight to its end.
    pub(super) fn begin_stop(&mut self, then: AfterStop, x: &PlanInputs, homed: bool) {
        // A bench operation's outputs hold nothing in place.
        #[cfg(feature = "bench")]
        if matches!(self.mode, Mode::Bench(_)) {
            self.mode = Mode::Idle;
        }
        if matches!(self.mode, Mode::Idle | Mode::Homing(_) | Mode::Faulted) {
            self.mode = match then {
                AfterStop::Off => Mode::Faulted,
                AfterStop::Hold | AfterStop::Park => Mode::Idle,
            };
            return;
        }
        // Already stopping: keep the ramp, take the stronger reaction.
        if let Mode::Stopping { then: t, .. } = &mut self.mode {
            self.stop.restart_hold();
            if *t != AfterStop::Off {
                *t = then;
            }
            return;
        }
        let setpoint = Setpoint {
            position_m: x.previous.position_m,
            velocity_mps: x.previous.velocity_mps,
            acceleration_mps2: 0.0,
        };
        let decel = stop_deceleration(
            x.config,
            x.safe.in_service,
            &x.pressures.last_pa,
            homed,
            setpoint.position_m,
            setpoint.velocity_mps,
        );
        self.stop.restart(decel);
        if matches!(self.stop.brake, FaultedBrake::Zeroing(_)) {
            self.stop.brake = FaultedBrake::None;
        }
        self.mode = Mode::Stopping { setpoint, then };
    }

    /// SS1 or STO, the stop every reaction ends in, once the reaction's fault is latched
    /// (`new`: it was not before): a controlled stop on the braking envelope that ends with
    /// the outputs off (SS1) while the position is trusted and known (`trusted_and_homed`),
    /// otherwise the outputs off at once (STO) — also when the fault was already latched
    /// with the position still trusted then.
    pub(super) fn enter_safe_state(&mut self, new: bool, trusted_and_homed: bool, x: &PlanInputs) {
        if !trusted_and_homed {
            self.mode = Mode::Faulted;
        } else if new {
            self.begin_stop(AfterStop::Off, x, true);
        }
    }
}

/// Starts the rotation of a new half cycle (at a dead point, or as strokes start): where
/// the timed port edge must be crossed (discharge opening, or expander cut-off) from the
/// measured line pressures (`last_pa`). Out of line: once per stroke.
#[inline(never)]
pub(super) fn begin_half(
    rotary: &mut RotaryAxis,
    half: HalfStart,
    c: &ControlConfig,
    last_pa: &[f32; 4],
) {
    let HalfStart {
        direction,
        from_m: from,
        to_m: to,
    } = half;
    let rotation = rotary.direction;
    let chamber = Synchroniser::timed_chamber(direction, rotation);
    // The chamber's largest volume is where its compression starts (compressor: the
    // stroke's start) or its expansion ends (expander: the stroke's end).
    let reference_x = match rotation {
        Rotation::Compressor => from,
        Rotation::Expander => to,
    };
    let [_, _, suction, discharge] = *last_pa;
    rotary.planned_discharge_pa = discharge;
    let edge = rotary.volume_ratio.opening_position_m(
        &c.cylinder,
        &c.gas,
        chamber,
        reference_x,
        suction,
        discharge,
    );
    // The stroke reference starts where the last one ended; the piston is there too
    // within the dead-point error, and the cam clamps the progress.
    let x_start = from;
    let reference_rad = rotary.reference_rad;
    rotary
        .synchroniser
        .begin_half(direction, rotation, x_start, to, edge, reference_rad);
}
