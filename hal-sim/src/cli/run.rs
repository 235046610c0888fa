//! The `fpc-sim run` subcommand: arguments, files written and what is printed.

use std::path::{Path, PathBuf};

use clap::Args;

use crate::failure::{CmdResult, Failure};
use crate::output::{show, OutDir, OutFile};
use crate::plant::model::MachineModel;
use crate::plot::{lines, lines_with, panels, Axes, Panel, Series};
use crate::run::{run_streamed, run_streamed_with_progress, RunOptions};
use crate::runlog::RunLog;
use crate::{errln, outln};

/// Closed-loop simulation of the machine with the firmware's tasks in the loop.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// Machine-model TOML (default: the embedded reference machine).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Target pressure ratio.
    #[arg(long, default_value_t = 3.1)]
    pub pressure_ratio: f64,
    /// Peak piston speed, m/s (default: from the pressure ratio, as in the paper's Fig. 3).
    #[arg(long)]
    pub speed: Option<f64>,
    /// Compression cycles to run.
    #[arg(long, default_value_t = 10)]
    pub cycles: u32,
    /// Output directory for run.csv, summary.json and the plots.
    #[arg(long, default_value = "out/run")]
    pub out: PathBuf,
    /// Print the JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
    /// Noise seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Also capture the firmware's telemetry stream into this file (`fpc-sim decode` reads it).
    #[arg(long)]
    pub telemetry: Option<PathBuf>,
    /// Control cycles per telemetry frame (1 = every 50 µs cycle; the firmware's default 10
    /// is 2000 Hz, the slowest rate `fpc-sim gap` analyses).
    #[arg(long, default_value_t = fpc::link::telemetry::DEFAULT_DECIMATION,
          value_parser = clap::value_parser!(u16).range(1..))]
    pub telemetry_decimation: u16,
    /// The channels the telemetry carries: `gap` (the seven a run log needs, the firmware's
    /// default), `all`, or names joined by commas.
    #[arg(long, value_name = "SET", default_value = "gap")]
    pub telemetry_channels: String,
    /// Inject a fault: `NAME@T[:k=v,…]` (`docs/faults.md`; repeat for several). An unknown name or
    /// a malformed specification exits 2 naming it.
    #[arg(long = "fault", value_name = "SPEC")]
    pub faults: Vec<String>,
    /// Replace outputs of an earlier run (run.csv, the plots, the telemetry file). Without
    /// it an existing output is refused before the run starts; an input is never replaced.
    #[arg(long)]
    pub force: bool,
    /// How the volume ratio is chosen: `adaptive` (it follows the measured pressure ratio,
    /// the machine's purpose) or `fixed:PR` (a conventional compressor's built-in volume
    /// ratio, designed for the pressure ratio PR; for comparison).
    #[arg(long, default_value = "adaptive", value_name = "MODE")]
    pub volume_ratio: String,
    /// The machine's mode: `compressor` (the default) or `expander` (the firmware's
    /// SetRotation before the first stroke: the ports timed to expand the gas).
    #[arg(long, default_value = "compressor", value_name = "MODE")]
    pub rotation: String,
    /// Rows of run.csv per simulated second: the control rate (20000) or a whole divisor of
    /// it (10000 matches the paper's logs; 1000 makes a long run's log 20 times smaller).
    #[arg(long, default_value_t = crate::run::CONTROL_RATE_HZ, value_name = "HZ")]
    pub log_rate: u32,
    /// A calibration file (`fpc-sim calibrate` writes one): the simulated board's flash
    /// holds it and the firmware loads it at boot, instead of the controller being handed
    /// the model's true cogging map. A bad file exits 2 naming the key.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    /// The controller: `ours` (this firmware on the simulated board) or `published` (the
    /// paper's master/slave drives, `[published]` in the model; a baseline to compare with).
    #[arg(long, default_value = "ours", value_name = "NAME")]
    pub controller: String,
    /// The paper's closed-port test instead of compression cycles: both ports closed, the
    /// published drives accelerate the piston from mid-travel toward head B at `--speed` and
    /// stop it at STOP_M (m from head A), then hold it `--hold` seconds while chamber B's
    /// pressure leaks away. Needs `--controller published`.
    #[arg(long, value_name = "STOP_M")]
    pub closed_port: Option<f64>,
    /// Hold after a closed-port stop, s.
    #[arg(long, default_value_t = 2.0, value_name = "S")]
    pub hold: f64,
    /// Keep the files of a run that fails (stops before its cycles without an injected
    /// fault, or ends before a fault begins), for diagnosis; it still exits 1. Ctrl-C then
    /// ends the run where it is and keeps its log up to the interrupt (exit 130). Without it
    /// a failed or interrupted run writes nothing.
    #[arg(long)]
    pub keep_partial: bool,
    /// Benchmark (`scripts/bench-main.sh`): simulate the run N times with no log and no
    /// file, then print the best loop time. Measures the loop alone.
    #[arg(long, hide = true, value_name = "N", default_value_t = 0)]
    pub bench_loop: u32,
}

/// The files `run` writes into its output directory.
pub const OUTPUTS: [&str; 5] = [
    "run.csv",
    "summary.json",
    "motion.svg",
    "pv.svg",
    "energy.svg",
];

/// Runs `fpc-sim run`.
pub fn main(args: RunArgs) -> CmdResult {
    let opts = options(&args)?;
    if args.bench_loop > 0 {
        return bench_loop(opts, args.bench_loop);
    }
    // Every output is checked before the run: an existing one without --force, an input, an
    // unwritable place are refused now (exit 2), not after the simulation.
    let inputs: Vec<&Path> = args
        .model
        .iter()
        .chain(&args.calibration)
        .map(PathBuf::as_path)
        .collect();
    let out = OutDir::prepare(&args.out, &OUTPUTS, args.force, &inputs)?;
    let telemetry = telemetry_file(&args, &out, &inputs)?;
    // With --keep-partial, Ctrl-C ends the run where it is and keeps its files (without,
    // it removes them: nothing half-written is left).
    if args.keep_partial {
        crate::interrupt::catch();
    }
    let outcome = simulate(&opts, &out)?;
    write_outputs(&out, &outcome, telemetry.as_ref())?;
    let csv = out.final_path("run.csv");
    let s = &outcome.summary;
    let failed = failure(&opts, s);
    let written = failed.is_none() || args.keep_partial;
    if written {
        out.commit()?;
        if let Some(t) = telemetry {
            t.commit()?;
        }
    } else {
        // A failed run leaves nothing (the staged files go with `out`).
        drop(out);
        drop(telemetry);
    }
    print_figures(s, written, &csv)?;
    print_injection(&outcome.injection)?;
    if args.json {
        let text = serde_json::to_string_pretty(s).map_err(|e| Failure::runtime(e.to_string()))?;
        outln!("{text}")?;
    }
    verdict(&args, s, failed, written)
}

/// The run the arguments ask for, checked (bad input: exit 2).
fn options(args: &RunArgs) -> Result<RunOptions, Failure> {
    let (model, model_name) = match &args.model {
        Some(path) => (
            MachineModel::read(path).map_err(|e| Failure::bad_input(e.0))?,
            path.display().to_string(),
        ),
        None => (MachineModel::reference(), "reference".to_string()),
    };
    let faults = args
        .faults
        .iter()
        .map(|spec| crate::faults::inject::parse(spec))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| Failure::bad_input(e.0))?;
    let calibration = args
        .calibration
        .as_deref()
        .map(crate::calibration::read)
        .transpose()
        .map_err(Failure::bad_input)?;
    let mut opts = RunOptions {
        model,
        model_name,
        calibration,
        faults,
        pressure_ratio: args.pressure_ratio,
        speed_mps: args.speed,
        cycles: args.cycles,
        seed: args.seed,
        volume_ratio: crate::run::parse_volume_ratio(&args.volume_ratio)
            .map_err(Failure::bad_input)?,
        log_rate_hz: args.log_rate,
        controller: crate::run::Controller::parse(&args.controller).map_err(Failure::bad_input)?,
        closed_port: args
            .closed_port
            .map(|stop_m| crate::run::closed::ClosedPort {
                stop_m,
                hold_s: args.hold,
            }),
        telemetry_decimation: if args.telemetry.is_some() {
            args.telemetry_decimation
        } else {
            0
        },
        telemetry_channels: crate::link::session::parse_channels(&args.telemetry_channels)
            .map_err(|e| Failure::bad_input(format!("--telemetry-channels: {e}")))?,
        ..RunOptions::reference()
    };
    let rotation = crate::run::parse_rotation(&args.rotation).map_err(Failure::bad_input)?;
    crate::run::set_rotation(&mut opts, rotation).map_err(Failure::bad_input)?;
    opts.validate().map_err(Failure::bad_input)?;
    Ok(opts)
}

/// The `--telemetry` file, prepared (refused when it is one of the run's own outputs).
fn telemetry_file(
    args: &RunArgs,
    out: &OutDir,
    inputs: &[&Path],
) -> Result<Option<OutFile>, Failure> {
    Ok(match &args.telemetry {
        Some(path) => {
            if OUTPUTS.iter().any(|n| out.final_path(n) == *path) {
                return Err(Failure::bad_input(format!(
                    "--telemetry {}: is one of the run's own outputs",
                    show(path)
                )));
            }
            Some(OutFile::prepare(path, args.force, inputs)?)
        }
        None => None,
    })
}

/// Runs `opts`, streaming its log into the staged `run.csv` of `out`, a progress bar on a
/// terminal.
fn simulate(opts: &RunOptions, out: &OutDir) -> Result<crate::run::RunOutcome, Failure> {
    let csv = out.path("run.csv");
    let file = std::fs::File::create(&csv)
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&csv))))?;
    let mut writer = std::io::BufWriter::with_capacity(1 << 20, file);
    // A bar on a terminal (hidden in pipes and files): a long run is otherwise silent.
    let bar = crate::cli::analysis::progress(u64::from(opts.cycles), "cycles");
    let outcome = run_streamed_with_progress(opts, &mut writer, &|done| {
        bar.set_position(u64::from(done));
    })
    .map_err(Failure::runtime)?;
    bar.finish_and_clear();
    drop(writer);
    Ok(outcome)
}

/// The plots, `summary.json` and the telemetry of `outcome`, staged in `out` (and
/// `telemetry`).
fn write_outputs(
    out: &OutDir,
    outcome: &crate::run::RunOutcome,
    telemetry: Option<&OutFile>,
) -> CmdResult {
    // The three plots are independent: drawn side by side, the first failure reported.
    let (motion, pv, energy) = std::thread::scope(|s| {
        let pv = s.spawn(|| plot_pv(out.path("pv.svg").as_path(), &outcome.log));
        let motion = plot_motion(out.path("motion.svg").as_path(), &outcome.log);
        let energy = plot_energy(out.path("energy.svg").as_path(), outcome);
        let pv = pv
            .join()
            .unwrap_or_else(|_| Err("pv.svg: the plot failed".into()));
        (motion, pv, energy)
    });
    motion.and(pv).and(energy).map_err(Failure::runtime)?;
    // The summary beside the files it describes, as `--json` prints it.
    let summary_path = out.path("summary.json");
    let summary_text = serde_json::to_string_pretty(&outcome.summary)
        .map_err(|e| Failure::runtime(e.to_string()))?;
    std::fs::write(&summary_path, summary_text + "\n")
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&summary_path))))?;
    if let Some(t) = telemetry {
        std::fs::write(t.path(), &outcome.telemetry).map_err(|e| {
            Failure::runtime(format!("cannot write {}: {e}", show(&t.final_path())))
        })?;
    }
    Ok(())
}

/// The run's line: its figures and whether its files were `written` (`csv` named).
fn print_figures(s: &crate::run::Summary, written: bool, csv: &Path) -> CmdResult {
    errln!(
        "fpc-sim run: {} cycles in {:.3} s simulated ({:.0}x real time), state {}, peak speed {:.2} m/s, \
         min head clearance {}, dead-point error {}, faults [{}]; {} {}",
        s.cycles,
        s.sim_time_s,
        s.realtime_factor,
        s.state,
        s.peak_speed_mps,
        fmt_mm(s.min_head_clearance_m),
        fmt_mm(s.dead_point_error_m),
        s.faults.join(", "),
        if written { "wrote" } else { "did not write" },
        csv.display()
    )?;
    Ok(())
}

/// What the injected faults did (nothing without them).
fn print_injection(r: &crate::faults::apply::InjectionReport) -> CmdResult {
    if let Some(onset_us) = r.first_onset_us() {
        let detected = r.first_fault_after_onset().map_or_else(
            || "no fault latched".to_string(),
            |(t_us, f)| {
                format!(
                    "{} after {:.2} ms",
                    f.name(),
                    (t_us - onset_us) as f64 * 1e-3
                )
            },
        );
        errln!(
            "fpc-sim run: injected fault from {:.4} s: {detected}; min head clearance since {}; \
             watchdog resets {}",
            onset_us as f64 * 1e-6,
            fmt_mm(r.min_clearance_m),
            r.resets_us.len()
        )?;
        if let Some(l) = &r.link {
            errln!(
                "fpc-sim run: DC link over the mains outage: {:.1} J left, {:.0}–{:.0} V, \
                 chopper {:.1} J, logic supply {}",
                l.energy_left_j,
                l.lowest_v,
                l.peak_v,
                l.chopped_j,
                if l.logic_dropped {
                    "dropped out"
                } else {
                    "kept"
                }
            )?;
        }
    }
    Ok(())
}

/// How the command ends: interrupted (its exit code), a failed run (exit 1, saying whether
/// the files were `written`), or success (saying why a run with injected faults stopped
/// early).
fn verdict(
    args: &RunArgs,
    s: &crate::run::Summary,
    failed: Option<String>,
    written: bool,
) -> CmdResult {
    if crate::interrupt::interrupted() {
        return Err(Failure {
            code: crate::interrupt::EXIT_CODE as u8,
            message: format!(
                "interrupted (Ctrl-C) after {} of {} cycles; --keep-partial kept the log up to \
                 the interrupt, its plots and summary in {}",
                s.cycles,
                s.cycles_requested,
                show(&args.out)
            ),
        });
    }
    if let Some(why) = failed {
        let files = if written {
            "the files are written"
        } else {
            "nothing written; --keep-partial keeps the files"
        };
        return Err(Failure::runtime(format!("{why} ({files})")));
    }
    if let Some(why) = &s.stopped_early {
        errln!(
            "fpc-sim run: the run stopped after {} of {} cycles: {why} (after the injected \
             fault; exit 0)",
            s.cycles,
            s.cycles_requested
        )?;
    }
    Ok(())
}

/// `--bench-loop N`: the simulation of `opts` `n` times, with no log rows (one a simulated
/// second) and nothing written, and the best loop wall time (its `realtime_factor`) printed.
/// The process's CPU time, measured from outside at two `n`, gives the loop's CPU time.
fn bench_loop(opts: RunOptions, n: u32) -> CmdResult {
    let opts = RunOptions {
        log_rate_hz: 1,
        ..opts
    };
    let mut best: Option<crate::run::Summary> = None;
    for _ in 0..n {
        let s = run_streamed(&opts, &mut std::io::sink())
            .map_err(Failure::runtime)?
            .summary;
        if best.as_ref().is_none_or(|b| s.wall_time_s < b.wall_time_s) {
            best = Some(s);
        }
    }
    if let Some(s) = best {
        outln!(
            "fpc-sim run --bench-loop: best of {n}: {:.2} ms wall for {:.3} s simulated \
             ({:.1}x real time; no log, no files)",
            s.wall_time_s * 1e3,
            s.sim_time_s,
            s.realtime_factor
        )?;
    }
    Ok(())
}

/// Why a finished run counts as failed (exit 1), if it does: a fault it ended before, or
/// stopping before its cycles with no fault injected (the machine could not do what was
/// asked). With an injected fault an early stop is the expected outcome.
fn failure(opts: &RunOptions, s: &crate::run::Summary) -> Option<String> {
    let missed = &s.faults_not_injected;
    if !missed.is_empty() {
        return Some(format!(
            "the run ended at {:.3} s simulated, before {} began: never injected (inject \
             earlier)",
            s.sim_time_s,
            missed.join(", ")
        ));
    }
    match &s.stopped_early {
        Some(why) if opts.faults.is_empty() => Some(format!(
            "the run stopped after {} of {} cycles: {why}",
            s.cycles, s.cycles_requested
        )),
        _ => None,
    }
}

fn fmt_mm(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".into(), |m| format!("{:.3} mm", m * 1e3))
}

/// `motion.svg`: the piston's position and its reference (dashed) over the run, and below
/// them the tracking error, which is too small to see as the distance between the two lines.
pub fn plot_motion(path: &Path, log: &RunLog) -> Result<(), String> {
    let t = log.column("t_s").unwrap_or_default();
    let x = scaled(log, "x_m", 1e3);
    let r = scaled(log, "x_ref_m", 1e3);
    let error: Vec<f64> = x.iter().zip(&r).map(|(x, r)| (x - r) * 1e3).collect();
    panels(
        path,
        "Piston position",
        "t, s",
        &[
            Panel {
                y_label: "x, mm",
                series: vec![
                    Series::new("x (master encoder)", t, &x),
                    Series::new("x reference", t, &r).dashed(),
                ],
                axes: Axes::default(),
            },
            // Scaled to the strokes' error: homing's push into head A, a spike ten times
            // larger, is drawn at the edge and counted.
            Panel {
                y_label: "x − reference, µm",
                series: vec![Series::new("tracking error", t, &error)],
                axes: Axes {
                    robust_y: true,
                    ..Axes::default()
                },
            },
        ],
    )
}

/// A column of the log times `k` (a unit change), empty when the log lacks it.
fn scaled(log: &RunLog, name: &str, k: f64) -> Vec<f64> {
    log.column(name)
        .unwrap_or_default()
        .iter()
        .map(|v| v * k)
        .collect()
}

/// `pv.svg`: the p–V diagram of both chambers from the plant's true pressures and volumes;
/// chamber B dashed, so that A shows where the two loops lie on each other.
pub fn plot_pv(path: &Path, log: &RunLog) -> Result<(), String> {
    let (va, vb) = (scaled(log, "vol_a_m3", 1e6), scaled(log, "vol_b_m3", 1e6));
    let (pa, pb) = (
        scaled(log, "p_a_true_pa", 1e-3),
        scaled(log, "p_b_true_pa", 1e-3),
    );
    lines(
        path,
        "p-V diagram of both chambers",
        "V, cm³",
        "p, kPa",
        &[
            Series::new("chamber A", &va, &pa),
            Series::new("chamber B", &vb, &pb).dashed(),
        ],
    )
}

/// Energy per compression cycle: what the motor sections put into the piston and what the
/// gas received (∮p·dV); the difference is friction and the other losses.
pub fn plot_energy(path: &Path, outcome: &crate::run::RunOutcome) -> Result<(), String> {
    let cycles: Vec<f64> = (0..outcome.cycle_work_j.len())
        .map(|c| (c + 2) as f64)
        .collect();
    lines_with(
        path,
        "Energy per compression cycle",
        "cycle",
        "work, J",
        &[
            Series::new(
                "motor work on the piston",
                &cycles,
                &outcome.cycle_motor_work_j,
            ),
            Series::new(
                "indicated work (both chambers)",
                &cycles,
                &outcome.cycle_work_j,
            ),
        ],
        Axes {
            integer_x: true,
            markers: true,
            ..Axes::default()
        },
    )
}
