//! `fpc-sim`: the host tool of the free-piston compressor — closed-loop simulation with the
//! firmware logic in the loop, and (as they land) the analysis commands of `formats.md`.
//!
//! Exit codes: 0 success, 1 runtime failure, 2 bad usage or bad input (one line on stderr
//! naming the file, line or flag at fault).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use hal_sim::model::MachineModel;
use hal_sim::plot::{lines, Series};
use hal_sim::run::{run, RunOptions};

#[derive(Parser)]
#[command(
    name = "fpc-sim",
    version,
    about = "Simulator and analysis tools of the free-piston compressor"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Closed-loop simulation of the machine with the firmware's tasks in the loop.
    Run {
        /// Machine-model TOML (default: the embedded reference machine).
        #[arg(long)]
        model: Option<PathBuf>,
        /// Target pressure ratio.
        #[arg(long, default_value_t = 3.1)]
        pressure_ratio: f64,
        /// Peak piston speed, m/s (default: from the pressure ratio, as in the paper's Fig. 3).
        #[arg(long)]
        speed: Option<f64>,
        /// Compression cycles to run.
        #[arg(long, default_value_t = 10)]
        cycles: u32,
        /// Output directory for run.csv and the plots.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Print the JSON summary on stdout.
        #[arg(long)]
        json: bool,
        /// Noise seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

/// A failure with its exit code.
struct Failure {
    code: u8,
    message: String,
}

fn bad_input(message: impl Into<String>) -> Failure {
    Failure {
        code: 2,
        message: message.into(),
    }
}

fn runtime(message: impl Into<String>) -> Failure {
    Failure {
        code: 1,
        message: message.into(),
    }
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // clap prints help/version to stdout with exit 0, usage errors with exit 2.
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { 2 } else { 0 });
        }
    };
    match dispatch(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            eprintln!("fpc-sim: {}", f.message);
            ExitCode::from(f.code)
        }
    }
}

fn dispatch(cmd: Cmd) -> Result<(), Failure> {
    match cmd {
        Cmd::Run {
            model,
            pressure_ratio,
            speed,
            cycles,
            out,
            json,
            seed,
        } => {
            let (model, model_name) = match &model {
                Some(path) => (
                    MachineModel::read(path).map_err(|e| bad_input(e.0))?,
                    path.display().to_string(),
                ),
                None => (MachineModel::reference(), "reference".to_string()),
            };
            let opts = RunOptions {
                model,
                model_name,
                pressure_ratio,
                speed_mps: speed,
                cycles,
                seed,
                ..RunOptions::reference()
            };
            opts.validate().map_err(bad_input)?;
            let outcome = run(&opts).map_err(runtime)?;
            std::fs::create_dir_all(&out)
                .map_err(|e| runtime(format!("cannot create {}: {e}", out.display())))?;
            let csv = out.join("run.csv");
            outcome
                .log
                .write(&csv)
                .map_err(|e| runtime(format!("cannot write {}: {e}", csv.display())))?;
            plot_motion(&out, &outcome.log).map_err(runtime)?;
            let s = &outcome.summary;
            eprintln!(
                "fpc-sim run: {} cycles in {:.3} s simulated ({:.0}x real time), state {}, peak speed {:.2} m/s, \
                 min head clearance {}, dead-point error {}, faults [{}]; wrote {}",
                s.cycles,
                s.sim_time_s,
                s.realtime_factor,
                s.state,
                s.peak_speed_mps,
                fmt_mm(s.min_head_clearance_m),
                fmt_mm(s.dead_point_error_m),
                s.faults.join(", "),
                csv.display()
            );
            if json {
                let text = serde_json::to_string_pretty(s).map_err(|e| runtime(e.to_string()))?;
                println!("{text}");
            }
            Ok(())
        }
    }
}

fn fmt_mm(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".into(), |m| format!("{:.3} mm", m * 1e3))
}

fn plot_motion(out: &Path, log: &hal_sim::runlog::RunLog) -> Result<(), String> {
    let t = log.column("t_s").unwrap_or_default();
    let x = log.column("x_m").unwrap_or_default();
    let r = log.column("x_ref_m").unwrap_or_default();
    lines(
        &out.join("motion.svg"),
        "Piston position",
        "t, s",
        "x, m",
        &[
            Series {
                label: "x (master encoder)",
                x: t,
                y: x,
            },
            Series {
                label: "x reference",
                x: t,
                y: r,
            },
        ],
    )
}
