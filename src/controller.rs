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

use crate::allocation::{allocate, AllocationConfig};
use crate::command::{Command, Refusal};
use crate::differentiator::{Derivatives, SavitzkyGolay, SgConfig, SgError};
use crate::encoder::{EncoderConfig, EncoderReading, SinCosDecoder};
use crate::faults::{Fault, FaultSet, ResetCause};
use crate::foc::{CurrentController, CurrentLoopGains, CurrentSense};
use crate::friction::FrictionParams;
use crate::gas::{Cylinder, GasProperties};
use crate::homing::{Homing, HomingConfig, HomingStep};
use crate::motor::{Dq, MotorParams};
use crate::port_timing::PortGeometry;
use crate::ports::{EncoderCodes, PhaseCurrentCodes, PressureCodes};
use crate::pressure::PressureCalibration;
use crate::quadrature::QuadratureCounter;
use crate::real::{clamp_f32, max_f32};
use crate::servo::{RotarySetpoint, ServoConfig, ServoController};
use crate::stroke::{DeadPoint, StrokeConfig, StrokeGenerator};
use crate::supervisor::{LimitFlags, Observation, Supervisor, SupervisorConfig};
use crate::synchroniser::{Rotation, Synchroniser};
use crate::trajectory::{PointToPoint, Setpoint};
use crate::units::{DacCode, PerSection, PhaseDuties, Section, Ticks, CONTROL_PERIOD_US};
use crate::volume_ratio::{Chamber, RatioTarget, VolumeRatio, VolumeRatioConfig};

/// Everything the control step needs to know about the machine, in SI units.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlConfig {
    /// Control period, s.
    pub sample_time_s: f32,
    /// Head-to-head travel, m.
    pub travel_m: f32,
    /// Clearance to a head that commanded positions must keep, m (target 1 mm).
    pub target_clearance_m: f32,
    /// Moving mass, m (feed-forward).
    pub moving_mass_kg: f32,
    /// Friction law (feed-forward).
    pub friction: FrictionParams<f32>,
    /// Cylinder geometry: area and chamber volumes (gas force, volume ratio).
    pub cylinder: Cylinder<f32>,
    /// The working gas.
    pub gas: GasProperties<f32>,
    /// Port windows of the rotation.
    pub port_geometry: PortGeometry<f32>,
    /// Stroke-by-stroke volume-ratio correction.
    pub volume_ratio: VolumeRatioConfig,
    /// Master-section encoder.
    pub encoder_master: EncoderConfig,
    /// Slave-section encoder.
    pub encoder_slave: EncoderConfig,
    /// Differentiator window (odd, ≤ 41).
    pub sg_window: usize,
    /// Differentiator polynomial order.
    pub sg_order: usize,
    /// Differentiator evaluation point, samples back from the newest.
    pub sg_lag: usize,
    /// Model feed-forward (m·a + friction − gas force) on; off only to measure what it is
    /// worth.
    pub feed_forward: bool,
    /// Position-loop stiffness, N/m.
    pub position_kp_n_per_m: f32,
    /// Position-loop damping, N·s/m.
    pub position_kd_ns_per_m: f32,
    /// Total force limit of both sections, N.
    pub force_limit_n: f32,
    /// Largest commanded speed, m/s.
    pub max_speed_mps: f32,
    /// Motor section parameters (both sections alike).
    pub motor: MotorParams<f32>,
    /// Split of the force over the sections, cogging compensation.
    pub allocation: AllocationConfig,
    /// Current-loop gains.
    pub current_gains: CurrentLoopGains,
    /// Current-sense calibration per section.
    pub current_sense: PerSection<CurrentSense>,
    /// Electrical-angle offset per section (wrapping, 2³² = one period), from alignment.
    pub angle_offset: PerSection<u32>,
    /// Rotation servo.
    pub servo: ServoConfig,
    /// Pressure-sensor calibration (all four channels alike).
    pub pressure: PressureCalibration,
    /// Homing.
    pub homing: HomingConfig,
    /// Where the piston parks after homing or when the host is lost, m.
    pub park_position_m: f32,
    /// Peak speed of a park move, m/s.
    pub park_speed_mps: f32,
    /// Time without a heartbeat after which the piston parks (once heartbeats were seen), s.
    pub heartbeat_timeout_s: f32,
    /// Supervision limits.
    pub supervisor: SupervisorConfig,
    /// The periodic stroke (its peak speed is set by the start command).
    pub stroke: StrokeConfig,
}

impl ControlConfig {
    /// The reference machine of `machine.md`.
    pub fn reference() -> Self {
        let motor = MotorParams::<f32>::reference();
        ControlConfig {
            sample_time_s: 50e-6,
            travel_m: 0.205,
            target_clearance_m: 1.0e-3,
            moving_mass_kg: 12.0,
            friction: FrictionParams::reference(),
            cylinder: Cylinder::reference(),
            gas: GasProperties::air(),
            port_geometry: PortGeometry::reference(),
            volume_ratio: VolumeRatioConfig::reference(),
            encoder_master: EncoderConfig::reference(),
            encoder_slave: EncoderConfig::reference(),
            // 25, not 21: acceleration error 3.8 % vs 4.5 % of peak on a 4 m/s stroke at
            // σx = 1 µm, same cost (tests/velocity_estimate_quality.rs).
            sg_window: 25,
            sg_order: 2,
            sg_lag: 0,
            feed_forward: true,
            // ≈ 40 Hz position bandwidth on 12 kg, damping 0.8.
            position_kp_n_per_m: 7.5e5,
            position_kd_ns_per_m: 4.8e3,
            force_limit_n: 10_000.0,
            max_speed_mps: 4.5,
            current_gains: CurrentLoopGains::for_bandwidth(&motor, 8000.0),
            allocation: AllocationConfig::reference(),
            motor,
            current_sense: PerSection {
                master: CurrentSense::reference(),
                slave: CurrentSense::reference(),
            },
            angle_offset: PerSection::default(),
            servo: ServoConfig::reference(),
            pressure: PressureCalibration::reference(),
            homing: HomingConfig::reference(),
            park_position_m: 0.01,
            park_speed_mps: 0.2,
            heartbeat_timeout_s: 0.5,
            supervisor: SupervisorConfig::reference(),
            stroke: StrokeConfig::reference(2.3),
        }
    }
}

/// Why a configuration was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConfigError {
    /// The differentiator configuration is invalid.
    Differentiator(SgError),
    /// A physical parameter is not finite and positive (names the field).
    NotPositive(&'static str),
}

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
    /// Servo torque command.
    pub servo: DacCode,
}

/// Operating mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ModeKind {
    /// Outputs off, waiting for a command.
    Idle,
    /// Searching the zero.
    Homing,
    /// Holding a position.
    Holding,
    /// Executing a move.
    Moving,
    /// Compressing: continuous strokes.
    Running,
    /// Controlled stop in progress.
    Stopping,
    /// A fault is latched; outputs off.
    Faulted,
}

impl ModeKind {
    /// Stable lower-case name.
    pub const fn name(self) -> &'static str {
        match self {
            ModeKind::Idle => "idle",
            ModeKind::Homing => "homing",
            ModeKind::Holding => "holding",
            ModeKind::Moving => "moving",
            ModeKind::Running => "running",
            ModeKind::Stopping => "stopping",
            ModeKind::Faulted => "faulted",
        }
    }
}

/// A snapshot of the machine after a step: what the run log and telemetry record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Status {
    /// Sampling instant.
    pub t: Ticks,
    /// Mode.
    pub mode: ModeKind,
    /// The zero is known.
    pub homed: bool,
    /// Position from the master encoder, m.
    pub position_m: f32,
    /// Position from the slave encoder, m.
    pub slave_position_m: f32,
    /// Velocity, m/s (differentiator).
    pub velocity_mps: f32,
    /// Acceleration, m/s² (differentiator).
    pub acceleration_mps2: f32,
    /// Position reference, m.
    pub reference_m: f32,
    /// Rotation angle, rad.
    pub theta_rad: f32,
    /// Rotation reference, rad.
    pub theta_reference_rad: f32,
    /// Force of the master section from its measured q-current, N.
    pub force_master_n: f32,
    /// Force of the slave section from its measured q-current, N.
    pub force_slave_n: f32,
    /// Total force commanded, N.
    pub force_command_n: f32,
    /// Chamber A pressure as converted, Pa (its validity is supervised separately).
    pub pressure_a_pa: f32,
    /// Chamber B pressure as converted, Pa.
    pub pressure_b_pa: f32,
    /// Latched faults.
    pub faults: FaultSet,
    /// Limits active this cycle.
    pub limits: LimitFlags,
}

impl Status {
    /// The state before the first step.
    pub const INIT: Status = Status {
        t: Ticks(0),
        mode: ModeKind::Idle,
        homed: false,
        position_m: 0.0,
        slave_position_m: 0.0,
        velocity_mps: 0.0,
        acceleration_mps2: 0.0,
        reference_m: 0.0,
        theta_rad: 0.0,
        theta_reference_rad: 0.0,
        force_master_n: 0.0,
        force_slave_n: 0.0,
        force_command_n: 0.0,
        pressure_a_pa: 0.0,
        pressure_b_pa: 0.0,
        faults: FaultSet::new(),
        limits: LimitFlags {
            force: false,
            voltage: false,
            envelope: false,
        },
    };
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
    limits: LimitFlags,
    faults: FaultSet,
    status: Status,
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
            limits: LimitFlags::default(),
            faults: FaultSet::new(),
            status: Status::INIT,
            config,
        })
    }

    /// Applies the cause of the last reset: after a watchdog reset the machine starts in
    /// the fault state (outputs off, restart inhibited until the fault is cleared).
    pub fn boot(&mut self, cause: ResetCause) {
        if cause == ResetCause::Watchdog {
            self.latch(Fault::WatchdogReset);
            self.status.faults = self.faults;
            self.status.mode = self.mode_kind();
        }
    }

    /// The configuration in use.
    pub fn config(&self) -> &ControlConfig {
        &self.config
    }

    /// The snapshot of the last step.
    pub fn status(&self) -> &Status {
        &self.status
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
            Command::ClearFaults => {
                if self.faults.is_empty() {
                    return Ok(());
                }
                if self.encoders.master.cause_present() || self.encoders.slave.cause_present() {
                    return Err(Refusal::CausePersists);
                }
                self.encoders.master.clear_fault();
                self.encoders.slave.clear_fault();
                // An encoder fault loses the zero: homing is required again.
                if self.faults.contains(Fault::EncoderSignal) {
                    self.zero_raw_m = None;
                }
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
            if inputs.t.since_us(last) > (CONTROL_PERIOD_US * 3 / 2) as i32 {
                self.latch(Fault::Deadline);
            }
        }
        self.last_t = Some(inputs.t);

        let master = self.encoders.master.update(inputs.encoders.master);
        let slave = self.encoders.slave.update(inputs.encoders.slave);
        if master.signal_fault || slave.signal_fault {
            self.latch(Fault::EncoderSignal);
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
            (Some(a), Some(b)) => self.config.cylinder.gas_force_n(a, b),
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

        let homed = self.zero_raw_m.is_some();
        let driving = !matches!(self.mode, Mode::Idle | Mode::Faulted);
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
            rotation_error_rad: if driving {
                self.theta_reference_rad - self.servo.angle_rad()
            } else {
                0.0
            },
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
            self.latch(fault);
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
            None => {
                self.currents.master.reset();
                self.currents.slave.reset();
                self.shares = PerSection::default();
                self.status.force_command_n = 0.0;
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
        CycleOutputs { pwm, servo }
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
        }
    }

    /// The position reference the loop tracked in the last cycle (none with outputs off).
    fn reference_m(&self) -> Option<f32> {
        self.setpoint.map(|sp| sp.position_m)
    }

    fn raw_position_m(&self) -> f32 {
        self.status.position_m + self.zero_raw_m.unwrap_or(0.0)
    }

    fn latch(&mut self, fault: Fault) {
        if self.faults.latch(fault) {
            if fault.position_trusted() && self.zero_raw_m.is_some() {
                self.begin_stop(AfterStop::Off);
            } else {
                self.mode = Mode::Faulted;
            }
        }
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
        self.mode = Mode::Stopping { setpoint, then };
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
            Mode::Idle | Mode::Faulted => None,
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
                let brake = self.config.supervisor.brake_deceleration_mps2;
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
                let sp = *setpoint;
                if v_next == 0.0 {
                    let then = *then;
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
