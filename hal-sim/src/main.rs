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
}

fn dispatch(cmd: Cmd) -> CmdResult {
    match cmd {
        Cmd::Run(args) => hal_sim::run_cmd::main(args),
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
