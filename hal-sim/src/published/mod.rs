//! The published rig's controller as a baseline (`fpc-sim run --controller published`):
//! the paper's master/slave drives, written from its text (§2, §4, §4.1, §4.3) and apart
//! from this project's firmware, driving the same simulated plant and sensors.
//!
//! - **Master and slave, each with its own drive.** The master drive closes the position
//!   loop on its own encoder and computes the force setpoint; "the force setpoints … are
//!   transferred to the slave motor directly", which applies them `slave_lag_s` later (the
//!   0.75 ms of Fig. 4, which the paper relates to the cycle time). Each drive commutates its
//!   section on its own encoder with its own current loop ([`drive`]).
//! - **The loop**: position P with velocity feed-forward, velocity PI on the drive's own
//!   velocity estimate, every `cycle_s`; the drive's velocity *reading* is a separate,
//!   8.5 ms-late signal (Fig. 7), logged as `v_drive_mps`. `loop_velocity_delay_s` puts that
//!   delay inside the loop instead (the literal reading of the paper; see
//!   `docs/published-baseline.md` for what each does).
//! - **The motion**: the accelerate-then-stop profile ([`profile`]) between the model's dead
//!   points, the rotation programmed along it in time; no feed-forward of the gas force
//!   (the paper's model-predictive feed-forward was future work).
//!
//! The drives are zeroed before the run (the paper's homing — "slowly moving the piston until
//! its extreme position and detecting the rising current" — is not simulated): `Home` holds
//! the piston where it is for `rest_s` (the at-rest window: "even when the slider was not
//! moving", §4), then moves slowly to dead point A. No supervision: the
//! published drives had none of this project's fault reactions, so `--fault` is refused.

pub mod drive;
pub mod profile;

use std::f64::consts::TAU;
use std::ops::ControlFlow;

use fpc::control::command::Command;
use fpc::motion::volume_ratio::RatioTarget;
use fpc::status::{ModeKind, Status};
use fpc::units::{DacCode, PerSection, Section, Ticks, CONTROL_PERIOD_S};

use crate::board::world::World;
use crate::plant::model::MachineModel;
use drive::{Cascade, CurrentLoop, Delay, EncoderReader, LoopGains};
use profile::{RotationProgramme, Setpoint, Stroke};

/// Speed of the slow moves (to dead point A before the strokes), m/s.
pub const CREEP_MPS: f64 = 0.05;

/// Bandwidth of the rotation servo's position loop, Hz (`docs/machine.md`: ≈ 30 Hz).
pub const SERVO_BANDWIDTH_HZ: f64 = 30.0;

/// What the programme is doing.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Programme {
    /// Holding the reference where it is.
    Hold,
    /// Holding the piston at rest where the drives were zeroed until `until_s` (the at-rest
    /// window), then the slow move to dead point A.
    AtRest { until_s: f64 },
    /// The slow move to dead point A.
    ToDeadPoint,
    /// Strokes; `stop` once the current stroke ends.
    Strokes { stop: bool },
}

/// The published rig: both drives, the rotation servo and the motion programme.
pub struct Rig {
    period_s: f64,
    cycle_periods: u64,
    force_constant: PerSection<f64>,
    current_limit_a: f64,
    electrical_period_m: f64,
    encoders: PerSection<EncoderReader>,
    cascade: Cascade,
    currents: PerSection<CurrentLoop>,
    slave_link: Delay,
    /// Force setpoint of each section from the master drive, N.
    section_force_n: f64,
    /// The slave's setpoint as it arrives, N.
    slave_force_n: f64,
    /// An open-loop replay: the master's force command of each period from the first, N
    /// (the last held after its end), and the period it started.
    replay: Option<(Vec<f64>, u64)>,
    dead_a_m: f64,
    dead_b_m: f64,
    stroke: Stroke,
    toward_b: bool,
    turns: f64,
    rotation: RotationProgramme,
    programme: Programme,
    peak_mps: f64,
    /// The strokes' ramp fraction (`profile_ramp_fraction`).
    ramp_fraction: f64,
    servo: Servo,
    setpoint: Setpoint,
    /// The last status, as the firmware's would read.
    status: Status,
    rest_s: f64,
}

/// The rotation servo drive: PID on its quadrature count with feed-forward of the
/// programmed angular acceleration.
struct Servo {
    counts_per_rev: f64,
    inertia: f64,
    full_scale_nm: f64,
    last_count: u16,
    counts: i64,
    omega_filtered: f64,
    integral: f64,
    angle_rad: f64,
    last_rate: f64,
}

impl Servo {
    fn torque(&mut self, count: u16, theta_ref: f64, rate_ref: f64, period_s: f64) -> f64 {
        let step = count.wrapping_sub(self.last_count) as i16;
        self.last_count = count;
        self.counts += i64::from(step);
        let theta = self.counts as f64 * TAU / self.counts_per_rev;
        let omega = (theta - self.angle_rad) / period_s;
        self.angle_rad = theta;
        self.omega_filtered += (period_s / (1e-3 + period_s)) * (omega - self.omega_filtered);
        let w = TAU * SERVO_BANDWIDTH_HZ;
        let (kp, kd, ki) = (
            self.inertia * w * w,
            1.6 * self.inertia * w,
            0.25 * self.inertia * w * w * w,
        );
        let e = theta_ref - theta;
        let accel_ref = (rate_ref - self.last_rate) / period_s;
        self.last_rate = rate_ref;
        self.integral += ki * e * period_s;
        self.integral = self.integral.clamp(-self.full_scale_nm, self.full_scale_nm);
        let t = self.inertia * accel_ref
            + kp * e
            + kd * (rate_ref - self.omega_filtered)
            + self.integral;
        t.clamp(-self.full_scale_nm, self.full_scale_nm)
    }
}

/// The published drives' cascade gains of `model` at the loop's cycle `cycle_s`, s, its
/// output limited at the force limit or where the sections' current clamp `current_limit_a`,
/// A, acts.
fn loop_gains(model: &MachineModel, cycle_s: f64, current_limit_a: f64) -> LoopGains {
    let p = &model.published;
    let sections = model.motor_sections();
    let cycles = |s: f64| (s / cycle_s).round() as usize;
    // Half the setpoint goes to each section, each clamped at the drive's current: the
    // loop's output is limited where that clamp acts (or at the force limit, if lower),
    // so its integrator stops winding up where the force really stops growing.
    let kf_min = sections
        .master
        .force_constant_n_per_a
        .min(sections.slave.force_constant_n_per_a);
    let clamp_n = 2.0 * kf_min * current_limit_a;
    LoopGains {
        cycle_s,
        position_gain_per_s: p.position_gain_per_s,
        velocity_gain_ns_per_m: p.velocity_gain_ns_per_m,
        velocity_integral_time_s: p.velocity_integral_time_s,
        velocity_feedforward: p.velocity_feedforward,
        velocity_filter_s: p.velocity_filter_s,
        loop_velocity_delay_cycles: cycles(p.loop_velocity_delay_s),
        // A moving average of N backward differences is late by N/2 cycles.
        reported_velocity_cycles: cycles(2.0 * p.reported_velocity_delay_s).max(1),
        force_limit_n: model.limits.force_limit_n.min(clamp_n),
    }
}

impl Rig {
    /// The rig of `model`, its drives zeroed on the piston where `world` has it, the rotation
    /// programmed for the pressure ratio `pressure_ratio` (a fixed volume ratio `target`
    /// programmes its design ratio instead).
    pub fn new(
        model: &MachineModel,
        world: &World,
        pressure_ratio: f64,
        target: RatioTarget,
    ) -> Self {
        let p = &model.published;
        let period_s = f64::from(CONTROL_PERIOD_S);
        let cycle_periods = (p.cycle_s / period_s).round().max(1.0) as u64;
        let cycle_s = cycle_periods as f64 * period_s;
        let sections = model.motor_sections();
        let current_limit_a = if p.current_limit_a > 0.0 {
            p.current_limit_a
        } else {
            sections.master.current_limit_a
        };
        let gains = loop_gains(model, cycle_s, current_limit_a);
        let current = |s: Section| {
            let m = sections.get(s);
            CurrentLoop::new(
                m.resistance_ohm,
                m.inductance_h,
                p.current_bandwidth_hz,
                m.bus_voltage_v,
                m.back_emf_v_per_mps(),
                period_s,
            )
        };
        let codes = world.cycle_inputs().encoders;
        let x0 = world.plant.x_m;
        let enc = |c| EncoderReader::zeroed(model.encoder.period_m, c, x0);
        let clearance = model.limits.target_head_clearance_m;
        let (dead_a_m, dead_b_m) = (clearance, model.piston.travel_m - clearance);
        let pr = match target {
            RatioTarget::Fixed { pressure_ratio } => f64::from(pressure_ratio),
            RatioTarget::FollowMeasured => pressure_ratio,
        };
        let quadrature = world.cycle_inputs().quadrature;
        Rig {
            period_s,
            cycle_periods,
            force_constant: PerSection {
                master: sections.master.force_constant_n_per_a,
                slave: sections.slave.force_constant_n_per_a,
            },
            current_limit_a,
            electrical_period_m: 2.0 * model.motor.pole_pitch_m,
            encoders: PerSection {
                master: enc(codes.master),
                slave: enc(codes.slave),
            },
            cascade: Cascade::new(gains),
            currents: PerSection {
                master: current(Section::Master),
                slave: current(Section::Slave),
            },
            slave_link: Delay::new((p.slave_lag_s / period_s).round() as usize),
            section_force_n: 0.0,
            slave_force_n: 0.0,
            replay: None,
            dead_a_m,
            dead_b_m,
            stroke: Stroke {
                t0_s: 0.0,
                from_m: x0,
                to_m: x0,
                peak_mps: CREEP_MPS,
                ramp_fraction: 0.5,
            },
            toward_b: true,
            turns: 0.0,
            rotation: RotationProgramme::new(model, dead_a_m, dead_b_m, pr),
            programme: Programme::Hold,
            peak_mps: 1.0,
            ramp_fraction: p.profile_ramp_fraction,
            servo: Servo {
                counts_per_rev: f64::from(model.servo.counts_per_rev),
                inertia: model.servo.inertia_kgm2,
                full_scale_nm: model.servo.torque_full_scale_nm,
                last_count: quadrature,
                counts: 0,
                omega_filtered: 0.0,
                integral: 0.0,
                angle_rad: 0.0,
                last_rate: 0.0,
            },
            setpoint: Setpoint {
                x_m: x0,
                ..Setpoint::default()
            },
            status: Status {
                homed: true,
                mode: ModeKind::Holding,
                position_m: x0 as f32,
                slave_position_m: x0 as f32,
                reference_m: x0 as f32,
                ..Status::INIT
            },
            rest_s: p.rest_s,
        }
    }

    /// The status after the last step, in the firmware's vocabulary (what the run logs).
    pub fn status(&self) -> Status {
        self.status
    }

    /// The drive's velocity reading of the last step (`v_drive_mps`), m/s.
    pub fn reported_velocity_mps(&self) -> f64 {
        self.cascade.reported_velocity_mps
    }

    /// A command as an operator gives it: `Home` (the at-rest hold, then the slow move to
    /// dead point A), `Start` (strokes at the peak speed), `Stop` (after the current
    /// stroke). Others are ignored.
    pub fn command(&mut self, command: Command, t_s: f64) {
        match command {
            Command::Home => {
                self.programme = Programme::AtRest {
                    until_s: t_s + self.rest_s,
                };
                self.status.mode = ModeKind::Homing;
            }
            Command::Start { peak_speed_mps } => {
                self.peak_mps = f64::from(peak_speed_mps);
                self.toward_b = true;
                self.stroke = Stroke {
                    t0_s: t_s,
                    from_m: self.setpoint.x_m,
                    to_m: self.dead_b_m,
                    peak_mps: self.peak_mps,
                    ramp_fraction: self.ramp_fraction,
                };
                self.programme = Programme::Strokes { stop: false };
                self.status.mode = ModeKind::Running;
            }
            Command::Stop => {
                if let Programme::Strokes { .. } = self.programme {
                    self.programme = Programme::Strokes { stop: true };
                    self.status.mode = ModeKind::Stopping;
                }
            }
            _ => {}
        }
    }

    /// Moves the reference (without rotating) to `x_m` at peak speed `peak_mps` from `t_s`,
    /// then holds (the closed-port campaign's stop).
    pub fn move_to(&mut self, x_m: f64, peak_mps: f64, t_s: f64) {
        self.stroke = Stroke {
            t0_s: t_s,
            from_m: self.setpoint.x_m,
            to_m: x_m,
            peak_mps,
            ramp_fraction: 0.5,
        };
        self.programme = Programme::Hold;
        self.status.mode = ModeKind::Moving;
    }

    /// Drives the force command open loop from now on: `force_n[k]` in the `k`-th period
    /// (the last value held after the end), the position loop out of the path, as the
    /// paper's closed-port test replayed "the same force as a function of time" (§4).
    pub fn replay_force(&mut self, force_n: Vec<f64>, cycle: u64) {
        self.replay = Some((force_n, cycle));
        self.status.mode = ModeKind::Moving;
    }

    /// Whether the last move has ended.
    pub fn move_done(&self, t_s: f64) -> bool {
        t_s >= self.stroke.end_s()
    }

    /// The references at `t_s`, advancing the programme.
    fn programme(&mut self, t_s: f64) -> (Setpoint, f64, f64) {
        match self.programme {
            Programme::AtRest { until_s } if t_s >= until_s => {
                self.stroke = Stroke {
                    t0_s: t_s,
                    from_m: self.setpoint.x_m,
                    to_m: self.dead_a_m,
                    peak_mps: CREEP_MPS,
                    ramp_fraction: 0.5,
                };
                self.programme = Programme::ToDeadPoint;
            }
            Programme::ToDeadPoint if t_s >= self.stroke.end_s() => {
                self.programme = Programme::Hold;
                self.status.mode = ModeKind::Holding;
            }
            Programme::Strokes { stop } if t_s >= self.stroke.end_s() => {
                if !self.toward_b {
                    self.turns += 1.0;
                }
                if stop {
                    self.programme = Programme::Hold;
                    self.status.mode = ModeKind::Holding;
                } else {
                    self.toward_b = !self.toward_b;
                    let to = if self.toward_b {
                        self.dead_b_m
                    } else {
                        self.dead_a_m
                    };
                    self.stroke = Stroke {
                        t0_s: self.stroke.end_s(),
                        from_m: self.stroke.to_m,
                        to_m: to,
                        peak_mps: self.peak_mps,
                        ramp_fraction: self.ramp_fraction,
                    };
                }
            }
            _ => {}
        }
        let sp = self.stroke.at(t_s);
        let (phase, rate) = match self.programme {
            Programme::Strokes { .. } => self.rotation.phase(&sp, self.toward_b),
            _ => (0.0, 0.0),
        };
        (sp, TAU * self.turns + phase, rate)
    }

    /// One 50 µs period: reads the sampled burst of `world`, writes its outputs.
    pub fn step(&mut self, world: &mut World) {
        let t = world.time_s();
        let inputs = world.cycle_inputs();
        let x = self.encoders.master.read(inputs.encoders.master);
        let xs = self.encoders.slave.read(inputs.encoders.slave);
        let (sp, theta_ref, rate_ref) = self.programme(t);
        self.setpoint = sp;
        if let Some((force_n, from)) = &self.replay {
            let k = usize::try_from(world.cycle().saturating_sub(*from)).unwrap_or(usize::MAX);
            let f = force_n.get(k).or(force_n.last()).copied().unwrap_or(0.0);
            self.status.force_command_n = f as f32;
            self.section_force_n = 0.5 * f;
        } else if world.cycle().is_multiple_of(self.cycle_periods) {
            let f = self.cascade.step(x, sp.x_m, sp.v_mps);
            self.status.force_command_n = f as f32;
            self.section_force_n = 0.5 * f;
        }
        // The slave drive gets the master's setpoint over its link, late.
        self.slave_force_n = self.slave_link.push(self.section_force_n);
        let v = self.cascade.raw_velocity_mps;
        let mut measured = PerSection::<f64>::default();
        for (section, x_enc, force) in [
            (Section::Master, x, self.section_force_n),
            (Section::Slave, xs, self.slave_force_n),
        ] {
            let kf = *self.force_constant.get(section);
            let iq = (force / kf).clamp(-self.current_limit_a, self.current_limit_a);
            let angle = TAU * x_enc / self.electrical_period_m;
            let (s, c) = angle.sin_cos();
            let phase = world.plant.phase_currents(section);
            let duties = self.currents.get_mut(section).step(iq, phase, (s, c), v);
            // The published drives are not this board's timers (whose compare preload puts a
            // written duty in force a period later, `board::world`): their duties act in the
            // period they are written, as this model of them always had it.
            *world.duties.get_mut(section) = duties;
            *world.duties_in_force.get_mut(section) = duties;
            let i = fpc::physics::motor::park(fpc::physics::motor::clarke(phase), s, c);
            *measured.get_mut(section) = kf * i.q;
        }
        world.enabled = true;
        world.sections_on = PerSection {
            master: true,
            slave: true,
        };
        let torque = self
            .servo
            .torque(inputs.quadrature, theta_ref, rate_ref, self.period_s);
        let code = 2048.0 + torque / self.servo.full_scale_nm * 2047.0;
        world.servo_code = DacCode(code.round().clamp(0.0, 4095.0) as u16);
        let s = &mut self.status;
        s.t = Ticks(world.ticks().0);
        s.position_m = x as f32;
        s.slave_position_m = xs as f32;
        s.velocity_mps = self.cascade.reported_velocity_mps as f32;
        s.reference_m = sp.x_m as f32;
        s.theta_rad = self.servo.angle_rad as f32;
        s.theta_reference_rad = theta_ref as f32;
        s.force_master_n = measured.master as f32;
        s.force_slave_n = measured.slave as f32;
        let cal = &world.sensors.pressure.calibration;
        s.pressure_a_pa = cal.convert(inputs.pressures.chamber_a).pressure_pa;
        s.pressure_b_pa = cal.convert(inputs.pressures.chamber_b).pressure_pa;
    }
}

/// Runs the rig on `world` until `each_cycle` breaks: every period the rig reads the burst
/// and writes its outputs, `each_cycle` observes and commands, the world advances — the
/// order of [`crate::board::exec::simulate`].
pub fn simulate<F>(mut world: World, rig: &mut Rig, mut each_cycle: F) -> World
where
    F: FnMut(&mut World, &mut Rig) -> ControlFlow<()>,
{
    loop {
        rig.step(&mut world);
        if each_cycle(&mut world, rig).is_break() {
            break;
        }
        world.advance();
    }
    world
}
