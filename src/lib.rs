//! `fpc`: the hardware-agnostic control logic of the free-piston compressor.
//!
//! `no_std`, shared by the STM32G474 firmware (`src/main.rs`, `src/board/`), the host
//! simulator `hal-sim` and the Cortex-M4 benchmark. One physical concept per module, one
//! subsystem per folder.
//!
//! The tree follows the data from sensor codes to switching duties; the module map, the walk
//! of one control cycle through it and the recipes for extending it are in
//! `docs/architecture.md`, the one place they are written.
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
pub mod reference;
pub mod safety;
pub mod sensing;
pub mod shared;
pub mod status;
pub mod tasks;
pub mod units;
