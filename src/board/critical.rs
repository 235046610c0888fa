//! The firmware's critical sections, in two strengths.
//!
//! - The global one (`critical_section::with`, which embassy-time, embassy-stm32's time
//!   driver and the defmt logger take) raises BASEPRI to the priority of embassy-time's
//!   interrupt: it masks TIM2, FLASH and every less urgent interrupt, and never the
//!   end-of-burst interrupt or the control executor's, so a thread-mode critical section
//!   cannot delay the 20 kHz duties (BASEPRI masks the exceptions whose priority value is
//!   at or above it: ARMv7-M ARM B1.5.4, "Execution priority and priority boosting").
//! - [`ControlRawMutex`] masks every interrupt (PRIMASK): data the end-of-burst interrupt
//!   or the control task shares with anyone is behind it.
//!
//! Rule: code running at the end-of-burst or the control priority never takes the global
//! critical section (it could preempt a thread-mode holder of it). Should it, the global one
//! masks every interrupt there too, and [`CONTROL_LEVEL_ENTRIES`] counts it: the PIL's
//! scenarios read it from RAM and require 0.

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::register::{basepri, basepri_max, primask};

/// BASEPRI while in the global critical section: embassy-time's interrupt priority.
const MASK: u8 = super::TIME_PRIORITY as u8;
/// The low bit of the restore state: the global critical section also set PRIMASK.
const MASKED_ALL: u8 = 1;

/// Global critical sections entered at a priority above [`MASK`] (end-of-burst, control or
/// a fault handler) since reset: each is a breach of the rule above, except on the way to a
/// reset.
#[no_mangle]
pub static CONTROL_LEVEL_ENTRIES: AtomicU32 = AtomicU32::new(0);

/// The global critical section's implementation.
struct BelowControl;
critical_section::set_impl!(BelowControl);

/// The current exception's priority is more urgent than [`MASK`] (thread mode: no).
fn above_mask() -> bool {
    let ipsr: u32;
    // SAFETY: reads IPSR into a register; no memory or flags touched.
    unsafe {
        core::arch::asm!("mrs {}, IPSR", out(reg) ipsr, options(nomem, nostack, preserves_flags))
    };
    match ipsr {
        0 => false,
        // NMI, HardFault and the other system exceptions this firmware does not configure.
        1..=15 => true,
        n => {
            let irq = (n - 16) as u16;
            let prio = cortex_m::peripheral::NVIC::get_priority(Irq(irq));
            prio < MASK
        }
    }
}

/// An interrupt number, for [`cortex_m::peripheral::NVIC::get_priority`].
#[derive(Clone, Copy)]
struct Irq(u16);

// SAFETY: `Irq` is built only from IPSR, a valid exception number minus 16.
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self.0
    }
}

// SAFETY: `acquire` masks every exception that can take the global critical section (the
// rule above; where it is broken, PRIMASK masks them all) until `release` restores the
// BASEPRI and PRIMASK it found: no two holders run at once on this single core.
unsafe impl critical_section::Impl for BelowControl {
    unsafe fn acquire() -> u8 {
        let was = basepri::read() & !MASKED_ALL;
        if above_mask() {
            CONTROL_LEVEL_ENTRIES.fetch_add(1, Ordering::Relaxed);
            let were_on = primask::read().is_active();
            cortex_m::interrupt::disable();
            return was | if were_on { MASKED_ALL } else { 0 };
        }
        basepri_max::write(MASK);
        was
    }

    unsafe fn release(was: u8) {
        if was & MASKED_ALL != 0 {
            // SAFETY: this critical section set PRIMASK; clearing it restores what it found.
            unsafe { cortex_m::interrupt::enable() };
            return;
        }
        // SAFETY: restores the BASEPRI `acquire` found (critical sections nest in order).
        unsafe { basepri::write(was) };
    }
}

/// A raw mutex that masks every interrupt: for data the end-of-burst interrupt or the
/// control task shares.
pub struct ControlRawMutex(());

// SAFETY: `lock` runs its closure with PRIMASK set, so nothing else runs on this single core
// until it returns; the mutex holds no state, so it is `Send`/`Sync` by construction.
unsafe impl embassy_sync::blocking_mutex::raw::RawMutex for ControlRawMutex {
    #[allow(clippy::declare_interior_mutable_const)]
    const INIT: Self = ControlRawMutex(());

    fn lock<R>(&self, f: impl FnOnce() -> R) -> R {
        cortex_m::interrupt::free(|_| f())
    }
}
