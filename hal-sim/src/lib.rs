//! `hal-sim`: the simulated hardware and plant of the free-piston compressor, and the
//! `fpc-sim` tool built on it.
//!
//! The simulated board implements the same port traits as the STM32G474 board, and
//! [`exec::simulate`] runs the firmware's own task bodies against it in lock-step with
//! simulated time — deterministic, seeded, no threads or sleeps.
//!
//! | module | what |
//! |---|---|
//! | [`plant`] | the physics: piston, end stops, friction, forces, configured by the model |
//! | [`chambers`] | the two chambers' gas: ports, leaks, heat transfer, one sub-step |
//! | [`motor_model`] | the two motor sections: dq model, misalignment, slave and actuator lag |
//! | [`servo_model`] | the rotation: servo drive, inertia, friction, spline backlash |
//! | [`fastmath`] | fast, accurate `sin_cos` for the plant's hot path |
//! | [`sensors`] | sensor models: encoders, currents, pressures, quadrature; seeded noise |
//! | [`kinematic`] | prescribed-motion drive of the plant (physics checks, synthetic data) |
//! | [`world`] | the simulated board: time, sampling, outputs, the port impls |
//! | [`exec`] | running the firmware's task bodies in simulated time |
//! | [`inject`] | `--fault` specifications of the fault scenarios |
//! | [`fault_apply`] | the fault scenarios applied to a running simulation, and what they did |
//! | [`model`] | the machine-model TOML |
//! | [`runlog`] | the run-log CSV |
//! | [`cli`] | what every subcommand shares: failures and exit codes |
//! | [`run`] | the closed-loop run and its figures |
//! | [`run_cmd`] | `fpc-sim run` |
//! | [`plot`] | SVG plots |
//! | [`capture`] | the simulated telemetry sink; decoding a capture to a run log |
//! | [`signal`] | cross-correlation lag, filtfilt, differences, strokes |
//! | [`analysis`] | what the log-analysis subcommands share |
//! | [`gap`], [`gap_cmd`] | the model-gap workflow; `fpc-sim gap` |
//! | [`derive`] | `fpc-sim derive`: the firmware's differentiator over a run log |
//! | [`decode_cmd`], [`lag_cmd`], [`filters_cmd`], [`forces_cmd`], [`energy_cmd`], [`pv_cmd`] | `fpc-sim decode`, `lag`, `filters`, `forces`, `energy`, `pv` |
#![warn(missing_docs)]

pub mod analysis;
pub mod capture;
pub mod chambers;
pub mod cli;
pub mod decode_cmd;
pub mod derive;
pub mod energy_cmd;
pub mod exec;
pub mod fastmath;
pub mod fault_apply;
pub mod filters_cmd;
pub mod forces_cmd;
pub mod gap;
pub mod gap_cmd;
pub mod inject;
pub mod kinematic;
pub mod lag_cmd;
pub mod model;
pub mod motor_model;
pub mod plant;
pub mod plot;
pub mod pv_cmd;
pub mod run;
pub mod run_cmd;
pub mod runlog;
pub mod sensors;
pub mod servo_model;
pub mod signal;
pub mod world;
