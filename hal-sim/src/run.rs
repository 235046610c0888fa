//! `fpc-sim run`: the closed-loop simulation of the machine with the firmware in the loop.
//!
//! The host side of the run plays the operator: it homes the axis, then commands strokes
//! between the two dead points (1 mm from each head) at the requested peak speed for the
//! requested number of cycles, exactly as it would over the RTT command channel. Everything
//! the firmware does, it does in its own task bodies against the simulated board.
//!
//! With fault specifications (`--fault`, [`crate::faults::apply`]) the faults are injected as
//! the run goes, the board's watchdog can reset it ([`crate::board::exec::simulate_board`]), and the
//! run goes on past the first latched fault until each fault's outcome is known.

use std::io::Write;
use std::ops::ControlFlow;
use std::time::Instant;

use fpc::control::command::Command;
use fpc::control::config::ControlConfig;
use fpc::safety::faults::Fault;
use fpc::status::{ModeKind, Status};
use fpc::units::CONTROL_PERIOD_S;
use serde::Serialize;

use crate::board::exec::{simulate_board, Execution, SimShared, WATCHDOG_TIMEOUT_US};
use crate::board::world::World;
use crate::failure::num;
use crate::faults::apply::{InjectionReport, Injector};
use crate::faults::inject::FaultSpec;
use crate::plant::chambers::PortMode;
use crate::plant::model::validate::PRESSURE_FULL_SCALE_PA;
use crate::plant::model::MachineModel;
use crate::runlog::{RunLog, REQUIRED};

/// Pressure ratio → peak speed of the paper's Fig. 3 (PR, m/s).
pub const FIG3_SPEEDS: [(f64, f64); 4] = [(3.1, 2.3), (3.7, 2.8), (4.3, 3.5), (5.1, 4.1)];

/// Accepted pressure ratios. Near 1 the volume ratio is so near 1 that the discharge port
/// opens almost as the intake closes, and at speed the rotation cannot time the ports: the
/// run stops on `rotation_sync` (measured on the reference machine: 1.0–1.05 at every
/// speed, 1.1 from 2.8 m/s, 1.2 from 4 m/s, 1.3 and 1.4 at 4.5 m/s within 10 cycles; 1.5
/// runs 100 cycles clean at 0.05–4.5 m/s).
pub const PRESSURE_RATIO_RANGE: (f64, f64) = (1.5, 6.0);
/// Accepted peak speeds, m/s (and never above the model's `limits.max_speed_mps`).
pub const SPEED_RANGE_MPS: (f64, f64) = (0.05, 4.5);
/// Accepted `--cycles`: at least one; the upper bound keeps a run's wall time within about
/// an hour at the slowest speed.
pub const CYCLES_RANGE: (u32, u32) = (1, 10_000);
/// Homing creeps at about this speed, m/s: the time it may take is the travel at this
/// speed, plus [`STALL_SPARE_S`].
pub const HOMING_SPEED_MPS: f64 = 0.01;
/// Spare time for each stage of a run (homing, a cycle, the stop), s simulated: a stage
/// that takes longer than its expected time plus this has stalled, and the run ends
/// saying so rather than running out the whole run's time.
pub const STALL_SPARE_S: f64 = 2.0;

/// How far the section forces in a run-log row lag its position, s (`# force_delay_s`):
/// one control period — the firmware's status reports each section's force from the current
/// measured in the previous cycle.
pub const FIRMWARE_FORCE_DELAY_S: f64 = 50e-6;

/// Options of a run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The machine.
    pub model: MachineModel,
    /// Where the model came from (for the log's metadata).
    pub model_name: String,
    /// Target pressure ratio.
    pub pressure_ratio: f64,
    /// Peak speed, m/s (`None`: from the pressure ratio as in Fig. 3).
    pub speed_mps: Option<f64>,
    /// Compression cycles (A → B → A) to run.
    pub cycles: u32,
    /// Noise seed.
    pub seed: u64,
    /// What the board's µs time base reads at the start (to exercise its wrap).
    pub start_us: u32,
    /// Where the piston rests at power-up, m from head A.
    pub start_position_m: f64,
    /// Telemetry: one frame every this many control cycles, captured in
    /// [`RunOutcome::telemetry`]; 0 = off.
    pub telemetry_decimation: u16,
    /// Relative error of the controller's model against the plant: its mass and friction
    /// are (1 + this) × the plant's (the acceptance runs use 0.05).
    pub model_error: f64,
    /// The controller's configuration is otherwise the reference; this may change it (tests
    /// switch the feed-forward off with it).
    pub configure: Option<fn(&mut ControlConfig)>,
    /// What the host does during the run, by completed compression cycle.
    pub schedule: Vec<(u32, HostAction)>,
    /// Faults injected during the run (`--fault`; `faults.md` scenarios). With faults the
    /// run does not end at the first latched fault: it runs on until each fault's outcome
    /// (the stop, the piston at rest, homing's end) is known.
    pub faults: Vec<FaultSpec>,
    /// Timeout of the board's independent watchdog, µs (the board's
    /// [`crate::board::exec::WATCHDOG_TIMEOUT_US`]; a run may try another).
    pub watchdog_timeout_us: u64,
}

/// Something the host does at the start of a given cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HostAction {
    /// Change the discharge-line pressure to this ratio over the suction pressure (the load).
    SetLinePressureRatio(f64),
    /// Send a command to the firmware.
    Command(Command),
}

impl RunOptions {
    /// Defaults on the reference machine.
    pub fn reference() -> Self {
        RunOptions {
            model: MachineModel::reference(),
            model_name: "reference".into(),
            pressure_ratio: 3.1,
            speed_mps: None,
            cycles: 10,
            seed: 1,
            start_us: 0,
            start_position_m: 0.005,
            telemetry_decimation: 0,
            model_error: 0.0,
            configure: None,
            schedule: Vec::new(),
            faults: Vec::new(),
            watchdog_timeout_us: WATCHDOG_TIMEOUT_US,
        }
    }

    /// Peak speed to use, m/s.
    pub fn peak_speed_mps(&self) -> f64 {
        self.speed_mps
            .unwrap_or_else(|| speed_for_pressure_ratio(self.pressure_ratio))
    }

    /// The longest the run may last, s simulated: homing creeps at 10 mm/s over at most the
    /// travel; a cycle is two strokes of the sinusoidal reference (mean speed 2/π of the
    /// peak), with 2 s to spare each.
    pub fn time_limit_s(&self) -> f64 {
        self.homing_limit_s() + f64::from(self.cycles) * self.cycle_limit_s() + STALL_SPARE_S
    }

    /// The longest homing may take, s simulated: the whole travel at [`HOMING_SPEED_MPS`]
    /// and [`STALL_SPARE_S`].
    pub fn homing_limit_s(&self) -> f64 {
        STALL_SPARE_S + self.model.piston.travel_m / HOMING_SPEED_MPS
    }

    /// The longest one compression cycle may take, s simulated: twice two strokes of the
    /// sinusoidal reference (mean speed 2/π of the peak; a cycle measured at 0.05 m/s takes
    /// 1.35 times that) and [`STALL_SPARE_S`].
    pub fn cycle_limit_s(&self) -> f64 {
        STALL_SPARE_S
            + 2.0 * std::f64::consts::PI * self.model.piston.travel_m / self.peak_speed_mps()
    }

    /// Checks the options; the error names the flag at fault.
    pub fn validate(&self) -> Result<(), String> {
        let (lo, hi) = PRESSURE_RATIO_RANGE;
        if !(self.pressure_ratio.is_finite() && (lo..=hi).contains(&self.pressure_ratio)) {
            return Err(format!(
                "--pressure-ratio {} is outside [{lo}, {hi}] (below {lo} the rotation cannot \
                 time the ports at speed)",
                num(self.pressure_ratio)
            ));
        }
        let suction = self.model.lines.suction_pa;
        if suction * self.pressure_ratio > PRESSURE_FULL_SCALE_PA {
            return Err(format!(
                "--pressure-ratio {} with the model's `lines.suction_pa` = {} Pa puts the \
                 discharge line beyond the pressure sensors' full scale {} Pa (at most {:.2})",
                num(self.pressure_ratio),
                num(suction),
                num(PRESSURE_FULL_SCALE_PA),
                PRESSURE_FULL_SCALE_PA / suction
            ));
        }
        let (lo, hi) = SPEED_RANGE_MPS;
        if let Some(v) = self.speed_mps {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(format!("--speed {} is outside [{lo}, {hi}] m/s", num(v)));
            }
        }
        let max = self.model.limits.max_speed_mps;
        let v = self.peak_speed_mps();
        if v > max {
            let flag = match self.speed_mps {
                Some(_) => format!("--speed {}", num(v)),
                None => format!(
                    "--pressure-ratio {} asks for {} m/s (Fig. 3; give --speed) and",
                    num(self.pressure_ratio),
                    num(v)
                ),
            };
            return Err(format!(
                "{flag} is above the model's `limits.max_speed_mps` = {} m/s: the machine \
                 may not go that fast (range [{lo}, {}] m/s)",
                num(max),
                num(max.min(hi))
            ));
        }
        let (lo, hi) = CYCLES_RANGE;
        if !(lo..=hi).contains(&self.cycles) {
            return Err(format!("--cycles {} is outside [{lo}, {hi}]", self.cycles));
        }
        let limit = self.time_limit_s();
        if let Some(late) = self.faults.iter().find(|f| f.at_s > limit) {
            return Err(format!(
                "--fault {}@{}: the run lasts at most {limit:.1} s simulated ({} cycles at \
                 {} m/s); it would never be injected",
                late.kind.name(),
                num(late.at_s),
                self.cycles,
                num(v)
            ));
        }
        Ok(())
    }
}

/// Peak speed for a pressure ratio, interpolated (and held at the ends) in Fig. 3's table.
pub fn speed_for_pressure_ratio(pr: f64) -> f64 {
    let mut prev = FIG3_SPEEDS[0];
    if pr <= prev.0 {
        return prev.1;
    }
    for &(p, v) in &FIG3_SPEEDS[1..] {
        if pr <= p {
            return prev.1 + (v - prev.1) * (pr - prev.0) / (p - prev.0);
        }
        prev = (p, v);
    }
    prev.1
}

/// The JSON summary of a run (`formats.md` §3). `None` is printed as `null`: a figure that
/// this simulation cannot yet produce is never invented.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Summary {
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Wall-clock time of the simulation, s.
    pub wall_time_s: f64,
    /// Simulated seconds per wall second.
    pub realtime_factor: f64,
    /// Completed compression cycles.
    pub cycles: u32,
    /// Cycles asked for (`--cycles`).
    pub cycles_requested: u32,
    /// Why the run ended before `cycles_requested`, if it did (a latched fault, a stage that
    /// made no progress, the injected faults' outcome known); `null` when it completed.
    pub stopped_early: Option<String>,
    /// The `--fault` specifications the run ended before (`NAME@T`): never injected.
    pub faults_not_injected: Vec<String>,
    /// Requested pressure ratio.
    pub pressure_ratio_target: f64,
    /// Max over the last 5 cycles of |p_chamber − p_discharge|/p_discharge at discharge
    /// opening (needs the chamber model).
    pub discharge_open_pressure_error: Option<f64>,
    /// RMS of (piston position − reference) while compressing, m.
    pub tracking_error_rms_m: Option<f64>,
    /// Indicated work per cycle, ∮p·dV over both chambers, mean of the last 5 cycles, J.
    pub indicated_work_j_per_cycle: Option<f64>,
    /// Max over the last 5 cycles of |reached − target| dead point, m.
    pub dead_point_error_m: Option<f64>,
    /// Smallest distance to a head after homing, m.
    pub min_head_clearance_m: Option<f64>,
    /// Largest |velocity|, m/s.
    pub peak_speed_mps: f64,
    /// RMS of the master − slave force difference while stroking, N.
    pub master_slave_force_diff_rms_n: Option<f64>,
    /// Faults in the order latched.
    pub faults: Vec<String>,
    /// Final mode.
    pub state: String,
}

/// A finished run: the summary and the run log.
#[derive(Clone, Debug)]
pub struct RunOutcome {
    /// Figures.
    pub summary: Summary,
    /// The log (what `run.csv` holds).
    pub log: RunLog,
    /// The bytes the firmware's telemetry task sent (empty when telemetry is off).
    pub telemetry: Vec<u8>,
    /// (cycles completed before it, |p_chamber − p_d|/p_d) at every discharge opening.
    pub opening_errors: Vec<(u32, f64)>,
    /// Indicated work of each completed cycle, both chambers, J (negative: the gas did
    /// work, as in an expander).
    pub cycle_work_j: Vec<f64>,
    /// Work the motor sections did on the piston in each completed cycle, J.
    pub cycle_motor_work_j: Vec<f64>,
    /// What the injected faults did (empty without faults).
    pub injection: InjectionReport,
}

/// Columns of the simulator's run log: the required ones, then optional ones.
pub const COLUMNS: [&str; 18] = [
    REQUIRED[0],
    REQUIRED[1],
    REQUIRED[2],
    REQUIRED[3],
    REQUIRED[4],
    REQUIRED[5],
    REQUIRED[6],
    REQUIRED[7],
    "x_ref_m",
    "theta_ref_rad",
    "v_mps",
    "fault",
    // The plant's truth (simulator only): chamber pressures and volumes, line pressures.
    "p_a_true_pa",
    "p_b_true_pa",
    "vol_a_m3",
    "vol_b_m3",
    "p_suction_pa",
    "p_discharge_pa",
];

/// The controller's configuration for a model: the firmware's reference tuning with the
/// model's machine parameters.
pub fn control_config(model: &MachineModel) -> ControlConfig {
    let mut c = ControlConfig::reference();
    c.moving_mass_kg = model.piston.mass_kg as f32;
    c.travel_m = model.piston.travel_m as f32;
    c.cylinder = fpc::physics::gas::Cylinder::from_bore(
        model.piston.bore_m as f32,
        model.piston.rod_m as f32,
        model.piston.travel_m as f32,
        model.piston.dead_length_a_m as f32,
        model.piston.dead_length_b_m as f32,
    );
    let f = model.friction();
    c.friction.coulomb_n = f.coulomb_n as f32;
    c.friction.static_n = f.static_n as f32;
    c.friction.viscous_ns_per_m = f.viscous_ns_per_m as f32;
    c.friction.stribeck_velocity_mps = f.stribeck_velocity_mps as f32;
    c.friction.stribeck_exponent = f.stribeck_exponent as f32;
    c.encoder_master.period_m = model.encoder.period_m as f32;
    c.encoder_slave.period_m = model.encoder.period_m as f32;
    c.motor.electrical_period_m = (2.0 * model.motor.pole_pitch_m) as f32;
    let m = model.motor_sections().master;
    c.motor.force_constant_n_per_a = m.force_constant_n_per_a as f32;
    c.motor.resistance_ohm = m.resistance_ohm as f32;
    c.motor.inductance_h = m.inductance_h as f32;
    c.motor.bus_voltage_v = m.bus_voltage_v as f32;
    c.motor.current_limit_a = m.current_limit_a as f32;
    c.servo.inertia_kgm2 = model.servo.inertia_kgm2 as f32;
    c.servo.torque_full_scale_nm = model.servo.torque_full_scale_nm as f32;
    c.servo.counts_per_rev = model.servo.counts_per_rev;
    c.target_clearance_m = model.limits.target_head_clearance_m as f32;
    // The dead points at the target clearance from each head of this model's travel (the
    // firmware's reference stroke is for a 0.205 m travel: on another travel it stroked into
    // a head or short of it).
    let clearance = model.limits.target_head_clearance_m;
    c.stroke.dead_a_m = clearance as f32;
    c.stroke.dead_b_m = (model.piston.travel_m - clearance) as f32;
    c.force_limit_n = model.limits.force_limit_n as f32;
    c.max_speed_mps = model.limits.max_speed_mps as f32;
    // The model's cogging as the compensation map (what the calibration would find).
    if let Some(cog) = model.cogging() {
        let mut map = fpc::physics::cogging::HarmonicMap::none();
        map.period_m = cog.period_m as f32;
        // A·sin(θ + φ) = A·cos φ·sin θ + A·sin φ·cos θ.
        map.sin_n[0] = (cog.amplitude_n * cog.phase_rad.cos()) as f32;
        map.cos_n[0] = (cog.amplitude_n * cog.phase_rad.sin()) as f32;
        c.allocation.cogging = map;
    }
    c
}

/// The simulated board for a model.
///
/// The chambers start unloaded (both open to the suction line, the rig's start-up bypass):
/// during homing the rotation is at rest and the port timing would seal a chamber. The run
/// closes the bypass (`world.plant.port_mode = PortMode::Timed`) when compression starts.
pub fn world(model: &MachineModel, seed: u64, start_us: u32, start_position_m: f64) -> World {
    let mut w = World::from_model(model, seed, start_us, start_position_m);
    w.plant.port_mode = PortMode::Unloaded;
    w
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    Homing,
    /// The firmware strokes on its own; the host watches the reference turn at each dead
    /// point (it is noise-free; 20 µm of hysteresis ignores rounding at the ends).
    Running {
        toward_b: bool,
        ref_extreme_m: f64,
    },
    Stopping,
    Done,
}

/// Collects the figures while the run goes on.
#[derive(Default)]
struct Metrics {
    dead_point_errors: Vec<f64>,
    /// (completed cycles, |p_chamber − p_d|/p_d) at each discharge opening (plant truth).
    opening_errors: Vec<(u32, f64)>,
    tracking_sq_m2: f64,
    tracking_n: u64,
    /// Port phase of the previous cycle, rad.
    last_phase_rad: Option<f64>,
    /// Work done on the gas of both chambers at each completed cycle, J (cumulative).
    work_at_cycle_j: Vec<f64>,
    /// Work the two motor sections did on the piston, J (cumulative since compression began).
    motor_work_j: f64,
    /// `motor_work_j` at each completed cycle.
    motor_work_at_cycle_j: Vec<f64>,
    extreme_m: Option<f64>,
    min_clearance_m: Option<f64>,
    peak_speed_mps: f64,
    force_diff_sq: f64,
    force_diff_n: u64,
    faults: Vec<Fault>,
}

/// Runs the simulation; the whole run log is kept in [`RunOutcome::log`].
pub fn run(opts: &RunOptions) -> Result<RunOutcome, String> {
    simulate(opts, None)
}

/// Runs the simulation writing the run-log CSV to `csv` as it goes, in chunks of
/// [`STREAM_CHUNK_ROWS`] rows, so memory does not grow with the run's length. The bytes are
/// exactly [`RunLog::to_csv`] of the log [`run`] returns; [`RunOutcome::log`] then holds an
/// evenly decimated copy of at most [`KEPT_ROWS`] rows (every row for runs that short), for
/// plots. A write error ends nothing early but is returned at the end.
pub fn run_streamed(opts: &RunOptions, csv: &mut dyn Write) -> Result<RunOutcome, String> {
    simulate(opts, Some(csv))
}

fn simulate(opts: &RunOptions, csv: Option<&mut dyn Write>) -> Result<RunOutcome, String> {
    opts.validate()?;
    let model = &opts.model;
    let speed = opts.peak_speed_mps();
    let mut config = control_config(model);
    // The controller's model of the machine is off by `model_error` in mass and friction.
    let k = 1.0 + opts.model_error as f32;
    config.moving_mass_kg *= k;
    config.friction.coulomb_n *= k;
    config.friction.static_n *= k;
    config.friction.viscous_ns_per_m *= k;
    if let Some(configure) = opts.configure {
        configure(&mut config);
    }
    let mut actions = opts.schedule.clone();
    actions.sort_by_key(|(cycle, _)| *cycle);
    let mut actions = actions.into_iter().peekable();
    let dead_a = f64::from(config.target_clearance_m);
    let dead_b = f64::from(config.travel_m - config.target_clearance_m);
    let mut injector = Injector::new(&opts.faults, &config, opts.seed);
    let heartbeat_timeout_s = config.heartbeat_timeout_s;
    let mut world = world(
        model,
        opts.seed,
        injector.start_us(opts.start_us),
        injector.start_position_m(opts.start_position_m),
    );
    injector.prepare(&mut world);
    world.telemetry.decimation = opts.telemetry_decimation;
    world.plant.lines.set_pressure_ratio(opts.pressure_ratio);

    let mut log = RunLog::with_columns(&COLUMNS);
    log.meta.push(("source".into(), "fpc-sim run".into()));
    log.meta.push(("sample_rate_hz".into(), "20000".into()));
    log.meta.push(("model".into(), opts.model_name.clone()));
    log.meta.push(("seed".into(), opts.seed.to_string()));
    log.meta.push((
        "force_delay_s".into(),
        format!("{FIRMWARE_FORCE_DELAY_S:e}"),
    ));

    let mut phase = Phase::Homing;
    let mut metrics = Metrics::default();
    let mut cycles_done = 0u32;
    let limit_s = opts.time_limit_s();
    // Each stage must finish in its own time (no waiting out the whole run's limit when
    // homing or a cycle stalls) until the first injected fault begins; after it, the
    // injector decides when the outcome is known.
    let first_fault_s = opts
        .faults
        .iter()
        .map(|f| f.at_s)
        .fold(f64::INFINITY, f64::min);
    let mut stage_deadline_s = opts.homing_limit_s();
    let mut stop_reason: Option<String> = None;
    let mut capture = Capture::new(limit_s, csv, &log);
    let mut last = Status::INIT;
    let started = Instant::now();

    // The board's independent watchdog runs as on the MCU (only a hung task starves it).
    let execution = Execution {
        watchdog_timeout_us: Some(opts.watchdog_timeout_us),
        ..Execution::default()
    };
    let each_cycle = |w: &mut World, shared: &SimShared, exec: &mut Execution| {
        if !injector.is_empty() {
            injector.step(w, shared, exec);
        }
        let status = shared.status();
        let t = w.time_s();
        if w.cycle() > 0 {
            capture.push(&status, w);
        }
        for f in status.faults.iter() {
            if !metrics.faults.contains(&f) {
                metrics.faults.push(f);
            }
        }
        metrics.peak_speed_mps = metrics.peak_speed_mps.max(w.plant.v_mps.abs());
        if matches!(phase, Phase::Running { .. }) {
            if let Some(e) = discharge_opening(&w.plant, metrics.last_phase_rad) {
                metrics.opening_errors.push((cycles_done, e));
            }
            let e = w.plant.x_m - f64::from(status.reference_m);
            metrics.tracking_sq_m2 += e * e;
            metrics.motor_work_j += (w.plant.force_n.master + w.plant.force_n.slave)
                * w.plant.v_mps
                * f64::from(CONTROL_PERIOD_S);
            metrics.tracking_n += 1;
        }
        metrics.last_phase_rad = Some(w.plant.port_phase_rad());
        let faulted = !status.faults.is_empty();
        let before = phase;
        phase = match phase {
            Phase::Homing if w.cycle() == 0 => {
                let _ = shared.post_command(Command::Home);
                Phase::Homing
            }
            Phase::Homing if status.homed && status.mode == ModeKind::Holding => {
                // Close the bypass: from now on the rotation times the ports.
                w.plant.port_mode = PortMode::Timed;
                while let Some((_, action)) = actions.next_if(|(c, _)| *c == 0) {
                    act(w, shared, action);
                }
                let _ = shared.post_command(Command::Start {
                    peak_speed_mps: speed as f32,
                });
                Phase::Running {
                    toward_b: true,
                    ref_extreme_m: f64::from(status.reference_m),
                }
            }
            Phase::Running {
                toward_b,
                ref_extreme_m,
            } => {
                let x = w.plant.x_m;
                let c = w.plant.head_clearance_m();
                metrics.min_clearance_m =
                    Some(metrics.min_clearance_m.map_or(c, |m: f64| m.min(c)));
                let diff = f64::from(status.force_master_n - status.force_slave_n);
                metrics.force_diff_sq += diff * diff;
                metrics.force_diff_n += 1;
                metrics.extreme_m = Some(match metrics.extreme_m {
                    None => x,
                    Some(e) if toward_b => e.max(x),
                    Some(e) => e.min(x),
                });
                let r = f64::from(status.reference_m);
                let turned = if toward_b {
                    r < ref_extreme_m - 20e-6
                } else {
                    r > ref_extreme_m + 20e-6
                };
                if turned && status.mode == ModeKind::Running {
                    let target = if toward_b { dead_b } else { dead_a };
                    let reached = metrics.extreme_m.take().unwrap_or(x);
                    metrics.dead_point_errors.push((reached - target).abs());
                    if !toward_b {
                        cycles_done += 1;
                        while let Some((_, action)) = actions.next_if(|(c, _)| *c <= cycles_done) {
                            act(w, shared, action);
                        }
                        let c = &w.plant.chambers;
                        metrics
                            .work_at_cycle_j
                            .push(c.a.totals.work_on_gas_j + c.b.totals.work_on_gas_j);
                        metrics.motor_work_at_cycle_j.push(metrics.motor_work_j);
                    }
                    if cycles_done >= opts.cycles {
                        let _ = shared.post_command(Command::Stop);
                        Phase::Stopping
                    } else {
                        Phase::Running {
                            toward_b: !toward_b,
                            ref_extreme_m: r,
                        }
                    }
                } else {
                    let ref_extreme_m = if toward_b {
                        ref_extreme_m.max(r)
                    } else {
                        ref_extreme_m.min(r)
                    };
                    Phase::Running {
                        toward_b,
                        ref_extreme_m,
                    }
                }
            }
            Phase::Stopping if status.mode == ModeKind::Holding => Phase::Done,
            other => other,
        };
        // A new stage (homing done, a cycle done, the stop begun) gets its own time.
        let new_stage = match (before, phase) {
            (
                Phase::Homing
                | Phase::Running {
                    toward_b: false, ..
                },
                Phase::Running { toward_b, .. },
            ) => toward_b,
            (Phase::Running { .. }, Phase::Stopping) => true,
            _ => false,
        };
        if new_stage {
            stage_deadline_s = t + opts.cycle_limit_s();
        }
        last = status;
        let outcome_known = if injector.is_empty() {
            faulted
        } else {
            injector.finished(w.time_us(), heartbeat_timeout_s)
        };
        if phase == Phase::Done {
            return ControlFlow::Break(());
        }
        if outcome_known {
            if !faulted {
                stop_reason = Some("the injected faults' outcome was known".into());
            }
            return ControlFlow::Break(());
        }
        if t > limit_s {
            stop_reason = Some(format!(
                "the time limit of {limit_s:.1} s simulated ran out"
            ));
            return ControlFlow::Break(());
        }
        if t > stage_deadline_s && t < first_fault_s {
            let what = match phase {
                Phase::Homing => format!(
                    "homing did not finish within {:.1} s simulated",
                    opts.homing_limit_s()
                ),
                Phase::Stopping => format!(
                    "the stop did not end in holding within {:.1} s simulated",
                    opts.cycle_limit_s()
                ),
                _ => format!(
                    "cycle {} did not complete within {:.1} s simulated",
                    cycles_done + 1,
                    opts.cycle_limit_s()
                ),
            };
            stop_reason = Some(format!("no progress: {what} (mode {})", status.mode.name()));
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    };
    let (world, _) = simulate_board(world, config, execution, each_cycle);

    // The loop alone: writing a streamed log is not part of it, as writing the CSV after the
    // loop is not.
    let wall = (started.elapsed().as_secs_f64() - capture.writing_s()).max(0.0);
    // Making the columns is part of writing the log, as the CSV is: outside the timing.
    capture.finish(&mut log)?;
    let sim_time_s = world.time_s();
    let last5 = metrics.dead_point_errors.len().saturating_sub(10);
    let summary = Summary {
        sim_time_s,
        wall_time_s: wall,
        realtime_factor: if wall > 0.0 {
            sim_time_s / wall
        } else {
            f64::INFINITY
        },
        cycles: cycles_done,
        cycles_requested: opts.cycles,
        stopped_early: (cycles_done < opts.cycles).then(|| {
            let names: Vec<&str> = metrics.faults.iter().map(|f| f.name()).collect();
            match (names.is_empty(), stop_reason) {
                (false, _) => format!("faults latched: {}", names.join(", ")),
                (true, Some(why)) => why,
                (true, None) => "the run ended early".to_string(),
            }
        }),
        faults_not_injected: opts
            .faults
            .iter()
            .filter(|f| f.at_s > sim_time_s)
            .map(|f| format!("{}@{}", f.kind.name(), num(f.at_s)))
            .collect(),
        pressure_ratio_target: opts.pressure_ratio,
        discharge_open_pressure_error: last_max(
            &metrics
                .opening_errors
                .iter()
                .map(|(_, e)| *e)
                .collect::<Vec<_>>(),
            10,
        ),
        tracking_error_rms_m: (metrics.tracking_n > 0)
            .then(|| (metrics.tracking_sq_m2 / metrics.tracking_n as f64).sqrt()),
        indicated_work_j_per_cycle: indicated_work(&metrics.work_at_cycle_j),
        dead_point_error_m: metrics
            .dead_point_errors
            .get(last5..)
            .and_then(|e| e.iter().copied().reduce(f64::max)),
        min_head_clearance_m: metrics.min_clearance_m,
        peak_speed_mps: metrics.peak_speed_mps,
        master_slave_force_diff_rms_n: (metrics.force_diff_n > 0)
            .then(|| (metrics.force_diff_sq / metrics.force_diff_n as f64).sqrt()),
        faults: metrics
            .faults
            .iter()
            .map(|f| f.name().to_string())
            .collect(),
        state: last.mode.name().to_string(),
    };
    Ok(RunOutcome {
        summary,
        log,
        telemetry: world.telemetry.bytes,
        opening_errors: metrics.opening_errors,
        cycle_work_j: metrics
            .work_at_cycle_j
            .windows(2)
            .map(|w| w[1] - w[0])
            .collect(),
        cycle_motor_work_j: metrics
            .motor_work_at_cycle_j
            .windows(2)
            .map(|w| w[1] - w[0])
            .collect(),
        injection: injector.report().clone(),
    })
}

/// The run log as the loop records it, made into [`COLUMNS`] after the loop (with the CSV),
/// or chunk by chunk into the CSV while it runs ([`run_streamed`]).
///
/// A row is 80 bytes instead of 18 separate `f64` pushes (144): the status fields as the
/// firmware has them (`f32`), the cycle instead of the time, the line pressures only when
/// they change. Each fresh page costs a fault, which costs more than the rest of the
/// recording; the buffer is reserved for the longest run so it never moves.
struct Capture<'s> {
    rows: Vec<CapturedRow>,
    /// (first row, p_suction, p_discharge) at each change of the line pressures.
    lines: Vec<(usize, f64, f64)>,
    /// Where the rows go while the run goes on, when streamed.
    stream: Option<Stream<'s>>,
}

/// The CSV a streamed [`Capture`] writes, and the decimated copy it keeps.
struct Stream<'s> {
    out: &'s mut dyn Write,
    /// The first write error; later chunks are not written.
    error: Option<std::io::Error>,
    /// Text of one chunk (reused).
    text: String,
    /// Every `stride`-th row of the run, for plots.
    kept: RunLog,
    stride: usize,
    /// Rows written before the current chunk.
    written: usize,
    /// Wall time spent writing, s (kept out of the loop's real-time factor).
    writing_s: f64,
}

/// One control cycle of [`Capture`].
#[derive(Clone, Copy, Debug)]
struct CapturedRow {
    /// x, x_slave, θ, F_master, F_slave, p_A, p_B, x_ref, θ_ref, v as in [`COLUMNS`].
    status: [f32; 10],
    cycle: u32,
    fault: u8,
    /// p_A, p_B, V_A, V_B (plant truth) as in [`COLUMNS`].
    truth: [f64; 4],
}

/// Rows [`Capture`] reserves at most (80 MB of address space; it grows beyond).
const MAX_RESERVED_ROWS: usize = 1 << 20;

/// Rows a streamed run writes at a time (3.3 s of simulated time; ≈ 20 MB of buffers).
pub const STREAM_CHUNK_ROWS: usize = 1 << 16;

/// Most rows a streamed run keeps for its plots (≈ 13 s at the control rate: every row of
/// the default 10-cycle run; 38 MB).
pub const KEPT_ROWS: usize = 1 << 18;

impl<'s> Capture<'s> {
    /// Room for a run of at most `limit_s` simulated seconds (untouched capacity costs no
    /// memory), or for one chunk when streamed to `csv` (whose head, the metadata and
    /// column names of `log`, is written at once).
    fn new(limit_s: f64, csv: Option<&'s mut dyn Write>, log: &RunLog) -> Self {
        let rows = (limit_s / f64::from(CONTROL_PERIOD_S)) as usize;
        let stream = csv.map(|out| {
            let mut text = String::new();
            log.head_to_csv(&mut text);
            let error = out.write_all(text.as_bytes()).err();
            let mut kept = RunLog::with_columns(&COLUMNS);
            kept.meta = log.meta.clone();
            Stream {
                out,
                error,
                text,
                kept,
                stride: 1,
                written: 0,
                writing_s: 0.0,
            }
        });
        let reserve = if stream.is_some() {
            STREAM_CHUNK_ROWS
        } else {
            rows.min(MAX_RESERVED_ROWS)
        };
        Capture {
            rows: Vec::with_capacity(reserve),
            lines: Vec::new(),
            stream,
        }
    }

    #[inline]
    fn push(&mut self, status: &Status, w: &World) {
        let (c, l) = (&w.plant.chambers, &w.plant.lines);
        let line_pa = (l.suction_pa, l.discharge_pa);
        if self.lines.last().is_none_or(|&(_, s, d)| (s, d) != line_pa) {
            self.lines.push((self.rows.len(), line_pa.0, line_pa.1));
        }
        self.rows.push(CapturedRow {
            status: [
                status.position_m,
                status.slave_position_m,
                status.theta_rad,
                status.force_master_n,
                status.force_slave_n,
                status.pressure_a_pa,
                status.pressure_b_pa,
                status.reference_m,
                status.theta_reference_rad,
                status.velocity_mps,
            ],
            cycle: u32::try_from(w.cycle()).unwrap_or(u32::MAX),
            fault: status.faults.first().map_or(0, |f| f as u8),
            truth: [
                c.a.pressure_pa,
                c.b.pressure_pa,
                c.a.volume_m3,
                c.b.volume_m3,
            ],
        });
        if self.stream.is_some() && self.rows.len() >= STREAM_CHUNK_ROWS {
            self.flush();
        }
    }

    /// Streamed: writes the captured rows to the CSV, keeps every `stride`-th for the plots
    /// (halving the copy and doubling the stride when it outgrows [`KEPT_ROWS`]) and starts
    /// the next chunk with the line pressures in force.
    fn flush(&mut self) {
        let Some(s) = self.stream.as_mut() else {
            return;
        };
        let started = Instant::now();
        let mut chunk = RunLog::with_columns(&COLUMNS);
        fill_columns(&self.rows, &self.lines, &mut chunk);
        if s.error.is_none() {
            s.text.clear();
            chunk.rows_to_csv(&mut s.text);
            s.error = s.out.write_all(s.text.as_bytes()).err();
        }
        let mut row = Vec::with_capacity(COLUMNS.len());
        for r in 0..chunk.len() {
            if (s.written + r) % s.stride == 0 {
                row.clear();
                row.extend(
                    chunk
                        .columns
                        .iter()
                        .map(|c| c.get(r).copied().unwrap_or(f64::NAN)),
                );
                s.kept.push_row(&row);
            }
        }
        while s.kept.len() > KEPT_ROWS {
            for column in &mut s.kept.columns {
                *column = column.iter().step_by(2).copied().collect();
            }
            s.stride *= 2;
        }
        s.written += chunk.len();
        s.writing_s += started.elapsed().as_secs_f64();
        let in_force = self.lines.last().map(|&(_, su, di)| (0, su, di));
        self.rows.clear();
        self.lines.clear();
        self.lines.extend(in_force);
    }

    /// Wall time spent writing the streamed CSV so far, s.
    fn writing_s(&self) -> f64 {
        self.stream.as_ref().map_or(0.0, |s| s.writing_s)
    }

    /// The log of the run: all rows into `log` (which has [`COLUMNS`]); streamed, the rest
    /// written and the kept copy in `log`, or the first write error.
    fn finish(mut self, log: &mut RunLog) -> Result<(), String> {
        if self.stream.is_none() {
            fill_columns(&self.rows, &self.lines, log);
            return Ok(());
        }
        self.flush();
        let Some(s) = self.stream.take() else {
            return Ok(());
        };
        if let Some(e) = s.error.or_else(|| s.out.flush().err()) {
            return Err(format!("cannot write the run log: {e}"));
        }
        *log = s.kept;
        Ok(())
    }
}

/// Appends the captured `rows` to `log` (which has [`COLUMNS`]), one column at a time; `lines`
/// are the line-pressure changes (first row index, suction, discharge).
fn fill_columns(rows: &[CapturedRow], lines: &[(usize, f64, f64)], log: &mut RunLog) {
    let n = rows.len();
    for (j, column) in log.columns.iter_mut().enumerate() {
        column.reserve_exact(n);
        match j {
            0 => column.extend(rows.iter().map(|r| World::time_s_at(u64::from(r.cycle)))),
            1..=10 => column.extend(
                rows.iter()
                    .map(|r| r.status.get(j - 1).copied().map_or(f64::NAN, f64::from)),
            ),
            11 => column.extend(rows.iter().map(|r| f64::from(r.fault))),
            12..=15 => column.extend(
                rows.iter()
                    .map(|r| r.truth.get(j - 12).copied().unwrap_or(f64::NAN)),
            ),
            _ => {
                // Each line pressure holds from its change to the next.
                let ends = lines.iter().skip(1).map(|l| l.0).chain([n]);
                for (&(start, suction, discharge), end) in lines.iter().zip(ends) {
                    let v = if j == 16 { suction } else { discharge };
                    column.extend(std::iter::repeat_n(v, end.saturating_sub(start)));
                }
            }
        }
    }
}

/// Largest of the last `n` values.
fn last_max(values: &[f64], n: usize) -> Option<f64> {
    values
        .get(values.len().saturating_sub(n)..)
        .and_then(|v| v.iter().copied().reduce(f64::max))
}

/// Mean work per cycle over the last 5 cycles, from cumulative work at each cycle end, J.
fn indicated_work(cumulative_j: &[f64]) -> Option<f64> {
    let n = cumulative_j.len();
    let k = 5.min(n.saturating_sub(1));
    if k == 0 {
        return None;
    }
    let last = cumulative_j.get(n - 1)?;
    let first = cumulative_j.get(n - 1 - k)?;
    Some((last - first) / k as f64)
}

/// If a discharge port's half-open angle was crossed since `last_phase_rad` (forward
/// rotation: compressor), the relative pressure error of that chamber against the discharge
/// line at that instant: what a well-timed volume ratio makes zero.
fn discharge_opening(
    plant: &crate::plant::dynamics::Plant,
    last_phase_rad: Option<f64>,
) -> Option<f64> {
    use fpc::physics::port_timing::Port;
    let last = last_phase_rad?;
    let now = plant.port_phase_rad();
    let ports = &plant.chambers.params.ports;
    let advance = wrap_turn(now - last);
    // Reverse rotation (expander: the discharge port is the admission) or standstill: no
    // discharge opening to judge.
    if advance == 0.0 || advance >= std::f64::consts::PI {
        return None;
    }
    for (port, chamber) in [
        (Port::DischargeA, &plant.chambers.a),
        (Port::DischargeB, &plant.chambers.b),
    ] {
        let to_edge = wrap_turn(ports.half_open_rad(port) - last);
        if to_edge > 0.0 && to_edge <= advance {
            let pd = plant.lines.discharge_pa;
            return Some((chamber.pressure_pa - pd).abs() / pd);
        }
    }
    None
}

/// `x.rem_euclid(2π)`: within one turn of the range (the phases here are in [0, 2π)) one add
/// does it, bit for bit, without `rem_euclid`'s `fmod` (a slow library loop).
#[inline]
fn wrap_turn(x: f64) -> f64 {
    let turn = std::f64::consts::TAU;
    if (0.0..turn).contains(&x) {
        x
    } else if x > -turn && x < 0.0 {
        x + turn
    } else {
        x.rem_euclid(turn)
    }
}

/// Carries out a scheduled host action.
fn act(w: &mut World, shared: &SimShared, action: HostAction) {
    match action {
        HostAction::SetLinePressureRatio(pr) => w.plant.lines.set_pressure_ratio(pr),
        HostAction::Command(c) => {
            let _ = shared.post_command(c);
        }
    }
}
