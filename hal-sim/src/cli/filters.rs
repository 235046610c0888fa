//! `fpc-sim filters` (the paper's Fig. 7): the piston velocity from the logged position four
//! ways — no filter (backward difference, the paper's Eq. 5: half a sample late), zero-phase
//! `filtfilt` of the central difference (the reference), the firmware's own
//! Savitzky–Golay differentiator (`fpc::sensing::differentiator`, as the control step runs it), and
//! the drive's velocity reading (column `v_drive_mps` if logged, else the `filtfilt`
//! velocity delayed by `--drive-delay-ms`, the 8.5 ms the paper measured).
//!
//! Prints, for each, the RMS difference from the zero-phase velocity and its delay behind it
//! (cross-correlation), and plots the velocities over a window of the last stroke.

use clap::Args;
use fpc::control::config::ControlConfig;
use serde::Serialize;

use crate::cli::analysis::{
    column, default_window, finish, interior, read_log_needing, read_model, sample_time_s,
    time_window, LogToolArgs, Steps, WindowArgs, ZeroPhaseArgs,
};
use crate::console::Num;
use crate::failure::{CmdResult, Failure};
use crate::outln;
use crate::plot::{lines, Series};
use crate::runlog::RunLog;
use crate::signal::{
    backward_difference, central_difference, delayed, filtfilt, firmware_derivatives,
    rms_difference, sg_check, strokes, xcorr_lag, SgSettings,
};

/// Velocity estimates compared (Fig. 7).
#[derive(Args, Debug)]
pub struct FiltersArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub io: LogToolArgs,
    /// Position column.
    #[arg(long, default_value = "x_m")]
    pub column: String,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub filter: ZeroPhaseArgs,
    /// Savitzky–Golay window (default: the firmware's).
    #[arg(long, default_value_t = ControlConfig::reference().sg_window)]
    pub sg_window: usize,
    /// Savitzky–Golay polynomial order (default: the firmware's).
    #[arg(long, default_value_t = ControlConfig::reference().sg_order)]
    pub sg_order: usize,
    /// Savitzky–Golay evaluation point, samples back from the newest (default: the firmware's).
    #[arg(long, default_value_t = ControlConfig::reference().sg_lag)]
    pub sg_lag: usize,
    /// Delay of the drive's velocity reading when the log has no `v_drive_mps`, ms.
    #[arg(long, default_value_t = 8.5)]
    pub drive_delay_ms: f64,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub window: WindowArgs,
}

/// One velocity estimate and how it compares with the zero-phase one.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// What it is.
    pub label: String,
    /// Velocity, m/s, one per sample.
    pub v_mps: Vec<f64>,
    /// RMS difference from the zero-phase velocity, m/s.
    pub rms_diff_mps: f64,
    /// Delay behind the zero-phase velocity, s.
    pub delay_s: f64,
}

/// Longest `--drive-delay-ms` accepted, ms: a drive's velocity reading lags by
/// milliseconds; a second is already several strokes.
pub const MAX_DRIVE_DELAY_MS: f64 = 1000.0;

/// The position column `name` of `log`: its unit, by the log's naming (`docs/formats.md` §1),
/// is metres (`…_m`), so its derivative is a velocity.
fn position_column<'a>(log: &'a RunLog, name: &str) -> Result<&'a [f64], Failure> {
    let x = column(log, name, "--column")?;
    if !name.ends_with("_m") {
        let positions: Vec<&str> = log
            .names
            .iter()
            .map(String::as_str)
            .filter(|n| n.ends_with("_m"))
            .collect();
        return Err(Failure::bad_input(format!(
            "--column {name}: not a position in metres (the log's are: {})",
            positions.join(", ")
        )));
    }
    Ok(x)
}

/// Computes the four estimates (zero-phase first); the figures leave out 20 ms at each end.
pub fn estimates(log: &RunLog, args: &FiltersArgs) -> Result<Vec<Estimate>, Failure> {
    let dt = sample_time_s(log)?;
    let x = position_column(log, &args.column)?;
    let model = read_model(args.io.model.as_deref())?;
    let sections = args.filter.sections(dt)?;
    if !(0.0..=MAX_DRIVE_DELAY_MS).contains(&args.drive_delay_ms) {
        return Err(Failure::bad_input(format!(
            "--drive-delay-ms {}: must be 0..={MAX_DRIVE_DELAY_MS} ms",
            crate::failure::num(args.drive_delay_ms)
        )));
    }
    let raw = backward_difference(x, dt);
    let reference = filtfilt(&sections, &central_difference(x, dt));
    let sg = SgSettings {
        window: args.sg_window,
        order: args.sg_order,
        lag: args.sg_lag,
    };
    sg_check(
        sg,
        dt,
        model.encoder.period_m,
        ["--sg-window", "--sg-order", "--sg-lag"],
    )
    .map_err(Failure::bad_input)?;
    let (v_sg, _) =
        firmware_derivatives(x, dt, model.encoder.period_m, sg).map_err(Failure::bad_input)?;
    let (drive_label, drive) = match log.column("v_drive_mps") {
        Some(v) => ("drive reading (v_drive_mps)".to_string(), v.to_vec()),
        None => (
            format!(
                "drive reading (filtfilt delayed {} ms)",
                args.drive_delay_ms
            ),
            delayed(&reference, args.drive_delay_ms * 1e-3 / dt),
        ),
    };
    // Delays up to 50 ms are searched: far beyond any filter, well below a stroke.
    let max_lag = Some(((0.05 / dt).round() as usize).max(2));
    let inner = interior(x.len(), dt);
    let compare = |label: String, v: Vec<f64>| -> Estimate {
        let r = reference.get(inner.clone()).unwrap_or_default();
        let e = v.get(inner.clone()).unwrap_or_default();
        let delay_s = xcorr_lag(r, e, dt, max_lag).map_or(f64::NAN, |l| l.seconds);
        Estimate {
            label,
            rms_diff_mps: rms_difference(e, r),
            delay_s,
            v_mps: v,
        }
    };
    Ok(vec![
        compare(args.filter.describe(), reference.clone()),
        compare("no filter (backward difference)".into(), raw),
        compare(
            format!(
                "firmware Savitzky-Golay (N {}, order {}, lag {})",
                sg.window, sg.order, sg.lag
            ),
            v_sg,
        ),
        compare(drive_label, drive),
    ])
}

/// Runs `fpc-sim filters`.
pub fn main(args: FiltersArgs) -> CmdResult {
    let out = args
        .io
        .output("filters", &["filters.svg", "filters.json"])?;
    let steps = Steps::new(3, "reading");
    // The time and the position filtered (named by --column when missing).
    let log = read_log_needing(&args.io.measured, &[])?;
    steps.next("filtering");
    let est = estimates(&log, &args)?;
    steps.next("plotting");
    let t = column(&log, "t_s", "t_s")?;
    let dt = sample_time_s(&log)?;
    let reference = est.first().map(|e| e.v_mps.as_slice()).unwrap_or_default();
    let x = position_column(&log, &args.column)?;
    let window = time_window(
        t,
        args.window.from_s,
        args.window.to_s,
        default_window(t, &strokes(x, reference), dt),
    )?;
    let tw = t.get(window.clone()).unwrap_or_default();
    let series: Vec<Series> = est
        .iter()
        .map(|e| {
            Series::new(
                &e.label,
                tw,
                e.v_mps.get(window.clone()).unwrap_or_default(),
            )
        })
        .collect();
    let path = out.path("filters.svg");
    lines(&path, "Piston velocity (Fig. 7)", "t, s", "v, m/s", &series)
        .map_err(Failure::runtime)?;
    steps.finish();
    let figures = FiltersFigures {
        column: args.column.clone(),
        sample_rate_hz: 1.0 / dt,
        samples: log.len(),
        estimates: est
            .iter()
            .map(|e| EstimateFigures {
                label: e.label.clone(),
                rms_diff_mps: e.rms_diff_mps,
                delay_s: e.delay_s,
            })
            .collect(),
    };
    finish(&args.io, "filters", out, &figures, &["filters.svg"], || {
        outln!(
            "velocity from {} at {:.0} Hz, {} samples",
            figures.column,
            figures.sample_rate_hz,
            figures.samples
        )?;
        outln!(
            "{:<52} {:>14} {:>12}",
            "estimate",
            "rms diff m/s",
            "delay ms"
        )?;
        for e in &figures.estimates {
            outln!(
                "{:<52} {:>14.5} {:>12.4}",
                e.label,
                Num(e.rms_diff_mps),
                Num(e.delay_s * 1e3)
            )?;
        }
        Ok(())
    })
}

/// What `fpc-sim filters` reports (printed, `--json`, and `filters.json`).
#[derive(Debug, Serialize)]
pub struct FiltersFigures {
    /// The position column differentiated.
    pub column: String,
    /// The log's sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Rows in the log.
    pub samples: usize,
    /// Each velocity estimate against the reference.
    pub estimates: Vec<EstimateFigures>,
}

/// One velocity estimate's figures.
#[derive(Debug, Serialize)]
pub struct EstimateFigures {
    /// What it is.
    pub label: String,
    /// RMS difference to the reference velocity, m/s.
    pub rms_diff_mps: f64,
    /// Its delay behind the reference, s.
    pub delay_s: f64,
}
