//! The calibration record in NOR flash, safe against a power cut at any step of a save.
//!
//! Built on `sequential-storage`'s map with one key ([`RECORD_KEY`]). Why the map and not
//! its queue: a save appends a new item and the newest complete item of the key wins, so a
//! save cut short leaves the old record the newest *complete* one (the crate checks each
//! item's header and data CRC and skips a torn item); pages are erased only once their
//! items are copied forward, so the old record is never destroyed before the new one is
//! whole. A queue would need the reader to pop the old record and trust the last one, two
//! operations where a cut in between loses the record.
//!
//! Our own CRC and version ([`super::record`]) sit inside the item: the storage crate's CRC
//! guards the flash, ours guards the meaning (a record of another layout is refused by
//! name, not misread).
//!
//! Runs in thread mode only (a save erases pages: tens of ms on the STM32G4, during which
//! flash reads stall); never from the control step.

use embedded_storage_async::nor_flash::NorFlash;
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage};

use super::record::{CalibrationRecord, CalibrationStatus, RecordError, RECORD_BYTES};

/// The map key of the calibration record.
pub const RECORD_KEY: u8 = 1;

/// Scratch the storage crate needs: key + record, rounded up to the flash word.
const BUFFER_BYTES: usize = RECORD_BYTES + 32;

/// Why no record was loaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum LoadError {
    /// No record stored (a new or erased board).
    Missing,
    /// A record is stored but refused.
    Invalid(RecordError),
    /// The flash could not be read, or the storage's own structure is damaged beyond its
    /// repair.
    Flash,
}

impl LoadError {
    /// The status a machine booting with this error has.
    pub const fn status(self) -> CalibrationStatus {
        match self {
            LoadError::Missing => CalibrationStatus::Missing,
            LoadError::Invalid(_) | LoadError::Flash => CalibrationStatus::Invalid,
        }
    }
}

pub use crate::ports::SaveError;

/// The calibration record's store over a range of NOR flash pages (at least two).
pub struct CalibrationStore<F: NorFlash> {
    map: MapStorage<u8, F, Cache<Uncached, Uncached, Uncached, u8>>,
    buffer: [u8; BUFFER_BYTES],
}

impl<F: NorFlash> CalibrationStore<F> {
    /// The store in `flash`'s bytes `range` (page aligned, at least two pages), or `None`
    /// when the range cannot hold it.
    pub fn new(flash: F, range: core::ops::Range<u32>) -> Option<Self> {
        let config = MapConfig::<F>::try_new(range).ok()?;
        Some(CalibrationStore {
            map: MapStorage::new(flash, config, Cache::new_uncached()),
            buffer: [0; BUFFER_BYTES],
        })
    }

    /// Reads the newest complete record.
    pub async fn load(&mut self) -> Result<CalibrationRecord, LoadError> {
        match self
            .map
            .fetch_item::<&[u8]>(&mut self.buffer, &RECORD_KEY)
            .await
        {
            Ok(None) => Err(LoadError::Missing),
            Ok(Some(bytes)) => CalibrationRecord::decode(bytes).map_err(LoadError::Invalid),
            Err(_) => Err(LoadError::Flash),
        }
    }

    /// Stores `record` as the newest; the old one stays readable until this one is whole.
    /// The save is read back: only a record that loads equal to `record` counts as saved
    /// (a flash driver may report a failed program as done).
    pub async fn save(&mut self, record: &CalibrationRecord) -> Result<(), SaveError> {
        let bytes = record.encode();
        self.map
            .store_item(&mut self.buffer, &RECORD_KEY, &bytes.as_slice())
            .await
            .map_err(|e| match e {
                sequential_storage::Error::Corrupted { .. } => SaveError::Corrupted,
                _ => SaveError::Flash,
            })?;
        match self.load().await {
            Ok(stored) if stored.encode() == bytes => Ok(()),
            _ => Err(SaveError::Verify),
        }
    }

    /// Gives the flash back (the simulator's "reboot" reads it again through a new store).
    pub fn into_flash(self) -> F {
        self.map.destroy().0
    }
}
