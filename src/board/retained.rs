//! The calibration kept in RAM across a watchdog reset (issue #16, finding 5).
//!
//! After a watchdog reset the controller brakes on its own (the piston may be moving at full
//! speed when a task hangs). It must brake with the calibration the machine was running on,
//! not the built-in defaults: current offsets off by a few codes give wrong forces. SRAM
//! keeps its contents through a system reset, so each record a calibration routine produces
//! is copied here (a `.uninit` section, which the start-up code neither zeroes nor
//! initialises), and the boot after a watchdog reset loads it if it is intact
//! ([`fpc::control::calibration::record::after_reset`]: magic, version, CRC). After power-on
//! the bytes are garbage and are not used. With the feature `calibration-store` the flash
//! holds the same record and this copy is not needed.

use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

use fpc::control::calibration::record::{after_reset, CalibrationRecord, RECORD_BYTES};
use fpc::safety::faults::ResetCause;

/// The retained record's bytes.
#[link_section = ".uninit.fpc_retained_calibration"]
static mut RETAINED: MaybeUninit<[u8; RECORD_BYTES]> = MaybeUninit::uninit();

/// Keeps `record` for the boot after a watchdog reset.
pub fn keep(record: &CalibrationRecord) {
    let bytes = record.encode();
    // SAFETY: only the one retaining task (thread mode) writes, and the boot reads before
    // that task is spawned, so no access overlaps; a raw-pointer volatile write of plain
    // bytes, no reference to the `static mut` is formed.
    unsafe {
        addr_of_mut!(RETAINED)
            .cast::<[u8; RECORD_BYTES]>()
            .write_volatile(bytes)
    };
}

/// The record to boot with after a reset of cause `cause`, if one is retained and intact.
pub fn at_boot(cause: ResetCause) -> Option<CalibrationRecord> {
    // SAFETY: read once at boot before the retaining task exists (no concurrent write);
    // every bit pattern is a valid byte array, so reading bytes that power-on left
    // undefined gives garbage, never undefined values of another type, and the record's
    // magic, version and CRC refuse it.
    let bytes = unsafe {
        addr_of!(RETAINED)
            .cast::<[u8; RECORD_BYTES]>()
            .read_volatile()
    };
    after_reset(cause, &bytes)
}
