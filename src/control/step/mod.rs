//! The 20 kHz control step of the linear axis and the rotation, as a pure function of its
//! inputs.
//!
//! [`ControlStep::step`] takes one burst of samples (encoders, phase currents, quadrature
//! count, pressures, the sampling instant) and returns the outputs (six PWM duties or
//! "outputs off", the servo torque code). It reads no clock and touches no hardware, so the
//! firmware's control task, the simulator and the benchmarks all call the same code.
//!
//! Per cycle: decode both encoders → differentiate the master position (Savitzky–Golay) →
//! convert pressures → mode logic gives a setpoint → position loop with model feed-forward
//! (`m·a + F_fr(v) − F_gas`) → one total force, split over the two sections → FOC of both
//! sections with each section's own encoder angle → duties for both, written in the same
//! cycle → servo loop.
//!
//! The stages live in their own modules, each with the state it owns (a struct of its own,
//! one field of [`ControlStep`]) and an `impl ControlStep` block; values pass between them
//! (`Sensed` → the plan's setpoint → the actuation's force), not through shared fields: `sense` (encoders, differentiator, pressures, and what a failed encoder
//! changes), `supervise` (limits and faults detected, each dispatched to its reaction),
//! `safe_state` (the reactions: SS1, STO, a section dropped, braking without position or
//! after a reset, the park's vent turn), `modes` (the mode machine that plans the setpoint:
//! homing, moves, strokes, controlled stops), `estimate` (both disturbance observers of the
//! force balance: the controlled stop's and the running step's), `commands`
//! (what a host command may change, and when), `actuate` (position loop, allocation,
//! both sections' FOC, the servo) and `calibrate` (a calibration routine's cycle).

mod actuate;
mod calibrate;
mod commands;
mod estimate;
mod modes;
mod safe_state;
mod sense;
mod supervise;

pub use estimate::DOB_TIME_S;
pub use modes::HOLD_RELEASE_S;

use crate::control::calibration::record::{CalibrationRecord, CalibrationStatus};
use crate::control::calibration::store::LoadError;
use crate::control::calibration::Calibrated;
use crate::control::command::Refusal;
use crate::control::config::{ConfigError, ControlConfig};
use crate::drive::foc::CurrentController;
use crate::motion::stroke::DeadPoint;
use crate::motion::trajectory::Setpoint;
use crate::ports::{EncoderCodes, PhaseCurrentCodes, PressureCodes};
use crate::safety::faults::{Fault, FaultSet, ResetCause};
use crate::sensing::differentiator::{SavitzkyGolay, SgConfig};
use crate::sensing::encoder::SinCosDecoder;
use crate::status::Status;
use crate::units::{DacCode, PerSection, PhaseDuties, Section, Ticks};
use actuate::RotaryAxis;
use calibrate::CalibrationState;
use estimate::Estimator;
use modes::Mode;
use safe_state::SafeState;
use sense::{Sensed, Sensing};
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

/// The control step and all its state, grouped by the stage that owns it: the sense stage's
/// decoders, frame and pressure monitor ([`Sensing`]), the supervision ([`Supervision`]), the
/// safe state's stop and hold ([`SafeState`]), both disturbance observers ([`Estimator`]),
/// the rotation ([`RotaryAxis`]) and the calibration's bookkeeping ([`CalibrationState`]).
///
/// `repr(C)`: the fields lie in the order written. What the running step reads and writes
/// field by field comes first — the configuration, the observers, the status, the stop and
/// hold state, the rotation, the mode, then the sense stage's scalars at the head of
/// [`Sensing`] — mostly within the ±1020-byte reach of the Cortex-M4's `vldr`/`vstr` from
/// `self`; the large state reached through a pointer (the decoders, the differentiator's
/// window, the current loops, the calibration's maps) lies after it. Left to the compiler's
/// order the grouped state cost 16 instructions per running step; in this order it saves 7
/// against the ungrouped step (`scripts/bench-cm4.sh`).
#[derive(Clone, Debug)]
#[repr(C)]
pub struct ControlStep {
    config: ControlConfig,
    estimator: Estimator,
    /// Force commanded to each section in the last cycle, N.
    shares: PerSection<f32>,
    /// The setpoint of the last cycle (none with outputs off).
    setpoint: Option<Setpoint>,
    status: Status,
    safe: SafeState,
    supervision: Supervision,
    /// The latched faults.
    faults: FaultSet,
    /// The last dead point the running strokes reached.
    last_dead_point: Option<DeadPoint>,
    rotary: RotaryAxis,
    mode: Mode,
    sensing: Sensing,
    currents: PerSection<CurrentController>,
    calibration: CalibrationState,
    /// The power-good input as the supervision task last read it.
    supply_good: bool,
    /// Sections whose bridge the hardware over-current trip switched off (their timer's
    /// break input), until `ClearFaults` re-arms it ([`ControlStep::hardware_trip`]).
    tripped: PerSection<bool>,
}

impl ControlStep {
    /// Builds the step from a configuration, refusing invalid parameters.
    pub fn new(mut config: ControlConfig) -> Result<Self, ConfigError> {
        // The supervisor's geometry and speed limit follow the machine's, never disagree.
        config.supervisor.travel_m = config.travel_m;
        config.supervisor.overspeed_mps = 1.2 * config.max_speed_mps;
        for (name, v) in [
            ("sample_time_s", config.sample_time_s),
            ("travel_m", config.travel_m),
            ("moving_mass_kg", config.moving_mass_kg),
            ("force_limit_n", config.force_limit_n),
            (
                "motor.force_constant_n_per_a",
                config.motor.force_constant_n_per_a,
            ),
            ("motor.bus_voltage_v", config.motor.bus_voltage_v),
            ("max_speed_mps", config.max_speed_mps),
            (
                "supervisor.brake_deceleration_mps2",
                config.supervisor.brake_deceleration_mps2,
            ),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ConfigError::NotPositive(name));
            }
        }
        // The observer's gains per cycle must stay within [0, 0.5] (a well damped update;
        // NaN fails too), its threshold non-negative.
        for (name, k) in [
            (
                "disturbance_bandwidth_rad_s",
                config.disturbance_bandwidth_rad_s,
            ),
            ("disturbance_slow_rad_s", config.disturbance_slow_rad_s),
        ] {
            if !(k >= 0.0 && k * config.sample_time_s <= 0.5) {
                return Err(ConfigError::OutOfRange(name));
            }
        }
        // The allocation relies on capabilities within [0, 1] (NaN fails too).
        for (name, c) in [
            (
                "allocation.capability.master",
                config.allocation.capability.master,
            ),
            (
                "allocation.capability.slave",
                config.allocation.capability.slave,
            ),
        ] {
            if !(0.0..=1.0).contains(&c) {
                return Err(ConfigError::OutOfRange(name));
            }
        }
        let threshold = config.disturbance_threshold_n;
        if threshold.is_nan() || threshold < 0.0 {
            return Err(ConfigError::OutOfRange("disturbance_threshold_n"));
        }
        let differentiator = SavitzkyGolay::new(SgConfig {
            window: config.sg_window,
            order: config.sg_order,
            lag: config.sg_lag,
            sample_time_s: config.sample_time_s,
            m_per_count: config.encoder_master.m_per_count(),
        })
        .map_err(ConfigError::Differentiator)?;
        let current =
            |_| CurrentController::new(&config.motor, config.current_gains, config.sample_time_s);
        Ok(ControlStep {
            sensing: Sensing::new(&config, differentiator),
            supervision: Supervision::new(),
            faults: FaultSet::new(),
            safe: SafeState::new(&config),
            mode: Mode::Idle,
            setpoint: None,
            last_dead_point: None,
            estimator: Estimator::new(),
            currents: PerSection {
                master: current(Section::Master),
                slave: current(Section::Slave),
            },
            shares: PerSection::default(),
            rotary: RotaryAxis::new(&config),
            status: Status::INIT,
            calibration: CalibrationState::new(),
            supply_good: true,
            tripped: PerSection::default(),
            config,
        })
    }

    /// What the power-good input reads (the supervision task's last look, before each
    /// step): the supply lost latches [`Fault::SupplyLoss`], whose brake runs on the DC
    /// link's energy ([`Reaction::BrakeWithoutPosition`](crate::safety::faults::Reaction):
    /// the short-circuited windings take the braking current, the link feeds only the
    /// gate drivers, the MCU and the servo's sealing turn). The fault cannot be cleared while
    /// the supply stays lost.
    #[inline]
    pub fn supply(&mut self, good: bool) {
        if !good && self.supply_good {
            self.supply_lost();
        }
        self.supply_good = good;
    }

    /// Whether a hardware over-current trip is latched (the control cycle then calls
    /// [`ControlStep::hardware_trip`] each cycle; one load and a branch otherwise).
    #[inline]
    pub fn trip_latched(&self) -> bool {
        self.tripped.master || self.tripped.slave
    }

    /// The bridges' hardware over-current trip (`docs/firmware.md`, "The hardware
    /// over-current trip"): `now` is which sections' timers show a break (their BIF), which
    /// switched their outputs off in hardware. A new one latches [`Fault::Overcurrent`] and
    /// takes that section out of the allocation (the other brakes, as after a measured
    /// overcurrent). Returns the sections whose trip may be re-armed (their break flag
    /// cleared) because `ClearFaults` has cleared the fault; a break input still active then
    /// trips again at once.
    #[cold]
    #[inline(never)]
    pub fn hardware_trip(&mut self, now: PerSection<bool>) -> PerSection<bool> {
        let new = PerSection {
            master: now.master && !self.tripped.master,
            slave: now.slave && !self.tripped.slave,
        };
        if !(new.master || new.slave) {
            if self.faults.contains(Fault::Overcurrent) {
                return PerSection::default();
            }
            return core::mem::take(&mut self.tripped);
        }
        if new.master {
            self.tripped.master = true;
            self.drop_section(0);
        }
        if new.slave {
            self.tripped.slave = true;
            self.drop_section(1);
        }
        self.enter_safe_state(Fault::Overcurrent, true);
        PerSection::default()
    }

    #[cold]
    #[inline(never)]
    fn supply_lost(&mut self) {
        if !self.faults.contains(Fault::SupplyLoss) {
            self.latch(Fault::SupplyLoss);
        }
    }

    /// Applies the cause of the last reset: after a watchdog reset the machine starts in
    /// the fault state (outputs off, restart inhibited until the fault is cleared).
    ///
    /// The piston may still be moving (a task hung at speed, the outputs held for up to the
    /// watchdog's timeout): once a straight line through the first
    /// [`RESET_FIT_SAMPLES`](safe_state::RESET_FIT_SAMPLES) samples gives its velocity (the
    /// differentiator's window is refilled with that line) the step brakes it in the
    /// encoders' own frame (the sin/cos angle commutates without the zero,
    /// the incremental position holds it): at full force until the measured velocity is
    /// zero, then held there. The hold does not end by itself (with neither the heads'
    /// distance nor the rotation's phase known, nothing says the gas will leave the piston
    /// still once the outputs are off): `ClearFaults` ends it, outputs off. Where the heads
    /// are is unknown until homing; the fault stays latched.
    pub fn boot(&mut self, cause: ResetCause) {
        if cause == ResetCause::Watchdog {
            // Its reaction waits for the velocity, then brakes (`Reaction::BrakeAfterReset`).
            self.latch(Fault::WatchdogReset);
            self.status.faults = self.faults;
            self.status.mode = self.mode_kind();
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
                self.calibration.calibrated = record.calibrated;
                self.calibration.status = record.status();
            }
            Err(e) => self.calibration.status = e.status(),
        }
    }

    /// Loads a record written over the link (already checked: magic, version, CRC), as a
    /// boot load does, and marks it for the storage task. Only with the outputs off and no
    /// operation in progress ([`Mode::Idle`], else [`Refusal::Busy`]): the sin/cos decoders
    /// restart with the new correction, so the zero found by homing no longer holds and the
    /// machine must home again.
    pub fn load_calibration_from_link(&mut self, record: CalibrationRecord) -> Result<(), Refusal> {
        if !matches!(self.mode, Mode::Idle) {
            return Err(Refusal::Busy);
        }
        self.load_calibration(Ok(record));
        self.sensing.zero_raw_m = None;
        self.calibration.unsaved = true;
        Ok(())
    }

    /// The record of the calibration the controller runs on (what a read over the link
    /// returns).
    pub fn calibration_record(&self) -> CalibrationRecord {
        CalibrationRecord::of(&self.calibration.calibrated, &self.config)
    }

    /// Whether the machine may `Start` on its calibration.
    pub fn calibration_status(&self) -> CalibrationStatus {
        self.calibration.status
    }

    /// The record to save, once after each routine that succeeded (the control task hands
    /// it to the storage task; nothing of the save runs in the step).
    pub fn take_calibration_to_save(&mut self) -> Option<CalibrationRecord> {
        if !self.calibration.unsaved {
            return None;
        }
        self.calibration.unsaved = false;
        Some(CalibrationRecord::of(
            &self.calibration.calibrated,
            &self.config,
        ))
    }

    /// The configuration in use.
    pub fn config(&self) -> &ControlConfig {
        &self.config
    }

    /// The snapshot of the last step.
    pub fn status(&self) -> &Status {
        &self.status
    }

    /// What the calibration routines have measured and loaded (and the last failure).
    pub fn calibrated(&self) -> &Calibrated {
        &self.calibration.calibrated
    }

    /// The largest mean phase current seen with the outputs off, A, once enough samples
    /// were seen (the current-sense offset check).
    pub fn current_sense_residual_a(&self) -> Option<f32> {
        self.calibration.sense_monitor.residual_a(&self.config)
    }

    /// The last dead point reached by the running strokes (target and reached, m).
    pub fn last_dead_point(&self) -> Option<DeadPoint> {
        self.last_dead_point
    }

    /// One control cycle: the stages in the order the samples flow through them.
    ///
    /// sense (decode, differentiate, convert) → supervise (limits, faults, host watchdog) →
    /// plan (the mode machine's setpoint) → actuate (position loop, allocation, both
    /// sections' FOC) → rotate (servo, synchronised to the stroke) → publish (status). A
    /// calibration routine, when one runs, takes the outputs after the rest.
    pub fn step(&mut self, inputs: &CycleInputs) -> CycleOutputs {
        self.check_deadline(inputs.t);
        let sensed = self.sense(inputs);
        self.supervise(&sensed);
        let plan = self.plan(&sensed);
        let pwm = self.actuate(inputs, &sensed, plan);
        let stroke = match (&self.mode, &plan) {
            (Mode::Running(g), Some((sp, _))) if !g.waiting() => Some(sp),
            _ => None,
        };
        let servo = self.rotary.rotate(
            sensed.position_m,
            stroke,
            pwm.is_some(),
            &self.config.gas,
            &self.sensing.pressures.last_pa,
        );
        self.publish(inputs.t, &sensed);
        let sections = self.sections_in_service();
        let pwm = if matches!(self.mode, Mode::Calibrating(_)) {
            self.calibration_cycle(inputs)
        } else {
            pwm
        };
        CycleOutputs {
            pwm,
            sections,
            servo,
        }
    }

    /// The publish stage: the status snapshot of this cycle. Kept out of line: inlined, the
    /// register pressure of the whole step costs ~3 instructions per cycle more on the
    /// Cortex-M4 (`scripts/bench-cm4.sh`).
    #[inline(never)]
    fn publish(&mut self, t: Ticks, s: &Sensed) {
        let turn_rad = self.rotary.turns as f32 * core::f32::consts::TAU;
        self.status = Status {
            t,
            mode: self.mode_kind(),
            homed: self.sensing.zero_raw_m.is_some(),
            position_m: s.position_m,
            slave_position_m: s.slave_raw_m - self.sensing.zero_slave_raw_m,
            velocity_mps: s.derivatives.velocity_mps,
            acceleration_mps2: s.derivatives.acceleration_mps2,
            reference_m: self.reference_m().unwrap_or(s.position_m),
            theta_rad: self.rotary.servo.angle_rad() + turn_rad,
            theta_reference_rad: self.rotary.reference_rad + turn_rad,
            force_master_n: s.force_master_n,
            force_slave_n: s.force_slave_n,
            force_command_n: self.status.force_command_n,
            pressure_a_pa: s.pressure_a_pa,
            pressure_b_pa: s.pressure_b_pa,
            faults: self.faults,
            limits: self.supervision.limits,
        };
    }

    /// The sections still in the allocation (a dropped one has capability 0).
    fn sections_in_service(&self) -> PerSection<bool> {
        let cap = &self.config.allocation.capability;
        PerSection {
            master: cap.master > 0.0,
            slave: cap.slave > 0.0,
        }
    }

    /// The position reference the loop tracked in the last cycle (none with outputs off).
    fn reference_m(&self) -> Option<f32> {
        self.setpoint.map(|sp| sp.position_m)
    }

    fn raw_position_m(&self) -> f32 {
        self.status.position_m + self.sensing.zero_raw_m.unwrap_or(0.0)
    }
}
