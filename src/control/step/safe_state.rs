//! The safe state: what the machine does once a fault has latched, each reaction of
//! [`crate::safety::faults::Reaction`] carried out — SS1 (a controlled stop, then the outputs
//! off) or STO (outputs off at once), a section taken out of the allocation, braking without
//! position after both encoders were lost, braking after a watchdog reset — and the park's
//! turn to a venting phase when the host is lost. The supervise stage detects a fault and
//! dispatches its reaction here ([`ControlStep::react`]); the mode machine (`modes.rs`) runs
//! the controlled stop these reactions start.

use super::actuate::RotaryAxis;
use super::modes::{turn_phase, AfterStop, Mode};
use super::sense::Sensed;
use super::{ControlStep, CycleInputs};
use crate::control::config::ControlConfig;
use crate::motion::trajectory::Setpoint;
use crate::physics::port_timing::{PortGeometry, PortWindow};
use crate::real::{clamp_f32, max_f32, min_f32, sqrt_f32};
use crate::safety::faults::Fault;
use crate::units::{PerSection, PhaseDuties};
use core::f32::consts::{FRAC_PI_2, PI, TAU};

/// How fast the rotation turns to the venting phase before a park, rad/s (half a turn, the
/// farthest, in 0.5 s).
pub const VENT_SPEED_RAD_S: f32 = core::f32::consts::TAU;

/// How long the park holds the piston while the rotation turns to the venting phase, s:
/// half a turn at [`VENT_SPEED_RAD_S`] and 0.25 s for the servo to settle there. The park
/// move's clock starts this far below zero (its path is at rest there).
pub const VENT_TIME_S: f32 = 0.75;

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

/// Samples the first velocity after a watchdog reset is fitted to (a straight line through
/// them, [`SavitzkyGolay::restart_on_line`](crate::sensing::differentiator::SavitzkyGolay::restart_on_line)),
/// the outputs off meanwhile: 0.25 ms after the first sample instead of the differentiator's
/// full window (25 samples and 5 to settle, 1.5 ms), which an expander braking into a dead
/// point alone cannot spare. Its noise with the encoders' σ ≈ 1 µm: ≈ 5 mm/s
/// (0.24·σ/T), and under the gas's push with the outputs off (≤ 2.5 kN on 12 kg) a lag of
/// ≤ 26 mm/s; the controlled stop's loop takes over from there.
pub const RESET_FIT_SAMPLES: usize = 6;

/// The first velocity after a watchdog reset above which the stop brakes at full force until
/// the measured velocity is zero ([`ControlStep::stop_setpoint`]), m/s: ten times the first
/// velocity's noise (≈ 5 mm/s) and twice its lag under the gas's push (≤ 26 mm/s), so a
/// piston at rest (a hang at a dead point's rest) is stopped and held as before.
pub const RESET_ZEROING_MPS: f32 = 0.05;

/// The state of the stops and the reactions: the controlled stop's deceleration, SS1's hold
/// window, the blind brake's sealing turn, what the faulted state still does, and each
/// section's capability as configured.
#[derive(Clone, Debug)]
pub(super) struct SafeState {
    /// Deceleration of the controlled stop in progress, m/s².
    pub stop_decel_mps2: f32,
    /// SS1's hold: time into the current averaging window, s, and the integrals over it of
    /// the motor force and of the measured gas force, N·s.
    pub hold_quiet_s: f32,
    pub hold_motor_ns: f32,
    pub hold_gas_ns: f32,
    /// Both encoders lost: the rotation's sealing turn as decided, rad, signed (which way
    /// round it goes).
    pub sealing_turn_rad: f32,
    /// What the faulted state still does with the outputs: brake after a watchdog reset, or
    /// brake without position after both encoders were lost.
    pub brake: FaultedBrake,
    /// Each section's capability as configured (restored when faults are cleared).
    pub nominal_capability: PerSection<f32>,
    /// SS1's rest turn before the outputs go off ([`ControlStep::turn_to_rest`]).
    pub rest: RestTurn,
}

/// SS1's turn of the rotation, the piston held at rest, to the phase the outputs go off at
/// ([`ControlStep::turn_to_rest`]); phases in rad, [0, 2π).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum RestTurn {
    /// Not planned yet (a stop is in progress).
    Unplanned,
    /// The shorter way to `via`, inside the near chamber's intake window, then forward to
    /// `target`.
    Via { via: f32, target: f32 },
    /// Forward to `target`, across the near chamber's intake closing.
    Final { target: f32 },
    /// At the target (or no turn possible): the hold may end.
    Done,
}

impl SafeState {
    pub(super) fn new(config: &ControlConfig) -> Self {
        SafeState {
            stop_decel_mps2: config.supervisor.brake_deceleration_mps2,
            hold_quiet_s: 0.0,
            hold_motor_ns: 0.0,
            hold_gas_ns: 0.0,
            sealing_turn_rad: 0.0,
            brake: FaultedBrake::None,
            nominal_capability: config.allocation.capability,
            rest: RestTurn::Unplanned,
        }
    }
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
    /// After a watchdog reset, the stop braking at full force against the measured velocity
    /// until it is zero (its direction, +1 or −1; [`ControlStep::stop_setpoint`]): the
    /// continuation of the brake after the reset.
    Zeroing(i16),
}

impl ControlStep {
    /// SS1 or STO for `fault`, the stop every reaction ends in: latches `fault`; with the
    /// position trusted (and known: homed) a controlled stop on the braking envelope that
    /// ends with the outputs off (SS1), otherwise the outputs off at once (STO) — also when
    /// the fault was already latched with the position still trusted then.
    #[cold]
    #[inline(never)]
    pub(super) fn enter_safe_state(&mut self, fault: Fault, position_trusted: bool) {
        let new = self.faults.latch(fault);
        if !(position_trusted && self.sensing.zero_raw_m.is_some()) {
            self.mode = Mode::Faulted;
        } else if new {
            self.begin_stop(AfterStop::Off);
        }
    }

    /// Takes a section out of the allocation (lost, or switched off after an overcurrent).
    pub(super) fn drop_section(&mut self, index: usize) {
        let cap = &mut self.config.allocation.capability;
        if index == 0 {
            cap.master = 0.0;
        } else {
            cap.slave = 0.0;
        }
    }

    /// After an overcurrent: the section with the larger peak phase current is taken out;
    /// the other one stops the piston.
    pub(super) fn drop_hotter_section(&mut self) {
        let m = self.currents.master.state().peak_phase_a;
        let s = self.currents.slave.state().peak_phase_a;
        self.drop_section(if m >= s { 0 } else { 1 });
    }

    /// After a watchdog reset: the outputs stay off for the [`RESET_FIT_SAMPLES`] the first
    /// velocity is fitted to, then [`ControlStep::brake_after_reset`] starts the controlled
    /// stop (see [`ControlStep::boot`]).
    pub(super) fn await_velocity_then_brake(&mut self) {
        self.safe.brake = FaultedBrake::AfterReset((RESET_FIT_SAMPLES - 1) as u16);
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
        self.estimator.load_state = f32::NAN;
        self.estimator.load_n = 0.0;
        self.shares = PerSection::default();
        self.status.force_command_n = 0.0;
        if self.safe.brake == FaultedBrake::Blind(0) {
            return Some(PerSection::default());
        }
        self.calibration.sense_monitor.observe(&inputs.currents);
        None
    }

    /// Both encoders lost (`docs/faults.md` #22): nothing tells where the piston is,
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
    ///
    ///    The chamber behind still on its line at the loss (as an expander: its admission,
    ///    the stroke just begun, the piston near the head behind) also counts the time the
    ///    turn spends in the *sealed* chamber's own admission window: the turn the way the
    ///    rotation runs reaches its sealed arc through that window, so it seals the line's
    ///    gas in a long column, which after taking the piston's energy expands back to
    ///    suction over PR^(1/γ) = 2.2–3.2 times its volume — beyond the other head (five
    ///    runs of the expander sweep, −0.02 mm). The other way round, the chamber behind
    ///    stays on its line a little longer and the chamber ahead is sealed from its intake
    ///    at the suction pressure (≥ 18.5 mm there). Later in the stroke the chamber ahead
    ///    is short when sealed, and the turn away from the admission would put the line
    ///    behind the piston for a whole window: there only the chamber behind counts.
    #[cold]
    #[inline(never)]
    pub(super) fn brake_without_position(&mut self) {
        if matches!(self.safe.brake, FaultedBrake::Blind(_)) {
            return;
        }
        let g = &self.config.port_geometry;
        let ramp = g.ramp_rad;
        let phase = turn_phase(self.rotary.reference_rad);
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
        // discharge line drives the piston on toward the head (see above); on its line now,
        // the sealed chamber's admission counts too (see above).
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
        let behind_on_line = turn_phase(phase - behind.open_rad) < behind.span_rad();
        let speed = self.rotary.servo.velocity_rad_s();
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
                let mut exposed = time_in_window(phase, turn, behind, speed, accel);
                if behind_on_line && !discharging {
                    exposed += time_in_window(phase, turn, discharge, speed, accel);
                }
                best = match best {
                    Some((e, b)) if (e, b.abs()) <= (exposed, turn.abs()) => Some((e, b)),
                    _ => Some((exposed, turn)),
                };
            }
        }
        let m = &self.config.motor;
        let decay_s = m.inductance_h * m.current_limit_a / m.bus_voltage_v;
        let cycles = clamp_f32(decay_s / self.config.sample_time_s + 1.0, 1.0, 1000.0) as u16;
        self.safe.brake = FaultedBrake::Blind(cycles);
        // The phase to turn to once the windings are shorted (SS1's hold timer is free
        // while faulted).
        let turn = best.map_or(0.0, |(_, turn)| turn);
        self.safe.hold_quiet_s = turn_phase(phase + turn);
        self.safe.sealing_turn_rad = turn;
    }

    /// A cycle of the faulted state: nothing while no brake runs ([`FaultedBrake::None`]);
    /// after a watchdog reset, the wait for the velocity estimate; after both encoders were
    /// lost, the countdown to the short circuit, and at its end the rotation sent to the
    /// sealing phase (once).
    #[cold]
    #[inline(never)]
    pub(super) fn faulted_cycle(&mut self) {
        match self.safe.brake {
            FaultedBrake::None | FaultedBrake::Zeroing(_) => {}
            FaultedBrake::AfterReset(_) => self.brake_after_reset(),
            FaultedBrake::Blind(left) => {
                self.safe.brake = FaultedBrake::Blind(left.saturating_sub(1));
                if left <= 1 && !self.safe.hold_quiet_s.is_nan() {
                    // From where the rotation has coasted, the way round decided: a turn
                    // of about half a revolution is otherwise taken the other way once the
                    // coast has made that way the shorter (a backward turn of 179.9°
                    // applied forward: across the admission the turn was chosen to avoid,
                    // −0.25 mm). A short turn goes the shorter way, so a coast
                    // past a target close by comes back to it.
                    let now = turn_phase(self.rotary.reference_rad);
                    let mut turn = turn_phase(self.safe.hold_quiet_s - now + PI) - PI;
                    let decided = self.safe.sealing_turn_rad;
                    if decided < -FRAC_PI_2 && turn > 0.0 {
                        turn -= TAU;
                    } else if decided > FRAC_PI_2 && turn < 0.0 {
                        turn += TAU;
                    }
                    self.rotary.reference_rad += turn;
                    self.safe.hold_quiet_s = f32::NAN;
                }
            }
        }
    }

    /// SS1's rest turn: before the outputs go off, the rotation — the piston
    /// held at rest by the sections — turns to the phase where the chamber between the
    /// piston and the nearer head has just been vented to its intake and sealed, and the
    /// other chamber is open to its intake. Returns whether the rotation is there (the hold
    /// may end).
    ///
    /// Why: with the outputs off nothing but the gas holds the piston. A chamber open to a
    /// line pushes with a constant pressure; a sealed one is a gas spring, stiff in
    /// proportion to 1/(its gas column). Left with the *far* chamber sealed above the near
    /// one's line (a 100 mm column at 1.08 bar against suction: 50 N), the piston drifts
    /// until the far chamber has expanded to the line's pressure — 6 mm, into the head
    /// (the expander's failures before this turn). Left with the near chamber sealed at a
    /// line's discharge pressure, its gas throws the piston across the stroke. Sealed at
    /// the suction pressure with the far chamber at suction too, no pressure difference
    /// pushes the piston either way, and a push toward the near head compresses a column
    /// of a few millimetres: it stops within a fraction of one.
    ///
    /// The phases come from the port geometry alone: the target is one and a half ramps past
    /// the near chamber's intake closing (the far chamber's intake open there on the
    /// reference geometry: 189° near head A, 9° near head B), reached going forward across
    /// that closing from inside the intake window, so the chamber is vented on the way.
    /// From anywhere else the rotation first turns the shorter way to one and a half ramps
    /// before the closing. The rotation is at rest after the stop in either mode (the stop
    /// freezes its reference), so the direction it ran in does not change the turn.
    /// Crossing the far chamber's discharge window on the way puts the line's pressure
    /// difference on the piston (2.5 kN at PR 5.1): one section alone holds 5 kN.
    ///
    /// No turn with the rotation itself faulted: the hold then ends on the force criterion
    /// alone. After a watchdog reset (not homed: SS1 needs the zero) neither the heads'
    /// distance nor the rotation's phase is known, so no turn can be chosen and nothing
    /// says the gas will leave the piston still once the outputs are off: the hold
    /// continues (never `true`) until the faults are cleared. Released on the force
    /// criterion, a piston stopped 0.3 mm from head B as an expander (`docs/firmware.md`, "The
    /// fault sweep") crept into it at 0.5 mm/s, its far chamber's pressure rising 6 kPa above the
    /// near one's.
    #[cold]
    #[inline(never)]
    pub(super) fn turn_to_rest(&mut self, dt: f32) -> bool {
        if self.sensing.zero_raw_m.is_none() {
            return false;
        }
        if self.faults.contains(Fault::RotationSync) {
            self.safe.rest = RestTurn::Done;
        }
        let phase = turn_phase(self.rotary.reference_rad);
        if self.safe.rest == RestTurn::Unplanned {
            let g = &self.config.port_geometry;
            let margin = 1.5 * g.ramp_rad;
            let near_a = self.status.position_m < 0.5 * self.config.supervisor.travel_m;
            let intake = if near_a { &g.intake_a } else { &g.intake_b };
            let via = turn_phase(intake.close_rad - margin);
            let target = turn_phase(intake.close_rad + margin);
            // Already inside the intake's open part, before the via point: straight on.
            let from = intake.open_rad + g.ramp_rad;
            self.safe.rest = if turn_phase(phase - from) <= turn_phase(via - from) {
                RestTurn::Final { target }
            } else {
                RestTurn::Via { via, target }
            };
        }
        let step = VENT_SPEED_RAD_S * dt;
        match self.safe.rest {
            RestTurn::Via { via, target } => {
                let d = turn_phase(via - phase + PI) - PI;
                self.rotary.reference_rad += clamp_f32(d, -step, step);
                if d.abs() <= step {
                    self.safe.rest = RestTurn::Final { target };
                }
                false
            }
            RestTurn::Final { target } => {
                // Forward only (the chamber is vented on the way to its intake's closing).
                let left = turn_phase(target - phase);
                self.rotary.reference_rad += min_f32(left, step);
                if left <= step {
                    self.safe.rest = RestTurn::Done;
                }
                false
            }
            RestTurn::Unplanned | RestTurn::Done => true,
        }
    }

    /// After a watchdog reset: counts the cycles until the velocity estimate is valid, then
    /// starts the controlled stop (see [`ControlStep::boot`]).
    #[cold]
    #[inline(never)]
    pub(super) fn brake_after_reset(&mut self) {
        let left = match self.safe.brake {
            FaultedBrake::AfterReset(n) => n,
            _ => 0,
        };
        if left > 0 {
            self.safe.brake = FaultedBrake::AfterReset(left - 1);
            return;
        }
        self.safe.brake = FaultedBrake::None;
        if self.faults.contains(Fault::EncoderSignal)
            || self.faults.contains(Fault::EncoderMismatch)
        {
            return;
        }
        let first = self
            .sensing
            .differentiator
            .restart_on_line(RESET_FIT_SAMPLES);
        self.safe.hold_quiet_s = 0.0;
        self.safe.hold_motor_ns = 0.0;
        self.safe.hold_gas_ns = 0.0;
        self.safe.rest = RestTurn::Unplanned;
        self.safe.stop_decel_mps2 = self.stop_deceleration(self.status.position_m, 0.0);
        // (NaN: not above the threshold, the planned stop.)
        if first.velocity_mps.abs() > RESET_ZEROING_MPS {
            self.safe.brake = FaultedBrake::Zeroing(if first.velocity_mps > 0.0 { 1 } else { -1 });
        }
        self.estimator.stop_n = 0.0;
        self.mode = Mode::Stopping {
            setpoint: Setpoint {
                position_m: self.status.position_m,
                velocity_mps: first.velocity_mps,
                acceleration_mps2: 0.0,
            },
            then: AfterStop::Off,
        };
    }

    /// The setpoint of a controlled stop's cycle: `planned` (the stop's plan, advanced this
    /// cycle) with the force the model does not know cancelled through the feed-forward (an
    /// external load, the gas of a chamber whose sensor failed: the position loop alone
    /// would yield 4 mm to 3 kN, near a head too much; [`observe_stop`](super::estimate::Estimator::observe_stop)) — or,
    /// after a watchdog reset while the piston still moves ([`FaultedBrake::Zeroing`]), full
    /// force against the measured velocity until it is about to be zero, then the hold
    /// where the piston is. Out of line, in place of the observer's own call: a guarded arm
    /// in the mode machine cost the running step 10 instructions.
    ///
    /// Why: after the reset the sections' force rises from zero at the windings'
    /// slew (`V_dc/√3 / L · K_f`, ≈ 215 N per cycle per section), while a stop planned on
    /// the full deceleration is over within a few cycles: at a dead point as an expander (0.21 m/s,
    /// 0.4 mm from the head; `docs/firmware.md`, "The fault sweep") the planned reference had ended
    /// at 1.3 kN per section with the piston still at full speed, and the hold that followed (a
    /// 40 Hz position loop, ≈ 0.6 kN at 0.12 m/s) let it creep a further 0.12 mm. Here the setpoint
    /// follows the measured position and velocity (no feedback to fight) with the stop's full
    /// deceleration as feed-forward, so the force keeps rising until the piston has stopped.
    ///
    /// When it ends: the force, once no longer commanded, falls at the same slew, and
    /// meanwhile still brakes: each section's `Fᵢ` takes `Fᵢ²/(2·slew)` of momentum more.
    /// The phase ends once the measured velocity is down to what that takes (the sections'
    /// shares by their capability); a non-finite velocity ends it too. The velocity estimate
    /// lags the braking (its window was refilled with the first velocity's line), so the
    /// phase ends late and the piston springs back at up to its approach speed, away from
    /// the head it approached. The hold target is the measured position there, near where
    /// the piston came to rest (not where a plan ended, behind it), and the hold continues
    /// ([`ControlStep::turn_to_rest`]).
    #[cold]
    #[inline(never)]
    pub(super) fn stop_setpoint(
        &mut self,
        planned: Setpoint,
        s: &Sensed,
        measured_force_n: f32,
        dt: f32,
    ) -> Setpoint {
        let mut sp = match self.safe.brake {
            FaultedBrake::Zeroing(sign) => self.zero_velocity(f32::from(sign), s, measured_force_n),
            _ => planned,
        };
        sp.acceleration_mps2 -= self.estimator.observe_stop(
            &self.config,
            &self.status,
            self.sensing.pressures.usable(),
            measured_force_n,
            dt,
        ) / self.config.moving_mass_kg;
        sp
    }

    /// A cycle of [`FaultedBrake::Zeroing`] against the measured velocity of direction
    /// `sign` ([`ControlStep::stop_setpoint`]): the setpoint, also left as the stop's state.
    fn zero_velocity(&mut self, sign: f32, s: &Sensed, measured_force_n: f32) -> Setpoint {
        let c = &self.config;
        let v = s.derivatives.velocity_mps;
        let (cm, cs) = (
            clamp_f32(c.allocation.capability.master, 0.0, 1.0),
            clamp_f32(c.allocation.capability.slave, 0.0, 1.0),
        );
        let total = cm + cs;
        // Σ Fᵢ² = F² · Σcᵢ²/(Σcᵢ)² with the force split by capability.
        let spread = if total > 0.0 {
            (cm * cm + cs * cs) / (total * total)
        } else {
            1.0
        };
        let m = &c.motor;
        let slew_n_per_s = m.voltage_limit_v() / m.inductance_h * m.force_constant_n_per_a;
        let braking_n = max_f32(-sign * measured_force_n, 0.0);
        let still_lost_mps =
            braking_n * braking_n * spread / (2.0 * slew_n_per_s * c.moving_mass_kg);
        let mut sp = Setpoint {
            position_m: s.position_m,
            velocity_mps: v,
            acceleration_mps2: -sign * self.safe.stop_decel_mps2,
        };
        // (A NaN velocity: not moving, ends.)
        let moving = sign * v > still_lost_mps;
        if !moving {
            self.safe.brake = FaultedBrake::None;
            sp = Setpoint::at_rest(s.position_m);
        }
        if let Mode::Stopping { setpoint, .. } = &mut self.mode {
            *setpoint = sp;
        }
        sp
    }
}

/// The park's turn of the rotation to a phase where both chambers vent (the rotary state
/// it moves, the port geometry as an argument).
impl RotaryAxis {
    /// The nearest phase where both chambers breathe
    /// ([`crate::physics::port_timing::PortGeometry::venting_phases_rad`]), as a turn of the
    /// rotation from the current reference, rad in [−π, π); `None` for a geometry without one.
    fn vent_turn_rad(&self, geometry: &PortGeometry<f32>) -> Option<f32> {
        let phase = turn_phase(self.reference_rad);
        geometry
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

#[cfg(test)]
mod tests {
    use super::*;

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
