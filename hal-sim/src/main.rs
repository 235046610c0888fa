//! `fpc-sim`: the host tool of the free-piston compressor — closed-loop simulation with the
//! firmware logic in the loop, and the analysis commands of `docs/formats.md`.
//!
//! The tool is [`hal_sim::cli::execute`]; each subcommand lives in its own module of
//! [`hal_sim::cli`]. Exit codes: 0 success, 1 runtime failure, 2 bad usage or input.

use std::process::ExitCode;

fn main() -> ExitCode {
    // Ctrl-C removes what the command staged (or lets it finish, where it says so).
    hal_sim::interrupt::install();
    ExitCode::from(hal_sim::cli::execute(std::env::args_os()))
}
