//! The calibration store's flash, as the store and the fault path use it.
//!
//! - [`CheckedFlash`]: embassy's async flash driver with the flash controller's error flags
//!   latched. embassy-stm32 0.6's FLASH interrupt clears every error flag of FLASH_SR before
//!   the waiting future reads them, so a program or an erase the controller ends with an
//!   error is returned as done (`docs/upstream-flash-error-flags.md`). [`LatchFlashErrors`],
//!   bound to the FLASH interrupt ahead of embassy's handler, ORs the flags into
//!   [`LATCHED`] first; [`CheckedFlash`] clears it before each program or erase and turns a
//!   flag latched meanwhile into that operation's error. So a failed erase or copy-forward
//!   inside the storage crate fails the save, as a failed record write did already (the
//!   save's read-back).
//! - [`CheckedFlash`]'s reads yield to the other thread-mode tasks: a save into a full
//!   store scans its items for several milliseconds of CPU, longer than the watchdog's 3 ms
//!   window that the supervision task (the same executor) must feed within.
//! - [`zero_double_word`] and [`erase_calibration_store`]: register-level, for the NMI
//!   handler (interrupts masked, no driver, no await).

use core::sync::atomic::{AtomicU32, Ordering};

use embassy_stm32::flash::{Async, Error, Flash};
use embassy_stm32::interrupt::typelevel::{Handler, FLASH};
use embassy_stm32::pac;
use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

use super::watchdog::reload_watchdog;

/// FLASH_SR's error flags (RM0440, FLASH_SR): OPERR, PROGERR, WRPERR, PGAERR, SIZERR,
/// PGSERR, MISERR, FASTERR.
const SR_ERRORS: u32 = 0x3FA;
/// FLASH_SR's write-1-to-clear bits (EOP and every flag).
const SR_W1C: u32 = 0xC3FB;
const SR_BSY: u32 = 1 << 16;
const CR_PG: u32 = 1 << 0;
const CR_PER: u32 = 1 << 1;
const CR_BKER: u32 = 1 << 11;
const CR_STRT: u32 = 1 << 16;
const CR_LOCK: u32 = 1 << 31;
/// FLASH_ACR.DCEN: the data cache, off while the fault path programs (embassy does the same
/// around its operations).
const ACR_DCEN: u32 = 1 << 10;

/// Error flags of FLASH_SR seen by the FLASH interrupt since the last program or erase began.
static LATCHED: AtomicU32 = AtomicU32::new(0);

/// The FLASH interrupt's first handler: latches the error flags before embassy's handler
/// clears them. Bind it ahead of `embassy_stm32::flash::InterruptHandler`.
pub struct LatchFlashErrors;

impl Handler<FLASH> for LatchFlashErrors {
    unsafe fn on_interrupt() {
        LATCHED.fetch_or(pac::FLASH.sr().read().0 & SR_ERRORS, Ordering::Relaxed);
    }
}

/// The flash error a latched FLASH_SR flag stands for (embassy's own mapping), or none.
fn latched_error() -> Result<(), Error> {
    let sr = LATCHED.swap(0, Ordering::Relaxed);
    match sr {
        0 => Ok(()),
        s if s & (1 << 3) != 0 => Err(Error::Prog),
        s if s & (1 << 4) != 0 => Err(Error::Protected),
        s if s & (1 << 5) != 0 => Err(Error::Unaligned),
        s if s & (1 << 6) != 0 => Err(Error::Size),
        s if s & (1 << 8) != 0 => Err(Error::Miss),
        // PGSERR, OPERR (an erase that failed), FASTERR.
        _ => Err(Error::Seq),
    }
}

/// embassy's async flash driver whose programs and erases fail when the flash controller
/// flagged an error (see the module header).
pub struct CheckedFlash {
    inner: Flash<'static, Async>,
}

impl CheckedFlash {
    /// Wraps the driver. Its interrupt must be bound with [`LatchFlashErrors`] first.
    pub fn new(inner: Flash<'static, Async>) -> Self {
        CheckedFlash { inner }
    }
}

impl ErrorType for CheckedFlash {
    type Error = Error;
}

impl ReadNorFlash for CheckedFlash {
    const READ_SIZE: usize = <Flash<'static, Async> as ReadNorFlash>::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        // A read is memory-mapped and never waits, so a save's scan of a full store (its
        // items checked for newer copies before a page is erased: > 3 ms of thread-mode CPU
        // in the emulator) would keep the supervision task, and its watchdog feed, from
        // running. Each read lets the other thread-mode tasks run first.
        embassy_futures::yield_now().await;
        self.inner.read(offset, bytes).await
    }

    fn capacity(&self) -> usize {
        self.inner.capacity()
    }
}

impl NorFlash for CheckedFlash {
    const WRITE_SIZE: usize = <Flash<'static, Async> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <Flash<'static, Async> as NorFlash>::ERASE_SIZE;

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        LATCHED.store(0, Ordering::Relaxed);
        let done = NorFlash::write(&mut self.inner, offset, bytes).await;
        let latched = latched_error();
        done.and(latched)
    }

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        LATCHED.store(0, Ordering::Relaxed);
        let done = NorFlash::erase(&mut self.inner, from, to).await;
        let latched = latched_error();
        done.and(latched)
    }
}

/// Waits until the flash controller is idle, reloading the IWDG meanwhile (the fault path
/// outlasts the watchdog's window during an erase).
fn wait_idle() {
    while pac::FLASH.sr().read().0 & SR_BSY != 0 {
        reload_watchdog();
    }
}

/// Unlocks FLASH_CR (KEYR sequence) if it is locked; false if it stays locked (a wrong key
/// sequence earlier locks it until the next reset).
fn unlock() -> bool {
    let flash = pac::FLASH;
    if flash.cr().read().0 & CR_LOCK != 0 {
        flash.keyr().write_value(0x4567_0123);
        flash.keyr().write_value(0xCDEF_89AB);
    }
    flash.cr().read().0 & CR_LOCK == 0
}

/// Programs the double word at `address` (8-byte aligned, in the calibration store) to all
/// zeros, from the fault path (interrupts masked). True if the controller reported no error.
pub fn zero_double_word(address: u32) -> bool {
    let flash = pac::FLASH;
    wait_idle();
    if !unlock() {
        return false;
    }
    let acr = flash.acr().read();
    flash
        .acr()
        .write_value(pac::flash::regs::Acr(acr.0 & !ACR_DCEN));
    // A program may not start over stale error flags (PGSERR): clear them first.
    if !super::mutation::is("flash-over-stale-flags") {
        flash.sr().write_value(pac::flash::regs::Sr(SR_W1C));
    }
    flash.cr().write_value(pac::flash::regs::Cr(CR_PG));
    let word = (address & !7) as *mut u32;
    // SAFETY: `address` is inside the calibration store (the caller checks it against
    // `CALIBRATION_STORE`), kept out of the program by memory.x, and FLASH_CR.PG is set: these
    // two aligned word writes are the double-word program sequence of RM0440, nothing else
    // holds a reference to those bytes, and interrupts are masked.
    unsafe {
        word.write_volatile(0);
        word.add(1).write_volatile(0);
    }
    wait_idle();
    let ok = flash.sr().read().0 & SR_ERRORS == 0;
    flash.cr().write_value(pac::flash::regs::Cr(CR_LOCK));
    ok
}

/// Erases the calibration store's pages with the interrupts masked (the fault path: nothing
/// else may run), reloading the IWDG while each erase (≈ 22 ms, longer than the boot
/// window) runs in bank 2 and this code in bank 1. The last resort when zeroing a double
/// word failed.
pub fn erase_calibration_store() {
    let flash = pac::FLASH;
    wait_idle();
    if !unlock() {
        return;
    }
    let first = (super::CALIBRATION_STORE.start - 0x4_0000) / 2048;
    let last = (super::CALIBRATION_STORE.end - 0x4_0000) / 2048;
    for page in first..last {
        // Clear the error flags (write 1), then one page erase in bank 2.
        flash.sr().write_value(pac::flash::regs::Sr(SR_W1C));
        flash.cr().write_value(pac::flash::regs::Cr(
            CR_PER | CR_BKER | (page << 3) | CR_STRT,
        ));
        wait_idle();
    }
    flash.cr().write_value(pac::flash::regs::Cr(CR_LOCK));
}
