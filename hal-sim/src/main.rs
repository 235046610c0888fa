//! `fpc-sim`: the host tool of the free-piston compressor — closed-loop simulation with the
//! firmware logic in the loop, and the analysis commands of `formats.md`.
//!
//! Each subcommand lives in its own module with its clap arguments; this file only lists
//! them. Exit codes: see [`hal_sim::cli`].

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use hal_sim::failure::CmdResult;

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
    /// Closed-loop simulation with the firmware's tasks in the loop.
    Run(hal_sim::cli::run::RunArgs),
    /// The firmware's Savitzky–Golay differentiator over a run log's position.
    Derive(hal_sim::cli::derive::DeriveArgs),
    /// Decode a captured telemetry stream into a run log (CSV).
    Decode(hal_sim::cli::decode::DecodeArgs),
    /// Time lag between two logged signals by FFT cross-correlation (Fig. 4).
    Lag(hal_sim::cli::lag::LagArgs),
    /// Velocity without filter, filtfilt, firmware Savitzky-Golay, drive reading (Fig. 7).
    Filters(hal_sim::cli::filters::FiltersArgs),
    /// Inertia force from position against the forces acting (Fig. 8).
    Forces(hal_sim::cli::forces::ForcesArgs),
    /// Motor, inertia, gas and friction work along one stroke (Fig. 9).
    Energy(hal_sim::cli::energy::EnergyArgs),
    /// p-V diagram of both chambers (Fig. 3).
    Pv(hal_sim::cli::pv::PvArgs),
    /// Find, name and add the effect missing from a model (model-gap workflow).
    Gap(hal_sim::cli::gap::GapArgs),
}

fn dispatch(cmd: Cmd) -> CmdResult {
    match cmd {
        Cmd::Run(args) => hal_sim::cli::run::main(args),
        Cmd::Derive(args) => hal_sim::cli::derive::main(args),
        Cmd::Decode(args) => hal_sim::cli::decode::main(args),
        Cmd::Lag(args) => hal_sim::cli::lag::main(args),
        Cmd::Filters(args) => hal_sim::cli::filters::main(args),
        Cmd::Forces(args) => hal_sim::cli::forces::main(args),
        Cmd::Energy(args) => hal_sim::cli::energy::main(args),
        Cmd::Pv(args) => hal_sim::cli::pv::main(args),
        Cmd::Gap(args) => hal_sim::cli::gap::main(args),
    }
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // Help and version go to stdout with exit 0; usage errors exit 2.
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
