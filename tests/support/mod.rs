//! Set-up shared by the behaviour tests: one module per kind of test bench.
//!
//! - [`sensing`]: seeded noise and distorted encoder signals built from the library's types;
//! - [`drive`]: the firmware's control step on the simulated board, one period at a time;
//! - [`gap`]: model files, synthetic runs and the model-gap workflow run on them;
//! - [`forms`]: the benchmarks of the field logs' forms on the plants written apart;
//! - [`rig`]: a bench session on the simulated board through the link, as on the rig;
//! - [`strokes`]: the stroke cycle of a fault-free run, to place faults at its phases.
//!
//! Each test file declares `mod support;` and uses the subset it needs.
#![allow(dead_code)] // each test file uses its own subset

pub mod drive;
pub mod forms;
pub mod gap;
pub mod rig;
pub mod sensing;
pub mod strokes;
