//! `fpc-pil run`: the main job's scenario on the release ELF — boot, the calibration record
//! in the emulated flash store, home, start over the RTT command channel, N cycles at the
//! pressure ratio's speed on the machine model — with the same operator and figures as
//! `fpc-sim run` (`hal_sim::run::RunDriver`), and the same plant, sensors and seed driven by
//! the host build for comparison.

use std::io::Write;
use std::time::Instant;

use fpc::control::calibration::record::CalibrationRecord;
use hal_sim::run::{RunDriver, RunOptions, RunOutcome, Summary};
use serde::Serialize;

use crate::board::Board;
use crate::chip::{ChipOptions, PeriodLoad};
use crate::elf::Image;
use crate::session::Session;

/// The SYSCLK the instruction figures are stated at, Hz.
pub const SYSCLK_HZ: f64 = 170e6;
/// The control period, s.
pub const PERIOD_S: f64 = 50e-6;

/// What `fpc-pil run` prints: `fpc-sim run --json`'s summary and the PIL's own figures.
#[derive(Clone, Debug, Serialize)]
pub struct PilSummary {
    /// The same summary as `fpc-sim run --json`.
    #[serde(flatten)]
    pub run: Summary,
    /// Mean instructions per control period from the first exception entry to the return to
    /// thread mode (the interrupt path: DMA end of burst, the control executor, any other
    /// interrupt that ran in the period), over the periods from Start to the end.
    pub instructions_per_cycle_mean: f64,
    /// The largest of those.
    pub instructions_per_cycle_max: u64,
    /// Thread-mode instructions per period (supervision, telemetry, commands, storage), mean.
    pub thread_instructions_per_cycle_mean: f64,
    /// Clock cycles per instruction the figures below assume (`--cpi`).
    pub cpi: f64,
    /// The worst period's interrupt path at 170 MHz with that CPI, µs (the budget is 50).
    pub worst_cycle_us: f64,
    /// RMS of the difference between the piston position (as the encoders report it) of
    /// this run and of the host build on the same plant and seed, aligned at Start, m.
    pub position_rms_diff_vs_host_m: Option<f64>,
    /// Wall-clock time of the emulated run alone, s.
    pub pil_wall_time_s: f64,
    /// Wall-clock time of everything (commissioning, the host run, the PIL run), s.
    pub total_wall_time_s: f64,
    /// Resets of the emulated chip after power-on.
    pub resets: usize,
    /// Telemetry frames received.
    pub telemetry_frames: u64,
}

/// A finished PIL run.
pub struct PilOutcome {
    /// The figures.
    pub summary: PilSummary,
    /// The run (log, per-cycle work) as `fpc-sim run` gives it.
    pub outcome: RunOutcome,
    /// The defmt log, with emulated times.
    pub defmt: Vec<(f64, String)>,
    /// The per-period loads from Start on.
    pub periods: Vec<PeriodLoad>,
}

/// Options of `fpc-pil run`.
pub struct PilOptions {
    /// The firmware.
    pub image: Image,
    /// The run (model, cycles, seed, pressure ratio...).
    pub run: RunOptions,
    /// The emulated chip.
    pub chip: ChipOptions,
    /// Also run the host build for `position_rms_diff_vs_host_m`.
    pub compare_with_host: bool,
}

/// The calibration the board's flash holds: the model commissioned by the host build's
/// routines (`fpc-sim calibrate`), saved by the firmware's own store code.
pub fn commissioned(run: &RunOptions) -> Result<CalibrationRecord, String> {
    hal_sim::calibration::commission(&run.model, run.seed).map(|(r, _)| r)
}

/// Runs the scenario; the run log goes to `csv` as it is made.
pub fn run(opts: &PilOptions, csv: Option<&mut dyn Write>) -> Result<PilOutcome, String> {
    let started = Instant::now();
    opts.run.validate()?;
    let mut run_opts = opts.run.clone();
    let record = match &run_opts.calibration {
        Some(r) => *r,
        None => commissioned(&run_opts)?,
    };
    run_opts.calibration = Some(record);
    // The host can see the firmware's status only through telemetry: the log has a row per
    // frame (the firmware's default decimation, 1 kHz).
    run_opts.log_rate_hz = 1_000_000
        / fpc::units::CONTROL_PERIOD_US
        / u32::from(fpc::link::telemetry::DEFAULT_DECIMATION);

    let host = if opts.compare_with_host {
        let mut h = opts.run.clone();
        h.calibration = Some(record);
        Some(hal_sim::run::run(&h)?)
    } else {
        None
    };

    let flash = hal_sim::board::flash::holding(&record)?;
    let mut world = hal_sim::run::world(
        &run_opts.model,
        run_opts.seed,
        run_opts.start_us,
        run_opts.start_position_m,
    );
    world
        .plant
        .lines
        .set_pressure_ratio(run_opts.pressure_ratio);
    let mut session = Session::new(opts.image.clone(), Board::new(world), opts.chip.clone())?;
    session.chip.soc().flash.load_image(flash.image());
    let config = hal_sim::run::run_config(&run_opts);
    let mut driver = RunDriver::new(&run_opts, &config, "fpc-pil run", csv).log_each_status();
    let pil_started = Instant::now();
    let mut running_from: Option<usize> = None;
    loop {
        session.step()?;
        let fresh = session.fresh;
        let (world, mut link) = session.link();
        let flow = driver.cycle(world, &mut link, fresh, None);
        if running_from.is_none()
            && driver.cycles_done() == 0
            && session.status.mode == fpc::status::ModeKind::Running
        {
            let soc = session.chip.soc();
            soc.recording = true;
            running_from = Some(0);
        }
        if flow.is_break() {
            break;
        }
    }
    let pil_wall = pil_started.elapsed().as_secs_f64();
    let soc = session.chip.soc();
    let periods = std::mem::take(&mut soc.periods);
    let resets = soc.resets.len();
    let world = soc.board.world.clone();
    let outcome = driver.finish(world, Default::default())?;
    let n = periods.len().max(1) as f64;
    let mean = periods.iter().map(|p| p.interrupt_path as f64).sum::<f64>() / n;
    let max = periods.iter().map(|p| p.interrupt_path).max().unwrap_or(0);
    let thread = periods.iter().map(|p| p.thread as f64).sum::<f64>() / n;
    let rms = host
        .as_ref()
        .and_then(|h| position_rms_diff(&outcome.log, &h.log));
    let summary = PilSummary {
        run: outcome.summary.clone(),
        instructions_per_cycle_mean: mean,
        instructions_per_cycle_max: max,
        thread_instructions_per_cycle_mean: thread,
        cpi: opts.chip.cpi,
        worst_cycle_us: max as f64 * opts.chip.cpi / SYSCLK_HZ * 1e6,
        position_rms_diff_vs_host_m: rms,
        pil_wall_time_s: pil_wall,
        total_wall_time_s: started.elapsed().as_secs_f64(),
        resets,
        telemetry_frames: session.frames,
    };
    Ok(PilOutcome {
        summary,
        outcome,
        defmt: session.log.lines.clone(),
        periods,
    })
}

/// RMS difference of `x_m` between two run logs over the strokes. The time axes are aligned
/// on the position reference: the Start command reaches the firmware over RTT at its command
/// task's 1 kHz poll, the host build's at the next control cycle, so the strokes begin up to
/// a millisecond apart; the offset (in whole control periods, within ±5 ms of the two runs'
/// Start posts) is the one that best overlays the two references. The second log is looked
/// up at each row time of the first.
pub fn position_rms_diff(
    pil: &hal_sim::runlog::RunLog,
    host: &hal_sim::runlog::RunLog,
) -> Option<f64> {
    let start = |l: &hal_sim::runlog::RunLog| l.meta("ports_from_s")?.parse::<f64>().ok();
    let (s_pil, s_host) = (start(pil)?, start(host)?);
    let (t_p, x_p, r_p) = (
        pil.column("t_s")?,
        pil.column("x_m")?,
        pil.column("x_ref_m")?,
    );
    let (t_h, x_h, r_h) = (
        host.column("t_s")?,
        host.column("x_m")?,
        host.column("x_ref_m")?,
    );
    let period = f64::from(fpc::units::CONTROL_PERIOD_S);
    let nearest = |target: f64| -> Option<usize> {
        let i = t_h.partition_point(|&th| th < target);
        let j =
            if i > 0 && (i == t_h.len() || (t_h[i] - target).abs() > (target - t_h[i - 1]).abs()) {
                i - 1
            } else {
                i
            };
        (j < t_h.len() && (t_h[j] - target).abs() < period).then_some(j)
    };
    let rms = |shift: f64, a: &[f64], b: &[f64]| -> Option<f64> {
        let (mut sum, mut n) = (0.0, 0usize);
        for (i, &t) in t_p.iter().enumerate() {
            if t < s_pil {
                continue;
            }
            let Some(j) = nearest(t - s_pil + s_host + shift) else {
                continue;
            };
            let d = a[i] - b[j];
            sum += d * d;
            n += 1;
        }
        (n > 100).then(|| (sum / n as f64).sqrt())
    };
    let shift = (-100..=100)
        .map(|k| f64::from(k) * period)
        .filter_map(|shift| Some((rms(shift, r_p, r_h)?, shift)))
        .min_by(|a, b| a.0.total_cmp(&b.0))?
        .1;
    rms(shift, x_p, x_h)
}
