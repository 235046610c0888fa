//! `hal-sim`: the simulated hardware and plant of the free-piston compressor, and the
//! `fpc-sim` tool built on it.
//!
//! The simulated board implements the same port traits as the STM32G474 board, and
//! [`exec::simulate`] runs the firmware's own task bodies against it in lock-step with
//! simulated time — deterministic, seeded, no threads or sleeps.
//!
//! | module | what |
//! |---|---|
//! | [`plant`] | the physics: piston, end stops, motor sections, rotation |
//! | [`world`] | the simulated board: time, sampling, outputs, the port impls |
//! | [`exec`] | running the firmware's task bodies in simulated time |
//! | [`model`] | the machine-model TOML |
//! | [`runlog`] | the run-log CSV |
//! | [`cli`] | what every subcommand shares: failures and exit codes |
//! | [`run`] | the closed-loop run and its figures |
//! | [`run_cmd`] | `fpc-sim run` |
//! | [`plot`] | SVG plots |
#![warn(missing_docs)]

pub mod cli;
pub mod exec;
pub mod model;
pub mod plant;
pub mod plot;
pub mod run;
pub mod run_cmd;
pub mod runlog;
pub mod world;
