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

use crate::control::calibration::{
    Calibrated, Calibration, Demand, Measurements, Routine, SenseMonitor,
};
use crate::control::command::{Command, Parameter, Refusal};
use crate::drive::allocation::allocate;
use crate::drive::foc::CurrentController;
use crate::drive::servo::{RotarySetpoint, ServoController};
use crate::motion::stroke::{DeadPoint, StrokeGenerator};
use crate::motion::synchroniser::{Rotation, Synchroniser};
use crate::motion::trajectory::{PointToPoint, Setpoint};
use crate::motion::volume_ratio::{Chamber, RatioTarget, VolumeRatio};
use crate::physics::motor::Dq;
use crate::ports::{EncoderCodes, PhaseCurrentCodes, PressureCodes};
use crate::real::{clamp_f32, max_f32};
use crate::safety::faults::{Fault, FaultSet, ResetCause};
use crate::safety::supervisor::{LimitFlags, Observation, Supervisor};
use crate::sensing::differentiator::{Derivatives, SavitzkyGolay, SgConfig};
use crate::sensing::encoder::{EncoderReading, SinCosDecoder};
use crate::sensing::homing::{Homing, HomingStep};
use crate::sensing::pressure::{StuckConfig, StuckMonitor};
use crate::sensing::quadrature::QuadratureCounter;
use crate::units::{AdcCode, DacCode, PerSection, PhaseDuties, Section, Ticks, CONTROL_PERIOD_US};

/// The window over which holding the stopped piston must need (almost) no force before SS1
/// switches the outputs off, s: 50 ms, ten times the force's settling after the stop ramp.
pub const HOLD_RELEASE_S: f32 = 0.05;

/// Time constant of the controlled stop's disturbance observer, s: 2 ms, four differentiator
/// windows (its acceleration is the noisiest input) and still fast next to the 10–30 ms a
/// stop takes.
pub const DOB_TIME_S: f32 = 0.5e-3;

use crate::control::config::{ConfigError, ControlConfig};
use crate::status::{ModeKind, Status};
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

/// What follows a controlled stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum AfterStop {
    /// Hold where the piston stopped (operator stop).
    Hold,
    /// Outputs off: the second half of SS1 after a fault.
    Off,
    /// Move slowly to the park position and hold there (host lost).
    Park,
}

/// What the position loop is doing.
#[derive(Clone, Debug)]
enum Mode {
    Idle,
    Homing(Homing),
    Holding(Setpoint),
    Moving { path: PointToPoint, elapsed_s: f32 },
    Running(StrokeGenerator),
    Stopping { setpoint: Setpoint, then: AfterStop },
    Faulted,
    Calibrating(Calibration),
}

/// The control step and all its state.
#[derive(Clone, Debug)]
pub struct ControlStep {
    config: ControlConfig,
    encoders: PerSection<SinCosDecoder>,
    differentiator: SavitzkyGolay,
    currents: PerSection<CurrentController>,
    servo: ServoController,
    quadrature: QuadratureCounter,
    mode: Mode,
    /// Raw master position at x = 0 (set by homing), m.
    zero_raw_m: Option<f32>,
    /// Raw slave position at x = 0, m.
    zero_slave_raw_m: f32,
    theta_reference_rad: f32,
    /// Speed of the rotation reference, rad/s.
    theta_reference_speed_rad_s: f32,
    last_t: Option<Ticks>,
    supervisor: Supervisor,
    /// Time since the last heartbeat, s; `None` until the host sends one.
    heartbeat_s: Option<f32>,
    /// The last dead point the running strokes reached.
    last_dead_point: Option<DeadPoint>,
    /// The setpoint of the last cycle (none with outputs off).
    setpoint: Option<Setpoint>,
    synchroniser: Synchroniser,
    volume_ratio: VolumeRatio,
    /// Compressor or expander for the next half cycle.
    rotation: Rotation,
    /// Whole turns the rotation base has moved (status angles are unwrapped with it).
    turns: i32,
    /// Last valid pressures: chamber A, chamber B, suction, discharge, Pa (NaN: none yet).
    pressures_pa: [f32; 4],
    /// The discharge pressure the current half cycle's opening was planned for, Pa.
    planned_discharge_pa: f32,
    /// Force commanded to each section in the last cycle, N.
    shares: PerSection<f32>,
    /// Consecutive cycles with an invalid chamber-pressure sample.
    pressure_bad: u8,
    /// Chamber A and B readings watched for following the volume while running (a stuck
    /// sensor); one of the two is updated per cycle.
    stuck: [StuckMonitor; 2],
    /// Cycles counted for the pressure plausibility check (it runs every 8th cycle).
    stuck_cycles: u8,
    /// The chamber pressures may be used in the feed-forward (false once one is found stuck).
    pressures_trusted: bool,
    /// The encoder that failed while the other still gives the position (its section is
    /// dropped); `None` while both are good.
    lost_encoder: Option<Section>,
    /// Master minus slave position, counts, when the master encoder was lost (the slave
    /// stands in for it at this offset).
    slave_offset_counts: i32,
    /// SS1's hold: time into the current averaging window, s, and the integrals over it of
    /// the motor force and of the measured gas force, N·s.
    hold_quiet_s: f32,
    hold_motor_ns: f32,
    hold_gas_ns: f32,
    /// Each section's capability as configured (restored when faults are cleared).
    nominal_capability: PerSection<f32>,
    /// After a watchdog reset: cycles until the piston is braked (`None`: no reset, or done).
    brake_after_reset_in: Option<u16>,
    /// Deceleration of the controlled stop in progress, m/s².
    stop_decel_mps2: f32,
    /// The stop's estimate of the force the model does not explain, N (toward +x).
    disturbance_n: f32,
    limits: LimitFlags,
    faults: FaultSet,
    status: Status,
    /// What the calibration routines have loaded.
    calibrated: Calibrated,
    /// The phase currents while the outputs are off (current-sense offset detection).
    sense_monitor: SenseMonitor,
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
            encoders: PerSection {
                master: SinCosDecoder::new(config.encoder_master),
                slave: SinCosDecoder::new(config.encoder_slave),
            },
            differentiator,
            currents: PerSection {
                master: current(Section::Master),
                slave: current(Section::Slave),
            },
            servo: ServoController::new(config.servo),
            quadrature: QuadratureCounter::new(),
            mode: Mode::Idle,
            zero_raw_m: None,
            zero_slave_raw_m: 0.0,
            theta_reference_rad: 0.0,
            theta_reference_speed_rad_s: 0.0,
            last_t: None,
            supervisor: Supervisor::new(),
            heartbeat_s: None,
            last_dead_point: None,
            setpoint: None,
            synchroniser: Synchroniser::new(config.port_geometry, 0.0),
            volume_ratio: VolumeRatio::new(config.volume_ratio),
            rotation: Rotation::Compressor,
            turns: 0,
            pressures_pa: [f32::NAN; 4],
            planned_discharge_pa: f32::NAN,
            shares: PerSection::default(),
            pressure_bad: 0,
            stuck: [StuckMonitor::new(StuckConfig::reference()); 2],
            stuck_cycles: 0,
            pressures_trusted: true,
            lost_encoder: None,
            slave_offset_counts: 0,
            hold_quiet_s: 0.0,
            hold_motor_ns: 0.0,
            hold_gas_ns: 0.0,
            nominal_capability: config.allocation.capability,
            brake_after_reset_in: None,
            stop_decel_mps2: config.supervisor.brake_deceleration_mps2,
            disturbance_n: 0.0,
            limits: LimitFlags::default(),
            faults: FaultSet::new(),
            status: Status::INIT,
            calibrated: Calibrated::default(),
            sense_monitor: SenseMonitor::new(),
            config,
        })
    }

    /// Applies the cause of the last reset: after a watchdog reset the machine starts in
    /// the fault state (outputs off, restart inhibited until the fault is cleared).
    ///
    /// The piston may still be moving (a task hung at speed, the outputs held for up to the
    /// watchdog's timeout): once the differentiator has a full window of samples the step
    /// brakes it in the encoders' own frame (the sin/cos angle commutates without the zero,
    /// the incremental position holds it), as SS1 does, and releases the outputs once holding
    /// needs no force. Where the heads are is unknown until homing; the fault stays latched.
    pub fn boot(&mut self, cause: ResetCause) {
        if cause == ResetCause::Watchdog {
            self.latch(Fault::WatchdogReset);
            self.status.faults = self.faults;
            self.status.mode = self.mode_kind();
            self.brake_after_reset_in = Some(self.config.sg_window.saturating_add(5) as u16);
        }
    }

    /// After a watchdog reset: counts the cycles until the velocity estimate is valid, then
    /// starts the controlled stop (see [`ControlStep::boot`]).
    #[cold]
    #[inline(never)]
    fn brake_after_reset(&mut self) {
        let left = self.brake_after_reset_in.unwrap_or(0);
        if left > 0 {
            self.brake_after_reset_in = Some(left - 1);
            return;
        }
        self.brake_after_reset_in = None;
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
        &self.calibrated
    }

    /// The largest mean phase current seen with the outputs off, A, once enough samples
    /// were seen (the current-sense offset check).
    pub fn current_sense_residual_a(&self) -> Option<f32> {
        self.sense_monitor.residual_a(&self.config)
    }

    /// Refuses to switch the outputs on while the phase currents read a current with the
    /// outputs off: the current loops would drive that offset into the motor.
    fn check_current_sense(&self) -> Result<(), Refusal> {
        if self.sense_monitor.offset_detected(&self.config) {
            Err(Refusal::CurrentSenseOffset)
        } else {
            Ok(())
        }
    }

    /// The last dead point reached by the running strokes (target and reached, m).
    pub fn last_dead_point(&self) -> Option<DeadPoint> {
        self.last_dead_point
    }

    /// Refuses a peak speed that is not finite or outside (0, max].
    fn check_speed(&self, peak_speed_mps: f32) -> Result<(), Refusal> {
        if !peak_speed_mps.is_finite() {
            return Err(Refusal::NotFinite);
        }
        if !(peak_speed_mps > 0.0 && peak_speed_mps <= self.config.max_speed_mps) {
            return Err(Refusal::OutOfRange);
        }
        Ok(())
    }

    /// Handles a host command. A refused command changes nothing.
    pub fn command(&mut self, command: Command) -> Result<(), Refusal> {
        match command {
            Command::Heartbeat => {
                // The first heartbeat arms the host watchdog; every one restarts it.
                self.heartbeat_s = Some(0.0);
                Ok(())
            }
            Command::Home => {
                if !self.faults.is_empty() {
                    return Err(Refusal::FaultActive);
                }
                self.check_current_sense()?;
                if !matches!(self.mode, Mode::Idle | Mode::Holding(_)) {
                    return Err(Refusal::Busy);
                }
                self.mode = Mode::Homing(Homing::new(self.config.homing, self.raw_position_m()));
                self.zero_raw_m = None;
                Ok(())
            }
            Command::MoveTo {
                position_m,
                peak_speed_mps,
            } => {
                if !(position_m.is_finite() && peak_speed_mps.is_finite()) {
                    return Err(Refusal::NotFinite);
                }
                let lo = self.config.target_clearance_m;
                let hi = self.config.travel_m - self.config.target_clearance_m;
                let speed_ok = peak_speed_mps > 0.0 && peak_speed_mps <= self.config.max_speed_mps;
                if !((lo..=hi).contains(&position_m) && speed_ok) {
                    return Err(Refusal::OutOfRange);
                }
                if !self.faults.is_empty() {
                    return Err(Refusal::FaultActive);
                }
                if self.zero_raw_m.is_none() {
                    return Err(Refusal::NotHomed);
                }
                let from = match &self.mode {
                    Mode::Holding(sp) => sp.position_m,
                    _ => return Err(Refusal::Busy),
                };
                self.mode = Mode::Moving {
                    path: PointToPoint::new(from, position_m, peak_speed_mps),
                    elapsed_s: 0.0,
                };
                Ok(())
            }
            Command::Start { peak_speed_mps } => {
                self.check_speed(peak_speed_mps)?;
                if !self.faults.is_empty() {
                    return Err(Refusal::FaultActive);
                }
                if self.zero_raw_m.is_none() {
                    return Err(Refusal::NotHomed);
                }
                let Mode::Holding(sp) = &self.mode else {
                    return Err(Refusal::Busy);
                };
                let mut stroke = self.config.stroke;
                stroke.peak_speed_mps = peak_speed_mps;
                let generator = StrokeGenerator::new(stroke, sp.position_m);
                self.begin_half(&generator);
                self.mode = Mode::Running(generator);
                // The plausibility of the chamber pressures is judged over running strokes.
                for m in &mut self.stuck {
                    m.reset();
                }
                Ok(())
            }
            Command::SetSpeed { peak_speed_mps } => {
                self.check_speed(peak_speed_mps)?;
                match &mut self.mode {
                    Mode::Running(g) => {
                        g.set_peak_speed(peak_speed_mps);
                        Ok(())
                    }
                    _ => Err(Refusal::Busy),
                }
            }
            Command::SetParameter { parameter, value } => {
                if !value.is_finite() {
                    return Err(Refusal::NotFinite);
                }
                let (lo, hi) = parameter.range();
                if !(lo..=hi).contains(&value) {
                    return Err(Refusal::OutOfRange);
                }
                // Not while compressing: a gain change mid-stroke is not a tested transition.
                if matches!(self.mode, Mode::Running(_)) {
                    return Err(Refusal::Busy);
                }
                let c = &mut self.config;
                match parameter {
                    Parameter::PositionKp => c.position_kp_n_per_m = value,
                    Parameter::PositionKd => c.position_kd_ns_per_m = value,
                    Parameter::HeartbeatTimeout => c.heartbeat_timeout_s = value,
                    Parameter::ParkPosition => c.park_position_m = value,
                    Parameter::DeadPointGain => c.stroke.correction_gain = value,
                }
                Ok(())
            }
            Command::SetRotation { rotation } => {
                self.rotation = rotation;
                Ok(())
            }
            Command::SetVolumeRatio { target } => {
                if let RatioTarget::Fixed { pressure_ratio } = target {
                    if !pressure_ratio.is_finite() {
                        return Err(Refusal::NotFinite);
                    }
                    if !(1.0..=10.0).contains(&pressure_ratio) {
                        return Err(Refusal::OutOfRange);
                    }
                }
                self.volume_ratio.set_target(target);
                Ok(())
            }
            Command::Stop => {
                match &mut self.mode {
                    Mode::Running(g) => g.request_stop(),
                    _ => self.begin_stop(AfterStop::Hold),
                }
                Ok(())
            }
            Command::Calibrate { routine } => {
                if !self.faults.is_empty() {
                    return Err(Refusal::FaultActive);
                }
                if routine != Routine::CurrentSense {
                    self.check_current_sense()?;
                }
                let homed = self.zero_raw_m.is_some();
                if routine.needs_homing() && !homed {
                    return Err(Refusal::NotHomed);
                }
                let from = match &self.mode {
                    Mode::Holding(sp) => sp.position_m,
                    Mode::Idle => self.status.position_m,
                    _ => return Err(Refusal::Busy),
                };
                let calibration = Calibration::new(routine, &self.config, homed.then_some(from))
                    .map_err(|_| Refusal::OutOfRange)?;
                self.mode = Mode::Calibrating(calibration);
                Ok(())
            }
            Command::ClearFaults => {
                if self.faults.is_empty() {
                    return Ok(());
                }
                // A controlled stop ends on its own (outputs off once holding the piston needs
                // no force): switching off earlier could let the gas throw the piston.
                if matches!(self.mode, Mode::Stopping { .. }) {
                    return Err(Refusal::Busy);
                }
                if self.encoders.master.cause_present()
                    || self.encoders.slave.cause_present()
                    || self.pressure_bad > 0
                {
                    return Err(Refusal::CausePersists);
                }
                self.encoders.master.clear_fault();
                self.encoders.slave.clear_fault();
                // An encoder fault loses the zero: homing is required again.
                if self.faults.contains(Fault::EncoderSignal) {
                    self.zero_raw_m = None;
                }
                self.config.allocation.capability = self.nominal_capability;
                self.lost_encoder = None;
                self.pressures_trusted = true;
                self.faults.clear();
                self.mode = Mode::Idle;
                Ok(())
            }
        }
    }

    /// One control cycle.
    pub fn step(&mut self, inputs: &CycleInputs) -> CycleOutputs {
        let dt = self.config.sample_time_s;
        if let Some(last) = self.last_t {
            // A gap of more than 1.5 periods means at least one cycle was missed.
            let gap_us = inputs.t.since_us(last);
            if gap_us > (CONTROL_PERIOD_US * 3 / 2) as i32 {
                self.latch(Fault::Deadline);
                self.catch_up(gap_us);
            }
        }
        self.last_t = Some(inputs.t);

        let mut master = self.encoders.master.update(inputs.encoders.master);
        let mut slave = self.encoders.slave.update(inputs.encoders.slave);
        if master.signal_fault || slave.signal_fault || self.lost_encoder.is_some() {
            (master.position, slave.position) = self.encoder_fault(&master, &slave);
        }
        let derivatives = self.differentiator.push(master.position);
        let m_per_count = self.config.encoder_master.m_per_count();
        let raw_m = master.position as f32 * m_per_count;
        let slave_raw_m = slave.position as f32 * self.config.encoder_slave.m_per_count();
        let zero = self.zero_raw_m.unwrap_or(0.0);
        let position_m = raw_m - zero;

        let cal = self.config.pressure;
        let pa = cal.convert(inputs.pressures.chamber_a);
        let pb = cal.convert(inputs.pressures.chamber_b);
        let gas_force_n = match (pa.valid(), pb.valid()) {
            (Some(a), Some(b)) if self.pressures_trusted => self.config.cylinder.gas_force_n(a, b),
            _ => 0.0,
        };

        let ps = cal.convert(inputs.pressures.suction);
        let pd = cal.convert(inputs.pressures.discharge);
        for (slot, sample) in self.pressures_pa.iter_mut().zip([pa, pb, ps, pd]) {
            if let Some(p) = sample.valid() {
                *slot = p;
            }
        }

        let count = self.quadrature.update(inputs.quadrature);
        self.servo.observe(count);

        // Measured section forces (before this cycle's FOC step: last cycle's state).
        let kf = self.config.motor.force_constant_n_per_a;
        let force_master = self.currents.master.state().current.q * kf;
        let force_slave = self.currents.slave.state().current.q * kf;

        // Invalid pressure samples never reach the control law (the gas feed-forward above
        // falls back to zero); two in a row latch the fault (one glitch is tolerated).
        let pressures_valid = pa.valid().is_some() && pb.valid().is_some();
        self.pressure_bad = if pressures_valid {
            0
        } else {
            self.pressure_bad.saturating_add(1)
        };
        if self.pressure_bad >= 2 {
            self.latch(Fault::PressureSensor);
        }
        if matches!(self.mode, Mode::Running(_)) {
            self.stuck_cycles = self.stuck_cycles.wrapping_add(1);
            if self.stuck_cycles & 7 == 0 {
                self.check_pressures_follow_volume(inputs, position_m);
            }
        }

        let homed = self.zero_raw_m.is_some();
        let driving = !matches!(self.mode, Mode::Idle | Mode::Faulted);
        // The rotation times the ports only while compressing; in a stop it only holds (or,
        // after a reset, coasts down), whatever the linear motion does.
        let running = matches!(self.mode, Mode::Running(_));
        let rotation_error_rad = if running {
            self.theta_reference_rad - self.servo.angle_rad()
        } else {
            0.0
        };
        // Only looked at once the error is large (never in normal running: the step stays
        // cheap).
        let rotation_stalled = rotation_error_rad.abs()
            > self.config.supervisor.rotation_stall_error_rad
            && self.rotation_stalled();
        let observation = Observation {
            dt_s: dt,
            homed,
            driving: driving && !matches!(self.mode, Mode::Homing(_)),
            position_m,
            slave_position_m: slave_raw_m - self.zero_slave_raw_m,
            velocity_mps: derivatives.velocity_mps,
            reference_m: self.reference_m().unwrap_or(position_m),
            peak_phase_a: max_f32(
                self.currents.master.state().peak_phase_a,
                self.currents.slave.state().peak_phase_a,
            ),
            commanded_n: [self.shares.master, self.shares.slave],
            delivered_n: [force_master, force_slave],
            rotation_error_rad,
            rotation_stalled,
        };
        let verdict = self.supervisor.check(&self.config.supervisor, &observation);
        if let Some(section) = verdict.lost_section {
            self.drop_section(section);
        }
        if let Some(fault) = verdict.fault {
            if fault == Fault::Overcurrent {
                // Drop the section with the excessive current; the other one stops the piston.
                let m = self.currents.master.state().peak_phase_a;
                let s = self.currents.slave.state().peak_phase_a;
                self.drop_section(if m >= s { 0 } else { 1 });
            }
            if fault == Fault::EncoderMismatch {
                self.encoder_mismatch(&master, &slave);
            } else {
                self.latch(fault);
            }
        }

        if let Some(elapsed) = self.heartbeat_s.as_mut() {
            *elapsed += dt;
            if *elapsed >= self.config.heartbeat_timeout_s {
                // Host lost: park (a controlled stop first), not a fault. Disarmed until the
                // host is back.
                self.heartbeat_s = None;
                if matches!(
                    self.mode,
                    Mode::Moving { .. } | Mode::Holding(_) | Mode::Running(_)
                ) {
                    self.begin_stop(AfterStop::Park);
                }
            }
        }

        self.limits = LimitFlags::default();
        let setpoint = self.next_setpoint(raw_m, slave_raw_m, force_master + force_slave, dt);
        self.setpoint = setpoint.map(|(sp, _)| sp);
        let pwm = match setpoint {
            Some((sp, limit)) => {
                let force = self.position_loop(&sp, position_m, &derivatives, gas_force_n, limit);
                self.limits.force = force.abs() >= limit;
                self.status.force_command_n = force;
                let duties = self.drive(
                    inputs,
                    &master,
                    &slave,
                    force,
                    position_m,
                    derivatives.velocity_mps,
                );
                self.limits.voltage = self.currents.master.state().voltage_limited
                    || self.currents.slave.state().voltage_limited;
                Some(duties)
            }
            // A calibration drives the outputs itself, at the end of the step.
            None if matches!(self.mode, Mode::Calibrating(_)) => None,
            None => {
                self.currents.master.reset();
                self.currents.slave.reset();
                self.shares = PerSection::default();
                self.status.force_command_n = 0.0;
                self.sense_monitor.observe(&inputs.currents);
                None
            }
        };

        let servo = if pwm.is_some() {
            let rotary = match (&self.mode, setpoint) {
                (Mode::Running(_), Some((sp, _))) => {
                    self.synchroniser
                        .setpoint(position_m, sp.velocity_mps, sp.acceleration_mps2)
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
        let turn_rad = self.turns as f32 * core::f32::consts::TAU;

        self.status = Status {
            t: inputs.t,
            mode: self.mode_kind(),
            homed: self.zero_raw_m.is_some(),
            position_m,
            slave_position_m: slave_raw_m - self.zero_slave_raw_m,
            velocity_mps: derivatives.velocity_mps,
            acceleration_mps2: derivatives.acceleration_mps2,
            reference_m: self.reference_m().unwrap_or(position_m),
            theta_rad: self.servo.angle_rad() + turn_rad,
            theta_reference_rad: self.theta_reference_rad + turn_rad,
            force_master_n: force_master,
            force_slave_n: force_slave,
            force_command_n: self.status.force_command_n,
            pressure_a_pa: pa.pressure_pa,
            pressure_b_pa: pb.pressure_pa,
            faults: self.faults,
            limits: self.limits,
        };
        let sections = self.sections_in_service();
        if matches!(self.mode, Mode::Calibrating(_)) {
            let pwm = self.calibration_cycle(inputs);
            return CycleOutputs {
                pwm,
                sections,
                servo,
            };
        }
        CycleOutputs {
            pwm,
            sections,
            servo,
        }
    }

    /// The sections still in the allocation (a dropped one has capability 0).
    fn sections_in_service(&self) -> PerSection<bool> {
        let cap = &self.config.allocation.capability;
        PerSection {
            master: cap.master > 0.0,
            slave: cap.slave > 0.0,
        }
    }

    fn mode_kind(&self) -> ModeKind {
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

    /// The position reference the loop tracked in the last cycle (none with outputs off).
    fn reference_m(&self) -> Option<f32> {
        self.setpoint.map(|sp| sp.position_m)
    }

    fn raw_position_m(&self) -> f32 {
        self.status.position_m + self.zero_raw_m.unwrap_or(0.0)
    }

    /// Latches `fault` and starts its reaction: SS1 while the position can be trusted,
    /// STO when it cannot (see [`Fault::position_trusted`]).
    fn latch(&mut self, fault: Fault) {
        self.latch_as(fault, fault.position_trusted());
    }

    /// The one place that moves the machine to its safe state: latches `fault`; with the
    /// position trusted (and known: homed) a controlled stop on the braking envelope that
    /// ends with the outputs off (SS1), otherwise the outputs off at once (STO) — also when
    /// the fault was already latched with the position still trusted then.
    #[cold]
    #[inline(never)]
    fn latch_as(&mut self, fault: Fault, position_trusted: bool) {
        let new = self.faults.latch(fault);
        if !(position_trusted && self.zero_raw_m.is_some()) {
            self.mode = Mode::Faulted;
        } else if new {
            self.begin_stop(AfterStop::Off);
        }
    }

    /// An encoder's error-rate filter tripped, or one was lost before; returns the master
    /// and slave positions, counts, to use from now on. One encoder lost while the other is
    /// good: the good one gives both positions, at the offset between them when the other
    /// was lost (it had extrapolated its last rejected samples, so the position runs on
    /// without a jump and the master/slave cross-check, which has nothing left to compare,
    /// stays quiet); the lost one's section is dropped (its commutation angle is gone) and
    /// the other section stops the piston (SS1). Both lost: nothing tells where the piston
    /// is (STO).
    #[cold]
    #[inline(never)]
    fn encoder_fault(&mut self, master: &EncoderReading, slave: &EncoderReading) -> (i32, i32) {
        let both = (master.position, slave.position);
        let failed = match (master.signal_fault, slave.signal_fault) {
            (true, true) => {
                self.latch_as(Fault::EncoderSignal, false);
                return both;
            }
            (true, false) => Some(Section::Master),
            (false, true) => Some(Section::Slave),
            // Lost earlier by the cross-check.
            (false, false) => None,
        };
        match (failed, self.lost_encoder) {
            (Some(f), Some(lost)) if f != lost => {
                // The other one was lost before: none is left.
                self.latch_as(Fault::EncoderSignal, false);
                return both;
            }
            (Some(f), None) => {
                let trusted = !self.faults.contains(Fault::EncoderMismatch);
                self.lose_encoder(f, master, slave);
                self.latch_as(Fault::EncoderSignal, trusted);
            }
            _ => {}
        }
        let offset = self.slave_offset_counts;
        match self.lost_encoder {
            Some(Section::Master) => (slave.position.wrapping_add(offset), slave.position),
            Some(Section::Slave) => (master.position, master.position.wrapping_sub(offset)),
            None => both,
        }
    }

    /// Takes `failed` out: the other encoder stands in for it from now on, at their present
    /// offset, and its section is dropped. The slave's zero moves to where the two agree
    /// now: the master/slave cross-check has nothing left to compare.
    fn lose_encoder(&mut self, failed: Section, master: &EncoderReading, slave: &EncoderReading) {
        self.lost_encoder = Some(failed);
        self.slave_offset_counts = master.position.wrapping_sub(slave.position);
        let master_raw_m = master.position as f32 * self.config.encoder_master.m_per_count();
        let slave_raw_m = slave.position as f32 * self.config.encoder_slave.m_per_count();
        self.zero_slave_raw_m = slave_raw_m - (master_raw_m - self.zero_raw_m.unwrap_or(0.0));
        self.drop_section(if failed == Section::Master { 0 } else { 1 });
    }

    /// The two encoders disagree. If one of them looks wrong — its error-rate filter is up,
    /// or its amplitude is off nominal by more than 20 % in power while the other's is within
    /// 10 % (a stuck channel passes the amplitude window near the axes and drifts before
    /// the filter trips) — and the other does not, the other is trusted: the suspect is lost
    /// as if its filter had tripped, and SS1 runs on the other (the position carries at most
    /// the disagreement, 2 mm). Otherwise nothing says which one is right: STO.
    #[cold]
    #[inline(never)]
    fn encoder_mismatch(&mut self, master: &EncoderReading, slave: &EncoderReading) {
        let odd = |r: &EncoderReading, d: &SinCosDecoder| {
            d.cause_present() || (r.amplitude_squared - 1.0).abs() > 0.2
        };
        let sound = |r: &EncoderReading, d: &SinCosDecoder| {
            !d.cause_present() && (r.amplitude_squared - 1.0).abs() < 0.1
        };
        let (dm, ds) = (&self.encoders.master, &self.encoders.slave);
        let suspect = if odd(master, dm) && sound(slave, ds) {
            Some(Section::Master)
        } else if odd(slave, ds) && sound(master, dm) {
            Some(Section::Slave)
        } else {
            None
        };
        match (suspect, self.lost_encoder) {
            (Some(s), None) => {
                self.lose_encoder(s, master, slave);
                self.latch_as(Fault::EncoderMismatch, true);
            }
            _ => self.latch_as(Fault::EncoderMismatch, false),
        }
    }

    /// The step missed cycles (`gap_us` since the last one): the encoders moved on
    /// meanwhile, and their decoders expect one period per sample. Feed each decoder (and
    /// the differentiator) the samples it missed as the last velocity predicts them, so the
    /// real sample that follows is judged against where the piston now is, not rejected as
    /// a jump. Up to 40 missed samples (2 ms); beyond that the extrapolation means nothing
    /// and the decoders judge the new sample as they would after a glitch.
    #[cold]
    #[inline(never)]
    fn catch_up(&mut self, gap_us: i32) {
        let period = CONTROL_PERIOD_US as i32;
        let missed = ((gap_us + period / 2) / period - 1).clamp(0, 40) as u32;
        let v = self.status.velocity_mps;
        let zero = self.zero_raw_m.unwrap_or(0.0);
        for section in Section::ALL {
            let (config, decoder, raw_m) = match section {
                Section::Master => (
                    self.config.encoder_master,
                    &mut self.encoders.master,
                    self.status.position_m + zero,
                ),
                Section::Slave => (
                    self.config.encoder_slave,
                    &mut self.encoders.slave,
                    self.status.slave_position_m + self.zero_slave_raw_m,
                ),
            };
            // The last angle from the last position (its 20 fraction bits are the angle's top
            // bits), and the step per period, in 2⁻³² periods (wrapping).
            let counts = (raw_m / config.m_per_count()) as i32;
            let mut angle = (counts as u32) << (32 - crate::sensing::encoder::POSITION_FRAC_BITS);
            let turns = v * self.config.sample_time_s / config.period_m;
            let step = (turns * 4_294_967_296.0) as i64 as u32;
            for _ in 0..missed {
                angle = angle.wrapping_add(step);
                let theta_rad = angle as f32 * (core::f32::consts::TAU / 4_294_967_296.0);
                let (s, c) = config.calibration.codes_at(theta_rad);
                let code = |x: f32| AdcCode(clamp_f32(x + 0.5, 0.0, 4095.0) as u16);
                let reading = decoder.update(crate::ports::SinCosCodes {
                    sin: code(s),
                    cos: code(c),
                });
                if section == Section::Master {
                    self.differentiator.push(reading.position);
                }
            }
        }
    }

    /// The chamber pressures must follow the volume while the piston strokes: a reading that
    /// stays flat over half a stroke each way is stuck (`pressure::StuckMonitor`), and from
    /// then on neither chamber pressure feeds the control law. Called every 8th cycle, for
    /// chamber A and B in turn (each every 0.8 ms: 3 mm of travel at 4 m/s, nothing next to
    /// the 0.1 m the check needs) to keep the 20 kHz step cheap.
    #[cold]
    #[inline(never)]
    fn check_pressures_follow_volume(&mut self, inputs: &CycleInputs, position_m: f32) {
        let (monitor, code) = if self.stuck_cycles & 8 == 0 {
            (&mut self.stuck[0], inputs.pressures.chamber_a)
        } else {
            (&mut self.stuck[1], inputs.pressures.chamber_b)
        };
        if monitor.update(code, position_m) {
            self.pressures_trusted = false;
            self.latch(Fault::PressurePlausibility);
        }
    }

    /// SS1's end: the piston is at rest and held; the outputs go off only once, averaged
    /// over [`HOLD_RELEASE_S`] (the damping term's velocity noise averages out), holding it
    /// needs no more than the static friction and the measured gas force is below half of
    /// it, so friction alone keeps it still. Released earlier, the gas of a compressed
    /// chamber (or an external load) would throw the piston into a head with nothing to stop
    /// it. Until then it stays held, and a new window starts.
    #[cold]
    #[inline(never)]
    fn hold_released(&mut self, dt: f32) -> bool {
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

    /// Starts a controlled stop on the braking deceleration from the measured position and
    /// velocity (not the reference: after a fault the piston may be far from it). Without
    /// outputs on there is nothing to stop: the mode goes straight to its end.
    fn begin_stop(&mut self, then: AfterStop) {
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

    /// Whether the rotation turns at less than a quarter of its reference's speed.
    #[cold]
    #[inline(never)]
    fn rotation_stalled(&self) -> bool {
        self.servo.velocity_rad_s().abs() < 0.25 * self.theta_reference_speed_rad_s.abs()
    }

    /// The disturbance observer of a controlled stop: the force on the piston that the model
    /// does not explain, `m·a − (F_motor + F_gas − F_friction(v))` from the measured
    /// acceleration, motor force (q-currents) and gas force (when the pressures are valid;
    /// otherwise the gas is part of what it estimates), low-passed over [`DOB_TIME_S`]. N,
    /// toward +x.
    #[cold]
    #[inline(never)]
    fn observe_disturbance(&mut self, motor_force_n: f32, dt: f32) -> f32 {
        let c = &self.config;
        let st = &self.status;
        let gas_n = if self.pressures_trusted && self.pressure_bad == 0 {
            c.cylinder.gas_force_n(st.pressure_a_pa, st.pressure_b_pa)
        } else {
            0.0
        };
        let unexplained = c.moving_mass_kg * st.acceleration_mps2 - motor_force_n - gas_n
            + c.friction.force_n(st.velocity_mps);
        if unexplained.is_finite() {
            let alpha = clamp_f32(dt / DOB_TIME_S, 0.0, 1.0);
            self.disturbance_n += alpha * (unexplained - self.disturbance_n);
        }
        // Never more than the sections can push against.
        let limit = c.force_limit_n;
        self.disturbance_n = clamp_f32(self.disturbance_n, -limit, limit);
        self.disturbance_n
    }

    /// The deceleration of a controlled stop from `velocity_mps` at `position_m`: the
    /// braking envelope's `a_brake`, or more when the piston is closer to the head it moves
    /// toward than that needs (a disturbance pushed it past the envelope, which is what
    /// tripped): enough to stop 1 mm short of the minimum clearance with 25 % in hand, up to
    /// `a_brake` per healthy section (`a_brake` is what one section alone guarantees). Without
    /// the zero (after a watchdog reset) the heads' distance is unknown: the most there is.
    fn stop_deceleration(&self, position_m: f32, velocity_mps: f32) -> f32 {
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

    /// Advances the mode; returns the setpoint (position frame after homing) and the force
    /// limit, or `None` when the outputs must be off.
    fn next_setpoint(
        &mut self,
        raw_m: f32,
        slave_raw_m: f32,
        measured_force_n: f32,
        dt: f32,
    ) -> Option<(Setpoint, f32)> {
        let limit = self.config.force_limit_n;
        match &mut self.mode {
            // Calibration drives the outputs itself (`calibration_cycle`).
            Mode::Faulted if self.brake_after_reset_in.is_some() => {
                self.brake_after_reset();
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
                if *elapsed_s >= path.duration_s() {
                    self.mode = Mode::Holding(Setpoint::at_rest(path.target_m()));
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
                            elapsed_s: 0.0,
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

    /// The measured rotation crossed the timed edge: in compressor mode the discharge of
    /// `chamber` just opened, and its pressure now says whether it opened on time.
    fn edge_crossed(&mut self, chamber: Chamber, rotation: Rotation) {
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

    /// Starts the rotation of a new half cycle: where the timed port edge must be crossed
    /// (discharge opening, or expander cut-off) from the measured line pressures.
    fn begin_half(&mut self, g: &StrokeGenerator) {
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

    /// One cycle of a calibration routine, after the rest of the step (supervision, status):
    /// the routine says what to do with the outputs (off, forced current vectors, or
    /// position control along its sweep); when it is done its parameters are loaded and the
    /// machine holds (homed) or goes idle. It reads what it needs from the status this step
    /// has just written, so the normal step carries nothing for it; the rotation is not
    /// driven meanwhile.
    #[cold]
    #[inline(never)]
    fn calibration_cycle(&mut self, inputs: &CycleInputs) -> Option<PerSection<PhaseDuties>> {
        let s = self.status;
        // The encoders' electrical angles from the raw positions (20-bit resolution within
        // the period, 23 nm: far finer than any calibration needs).
        let raw_m = s.position_m + self.zero_raw_m.unwrap_or(0.0);
        let slave_raw_m = s.slave_position_m + self.zero_slave_raw_m;
        let angle_of = |x_m: f32, period_m: f32| crate::angle::turns(x_m / period_m);
        let [pa, pb, _, _] = self.pressures_pa;
        let gas_force_n = if pa.is_finite() && pb.is_finite() {
            self.config.cylinder.gas_force_n(pa, pb)
        } else {
            0.0
        };
        let position_m = s.position_m;
        let Mode::Calibrating(calibration) = &mut self.mode else {
            return None;
        };
        let routine = calibration.routine();
        let measured = Measurements {
            position_m,
            velocity_mps: s.velocity_mps,
            angle: PerSection {
                master: angle_of(raw_m, self.config.encoder_master.period_m),
                slave: angle_of(slave_raw_m, self.config.encoder_slave.period_m),
            },
            currents: &inputs.currents,
            force_n: PerSection {
                master: s.force_master_n,
                slave: s.force_slave_n,
            },
            gas_force_n,
        };
        let mut demand = calibration.step(&self.config, &measured);
        if let Demand::Done(result) = demand {
            if let Ok(outcome) = &result {
                outcome.apply(&mut self.config);
            }
            self.calibrated.record(routine, result);
            let hold = Setpoint::at_rest(position_m);
            (self.mode, demand) = if self.zero_raw_m.is_some() {
                let track = Demand::Track {
                    setpoint: hold,
                    master_only: false,
                    slave_d_a: 0.0,
                };
                (Mode::Holding(hold), track)
            } else {
                (Mode::Idle, Demand::Off)
            };
            self.status.mode = self.mode_kind();
        }
        self.shares = PerSection::default();
        let inv_kf = 1.0 / self.config.motor.force_constant_n_per_a;
        let o = self.config.angle_offset;
        let own_frame = PerSection {
            master: measured.angle.master.wrapping_add(o.master),
            slave: measured.angle.slave.wrapping_add(o.slave),
        };
        // Each section's angle (forced, or its encoder's with its offset) and d/q reference.
        let frames = match demand {
            Demand::Forced(forced) => {
                let frame = |f: Option<crate::control::calibration::Forced>, own: u32| {
                    f.map_or((own, Dq::default()), |f| (f.angle, f.current))
                };
                PerSection {
                    master: frame(forced.master, own_frame.master),
                    slave: frame(forced.slave, own_frame.slave),
                }
            }
            Demand::Track {
                setpoint,
                master_only,
                slave_d_a,
            } => {
                // The position loop as in any mode (the next cycle's supervision checks the
                // following error against this setpoint).
                self.setpoint = Some(setpoint);
                let limit = self.config.force_limit_n;
                let derivatives = Derivatives {
                    velocity_mps: s.velocity_mps,
                    acceleration_mps2: s.acceleration_mps2,
                };
                let force =
                    self.position_loop(&setpoint, position_m, &derivatives, gas_force_n, limit);
                let mut allocation = self.config.allocation;
                if master_only {
                    allocation.capability.slave = 0.0;
                }
                self.shares = allocate(&allocation, force, position_m);
                self.status.reference_m = setpoint.position_m;
                self.status.force_command_n = force;
                self.status.limits.force = force.abs() >= limit;
                PerSection {
                    master: (
                        own_frame.master,
                        Dq {
                            d: 0.0,
                            q: self.shares.master * inv_kf,
                        },
                    ),
                    slave: (
                        own_frame.slave,
                        Dq {
                            d: slave_d_a,
                            q: self.shares.slave * inv_kf,
                        },
                    ),
                }
            }
            Demand::Off | Demand::Done(_) => {
                self.currents.master.reset();
                self.currents.slave.reset();
                return None;
            }
        };
        let mut out = PerSection::<PhaseDuties>::default();
        for section in Section::ALL {
            let (angle, reference) = *frames.get(section);
            let amps = self
                .config
                .current_sense
                .get(section)
                .amps(inputs.currents.get(section));
            *out.get_mut(section) =
                self.currents
                    .get_mut(section)
                    .step(amps, angle, reference, s.velocity_mps);
        }
        self.status.limits.voltage = self.currents.master.state().voltage_limited
            || self.currents.slave.state().voltage_limited;
        Some(out)
    }

    /// Takes a section out of the allocation (lost, or switched off after an overcurrent).
    fn drop_section(&mut self, index: usize) {
        let cap = &mut self.config.allocation.capability;
        if index == 0 {
            cap.master = 0.0;
        } else {
            cap.slave = 0.0;
        }
    }

    /// Position loop with model feed-forward: total motor force, N, saturated at `limit`.
    /// Always inlined: the calibration calls it too, and a second call site must not take
    /// it out of the step.
    #[inline(always)]
    fn position_loop(
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
    fn drive(
        &mut self,
        inputs: &CycleInputs,
        master: &EncoderReading,
        slave: &EncoderReading,
        force_n: f32,
        position_m: f32,
        velocity_mps: f32,
    ) -> PerSection<PhaseDuties> {
        let shares = allocate(&self.config.allocation, force_n, position_m);
        self.shares = shares;
        let inv_kf = 1.0 / self.config.motor.force_constant_n_per_a;
        let mut out = PerSection::<PhaseDuties>::default();
        for (section, angle) in [
            (Section::Master, master.angle),
            (Section::Slave, slave.angle),
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
            *out.get_mut(section) =
                self.currents
                    .get_mut(section)
                    .step(amps, angle, reference, velocity_mps);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_parameter_validates_and_changes_only_what_it_names() {
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        let before = step.config().clone();
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
            assert_eq!(step.config(), &before, "a refused command changes nothing");
        }
        assert_eq!(
            step.command(Command::SetParameter {
                parameter: Parameter::HeartbeatTimeout,
                value: 1.5
            }),
            Ok(())
        );
        let mut expected = before;
        expected.heartbeat_timeout_s = 1.5;
        assert_eq!(step.config(), &expected);
    }
}
