//! `fpc-sim lag` (`docs/formats.md` §3): how far one logged signal lags another, by FFT
//! cross-correlation with sub-sample refinement — the paper's Fig. 4 method, which found the
//! slave drive's force 0.75 ms behind the master's.
//!
//! The whole log is correlated (means removed); the paper cut one period out first, which
//! only matters when the lag drifts along the log.

use std::path::PathBuf;

use clap::Args;
use serde::Serialize;

use crate::cli::analysis::{column, read_log_needing, sample_time_s};
use crate::failure::{CmdResult, Failure};
use crate::outln;
use crate::runlog::RunLog;
use crate::signal::xcorr_lag;

/// Time shift between two signals of a run log.
#[derive(Args, Debug)]
pub struct LagArgs {
    /// The run log (CSV).
    #[arg(long)]
    pub measured: PathBuf,
    /// Reference signal (column name).
    #[arg(long, default_value = "f_master_n")]
    pub a: String,
    /// Signal whose lag behind `a` is measured (column name).
    #[arg(long, default_value = "f_slave_n")]
    pub b: String,
    /// Largest lag searched, s (default: half the log).
    #[arg(long)]
    pub max_lag_s: Option<f64>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// The result, as printed with `--json`.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct LagReport {
    /// Reference column.
    pub a: String,
    /// Lagging column.
    pub b: String,
    /// How far `b` lags `a`, s (negative: `b` leads).
    pub lag_s: f64,
    /// The same in samples (sub-sample refined).
    pub lag_samples: f64,
    /// Normalised correlation at the peak (near 1: the shapes agree).
    pub correlation: f64,
}

/// Measures how far column `b` lags column `a` in `log`.
pub fn measure(
    log: &RunLog,
    a: &str,
    b: &str,
    max_lag_s: Option<f64>,
) -> Result<LagReport, Failure> {
    let dt = sample_time_s(log)?;
    let xa = column(log, a, "--a")?;
    let xb = column(log, b, "--b")?;
    let max_lag = match max_lag_s {
        Some(s) if s.is_finite() && s > 0.0 => Some((s / dt).round() as usize),
        Some(s) => {
            return Err(Failure::bad_input(format!(
                "--max-lag-s {s}: must be positive"
            )))
        }
        None => None,
    };
    if a == b {
        // A signal against itself: no lag, by definition (and no estimate needed).
        return Ok(LagReport {
            a: a.to_string(),
            b: b.to_string(),
            lag_s: 0.0,
            lag_samples: 0.0,
            correlation: 1.0,
        });
    }
    let lag =
        xcorr_lag(xa, xb, dt, max_lag).map_err(|e| Failure::bad_input(format!("{a}/{b}: {e}")))?;
    Ok(LagReport {
        a: a.to_string(),
        b: b.to_string(),
        lag_s: lag.seconds,
        lag_samples: lag.samples,
        correlation: lag.correlation,
    })
}

/// Runs `fpc-sim lag`.
pub fn main(args: LagArgs) -> CmdResult {
    // Only the time and the two columns compared (each named by its flag when missing).
    let log = read_log_needing(&args.measured, &[])?;
    let r = measure(&log, &args.a, &args.b, args.max_lag_s)?;
    if args.json {
        let text = serde_json::to_string(&r).map_err(|e| Failure::runtime(e.to_string()))?;
        outln!("{text}")?;
    } else {
        outln!(
            "{} lags {} by {:.4} ms ({:.2} samples; correlation {:.4})",
            r.b,
            r.a,
            r.lag_s * 1e3,
            r.lag_samples,
            r.correlation
        )?;
    }
    Ok(())
}
