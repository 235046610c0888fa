//! The RTT link to the host: framing shared by both directions, and the codec of commands
//! (down-channel) and of their replies.
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
//!
//! # Commands (payload = tag ‖ fields, f32 little-endian)
//! | tag | command | fields |
//! |---|---|---|
//! | `0x10` | [`Command::Home`] | — |
//! | `0x11` | [`Command::MoveTo`] | `position_m: f32`, `peak_speed_mps: f32` |
//! | `0x12` | [`Command::Stop`] | — |
//! | `0x13` | [`Command::Heartbeat`] | — |
//! | `0x14` | [`Command::ClearFaults`] | — |
//! | `0x15` | [`Command::Start`] | `peak_speed_mps: f32` |
//! | `0x16` | [`Command::SetSpeed`] | `peak_speed_mps: f32` |
//! | `0x17` | [`Command::SetRotation`] | `rotation: u8` (0 compressor, 1 expander) |
//! | `0x18` | [`Command::SetVolumeRatio`] | `0` (follow measured) or `1` ‖ `pressure_ratio: f32` (fixed) |
//! | `0x19` | [`Command::Calibrate`] | `routine: u8` ([`crate::calibration::Routine`] as number) |
//! | `0x1A` | [`Command::SetParameter`] | `parameter: u8` ([`crate::command::Parameter`] as number), `value: f32` |
//!
//! Tags are part of the wire contract: never reuse or renumber. The codec checks only the
//! form; NaN, infinities and out-of-range values decode as sent, and the controller refuses
//! them with a [`Refusal`] (validation against limits is the controller's, one place).
//!
//! # Up-channel messages (payload = kind ‖ …)
//! | kind | message | rest |
//! |---|---|---|
//! | `0x01` | telemetry frame | see [`crate::telemetry`] |
//! | `0x02` | [`Reply`] | `result: u8` (0 accepted, else [`refusal_code`]) ‖ the command's payload |
//! | `0x03` | command frame rejected | `reason: u8` ([`FrameError`] as number) |

use crate::calibration::Routine;
use crate::command::{Command, Parameter, Refusal};
use crate::shared::Reply;
use crate::synchroniser::Rotation;
use crate::volume_ratio::RatioTarget;

/// The frame delimiter.
pub const DELIMITER: u8 = 0x00;

/// Message kind of a telemetry frame.
pub const KIND_TELEMETRY: u8 = 0x01;
/// Message kind of a reply to a command.
pub const KIND_REPLY: u8 = 0x02;
/// Message kind of a rejected (malformed) command frame.
pub const KIND_REJECTED: u8 = 0x03;

/// Command tags (first payload byte of a down-channel frame).
pub mod tag {
    /// [`crate::command::Command::Home`].
    pub const HOME: u8 = 0x10;
    /// [`crate::command::Command::MoveTo`].
    pub const MOVE_TO: u8 = 0x11;
    /// [`crate::command::Command::Stop`].
    pub const STOP: u8 = 0x12;
    /// [`crate::command::Command::Heartbeat`].
    pub const HEARTBEAT: u8 = 0x13;
    /// [`crate::command::Command::ClearFaults`].
    pub const CLEAR_FAULTS: u8 = 0x14;
    /// [`crate::command::Command::Start`].
    pub const START: u8 = 0x15;
    /// [`crate::command::Command::SetSpeed`].
    pub const SET_SPEED: u8 = 0x16;
    /// [`crate::command::Command::SetRotation`].
    pub const SET_ROTATION: u8 = 0x17;
    /// [`crate::command::Command::SetVolumeRatio`].
    pub const SET_VOLUME_RATIO: u8 = 0x18;
    /// [`crate::command::Command::Calibrate`].
    pub const CALIBRATE: u8 = 0x19;
    /// [`crate::command::Command::SetParameter`].
    pub const SET_PARAMETER: u8 = 0x1A;
}

/// Largest command payload (tag + two f32).
pub const MAX_COMMAND_PAYLOAD: usize = 9;
/// Largest encoded command frame, delimiter included.
pub const MAX_COMMAND_WIRE: usize = max_wire_len(MAX_COMMAND_PAYLOAD);
/// Largest encoded reply frame, delimiter included (kind, result, command payload).
pub const MAX_REPLY_WIRE: usize = max_wire_len(2 + MAX_COMMAND_PAYLOAD);

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
    raw: [u8; N],
    raw_len: usize,
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
            raw: [0; N],
            raw_len: 0,
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
            match self.raw.get_mut(self.raw_len) {
                Some(slot) => {
                    *slot = byte;
                    self.raw_len += 1;
                }
                None => self.overflowed = true,
            }
            return None;
        }
        let len = core::mem::take(&mut self.raw_len);
        if core::mem::take(&mut self.overflowed) {
            self.stats.rejected = self.stats.rejected.wrapping_add(1);
            return Some(Err(FrameError::Overlong));
        }
        if len == 0 {
            // Back-to-back delimiters: an idle line, not a frame.
            return None;
        }
        let result = self.check(len);
        match result {
            Ok(_) => self.stats.accepted = self.stats.accepted.wrapping_add(1),
            Err(_) => self.stats.rejected = self.stats.rejected.wrapping_add(1),
        }
        Some(result.map(|n| self.payload.get(..n).unwrap_or_default()))
    }

    /// Decodes the `len` raw bytes into the payload buffer; returns the payload length.
    fn check(&mut self, len: usize) -> Result<usize, FrameError> {
        let raw = self.raw.get(..len).ok_or(FrameError::Overlong)?;
        let n = cobs_decode(raw, &mut self.payload)?;
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

/// Appends bytes to a payload buffer; a write past the end is counted but not stored, so
/// the caller sees a length the buffer cannot hold and refuses it.
struct Writer<'a> {
    out: &'a mut [u8],
    len: usize,
}

impl Writer<'_> {
    fn byte(&mut self, b: u8) {
        if let Some(slot) = self.out.get_mut(self.len) {
            *slot = b;
        }
        self.len += 1;
    }

    fn f32(&mut self, v: f32) {
        for b in v.to_le_bytes() {
            self.byte(b);
        }
    }
}

/// Wire number of a rotation.
const fn rotation_code(rotation: Rotation) -> u8 {
    match rotation {
        Rotation::Compressor => 0,
        Rotation::Expander => 1,
    }
}

/// Writes a command's payload into `out`; returns its length.
fn command_payload(command: &Command, out: &mut [u8; MAX_COMMAND_PAYLOAD]) -> usize {
    let mut w = Writer { out, len: 0 };
    match *command {
        Command::Home => w.byte(tag::HOME),
        Command::MoveTo {
            position_m,
            peak_speed_mps,
        } => {
            w.byte(tag::MOVE_TO);
            w.f32(position_m);
            w.f32(peak_speed_mps);
        }
        Command::Start { peak_speed_mps } => {
            w.byte(tag::START);
            w.f32(peak_speed_mps);
        }
        Command::SetSpeed { peak_speed_mps } => {
            w.byte(tag::SET_SPEED);
            w.f32(peak_speed_mps);
        }
        Command::SetRotation { rotation } => {
            w.byte(tag::SET_ROTATION);
            w.byte(rotation_code(rotation));
        }
        Command::SetVolumeRatio { target } => {
            w.byte(tag::SET_VOLUME_RATIO);
            match target {
                RatioTarget::FollowMeasured => w.byte(0),
                RatioTarget::Fixed { pressure_ratio } => {
                    w.byte(1);
                    w.f32(pressure_ratio);
                }
            }
        }
        Command::Stop => w.byte(tag::STOP),
        Command::Heartbeat => w.byte(tag::HEARTBEAT),
        Command::ClearFaults => w.byte(tag::CLEAR_FAULTS),
        Command::Calibrate { routine } => {
            w.byte(tag::CALIBRATE);
            w.byte(routine as u8);
        }
        Command::SetParameter { parameter, value } => {
            w.byte(tag::SET_PARAMETER);
            w.byte(parameter as u8);
            w.f32(value);
        }
    }
    w.len
}

/// Encodes `command` as a complete down-channel frame into `out`; returns the bytes written
/// ([`MAX_COMMAND_WIRE`] always suffice).
pub fn encode_command(command: &Command, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    let mut payload = [0; MAX_COMMAND_PAYLOAD];
    let n = command_payload(command, &mut payload);
    encode_frame(payload.get(..n).ok_or(BufferTooSmall)?, out)
}

/// Decodes a command payload (as returned by [`Deframer::push`]).
pub fn decode_command(payload: &[u8]) -> Result<Command, FrameError> {
    let (&t, fields) = payload.split_first().ok_or(FrameError::TooShort)?;
    let bare = |c: Command| {
        if fields.is_empty() {
            Ok(c)
        } else {
            Err(FrameError::BadLength)
        }
    };
    match t {
        tag::HOME => bare(Command::Home),
        tag::STOP => bare(Command::Stop),
        tag::HEARTBEAT => bare(Command::Heartbeat),
        tag::CLEAR_FAULTS => bare(Command::ClearFaults),
        tag::MOVE_TO => {
            if fields.len() != 8 {
                return Err(FrameError::BadLength);
            }
            Ok(Command::MoveTo {
                position_m: f32_at(fields, 0)?,
                peak_speed_mps: f32_at(fields, 4)?,
            })
        }
        tag::START | tag::SET_SPEED => {
            if fields.len() != 4 {
                return Err(FrameError::BadLength);
            }
            let peak_speed_mps = f32_at(fields, 0)?;
            Ok(if t == tag::START {
                Command::Start { peak_speed_mps }
            } else {
                Command::SetSpeed { peak_speed_mps }
            })
        }
        tag::SET_ROTATION => match fields {
            [code] => [Rotation::Compressor, Rotation::Expander]
                .into_iter()
                .find(|r| rotation_code(*r) == *code)
                .map(|rotation| Command::SetRotation { rotation })
                .ok_or(FrameError::BadValue),
            _ => Err(FrameError::BadLength),
        },
        tag::SET_VOLUME_RATIO => match fields {
            [0] => Ok(Command::SetVolumeRatio {
                target: RatioTarget::FollowMeasured,
            }),
            [1, ratio @ ..] if ratio.len() == 4 => Ok(Command::SetVolumeRatio {
                target: RatioTarget::Fixed {
                    pressure_ratio: f32_at(ratio, 0)?,
                },
            }),
            [0 | 1, ..] | [] => Err(FrameError::BadLength),
            _ => Err(FrameError::BadValue),
        },
        tag::CALIBRATE => match fields {
            [code] => Routine::from_code(*code)
                .map(|routine| Command::Calibrate { routine })
                .ok_or(FrameError::BadValue),
            _ => Err(FrameError::BadLength),
        },
        tag::SET_PARAMETER => match fields {
            [code, value @ ..] if value.len() == 4 => Parameter::from_code(*code)
                .ok_or(FrameError::BadValue)
                .and_then(|parameter| {
                    Ok(Command::SetParameter {
                        parameter,
                        value: f32_at(value, 0)?,
                    })
                }),
            _ => Err(FrameError::BadLength),
        },
        _ => Err(FrameError::UnknownKind),
    }
}

/// Stable number of a refusal on the wire (0 is "accepted").
pub const fn refusal_code(refusal: Refusal) -> u8 {
    match refusal {
        Refusal::NotFinite => 1,
        Refusal::OutOfRange => 2,
        Refusal::NotHomed => 3,
        Refusal::FaultActive => 4,
        Refusal::Busy => 5,
        Refusal::CausePersists => 6,
        Refusal::CurrentSenseOffset => 7,
    }
}

/// The refusal with wire number `code`.
pub fn refusal_from_code(code: u8) -> Option<Refusal> {
    [
        Refusal::NotFinite,
        Refusal::OutOfRange,
        Refusal::NotHomed,
        Refusal::FaultActive,
        Refusal::Busy,
        Refusal::CausePersists,
        Refusal::CurrentSenseOffset,
    ]
    .into_iter()
    .find(|r| refusal_code(*r) == code)
}

/// Encodes `reply` as a complete up-channel frame into `out` ([`MAX_REPLY_WIRE`] suffice).
pub fn encode_reply(reply: &Reply, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    let mut payload = [0u8; 2 + MAX_COMMAND_PAYLOAD];
    let mut command = [0; MAX_COMMAND_PAYLOAD];
    let n = command_payload(&reply.command, &mut command);
    let [kind, result, rest @ ..] = &mut payload;
    *kind = KIND_REPLY;
    *result = match reply.result {
        Ok(()) => 0,
        Err(r) => refusal_code(r),
    };
    for (dst, src) in rest.iter_mut().zip(command.iter().take(n)) {
        *dst = *src;
    }
    encode_frame(payload.get(..2 + n).unwrap_or_default(), out)
}

/// Encodes the rejection of a malformed command frame as an up-channel frame.
pub fn encode_rejection(reason: FrameError, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    encode_frame(&[KIND_REJECTED, reason as u8], out)
}

/// An up-channel message other than telemetry: what the host reads back after a command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Answer {
    /// The controller's verdict on a command.
    Reply(Reply),
    /// A command frame the firmware could not decode, and why.
    Rejected(FrameError),
}

/// Decodes a reply or rejection payload (kinds `0x02`, `0x03`).
pub fn decode_answer(payload: &[u8]) -> Result<Answer, FrameError> {
    match payload {
        [KIND_REPLY, result, command @ ..] => {
            let result = match *result {
                0 => Ok(()),
                code => Err(refusal_from_code(code).ok_or(FrameError::BadValue)?),
            };
            Ok(Answer::Reply(Reply {
                command: decode_command(command)?,
                result,
            }))
        }
        [KIND_REJECTED, reason] => Ok(Answer::Rejected(
            FrameError::from_code(*reason).ok_or(FrameError::BadValue)?,
        )),
        [KIND_REPLY] | [KIND_REJECTED, ..] => Err(FrameError::BadLength),
        [] => Err(FrameError::TooShort),
        _ => Err(FrameError::UnknownKind),
    }
}

/// Streaming reader of the down-channel: bytes in, validated [`Command`]s out, every
/// malformed frame rejected and counted (its reason is what the firmware reports back).
#[derive(Clone, Debug, Default)]
pub struct CommandReader {
    deframer: Deframer<{ MAX_COMMAND_WIRE }>,
}

impl CommandReader {
    /// A reader waiting for the first frame.
    pub const fn new() -> Self {
        CommandReader {
            deframer: Deframer::new(),
        }
    }

    /// Feeds one byte; at the end of a frame returns the command or why it was rejected.
    pub fn push(&mut self, byte: u8) -> Option<Result<Command, FrameError>> {
        self.deframer.push_decoded(byte, decode_command)
    }

    /// Frames accepted and rejected so far.
    pub fn stats(&self) -> LinkStats {
        self.deframer.stats
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Seeded xorshift64*: the fuzz inputs are the same on every run and every machine.
    pub(crate) struct Rng(pub u64);
    impl Rng {
        pub fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        pub fn byte(&mut self) -> u8 {
            (self.next() >> 56) as u8
        }
        pub fn below(&mut self, n: usize) -> usize {
            (self.next() % n as u64) as usize
        }
    }

    fn feed(reader: &mut CommandReader, bytes: &[u8]) -> Vec<Result<Command, FrameError>> {
        bytes.iter().filter_map(|&b| reader.push(b)).collect()
    }

    fn wire(command: &Command) -> Vec<u8> {
        let mut out = [0u8; MAX_COMMAND_WIRE];
        let n = encode_command(command, &mut out).unwrap();
        out[..n].to_vec()
    }

    fn all_commands() -> Vec<Command> {
        vec![
            Command::Home,
            Command::MoveTo {
                position_m: 0.104,
                peak_speed_mps: 2.3,
            },
            Command::Start {
                peak_speed_mps: 2.3,
            },
            Command::SetSpeed {
                peak_speed_mps: 4.1,
            },
            Command::SetRotation {
                rotation: Rotation::Compressor,
            },
            Command::SetRotation {
                rotation: Rotation::Expander,
            },
            Command::SetVolumeRatio {
                target: RatioTarget::FollowMeasured,
            },
            Command::SetVolumeRatio {
                target: RatioTarget::Fixed {
                    pressure_ratio: 3.7,
                },
            },
            Command::Stop,
            Command::Heartbeat,
            Command::ClearFaults,
            Command::Calibrate {
                routine: Routine::CurrentSense,
            },
            Command::Calibrate {
                routine: Routine::Cogging,
            },
            Command::SetParameter {
                parameter: Parameter::PositionKp,
                value: 7.5e5,
            },
            Command::SetParameter {
                parameter: Parameter::DeadPointGain,
                value: 0.6,
            },
        ]
    }

    #[test]
    fn a_calibrate_command_names_a_known_routine() {
        for routine in Routine::ALL {
            assert_eq!(
                decode_command(&[tag::CALIBRATE, routine as u8]),
                Ok(Command::Calibrate { routine })
            );
        }
        assert_eq!(
            decode_command(&[tag::CALIBRATE, 4]),
            Err(FrameError::BadValue)
        );
        assert_eq!(
            decode_command(&[tag::CALIBRATE]),
            Err(FrameError::BadLength)
        );
        assert_eq!(
            refusal_from_code(refusal_code(Refusal::CurrentSenseOffset)),
            Some(Refusal::CurrentSenseOffset)
        );
    }

    #[test]
    fn crc_matches_the_published_check_value() {
        assert_eq!(crc16(b"123456789"), 0x29B1);
    }

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

    #[test]
    fn every_command_round_trips_exactly() {
        for c in all_commands() {
            let bytes = wire(&c);
            assert!(bytes.len() <= MAX_COMMAND_WIRE);
            assert_eq!(bytes.iter().filter(|&&b| b == 0).count(), 1);
            let mut r = CommandReader::new();
            assert_eq!(feed(&mut r, &bytes), vec![Ok(c)]);
        }
    }

    #[test]
    fn non_finite_setpoints_pass_the_codec_for_the_controller_to_refuse() {
        let c = Command::MoveTo {
            position_m: f32::NAN,
            peak_speed_mps: f32::INFINITY,
        };
        let mut r = CommandReader::new();
        match feed(&mut r, &wire(&c))[..] {
            [Ok(Command::MoveTo {
                position_m,
                peak_speed_mps,
            })] => {
                assert_eq!(position_m.to_bits(), f32::NAN.to_bits());
                assert_eq!(peak_speed_mps, f32::INFINITY);
            }
            ref other => panic!("{other:?}"),
        }
    }

    proptest! {
        #[test]
        fn move_to_round_trips_every_bit_pattern(p in any::<u32>(), v in any::<u32>()) {
            let c = Command::MoveTo {
                position_m: f32::from_bits(p),
                peak_speed_mps: f32::from_bits(v),
            };
            let mut r = CommandReader::new();
            let got = feed(&mut r, &wire(&c));
            match got[..] {
                [Ok(Command::MoveTo { position_m, peak_speed_mps })] => {
                    prop_assert_eq!(position_m.to_bits(), p);
                    prop_assert_eq!(peak_speed_mps.to_bits(), v);
                }
                _ => prop_assert!(false, "{:?}", got),
            }
        }

        #[test]
        fn replies_round_trip(ci in 0usize..64, res in 0u8..7, p in any::<u32>()) {
            let all = all_commands();
            let mut command = all[ci % all.len()];
            if let Command::MoveTo { position_m, .. } = &mut command {
                *position_m = f32::from_bits(p);
            }
            let result = match res { 0 => Ok(()), c => Err(refusal_from_code(c).unwrap()) };
            let reply = Reply { command, result };
            let mut out = [0u8; MAX_REPLY_WIRE];
            let n = encode_reply(&reply, &mut out).unwrap();
            let mut d = Deframer::<{ MAX_REPLY_WIRE }>::new();
            let answers: Vec<_> = out[..n].iter().filter_map(|&b| d.push(b).map(|r| r.map(decode_answer))).collect();
            prop_assert_eq!(answers.len(), 1);
            let got = answers[0].unwrap().unwrap();
            // Compare through the encoding so NaN payloads compare by bits.
            let Answer::Reply(back) = got else { panic!("{got:?}") };
            let mut again = [0u8; MAX_REPLY_WIRE];
            let m = encode_reply(&back, &mut again).unwrap();
            prop_assert_eq!(&out[..n], &again[..m]);
        }
    }

    #[test]
    fn rejections_round_trip() {
        for e in FrameError::ALL {
            let mut out = [0u8; 8];
            let n = encode_rejection(e, &mut out).unwrap();
            let mut d = Deframer::<8>::new();
            let got: Vec<_> = out[..n]
                .iter()
                .filter_map(|&b| d.push(b).map(|r| r.map(decode_answer)))
                .collect();
            assert_eq!(got, vec![Ok(Ok(Answer::Rejected(e)))]);
        }
    }

    #[test]
    fn truncated_and_corrupted_frames_are_rejected_and_counted() {
        let good = wire(&Command::MoveTo {
            position_m: 0.1,
            peak_speed_mps: 1.0,
        });
        let mut r = CommandReader::new();
        // Cut anywhere before the delimiter, then end the frame: rejected, never accepted.
        for cut in 1..good.len() - 1 {
            let mut bytes = good[..cut].to_vec();
            bytes.push(DELIMITER);
            let out = feed(&mut r, &bytes);
            assert_eq!(out.len(), 1);
            assert!(out[0].is_err(), "cut {cut}: {out:?}");
        }
        assert_eq!(r.stats().rejected as usize, good.len() - 2);
        assert_eq!(r.stats().accepted, 0);
        // Every single-bit flip is caught (CRC-16 detects all 1-bit errors).
        for i in 0..good.len() - 1 {
            for bit in 0..8 {
                let mut bytes = good.clone();
                bytes[i] ^= 1 << bit;
                let out = feed(&mut r, &bytes);
                assert!(
                    out.iter().all(Result::is_err),
                    "byte {i} bit {bit}: {out:?}"
                );
            }
        }
        // After all that, a good frame still decodes.
        assert_eq!(feed(&mut r, &good).len(), 1);
        assert_eq!(r.stats().accepted, 1);
    }

    #[test]
    fn wrong_lengths_unknown_tags_and_bad_values_are_rejected() {
        for payload in [
            &[tag::HOME, 1][..],
            &[tag::MOVE_TO, 0, 0, 0, 0][..],
            &[0x7F][..],
            &[KIND_TELEMETRY][..],
            &[tag::SET_ROTATION, 2][..],
            &[tag::SET_ROTATION][..],
            &[tag::SET_VOLUME_RATIO, 1, 0, 0][..],
            &[tag::SET_VOLUME_RATIO, 7][..],
        ] {
            let mut out = [0u8; 32];
            let n = encode_frame(payload, &mut out).unwrap();
            let mut r = CommandReader::new();
            let got = feed(&mut r, &out[..n]);
            assert!(
                matches!(
                    got[..],
                    [Err(FrameError::BadLength
                        | FrameError::UnknownKind
                        | FrameError::BadValue)]
                ),
                "{got:?}"
            );
            assert_eq!(
                r.stats(),
                LinkStats {
                    accepted: 0,
                    rejected: 1
                }
            );
        }
    }

    #[test]
    fn overlong_garbage_is_rejected_once_then_the_reader_resynchronises() {
        let mut r = CommandReader::new();
        let mut bytes = vec![0x55; 5 * MAX_COMMAND_WIRE];
        bytes.push(DELIMITER);
        bytes.extend(wire(&Command::Stop));
        assert_eq!(
            feed(&mut r, &bytes),
            vec![Err(FrameError::Overlong), Ok(Command::Stop)]
        );
    }

    /// ≥ 10⁶ seeded random inputs: random bytes, and valid frames mangled by truncation,
    /// bit flips, insertions and garbage bursts. The reader never panics, and a clean frame
    /// after any garbage decodes exactly. (A CRC-16 lets a random frame through with odds
    /// 2⁻¹⁶; the controller's own validation is the second line.)
    #[test]
    fn fuzzed_command_reader_never_panics_and_resynchronises() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let commands = all_commands();
        let mut r = CommandReader::new();
        let mut inputs = 0u32;
        while inputs < 1_000_000 {
            inputs += 1;
            let mut bytes = Vec::with_capacity(48);
            match rng.below(4) {
                0 => bytes.extend((0..rng.below(40)).map(|_| rng.byte())),
                _ => {
                    let c = commands[rng.below(commands.len())];
                    bytes = wire(&c);
                    match rng.below(4) {
                        0 => bytes.truncate(rng.below(bytes.len())),
                        1 => {
                            let i = rng.below(bytes.len());
                            bytes[i] ^= 1 << rng.below(8);
                        }
                        2 => {
                            let i = rng.below(bytes.len());
                            bytes.insert(i, rng.byte());
                        }
                        _ => bytes.extend((0..rng.below(8)).map(|_| rng.byte())),
                    }
                }
            }
            let _ = feed(&mut r, &bytes);
            if inputs.is_multiple_of(1000) {
                // Resynchronisation: a delimiter ends whatever garbage is pending, and the
                // next clean frame decodes exactly.
                let c = commands[rng.below(commands.len())];
                let mut clean = vec![DELIMITER];
                clean.extend(wire(&c));
                let got = feed(&mut r, &clean);
                assert_eq!(got.last(), Some(&Ok(c)), "input {inputs}");
            }
        }
        let s = r.stats();
        assert!(s.rejected > 100_000 && s.accepted > 50_000, "{s:?}");
    }
}
