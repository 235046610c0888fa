//! The safe state: the reaction stage — the latched faults and the sections in service, which
//! a [`Trip`] changes — and the state of the stops every reaction ends in, which the mode
//! machine (`modes.rs`) runs: SS1's controlled stop and the hold that ends it (with its turn
//! of the rotation to rest), braking without position after both encoders were lost, and
//! braking after a watchdog reset. What each fault asks for is data
//! ([`Fault::reaction`](crate::safety::faults::Fault::reaction), [`Trip`]); the step carries
//! it out in one place (`ControlStep::react`).

use super::estimate::StopObserver;
use super::publish::Previous;
use super::rotate::VENT_SPEED_RAD_S;
use super::sense::Sensed;
use crate::angle::{wrap_rad_cold, wrap_signed_rad_cold};
use crate::control::config::ControlConfig;
use crate::drive::allocation::Split;
use crate::motion::trajectory::Setpoint;
use crate::real::{clamp_f32, max_f32, min_f32};
use crate::safety::faults::{Fault, FaultSet, Trip};
use crate::units::PerSection;
use core::f32::consts::{FRAC_PI_2, TAU};

/// Samples the first velocity after a watchdog reset is fitted to (a straight line through
/// them, [`SavitzkyGolay::restart_on_line`](crate::sensing::differentiator::SavitzkyGolay::restart_on_line)),
/// the outputs off meanwhile: 0.25 ms after the first sample instead of the differentiator's
/// full window (25 samples and 5 to settle, 1.5 ms), which an expander braking into a dead
/// point alone cannot spare. Its noise with the encoders' σ ≈ 1 µm: ≈ 5 mm/s (0.24·σ/T), and
/// under the gas's push with the outputs off (≤ 2.5 kN on 12 kg) a lag of ≤ 26 mm/s; the
/// controlled stop's loop takes over from there.
pub const RESET_FIT_SAMPLES: usize = 6;

/// The first velocity after a watchdog reset above which the stop brakes at full force until
/// the measured velocity is zero ([`Stop::setpoint`]), m/s: ten times the first velocity's
/// noise (≈ 5 mm/s) and twice its lag under the gas's push (≤ 26 mm/s), so a piston at rest
/// (a hang at a dead point's rest) is stopped and held as before.
pub const RESET_ZEROING_MPS: f32 = 0.05;

/// The reaction stage's state: the latched faults and each section's capability in service
/// (the configured one, or 0 once a trip has taken the section out).
#[derive(Clone, Debug)]
#[repr(C)]
pub(super) struct SafeState {
    /// Each section's capability in the allocation, within [0, 1] (0: out of service).
    /// Changed only through [`SafeState::latch`] and [`SafeState::clear`], which keep
    /// `switching` and `split` with it.
    pub in_service: PerSection<f32>,
    /// The sections with a capability above 0, whose bridges switch while the outputs are
    /// on: kept where `in_service` changes, not compared every cycle.
    switching: PerSection<bool>,
    /// The total force's split over the sections in service, likewise kept.
    pub split: Split,
    /// The force one nominal section can deliver, N (the configuration's).
    section_limit_n: f32,
    /// The latched faults.
    pub faults: FaultSet,
    /// Sections whose bridge the hardware over-current trip switched off (their timer's
    /// break input), until the fault is cleared and the trip re-armed
    /// ([`SafeState::hardware_trip`]).
    pub tripped: PerSection<bool>,
}

impl SafeState {
    pub(super) fn new(config: &ControlConfig) -> Self {
        SafeState {
            in_service: config.allocation.capability,
            switching: switching(config.allocation.capability),
            split: Split::of(
                config.allocation.section_limit_n,
                config.allocation.capability,
            ),
            section_limit_n: config.allocation.section_limit_n,
            faults: FaultSet::new(),
            tripped: PerSection {
                master: false,
                slave: false,
            },
        }
    }

    /// The reaction's own part of `trip`: the sections it names taken out of service, its
    /// fault latched. True when the fault was not latched before.
    pub(super) fn latch(&mut self, trip: &Trip) -> bool {
        if trip.drop.master {
            self.in_service.master = 0.0;
        }
        if trip.drop.slave {
            self.in_service.slave = 0.0;
        }
        self.switching = switching(self.in_service);
        self.split = Split::of(self.section_limit_n, self.in_service);
        self.faults.latch(trip.fault)
    }

    /// Faults cleared: every section back in service at its configured capability.
    pub(super) fn clear(&mut self, config: &ControlConfig) {
        self.in_service = config.allocation.capability;
        self.switching = switching(self.in_service);
        self.section_limit_n = config.allocation.section_limit_n;
        self.split = Split::of(self.section_limit_n, self.in_service);
        self.faults.clear();
    }

    /// Whether a hardware over-current trip is latched.
    #[inline(always)]
    pub(super) fn trip_latched(&self) -> bool {
        self.tripped.master || self.tripped.slave
    }

    /// The bridges' hardware over-current trip: `now` is which sections' timers show a break
    /// (their BIF). The sections tripped anew are remembered and named in the returned
    /// [`Fault::Overcurrent`] trip (its reaction takes them out of service); `None` when
    /// none is new.
    pub(super) fn hardware_trip(&mut self, now: PerSection<bool>) -> Option<Trip> {
        let new = PerSection {
            master: now.master && !self.tripped.master,
            slave: now.slave && !self.tripped.slave,
        };
        if !(new.master || new.slave) {
            return None;
        }
        self.tripped.master |= new.master;
        self.tripped.slave |= new.slave;
        Some(Trip {
            drop: new,
            ..Trip::of(Fault::Overcurrent)
        })
    }

    /// The sections whose hardware trip may be re-armed: all those tripped once
    /// [`Fault::Overcurrent`] is cleared (then forgotten here), none while it stays latched.
    pub(super) fn rearm(&mut self) -> PerSection<bool> {
        if self.faults.contains(Fault::Overcurrent) {
            return PerSection::default();
        }
        core::mem::take(&mut self.tripped)
    }

    /// The sections whose bridges switch while the outputs are on.
    #[inline(always)]
    pub(super) fn sections_in_service(&self) -> PerSection<bool> {
        self.switching
    }
}

/// The sections whose capability `in_service` is above 0.
fn switching(in_service: PerSection<f32>) -> PerSection<bool> {
    PerSection {
        master: in_service.master > 0.0,
        slave: in_service.slave > 0.0,
    }
}

/// The state of the stops: the controlled stop's deceleration and disturbance observer, SS1's
/// hold window and rest turn, and what the faulted state still does with the outputs.
#[derive(Clone, Debug)]
#[repr(C)]
pub(super) struct Stop {
    /// Deceleration of the controlled stop in progress, m/s².
    pub decel_mps2: f32,
    /// The stop's disturbance observer.
    pub observer: StopObserver,
    /// SS1's hold: time into the current averaging window, s, and the integrals over it of
    /// the motor force and of the measured gas force, N·s.
    pub hold_s: f32,
    pub hold_motor_ns: f32,
    pub hold_gas_ns: f32,
    /// SS1's rest turn before the outputs go off ([`Stop::rest_turn`]).
    pub rest: RestTurn,
    /// What the faulted state still does with the outputs: brake after a watchdog reset, or
    /// brake without position after both encoders were lost.
    pub brake: FaultedBrake,
}

/// SS1's turn of the rotation, the piston held at rest, to the phase the outputs go off at
/// ([`Stop::rest_turn`]); phases in rad, [0, 2π).
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

/// The blind brake's turn of the rotation to seal a chamber: the phase to turn to, rad in
/// [0, 2π), and the turn as decided from where the rotation was, rad (signed: which way
/// round).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct SealingTurn {
    pub phase_rad: f32,
    pub turn_rad: f32,
}

/// What the faulted state still does with the outputs (they are off otherwise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum FaultedBrake {
    /// Nothing.
    None,
    /// After a watchdog reset: cycles until the velocity estimate is valid, then a controlled
    /// stop in the encoders' own frame (`ControlStep::boot`).
    AfterReset(u16),
    /// Both encoders lost ([`Stop::brake_without_position`]): cycles of outputs off left
    /// before the windings are short-circuited (0: shorted), and the rotation's sealing turn
    /// until it is sent on it.
    Blind {
        cycles: u16,
        seal: Option<SealingTurn>,
    },
    /// After a watchdog reset, the stop braking at full force against the measured velocity
    /// until it is zero (its direction, +1 or −1; [`Stop::setpoint`]): the continuation of
    /// the brake after the reset.
    Zeroing(i16),
}

impl Stop {
    pub(super) fn new(config: &ControlConfig) -> Self {
        Stop {
            decel_mps2: config.supervisor.brake_deceleration_mps2(),
            observer: StopObserver::new(),
            hold_s: 0.0,
            hold_motor_ns: 0.0,
            hold_gas_ns: 0.0,
            rest: RestTurn::Unplanned,
            brake: FaultedBrake::None,
        }
    }

    /// A stop (re)starts: SS1's hold window and rest turn start afresh.
    pub(super) fn restart_hold(&mut self) {
        self.hold_s = 0.0;
        self.hold_motor_ns = 0.0;
        self.hold_gas_ns = 0.0;
        self.rest = RestTurn::Unplanned;
    }

    /// A controlled stop starts at `decel_mps2`: the hold window, the rest turn and the
    /// observer start afresh.
    pub(super) fn restart(&mut self, decel_mps2: f32) {
        self.restart_hold();
        self.decel_mps2 = decel_mps2;
        self.observer.n = 0.0;
    }

    /// Whether the outputs are the blind brake's short circuit now (equal duties, zero
    /// voltage on every phase).
    #[inline(always)]
    pub(super) fn shorted(&self) -> bool {
        matches!(self.brake, FaultedBrake::Blind { cycles: 0, .. })
    }

    /// After a watchdog reset: the outputs stay off for the [`RESET_FIT_SAMPLES`] the first
    /// velocity is fitted to, then the controlled stop starts (`ControlStep::boot`).
    pub(super) fn await_velocity_then_brake(&mut self) {
        self.brake = FaultedBrake::AfterReset((RESET_FIT_SAMPLES - 1) as u16);
    }

    /// Both encoders lost or the supply lost (`docs/faults.md` #22, #24): nothing tells
    /// where the piston is, so nothing can commutate a braking force. The reaction, chosen
    /// by simulation over the whole stroke cycle (`docs/firmware.md`, "Both encoders lost"):
    ///
    /// 1. Outputs off (STO) while the winding currents decay into the bus (`L·I_max/V_bus`,
    ///    0.7 ms): shorted at once, a current that was holding the piston against the gas
    ///    would go on pulling it for the windings' `L/R` (10 ms).
    /// 2. Then the windings short-circuited (all six low-side switches on): the back-EMF
    ///    drives braking currents through the windings' resistance, up to ~2.7 kN for both
    ///    sections near 0.4 m/s, ~0.5 kN at 4.1 m/s — a strong damper at low speed.
    /// 3. The rotation, whose own encoder is still good, turns to the nearest phase where
    ///    both ports of the chamber ahead (by the last trusted velocity, `velocity_mps`) are
    ///    closed, a ramp inside its sealed arc, and holds there: that chamber becomes a gas
    ///    spring that takes the piston's kinetic energy, and the short circuit damps the
    ///    rebound. A coasting rotation would open the chamber ahead to its intake, or hold it
    ///    on the discharge line. Except near a dead point, the chamber ahead already
    ///    discharging: the line's pressure turns the piston there, and the turn back to seal
    ///    that chamber (against the rotation's own speed) would leave it on the line through
    ///    the rebound. Then the other chamber, ahead after the turn, is sealed: forward, the
    ///    way the rotation already goes, past the dead-point phase where the discharge
    ///    closes.
    ///
    ///    Which way round: the turn that holds the chamber *behind* on its discharge port
    ///    for the least time (at full servo torque from the rotation's speed now,
    ///    `speed_rad_s`: against it, the rotation must stop first), and of those the
    ///    shortest. As a compressor no turn crosses that port, and this is the shortest
    ///    turn. As an expander the rotation runs backwards and the chamber behind is
    ///    admitting from the line: the shorter turn can go back through its admission, the
    ///    line driving the piston into the head; the turn the way the rotation runs cuts the
    ///    admission off.
    ///
    ///    The chamber behind still on its line at the loss (as an expander: its admission,
    ///    the stroke just begun) also counts the time the turn spends in the *sealed*
    ///    chamber's own admission window: reached through that window, the sealed chamber
    ///    would hold the line's gas in a long column, which after taking the piston's energy
    ///    expands back to suction over PR^(1/γ) = 2.2–3.2 times its volume, beyond the other
    ///    head. Later in the stroke the chamber ahead is short when sealed, and the turn away
    ///    from the admission would put the line behind the piston for a whole window: there
    ///    only the chamber behind counts.
    ///
    /// `reference_rad` is the rotation's reference now. Once the brake runs, a second loss
    /// changes nothing.
    #[cold]
    #[inline(never)]
    pub(super) fn brake_without_position(
        &mut self,
        c: &ControlConfig,
        reference_rad: f32,
        speed_rad_s: f32,
        velocity_mps: f32,
    ) {
        if matches!(self.brake, FaultedBrake::Blind { .. }) {
            return;
        }
        let g = &c.port_geometry;
        let phase = wrap_rad_cold(reference_rad);
        let toward_b = velocity_mps >= 0.0;
        // The chamber ahead already discharging: the line turns the piston before its dead
        // point; the chamber to seal is the other one, ahead after the turn (see above).
        let ahead = if toward_b {
            &g.discharge_b
        } else {
            &g.discharge_a
        };
        let discharging = ahead.contains(phase);
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
        // Of the turns to either end of either sealed arc (0 inside one), the one that holds
        // the behind chamber on the line for the least time — the rotation going at full
        // torque from its speed now (against it, it must stop first) — and of those the
        // shortest.
        let behind_on_line = behind.contains(phase);
        let sc = &c.servo;
        let accel = max_f32(sc.torque_full_scale_nm / sc.inertia_kgm2, 1.0);
        let mut best: Option<(f32, f32)> = None;
        for arc in g.sealed_arcs(intake, discharge).into_iter().flatten() {
            let into = arc.past_start(phase);
            // Inside the arc: no turn; outside: back to its far end or on to its near one.
            let turns = if into <= arc.span_rad {
                [0.0, 0.0]
            } else {
                [arc.span_rad - into, TAU - into]
            };
            for turn in turns {
                let mut exposed = behind.time_in_turn(phase, turn, speed_rad_s, accel);
                if behind_on_line && !discharging {
                    exposed += discharge.time_in_turn(phase, turn, speed_rad_s, accel);
                }
                best = match best {
                    Some((e, b)) if (e, b.abs()) <= (exposed, turn.abs()) => Some((e, b)),
                    _ => Some((exposed, turn)),
                };
            }
        }
        let m = &c.motor;
        let decay_s = m.inductance_h * m.current_limit_a / m.bus_voltage_v;
        let cycles = clamp_f32(decay_s / c.sample_time_s + 1.0, 1.0, 1000.0) as u16;
        // The phase to turn to once the windings are shorted.
        let turn = best.map_or(0.0, |(_, turn)| turn);
        self.brake = FaultedBrake::Blind {
            cycles,
            seal: Some(SealingTurn {
                phase_rad: wrap_rad_cold(phase + turn),
                turn_rad: turn,
            }),
        };
    }

    /// A cycle of the faulted state: nothing while no brake runs ([`FaultedBrake::None`]);
    /// after both encoders were lost, the countdown to the short circuit, and at its end the
    /// rotation's reference (`reference_rad`) sent to the sealing phase, once; after a
    /// watchdog reset, the wait for the velocity estimate. True when that wait is over: the
    /// caller starts the stop ([`Stop::start_after_reset`]).
    #[cold]
    #[inline(never)]
    pub(super) fn faulted_cycle(&mut self, reference_rad: &mut f32) -> bool {
        match self.brake {
            FaultedBrake::None | FaultedBrake::Zeroing(_) => false,
            FaultedBrake::AfterReset(left) => {
                if left > 0 {
                    self.brake = FaultedBrake::AfterReset(left - 1);
                    return false;
                }
                self.brake = FaultedBrake::None;
                true
            }
            FaultedBrake::Blind { cycles, seal } => {
                let mut seal = seal;
                if let Some(decided) = seal.filter(|_| cycles <= 1) {
                    seal = None;
                    // From where the rotation has coasted, the way round decided: a turn of
                    // about half a revolution is otherwise taken the other way once the
                    // coast has made that way the shorter (across the admission the turn
                    // was chosen to avoid). A short turn goes the shorter way, so a coast
                    // past a target close by comes back to it.
                    let now = wrap_rad_cold(*reference_rad);
                    let mut turn = wrap_signed_rad_cold(decided.phase_rad - now);
                    if decided.turn_rad < -FRAC_PI_2 && turn > 0.0 {
                        turn -= TAU;
                    } else if decided.turn_rad > FRAC_PI_2 && turn < 0.0 {
                        turn += TAU;
                    }
                    *reference_rad += turn;
                }
                self.brake = FaultedBrake::Blind {
                    cycles: cycles.saturating_sub(1),
                    seal,
                };
                false
            }
        }
    }

    /// The controlled stop after a watchdog reset, once the first velocity is known
    /// (`first_velocity_mps`, fitted to the first samples) at `position_m`: on
    /// `decel_mps2`; above [`RESET_ZEROING_MPS`] braking at full force against the measured
    /// velocity until it is zero ([`FaultedBrake::Zeroing`]). Returns the stop's first
    /// setpoint.
    #[cold]
    #[inline(never)]
    pub(super) fn start_after_reset(
        &mut self,
        decel_mps2: f32,
        position_m: f32,
        first_velocity_mps: f32,
    ) -> Setpoint {
        self.restart_hold();
        self.decel_mps2 = decel_mps2;
        // (NaN: not above the threshold, the planned stop.)
        if first_velocity_mps.abs() > RESET_ZEROING_MPS {
            self.brake = FaultedBrake::Zeroing(if first_velocity_mps > 0.0 { 1 } else { -1 });
        }
        self.observer.n = 0.0;
        Setpoint {
            position_m,
            velocity_mps: first_velocity_mps,
            acceleration_mps2: 0.0,
        }
    }

    /// SS1's rest turn: before the outputs go off, the rotation — the piston held at rest by
    /// the sections — turns to the phase where the chamber between the piston and the nearer
    /// head has just been vented to its intake and sealed, and the other chamber is open to
    /// its intake. Moves `reference_rad` (the rotation's reference) by at most
    /// [`VENT_SPEED_RAD_S`]·`dt`; returns whether the rotation is there (the hold may end).
    ///
    /// Why: with the outputs off nothing but the gas holds the piston. A chamber open to a
    /// line pushes with a constant pressure; a sealed one is a gas spring, stiff in
    /// proportion to 1/(its gas column). Left with the *far* chamber sealed above the near
    /// one's line, the piston drifts until the far chamber has expanded to the line's
    /// pressure, into the head. Left with the near chamber sealed at a line's discharge
    /// pressure, its gas throws the piston across the stroke. Sealed at the suction pressure
    /// with the far chamber at suction too, no pressure difference pushes the piston either
    /// way, and a push toward the near head compresses a column of a few millimetres: it
    /// stops within a fraction of one.
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
    /// No turn with the rotation itself faulted (`rotation_faulted`): the hold then ends on
    /// the force criterion alone. Not `homed` (after a watchdog reset: SS1 needs the zero)
    /// neither the heads' distance nor the rotation's phase is known, so no turn can be
    /// chosen and nothing says the gas will leave the piston still once the outputs are off:
    /// the hold continues (never `true`) until the faults are cleared.
    #[cold]
    #[inline(never)]
    pub(super) fn rest_turn(
        &mut self,
        c: &ControlConfig,
        reference_rad: &mut f32,
        position_m: f32,
        homed: bool,
        rotation_faulted: bool,
        dt: f32,
    ) -> bool {
        if !homed {
            return false;
        }
        if rotation_faulted {
            self.rest = RestTurn::Done;
        }
        let phase = wrap_rad_cold(*reference_rad);
        if self.rest == RestTurn::Unplanned {
            let g = &c.port_geometry;
            let margin = 1.5 * g.ramp_rad;
            let near_a = position_m < 0.5 * c.supervisor.travel_m;
            let intake = if near_a { &g.intake_a } else { &g.intake_b };
            let via = wrap_rad_cold(intake.close_rad - margin);
            let target = wrap_rad_cold(intake.close_rad + margin);
            // Already inside the intake's open part, before the via point: straight on.
            let from = intake.open_rad + g.ramp_rad;
            self.rest = if wrap_rad_cold(phase - from) <= wrap_rad_cold(via - from) {
                RestTurn::Final { target }
            } else {
                RestTurn::Via { via, target }
            };
        }
        let step = VENT_SPEED_RAD_S * dt;
        match self.rest {
            RestTurn::Via { via, target } => {
                let d = wrap_signed_rad_cold(via - phase);
                *reference_rad += clamp_f32(d, -step, step);
                if d.abs() <= step {
                    self.rest = RestTurn::Final { target };
                }
                false
            }
            RestTurn::Final { target } => {
                // Forward only (the chamber is vented on the way to its intake's closing).
                let left = wrap_rad_cold(target - phase);
                *reference_rad += min_f32(left, step);
                if left <= step {
                    self.rest = RestTurn::Done;
                }
                false
            }
            RestTurn::Unplanned | RestTurn::Done => true,
        }
    }

    /// SS1's end: the piston is at rest and held; the outputs go off only once, averaged
    /// over [`HOLD_RELEASE_S`] (the damping term's velocity noise averages out), holding it
    /// needs no more than the static friction and the measured gas force is below half of
    /// it, so friction alone keeps it still. Released earlier, the gas of a compressed
    /// chamber (or an external load) would throw the piston into a head with nothing to stop
    /// it. Until then it stays held, and a new window starts. `previous` gives the last
    /// cycle's force command and chamber pressures (used while `pressures_usable`).
    #[cold]
    #[inline(never)]
    pub(super) fn hold_released(
        &mut self,
        c: &ControlConfig,
        previous: &Previous,
        pressures_usable: bool,
        dt: f32,
    ) -> bool {
        let gas_n = if pressures_usable {
            c.cylinder
                .gas_force_n(previous.pressure_a_pa, previous.pressure_b_pa)
        } else {
            0.0
        };
        self.hold_s += dt;
        self.hold_motor_ns += previous.force_command_n * dt;
        self.hold_gas_ns += gas_n * dt;
        if self.hold_s < HOLD_RELEASE_S {
            return false;
        }
        let window = self.hold_s;
        let (motor, gas) = (self.hold_motor_ns / window, self.hold_gas_ns / window);
        self.hold_s = 0.0;
        self.hold_motor_ns = 0.0;
        self.hold_gas_ns = 0.0;
        let stiction = c.friction.static_n;
        motor.abs() <= stiction && gas.abs() <= 0.5 * stiction
    }

    /// The setpoint of a controlled stop's cycle: `planned` (the stop's plan, advanced this
    /// cycle) with the force the model does not know cancelled through the feed-forward (an
    /// external load, the gas of a chamber whose sensor failed: the position loop alone
    /// would yield 4 mm to 3 kN, near a head too much; [`StopObserver::observe`]) — or,
    /// after a watchdog reset while the piston still moves ([`FaultedBrake::Zeroing`]), full
    /// force against the measured velocity until it is about to be zero, then the hold
    /// where the piston is (the second value true: the setpoint is the stop's new state).
    /// Out of line, in place of the observer's own call: a guarded arm in the mode machine
    /// costs the running step instructions.
    ///
    /// Why the zeroing: after the reset the sections' force rises from zero at the windings'
    /// slew (`V_dc/√3 / L · K_f`, ≈ 215 N per cycle per section), while a stop planned on
    /// the full deceleration is over within a few cycles, its reference ended with the piston
    /// still moving, and the hold that follows (a 40 Hz position loop) lets it creep on. Here
    /// the setpoint follows the measured position and velocity (no feedback to fight) with
    /// the stop's full deceleration as feed-forward, so the force keeps rising until the
    /// piston has stopped.
    ///
    /// When it ends: the force, once no longer commanded, falls at the same slew, and
    /// meanwhile still brakes: each section's `Fᵢ` takes `Fᵢ²/(2·slew)` of momentum more.
    /// The phase ends once the measured velocity is down to what that takes (the sections'
    /// shares by their capability in service, `in_service`); a non-finite velocity ends it
    /// too. The velocity estimate lags the braking (its window was refilled with the first
    /// velocity's line), so the phase ends late and the piston springs back at up to its
    /// approach speed, away from the head it approached. The hold target is the measured
    /// position there, near where the piston came to rest (not where a plan ended, behind
    /// it), and the hold continues ([`Stop::rest_turn`]).
    #[cold]
    #[inline(never)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn setpoint(
        &mut self,
        c: &ControlConfig,
        planned: Setpoint,
        s: &Sensed,
        previous: &Previous,
        pressures_usable: bool,
        in_service: PerSection<f32>,
        measured_force_n: f32,
        dt: f32,
    ) -> (Setpoint, bool) {
        let (mut sp, zeroing) = match self.brake {
            FaultedBrake::Zeroing(sign) => (
                self.zero_velocity(c, f32::from(sign), s, in_service, measured_force_n),
                true,
            ),
            _ => (planned, false),
        };
        sp.acceleration_mps2 -=
            self.observer
                .observe(c, previous, pressures_usable, measured_force_n, dt)
                / c.moving_mass_kg;
        (sp, zeroing)
    }

    /// A cycle of [`FaultedBrake::Zeroing`] against the measured velocity of direction
    /// `sign` ([`Stop::setpoint`]).
    fn zero_velocity(
        &mut self,
        c: &ControlConfig,
        sign: f32,
        s: &Sensed,
        in_service: PerSection<f32>,
        measured_force_n: f32,
    ) -> Setpoint {
        let v = s.derivatives.velocity_mps;
        let (cm, cs) = (
            clamp_f32(in_service.master, 0.0, 1.0),
            clamp_f32(in_service.slave, 0.0, 1.0),
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
        let sp = Setpoint {
            position_m: s.position_m,
            velocity_mps: v,
            acceleration_mps2: -sign * self.decel_mps2,
        };
        // (A NaN velocity: not moving, ends.)
        let moving = sign * v > still_lost_mps;
        if moving {
            sp
        } else {
            self.brake = FaultedBrake::None;
            Setpoint::at_rest(s.position_m)
        }
    }
}

/// The window over which holding the stopped piston must need (almost) no force before SS1
/// switches the outputs off, s: 50 ms, ten times the force's settling after the stop ramp.
pub const HOLD_RELEASE_S: f32 = 0.05;

/// The deceleration of a controlled stop from `velocity_mps` at `position_m`: the braking
/// envelope's `a_brake`, or more when the piston is closer to the head it moves toward than
/// that needs (a disturbance pushed it past the envelope, which is what tripped): enough to
/// stop 1 mm short of the minimum clearance with 25 % in hand, up to the most the sections in
/// service (`in_service`) guarantee. Not `homed` (after a watchdog reset) the heads' distance
/// is unknown: that most.
///
/// The most: `a_brake` per healthy section (what one section alone guarantees), or, when
/// larger, the healthy sections' peak force less the largest push the gas can give toward
/// the head — one chamber on the discharge line, the other at suction, by the last line
/// pressures (`last_pa`: chamber A, B, suction, discharge, Pa) — over the moving mass
/// (PR 5.1: 10 kN − 2.5 kN, 625 m/s²; one section 210 m/s²). As a compressor the chamber
/// ahead is a gas spring that helps; as an expander it exhausts near the dead point and the
/// sections brake the piston alone, on the envelope's edge: a section lost there, or a
/// control task hung there for the watchdog's 5 ms, leaves the piston past what `a_brake`
/// stops.
pub(super) fn stop_deceleration(
    config: &ControlConfig,
    in_service: PerSection<f32>,
    last_pa: &[f32; 4],
    homed: bool,
    position_m: f32,
    velocity_mps: f32,
) -> f32 {
    let c = &config.supervisor;
    let sections = clamp_f32(in_service.master, 0.0, 1.0) + clamp_f32(in_service.slave, 0.0, 1.0);
    let mut a_max = c.brake_deceleration_mps2() * max_f32(sections, 1.0);
    let [_, _, suction, discharge] = *last_pa;
    // (Arguments in this order: a NaN pressure gives a NaN push.)
    let gas_n = max_f32(0.0, discharge - suction) * config.cylinder.area_m2;
    let a_force = (config.allocation.section_limit_n * sections - gas_n) / config.moving_mass_kg;
    // (NaN — no line pressure yet — keeps `a_brake` per section.)
    if a_force > a_max {
        a_max = a_force;
    }
    if !homed {
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
    clamp_f32(needed, c.brake_deceleration_mps2(), a_max)
}
