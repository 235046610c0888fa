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
use crate::faults::{Fault, FaultSet};
use crate::foc::{CurrentController, CurrentLoopGains, CurrentSense};
use crate::friction::FrictionParams;
use crate::homing::{Homing, HomingConfig, HomingStep};
use crate::motor::{Dq, MotorParams};
use crate::ports::{EncoderCodes, PhaseCurrentCodes, PressureCodes};
use crate::pressure::PressureCalibration;
use crate::quadrature::QuadratureCounter;
use crate::servo::{RotarySetpoint, ServoConfig, ServoController};
use crate::supervisor::{LimitFlags, Observation, Supervisor, SupervisorConfig};
use crate::trajectory::{PointToPoint, Setpoint};
use crate::units::{DacCode, PerSection, PhaseDuties, Section, Ticks, CONTROL_PERIOD_US};

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
    /// Effective piston area A_eff, m² (gas-force feed-forward).
    pub piston_area_m2: f32,
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
    /// Where the piston parks after homing, m.
    pub park_position_m: f32,
    /// Supervision limits.
    pub supervisor: SupervisorConfig,
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
            piston_area_m2: 6.05e-3,
            encoder_master: EncoderConfig::reference(),
            encoder_slave: EncoderConfig::reference(),
            sg_window: 21,
            sg_order: 2,
            sg_lag: 0,
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
            supervisor: SupervisorConfig::reference(),
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

/// What the position loop is doing.
#[derive(Clone, Debug)]
enum Mode {
    Idle,
    Homing(Homing),
    Holding(Setpoint),
    Moving { path: PointToPoint, elapsed_s: f32 },
    Stopping { setpoint: Setpoint, then_off: bool },
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
            shares: PerSection::default(),
            pressure_bad: 0,
            limits: LimitFlags::default(),
            faults: FaultSet::new(),
            status: Status::INIT,
            config,
        })
    }

    /// The configuration in use.
    pub fn config(&self) -> &ControlConfig {
        &self.config
    }

    /// The snapshot of the last step.
    pub fn status(&self) -> &Status {
        &self.status
    }

    /// Handles a host command. A refused command changes nothing.
    pub fn command(&mut self, command: Command) -> Result<(), Refusal> {
        match command {
            Command::Heartbeat => Ok(()),
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
            Command::Stop => {
                self.begin_stop(false);
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
            (Some(a), Some(b)) => (a - b) * self.config.piston_area_m2,
            _ => 0.0,
        };

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
            peak_phase_a: self
                .currents
                .master
                .state()
                .peak_phase_a
                .max(self.currents.slave.state().peak_phase_a),
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

        self.limits = LimitFlags::default();
        let setpoint = self.next_setpoint(raw_m, slave_raw_m, force_master + force_slave, dt);
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
            self.servo.control(&RotarySetpoint {
                angle_rad: self.theta_reference_rad,
                ..RotarySetpoint::default()
            })
        } else {
            self.theta_reference_rad = self.servo.angle_rad();
            self.servo.command(0.0)
        };

        self.status = Status {
            t: inputs.t,
            mode: self.mode_kind(),
            homed: self.zero_raw_m.is_some(),
            position_m,
            slave_position_m: slave_raw_m - self.zero_slave_raw_m,
            velocity_mps: derivatives.velocity_mps,
            acceleration_mps2: derivatives.acceleration_mps2,
            reference_m: self.reference_m().unwrap_or(position_m),
            theta_rad: self.servo.angle_rad(),
            theta_reference_rad: self.theta_reference_rad,
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
            Mode::Stopping { .. } => ModeKind::Stopping,
            Mode::Faulted => ModeKind::Faulted,
        }
    }

    fn reference_m(&self) -> Option<f32> {
        match &self.mode {
            Mode::Holding(sp) | Mode::Stopping { setpoint: sp, .. } => Some(sp.position_m),
            Mode::Moving { path, elapsed_s } => Some(path.sample(*elapsed_s).position_m),
            _ => None,
        }
    }

    fn raw_position_m(&self) -> f32 {
        self.status.position_m + self.zero_raw_m.unwrap_or(0.0)
    }

    fn latch(&mut self, fault: Fault) {
        if self.faults.latch(fault) {
            if fault.position_trusted() && self.zero_raw_m.is_some() {
                self.begin_stop(true);
            } else {
                self.mode = Mode::Faulted;
            }
        }
    }

    /// Starts a controlled stop from the current reference (SS1 when `then_off`).
    fn begin_stop(&mut self, then_off: bool) {
        let setpoint = match &self.mode {
            Mode::Holding(sp) => *sp,
            Mode::Moving { path, elapsed_s } => path.sample(*elapsed_s),
            Mode::Stopping { setpoint, .. } => *setpoint,
            Mode::Idle | Mode::Homing(_) | Mode::Faulted => {
                self.mode = if then_off { Mode::Faulted } else { Mode::Idle };
                return;
            }
        };
        self.mode = Mode::Stopping { setpoint, then_off };
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
            Mode::Stopping { setpoint, then_off } => {
                let v = setpoint.velocity_mps;
                let dv = self.config.supervisor.brake_deceleration_mps2 * dt;
                let (v_next, a) = if v.abs() <= dv {
                    (0.0, -v / dt)
                } else if v > 0.0 {
                    (v - dv, -self.config.supervisor.brake_deceleration_mps2)
                } else {
                    (v + dv, self.config.supervisor.brake_deceleration_mps2)
                };
                setpoint.position_m += 0.5 * (v + v_next) * dt;
                setpoint.velocity_mps = v_next;
                setpoint.acceleration_mps2 = a;
                let sp = *setpoint;
                if v_next == 0.0 {
                    let off = *then_off;
                    self.mode = if off {
                        Mode::Faulted
                    } else {
                        Mode::Holding(Setpoint::at_rest(sp.position_m))
                    };
                    if off {
                        return None;
                    }
                }
                Some((sp, limit))
            }
        }
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
        let feed_forward = c.moving_mass_kg * sp.acceleration_mps2
            + c.friction.force_n(sp.velocity_mps)
            - gas_force_n;
        let feedback = c.position_kp_n_per_m * (sp.position_m - position_m)
            + c.position_kd_ns_per_m * (sp.velocity_mps - d.velocity_mps);
        let f = feed_forward + feedback;
        if f.is_nan() {
            0.0
        } else {
            f.clamp(-limit, limit)
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
