//! `fpc`: the hardware-agnostic control logic of the free-piston compressor.
//!
//! `no_std`, shared by the STM32G474 firmware (`src/main.rs`, `src/board/`), the host
//! simulator `hal-sim` and the Cortex-M4 benchmark. One physical concept per module, one
//! subsystem per folder.
//!
//! The tree follows the data from sensor codes to switching duties:
//!
//! | module | owns |
//! |---|---|
//! | [`units`], [`real`], [`angle`] | ticks, codes, duties, the two sections; the scalar the physics is written over; fixed-point angles |
//! | [`ports`] | the hardware boundary as small traits |
//! | [`status`] | the operating mode and the per-step status snapshot |
//! | [`sensing`] | encoders, quadrature, differentiator, pressures, homing |
//! | [`physics`] | friction, gas and chambers, cogging, motor, port timing (shared with the plant and the workflow) |
//! | [`safety`] | faults and the per-cycle supervisor |
//! | [`motion`] | trajectories, the stroke, the volume ratio, the rotation synchroniser |
//! | [`drive`] | force allocation over both sections, current loops, the servo loop |
//! | [`control`] | configuration, commands, calibration, the control step |
//! | [`link`] | RTT framing, the command and reply codec, the telemetry frame |
//! | [`shared`] | state shared between tasks |
//! | [`tasks`] | the generic task bodies the firmware and the simulator both run |
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
// The control path never panics: no unwrap/expect/panic/unchecked indexing outside tests.
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable,
        clippy::todo,
        clippy::unimplemented
    )
)]
#![cfg_attr(test, allow(clippy::disallowed_methods))]

pub mod angle;
pub mod control;
pub mod drive;
pub mod link;
pub mod motion;
pub mod physics;
pub mod ports;
pub mod real;
pub mod safety;
pub mod sensing;
pub mod shared;
pub mod status;
pub mod tasks;
pub mod units;
