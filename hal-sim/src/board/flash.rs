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
//!
//! **ECC poison** ([`SimFlash::with_ecc_poison`]): the G4 stores 8 ECC bits with every double
//! word (RM0440 §5.3.9). A program or an erase cut half-way leaves cells whose data and ECC
//! disagree, and reading such a double word is a double ECC error: FLASH_ECCR.ECCD and an NMI
//! (the firmware's handler erases the store and resets, `src/board/fault.rs`). In this mode a
//! torn program poisons its double word, a torn erase every double word of the page it did not
//! reach, and a read that touches a poisoned double word fails with
//! [`SimFlashError::EccDouble`] (the NMI) instead of returning the half-programmed data. An
//! erase clears the poison. Without it, a torn word reads as its half-programmed bytes.

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
    /// A read touched a double word whose ECC does not match its data (a torn program or
    /// erase, in ECC-poison mode): the double ECC error, an NMI on the chip. The offset of
    /// the double word.
    EccDouble(u32),
}

impl NorFlashError for SimFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SimFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            SimFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            SimFlashError::PowerLost
            | SimFlashError::WrittenTwice
            | SimFlashError::EccDouble(_) => NorFlashErrorKind::Other,
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
    /// Torn operations leave double ECC errors (see the module header).
    ecc_poison: bool,
    /// Per double word: its data and ECC disagree.
    poisoned: Vec<bool>,
    /// The first double ECC error a read met since the last reboot (its offset).
    ecc_error: Option<u32>,
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
            ecc_poison: false,
            poisoned: vec![false; pages * PAGE_BYTES / WORD_BYTES],
            ecc_error: None,
        }
    }

    /// A flash holding `image` (a chip's store pages, as read back by a probe), every double
    /// word that is not all 0xFF taken as programmed.
    pub fn from_image(image: &[u8]) -> Self {
        let pages = image.len().div_ceil(PAGE_BYTES);
        let mut f = SimFlash::new(pages);
        f.bytes[..image.len()].copy_from_slice(image);
        for (w, word) in f.bytes.chunks(WORD_BYTES).enumerate() {
            f.written[w] = word.iter().any(|b| *b != 0xFF);
        }
        f
    }

    /// `pages` erased pages whose torn operations leave double ECC errors (module header).
    pub fn with_ecc_poison(pages: usize) -> Self {
        SimFlash {
            ecc_poison: true,
            ..SimFlash::new(pages)
        }
    }

    /// The first double ECC error a read met since the last reboot: the offset of its double
    /// word (the chip's FLASH_ECCR.ADDR_ECC, its NMI).
    pub fn ecc_error(&self) -> Option<u32> {
        self.ecc_error
    }

    /// Double words whose data and ECC disagree.
    pub fn poisoned_words(&self) -> usize {
        self.poisoned.iter().filter(|p| **p).count()
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
            ecc_error: None,
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
        if !r.is_empty() {
            let words = r.start / WORD_BYTES..=(r.end - 1) / WORD_BYTES;
            if let Some(w) = words.into_iter().find(|&w| self.poisoned[w]) {
                let at = (w * WORD_BYTES) as u32;
                self.ecc_error.get_or_insert(at);
                return Err(SimFlashError::EccDouble(at));
            }
        }
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
            self.written[words.clone()].fill(false);
            self.poisoned[words].fill(false);
            if tears {
                if self.ecc_poison {
                    // The cells the erase did not reach are half-way: data and ECC disagree.
                    let rest = (start + erased) / WORD_BYTES..(start + PAGE_BYTES) / WORD_BYTES;
                    self.poisoned[rest].fill(true);
                }
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
                self.poisoned[word] |= self.ecc_poison;
                return Err(SimFlashError::PowerLost);
            }
            // A whole program writes the ECC with the data: the double word reads clean again
            // (how the NMI handler repairs a torn one, with zeros).
            self.poisoned[word] = false;
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

/// The board's boot read of its calibration store, with the firmware's NMI handler
/// (`src/board/fault.rs`): a double ECC error in the store programs that double word to zero
/// and resets (the store's pages are erased only if that program fails), and the next boot
/// reads the store with the zeros, which the storage crate's CRCs skip. Returns the load, the
/// flash as the boots left it, and the resets the NMI made (never a loop).
pub fn boot_read(
    flash: SimFlash,
) -> (
    Result<CalibrationRecord, fpc::control::calibration::store::LoadError>,
    SimFlash,
    u32,
) {
    let mut flash = flash;
    flash.ecc_error = None;
    let mut resets = 0;
    loop {
        let mut s = match store(flash.clone()) {
            Ok(s) => s,
            Err(_) => {
                return (
                    Err(fpc::control::calibration::store::LoadError::Flash),
                    flash,
                    resets,
                )
            }
        };
        let loaded = block_on(s.load());
        let after = s.into_flash();
        if after.ecc_error().is_none() {
            return (loaded, after, resets);
        }
        // The NMI: the failing double word is in the store (the store is all this flash), so
        // the handler programs it to zero, then resets; if that fails, it erases the store.
        let at = after.ecc_error().unwrap_or(0);
        let mut repaired = after.reboot();
        if block_on(repaired.write(at, &[0; WORD_BYTES])).is_err() {
            let end = (repaired.bytes.len()) as u32;
            if block_on(repaired.erase(0, end)).is_err() {
                return (loaded, repaired, resets + 1);
            }
        }
        if resets > 4 {
            // Each reset repairs one word; more than a save can have torn would be a loop.
            return (loaded, repaired, resets + 1);
        }
        resets += 1;
        flash = repaired.reboot();
    }
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
    fn with_ecc_poison_a_torn_word_reads_as_a_double_ecc_error_until_erased() {
        let mut f = SimFlash::with_ecc_poison(2);
        block_on(f.write(0, &[0x11; 8])).unwrap();
        f.cut_power_at(1);
        assert_eq!(
            block_on(f.write(8, &[0; 16])),
            Err(SimFlashError::PowerLost)
        );
        let mut f = f.reboot();
        let mut buf = [0u8; 8];
        block_on(f.read(0, &mut buf)).unwrap();
        assert_eq!(buf, [0x11; 8]);
        // The second double word tore; one byte of it is enough to raise the error.
        let mut one = [0u8; 1];
        assert_eq!(
            block_on(f.read(20, &mut one)),
            Err(SimFlashError::EccDouble(16))
        );
        assert_eq!(f.ecc_error(), Some(16));
        // A torn erase poisons the half of the page it did not reach.
        f.cut_power_at(0);
        assert!(block_on(f.erase(PAGE_BYTES as u32, 2 * PAGE_BYTES as u32)).is_err());
        let mut f = f.reboot();
        assert_eq!(f.poisoned_words(), 1 + PAGE_BYTES / WORD_BYTES / 2);
        block_on(f.erase(0, 2 * PAGE_BYTES as u32)).unwrap();
        assert_eq!(f.poisoned_words(), 0);
        block_on(f.read(16, &mut buf)).unwrap();
        assert_eq!(buf, [0xFF; 8]);
        // Without the mode a torn word reads as its half-programmed bytes.
        let mut plain = SimFlash::new(1);
        plain.cut_power_at(0);
        let _ = block_on(plain.write(0, &[0; 8]));
        let mut plain = plain.reboot();
        block_on(plain.read(0, &mut buf)).unwrap();
        assert_eq!(buf, [0, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF]);
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
