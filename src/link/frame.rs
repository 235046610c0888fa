//! The RTT link's framing, shared by both directions and by every payload: COBS, CRC-16,
//! the message kinds, and a deframer that counts what it rejects. It knows no payload.
//!
//! # Framing (both directions)
//! A message is a *payload* (first byte: the message kind or command tag), followed by a
//! CRC-16/CCITT-FALSE of the payload (little-endian), the whole COBS-encoded so that it
//! contains no `0x00`, then one `0x00` delimiter:
//!
//! ```text
//! wire = COBS(payload ‖ crc16(payload) as LE) ‖ 0x00
//! ```
//!
//! COBS costs one byte per 254 (one byte for every message here). A receiver that starts
//! mid-stream, or sees garbage, loses at most the message in progress: the next `0x00`
//! ends it and the one after decodes cleanly. Every frame that fails (too long, bad COBS,
//! too short, bad CRC, unknown kind, wrong length) is rejected and counted, never half-used.

/// The frame delimiter.
pub const DELIMITER: u8 = 0x00;

/// Message kind of a telemetry frame.
pub const KIND_TELEMETRY: u8 = 0x01;
/// Message kind of a reply to a command.
pub const KIND_REPLY: u8 = 0x02;
/// Message kind of a rejected (malformed) command frame.
pub const KIND_REJECTED: u8 = 0x03;
/// Message kind of an answer to a calibration transfer.
pub const KIND_CALIBRATION: u8 = 0x04;

/// Why a frame was rejected. The number is sent back in a `0x03` message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
#[repr(u8)]
pub enum FrameError {
    /// No delimiter within the receiver's buffer: garbage or a lost delimiter.
    Overlong = 1,
    /// The COBS encoding is broken (a code byte points past the end).
    Cobs = 2,
    /// Too short to hold a kind byte and the CRC.
    TooShort = 3,
    /// The CRC does not match: corrupted or truncated.
    Crc = 4,
    /// Unknown message kind or command tag.
    UnknownKind = 5,
    /// The payload length does not fit the kind.
    BadLength = 6,
    /// A field holds a value with no meaning (e.g. an unknown mode or refusal code).
    BadValue = 7,
}

impl FrameError {
    /// Every variant, in number order.
    pub const ALL: [FrameError; 7] = [
        FrameError::Overlong,
        FrameError::Cobs,
        FrameError::TooShort,
        FrameError::Crc,
        FrameError::UnknownKind,
        FrameError::BadLength,
        FrameError::BadValue,
    ];

    /// The variant with number `code`.
    pub fn from_code(code: u8) -> Option<FrameError> {
        FrameError::ALL.iter().copied().find(|e| *e as u8 == code)
    }
}

/// The output buffer is too small for the frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct BufferTooSmall;

/// Wire length of a payload of `payload_len` bytes in the worst case: CRC, COBS overhead
/// (one code byte per 254 bytes, plus one), delimiter.
pub const fn max_wire_len(payload_len: usize) -> usize {
    let body = payload_len + 2;
    body + body / 254 + 1 + 1
}

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor); check value
/// of `"123456789"` is `0x29B1`.
pub fn crc16(data: &[u8]) -> u16 {
    data.iter().fold(0xFFFF, |crc, &b| crc16_update(crc, b))
}

/// Table-driven: 512 bytes of flash, one lookup per byte (the telemetry task frames up to
/// 20 000 messages a second).
const CRC_TABLE: [u16; 256] = crc_table();

// Evaluated at compile time only: an index out of range is a build error, not a panic.
#[allow(clippy::indexing_slicing)]
const fn crc_table() -> [u16; 256] {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
}

#[inline]
fn crc16_update(crc: u16, byte: u8) -> u16 {
    let index = ((crc >> 8) as u8 ^ byte) as usize;
    // The index is a u8, the table has 256 entries: the lookup cannot miss.
    let entry = CRC_TABLE.get(index).copied().unwrap_or(0);
    (crc << 8) ^ entry
}

/// Frames `payload` into `out`: payload, CRC, COBS, delimiter. Returns the bytes written.
/// Not inlined: each answer kind's encoder calls this one copy (flash, not speed, is short).
#[inline(never)]
pub fn encode_frame(payload: &[u8], out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    let crc = crc16(payload).to_le_bytes();
    let body = payload.iter().copied().chain(crc);
    let n = cobs_encode(body, out)?;
    *out.get_mut(n).ok_or(BufferTooSmall)? = DELIMITER;
    Ok(n + 1)
}

/// COBS-encodes `data` into `out` (no delimiter); returns the length.
fn cobs_encode(data: impl Iterator<Item = u8>, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    // `code_at` is where the current block's code byte goes; it is written once the block
    // ends (at a zero, after 254 data bytes, or at the end).
    let mut code_at = 0;
    let mut write = 1;
    let mut code: u8 = 1;
    for byte in data {
        if byte == 0 {
            *out.get_mut(code_at).ok_or(BufferTooSmall)? = code;
            code_at = write;
            write += 1;
            code = 1;
        } else {
            *out.get_mut(write).ok_or(BufferTooSmall)? = byte;
            write += 1;
            code += 1;
            if code == 0xFF {
                *out.get_mut(code_at).ok_or(BufferTooSmall)? = code;
                code_at = write;
                write += 1;
                code = 1;
            }
        }
    }
    *out.get_mut(code_at).ok_or(BufferTooSmall)? = code;
    Ok(write)
}

/// COBS-decodes `src` (no delimiter) into `dst`; returns the length.
fn cobs_decode(src: &[u8], dst: &mut [u8]) -> Result<usize, FrameError> {
    let mut read = 0;
    let mut write = 0;
    while let Some(&code) = src.get(read) {
        if code == 0 {
            return Err(FrameError::Cobs);
        }
        read += 1;
        let n = usize::from(code) - 1;
        let block = src.get(read..read + n).ok_or(FrameError::Cobs)?;
        dst.get_mut(write..write + n)
            .ok_or(FrameError::Overlong)?
            .copy_from_slice(block);
        read += n;
        write += n;
        // A block shorter than 254 stands for its data and one zero, except the last.
        if code != 0xFF && read < src.len() {
            *dst.get_mut(write).ok_or(FrameError::Overlong)? = 0;
            write += 1;
        }
    }
    Ok(write)
}

/// Counts of a receiver: frames accepted and rejected.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct LinkStats {
    /// Frames that passed framing and CRC (and, in the typed readers, the payload checks).
    pub accepted: u32,
    /// Frames rejected for any [`FrameError`].
    pub rejected: u32,
}

/// Streaming receiver of frames: feed it bytes as they arrive, it returns each payload whose
/// framing and CRC are intact. `N` bounds the encoded frame (without delimiter); a longer run
/// without delimiter is rejected once, then skipped up to the next delimiter.
#[derive(Clone, Debug)]
pub struct Deframer<const N: usize> {
    /// The encoded bytes since the last delimiter (a bounded buffer: a push past `N` fails
    /// and marks the frame overlong).
    raw: heapless::Vec<u8, N>,
    overflowed: bool,
    payload: [u8; N],
    /// Frames accepted and rejected so far.
    pub stats: LinkStats,
}

impl<const N: usize> Default for Deframer<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Deframer<N> {
    /// An empty receiver, waiting for the first frame.
    pub const fn new() -> Self {
        Deframer {
            raw: heapless::Vec::new(),
            overflowed: false,
            payload: [0; N],
            stats: LinkStats {
                accepted: 0,
                rejected: 0,
            },
        }
    }

    /// Feeds one byte. At a delimiter that ends a non-empty frame, returns the frame's
    /// payload (CRC stripped) or why it was rejected; otherwise `None`.
    pub fn push(&mut self, byte: u8) -> Option<Result<&[u8], FrameError>> {
        if byte != DELIMITER {
            if self.raw.push(byte).is_err() {
                self.overflowed = true;
            }
            return None;
        }
        if core::mem::take(&mut self.overflowed) {
            self.raw.clear();
            self.stats.rejected = self.stats.rejected.wrapping_add(1);
            return Some(Err(FrameError::Overlong));
        }
        if self.raw.is_empty() {
            // Back-to-back delimiters: an idle line, not a frame.
            return None;
        }
        let result = self.check();
        self.raw.clear();
        match result {
            Ok(_) => self.stats.accepted = self.stats.accepted.wrapping_add(1),
            Err(_) => self.stats.rejected = self.stats.rejected.wrapping_add(1),
        }
        Some(result.map(|n| self.payload.get(..n).unwrap_or_default()))
    }

    /// Decodes the raw bytes into the payload buffer; returns the payload length.
    fn check(&mut self) -> Result<usize, FrameError> {
        let n = cobs_decode(&self.raw, &mut self.payload)?;
        if n < 3 {
            return Err(FrameError::TooShort);
        }
        let body = n - 2;
        let crc = match self.payload.get(body..n) {
            Some(&[lo, hi]) => u16::from_le_bytes([lo, hi]),
            _ => return Err(FrameError::TooShort),
        };
        let payload = self.payload.get(..body).ok_or(FrameError::TooShort)?;
        if crc16(payload) != crc {
            return Err(FrameError::Crc);
        }
        Ok(body)
    }

    /// As [`Deframer::push`], with the payload decoded by `decode` (the typed readers): a
    /// frame that passed framing but whose payload `decode` refuses counts as rejected.
    pub fn push_decoded<T>(
        &mut self,
        byte: u8,
        decode: impl FnOnce(&[u8]) -> Result<T, FrameError>,
    ) -> Option<Result<T, FrameError>> {
        let decoded = match self.push(byte)? {
            Ok(payload) => decode(payload),
            Err(e) => return Some(Err(e)),
        };
        if decoded.is_err() {
            self.stats.accepted = self.stats.accepted.wrapping_sub(1);
            self.stats.rejected = self.stats.rejected.wrapping_add(1);
        }
        Some(decoded)
    }
}

/// Little-endian f32 at `at` in `p`.
pub(crate) fn f32_at(p: &[u8], at: usize) -> Result<f32, FrameError> {
    match p.get(at..at + 4) {
        Some(&[a, b, c, d]) => Ok(f32::from_le_bytes([a, b, c, d])),
        _ => Err(FrameError::BadLength),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cobs_round_trips_zeros_and_long_runs() {
        let cases: Vec<Vec<u8>> = vec![
            vec![],
            vec![0],
            vec![0, 0],
            vec![1, 0, 2],
            (1..=254).collect(),
            (1..=255).collect(),
            (0..600).map(|i| (i % 7) as u8).collect(),
        ];
        for data in cases {
            let mut enc = [0u8; 700];
            let n = cobs_encode(data.iter().copied(), &mut enc).unwrap();
            assert!(!enc[..n].contains(&0), "{data:?}");
            let mut dec = [0u8; 700];
            let m = cobs_decode(&enc[..n], &mut dec).unwrap();
            assert_eq!(&dec[..m], &data[..]);
        }
    }
}
