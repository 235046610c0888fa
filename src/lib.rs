//! `fpc`: the hardware-agnostic control logic of the free-piston compressor.
//!
//! `no_std`, shared by the STM32G474 firmware (`src/main.rs`, `src/board/`), the host
//! simulator `hal-sim` and the Cortex-M4 benchmark. One physical concept per module:
//!
//! | module | concept |
//! |---|---|
//! | [`units`] | time ticks, ADC/DAC codes, duties, the two sections |
//! | [`ports`] | the hardware boundary as small traits |
//! | [`real`] | the scalar the physics is written over (f32 on the MCU, f64 in the plant) |
//! | [`encoder`] | sin/cos interpolation and period counting |
//! | [`quadrature`] | the servo's wrapping counter, extended |
//! | [`differentiator`] | fixed-point Savitzky–Golay velocity and acceleration |
//! | [`pressure`] | pressure codes to pascal, open/short detection |
//! | [`friction`] | Bo & Pavelescu friction law |
//! | [`cogging`] | cogging force: the law, and the calibrated compensation map |
//! | [`motor`] | linear-motor parameters and Clarke/Park |
//! | [`allocation`] | one force command split over both sections, cogging cancelled |
//! | [`foc`] | current loops and modulation of one section |
//! | [`servo`] | rotation servo loop |
//! | [`trajectory`] | reference setpoints and moves |
//! | [`homing`] | finding the zero at head A |
//! | [`faults`] | the fault enum and the latched set |
//! | [`supervisor`] | the per-cycle checks, the braking envelope, limit flags |
//! | [`command`] | host commands and refusals |
//! | [`controller`] | the 20 kHz control step, a pure function of its inputs |
//! | [`shared`] | state shared between tasks |
//! | [`tasks`] | the generic task bodies the firmware and the simulator both run |
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod allocation;
pub mod cogging;
pub mod command;
pub mod controller;
pub mod differentiator;
pub mod encoder;
pub mod faults;
pub mod foc;
pub mod friction;
pub mod homing;
pub mod motor;
pub mod ports;
pub mod pressure;
pub mod quadrature;
pub mod real;
pub mod servo;
pub mod shared;
pub mod supervisor;
pub mod tasks;
pub mod trajectory;
pub mod units;
