//! `hal-sim`: the simulated hardware and plant of the free-piston compressor, and the
//! `fpc-sim` tool built on it.
//!
//! The simulated board implements the same port traits as the STM32G474 board, and
//! [`board::exec::simulate`] runs the firmware's own task bodies against it in lock-step with
//! simulated time — deterministic, seeded, no threads or sleeps.
//!
//! The tree follows the roles:
//!
//! | module | what |
//! |---|---|
//! | [`plant`] | the physics (piston, sections, rotation, chambers) and the machine-model TOML |
//! | [`board`] | the simulated board: time, sampling, sensors and their faults, outputs, the executor, telemetry capture |
//! | [`faults`] | `--fault` specifications and their injection into a running simulation |
//! | [`published`] | the published rig's master/slave drives, a baseline controller written from the paper |
//! | [`run`] | the closed-loop run and its figures |
//! | [`runlog`] | the run-log CSV |
//! | [`signal`] | cross-correlation lag, filtfilt, differences, strokes |
//! | [`gap`] | the model-gap workflow |
//! | [`balance`] | the force balance along a log and the works of a stroke (`fpc-sim forces`, `energy`) |
//! | [`sweep`] | studies: every run of a plan in parallel, sharded, merged |
//! | [`link`] | the host link to the running board over RTT (`fpc-sim link`) |
//! | [`plot`] | SVG plots (reports of the runs, the log tools and the gap workflow) |
//! | [`calibration`] | calibration files (TOML), the simulated commissioning that writes one, the flash that holds one |
//! | [`failure`] | the failure type and its exit codes |
//! | [`output`] | outputs checked before work, staged and moved into place complete |
//! | [`console`] | stdout/stderr lines that fail with exit 1 instead of panicking |
//! | [`cli`] | `fpc-sim`: a module per subcommand and the log tools' shared plumbing |
#![warn(missing_docs)]

pub mod balance;
pub mod board;
pub mod calibration;
pub mod cli;
pub mod console;
pub mod failure;
pub mod faults;
pub mod gap;
pub mod link;
pub mod output;
pub mod plant;
pub mod plot;
pub mod published;
pub mod run;
pub mod runlog;
pub mod signal;
pub mod sweep;
