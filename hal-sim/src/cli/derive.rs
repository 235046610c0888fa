//! The `fpc-sim derive` subcommand: the firmware's own fixed-point Savitzky–Golay
//! differentiator (`fpc::sensing::differentiator`), run offline over a run log's `x_m`.
//!
//! Prints CSV `t_s,x_m,v_mps,a_mps2` on stdout, one row per log row (a filter: `fpc-sim
//! derive … | head`), or writes it to `--out FILE`; with `--json` the CSV goes to `--out`
//! (default `out/derive/derived.csv`) and stdout gets the figures as one JSON object. Each value is the
//! derivative *at that row's time*: the window ending `lag` rows later (so `--lag 0`, the
//! causal end point, is exactly what the firmware has at that instant, and `--lag (N−1)/2`
//! is scipy's `savgol_filter`). Rows without such a window — the first N−1−L and the last
//! L — are evaluated on the first or last N samples at their own offset, which is scipy's
//! `mode='interp'`. So every row matches scipy (`tests/derive_matches_scipy.rs`).
//!
//! Positions are fed as counts of a scale fitted to the log (2³⁰ counts over the largest
//! excursion from the first sample, sub-nm for a stroke), not the encoder's 22.9 nm, so the
//! figures are the differentiator's and not a re-quantisation's.

use std::io::Write;
use std::path::{Path, PathBuf};

use clap::Args;
use fpc::control::config::ControlConfig;
use fpc::sensing::differentiator::{Derivatives, SavitzkyGolay, SgConfig};
use fpc::sensing::encoder::PositionCounts;

use crate::failure::{CmdResult, Failure};
use crate::output::{show, OutFile};
use crate::runlog::RunLog;

/// Velocity and acceleration of the logged position by the firmware's differentiator.
#[derive(Args, Debug)]
pub struct DeriveArgs {
    /// Run log (CSV, `docs/formats.md` §1).
    #[arg(long)]
    pub measured: PathBuf,
    /// Window length N (odd, 3..=41; default: the firmware's).
    #[arg(long)]
    pub window: Option<usize>,
    /// Polynomial order K (1..=4, < N; default: the firmware's).
    #[arg(long)]
    pub order: Option<usize>,
    /// Evaluation point, samples back from the newest (0 = causal end point, (N−1)/2 =
    /// centred; default: the firmware's).
    #[arg(long)]
    pub lag: Option<usize>,
    /// Write the CSV to this file instead of stdout (with --json: default
    /// out/derive/derived.csv).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Print the figures (settings, rows, peak speed and acceleration) as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Replace an existing --out file fpc-sim did not write (never the log itself).
    #[arg(long)]
    pub force: bool,
}

/// What `derive --json` prints.
#[derive(Debug, serde::Serialize)]
pub struct DeriveFigures {
    /// Window length N.
    pub window: usize,
    /// Polynomial order K.
    pub order: usize,
    /// Evaluation point, samples back from the newest.
    pub lag: usize,
    /// Rows derived.
    pub rows: usize,
    /// The log's sample time, s.
    pub sample_time_s: f64,
    /// Largest |velocity|, m/s.
    pub peak_speed_mps: f64,
    /// Largest |acceleration|, m/s².
    pub peak_acceleration_mps2: f64,
    /// Where the CSV went.
    pub out: String,
}

/// Differentiator settings: window, order, evaluation point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// Window length N.
    pub window: usize,
    /// Polynomial order K.
    pub order: usize,
    /// Evaluation point, samples back from the newest.
    pub lag: usize,
}

impl Settings {
    /// What the firmware runs (`ControlConfig::reference()`).
    pub fn firmware() -> Self {
        let c = ControlConfig::reference();
        Settings {
            window: c.sg_window,
            order: c.sg_order,
            lag: c.sg_lag,
        }
    }
}

/// The derivatives of a position series, one per sample, at that sample's time.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Derived {
    /// Velocity, m/s.
    pub v_mps: Vec<f64>,
    /// Acceleration, m/s² (0 for order 1).
    pub a_mps2: Vec<f64>,
}

/// Runs `fpc-sim derive`.
pub fn main(args: DeriveArgs) -> CmdResult {
    let fw = Settings::firmware();
    let settings = Settings {
        window: args.window.unwrap_or(fw.window),
        order: args.order.unwrap_or(fw.order),
        lag: args.lag.unwrap_or(fw.lag),
    };
    check(settings).map_err(Failure::bad_input)?;
    let log = read(&args.measured)?;
    let t = log.column("t_s").unwrap_or_default();
    let x = log.column("x_m").unwrap_or_default();
    let dt = log.sample_time_s().unwrap_or(0.0);
    let d = derive(x, dt, settings)
        .map_err(|e| Failure::bad_input(format!("{}: {e}", args.measured.display())))?;
    let write = |out: &mut dyn Write| -> std::io::Result<()> {
        let mut out = std::io::BufWriter::new(out);
        writeln!(out, "t_s,x_m,v_mps,a_mps2")?;
        for (((t, x), v), a) in t.iter().zip(x).zip(&d.v_mps).zip(&d.a_mps2) {
            writeln!(out, "{t},{x},{v},{a}")?;
        }
        out.flush()
    };
    let file = match (&args.out, args.json) {
        (Some(path), _) => Some(path.clone()),
        (None, true) => Some(crate::cli::analysis::default_out("derive").join("derived.csv")),
        (None, false) => None,
    };
    let Some(path) = file else {
        return write(&mut crate::console::stdout()).map_err(|e| Failure::stdout_error(&e));
    };
    let out = OutFile::prepare(&path, args.force, &[args.measured.as_path()])?;
    let mut f = std::fs::File::create(out.path())
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&path))))?;
    write(&mut f).map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&path))))?;
    drop(f);
    out.commit()?;
    let peak = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let figures = DeriveFigures {
        window: settings.window,
        order: settings.order,
        lag: settings.lag,
        rows: t.len(),
        sample_time_s: dt,
        peak_speed_mps: peak(&d.v_mps),
        peak_acceleration_mps2: peak(&d.a_mps2),
        out: path.display().to_string(),
    };
    if args.json {
        let text = serde_json::to_string(&figures).map_err(|e| Failure::runtime(e.to_string()))?;
        crate::outln!("{text}")
    } else {
        crate::outln!("wrote {} ({} rows)", path.display(), figures.rows)
    }
}

/// Reads and validates the log (the time and the position are all it reads); the message
/// names the file, line and column at fault.
fn read(path: &Path) -> Result<RunLog, Failure> {
    crate::cli::analysis::read_log_needing(path, &["x_m"])
}

/// Checks the settings; the message names the flag at fault.
pub fn check(s: Settings) -> Result<(), String> {
    SavitzkyGolay::new(config(s, 1.0, 1.0))
        .map(|_| ())
        .map_err(|e| crate::signal::sg_problem(e, sg(s), ["--window", "--order", "--lag"]))
}

/// The settings as the signal module names them.
fn sg(s: Settings) -> crate::signal::SgSettings {
    crate::signal::SgSettings {
        window: s.window,
        order: s.order,
        lag: s.lag,
    }
}

fn config(s: Settings, sample_time_s: f64, m_per_count: f64) -> SgConfig {
    SgConfig {
        window: s.window,
        order: s.order,
        lag: s.lag,
        sample_time_s: sample_time_s as f32,
        m_per_count: m_per_count as f32,
    }
}

/// The derivatives of `x_m` (uniform sample time `sample_time_s`) at every sample, by the
/// firmware's differentiator, with scipy's edge treatment (see the module doc).
pub fn derive(x_m: &[f64], sample_time_s: f64, s: Settings) -> Result<Derived, String> {
    let n = s.window;
    if x_m.len() < n {
        return Err(format!("{} samples, the window needs {n}", x_m.len()));
    }
    if !(sample_time_s.is_finite() && sample_time_s > 0.0) {
        return Err(format!("sample time {sample_time_s} s is not positive"));
    }
    // Counts of a scale that spans ±2³⁰ over the largest excursion: exact to < 1e-9 of it.
    let x0 = x_m.first().copied().unwrap_or(0.0);
    let span = x_m.iter().fold(0.0f64, |m, x| m.max((x - x0).abs()));
    let m_per_count = if span > 0.0 {
        span / f64::from(1u32 << 30)
    } else {
        1e-9
    };
    let counts: Vec<i32> = x_m
        .iter()
        .map(|x| ((x - x0) / m_per_count).round() as i32)
        .collect();
    let make = |lag: usize| {
        SavitzkyGolay::new(config(Settings { lag, ..s }, sample_time_s, m_per_count))
            .map_err(|e| crate::signal::sg_problem(e, sg(s), ["--window", "--order", "--lag"]))
    };
    // The derivatives at the end of a window of N samples, evaluated `lag` back.
    let on_window = |window: &[i32], lag: usize| -> Result<Derivatives, String> {
        let mut sg = make(lag)?;
        let mut d = Derivatives::default();
        for &c in window {
            d = sg.push(PositionCounts::from_bits(c));
        }
        Ok(d)
    };

    let len = x_m.len();
    let mut out = vec![Derivatives::default(); len];
    // Interior: the window ending at i estimates row i − lag.
    let mut sg = make(s.lag)?;
    for (i, &c) in counts.iter().enumerate() {
        let d = sg.push(PositionCounts::from_bits(c));
        if i + 1 >= n {
            if let Some(o) = out.get_mut(i - s.lag) {
                *o = d;
            }
        }
    }
    // Edges: the first and last N samples, each row at its own offset.
    let first = counts.get(..n).unwrap_or_default();
    for (row, o) in out
        .iter_mut()
        .enumerate()
        .take((n - 1).saturating_sub(s.lag))
    {
        *o = on_window(first, n - 1 - row)?;
    }
    let last = counts.get(len - n..).unwrap_or_default();
    for (row, o) in out.iter_mut().enumerate().skip(len - s.lag) {
        *o = on_window(last, len - 1 - row)?;
    }
    Ok(Derived {
        v_mps: out.iter().map(|d| f64::from(d.velocity_mps)).collect(),
        a_mps2: out.iter().map(|d| f64::from(d.acceleration_mps2)).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parabola_is_differentiated_exactly_at_every_row() {
        let dt = 1e-3;
        let x: Vec<f64> = (0..200)
            .map(|i| {
                let t = i as f64 * dt;
                0.05 + 0.3 * t - 2.0 * t * t
            })
            .collect();
        for lag in [0, 3, 10, 20] {
            let d = derive(
                &x,
                dt,
                Settings {
                    window: 21,
                    order: 2,
                    lag,
                },
            )
            .unwrap();
            for (i, (v, a)) in d.v_mps.iter().zip(&d.a_mps2).enumerate() {
                let t = i as f64 * dt;
                assert!((v - (0.3 - 4.0 * t)).abs() < 1e-5, "lag {lag} row {i}: {v}");
                assert!((a + 4.0).abs() < 1e-3, "lag {lag} row {i}: {a}");
            }
        }
    }

    #[test]
    fn bad_settings_name_the_flag() {
        let s = Settings::firmware();
        assert!(check(Settings { window: 4, ..s })
            .unwrap_err()
            .contains("--window 4"));
        assert!(check(Settings { order: 5, ..s })
            .unwrap_err()
            .contains("--order 5"));
        assert!(check(Settings { lag: 99, ..s })
            .unwrap_err()
            .contains("--lag 99"));
        assert!(derive(&[0.0; 10], 1e-3, s)
            .unwrap_err()
            .contains("10 samples"));
    }
}
