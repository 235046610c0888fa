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

use cortex_m_rt::{exception, ExceptionFrame};
use embassy_stm32::pac;
use fpc::units::DacCode;

/// Safe torque off: both bridges' gates low (TIM1/TIM8 MOE = 0 with OSSI = 1 forces every
/// output to its idle level, low), servo torque command to zero.
pub fn safe_outputs_off() {
    super::safe_pwm_off();
    pac::DAC1.dhr12r(0).write(|w| w.set_dhr(DacCode::MID.0));
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
