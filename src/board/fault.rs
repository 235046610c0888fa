//! The fault path: panic and HardFault switch the motor outputs off before anything else.
//!
//! [`safe_outputs_off`] touches registers only (no driver, no lock, no allocation), so it is
//! callable from any context, including a fault inside the HAL. After it:
//! - panic: log the message over defmt, then `udf` → HardFault (a debugger running
//!   `probe-rs run` stops there and prints the backtrace);
//! - HardFault: outputs off again (it may be a fault of its own), log the faulting PC, then
//!   spin until the IWDG resets the board (≤ 20 ms). Interrupts stay masked, so nothing can
//!   re-enable the outputs meanwhile.
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
}

/// Safe torque off: both bridges' gates low (TIM1/TIM8 MOE = 0 with OSSI = 1 forces every
/// output to its idle level, low), servo torque command to zero.
pub fn safe_outputs_off() {
    super::safe_pwm_off();
    pac::DAC1.dhr12r(0).write(|w| w.set_dhr(DacCode::MID.0));
}

/// A boot check failed: outputs off, log which, reset. Runs before the watchdog is started,
/// so it resets by itself.
pub fn boot_fault(check: BootCheck) -> ! {
    cortex_m::interrupt::disable();
    safe_outputs_off();
    defmt::error!("boot check failed: {} ({=u8})", check, check as u8);
    // ≈ 10 ms at 170 MHz (≈ 100 ms at the 16 MHz boot clock) for a host to read the log.
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
// writes peripheral registers through the PAC and reads the stacked frame it is given.
#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    safe_outputs_off();
    defmt::error!("HardFault at pc {=u32:#010x}", frame.pc());
    loop {
        core::hint::spin_loop();
    }
}
