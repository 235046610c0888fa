//! `hal-sim`: the simulated hardware and plant of the free-piston compressor, and the
//! `fpc-sim` tool built on it.
//!
//! The simulated board implements the same port traits as the STM32G474 board, and
//! [`board::exec::simulate`] runs the firmware's own task bodies against it in lock-step with
//! simulated time — deterministic, seeded, no threads or sleeps.
//!
//! The tree follows the roles (plant, board, faults, run, gap, sweep, link, cli); the module
//! map is in `docs/architecture.md`, the one place it is written, and the manual of the tool
//! in `docs/fpc-sim.md`.
#![warn(missing_docs)]

pub mod balance;
pub mod board;
pub mod calibration;
pub mod cli;
pub mod console;
pub mod failure;
pub mod faults;
pub mod gap;
pub mod interrupt;
pub mod link;
pub mod logmeta;
pub mod output;
pub mod paper;
pub mod plant;
pub mod plot;
pub mod published;
pub mod run;
pub mod runlog;
pub mod signal;
pub mod sweep;
pub mod view;
