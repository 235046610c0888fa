//! Firmware entry (the STM32G474 board glue lands next).
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(not(target_os = "none"))]
fn main() {}
