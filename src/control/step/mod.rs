//! The 20 kHz control step of the linear axis and the rotation, as a pure function of its
//! inputs.
//!
//! [`ControlStep::step`] takes one burst of samples (encoders, phase currents, quadrature
//! count, pressures, the sampling instant) and returns the outputs (six PWM duties or
//! "outputs off", the servo torque code). It reads no clock and touches no hardware, so the
//! firmware's control task, the simulator and the benchmarks all call the same code.
//!
//! The step is a pipeline of stages, written out once in [`ControlStep::step`]:
//!
//! sense → supervise → react → plan → drive → rotate → publish
//!
//! Each stage is a plain struct that owns its state (one field of [`ControlStep`]) and a
//! method that takes values and returns a value: `sense` ([`sense::Sensing`]: both encoders
//! decoded, the master position differentiated, the pressures converted and checked →
//! `Sensed`), `supervise` ([`supervise::Supervision`]: the machine's limits, the host's
//! heartbeat, the supply → a [`Trip`]), `react` ([`safe_state::SafeState`]: a trip's fault
//! latched and its sections taken out of service; the stop it starts is the plan's), `plan`
//! ([`modes::Plan`]: the mode machine, with the stops' own state → the setpoint), `drive`
//! ([`actuate::Drive`]: the position loop with model feed-forward `m·a + F_fr(v) − F_gas`,
//! the force split over the sections in service, both sections' current loops → duties),
//! `rotate` ([`rotate::RotaryAxis`]: the servo slaved to the measured stroke → the torque
//! command) and `publish` ([`publish::Publish`]: what the cycle leaves for the next,
//! [`publish::Previous`], and the status the outside reads). A calibration routine, when one
//! runs, takes the outputs after the rest (`calibrate`). A stage that must change another's
//! state gets it as an argument here, where every write is visible; host commands are
//! checked into a change (`commands`) that [`ControlStep::command`] applies. The
//! configuration changes only when a calibration is loaded.

mod absent;
mod actuate;
#[cfg(feature = "bench")]
mod bench;
mod calibrate;
mod commands;
mod estimate;
mod modes;
mod publish;
mod rotate;
mod safe_state;
mod sense;
mod supervise;

pub use estimate::DOB_TIME_S;
pub use safe_state::HOLD_RELEASE_S;

use crate::control::calibration::record::{CalibrationRecord, CalibrationStatus};
#[cfg(feature = "bench")]
use crate::control::calibration::report::RoutineReport;
use crate::control::calibration::store::LoadError;
use crate::control::calibration::{encoder_map, Calibrated, Demand, Outcome};
use crate::control::command::{Command, Parameter, Refusal};
use crate::control::config::{ConfigError, ControlConfig};
use crate::motion::stroke::DeadPoint;
use crate::motion::trajectory::Setpoint;
use crate::ports::{EncoderCodes, PhaseCurrentCodes, PressureCodes};
use crate::safety::faults::{Fault, Reaction, ResetCause, Trip};
use crate::safety::supervisor::{LimitFlags, Observation};
use crate::sensing::differentiator::{Derivatives, SavitzkyGolay, SgConfig};
use crate::sensing::encoder::{EncoderReading, PositionCounts, SinCosDecoder};
use crate::status::Status;
use crate::units::{DacCode, PerSection, PhaseDuties, Ticks, CONTROL_PERIOD_US};
use actuate::Drive;
use commands::{Change, MachineView};
use modes::{AfterStop, Mode, Plan, PlanInputs};
use publish::Publish;
use rotate::RotaryAxis;
use safe_state::SafeState;
use sense::{EncoderLoss, Sensed, Sensing};
use supervise::Supervision;

/// One burst of samples.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CycleInputs {
    /// Sampling instant.
    pub t: Ticks,
    /// Both encoders.
    pub encoders: EncoderCodes,
    /// Phase currents of both sections.
    pub currents: PerSection<PhaseCurrentCodes>,
    /// Servo quadrature counter.
    pub quadrature: u16,
    /// Pressures.
    pub pressures: PressureCodes,
}

/// The outputs of one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CycleOutputs {
    /// Duties of both sections, or `None`: all motor outputs off (safe torque off).
    pub pwm: Option<PerSection<PhaseDuties>>,
    /// While `pwm` is `Some`, the sections whose bridges switch: `false` for a section taken
    /// out of service (after an overcurrent, or with its encoder lost), whose six gates are
    /// then held low while the other section drives.
    pub sections: PerSection<bool>,
    /// Servo torque command.
    pub servo: DacCode,
}

/// The control step: the configuration and one field per stage, each with the state it owns.
///
/// `repr(C)`: the fields lie in the order written. What the running step reads and writes
/// field by field comes first, mostly within the ±1020-byte reach of the Cortex-M4's
/// `vldr`/`vstr` from `self`; the large state reached through a pointer (the decoders, the
/// differentiator's window, the current loops, the calibration's maps) lies after it
/// (`scripts/bench-cm4.sh` counts the difference).
#[derive(Clone, Debug)]
#[repr(C)]
pub struct ControlStep {
    /// The configuration: changed only by a calibration load.
    config: ControlConfig,
    publish: Publish,
    safe: SafeState,
    supervision: Supervision,
    rotary: RotaryAxis,
    drive: Drive,
    plan: Plan,
    sensing: Sensing,
}

impl ControlStep {
    /// Builds the step from a configuration, refusing invalid parameters.
    pub fn new(mut config: ControlConfig) -> Result<Self, ConfigError> {
        // The supervisor's geometry and speed limit follow the machine's, never disagree.
        config.supervisor.travel_m = config.travel_m;
        config.supervisor.overspeed_mps = 1.2 * config.max_speed_mps;
        config.check()?;
        let differentiator = SavitzkyGolay::new(SgConfig {
            window: config.sg_window,
            order: config.sg_order,
            lag: config.sg_lag,
            sample_time_s: config.sample_time_s,
            m_per_count: config.encoder_master.m_per_count(),
        })
        .map_err(ConfigError::Differentiator)?;
        Ok(ControlStep {
            publish: Publish::INIT,
            safe: SafeState::new(&config),
            supervision: Supervision::new(config.heartbeat_timeout_s),
            rotary: RotaryAxis::new(&config),
            plan: Plan::new(&config),
            sensing: Sensing::new(&config, differentiator),
            drive: Drive::new(&config),
            config,
        })
    }

    /// What the power-good input reads (the supervision task's last look, before each
    /// step): the supply lost latches [`Fault::SupplyLoss`], whose brake runs on the DC
    /// link's energy ([`Reaction::BrakeWithoutPosition`]: the short-circuited windings take
    /// the braking current, the link feeds only the gate drivers, the MCU and the servo's
    /// sealing turn). The fault cannot be cleared while the supply stays lost.
    #[inline]
    pub fn supply(&mut self, good: bool) {
        if self.supervision.supply(good) {
            self.supply_lost();
        }
    }

    /// Whether a hardware over-current trip is latched (the control cycle then calls
    /// [`ControlStep::hardware_trip`] each cycle; one load and a branch otherwise).
    #[inline]
    pub fn trip_latched(&self) -> bool {
        self.safe.trip_latched()
    }

    /// The bridges' hardware over-current trip (`docs/firmware.md`, "The hardware
    /// over-current trip"): `now` is which sections' timers show a break (their BIF), which
    /// switched their outputs off in hardware. A new one latches [`Fault::Overcurrent`] and
    /// takes that section out of service (the other brakes, as after a measured
    /// overcurrent). Returns the sections whose trip may be re-armed (their break flag
    /// cleared) because `ClearFaults` has cleared the fault; a break input still active then
    /// trips again at once.
    #[cold]
    #[inline(never)]
    pub fn hardware_trip(&mut self, now: PerSection<bool>) -> PerSection<bool> {
        match self.safe.hardware_trip(now) {
            Some(trip) => {
                self.react(trip);
                PerSection::default()
            }
            None => self.safe.rearm(),
        }
    }

    #[cold]
    #[inline(never)]
    fn supply_lost(&mut self) {
        if !self.safe.faults.contains(Fault::SupplyLoss) {
            self.react(Trip::of(Fault::SupplyLoss));
        }
    }

    /// Applies the cause of the last reset: after a watchdog reset the machine starts in
    /// the fault state (outputs off, restart inhibited until the fault is cleared).
    ///
    /// The piston may still be moving (a task hung at speed, the outputs held for up to the
    /// watchdog's timeout): once a straight line through the first
    /// [`RESET_FIT_SAMPLES`](safe_state::RESET_FIT_SAMPLES) samples gives its velocity (the
    /// differentiator's window is refilled with that line) the step brakes it in the
    /// encoders' own frame (the sin/cos angle commutates without the zero, the incremental
    /// position holds it): at full force until the measured velocity is zero, then held
    /// there. The hold does not end by itself (with neither the heads' distance nor the
    /// rotation's phase known, nothing says the gas will leave the piston still once the
    /// outputs are off): `ClearFaults` ends it, outputs off. Where the heads are is unknown
    /// until homing; the fault stays latched.
    pub fn boot(&mut self, cause: ResetCause) {
        if cause == ResetCause::Watchdog {
            // The piston may be moving: a part lost is a fault from the first cycle.
            self.supervision.energised = true;
            // Its reaction waits for the velocity, then brakes (`Reaction::BrakeAfterReset`).
            self.react(Trip::of(Fault::WatchdogReset));
            self.publish.faults = self.safe.faults;
            self.publish.mode = self.plan.mode_kind();
        }
    }

    /// Loads the calibration read from flash at boot (before the first step): the record's
    /// parameters go into the configuration, and the machine refuses `Start` unless every
    /// routine's result is there. Absent, corrupt or of another layout
    /// ([`CalibrationStatus::Missing`], [`CalibrationStatus::Invalid`]): the configuration's
    /// own values stay, `Home` and `Calibrate` are accepted, `Start` is refused until the
    /// routines have run.
    pub fn load_calibration(&mut self, loaded: Result<CalibrationRecord, LoadError>) {
        match loaded {
            Ok(record) => {
                record.apply(&mut self.config);
                // The decoders copy their sin/cos correction when built.
                self.sensing.encoders = PerSection {
                    master: SinCosDecoder::new(self.config.encoder_master),
                    slave: SinCosDecoder::new(
                        crate::control::calibration::encoder_map::slave_encoder(&self.config),
                    ),
                };
                self.plan.calibration.calibrated = record.calibrated;
                self.plan.calibration.status = record.status();
            }
            Err(e) => self.plan.calibration.status = e.status(),
        }
    }

    /// Loads a record written over the link (already checked: magic, version, CRC), as a
    /// boot load does, and marks it for the storage task. Only with the outputs off and no
    /// operation in progress (idle, else [`Refusal::Busy`]): the sin/cos decoders restart
    /// with the new correction, so the zero found by homing no longer holds and the machine
    /// must home again.
    pub fn load_calibration_from_link(&mut self, record: CalibrationRecord) -> Result<(), Refusal> {
        if !matches!(self.plan.mode, Mode::Idle) {
            return Err(Refusal::Busy);
        }
        self.load_calibration(Ok(record));
        self.sensing.zero_raw_m = None;
        self.plan.calibration.unsaved = true;
        Ok(())
    }

    /// The record of the calibration the controller runs on (what a read over the link
    /// returns).
    pub fn calibration_record(&self) -> CalibrationRecord {
        CalibrationRecord::of(&self.plan.calibration.calibrated, &self.config)
    }

    /// Whether the machine may `Start` on its calibration.
    pub fn calibration_status(&self) -> CalibrationStatus {
        self.plan.calibration.status
    }

    /// The record to save, once after each routine that succeeded (the control task hands
    /// it to the storage task; nothing of the save runs in the step).
    pub fn take_calibration_to_save(&mut self) -> Option<CalibrationRecord> {
        self.plan.calibration.take_to_save(&self.config)
    }

    /// The last routine's report, once after each change (a routine accepted or ended): the
    /// control task hands it to the command task, which answers the host's request for it.
    /// The bench build's (Cargo.toml, `bench`).
    #[cfg(feature = "bench")]
    pub fn take_routine_report(&mut self) -> Option<RoutineReport> {
        self.plan.calibration.take_report()
    }

    /// Whether the last routine's report changed since it was last taken (one load: the
    /// control cycle's test).
    #[cfg(feature = "bench")]
    #[inline(always)]
    pub fn routine_report_changed(&self) -> bool {
        self.plan.calibration.report_changed
    }

    /// The configuration in use.
    pub fn config(&self) -> &ControlConfig {
        &self.config
    }

    /// The snapshot of the last step.
    pub fn status(&self) -> Status {
        self.publish.status()
    }

    /// What the calibration routines have measured and loaded (and the last failure).
    pub fn calibrated(&self) -> &Calibrated {
        &self.plan.calibration.calibrated
    }

    /// The largest mean phase current seen with the outputs off, A, once enough samples
    /// were seen (the current-sense offset check).
    pub fn current_sense_residual_a(&self) -> Option<f32> {
        self.drive.sense_monitor.residual_a(&self.config)
    }

    /// The last dead point reached by the running strokes (target and reached, m).
    pub fn last_dead_point(&self) -> Option<DeadPoint> {
        self.plan.last_dead_point
    }

    /// One control cycle: the stages in the order the samples flow through them.
    ///
    /// sense (decode, differentiate, convert) → supervise (limits, faults, host watchdog) →
    /// react (each trip as it is found) → plan (the mode machine's setpoint) → drive
    /// (position loop, allocation, both sections' FOC) → rotate (servo, synchronised to the
    /// stroke) → publish (what the next cycle reads, the status). A calibration routine,
    /// when one runs, takes the outputs after the rest.
    pub fn step(&mut self, inputs: &CycleInputs) -> CycleOutputs {
        self.step_then(inputs, |_, _| {})
    }

    /// [`ControlStep::step`], handing the duties and the sections in service to `out` as
    /// soon as the drive stage has them, before the rotate and publish stages (the board
    /// writes them to the bridges there: their deadline is the next PWM update). Not called
    /// while a calibration runs: its duties come after the rest, in the returned outputs.
    #[inline(always)]
    pub fn step_then(
        &mut self,
        inputs: &CycleInputs,
        out: impl FnOnce(Option<&PerSection<PhaseDuties>>, PerSection<bool>),
    ) -> CycleOutputs {
        // Sense. A missed cycle: the decoders are caught up on what the last velocity
        // predicts.
        if let Some(gap_us) = self.sensing.overrun_us(inputs.t) {
            self.missed_cycles(gap_us);
        }
        let (master, slave) = self.sensing.decode(&inputs.encoders);
        let mut positions = (master.position, slave.position);
        if self.sensing.encoder_trouble(&master, &slave) {
            positions = self.encoder_fault(&master, &slave);
        }
        let c = &self.config;
        let (s, pressures_failed) = self.sensing.measure(
            c,
            (master, slave),
            positions,
            &inputs.pressures,
            &self.drive.currents,
        );
        let count = self.sensing.rotation_count(inputs.quadrature);
        self.rotary.servo.observe(count);
        if pressures_failed {
            self.react(Trip::of(Fault::PressureSensor));
        }
        if self.plan.running()
            && self
                .sensing
                .pressures
                .watch_stroke(&inputs.pressures, s.position_m)
        {
            self.react(Trip::of(Fault::PressurePlausibility));
        }

        self.supervise(&s);

        // Plan.
        let inputs_plan = PlanInputs {
            config: &self.config,
            previous: &self.publish.previous,
            safe: &self.safe,
            pressures: &self.sensing.pressures,
        };
        let frame = modes::Frame {
            zero_raw_m: &mut self.sensing.zero_raw_m,
            zero_slave_raw_m: &mut self.sensing.zero_slave_raw_m,
            differentiator: &mut self.sensing.differentiator,
        };
        let planned = self.plan.plan(&s, &inputs_plan, &mut self.rotary, frame);
        self.publish.previous.reference_m = planned.setpoint.map(|(sp, _)| sp.position_m);

        // Drive.
        let mut limits = LimitFlags::default();
        let pwm = match planned.setpoint {
            Some((sp, limit)) => {
                let a = self.drive.actuate(
                    &self.config,
                    &inputs.currents,
                    &s,
                    &sp,
                    limit,
                    &self.safe.split,
                    self.plan.running(),
                );
                self.publish.previous.force_command_n = a.force_n;
                self.publish.previous.shares = a.shares;
                limits = a.limits;
                a.duties
            }
            // A calibration drives the outputs itself, at the end of the step.
            None if matches!(self.plan.mode, Mode::Calibrating(_)) => None,
            // So does a bench operation.
            #[cfg(feature = "bench")]
            None if matches!(self.plan.mode, Mode::Bench(_)) => None,
            None => {
                if let Some(fault) = planned.fault {
                    self.react(Trip::of(fault));
                }
                if !self.supervision.energised {
                    self.watch_absent(&s);
                }
                let shorted = self.plan.stop.shorted();
                self.publish.previous.outputs_off();
                self.drive.outputs_off(&inputs.currents, shorted)
            }
        };

        let sections = self.safe.sections_in_service();
        let calibrating = matches!(self.plan.mode, Mode::Calibrating(_));
        #[cfg(feature = "bench")]
        let calibrating = calibrating || matches!(self.plan.mode, Mode::Bench(_));
        if !calibrating {
            out(pwm.as_ref(), sections);
        }

        // Rotate.
        let servo = self.rotate_stage(&s, &planned, pwm.is_some());

        // Publish.
        self.publish(inputs.t, &s, limits);
        if calibrating {
            return self.calibrating_outputs(&inputs.currents, sections, servo);
        }
        CycleOutputs {
            pwm,
            sections,
            servo,
        }
    }

    /// Cycles were missed (`gap_us` since the last sample, µs): the deadline fault. A gap the
    /// decoders can be caught up over ([`sense::CATCH_UP_SAMPLES`]) stops the piston on its
    /// extrapolated position (SS1); a longer one — a stall, a debugger's halt, in which the
    /// motor timers may have frozen with their outputs off — leaves nothing to say where the
    /// piston went: it is braked as without position.
    #[cold]
    #[inline(never)]
    fn missed_cycles(&mut self, gap_us: i32) {
        let period = CONTROL_PERIOD_US as i32;
        if gap_us > (sense::CATCH_UP_SAMPLES as i32 + 1) * period + period / 2 {
            self.react(Trip {
                reaction: Reaction::BrakeWithoutPosition,
                ..Trip::of(Fault::Deadline)
            });
        } else {
            self.react(Trip::of(Fault::Deadline));
        }
        let previous = &self.publish.previous;
        self.sensing.catch_up(gap_us, &self.config, previous);
    }

    /// The rotate stage: a new half cycle's rotation started, then the servo's command
    /// synchronised to the stroke (`outputs_on`: the bridges switch this cycle).
    #[inline(always)]
    fn rotate_stage(&mut self, s: &Sensed, planned: &modes::Planned, outputs_on: bool) -> DacCode {
        if let Some(half) = planned.half {
            let last_pa = &self.sensing.pressures.last_pa;
            modes::begin_half(&mut self.rotary, half, &self.config, last_pa);
        }
        let stroke = match (&self.plan.mode, &planned.setpoint) {
            (Mode::Running(g), Some((sp, _))) if !g.waiting() => Some(sp),
            _ => None,
        };
        self.rotary.rotate(
            s.position_m,
            stroke,
            outputs_on,
            &self.config.gas,
            &self.sensing.pressures.last_pa,
        )
    }

    /// An encoder's filter tripped, or one was lost before: the positions to use
    /// ([`Sensing::encoder_fault`]), and what a loss found now asks for — one encoder lost,
    /// its section dropped and SS1 on the other (STO if the two disagreed before); both,
    /// braking without position.
    #[cold]
    #[inline(never)]
    fn encoder_fault(
        &mut self,
        master: &EncoderReading,
        slave: &EncoderReading,
    ) -> (PositionCounts, PositionCounts) {
        let (positions, loss) = self.sensing.encoder_fault(&self.config, master, slave);
        match loss {
            Some(EncoderLoss::One(section)) => {
                let mismatch = self.safe.faults.contains(Fault::EncoderMismatch);
                self.react(Trip::encoder_lost(section, mismatch));
            }
            Some(EncoderLoss::Both) => self.react(Trip::of(Fault::EncoderSignal)),
            None => {}
        }
        positions
    }

    /// The supervise stage: the limits and faults checked on what was sensed (each trip
    /// reacted to at once), then the host's watchdog.
    #[inline(always)]
    fn supervise(&mut self, s: &Sensed) {
        let observation = self.observation(s);
        if let Some(trip) = self
            .supervision
            .check(&self.config.supervisor, &observation)
        {
            self.supervised_trip(trip, s);
        }
        if self.supervision.host_lost(self.config.sample_time_s)
            && matches!(
                self.plan.mode,
                Mode::Moving { .. } | Mode::Holding(_) | Mode::Running(_)
            )
        {
            // Host lost: park (a controlled stop first), not a fault.
            self.begin_stop(AfterStop::Park);
        }
    }

    /// The supervisor's trip: two encoders that disagree are judged on their readings first
    /// (the suspect, if one, is taken out and the other stands in).
    #[cold]
    #[inline(never)]
    fn supervised_trip(&mut self, trip: Trip, s: &Sensed) {
        let trip = if trip.fault == Fault::EncoderMismatch {
            let suspect = self.sensing.suspect(&s.master, &s.slave);
            if let Some(section) = suspect {
                self.sensing
                    .lose_encoder(&self.config, section, &s.master, &s.slave);
            }
            trip.judged(suspect)
        } else {
            trip
        };
        self.react(trip);
    }

    /// What the supervisor sees this cycle.
    #[inline(always)]
    fn observation(&self, s: &Sensed) -> Observation {
        let c = &self.config;
        let mode = &self.plan.mode;
        let driving = !matches!(mode, Mode::Idle | Mode::Faulted);
        // The rotation times the ports only while compressing; in a stop it only holds (or,
        // after a reset, coasts down), whatever the linear motion does.
        let running = matches!(mode, Mode::Running(_));
        let rotation_error_rad = if running {
            self.rotary.reference_rad - self.rotary.servo.angle_rad()
        } else {
            0.0
        };
        // Only looked at once the error is large (never in normal running: the step stays
        // cheap).
        let rotation_stalled = rotation_error_rad.abs() > c.supervisor.rotation_stall_error_rad
            && self.rotary.stalled();
        let previous = &self.publish.previous;
        Observation {
            dt_s: c.sample_time_s,
            homed: self.sensing.zero_raw_m.is_some(),
            driving: driving && !matches!(mode, Mode::Homing(_)),
            position_m: s.position_m,
            slave_position_m: s.slave_raw_m - self.sensing.zero_slave_raw_m,
            velocity_mps: s.derivatives.velocity_mps,
            reference_m: previous.reference_m.unwrap_or(s.position_m),
            peak_phase_a: self.drive.peak_phase_a(),
            commanded_n: previous.shares,
            delivered_n: PerSection {
                master: s.force_master_n,
                slave: s.force_slave_n,
            },
            rotation_error_rad,
            rotation_stalled,
        }
    }

    /// The react stage, the one place a trip is carried out: its fault latched and the
    /// sections it names taken out of service ([`SafeState::latch`]), then the stop its
    /// reaction starts — SS1 (a controlled stop ending with the outputs off; STO while not
    /// homed) or STO — and the brake around it.
    #[cold]
    #[inline(never)]
    fn react(&mut self, trip: Trip) {
        if self.absent_at_boot(trip.fault) {
            return;
        }
        let new = self.safe.latch(&trip);
        let homed = self.sensing.zero_raw_m.is_some();
        let trusted_and_homed = trip.reaction.position_trusted() && homed;
        let x = PlanInputs {
            config: &self.config,
            previous: &self.publish.previous,
            safe: &self.safe,
            pressures: &self.sensing.pressures,
        };
        self.plan.enter_safe_state(new, trusted_and_homed, &x);
        match trip.reaction {
            Reaction::Ss1 | Reaction::Sto | Reaction::DropSection => {}
            Reaction::BrakeWithoutPosition => self.plan.stop.brake_without_position(
                &self.config,
                self.rotary.reference_rad,
                self.rotary.servo.velocity_rad_s(),
                self.publish.previous.velocity_mps,
            ),
            Reaction::BrakeAfterReset => self.plan.stop.await_velocity_then_brake(),
        }
    }

    /// Starts a controlled stop followed by `then` ([`Plan::begin_stop`]).
    fn begin_stop(&mut self, then: AfterStop) {
        let x = PlanInputs {
            config: &self.config,
            previous: &self.publish.previous,
            safe: &self.safe,
            pressures: &self.sensing.pressures,
        };
        self.plan
            .begin_stop(then, &x, self.sensing.zero_raw_m.is_some());
    }

    /// The publish stage: what this cycle leaves for the next and the status snapshot. Kept
    /// out of line: inlined, the register pressure of the whole step costs instructions per
    /// cycle on the Cortex-M4 (`scripts/bench-cm4.sh`).
    #[inline(never)]
    fn publish(&mut self, t: Ticks, s: &Sensed, limits: LimitFlags) {
        let turn_rad = self.rotary.turns_rad;
        let p = &mut self.publish;
        p.t = t;
        p.mode = self.plan.mode_kind();
        p.homed = self.sensing.zero_raw_m.is_some();
        p.previous.position_m = s.position_m;
        p.previous.slave_position_m = s.slave_raw_m - self.sensing.zero_slave_raw_m;
        p.previous.velocity_mps = s.derivatives.velocity_mps;
        p.previous.acceleration_mps2 = s.derivatives.acceleration_mps2;
        p.theta_rad = self.rotary.servo.angle_rad() + turn_rad;
        p.theta_reference_rad = self.rotary.reference_rad + turn_rad;
        p.force_master_n = s.force_master_n;
        p.force_slave_n = s.force_slave_n;
        p.previous.pressure_a_pa = s.pressure_a_pa;
        p.previous.pressure_b_pa = s.pressure_b_pa;
        p.faults = self.safe.faults;
        p.limits = limits;
    }

    /// One cycle of a calibration routine, after the rest of the step (supervision, status):
    /// the routine says what to do with the outputs (off, forced current vectors, or
    /// position control along its sweep); when it is done its outcome is loaded into the
    /// configuration (a calibration load) and the machine holds (homed) or goes idle. It
    /// reads what it needs from what this step has just published, so the normal step
    /// carries nothing for it; the rotation is not driven meanwhile.
    #[cold]
    #[inline(never)]
    fn calibration_cycle(
        &mut self,
        currents: &PerSection<PhaseCurrentCodes>,
    ) -> Option<PerSection<PhaseDuties>> {
        #[cfg(feature = "bench")]
        if let Mode::Bench(_) = self.plan.mode {
            return self.bench_cycle(currents);
        }
        let now = self.publish.previous;
        let forces = PerSection {
            master: self.publish.force_master_n,
            slave: self.publish.force_slave_n,
        };
        let measured = calibrate::measurements(
            &self.config,
            &now,
            forces,
            self.sensing.zero_raw_m.unwrap_or(0.0),
            self.sensing.zero_slave_raw_m,
            &self.sensing.pressures.last_pa,
            currents,
        );
        let Mode::Calibrating(calibration) = &mut self.plan.mode else {
            return None;
        };
        let routine = calibration.routine();
        let mut demand = calibration.step(&self.config, &measured);
        if let Demand::Done(result) = demand {
            if let Ok(outcome) = &result {
                outcome.apply(&mut self.config);
                if let Outcome::EncoderMap(_) = outcome {
                    // The slave's gate passes the map's step from the next cycle on.
                    let slave = encoder_map::slave_encoder(&self.config);
                    let gate = slave.glitch_gate_periods;
                    self.sensing.encoders.slave.set_glitch_gate(gate);
                }
            }
            self.plan.calibration.finish(routine, result, &self.config);
            let hold = Setpoint::at_rest(now.position_m);
            (self.plan.mode, demand) = if self.sensing.zero_raw_m.is_some() {
                let track = Demand::Track {
                    setpoint: hold,
                    master_only: false,
                    slave_d_a: 0.0,
                };
                (Mode::Holding(hold), track)
            } else {
                (Mode::Idle, Demand::Off)
            };
            self.publish.mode = self.plan.mode_kind();
        }
        self.publish.previous.shares = PerSection::default();
        let c = &self.config;
        let inv_kf = 1.0 / c.motor.force_constant_n_per_a;
        let own = PerSection {
            master: measured.angle.master.wrapping_add(c.angle_offset.master),
            slave: measured.angle.slave.wrapping_add(c.angle_offset.slave),
        };
        let frames = match demand {
            Demand::Forced(forced) => calibrate::forced_frames(forced, own),
            Demand::Track {
                setpoint,
                master_only,
                slave_d_a,
            } => {
                let shares =
                    self.calibration_track(&now, &setpoint, master_only, measured.gas_force_n);
                calibrate::tracking_frames(own, shares, inv_kf, slave_d_a)
            }
            Demand::Off | Demand::Done(_) => {
                self.drive.currents.master.reset();
                self.drive.currents.slave.reset();
                return None;
            }
        };
        let duties = self
            .drive
            .drive_sections(&self.config, currents, frames, now.velocity_mps);
        self.publish.limits.voltage = self.drive.voltage_limited();
        duties
    }

    /// A routine's position control on `setpoint` from `now` (the cycle just published):
    /// the position loop as in any mode (the next cycle's supervision checks the following
    /// error against this setpoint), its force split over the sections in service (the
    /// master alone with `master_only`). Returns each section's share, N.
    fn calibration_track(
        &mut self,
        now: &publish::Previous,
        setpoint: &Setpoint,
        master_only: bool,
        gas_force_n: f32,
    ) -> PerSection<f32> {
        let c = &self.config;
        let limit = c.force_limit_n;
        let derivatives = Derivatives {
            velocity_mps: now.velocity_mps,
            acceleration_mps2: now.acceleration_mps2,
        };
        let model = actuate::model_forces(c, setpoint, gas_force_n);
        let force = self.drive.position_loop(
            c,
            setpoint,
            now.position_m,
            &derivatives,
            &model,
            0.0,
            limit,
        );
        let mut in_service = self.safe.in_service;
        if master_only {
            in_service.slave = 0.0;
        }
        let shares =
            crate::drive::allocation::allocate(&c.allocation, in_service, force, now.position_m);
        let p = &mut self.publish;
        p.previous.reference_m = Some(setpoint.position_m);
        p.previous.shares = shares;
        p.previous.force_command_n = force;
        p.limits.force = force.abs() >= limit;
        shares
    }

    /// Handles a host command: checked into the change it makes ([`commands::check`]), which
    /// is applied here; a refused command changes nothing.
    pub fn command(&mut self, command: Command) -> Result<(), Refusal> {
        #[cfg(feature = "bench")]
        if let Command::Bench { op, seconds } = command {
            return self.bench_command(op, seconds);
        }
        let change = commands::check(command, &self.view())?;
        self.apply(change);
        Ok(())
    }

    /// The machine as the command checks see it.
    #[inline(always)]
    fn view(&self) -> MachineView<'_> {
        let previous = &self.publish.previous;
        MachineView {
            config: &self.config,
            mode: &self.plan.mode,
            faults: &self.safe.faults,
            homed: self.sensing.zero_raw_m.is_some(),
            raw_position_m: previous.position_m + self.sensing.zero_raw_m.unwrap_or(0.0),
            position_m: previous.position_m,
            calibration: self.plan.calibration.status,
            sense_monitor: &self.drive.sense_monitor,
            sensing: &self.sensing,
            supply_good: self.supervision.supply_good,
            absent: self.publish.absent,
            brake: self.plan.stop.brake,
            dead_point_gain: self.plan.dead_point_gain,
        }
    }

    /// Applies an accepted command's change.
    fn apply(&mut self, change: Change) {
        match change {
            Change::Nothing => {}
            Change::Heartbeat => self.supervision.heartbeat(),
            Change::Mode(mode) => {
                #[cfg(feature = "bench")]
                if let Mode::Calibrating(c) = &mode {
                    self.plan.calibration.start(c.routine(), &self.config);
                }
                self.plan.mode = mode;
                self.energise();
            }
            Change::Home(homing) => {
                self.plan.mode = Mode::Homing(homing);
                self.energise();
                self.sensing.zero_raw_m = None;
            }
            Change::Start(mut generator) => {
                // The first stroke's rotation starts from the phase of the dead point the
                // piston rests at. A rotation nearer the other dead point's phase (a piston
                // moved across the stroke with the rotation still, as homing does) first
                // turns there, the piston held.
                let turn_rad = self.rotary.start_turn_rad(generator.direction());
                if turn_rad.abs() > core::f32::consts::FRAC_PI_2 {
                    generator.wait(rotate::START_TURN_TIME_S);
                } else {
                    let last_pa = &self.sensing.pressures.last_pa;
                    let half = modes::HalfStart::of(&generator);
                    modes::begin_half(&mut self.rotary, half, &self.config, last_pa);
                }
                self.plan.mode = Mode::Running(generator);
                self.energise();
                // The plausibility of the chamber pressures is judged over running strokes.
                self.sensing.pressures.restart_stroke_watch();
            }
            Change::Speed(peak_speed_mps) => {
                if let Mode::Running(g) = &mut self.plan.mode {
                    g.set_peak_speed(peak_speed_mps);
                }
            }
            Change::Parameter(parameter, value) => match parameter {
                Parameter::PositionKp => self.drive.kp_n_per_m = value,
                Parameter::PositionKd => self.drive.kd_ns_per_m = value,
                Parameter::HeartbeatTimeout => self.supervision.heartbeat_timeout_s = value,
                Parameter::ParkPosition => self.plan.park_position_m = value,
                Parameter::DeadPointGain => self.plan.dead_point_gain = value,
            },
            Change::Rotation(rotation) => self.rotary.direction = rotation,
            Change::VolumeRatio(target) => self.rotary.volume_ratio.set_target(target),
            Change::Stop => match &mut self.plan.mode {
                Mode::Running(g) => g.request_stop(),
                _ => self.begin_stop(AfterStop::Hold),
            },
            Change::ClearFaults => {
                // An encoder fault loses the zero: homing is required again.
                let encoder_fault = self.safe.faults.contains(Fault::EncoderSignal);
                self.sensing.clear_faults(encoder_fault);
                self.safe.clear(&self.config);
                if matches!(self.plan.stop.brake, safe_state::FaultedBrake::Blind { .. }) {
                    self.plan.stop.brake = safe_state::FaultedBrake::None;
                }
                self.plan.mode = Mode::Idle;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::safe_state::FaultedBrake;
    use super::*;
    use crate::control::calibration::Routine;
    use crate::safety::absent::{Absent, Part};

    #[test]
    fn the_hold_after_a_watchdog_reset_ends_on_clear_faults_not_the_braking_before_it() {
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        step.supply(true);
        step.boot(ResetCause::Watchdog);
        // Braking the measured velocity to zero: busy.
        step.plan.mode = Mode::Stopping {
            setpoint: Setpoint {
                position_m: 0.01,
                velocity_mps: 0.2,
                acceleration_mps2: -625.0,
            },
            then: AfterStop::Off,
        };
        step.plan.stop.brake = FaultedBrake::Zeroing(1);
        assert_eq!(step.command(Command::ClearFaults), Err(Refusal::Busy));
        // Held at rest, not homed: the hold does not end by itself, the clear ends it.
        step.plan.stop.brake = FaultedBrake::None;
        step.plan.mode = Mode::Stopping {
            setpoint: Setpoint::at_rest(0.01),
            then: AfterStop::Off,
        };
        assert_eq!(step.command(Command::ClearFaults), Ok(()));
        assert!(matches!(step.plan.mode, Mode::Idle));
        assert!(step.safe.faults.is_empty());
        // SS1's hold (homed) ends on its own force criterion: busy.
        step.sensing.zero_raw_m = Some(0.0);
        step.react(Trip::of(Fault::Overspeed));
        step.plan.mode = Mode::Stopping {
            setpoint: Setpoint::at_rest(0.01),
            then: AfterStop::Off,
        };
        assert_eq!(step.command(Command::ClearFaults), Err(Refusal::Busy));
    }

    #[test]
    fn without_a_stored_calibration_start_is_refused_but_home_and_calibrate_are_not() {
        for (loaded, status) in [
            (Err(LoadError::Missing), CalibrationStatus::Missing),
            (Err(LoadError::Flash), CalibrationStatus::Invalid),
        ] {
            let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
            step.load_calibration(loaded);
            assert_eq!(step.calibration_status(), status);
            assert_eq!(
                status.name(),
                ["calibration_missing", "calibration_invalid"][status as usize - 2]
            );
            assert_eq!(
                step.command(Command::Start {
                    peak_speed_mps: 2.0
                }),
                Err(Refusal::NotCalibrated)
            );
            assert_eq!(
                step.command(Command::Calibrate {
                    routine: Routine::CurrentSense
                }),
                Ok(())
            );
            let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
            step.load_calibration(loaded);
            assert_eq!(step.command(Command::Home), Ok(()));
            assert_eq!(step.take_calibration_to_save(), None);
        }
    }

    /// A burst at cycle `n` on a bench with the encoders at electrical angle 0.3 rad and the
    /// chambers at 1 bar if `connected`; otherwise the encoders' inputs flat at mid-scale
    /// and the pressure inputs at 0 V. The phase currents read zero.
    fn bench_inputs(config: &ControlConfig, n: u32, connected: bool) -> CycleInputs {
        moving_inputs(config, n, connected, 0.0)
    }

    /// [`bench_inputs`] with the piston moving at `speed_mps` (encoders connected).
    fn moving_inputs(
        config: &ControlConfig,
        n: u32,
        connected: bool,
        speed_mps: f32,
    ) -> CycleInputs {
        let x_m = speed_mps * n as f32 * config.sample_time_s;
        let sincos = |e: &crate::sensing::encoder::EncoderConfig| {
            let angle = 0.3 + core::f32::consts::TAU * x_m / e.period_m;
            let (s, c) = if connected {
                e.calibration.codes_at(angle)
            } else {
                (2048.0, 2048.0)
            };
            crate::ports::SinCosCodes {
                sin: crate::units::AdcCode(s.round() as u16),
                cos: crate::units::AdcCode(c.round() as u16),
            }
        };
        let p = if connected {
            config.pressure.code_for(1.0e5)
        } else {
            crate::units::AdcCode(0)
        };
        CycleInputs {
            t: Ticks(n * 50),
            encoders: EncoderCodes {
                master: sincos(&config.encoder_master),
                slave: sincos(&config.encoder_slave),
            },
            currents: PerSection {
                master: [crate::units::AdcCode::MID; 3],
                slave: [crate::units::AdcCode::MID; 3],
            },
            quadrature: 0,
            pressures: PressureCodes {
                chamber_a: p,
                chamber_b: p,
                suction: p,
                discharge: p,
            },
        }
    }

    /// The bench operations on a bench with the bus at 12 V (power-good low since boot)
    /// and the sensors connected: a fixed duty drives its phase and 50 % elsewhere without
    /// energising (the supply stays absent, not a fault), ends on `Stop`, at its time and the
    /// cycle power-good rises; a servo torque drives the DAC with the outputs off. Each is
    /// refused out of range, with a fault latched or the machine busy, the fixed duty with
    /// the link up.
    #[test]
    fn bench_operations_drive_one_phase_or_the_servo_and_end_on_stop_time_or_the_link() {
        use crate::control::command::BenchOp;
        use crate::units::{DacCode, Duty, Section};
        let config = ControlConfig::reference();
        let mut step = ControlStep::new(config.clone()).unwrap();
        step.boot(ResetCause::PowerOn);
        let mut n = 0;
        let mut cycle = |step: &mut ControlStep, supply: bool| {
            step.supply(supply);
            n += 1;
            step.step(&bench_inputs(&config, n, true))
        };
        for _ in 0..200 {
            cycle(&mut step, false);
        }
        let fixed = |duty: f32| BenchOp::FixedDuty {
            section: Section::Slave,
            phase: 2,
            duty,
        };
        let bench = |op, seconds| Command::Bench { op, seconds };
        let torque = |torque_nm| BenchOp::ServoTorque { torque_nm };
        for (command, refusal) in [
            (bench(fixed(0.99), 1.0), Refusal::OutOfRange),
            (bench(fixed(0.04), 1.0), Refusal::OutOfRange),
            (bench(fixed(0.3), 61.0), Refusal::OutOfRange),
            (bench(fixed(0.3), 0.0), Refusal::OutOfRange),
            (bench(fixed(f32::NAN), 1.0), Refusal::NotFinite),
            (bench(torque(5.01), 1.0), Refusal::OutOfRange),
            (bench(torque(-5.01), 1.0), Refusal::OutOfRange),
            (bench(torque(0.5), f32::INFINITY), Refusal::NotFinite),
        ] {
            assert_eq!(step.command(command), Err(refusal), "{command:?}");
        }
        assert_eq!(step.command(bench(fixed(0.3), 1.0)), Ok(()));
        assert_eq!(
            step.command(bench(torque(0.5), 1.0)),
            Err(Refusal::Busy),
            "one at a time"
        );
        let half = [Duty::HALF; 3];
        let mut slave = half;
        slave[2] = Duty::from_fraction(0.3);
        for _ in 0..100 {
            let out = cycle(&mut step, false);
            let duties = PerSection {
                master: half,
                slave,
            };
            assert_eq!(out.pwm, Some(duties));
            assert_eq!(
                out.sections,
                PerSection {
                    master: true,
                    slave: true
                }
            );
        }
        let s = step.status();
        assert_eq!(s.mode, crate::status::ModeKind::Bench);
        assert!(s.faults.is_empty(), "{:?}", s.faults);
        assert!(
            !step.supervision.energised,
            "the supply stays absent, not lost"
        );
        // Stop ends it at once; the machine is idle, the outputs off.
        assert_eq!(step.command(Command::Stop), Ok(()));
        assert_eq!(cycle(&mut step, false).pwm, None);
        assert_eq!(step.status().mode, crate::status::ModeKind::Idle);
        // Its time: 1 ms is 20 cycles.
        assert_eq!(step.command(bench(fixed(0.6), 0.001)), Ok(()));
        let driven = (0..30).filter(|_| cycle(&mut step, false).pwm.is_some());
        assert_eq!(driven.count(), 19);
        // Power-good rising ends a fixed duty the same cycle; with the link up it is refused.
        assert_eq!(step.command(bench(fixed(0.6), 1.0)), Ok(()));
        assert!(cycle(&mut step, false).pwm.is_some());
        assert_eq!(cycle(&mut step, true).pwm, None);
        assert_eq!(step.status().mode, crate::status::ModeKind::Idle);
        assert_eq!(step.command(bench(fixed(0.6), 1.0)), Err(Refusal::SupplyUp));
        // The servo torque: its DAC code, the outputs off; zero torque after.
        assert_eq!(step.command(bench(torque(0.5), 0.01)), Ok(()));
        let code = crate::drive::servo::ServoController::new(config.servo).command(0.5);
        assert_eq!(code, DacCode(2099));
        for _ in 0..199 {
            let out = cycle(&mut step, true);
            assert_eq!((out.pwm, out.servo), (None, code));
        }
        let out = cycle(&mut step, true);
        assert_eq!(out.servo, step.rotary.servo.command(0.0));
        // A fault latched: refused.
        step.react(Trip::of(Fault::Overspeed));
        assert_eq!(
            step.command(bench(torque(0.5), 1.0)),
            Err(Refusal::FaultActive)
        );
    }

    #[test]
    fn a_bare_bench_waits_with_the_outputs_off_and_names_what_is_absent_until_it_appears() {
        let config = ControlConfig::reference();
        let mut step = ControlStep::new(config.clone()).unwrap();
        step.boot(ResetCause::PowerOn);
        let mut n = 0;
        let mut run = |step: &mut ControlStep, supply: bool, connected: bool, cycles: u32| {
            for _ in 0..cycles {
                step.supply(supply);
                let out = step.step(&bench_inputs(&config, n, connected));
                n += 1;
                assert_eq!(out.pwm, None, "the outputs stay off (cycle {n})");
                assert_eq!(out.servo, step.rotary.servo.command(0.0), "zero torque");
            }
        };
        run(&mut step, false, false, 200);
        let s = step.status();
        assert!(s.faults.is_empty(), "absent is not a fault: {:?}", s.faults);
        assert_eq!(s.mode, crate::status::ModeKind::Idle);
        assert_eq!(
            s.absent.iter().collect::<Vec<_>>(),
            [Part::Supply, Part::Encoders, Part::Pressures]
        );
        for command in [
            Command::ClearFaults,
            Command::Home,
            Command::Calibrate {
                routine: Routine::CurrentSense,
            },
            Command::Start {
                peak_speed_mps: 2.0,
            },
        ] {
            assert_eq!(
                step.command(command),
                Err(Refusal::SupplyAbsent),
                "{command:?}"
            );
        }
        // The link comes up: the sensors are named next, one by one.
        run(&mut step, true, false, 10);
        assert_eq!(step.command(Command::Home), Err(Refusal::EncodersAbsent));
        // The sensors appear: the encoders' filters recover within their limit's samples.
        run(&mut step, true, true, 200);
        assert_eq!(step.status().absent, Absent::NONE);
        assert!(step.status().faults.is_empty());
        assert_eq!(step.command(Command::ClearFaults), Ok(()));
        assert_eq!(step.command(Command::Home), Ok(()));
        // Energised: the supply lost now is the fault it always was.
        step.supply(false);
        assert!(step.safe.faults.contains(Fault::SupplyLoss));
        assert_eq!(step.status().absent, Absent::NONE);
    }

    #[test]
    fn a_piston_found_moving_at_boot_without_the_supply_is_braked_as_a_supply_loss() {
        let config = ControlConfig::reference();
        let mut step = ControlStep::new(config.clone()).unwrap();
        step.boot(ResetCause::PowerOn);
        let mut braked_at = None;
        for n in 0..200 {
            step.supply(false);
            step.step(&moving_inputs(&config, n, true, 0.5));
            if braked_at.is_none() && step.safe.faults.contains(Fault::SupplyLoss) {
                braked_at = Some(n);
            }
        }
        // Judged once the differentiator's window holds only samples of encoders present.
        let n = braked_at.expect("a moving piston with the supply low is a supply loss");
        assert!(
            n as usize + 1 >= 2 * config.sg_window && n < 60,
            "at cycle {n}"
        );
        assert_eq!(step.status().absent, Absent::NONE);
        // Its reaction as before: the windings shorted (zero duties, the outputs on).
        step.supply(false);
        let out = step.step(&moving_inputs(&config, 200, true, 0.5));
        assert!(out.pwm.is_some(), "{out:?}");
    }

    #[test]
    fn a_gap_longer_than_the_catch_up_brakes_without_position_a_short_one_stops_on_it() {
        let config = ControlConfig::reference();
        for (gap, blind) in [(3, false), (41, false), (42, true), (400, true)] {
            let mut step = ControlStep::new(config.clone()).unwrap();
            step.supply(true);
            for n in 0..100 {
                step.step(&bench_inputs(&config, n, true));
            }
            assert!(step.safe.faults.is_empty());
            step.step(&bench_inputs(&config, 99 + gap, true));
            assert!(step.safe.faults.contains(Fault::Deadline), "gap {gap}");
            assert_eq!(
                matches!(step.plan.stop.brake, FaultedBrake::Blind { .. }),
                blind,
                "gap {gap}: {:?}",
                step.plan.stop.brake
            );
        }
    }

    #[test]
    fn a_supply_loss_latches_once_and_is_cleared_only_once_the_supply_is_back() {
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        step.energise();
        step.supply(true);
        assert!(step.safe.faults.is_empty());
        step.supply(false);
        step.supply(false);
        assert!(step.safe.faults.contains(Fault::SupplyLoss));
        assert_eq!(step.safe.faults.iter().count(), 1);
        // Not homed: the brake's short circuit, the outputs' own (the faulted state).
        assert!(matches!(step.plan.mode, Mode::Faulted));
        assert_eq!(
            step.command(Command::ClearFaults),
            Err(Refusal::CausePersists)
        );
        step.supply(true);
        assert_eq!(step.command(Command::ClearFaults), Ok(()));
        assert!(step.safe.faults.is_empty());
    }

    /// The tunables of `step`: position gains, heartbeat timeout, park position, dead-point
    /// gain.
    fn tunables(step: &ControlStep) -> [f32; 5] {
        [
            step.drive.kp_n_per_m,
            step.drive.kd_ns_per_m,
            step.supervision.heartbeat_timeout_s,
            step.plan.park_position_m,
            step.plan.dead_point_gain,
        ]
    }

    #[test]
    fn set_parameter_validates_and_changes_only_what_it_names_never_the_configuration() {
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        let config = step.config().clone();
        let before = tunables(&step);
        for (parameter, value, refusal) in [
            (Parameter::PositionKp, f32::NAN, Refusal::NotFinite),
            (Parameter::PositionKp, f32::INFINITY, Refusal::NotFinite),
            (Parameter::PositionKp, 1.0e9, Refusal::OutOfRange),
            (Parameter::ParkPosition, -0.01, Refusal::OutOfRange),
            (Parameter::DeadPointGain, 1.5, Refusal::OutOfRange),
        ] {
            assert_eq!(
                step.command(Command::SetParameter { parameter, value }),
                Err(refusal)
            );
            assert_eq!(tunables(&step), before, "a refused command changes nothing");
        }
        for (i, parameter) in Parameter::ALL.into_iter().enumerate() {
            let (lo, hi) = parameter.range();
            let value = 0.5 * (lo + hi);
            assert_eq!(
                step.command(Command::SetParameter { parameter, value }),
                Ok(())
            );
            let mut expected = before;
            expected[i] = value;
            assert_eq!(tunables(&step), expected, "{parameter:?}");
            step.command(Command::SetParameter {
                parameter,
                value: before[i],
            })
            .unwrap();
        }
        assert_eq!(step.config(), &config, "the configuration is not a tunable");
    }

    #[test]
    fn a_hardware_trip_drops_its_section_and_is_re_armed_only_once_the_fault_is_cleared() {
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        let master = PerSection {
            master: true,
            slave: false,
        };
        assert!(!step.trip_latched());
        assert_eq!(step.hardware_trip(master), PerSection::default());
        assert!(step.trip_latched());
        assert!(step.safe.faults.contains(Fault::Overcurrent));
        assert_eq!(
            step.safe.sections_in_service(),
            PerSection {
                master: false,
                slave: true
            }
        );
        // Still latched: nothing to re-arm, and the same break is not a new trip.
        assert_eq!(step.hardware_trip(master), PerSection::default());
        assert_eq!(
            step.hardware_trip(PerSection::default()),
            PerSection::default()
        );
        assert!(step.trip_latched());
        assert_eq!(step.command(Command::ClearFaults), Ok(()));
        assert_eq!(step.hardware_trip(PerSection::default()), master);
        assert!(!step.trip_latched());
        assert!(step.safe.faults.is_empty());
        assert_eq!(
            step.safe.sections_in_service(),
            PerSection {
                master: true,
                slave: true
            }
        );
    }

    #[test]
    fn a_lost_section_is_out_of_service_until_the_faults_are_cleared() {
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        step.react(Trip::of(Fault::Overcurrent).dropping(crate::units::Section::Slave));
        assert_eq!(
            step.safe.sections_in_service(),
            PerSection {
                master: true,
                slave: false
            }
        );
        assert_eq!(step.config().allocation.capability.slave, 1.0);
        assert_eq!(step.command(Command::ClearFaults), Ok(()));
        assert_eq!(
            step.safe.sections_in_service(),
            PerSection {
                master: true,
                slave: true
            }
        );
    }
}
