//! `fpc-pil`: the release firmware ELF in an emulated STM32G474, closed-loop on the
//! `hal-sim` plant (see the library's documentation and `pil/README.md`).
//!
//! `fpc-pil run --elf PATH [--cycles N] [--model M] [--json] [--out DIR]`: the main job's
//! scenario; prints `fpc-sim run --json`'s summary with the instruction figures and the
//! position difference to the host build, writes `run.csv` and the plots to `--out`.
//! `fpc-pil fault SCENARIO --elf PATH`: a fault scenario. `fpc-pil save-timing --elf PATH
//! [--json]`: the control period while a save runs.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use fpc_pil::chip::ChipOptions;
use fpc_pil::elf::Image;
use fpc_pil::run::{run, PilOptions};
use hal_sim::plant::model::MachineModel;
use hal_sim::run::RunOptions;

#[derive(Parser)]
#[command(
    name = "fpc-pil",
    version,
    about = "The release firmware ELF in an emulated STM32G474, closed-loop on the simulated plant"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// The main job's scenario on the ELF: boot with the calibration in flash, home, start
    /// over RTT, N cycles; the same JSON as `fpc-sim run --json` and the PIL's figures.
    Run(RunArgs),
    /// A fault scenario on the ELF (docs/faults.md): boot-window, hung-control, fault-path,
    /// panic-on-stop, torn-save, torn-save-stale-flag, torn-save-in-motion, save-error,
    /// erase-error, single-bank, factory-brown-out, supply-loss, overcurrent, busy-link;
    /// prints the resets, the log and the faults.
    Fault(FaultArgs),
    /// The control period while a calibration save erases and programs flash (data cache
    /// off): the interrupt path's flash lines and flash data reads per period, turned into
    /// cycles with 4 wait states, against the 50 µs period.
    SaveTiming(SaveTimingArgs),
    /// The mutation tests (`scripts/fw-mutants.sh` builds the mutants): the release ELF must
    /// pass every check, each mutant ELF in DIR (fpc-NAME) must fail its own; prints one line
    /// per mutation, exit 1 if one is not caught.
    Mutants(MutantsArgs),
}

#[derive(clap::Args)]
struct MutantsArgs {
    /// The release firmware ELF.
    #[arg(long)]
    elf: PathBuf,
    /// The directory of the mutant ELFs.
    #[arg(long)]
    dir: PathBuf,
}

#[derive(clap::Args)]
struct SaveTimingArgs {
    /// The firmware ELF.
    #[arg(long)]
    elf: PathBuf,
    /// Print, on stderr, where the calibration phase's heaviest period spent its cycles (by
    /// function, and whether from flash or CCM SRAM).
    #[arg(long)]
    profile: bool,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct FaultArgs {
    /// The scenario.
    scenario: String,
    /// The firmware ELF.
    #[arg(long)]
    elf: PathBuf,
    /// Scenarios that stroke: inject this long after the Start command, s.
    #[arg(long, default_value_t = 0.25)]
    at: f64,
    /// `debug-halt`: how long the debugger halts the core, ms.
    #[arg(long, default_value_t = 5.0)]
    halt_ms: f64,
    /// `probe-capture`, `probe-session`: how long the host captures through the probe, s.
    #[arg(long, default_value_t = 10.0)]
    capture_s: f64,
    /// Scenarios that stroke: the pressure ratio (the peak speed follows it).
    #[arg(long, default_value_t = 3.1)]
    pressure_ratio: f64,
    /// Run the emulated time at this many clock cycles per instruction instead of the cycles
    /// counted per instruction (the default).
    #[arg(long)]
    cpi: Option<f64>,
    /// Print, on stderr, where the periods whose interrupt path took the most cycles spent
    /// them (by function and by block of code, whether from flash or CCM SRAM), each with
    /// its time since the last reset.
    #[arg(long)]
    profile: bool,
    /// With `--profile`: how many of those periods.
    #[arg(long, default_value_t = 3)]
    profile_periods: usize,
    /// With `--profile`: how many of each period's heaviest blocks of code to list.
    #[arg(long, default_value_t = 12)]
    profile_blocks: usize,
}

#[derive(clap::Args)]
struct RunArgs {
    /// The firmware ELF (`cargo fw` builds target/thumbv7em-none-eabihf/release/fpc).
    #[arg(long)]
    elf: PathBuf,
    /// Compression cycles.
    #[arg(long, default_value_t = 10)]
    cycles: u32,
    /// Machine-model TOML (default: the embedded reference machine).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Pressure ratio (the peak speed follows it as in `fpc-sim run`).
    #[arg(long, default_value_t = 3.1)]
    pressure_ratio: f64,
    /// Noise seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Run the emulated time at this many clock cycles per instruction instead of the cycles
    /// counted per instruction (the default; the cycle figures are counted either way).
    #[arg(long)]
    cpi: Option<f64>,
    /// Print, on stderr, where the worst period's interrupt path spent its cycles (by
    /// function, and whether from flash or CCM SRAM).
    #[arg(long)]
    profile: bool,
    /// Directory for run.csv and the plots (created; default: no files).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Skip the host-build run (no position_rms_diff_vs_host_m).
    #[arg(long)]
    no_host: bool,
    /// Print the JSON summary on stdout.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Cmd::Run(args) => run_cmd(args),
        Cmd::Fault(args) => fault_cmd(args),
        Cmd::Mutants(args) => mutants_cmd(args),
        Cmd::SaveTiming(args) => save_timing_cmd(args),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("fpc-pil: {e}");
            ExitCode::from(2)
        }
    }
}

fn run_cmd(args: RunArgs) -> Result<ExitCode, String> {
    let image = Image::read(&args.elf)?;
    let (model, model_name) = match &args.model {
        Some(p) => (
            MachineModel::read(p).map_err(|e| e.0)?,
            p.display().to_string(),
        ),
        None => (MachineModel::reference(), "reference".into()),
    };
    let cpi = timeline(args.cpi)?;
    let run_opts = RunOptions {
        model,
        model_name,
        pressure_ratio: args.pressure_ratio,
        cycles: args.cycles,
        seed: args.seed,
        ..RunOptions::reference()
    };
    run_opts.validate()?;
    let opts = PilOptions {
        image,
        run: run_opts,
        chip: ChipOptions {
            cpi,
            ..ChipOptions::default()
        },
        compare_with_host: !args.no_host,
        profile: args.profile,
    };
    let mut file = match &args.out {
        Some(dir) => {
            std::fs::create_dir_all(dir).map_err(|e| format!("--out {}: {e}", dir.display()))?;
            let path = dir.join("run.csv");
            Some(std::io::BufWriter::new(
                std::fs::File::create(&path).map_err(|e| format!("{}: {e}", path.display()))?,
            ))
        }
        None => None,
    };
    let outcome = run(&opts, file.as_mut().map(|f| f as &mut dyn std::io::Write))?;
    drop(file);
    if let Some(dir) = &args.out {
        use hal_sim::cli::run::{plot_energy, plot_motion, plot_pv};
        plot_motion(&dir.join("motion.svg"), &outcome.outcome.log)?;
        plot_pv(&dir.join("pv.svg"), &outcome.outcome.log)?;
        plot_energy(&dir.join("energy.svg"), &outcome.outcome)?;
        // The firmware's own account (boot milestones, faults), for a run that went wrong.
        let log: String = outcome
            .defmt
            .iter()
            .map(|(t, line)| format!("{t:.6} {line}\n"))
            .collect();
        let path = dir.join("defmt.log");
        std::fs::write(&path, log).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    if args.profile {
        print_profile("worst period's interrupt path", &outcome.profile);
    }
    let s = &outcome.summary;
    let mm = |v: Option<f64>| v.map_or("n/a".into(), |m| format!("{:.3} mm", m * 1e3));
    eprintln!(
        "fpc-pil run: {} cycles in {:.3} s emulated ({:.1} s wall), state {}, min head clearance {}, \
         dead-point error {}, faults [{}]; interrupt path {:.0} instructions per cycle mean, {} max, \
         {:.0} cycles mean, {} max ({:.1} µs at 170 MHz; {:.1} % of the instructions from flash); \
         position RMS difference to the host build {}",
        s.run.cycles,
        s.run.sim_time_s,
        s.pil_wall_time_s,
        s.run.state,
        mm(s.run.min_head_clearance_m),
        mm(s.run.dead_point_error_m),
        s.run.faults.join(", "),
        s.instructions_per_cycle_mean,
        s.instructions_per_cycle_max,
        s.cycles_per_cycle_mean,
        s.cycles_per_cycle_max,
        s.worst_cycle_us,
        s.flash_fetched_share * 100.0,
        s.position_rms_diff_vs_host_m
            .map_or("n/a".into(), |v| format!("{:.2} µm", v * 1e6)),
    );
    eprintln!("fpc-pil run: {}", s.deadline);
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(s).map_err(|e| e.to_string())?
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The emulated time's CPI (`None`: the counted cycles); `--cpi` must be plausible.
fn timeline(cpi: Option<f64>) -> Result<Option<f64>, String> {
    match cpi {
        Some(c) if !(c.is_finite() && (0.5..=5.0).contains(&c)) => {
            Err(format!("--cpi {c}: must be within [0.5, 5]"))
        }
        _ => Ok(cpi),
    }
}

fn fault_cmd(args: FaultArgs) -> Result<ExitCode, String> {
    use fpc_pil::faults::{run_with, Scenario};
    let scenario = Scenario::ALL
        .into_iter()
        .find(|s| s.name() == args.scenario)
        .ok_or_else(|| {
            let names: Vec<_> = Scenario::ALL.iter().map(|s| s.name()).collect();
            format!(
                "unknown scenario `{}` (one of: {})",
                args.scenario,
                names.join(", ")
            )
        })?;
    let image = Image::read(&args.elf)?;
    let started = std::time::Instant::now();
    if !(args.at.is_finite() && (0.0..=10.0).contains(&args.at)) {
        return Err(format!("--at {}: must be within [0, 10] s", args.at));
    }
    if !(args.halt_ms.is_finite() && (0.0..=1000.0).contains(&args.halt_ms)) {
        return Err(format!(
            "--halt-ms {}: must be within [0, 1000] ms",
            args.halt_ms
        ));
    }
    if !(args.capture_s.is_finite() && (0.001..=60.0).contains(&args.capture_s)) {
        return Err(format!(
            "--capture-s {}: must be within [0.001, 60] s",
            args.capture_s
        ));
    }
    let cpi = timeline(args.cpi)?;
    let opts = fpc_pil::faults::Options {
        inject_after_start_s: args.at,
        pressure_ratio: args.pressure_ratio,
        cpi,
        halt_s: args.halt_ms * 1e-3,
        capture_s: args.capture_s,
        profile_periods: if args.profile {
            args.profile_periods.max(1)
        } else {
            0
        },
    };
    let r = run_with(&image, scenario, &opts)?;
    println!(
        "fpc-pil fault {}: injected at {}, {:.3} s emulated in {:.1} s wall, min head clearance {:.3} mm at {:.4} s, {:.3} mm after the injection",
        scenario.name(),
        r.injected_at_s.map_or("-".into(), |t| format!("{t:.4} s")),
        r.end_s,
        started.elapsed().as_secs_f64(),
        r.min_clearance_m * 1e3,
        r.min_clearance_at_s,
        r.min_clearance_after_m * 1e3
    );
    for reset in &r.resets {
        println!("  reset at {:.4} s: {:?}", reset.at_s, reset.kind);
    }
    let mut boot = 0.0;
    for (t, m) in &r.milestones {
        if *m == fpc_pil::chip::Milestone::Reset {
            boot = *t;
        }
        println!("  {t:.6} s (+{:.3} ms) {m:?}", (t - boot) * 1e3);
    }
    println!(
        "  faults seen: [{}]; last mode {:?}",
        r.faults.join(", "),
        r.final_mode
    );
    println!("  {}; core halted {} times", r.deadline, r.halts);
    for (t, write) in &r.missed {
        println!(
            "  missed: the sample of the burst ending at {t:.6} s, last write {} cycles after it",
            write.map_or("-".into(), |w| w.to_string())
        );
    }
    if let Some(b) = &r.bare {
        println!(
            "  bare bench: {} periods, gates switching in {}, servo off zero torque in {}; absent [{}]; refused {:?}",
            b.periods,
            b.gates_on,
            b.servo_driven,
            b.absent.iter().map(|p| p.name()).collect::<Vec<_>>().join(", "),
            b.refused
                .iter()
                .map(|(c, why)| format!("{c:?}: {}", why.reason()))
                .collect::<Vec<_>>()
        );
        println!(
            "  then: present after {:?} s, calibrated {}, mode 1 s after start {:?}, refused {:?}",
            b.present_after_s, b.calibrated, b.mode_at_end, b.refused_after
        );
    }
    if let Some(c) = &r.capture {
        println!("  probe capture: {c}");
    }
    for (t, line) in &r.log {
        println!("  {t:.4} {line}");
    }
    print_fault_profiles(&r, args.profile_blocks);
    Ok(ExitCode::SUCCESS)
}

/// A fault scenario's heaviest periods (`fpc-pil fault --profile`): by function, then the
/// `blocks` heaviest blocks of code, each period timed from the last reset before it.
fn print_fault_profiles(r: &fpc_pil::faults::Report, blocks: usize) {
    for p in &r.profile {
        let reset = r
            .milestones
            .iter()
            .filter(|(t, m)| *m == fpc_pil::chip::Milestone::Reset && *t <= p.end_s)
            .map(|(t, _)| *t)
            .fold(0.0, f64::max);
        print_profile(
            &format!(
                "the period ending at {:.6} s ({:.3} ms after the last reset)",
                p.end_s,
                (p.end_s - reset) * 1e3
            ),
            &p.rows,
        );
        eprintln!("  its heaviest blocks:");
        for b in p.blocks.iter().take(blocks) {
            eprintln!(
                "  {:#010x} {:>6} cycles {:>5} instructions  {}",
                b.address, b.cycles, b.instructions, b.function
            );
        }
    }
}

fn mutants_cmd(args: MutantsArgs) -> Result<ExitCode, String> {
    let image = Image::read(&args.elf)?;
    let started = std::time::Instant::now();
    match fpc_pil::mutants::verdicts(&image, &args.dir) {
        Ok(lines) => {
            for l in &lines {
                println!("fpc-pil mutants: {l}");
            }
            println!(
                "fpc-pil mutants: {} of {} caught, the release ELF passing every check ({:.0} s wall)",
                lines.len(),
                fpc_pil::mutants::MUTATIONS.len(),
                started.elapsed().as_secs_f64()
            );
            Ok(ExitCode::SUCCESS)
        }
        Err(e) => {
            eprintln!("fpc-pil mutants: {e}");
            Ok(ExitCode::from(1))
        }
    }
}

fn save_timing_cmd(args: SaveTimingArgs) -> Result<ExitCode, String> {
    use fpc_pil::save_timing::PathFigures;
    let image = Image::read(&args.elf)?;
    let started = std::time::Instant::now();
    let t = fpc_pil::save_timing::run(&image)?;
    let mut acr = t.acr_during_operations.clone();
    acr.sort_unstable();
    acr.dedup();
    let acr: Vec<_> = acr.iter().map(|a| format!("{a:#05x}")).collect();
    println!(
        "fpc-pil save-timing: core cycles counted per instruction, {} wait states per flash access \
         (64-bit line, PRFTEN 0), 170 MHz, period {} µs; FLASH_ACR during the save's erase \
         and programs: {}; the save ended with \"{}\"; {:.1} s wall",
        t.wait_states,
        t.period_us,
        acr.join(", "),
        t.save_outcome,
        started.elapsed().as_secs_f64()
    );
    let row = |name: &str, f: &PathFigures| {
        println!(
            "  {name:<16} {:>6} periods: path ≤ {:>5} instructions, {:>4} lines ({:>4} line \
             entries), {:>4} flash data reads ({:>3} lines); worst period {:>5.1} µs caches on, \
             {:>5.1} µs data cache off, {:>5.1} µs no cache",
            f.periods,
            f.instructions_max,
            f.lines_max,
            f.line_entries_max,
            f.flash_reads_max,
            f.data_lines_max,
            f.worst_us_caches_on,
            f.worst_us_dcache_off,
            f.worst_us_uncached
        );
    };
    row("idle, no save", &t.no_save);
    row("during the save", &t.during_save);
    row("stroking", &t.stroking);
    println!("  calibrating and saving: {}", t.deadline_calibrating);
    println!("  stroking: {}", t.deadline_stroking);
    println!(
        "  worst control period during the save: {:.1} µs of {} µs (data cache off, as it \
         was); no-cache bound {:.1} µs; a save overlapping the strokes: {:.1} µs (no-cache \
         bound {:.1} µs)",
        t.during_save.worst_us_dcache_off,
        t.period_us,
        t.during_save.worst_us_uncached,
        t.stroking.worst_us_dcache_off,
        t.stroking.worst_us_uncached
    );
    if args.profile {
        print_profile(
            "the calibration phase's heaviest interrupt path",
            &t.calibration_profile,
        );
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&t).map_err(|e| e.to_string())?
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Prints a period's profile on stderr (`--profile`).
fn print_profile(what: &str, rows: &[fpc_pil::run::ProfileRow]) {
    let total: u64 = rows.iter().map(|r| r.cycles).sum();
    eprintln!("{what}, {total} cycles, by function:");
    for r in rows {
        eprintln!(
            "  {:#010x} {:>6} cycles {:>5} instructions  {}",
            r.address, r.cycles, r.instructions, r.function
        );
    }
}
