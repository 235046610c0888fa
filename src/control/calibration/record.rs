//! The calibration record: everything the calibration routines measured, plus both
//! encoders' sin/cos correction, as one versioned, checksummed block of bytes that survives
//! a power cut in flash ([`super::store`]).
//!
//! Layout, version [`RECORD_VERSION`], little-endian, [`RECORD_BYTES`] long:
//!
//! | offset | bytes | field |
//! |---|---|---|
//! | 0 | 4 | magic `FPCC` |
//! | 4 | 2 | version |
//! | 6 | 1 | routines present, bit `r` = [`Routine`] number `r` |
//! | 7 | 1 | reserved, 0 |
//! | 8 | 24 | current-sense offsets, codes: master a, b, c, slave a, b, c (f32) |
//! | 32 | 8 | electrical-angle offsets from the alignment: master, slave (u32) |
//! | 40 | 16 | misalignment: slave angle offset (u32), correction (periods), `D_dif` (m), encoder offset (m) (f32) |
//! | 56 | 36 | cogging map: period (m), sin₁..₄, cos₁..₄ (N) (f32) |
//! | 92 | 40 | sin/cos correction, master then slave: sin offset, cos offset, sin amplitude, cos amplitude (codes), phase (rad) (f32) |
//! | 132 | 4 | CRC-32 (IEEE) of bytes 0..132 |
//!
//! A routine not present is stored as zeros. Any change of layout bumps the version: a
//! record of another version is refused ([`RecordError::Version`]) and the machine asks to
//! be calibrated again rather than guess.

use super::{Calibrated, Misalignment, Routine};
use crate::control::config::ControlConfig;
use crate::physics::cogging::{HarmonicMap, MAP_HARMONICS};
use crate::sensing::encoder::SinCosCalibration;
use crate::units::PerSection;

/// Version of the layout above.
pub const RECORD_VERSION: u16 = 1;

/// Length of an encoded record, bytes (a multiple of the 8-byte flash word).
pub const RECORD_BYTES: usize = 136;

const MAGIC: [u8; 4] = *b"FPCC";
const CRC_AT: usize = RECORD_BYTES - 4;

/// What survives a power cut: the routines' results and the sin/cos correction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationRecord {
    /// The routines' results (`last_error` is not stored: it is always `None` on load).
    pub calibrated: Calibrated,
    /// Each encoder's sin/cos correction.
    pub sin_cos: PerSection<SinCosCalibration>,
}

/// Whether the machine has a calibration it may run on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
#[repr(u8)]
pub enum CalibrationStatus {
    /// Every routine's result is loaded (or the configuration was given complete, as the
    /// simulator gives it): `Start` is accepted.
    Calibrated = 0,
    /// A record was loaded but some routine has never run (or the alignment was redone
    /// without the misalignment): run the missing routines, then `Start`.
    Incomplete = 1,
    /// No calibration in flash (a new or erased board): run every routine (current sense,
    /// alignment, home, misalignment, cogging); `Start` is refused until then.
    Missing = 2,
    /// The stored calibration is corrupt, unreadable or of another firmware's layout:
    /// calibrate again (the new record replaces it); `Start` is refused until then.
    Invalid = 3,
}

impl CalibrationStatus {
    /// Stable snake_case name (logs, JSON).
    pub const fn name(self) -> &'static str {
        match self {
            CalibrationStatus::Calibrated => "calibrated",
            CalibrationStatus::Incomplete => "calibration_incomplete",
            CalibrationStatus::Missing => "calibration_missing",
            CalibrationStatus::Invalid => "calibration_invalid",
        }
    }
}

/// Why a stored record was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum RecordError {
    /// Not [`RECORD_BYTES`] long.
    Length,
    /// Does not start with the magic: not a calibration record.
    Magic,
    /// Written by a firmware with another layout (the version found).
    Version(u16),
    /// The CRC does not match: the bytes were damaged.
    Checksum,
    /// A value is NaN or infinite.
    NotFinite,
}

impl CalibrationRecord {
    /// A record with every routine's result and both encoders' corrections set, to
    /// representative values none of which is a default: what the codecs of the record
    /// (its flash bytes, the link's transfer, the calibration file) are checked on.
    pub fn example() -> CalibrationRecord {
        let mut map = HarmonicMap::none();
        map.sin_n = [30.0, -1.5, 0.25, 0.0];
        map.cos_n = [4.0, 0.5, 0.0, -0.125];
        CalibrationRecord {
            calibrated: Calibrated {
                current_sense: Some(PerSection {
                    master: [16.3, -10.2, 6.1],
                    slave: [-12.3, 0.0, 18.4],
                }),
                alignment: Some(PerSection {
                    master: 12_345,
                    slave: 0xF000_0000,
                }),
                misalignment: Some(Misalignment {
                    slave_angle_offset: 0xF010_0000,
                    correction_periods: 0.004,
                    misalignment_m: 1.5e-3,
                    encoder_offset_m: -2e-6,
                }),
                cogging: Some(map),
                #[cfg(feature = "bench")]
                commission: None,
                last_error: None,
            },
            sin_cos: PerSection {
                master: SinCosCalibration::ideal(1500.0),
                slave: SinCosCalibration {
                    sin_offset: 3.0,
                    cos_offset: -2.0,
                    sin_amplitude: 1490.0,
                    cos_amplitude: 1510.0,
                    phase_rad: 0.01,
                },
            },
        }
    }

    /// The record of what `calibrated` holds and the sin/cos correction `config` uses.
    pub fn of(calibrated: &Calibrated, config: &ControlConfig) -> Self {
        CalibrationRecord {
            calibrated: Calibrated {
                #[cfg(feature = "bench")]
                commission: None,
                last_error: None,
                ..*calibrated
            },
            sin_cos: PerSection {
                master: config.encoder_master.calibration,
                slave: config.encoder_slave.calibration,
            },
        }
    }

    /// Whether every routine's result is present.
    pub fn is_complete(&self) -> bool {
        let c = &self.calibrated;
        c.current_sense.is_some()
            && c.alignment.is_some()
            && c.misalignment.is_some()
            && c.cogging.is_some()
    }

    /// The status a machine loaded with this record has.
    pub fn status(&self) -> CalibrationStatus {
        if self.is_complete() {
            CalibrationStatus::Calibrated
        } else {
            CalibrationStatus::Incomplete
        }
    }

    /// Loads the record into `config`.
    pub fn apply(&self, config: &mut ControlConfig) {
        self.calibrated.apply(config);
        config.encoder_master.calibration = self.sin_cos.master;
        config.encoder_slave.calibration = self.sin_cos.slave;
    }

    /// Encodes the record (layout in the module header).
    pub fn encode(&self) -> [u8; RECORD_BYTES] {
        let c = &self.calibrated;
        let mut w = Writer {
            out: [0; RECORD_BYTES],
            at: 0,
        };
        w.bytes(&MAGIC);
        w.bytes(&RECORD_VERSION.to_le_bytes());
        let present = [
            c.current_sense.is_some(),
            c.alignment.is_some(),
            c.misalignment.is_some(),
            c.cogging.is_some(),
        ];
        let bits = Routine::ALL
            .iter()
            .zip(present)
            .filter(|(_, p)| *p)
            .fold(0u8, |b, (r, _)| b | 1 << (*r as u8));
        w.bytes(&[bits, 0]);
        let sense = c.current_sense.unwrap_or_default();
        for v in sense.master.iter().chain(&sense.slave) {
            w.f32(*v);
        }
        let align = c.alignment.unwrap_or_default();
        w.u32(align.master);
        w.u32(align.slave);
        let m = c.misalignment.unwrap_or(Misalignment {
            slave_angle_offset: 0,
            correction_periods: 0.0,
            misalignment_m: 0.0,
            encoder_offset_m: 0.0,
        });
        w.u32(m.slave_angle_offset);
        w.f32(m.correction_periods);
        w.f32(m.misalignment_m);
        w.f32(m.encoder_offset_m);
        let map = c.cogging.unwrap_or_default();
        w.f32(map.period_m);
        for v in map.sin_n.iter().chain(&map.cos_n) {
            w.f32(*v);
        }
        for s in [self.sin_cos.master, self.sin_cos.slave] {
            for v in [
                s.sin_offset,
                s.cos_offset,
                s.sin_amplitude,
                s.cos_amplitude,
                s.phase_rad,
            ] {
                w.f32(v);
            }
        }
        let crc = crc32(w.out.get(..CRC_AT).unwrap_or_default());
        w.bytes(&crc.to_le_bytes());
        w.out
    }

    /// Decodes a record, checking its length, magic, version, CRC and that every value is
    /// finite.
    pub fn decode(bytes: &[u8]) -> Result<Self, RecordError> {
        if bytes.len() != RECORD_BYTES {
            return Err(RecordError::Length);
        }
        let mut r = Reader { bytes, at: 0 };
        if r.take::<4>() != MAGIC {
            return Err(RecordError::Magic);
        }
        let version = u16::from_le_bytes(r.take());
        if version != RECORD_VERSION {
            return Err(RecordError::Version(version));
        }
        let stored = bytes.get(CRC_AT..).and_then(|b| b.try_into().ok());
        if stored.map(u32::from_le_bytes) != Some(crc32(bytes.get(..CRC_AT).unwrap_or_default())) {
            return Err(RecordError::Checksum);
        }
        let [bits, _] = r.take::<2>();
        let has = |routine: Routine| bits & (1 << (routine as u8)) != 0;
        let mut sense = PerSection::<[f32; 3]>::default();
        for v in sense.master.iter_mut().chain(sense.slave.iter_mut()) {
            *v = r.f32()?;
        }
        let align = PerSection {
            master: r.u32(),
            slave: r.u32(),
        };
        let mis = Misalignment {
            slave_angle_offset: r.u32(),
            correction_periods: r.f32()?,
            misalignment_m: r.f32()?,
            encoder_offset_m: r.f32()?,
        };
        let mut map = HarmonicMap {
            period_m: r.f32()?,
            sin_n: [0.0; MAP_HARMONICS],
            cos_n: [0.0; MAP_HARMONICS],
        };
        for v in map.sin_n.iter_mut().chain(map.cos_n.iter_mut()) {
            *v = r.f32()?;
        }
        let mut sin_cos = [SinCosCalibration::ideal(0.0); 2];
        for s in &mut sin_cos {
            *s = SinCosCalibration {
                sin_offset: r.f32()?,
                cos_offset: r.f32()?,
                sin_amplitude: r.f32()?,
                cos_amplitude: r.f32()?,
                phase_rad: r.f32()?,
            };
        }
        let [master, slave] = sin_cos;
        Ok(CalibrationRecord {
            calibrated: Calibrated {
                current_sense: has(Routine::CurrentSense).then_some(sense),
                alignment: has(Routine::Alignment).then_some(align),
                misalignment: has(Routine::Misalignment).then_some(mis),
                cogging: has(Routine::Cogging).then_some(map),
                #[cfg(feature = "bench")]
                commission: None,
                last_error: None,
            },
            sin_cos: PerSection { master, slave },
        })
    }
}

struct Writer {
    out: [u8; RECORD_BYTES],
    at: usize,
}

impl Writer {
    #[inline(never)]
    fn bytes(&mut self, b: &[u8]) {
        let end = self.at + b.len();
        if let Some(dst) = self.out.get_mut(self.at..end) {
            dst.copy_from_slice(b);
        }
        self.at = end;
    }

    // Not inlined here and below: one copy instead of one per field (≈ 1 KiB of flash); a
    // record is encoded and decoded once per save or load, never in the control step.
    #[inline(never)]
    fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }

    fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    /// The next `N` bytes (zeros past the end: the length was checked before reading).
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let end = self.at + N;
        let out = self
            .bytes
            .get(self.at..end)
            .and_then(|b| b.try_into().ok())
            .unwrap_or([0; N]);
        self.at = end;
        out
    }

    #[inline(never)]
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }

    #[inline(never)]
    fn f32(&mut self) -> Result<f32, RecordError> {
        let v = f32::from_bits(self.u32());
        if v.is_finite() {
            Ok(v)
        } else {
            Err(RecordError::NotFinite)
        }
    }
}

/// CRC-32 (IEEE 802.3: reflected polynomial 0xEDB88320, init and final xor 0xFFFFFFFF);
/// check value `crc32(b"123456789") == 0xCBF43926`. Bitwise: it runs once per load or save,
/// never in the control step, so a 1 KiB table is not worth its flash.
#[inline(never)]
pub fn crc32(data: &[u8]) -> u32 {
    !data.iter().fold(!0u32, |crc, &b| {
        (0..8).fold(crc ^ u32::from(b), |c, _| {
            (c >> 1) ^ (0xEDB8_8320 & (c & 1).wrapping_neg())
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_the_published_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn a_record_round_trips_bit_for_bit() {
        let r = CalibrationRecord::example();
        assert!(r.is_complete());
        assert_eq!(CalibrationRecord::decode(&r.encode()), Ok(r));
        let mut partial = r;
        partial.calibrated.misalignment = None;
        partial.calibrated.cogging = None;
        let back = CalibrationRecord::decode(&partial.encode()).unwrap();
        assert_eq!(back, partial);
        assert_eq!(back.status(), CalibrationStatus::Incomplete);
    }

    #[test]
    fn damaged_or_foreign_records_are_refused_by_name() {
        let bytes = CalibrationRecord::example().encode();
        for i in 0..RECORD_BYTES {
            for bit in 0..8 {
                let mut b = bytes;
                b[i] ^= 1 << bit;
                assert!(CalibrationRecord::decode(&b).is_err(), "byte {i} bit {bit}");
            }
        }
        let mut v2 = bytes;
        v2[4] = 2;
        assert_eq!(CalibrationRecord::decode(&v2), Err(RecordError::Version(2)));
        assert_eq!(
            CalibrationRecord::decode(&bytes[..100]),
            Err(RecordError::Length)
        );
        let mut nan = CalibrationRecord::example();
        nan.sin_cos.slave.phase_rad = f32::NAN;
        assert_eq!(
            CalibrationRecord::decode(&nan.encode()),
            Err(RecordError::NotFinite)
        );
    }

    #[test]
    fn a_loaded_record_sets_every_calibrated_field() {
        let r = CalibrationRecord::example();
        let mut config = ControlConfig::reference();
        r.apply(&mut config);
        assert_eq!(config.angle_offset.master, 12_345);
        assert_eq!(config.angle_offset.slave, 0xF010_0000);
        assert_eq!(config.current_sense.slave.offset_codes, [-12.3, 0.0, 18.4]);
        assert_eq!(config.allocation.cogging, r.calibrated.cogging.unwrap());
        assert_eq!(config.encoder_slave.calibration, r.sin_cos.slave);
        assert_eq!(CalibrationRecord::of(&r.calibrated, &config), r);
    }

    #[test]
    fn a_record_with_any_byte_corrupted_or_missing_is_refused() {
        let record = CalibrationRecord::example();
        let bytes = record.encode();
        assert_eq!(CalibrationRecord::decode(&bytes), Ok(record));
        for i in 0..RECORD_BYTES {
            let mut bad = bytes;
            bad[i] ^= 0x10;
            assert!(CalibrationRecord::decode(&bad).is_err(), "byte {i}");
        }
        assert!(CalibrationRecord::decode(&[0xA5; RECORD_BYTES]).is_err());
        assert!(CalibrationRecord::decode(&bytes[..RECORD_BYTES - 1]).is_err());
        assert!(CalibrationRecord::decode(&[]).is_err());
    }
}
