//! `fpc-pil`: processor-in-the-loop. The release firmware ELF — the binary a user flashes —
//! runs in an emulated STM32G474 (unicorn's Cortex-M4 and the peripherals the firmware
//! touches, modelled from RM0440), closed-loop with `hal-sim`'s plant at 20 kHz; the host
//! side plays the operator over the RTT channels as a debug probe does.
//!
//! | module | what |
//! |---|---|
//! | [`chip`] | the emulated MCU: core, exceptions, NVIC, timers, ADC/DMA, flash, IWDG, RCC |
//! | [`board`] | the PCB: pins to plant signals, bridges and servo to the plant |
//! | [`elf`] | the firmware image |
//! | [`session`] | the host attached as a probe: RTT (hal-sim's reader over the chip's memory), defmt, telemetry |
//! | [`run`], [`faults`] | the main job's scenario and the fault scenarios |
//! | [`commission`] | the motor's commissioning, as the host runs it over the link |
//! | [`bench`] | the bring-up's bench operations (a fixed duty, a servo torque) over the link |
//! | [`mutants`] | the mutation tests: each deliberate mistake caught |
//! | [`save_timing`] | the control period while a save erases and programs flash |
//! | [`log`] | the defmt log of up 0 |
//! | [`stack`] | the firmware's stack use, read from RAM as a probe would |
//! | [`time`] | emulated time |
//!
//! Licence: this package links unicorn (GPL-2.0), so it is GPL-2.0; it is its own
//! workspace so that nothing else in the repository links it (see `pil/README.md`).
#![warn(missing_docs)]

pub mod bench;
pub mod board;
pub mod capture;
pub mod chip;
pub mod commission;
pub mod elf;
pub mod faults;
pub mod log;
pub mod mutants;
pub mod probe;
pub mod run;
pub mod save_timing;
pub mod session;
pub mod stack;
pub mod time;
