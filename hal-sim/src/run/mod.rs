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
use fpc::link::channels::UP_TELEMETRY;
use fpc::link::settings::LinkRequest;
use fpc::link::telemetry::Ports;
use fpc::motion::volume_ratio::RatioTarget;
use fpc::safety::faults::Fault;
use fpc::status::{ModeKind, Status};
use fpc::units::CONTROL_PERIOD_S;
use serde::Serialize;

use crate::board::exec::{simulate_board, Execution, SimShared};
use crate::board::ram::SimRam;
use crate::board::world::World;
use crate::failure::num;
use crate::faults::apply::{InjectionReport, Injector};
use crate::link::rtt::{drain_up, ControlBlock, Locate};
use crate::plant::chambers::PortMode;
use crate::published::Rig;
use crate::runlog::{RunLog, REQUIRED};

mod capture;
pub mod closed;
mod figures;
use figures::{discharge_opening, electrical_per_cycle, indicated_work, last_max};
mod options;
pub mod spectrum;
pub mod text;

use capture::Capture;
pub use options::*;

/// The JSON summary of a run (`docs/formats.md` §3). `None` is printed as `null`: a figure that
/// this simulation cannot yet produce is never invented.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
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
    /// Which controller drove the plant (`ours`, `published`).
    pub controller: String,
    /// Largest |F_master − F_slave| (the sections' reported forces) within ±5 ms of a dead
    /// point, over the last 5 cycles, N (the paper's force fight, §4.1).
    pub dead_point_force_diff_n: Option<f64>,
    /// RMS of F_master − F_slave over the RMS of F_master + F_slave while stroking.
    pub force_diff_rms_fraction: Option<f64>,
    /// Largest overshoot past a dead point toward its head over the last 5 cycles, m
    /// (negative: every dead point short of its target).
    pub overshoot_m: Option<f64>,
    /// Largest minus smallest position over the last 5 cycles, m.
    pub travel_m: Option<f64>,
    /// V_max/V_min of each chamber over the last 5 cycles, mean of A and B.
    pub volume_ratio_reached: Option<f64>,
    /// p_max/p_min of each chamber over the last 5 cycles, mean of A and B (the PR of the
    /// paper's Fig. 3 read from its p–V loops; the target is the line ratio).
    pub pv_pressure_ratio: Option<f64>,
    /// Largest |F_master + F_slave| (the sections' reported forces) over the last 5 cycles,
    /// N (the paper's "sum of both forces", §4.1, and the motor force of Fig. 9).
    pub peak_motor_force_n: Option<f64>,
    /// Frequency of the line in 340–460 Hz of the measured position error (the master
    /// encoder's position − the reference: what the rig sees of a vibration) while
    /// stroking, Hz.
    pub line_hz: Option<f64>,
    /// Its amplitude, m.
    pub line_m: Option<f64>,
    /// Its noise floor: the median amplitude 15–100 Hz either side of it, m (the line is the bin of
    /// the band that stands highest above its floor).
    pub line_floor_m: Option<f64>,
    /// As `line_hz`, with the piston held at rest before the strokes (at least 0.1 s).
    pub rest_line_hz: Option<f64>,
    /// Its amplitude, m.
    pub rest_line_m: Option<f64>,
    /// Its noise floor, m.
    pub rest_line_floor_m: Option<f64>,
    /// The position error's most prominent line in 100–2000 Hz while stroking, Hz (a limit
    /// cycle wherever it settles).
    pub wide_line_hz: Option<f64>,
    /// Its amplitude, m.
    pub wide_line_m: Option<f64>,
    /// The same at rest, Hz.
    pub rest_wide_line_hz: Option<f64>,
    /// Its amplitude, m.
    pub rest_wide_line_m: Option<f64>,
    /// Closed-port run (`--closed-port`): the highest pressure of chamber B, Pa.
    pub closed_port_peak_pa: Option<f64>,
    /// Closed-port run: chamber B's pressure at the end of the hold, Pa.
    pub closed_port_end_pa: Option<f64>,
    /// Electrical input per cycle, mean of the last 5 cycles, J: both sections' bridges'
    /// output and losses and the servo drive's draw, regeneration stored in the DC link and
    /// used again (`plant::bridge`).
    pub electrical_energy_j_per_cycle: Option<f64>,
    /// Both sections' copper loss per cycle, mean of the last 5 cycles, J.
    pub copper_loss_j_per_cycle: Option<f64>,
    /// Both bridges' loss per cycle (conduction and switching, the stated model), J.
    pub bridge_loss_j_per_cycle: Option<f64>,
    /// The servo drive's draw per cycle, J.
    pub servo_energy_j_per_cycle: Option<f64>,
    /// What the sections returned to the DC link per cycle while braking, J.
    pub regenerated_j_per_cycle: Option<f64>,
    /// The I²-losses per cycle the sections' unequal currents added (the fight's cost), J.
    pub fight_loss_j_per_cycle: Option<f64>,
    /// Indicated work over electrical input, the same cycles.
    pub efficiency: Option<f64>,
    /// A `power_cut` run: the energy the DC link held at the end of the mains outage (or of
    /// the run), J; `null` without one.
    pub link_energy_left_j: Option<f64>,
    /// A `power_cut` run: the DC link's highest voltage over the outage (regeneration, at
    /// most the chopper's threshold), V.
    pub link_peak_v: Option<f64>,
    /// A `power_cut` run: the DC link's lowest voltage over the outage, V.
    pub link_lowest_v: Option<f64>,
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
    /// The plant's electrical energies at each completed cycle.
    electrical_at_cycle: Vec<crate::plant::bridge::ElectricalTotals>,
    extreme_m: Option<f64>,
    min_clearance_m: Option<f64>,
    peak_speed_mps: f64,
    force_diff_sq: f64,
    force_diff_n: u64,
    paper: figures::PaperFigures,
    faults: Vec<Fault>,
    /// The homing command went out.
    home_sent: bool,
}

/// Runs the simulation; the whole run log is kept in [`RunOutcome::log`].
pub fn run(opts: &RunOptions) -> Result<RunOutcome, String> {
    simulate(opts, None, None)
}

/// Runs the simulation writing the run-log CSV to `csv` as it goes, in chunks of
/// [`STREAM_CHUNK_ROWS`] rows, so memory does not grow with the run's length. The rows are
/// those of the log [`run`] returns, each value at its column's resolution ([`text`]: 1 nm,
/// 0.1 µrad, 1 mPa, …; the time exact); [`RunOutcome::log`] then holds an
/// evenly decimated copy of at most [`KEPT_ROWS`] rows (every row for runs that short), for
/// plots. A write error ends nothing early but is returned at the end.
pub fn run_streamed(opts: &RunOptions, csv: &mut dyn Write) -> Result<RunOutcome, String> {
    simulate(opts, Some(csv), None)
}

/// [`run_streamed`], calling `on_cycle` with the number of compression cycles done each time
/// one completes (a progress bar).
pub fn run_streamed_with_progress(
    opts: &RunOptions,
    csv: &mut dyn Write,
    on_cycle: &dyn Fn(u32),
) -> Result<RunOutcome, String> {
    simulate(opts, Some(csv), Some(on_cycle))
}

fn simulate<'s>(
    opts: &RunOptions,
    csv: Option<&'s mut dyn Write>,
    on_cycle: Option<&'s dyn Fn(u32)>,
) -> Result<RunOutcome, String> {
    opts.validate()?;
    if let Some(test) = opts.closed_port {
        return closed::simulate(opts, test, csv);
    }
    let config = run_config(opts);
    let mut injector = Injector::new(&opts.faults, &config, opts.seed);
    let heartbeat_timeout_s = config.heartbeat_timeout_s;
    let mut world = world(
        &opts.model,
        opts.seed,
        injector.start_us(opts.start_us),
        injector.start_position_m(opts.start_position_m),
    );
    injector.prepare(&mut world);
    world.telemetry.decimation = opts.telemetry_decimation;
    world.plant.lines.set_pressure_ratio(opts.pressure_ratio);
    let mut driver = RunDriver::new(opts, &config, "fpc-sim run", csv);
    driver.on_cycle = on_cycle;

    // The board's independent watchdog runs as on the MCU (only a hung task starves it).
    let execution = Execution {
        watchdog_timeout_us: Some(opts.watchdog_timeout_us),
        flash: opts
            .calibration
            .as_ref()
            .map(crate::board::flash::holding)
            .transpose()?,
        // The bypass is open from power-on and the telemetry carries the channels asked for;
        // the host says so at every boot.
        at_boot: vec![
            LinkRequest::DeclarePorts(Ports::Bypassed),
            LinkRequest::SetTelemetry {
                decimation: opts.telemetry_decimation,
                channels: opts.telemetry_channels,
            },
        ],
        ..Execution::default()
    };
    // The host of the telemetry channel: it finds the RTT control block in the board's RAM
    // and reads the channel there every control period, as a probe does (it always keeps up).
    let mut telemetry_host: Option<ControlBlock> = None;
    let mut telemetry_error: Option<String> = None;
    let world = match opts.controller {
        Controller::Ours => {
            let each_cycle = |w: &mut World, shared: &SimShared, exec: &mut Execution| {
                if opts.telemetry_decimation > 0 && telemetry_error.is_none() {
                    let block = match telemetry_host.take() {
                        Some(b) => Ok(b),
                        None => {
                            ControlBlock::find(&mut w.ram, &Locate::Scan(vec![SimRam::range()]))
                        }
                    };
                    let drained = block.and_then(|b| {
                        let World { ram, telemetry, .. } = &mut *w;
                        drain_up(&b, ram, UP_TELEMETRY, &mut telemetry.bytes)
                            .map_err(|e| e.to_string())?;
                        Ok(b)
                    });
                    match drained {
                        Ok(b) => telemetry_host = Some(b),
                        Err(e) => telemetry_error = Some(e),
                    }
                }
                let injected = if injector.is_empty() {
                    None
                } else {
                    injector.step(w, shared, exec);
                    Some(injector.finished(w.time_us(), heartbeat_timeout_s))
                };
                // While the MCU boots after a reset nothing reports a status.
                let fresh = exec.booting_until_us.is_none();
                let mut link = FirmwareLink { shared, exec };
                driver.cycle(w, &mut link, fresh, injected)
            };
            simulate_board(world, config, execution, each_cycle).0
        }
        Controller::Published => {
            let mut rig = Rig::new(&opts.model, &world, opts.pressure_ratio, opts.volume_ratio);
            crate::published::simulate(world, &mut rig, |w, rig| {
                let t_s = w.time_s();
                driver.cycle(w, &mut PublishedLink { rig, t_s }, true, None)
            })
        }
    };
    if let Some(e) = telemetry_error {
        return Err(format!("the telemetry host failed: {e}"));
    }
    driver.finish(world, injector.report().clone())
}

/// [`HostLink`] of a run on the simulated board: the firmware's shared state, and the board's
/// execution (whose boot-time link requests follow the ports the host declares).
struct FirmwareLink<'a> {
    shared: &'a SimShared,
    exec: &'a mut Execution,
}

impl HostLink for FirmwareLink<'_> {
    fn status(&self) -> Status {
        self.shared.status()
    }
    fn post_command(&mut self, command: Command) -> bool {
        self.shared.post_command(command).is_ok()
    }
    fn ports_timed(&mut self) {
        self.shared.declare_ports(Ports::Timed);
        if let Some(first) = self.exec.at_boot.first_mut() {
            *first = LinkRequest::DeclarePorts(Ports::Timed);
        }
    }
}

/// [`HostLink`] of a run with the published rig's drives (`--controller published`).
struct PublishedLink<'a> {
    rig: &'a mut Rig,
    t_s: f64,
}

impl HostLink for PublishedLink<'_> {
    fn status(&self) -> Status {
        self.rig.status()
    }
    fn post_command(&mut self, command: Command) -> bool {
        self.rig.command(command, self.t_s);
        true
    }
}

/// The controller configuration of a run: the model's, with the options' changes (a stored
/// calibration replaces the model's true cogging map; `model_error`; `configure`).
pub fn run_config(opts: &RunOptions) -> fpc::control::config::ControlConfig {
    let mut config = control_config(&opts.model);
    if opts.calibration.is_some() {
        // Not the model's truth: the firmware loads the stored map from its flash at boot.
        config.allocation.cogging = fpc::physics::cogging::HarmonicMap::none();
    }
    // The controller's model of the machine is off by `model_error` in mass and friction.
    let k = 1.0 + opts.model_error as f32;
    config.moving_mass_kg *= k;
    config.friction.coulomb_n *= k;
    config.friction.static_n *= k;
    config.friction.viscous_ns_per_m *= k;
    if let Some(configure) = opts.configure {
        configure(&mut config);
    }
    config
}

/// The host's side of a board running the firmware, as [`RunDriver`] uses it: the status as
/// the host last saw it, and the command channel.
pub trait HostLink {
    /// The firmware's status as last seen.
    fn status(&self) -> Status;
    /// Sends a command; false if the channel refused it (full).
    fn post_command(&mut self, command: Command) -> bool;
    /// The start-up bypass has closed: the rotation times the ports from now on (a host
    /// that declares the ports to the firmware says so; by default nothing to do).
    fn ports_timed(&mut self) {}
}

impl HostLink for &SimShared {
    fn status(&self) -> Status {
        SimShared::status(self)
    }
    fn post_command(&mut self, command: Command) -> bool {
        SimShared::post_command(self, command).is_ok()
    }
}

/// The operator of a run and its bookkeeping, one control period at a time: homes the
/// axis, closes the bypass, starts the strokes, counts cycles, stops; collects the figures
/// and the run log. `fpc-sim run` drives it with the host build of the firmware on the
/// simulated board; `fpc-pil` with the release ELF in an emulated MCU.
pub struct RunDriver<'o, 's> {
    opts: &'o RunOptions,
    speed: f64,
    actions: std::iter::Peekable<std::vec::IntoIter<(u32, HostAction)>>,
    dead_a: f64,
    dead_b: f64,
    log: RunLog,
    phase: Phase,
    metrics: Metrics,
    cycles_done: u32,
    limit_s: f64,
    first_fault_s: f64,
    stage_deadline_s: f64,
    stop_reason: Option<String>,
    capture: Capture<'s>,
    log_stride: u64,
    /// A row for every fresh status, whatever the cycle ([`RunDriver::log_each_status`]).
    log_each_status: bool,
    last_mode: fpc::status::ModeKind,
    started: Instant,
    /// Told the cycles done each time one completes.
    on_cycle: Option<&'s dyn Fn(u32)>,
}

impl<'o, 's> RunDriver<'o, 's> {
    /// A run of `opts` with the controller `config`, its log's `source` named so, streamed to
    /// `csv` if given.
    pub fn new(
        opts: &'o RunOptions,
        config: &fpc::control::config::ControlConfig,
        source: &str,
        csv: Option<&'s mut dyn Write>,
    ) -> Self {
        let mut actions = opts.schedule.clone();
        actions.sort_by_key(|(cycle, _)| *cycle);
        let mut log = RunLog::with_columns(&COLUMNS);
        log.meta.push(("source".into(), source.into()));
        log.meta
            .push(("sample_rate_hz".into(), opts.log_rate_hz.to_string()));
        log.meta.push(("model".into(), opts.model_name.clone()));
        log.meta.push(("seed".into(), opts.seed.to_string()));
        log.meta
            .push(("volume_ratio".into(), volume_ratio_name(opts.volume_ratio)));
        // The published drives report the force of the current sampled with the row's position.
        let force_delay_s = match opts.controller {
            Controller::Ours => FIRMWARE_FORCE_DELAY_S,
            Controller::Published => 0.0,
        };
        log.meta
            .push(("force_delay_s".into(), format!("{force_delay_s:e}")));
        if opts.controller == Controller::Published {
            log.meta.push(("controller".into(), "published".into()));
            // Its velocity column is the drive's reading (`filters` compares it, Fig. 7).
            for name in &mut log.names {
                if name == "v_mps" {
                    *name = "v_drive_mps".into();
                }
            }
        }
        let limit_s = opts.time_limit_s();
        let capture = Capture::new(limit_s, csv, &log);
        RunDriver {
            opts,
            speed: opts.peak_speed_mps(),
            actions: actions.into_iter().peekable(),
            dead_a: f64::from(config.target_clearance_m),
            dead_b: f64::from(config.travel_m - config.target_clearance_m),
            log,
            phase: Phase::Homing,
            metrics: Metrics::default(),
            cycles_done: 0,
            limit_s,
            // Each stage must finish in its own time (no waiting out the whole run's limit
            // when homing or a cycle stalls) until the first injected fault begins; after
            // it, the injector decides when the outcome is known.
            first_fault_s: opts
                .faults
                .iter()
                .map(|f| f.at_s)
                .fold(f64::INFINITY, f64::min),
            stage_deadline_s: opts.homing_limit_s(),
            stop_reason: None,
            capture,
            // One row every `log_stride` control cycles (`--log-rate`; checked to divide
            // evenly).
            log_stride: u64::from((CONTROL_RATE_HZ / opts.log_rate_hz.max(1)).max(1)),
            log_each_status: false,
            last_mode: Status::INIT.mode,
            started: Instant::now(),
            on_cycle: None,
        }
    }

    /// Logs a row for every fresh status instead of every `log_rate_hz`-th cycle: for a
    /// host that sees the status only in the firmware's telemetry frames (a real board's, at
    /// the firmware's own decimation, whose frames need not fall on those cycles).
    pub fn log_each_status(mut self) -> Self {
        self.log_each_status = true;
        self
    }

    /// Compression cycles completed so far.
    pub fn cycles_done(&self) -> u32 {
        self.cycles_done
    }

    /// One control period, after the firmware ran it and before the plant advances: looks
    /// at the status (`fresh`: seen this period; a stale one counts for the plant's figures
    /// only), acts, records. `injected`: the fault injector's verdict that the injected
    /// faults' outcome is known (`None` without injected faults). Breaks when the run is over.
    pub fn cycle(
        &mut self,
        w: &mut World,
        link: &mut dyn HostLink,
        fresh: bool,
        injected: Option<bool>,
    ) -> ControlFlow<()> {
        let opts = self.opts;
        let metrics = &mut self.metrics;
        let status = link.status();
        let t = w.time_s();
        if fresh
            && w.cycle() > 0
            && (self.log_each_status || w.cycle().is_multiple_of(self.log_stride))
        {
            self.capture.push(&status, w);
        }
        // `iter` walks every kind of fault: only when one is latched.
        if !status.faults.is_empty() {
            for f in status.faults.iter() {
                if !metrics.faults.contains(&f) {
                    metrics.faults.push(f);
                }
            }
        }
        metrics.peak_speed_mps = metrics.peak_speed_mps.max(w.plant.v_mps.abs());
        if matches!(self.phase, Phase::Running { .. }) {
            if let Some(e) = discharge_opening(&w.plant, metrics.last_phase_rad) {
                metrics.opening_errors.push((self.cycles_done, e));
            }
            if fresh {
                let e = w.plant.x_m - f64::from(status.reference_m);
                metrics.tracking_sq_m2 += e * e;
                metrics.tracking_n += 1;
            }
            metrics.motor_work_j += (w.plant.force_n.master + w.plant.force_n.slave)
                * w.plant.v_mps
                * f64::from(CONTROL_PERIOD_S);
        }
        metrics.last_phase_rad = Some(w.plant.port_phase_rad());
        if self.phase == Phase::Homing && fresh {
            metrics
                .paper
                .before_strokes(f64::from(status.position_m), status.reference_m);
        }
        let faulted = !status.faults.is_empty();
        let before = self.phase;
        self.phase = match self.phase {
            // Home as soon as the link takes a command (the simulator's at once; a real
            // board's once its RTT channels are up).
            Phase::Homing if !self.metrics.home_sent => {
                self.metrics.home_sent = link.post_command(Command::Home);
                Phase::Homing
            }
            Phase::Homing if status.homed && status.mode == ModeKind::Holding => {
                // Close the bypass: from now on the rotation times the ports.
                w.plant.port_mode = PortMode::Timed;
                link.ports_timed();
                self.capture.ports_timed_from(t);
                if opts.volume_ratio != RatioTarget::FollowMeasured {
                    let _ = link.post_command(Command::SetVolumeRatio {
                        target: opts.volume_ratio,
                    });
                }
                while let Some((_, action)) = self.actions.next_if(|(c, _)| *c == 0) {
                    act(w, link, action);
                }
                let _ = link.post_command(Command::Start {
                    peak_speed_mps: self.speed as f32,
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
                let metrics = &mut self.metrics;
                let x = w.plant.x_m;
                let c = w.plant.head_clearance_m();
                metrics.min_clearance_m =
                    Some(metrics.min_clearance_m.map_or(c, |m: f64| m.min(c)));
                if fresh {
                    let diff = f64::from(status.force_master_n - status.force_slave_n);
                    metrics.force_diff_sq += diff * diff;
                    metrics.force_diff_n += 1;
                    metrics.paper.stroking(
                        t,
                        f64::from(status.position_m - status.reference_m),
                        f64::from(status.force_master_n),
                        f64::from(status.force_slave_n),
                        &w.plant,
                    );
                }
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
                if fresh && turned && status.mode == ModeKind::Running {
                    let target = if toward_b { self.dead_b } else { self.dead_a };
                    let reached = metrics.extreme_m.take().unwrap_or(x);
                    metrics.dead_point_errors.push((reached - target).abs());
                    let overshoot = if toward_b {
                        reached - target
                    } else {
                        target - reached
                    };
                    metrics.paper.dead_point(t, overshoot);
                    if !toward_b {
                        self.cycles_done += 1;
                        let done = self.cycles_done;
                        if let Some(tell) = self.on_cycle {
                            tell(done);
                        }
                        while let Some((_, action)) = self.actions.next_if(|(c, _)| *c <= done) {
                            act(w, link, action);
                        }
                        let c = &w.plant.chambers;
                        metrics
                            .work_at_cycle_j
                            .push(c.a.totals.work_on_gas_j + c.b.totals.work_on_gas_j);
                        metrics.motor_work_at_cycle_j.push(metrics.motor_work_j);
                        metrics.electrical_at_cycle.push(w.plant.electrical);
                        metrics.paper.cycle_done();
                    }
                    if self.cycles_done >= opts.cycles {
                        let _ = link.post_command(Command::Stop);
                        Phase::Stopping
                    } else {
                        Phase::Running {
                            toward_b: !toward_b,
                            ref_extreme_m: r,
                        }
                    }
                } else {
                    let ref_extreme_m = if !fresh {
                        ref_extreme_m
                    } else if toward_b {
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
        let new_stage = match (before, self.phase) {
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
            self.stage_deadline_s = t + opts.cycle_limit_s();
        }
        self.last_mode = status.mode;
        let outcome_known = injected.unwrap_or(faulted);
        if self.phase == Phase::Done {
            return ControlFlow::Break(());
        }
        if outcome_known {
            if !faulted {
                self.stop_reason = Some("the injected faults' outcome was known".into());
            }
            return ControlFlow::Break(());
        }
        let limit_s = self.limit_s;
        if t > limit_s {
            self.stop_reason = Some(format!(
                "the time limit of {limit_s:.1} s simulated ran out"
            ));
            return ControlFlow::Break(());
        }
        // Ctrl-C, when the command keeps what ran (`run --keep-partial`).
        if crate::interrupt::interrupted() {
            self.stop_reason = Some(format!("interrupted (Ctrl-C) at {t:.3} s simulated"));
            return ControlFlow::Break(());
        }
        if t > self.stage_deadline_s && t < self.first_fault_s {
            let what = match self.phase {
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
                    self.cycles_done + 1,
                    opts.cycle_limit_s()
                ),
            };
            self.stop_reason = Some(format!("no progress: {what} (mode {})", status.mode.name()));
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    }

    /// The figures and the log of the run that ended with `world`.
    pub fn finish(self, world: World, injection: InjectionReport) -> Result<RunOutcome, String> {
        let RunDriver {
            opts,
            mut log,
            mut metrics,
            cycles_done,
            stop_reason,
            capture,
            last_mode,
            started,
            ..
        } = self;
        // The loop alone: writing a streamed log is not part of it, as writing the CSV after
        // the loop is not.
        let wall = (started.elapsed().as_secs_f64() - capture.writing_s()).max(0.0);
        // Making the columns is part of writing the log, as the CSV is: outside the timing.
        capture.finish(&mut log)?;
        let sim_time_s = world.time_s();
        let last5 = metrics.dead_point_errors.len().saturating_sub(10);
        let paper = std::mem::take(&mut metrics.paper).finish();
        let indicated = indicated_work(&metrics.work_at_cycle_j);
        let electrical = electrical_per_cycle(&metrics.electrical_at_cycle);
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
            indicated_work_j_per_cycle: indicated,
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
            state: last_mode.name().to_string(),
            controller: opts.controller.name().to_string(),
            dead_point_force_diff_n: paper.dead_point_force_diff_n,
            force_diff_rms_fraction: paper.force_diff_rms_fraction,
            overshoot_m: paper.overshoot_m,
            travel_m: paper.travel_m,
            volume_ratio_reached: paper.volume_ratio_reached,
            pv_pressure_ratio: paper.pv_pressure_ratio,
            peak_motor_force_n: paper.peak_motor_force_n,
            line_hz: paper.line_hz,
            line_m: paper.line_m,
            line_floor_m: paper.line_floor_m,
            rest_line_hz: paper.rest_line_hz,
            rest_line_m: paper.rest_line_m,
            rest_line_floor_m: paper.rest_line_floor_m,
            wide_line_hz: paper.wide_line_hz,
            wide_line_m: paper.wide_line_m,
            rest_wide_line_hz: paper.rest_wide_line_hz,
            rest_wide_line_m: paper.rest_wide_line_m,
            closed_port_peak_pa: None,
            closed_port_end_pa: None,
            electrical_energy_j_per_cycle: electrical.map(|e| e.input_j()),
            copper_loss_j_per_cycle: electrical.map(|e| e.copper_total_j()),
            bridge_loss_j_per_cycle: electrical.map(|e| e.bridge_loss_total_j()),
            servo_energy_j_per_cycle: electrical.map(|e| e.servo_j),
            regenerated_j_per_cycle: electrical.map(|e| e.regenerated_j),
            fight_loss_j_per_cycle: electrical.map(|e| e.fight_j),
            efficiency: indicated
                .zip(electrical)
                .and_then(|(w, e)| (e.input_j() > 0.0).then(|| w / e.input_j())),
            link_energy_left_j: injection.link.map(|l| l.energy_left_j),
            link_peak_v: injection.link.map(|l| l.peak_v),
            link_lowest_v: injection.link.map(|l| l.lowest_v),
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
            injection,
        })
    }
}

/// Carries out a scheduled host action.
fn act(w: &mut World, link: &mut dyn HostLink, action: HostAction) {
    match action {
        HostAction::SetLinePressureRatio(pr) => w.plant.lines.set_pressure_ratio(pr),
        HostAction::UnloadPorts => w.plant.port_mode = PortMode::Unloaded,
        HostAction::Command(c) => {
            let _ = link.post_command(c);
        }
    }
}
