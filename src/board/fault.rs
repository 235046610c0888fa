//! The fault path: panic, HardFault, any unexpected interrupt and a failed boot check switch
//! the motor outputs off before anything else, then end in a reset.
//!
//! [`safe_outputs_off`] touches registers only (no driver, no lock, no allocation), so it is
//! callable from any context, including a fault inside the HAL. After it:
//! - panic: log the message over defmt, then `udf` → HardFault (a debugger running
//!   `probe-rs run` stops there and prints the backtrace);
//! - HardFault, and `DefaultHandler` (an interrupt enabled without a handler): outputs off
//!   again (it may be a fault of its own), log, then [`reset_after_log`];
//! - a boot check that fails ([`boot_fault`]): outputs off, log the [`BootCheck`], reset.
//!
//! Every path ends in a reset of its own, so a fault before the watchdog starts (clock or
//! ADC bring-up) cannot hang the board. Interrupts stay masked meanwhile, so nothing can
//! re-enable the outputs.
//!
//! `panic-probe` is not linked: it has no hook to run before its own logging.

use core::panic::PanicInfo;

use cortex_m::peripheral::SCB;
use cortex_m_rt::{exception, ExceptionFrame};
use embassy_stm32::pac;
use fpc::units::DacCode;

use super::clocks::SYSCLK_HZ;

/// A boot-time read-back that did not match: the board refuses to run. Stable numbers (they
/// are logged); each line tells the operator what to do.
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum BootCheck {
    /// PWR_CR5 bit 8 (R1MODE) did not read back 0: the core is not in boost mode and must
    /// not run at 170 MHz. Check the PAC/embassy version against `docs/upstream-pwr-cr5-r1mode.md`.
    BoostMode = 1,
    /// An ADC's JSQR (injected sequence and trigger) did not read back as written: the
    /// injected queue was not disabled first, or the ADC was converting. Firmware bug.
    AdcJsqr = 2,
    /// An ADC's CFGR (regular trigger, JQDIS, overrun mode) did not read back as written.
    AdcCfgr = 3,
    /// ADC12_CCR (dual mode, DMA mode, clock prescaler) did not read back as written.
    Adc12Ccr = 4,
}

/// Safe torque off: both bridges' gates low (TIM1/TIM8 MOE = 0 with OSSI = 1 forces every
/// output to its idle level, low), servo torque command to zero.
pub fn safe_outputs_off() {
    super::safe_pwm_off();
    pac::DAC1.dhr12r(0).write(|w| w.set_dhr(DacCode::MID.0));
}

/// A boot check failed: outputs off, log which, reset.
pub fn boot_fault(check: BootCheck) -> ! {
    cortex_m::interrupt::disable();
    safe_outputs_off();
    defmt::error!("boot check failed: {} ({=u8})", check, check as u8);
    reset_after_log()
}

/// Waits ≈ 10 ms (at 170 MHz; ≈ 100 ms at the 16 MHz boot clock) so an attached host can
/// read the last log, then resets the MCU. The IWDG, if already running, may reset first.
fn reset_after_log() -> ! {
    cortex_m::asm::delay(SYSCLK_HZ / 100);
    SCB::sys_reset()
}

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    safe_outputs_off();
    // Location and static message only: formatting the message's arguments would link all
    // of core::fmt (float formatting alone is ~17 KiB of flash).
    let message = info.message().as_str().unwrap_or("(formatted message)");
    match info.location() {
        Some(l) => defmt::error!(
            "panic at {=str}:{=u32}: {=str}",
            l.file(),
            l.line(),
            message
        ),
        None => defmt::error!("panic: {=str}", message),
    }
    cortex_m::asm::udf()
}

// SAFETY: cortex-m-rt requires the HardFault handler to be an `unsafe fn`; this one only
// writes peripheral registers through the PAC, reads the stacked frame it is given and
// requests a system reset.
#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    safe_outputs_off();
    defmt::error!("HardFault at pc {=u32:#010x}", frame.pc());
    reset_after_log()
}

// SAFETY: cortex-m-rt requires `DefaultHandler` to be an `unsafe fn`. It runs for any
// exception or interrupt without a handler of its own (an interrupt enabled by mistake);
// it only writes peripheral registers, logs and requests a system reset.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    cortex_m::interrupt::disable();
    safe_outputs_off();
    defmt::error!("unexpected exception or interrupt {=i16}", irqn);
    reset_after_log()
}
