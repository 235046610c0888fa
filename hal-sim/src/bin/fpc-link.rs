//! `fpc-link`: the host link to the running board — `fpc-sim link` with the probe
//! transport, as a binary of its own (cargo feature `probe`), so that `fpc-sim` and its
//! default build stay as they are:
//!
//! ```sh
//! cargo install --path hal-sim --features probe --bin fpc-link
//! fpc-link telemetry --rate 2000
//! fpc-link capture --elf target/thumbv7em-none-eabihf/release/fpc --out rig-run
//! ```
//!
//! Every subcommand and flag is `fpc-sim link`'s (`fpc-link --help`).

use std::process::ExitCode;

fn main() -> ExitCode {
    hal_sim::interrupt::install();
    let args = std::env::args_os().skip(1);
    let argv = ["fpc-sim".into(), "link".into()].into_iter().chain(args);
    ExitCode::from(hal_sim::cli::execute::<_, std::ffi::OsString>(argv))
}
