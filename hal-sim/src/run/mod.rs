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

use fpc::control::command::Command;
use fpc::link::channels::UP_TELEMETRY;
use fpc::link::settings::LinkRequest;
use fpc::link::telemetry::Ports;
use fpc::status::Status;

use crate::board::exec::{simulate_board, Execution, SimShared};
use crate::board::ram::SimRam;
use crate::board::world::World;
use crate::faults::apply::{InjectionReport, Injector};
use crate::link::rtt::{drain_up, ControlBlock, Locate};
use crate::published::Rig;
use crate::runlog::{RunLog, REQUIRED};

mod capture;
pub mod closed;
mod driver;
mod figures;
mod metrics;
mod options;
pub mod spectrum;
mod summary;
pub mod text;

pub use driver::{HostLink, RunDriver};
pub use options::*;
pub use summary::Summary;

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
        boot_us: Some(opts.boot_us),
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
