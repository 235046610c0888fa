//! A simulated NOR flash with the STM32G474's geometry in dual-bank mode (2 KiB pages,
//! 8-byte double-word programming), behind the same `embedded-storage-async` traits the
//! firmware's flash driver implements, and a power cut injectable at any step.
//!
//! What NOR flash does, and what is modelled: an erase sets a whole page to `0xFF`; a write
//! can only clear bits (the stored word becomes `old & new`); a double word may be written
//! once after an erase (the G4's ECC forbids a second write, except all zeros), which the
//! simulation enforces so that a store relying on rewrites fails here as on the chip. Each
//! page counts its erases (wear: the G4 guarantees 10 000 cycles).
//!
//! A *step* is one double-word program or one page erase. [`SimFlash::cut_power_at`]`(k)`
//! makes step `k` (counted from 0 since the cut was armed) tear — half of the double word
//! programmed, or the first half of the page erased, as an interrupted operation leaves it
//! in address order — and every operation from then on fail with
//! [`SimFlashError::PowerLost`]. [`SimFlash::reboot`] gives the flash as it stands to a
//! new session, powered again.

use fpc::control::calibration::record::CalibrationRecord;
use fpc::control::calibration::store::CalibrationStore;

use embedded_storage_async::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// Erase unit, bytes (G474 dual-bank page).
pub const PAGE_BYTES: usize = 2048;
/// Programming unit, bytes (a double word).
pub const WORD_BYTES: usize = 8;

/// Why an operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimFlashError {
    /// The power was cut (this operation tore, or came after the cut).
    PowerLost,
    /// Outside the flash.
    OutOfBounds,
    /// Not aligned to the programming or erase unit.
    NotAligned,
    /// A double word written twice since its page was erased (not all zeros the second time).
    WrittenTwice,
}

impl NorFlashError for SimFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SimFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            SimFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            SimFlashError::PowerLost | SimFlashError::WrittenTwice => NorFlashErrorKind::Other,
        }
    }
}

/// The simulated flash.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SimFlash {
    bytes: Vec<u8>,
    /// Per double word: programmed since its page's last erase.
    written: Vec<bool>,
    /// Erases per page.
    wear: Vec<u32>,
    /// Steps done since the cut was armed (or since power-up).
    steps: u64,
    /// The step that tears.
    cut_at: Option<u64>,
    powered: bool,
}

impl SimFlash {
    /// `pages` erased pages (as a new chip's).
    pub fn new(pages: usize) -> Self {
        SimFlash {
            bytes: vec![0xFF; pages * PAGE_BYTES],
            written: vec![false; pages * PAGE_BYTES / WORD_BYTES],
            wear: vec![0; pages],
            steps: 0,
            cut_at: None,
            powered: true,
        }
    }

    /// Arms a power cut: step `step` from now tears, nothing after it happens.
    pub fn cut_power_at(&mut self, step: u64) {
        self.steps = 0;
        self.cut_at = Some(step);
    }

    /// Steps (double-word programs and page erases) since power-up or the cut was armed.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Whether the power is still on.
    pub fn powered(&self) -> bool {
        self.powered
    }

    /// The flash as it stands, powered again, with no cut armed (what the next boot reads).
    pub fn reboot(&self) -> SimFlash {
        SimFlash {
            steps: 0,
            cut_at: None,
            powered: true,
            ..self.clone()
        }
    }

    /// Erases per page.
    pub fn wear(&self) -> &[u32] {
        &self.wear
    }

    /// The contents.
    pub fn image(&self) -> &[u8] {
        &self.bytes
    }

    /// Counts a step; `Ok(true)` if this one tears.
    fn step(&mut self) -> Result<bool, SimFlashError> {
        if !self.powered {
            return Err(SimFlashError::PowerLost);
        }
        let tears = self.cut_at == Some(self.steps);
        self.steps += 1;
        if tears {
            self.powered = false;
        }
        Ok(tears)
    }

    fn range(&self, offset: u32, len: usize) -> Result<core::ops::Range<usize>, SimFlashError> {
        let start = offset as usize;
        let end = start
            .checked_add(len)
            .filter(|end| *end <= self.bytes.len())
            .ok_or(SimFlashError::OutOfBounds)?;
        Ok(start..end)
    }
}

impl ErrorType for SimFlash {
    type Error = SimFlashError;
}

impl ReadNorFlash for SimFlash {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), SimFlashError> {
        if !self.powered {
            return Err(SimFlashError::PowerLost);
        }
        let r = self.range(offset, bytes.len())?;
        bytes.copy_from_slice(&self.bytes[r]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.bytes.len()
    }
}

impl NorFlash for SimFlash {
    const WRITE_SIZE: usize = WORD_BYTES;
    const ERASE_SIZE: usize = PAGE_BYTES;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), SimFlashError> {
        let (from, to) = (from as usize, to as usize);
        if !from.is_multiple_of(PAGE_BYTES) || !to.is_multiple_of(PAGE_BYTES) || to < from {
            return Err(SimFlashError::NotAligned);
        }
        self.range(from as u32, to - from)?;
        for page in from / PAGE_BYTES..to / PAGE_BYTES {
            let tears = self.step()?;
            let start = page * PAGE_BYTES;
            let erased = if tears { PAGE_BYTES / 2 } else { PAGE_BYTES };
            self.bytes[start..start + erased].fill(0xFF);
            let words = start / WORD_BYTES..(start + erased) / WORD_BYTES;
            self.written[words].fill(false);
            if tears {
                return Err(SimFlashError::PowerLost);
            }
            self.wear[page] += 1;
        }
        Ok(())
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), SimFlashError> {
        if !(offset as usize).is_multiple_of(WORD_BYTES) || !bytes.len().is_multiple_of(WORD_BYTES)
        {
            return Err(SimFlashError::NotAligned);
        }
        let r = self.range(offset, bytes.len())?;
        for (i, data) in bytes.chunks_exact(WORD_BYTES).enumerate() {
            let at = r.start + i * WORD_BYTES;
            let word = at / WORD_BYTES;
            if self.written[word] && data.iter().any(|b| *b != 0) {
                return Err(SimFlashError::WrittenTwice);
            }
            let tears = self.step()?;
            let programmed = if tears { WORD_BYTES / 2 } else { WORD_BYTES };
            for (cell, d) in self.bytes[at..at + programmed].iter_mut().zip(data) {
                *cell &= d;
            }
            self.written[word] = true;
            if tears {
                return Err(SimFlashError::PowerLost);
            }
        }
        Ok(())
    }
}

/// Runs a future of the simulated flash to completion: it never waits (every operation is
/// done when polled), so polling with a no-op waker finishes it.
pub fn block_on<F: core::future::Future>(future: F) -> F::Output {
    let mut future = core::pin::pin!(future);
    let mut cx = core::task::Context::from_waker(core::task::Waker::noop());
    loop {
        if let core::task::Poll::Ready(out) = future.as_mut().poll(&mut cx) {
            return out;
        }
    }
}

/// Pages of the simulated board's calibration store (the firmware reserves as many).
pub const STORE_PAGES: usize = 4;

/// A simulated board's flash with `record` saved by the firmware's own store (what a board
/// calibrated earlier boots from).
pub fn holding(record: &CalibrationRecord) -> Result<SimFlash, String> {
    let mut store = store(SimFlash::new(STORE_PAGES))?;
    block_on(store.save(record)).map_err(|e| format!("saving to the simulated flash: {e:?}"))?;
    Ok(store.into_flash())
}

/// The firmware's calibration store over the whole simulated flash.
pub fn store(flash: SimFlash) -> Result<CalibrationStore<SimFlash>, String> {
    let end = (STORE_PAGES * PAGE_BYTES) as u32;
    CalibrationStore::new(flash, 0..end).ok_or_else(|| "the store does not fit".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_only_clear_bits_and_erase_sets_the_page() {
        let mut f = SimFlash::new(2);
        block_on(f.write(8, &[0x0F; 8])).unwrap();
        assert_eq!(
            block_on(f.write(8, &[0xF0; 8])),
            Err(SimFlashError::WrittenTwice)
        );
        block_on(f.write(8, &[0; 8])).unwrap();
        block_on(f.erase(0, PAGE_BYTES as u32)).unwrap();
        assert!(f.image()[..PAGE_BYTES].iter().all(|b| *b == 0xFF));
        assert_eq!(f.wear(), &[1, 0]);
        assert_eq!(
            block_on(f.write(3, &[0; 8])),
            Err(SimFlashError::NotAligned)
        );
    }

    #[test]
    fn a_cut_tears_its_step_and_stops_everything_after() {
        let mut f = SimFlash::new(1);
        f.cut_power_at(1);
        assert_eq!(
            block_on(f.write(0, &[0; 24])),
            Err(SimFlashError::PowerLost)
        );
        assert_eq!(
            &f.image()[..16],
            &[0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 255, 255, 255, 255]
        );
        assert_eq!(f.image()[16], 0xFF);
        let mut buf = [0u8; 4];
        assert_eq!(block_on(f.read(0, &mut buf)), Err(SimFlashError::PowerLost));
        let mut f = f.reboot();
        block_on(f.read(0, &mut buf)).unwrap();
        assert_eq!(buf, [0; 4]);
    }
}
