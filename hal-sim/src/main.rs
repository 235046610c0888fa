//! `fpc-sim`: the host tool of the free-piston compressor — closed-loop simulation with the
//! firmware logic in the loop, and the analysis commands of `formats.md`.
//!
//! Each subcommand lives in its own module with its clap arguments; this file only lists
//! them. Exit codes: see [`hal_sim::cli`].

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use hal_sim::cli::CmdResult;

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
    Run(hal_sim::run_cmd::RunArgs),
    /// The firmware's Savitzky–Golay differentiator over a run log's position.
    Derive(hal_sim::derive::DeriveArgs),
    /// Decode a captured telemetry stream into a run log (CSV).
    Decode(hal_sim::decode_cmd::DecodeArgs),
    /// Time lag between two logged signals by FFT cross-correlation (Fig. 4).
    Lag(hal_sim::lag_cmd::LagArgs),
    /// Velocity without filter, filtfilt, firmware Savitzky-Golay, drive reading (Fig. 7).
    Filters(hal_sim::filters_cmd::FiltersArgs),
    /// Inertia force from position against the forces acting (Fig. 8).
    Forces(hal_sim::forces_cmd::ForcesArgs),
    /// Motor, inertia, gas and friction work along one stroke (Fig. 9).
    Energy(hal_sim::energy_cmd::EnergyArgs),
    /// p-V diagram of both chambers (Fig. 3).
    Pv(hal_sim::pv_cmd::PvArgs),
    /// Find, name and add the effect missing from a model (model-gap workflow).
    Gap(hal_sim::gap_cmd::GapArgs),
}

fn dispatch(cmd: Cmd) -> CmdResult {
    match cmd {
        Cmd::Run(args) => hal_sim::run_cmd::main(args),
        Cmd::Derive(args) => hal_sim::derive::main(args),
        Cmd::Decode(args) => hal_sim::decode_cmd::main(args),
        Cmd::Lag(args) => hal_sim::lag_cmd::main(args),
        Cmd::Filters(args) => hal_sim::filters_cmd::main(args),
        Cmd::Forces(args) => hal_sim::forces_cmd::main(args),
        Cmd::Energy(args) => hal_sim::energy_cmd::main(args),
        Cmd::Pv(args) => hal_sim::pv_cmd::main(args),
        Cmd::Gap(args) => hal_sim::gap_cmd::main(args),
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
