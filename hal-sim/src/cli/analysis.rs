//! What the log-analysis subcommands (`decode`, `lag`, `filters`, `forces`, `energy`, `pv`)
//! share: reading the run log and the model with the exit codes of `docs/formats.md` (and the
//! force balance along it, [`crate::balance`], for `forces` and `energy`), looking up
//! columns, the output directory, and progress bars.

use std::io::IsTerminal;
use std::path::Path;

use indicatif::{ProgressBar, ProgressStyle};

use crate::balance::{force_balance, read_measured, ForceBalance};
use crate::failure::Failure;
use crate::output::OutDir;
use crate::plant::model::MachineModel;
use crate::runlog::RunLog;

/// Reads and validates a run log with every required column; a bad log is bad input (exit
/// 2) naming file, line and column (`docs/faults.md` #18).
pub fn read_log(path: &Path) -> Result<RunLog, Failure> {
    read_log_needing(path, &crate::runlog::REQUIRED)
}

/// [`read_log`] for a command that reads only the columns `needs` (and `t_s`). A log the
/// reader put on its time grid (jitter, dropped rows) is said in one line on stderr.
pub fn read_log_needing(path: &Path, needs: &[&str]) -> Result<RunLog, Failure> {
    let log = RunLog::read_needing(path, needs)
        .map_err(|e| Failure::bad_input(format!("{}: {e}", path.display())))?;
    if let Some(r) = &log.resampled {
        crate::errln!(
            "fpc-sim {}: {}: {r}",
            crate::output::command(),
            crate::output::show(path)
        )?;
    }
    Ok(log)
}

/// The model at `path`, or the embedded reference machine.
pub fn read_model(path: Option<&Path>) -> Result<MachineModel, Failure> {
    match path {
        Some(p) => MachineModel::read(p).map_err(|e| Failure::bad_input(e.0)),
        None => Ok(MachineModel::reference()),
    }
}

/// The column `name` of `log`; missing is bad input naming the flag that asked for it.
pub fn column<'a>(log: &'a RunLog, name: &str, flag: &str) -> Result<&'a [f64], Failure> {
    log.column(name).ok_or_else(|| {
        Failure::bad_input(format!(
            "{flag} {name}: no such column (the log has: {})",
            log.names.join(", ")
        ))
    })
}

/// The log's sample time, s (validated uniform and positive by the reader).
pub fn sample_time_s(log: &RunLog) -> Result<f64, Failure> {
    log.sample_time_s()
        .filter(|dt| dt.is_finite() && *dt > 0.0)
        .ok_or_else(|| Failure::bad_input("the log has no usable time step"))
}

/// A progress bar of `len` steps on stderr, hidden when stderr is not a terminal (pipes,
/// CI, tests).
pub fn progress(len: u64, what: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    if let Ok(style) = ProgressStyle::with_template("{msg:>10} [{bar:40}] {pos}/{len} {eta}") {
        bar.set_style(style);
    }
    bar.set_message(what.to_string());
    bar
}

/// Runs the named `steps` of an analysis in order, advancing one bar over them.
pub struct Steps {
    bar: ProgressBar,
}

impl Steps {
    /// A bar over `count` steps.
    pub fn new(count: u64, what: &str) -> Self {
        Steps {
            bar: progress(count, what),
        }
    }

    /// Marks one step done, naming the next.
    pub fn next(&self, next: &str) {
        self.bar.inc(1);
        self.bar.set_message(next.to_string());
    }

    /// Removes the bar.
    pub fn finish(self) {
        self.bar.finish_and_clear();
    }
}

/// Index range of the samples with `from_s ≤ t ≤ to_s`; a missing bound is taken from
/// `default` (itself clamped to the log). A bound that is not finite, bounds in the wrong
/// order, or a window holding fewer than two samples of the log are bad input naming the
/// flags.
pub fn time_window(
    t: &[f64],
    from_s: Option<f64>,
    to_s: Option<f64>,
    default: std::ops::Range<usize>,
) -> Result<std::ops::Range<usize>, Failure> {
    for (flag, v) in [("--from-s", from_s), ("--to-s", to_s)] {
        if let Some(v) = v.filter(|v| !v.is_finite()) {
            return Err(Failure::bad_input(format!("{flag} {v}: not a finite time")));
        }
    }
    if let (Some(f), Some(e)) = (from_s, to_s) {
        if f >= e {
            return Err(Failure::bad_input(format!(
                "--from-s {f} is not before --to-s {e}"
            )));
        }
    }
    let n = t.len();
    let start = match from_s {
        Some(f) => t.partition_point(|&v| v < f),
        None => default.start.min(n),
    };
    let end = match to_s {
        Some(e) => t.partition_point(|&v| v <= e),
        None => default.end.min(n),
    };
    if start + 2 <= end {
        Ok(start..end)
    } else if from_s.is_none() && to_s.is_none() {
        Ok(0..n)
    } else {
        let (first, last) = (
            t.first().copied().unwrap_or(0.0),
            t.last().copied().unwrap_or(0.0),
        );
        Err(Failure::bad_input(format!(
            "--from-s/--to-s: the window holds fewer than 2 samples of the log ({first} s to \
             {last} s)"
        )))
    }
}

/// The strokes that are whole: each ends at a reversal (not at the log's end) and lies
/// inside [`interior`] (away from the ends, where the zero-phase filter and one-sided
/// differences start up: a stroke there shows edge effects, not the machine).
pub fn whole_strokes(
    strokes: &[std::ops::Range<usize>],
    len: usize,
    dt: f64,
) -> Vec<std::ops::Range<usize>> {
    let inside = interior(len, dt);
    strokes
        .iter()
        .filter(|s| s.start >= inside.start && s.end <= inside.end && s.end < len)
        .cloned()
        .collect()
}

/// The plotting window of an analysis: from 10 ms before the start of the last whole stroke
/// ([`whole_strokes`]) to 90 ms into it (the acceleration, where filters differ most, as
/// in the paper's Figs. 7 and 8), or the whole log when it has none.
pub fn default_window(
    t: &[f64],
    strokes: &[std::ops::Range<usize>],
    dt: f64,
) -> std::ops::Range<usize> {
    match whole_strokes(strokes, t.len(), dt).last() {
        Some(s) => {
            let before = (0.010 / dt).round() as usize;
            let after = (0.090 / dt).round() as usize;
            s.start.saturating_sub(before)..(s.start + after).min(t.len())
        }
        None => 0..t.len(),
    }
}

/// What every plotting log tool reads and where it writes: the run log, the machine model
/// and the output directory.
#[derive(clap::Args, Clone, Debug)]
pub struct LogToolArgs {
    /// The run log (CSV).
    #[arg(long)]
    pub measured: std::path::PathBuf,
    /// Output directory for the plots (default: `out/<command>`, so that no two commands
    /// share a folder).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Machine model: mass, piston area, friction law, encoder period, dead lengths
    /// (default: the reference machine).
    #[arg(long)]
    pub model: Option<std::path::PathBuf>,
    /// Replace plots of an earlier analysis in the output directory (never an input).
    #[arg(long)]
    pub force: bool,
    /// Print the figures as one JSON object on stdout (they are also written beside the
    /// plots as `<command>.json`).
    #[arg(long)]
    pub json: bool,
}

impl LogToolArgs {
    /// The arguments for `measured`, writing into `out`, with the reference model.
    pub fn new(measured: &Path, out: &Path) -> Self {
        LogToolArgs {
            measured: measured.into(),
            out: Some(out.into()),
            model: None,
            force: false,
            json: false,
        }
    }

    /// The output directory of `command` for the files `names` (`--out`, or `out/<command>`),
    /// checked before any work (see [`OutDir::prepare`]): the log and the model are inputs it
    /// never replaces.
    pub fn output(&self, command: &str, names: &[&str]) -> Result<OutDir, Failure> {
        let mut inputs = vec![self.measured.as_path()];
        inputs.extend(self.model.as_deref());
        let dir = self.out.clone().unwrap_or_else(|| default_out(command));
        OutDir::prepare(&dir, names, self.force, &inputs)
    }
}

/// Ends a log tool: writes its figures beside its plots as `<command>.json`, commits the
/// output directory, and prints the figures as JSON (`--json`) or as `human` prints them,
/// then the files written.
pub fn finish<T: serde::Serialize>(
    io: &LogToolArgs,
    command: &str,
    out: OutDir,
    figures: &T,
    plots: &[&str],
    human: impl FnOnce() -> Result<(), Failure>,
) -> Result<(), Failure> {
    let text =
        serde_json::to_string_pretty(figures).map_err(|e| Failure::runtime(e.to_string()))?;
    let name = format!("{command}.json");
    let path = out.path(&name);
    std::fs::write(&path, format!("{text}\n"))
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", path.display())))?;
    let shown: Vec<String> = plots
        .iter()
        .chain(std::iter::once(&name.as_str()))
        .map(|n| out.final_path(n).display().to_string())
        .collect();
    out.commit()?;
    if io.json {
        crate::outln!("{text}")
    } else {
        human()?;
        crate::outln!("wrote {}", shown.join(", "))
    }
}

/// Where a command writes when `--out` is not given: `out/<command>`. One rule for every
/// command, so no two commands' files ever share a folder (`run` and `pv` both write
/// `pv.svg`).
pub fn default_out(command: &str) -> std::path::PathBuf {
    std::path::Path::new("out").join(command)
}

/// The zero-phase low-pass the analyses use as their reference filter.
#[derive(clap::Args, Clone, Debug)]
pub struct ZeroPhaseArgs {
    /// Cut-off of the zero-phase Butterworth low-pass (filtfilt), Hz.
    #[arg(long, default_value_t = 100.0)]
    pub cutoff_hz: f64,
    /// Order of that low-pass (even).
    #[arg(long, default_value_t = 4)]
    pub filter_order: usize,
}

impl ZeroPhaseArgs {
    /// The filter's sections at sample time `dt`; bad settings are bad input naming the flag.
    pub fn sections(&self, dt: f64) -> Result<Vec<crate::signal::Biquad>, Failure> {
        // Each setting checked on its own, so the message names the one flag at fault.
        let order = self.filter_order;
        if order == 0 || !order.is_multiple_of(2) || order > 12 {
            return Err(Failure::bad_input(format!(
                "--filter-order {order}: must be even, 2..=12"
            )));
        }
        let nyquist = 0.5 / dt;
        if !(self.cutoff_hz > 0.0 && self.cutoff_hz < nyquist) {
            return Err(Failure::bad_input(format!(
                "--cutoff-hz {}: must lie between 0 and {nyquist} Hz (half the log's sample rate)",
                self.cutoff_hz
            )));
        }
        crate::signal::butterworth_lowpass(order, self.cutoff_hz, 1.0 / dt)
            .map_err(|e| Failure::bad_input(format!("--cutoff-hz/--filter-order: {e}")))
    }

    /// Short description for printed figures.
    pub fn describe(&self) -> String {
        format!(
            "filtfilt, Butterworth order {} at {} Hz",
            self.filter_order, self.cutoff_hz
        )
    }
}

/// The time window plotted.
#[derive(clap::Args, Clone, Debug)]
pub struct WindowArgs {
    /// Plot from this time, s (default: 10 ms before the last stroke starts).
    #[arg(long)]
    pub from_s: Option<f64>,
    /// Plot up to this time, s (default: 90 ms into the last stroke).
    #[arg(long)]
    pub to_s: Option<f64>,
}

/// The samples compared by the analyses: all but 20 ms (at least 2 samples) at each end,
/// where one-sided differences and filter start-up would dominate the figures.
pub fn interior(len: usize, dt: f64) -> std::ops::Range<usize> {
    let edge = ((0.020 / dt).round() as usize).max(2);
    if len > 4 * edge {
        edge..len - edge
    } else {
        0..len
    }
}

/// The samples of `v` in `range` (empty where the range is out of the data).
pub fn in_window(v: &[f64], range: std::ops::Range<usize>) -> Vec<f64> {
    v.get(range).unwrap_or_default().to_vec()
}

/// The first steps of the force plots (`forces`, `energy`): the log and the model read, the
/// log's sample time, and the force balance ([`force_balance`]) under the zero-phase filter.
pub fn read_force_balance(
    io: &LogToolArgs,
    filter: &ZeroPhaseArgs,
    steps: &Steps,
) -> Result<(RunLog, MachineModel, f64, ForceBalance), Failure> {
    let log = read_log(&io.measured)?;
    let model = read_model(io.model.as_deref())?;
    let dt = sample_time_s(&log)?;
    steps.next("filtering");
    let data = read_measured(&log, &model)
        .map_err(|e| Failure::bad_input(format!("{}: {e}", io.measured.display())))?;
    let fb = force_balance(&data, &model, &filter.sections(dt)?)?;
    Ok((log, model, dt, fb))
}
