//! `fpc`: the hardware-agnostic control logic of the free-piston compressor.
//!
//! `no_std`, shared by the STM32G474 firmware (`src/main.rs`, `src/board/`), the host
//! simulator `hal-sim` and the Cortex-M4 benchmark. One physical concept per module:
//!
//! | module | concept |
//! |---|---|
//! | [`units`] | time ticks, ADC/DAC codes, duties, the two sections |
//! | [`angle`] | wrapping fixed-point angles, table sine and cosine |
//! | [`ports`] | the hardware boundary as small traits |
//! | [`real`] | the scalar the physics is written over (f32 on the MCU, f64 in the plant) |
//! | [`encoder`] | sin/cos interpolation and period counting |
//! | [`quadrature`] | the servo's wrapping counter, extended |
//! | [`differentiator`] | fixed-point Savitzky–Golay velocity and acceleration |
//! | [`pressure`] | pressure codes to pascal, open/short detection |
//! | [`friction`] | Bo & Pavelescu friction law |
//! | [`gas`] | chamber volumes, gas force, energy equation, nozzle and leak flow, heat |
//! | [`port_timing`] | port windows in rotation phase: which port is open, and how far |
//! | [`cogging`] | cogging force: the law, and the calibrated compensation map |
//! | [`motor`] | linear-motor parameters and Clarke/Park |
//! | [`allocation`] | one force command split over both sections, cogging cancelled |
//! | [`calibration`] | the calibration routines: offsets, alignment, misalignment, cogging map |
//! | [`foc`] | current loops and modulation of one section |
//! | [`servo`] | rotation servo loop |
//! | [`trajectory`] | reference setpoints and moves |
//! | [`stroke`] | the periodic stroke and dead-point control |
//! | [`volume_ratio`] | where the discharge opens, corrected stroke by stroke |
//! | [`synchroniser`] | the rotation slaved to the measured stroke: an electronic cam |
//! | [`homing`] | finding the zero at head A |
//! | [`faults`] | the fault enum and the latched set |
//! | [`supervisor`] | the per-cycle checks, the braking envelope, limit flags |
//! | [`command`] | host commands and refusals |
//! | [`link`] | RTT framing, command and reply codec |
//! | [`telemetry`] | the telemetry frame and its decoder |
//! | [`controller`] | the 20 kHz control step, a pure function of its inputs |
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

pub mod allocation;
pub mod angle;
pub mod calibration;
pub mod cogging;
pub mod command;
pub mod controller;
pub mod differentiator;
pub mod encoder;
pub mod faults;
pub mod foc;
pub mod friction;
pub mod gas;
pub mod homing;
pub mod link;
pub mod motor;
pub mod port_timing;
pub mod ports;
pub mod pressure;
pub mod quadrature;
pub mod real;
pub mod servo;
pub mod shared;
pub mod stroke;
pub mod supervisor;
pub mod synchroniser;
pub mod tasks;
pub mod telemetry;
pub mod trajectory;
pub mod units;
pub mod volume_ratio;
