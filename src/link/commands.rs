//! The codec of commands (down-channel) and of their replies, framed by [`super::frame`].
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
//! | `0x19` | [`Command::Calibrate`] | `routine: u8` ([`crate::control::calibration::Routine`] as number) |
//! | `0x1A` | [`Command::SetParameter`] | `parameter: u8` ([`crate::control::command::Parameter`] as number), `value: f32` |
//! | `0x1B` | [`Transfer::Read`] | `offset: u8` |
//! | `0x1C` | [`Transfer::Write`] | `offset: u8` ‖ 1..=[`CHUNK_BYTES`] record bytes |
//! | `0x1D` | [`Transfer::Commit`] | `crc: u32` (the record's own CRC-32, its last 4 bytes) |
//! | `0x1E`..`0x22` | [`LinkRequest`] | see [`crate::link::settings`] |
//! | `0x24` | `Command::Bench` (the bench build's; the release firmware rejects the tag as unknown) | `0` ‖ `section: u8` ‖ `phase: u8` ‖ `duty: f32` (a fixed duty), or `1` ‖ `torque_nm: f32` (a servo torque); then `seconds: f32` |
//!
//! The calibration transfer (`0x1B`..`0x1D`) is the command task's, not the controller's:
//! the record ([`crate::control::calibration::record`], [`RECORD_BYTES`] bytes) moves in
//! chunks of up to [`CHUNK_BYTES`] at a byte offset. A read answers the bytes of the record
//! the controller runs on ([`Refusal::Busy`] before the control task has published it,
//! [`Refusal::OutOfRange`] past the end). Writes fill a staging buffer strictly in order (offset 0 starts
//! over; any other offset must be where the previous chunk ended, else
//! [`Refusal::ChunkOutOfOrder`] and the staging is unchanged); the commit is accepted only
//! when all [`RECORD_BYTES`] are staged, the record decodes (magic, version, CRC) and its CRC
//! is the one sent ([`Refusal::BadRecord`] otherwise), and the controller is idle
//! ([`Refusal::Busy`]). Then the controller loads it as a boot load does and the storage
//! task saves it in flash. A refused commit changes nothing.
//!
//! Tags are part of the wire contract: never reuse or renumber. The codec checks only the
//! form; NaN, infinities and out-of-range values decode as sent, and the controller refuses
//! them with a [`Refusal`] (validation against limits is the controller's, one place).
//!
//! # Up-channel messages (payload = kind ‖ …)
//! | kind | message | rest |
//! |---|---|---|
//! | `0x01` | telemetry frame | see [`crate::link::telemetry`] |
//! | `0x02` | [`Reply`] | `result: u8` (0 accepted, else [`refusal_code`]) ‖ the command's payload |
//! | `0x03` | command frame rejected | `reason: u8` ([`FrameError`] as number) |
//! | `0x04` | [`TransferReply`] | `0` ‖ `0x1B` ‖ `offset: u8` ‖ the bytes (an accepted read), else `result: u8` ‖ the request's tag ‖ `offset` or `crc` (a link request: its `arg`) as u32 |
//! | `0x06`, `0x07` | scope recording | see [`crate::link::scope`] |
//! | `0x08` | the last routine's report | see [`crate::link::report`] |

use crate::control::calibration::record::RECORD_BYTES;
use crate::control::calibration::Routine;
#[cfg(feature = "bench")]
use crate::control::command::BenchOp;
use crate::control::command::Reply;
use crate::control::command::{Command, Parameter, Refusal};
use crate::motion::synchroniser::Rotation;
use crate::motion::volume_ratio::RatioTarget;

use super::frame::*;
use super::settings::{decode_link_request, is_link_tag, LinkRequest};
use super::tag::{self, TransferId};

/// Largest chunk of the calibration record in one frame, bytes: 9 frames carry the
/// [`RECORD_BYTES`] (the frame limit was raised for it, not a second framing).
pub const CHUNK_BYTES: usize = 16;

/// Largest command payload (a calibration write: tag, offset, one chunk).
pub const MAX_COMMAND_PAYLOAD: usize = 2 + CHUNK_BYTES;
/// Largest encoded command frame, delimiter included.
pub const MAX_COMMAND_WIRE: usize = max_wire_len(MAX_COMMAND_PAYLOAD);
/// Largest encoded reply frame, delimiter included (kind, result, command payload; a
/// calibration chunk is no longer).
pub const MAX_REPLY_WIRE: usize = max_wire_len(2 + MAX_COMMAND_PAYLOAD);

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
        #[cfg(feature = "bench")]
        Command::Bench { op, seconds } => {
            w.byte(tag::BENCH);
            match op {
                BenchOp::FixedDuty {
                    section,
                    phase,
                    duty,
                } => {
                    w.byte(0);
                    w.byte(section as u8);
                    w.byte(phase);
                    w.f32(duty);
                }
                BenchOp::ServoTorque { torque_nm } => {
                    w.byte(1);
                    w.f32(torque_nm);
                }
            }
            w.f32(seconds);
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
        #[cfg(feature = "bench")]
        tag::BENCH => decode_bench(fields),
        _ => Err(FrameError::UnknownKind),
    }
}

/// A bench command's fields: `0 ‖ section: u8 ‖ phase: u8 ‖ duty: f32` or
/// `1 ‖ torque_nm: f32`, then `seconds: f32`.
#[cfg(feature = "bench")]
fn decode_bench(fields: &[u8]) -> Result<Command, FrameError> {
    use crate::units::Section;
    let (op, seconds) = match fields {
        [0, section, phase, rest @ ..] if rest.len() == 8 => {
            let section = *Section::ALL
                .get(usize::from(*section))
                .ok_or(FrameError::BadValue)?;
            let op = BenchOp::FixedDuty {
                section,
                phase: *phase,
                duty: f32_at(rest, 0)?,
            };
            (op, f32_at(rest, 4)?)
        }
        [1, rest @ ..] if rest.len() == 8 => {
            let op = BenchOp::ServoTorque {
                torque_nm: f32_at(rest, 0)?,
            };
            (op, f32_at(rest, 4)?)
        }
        [0 | 1, ..] | [] => return Err(FrameError::BadLength),
        _ => return Err(FrameError::BadValue),
    };
    Ok(Command::Bench { op, seconds })
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
        Refusal::NotCalibrated => 8,
        Refusal::ChunkOutOfOrder => 9,
        Refusal::BadRecord => 10,
        Refusal::NotArmed => 11,
        Refusal::SupplyAbsent => 12,
        Refusal::EncodersAbsent => 13,
        Refusal::PressuresAbsent => 14,
        Refusal::BenchBuildOnly => 15,
        #[cfg(feature = "bench")]
        Refusal::SupplyUp => 16,
    }
}

/// The refusal with wire number `code`.
pub fn refusal_from_code(code: u8) -> Option<Refusal> {
    #[cfg(feature = "bench")]
    if code == refusal_code(Refusal::SupplyUp) {
        return Some(Refusal::SupplyUp);
    }
    [
        Refusal::NotFinite,
        Refusal::OutOfRange,
        Refusal::NotHomed,
        Refusal::FaultActive,
        Refusal::Busy,
        Refusal::CausePersists,
        Refusal::CurrentSenseOffset,
        Refusal::NotCalibrated,
        Refusal::ChunkOutOfOrder,
        Refusal::BadRecord,
        Refusal::NotArmed,
        Refusal::SupplyAbsent,
        Refusal::EncodersAbsent,
        Refusal::PressuresAbsent,
        Refusal::BenchBuildOnly,
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
    /// The command task's answer to a calibration transfer.
    Calibration(TransferReply),
    /// The last calibration routine's report ([`super::report`]).
    Report(super::report::ReportAnswer),
}

/// Decodes an answer payload (kinds `0x02`, `0x03`, `0x04`, `0x08`).
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
        [KIND_CALIBRATION, rest @ ..] => decode_transfer_reply(rest).map(Answer::Calibration),
        [super::report::KIND_ROUTINE_REPORT, ..] => super::report::decode_report(payload)
            .unwrap_or(Err(FrameError::UnknownKind))
            .map(Answer::Report),
        [KIND_REPLY] | [KIND_REJECTED, ..] => Err(FrameError::BadLength),
        [] => Err(FrameError::TooShort),
        _ => Err(FrameError::UnknownKind),
    }
}

/// A chunk of the calibration record: up to [`CHUNK_BYTES`] bytes at `offset`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Chunk {
    /// Byte offset in the record.
    pub offset: u8,
    len: u8,
    bytes: [u8; CHUNK_BYTES],
}

impl Chunk {
    /// The chunk of `data` at `offset`, or `None` if `data` is empty or longer than
    /// [`CHUNK_BYTES`] (the range in the record is the receiver's to check).
    pub fn new(offset: u8, data: &[u8]) -> Option<Chunk> {
        if data.is_empty() || data.len() > CHUNK_BYTES {
            return None;
        }
        let mut bytes = [0; CHUNK_BYTES];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Chunk {
            offset,
            len: data.len() as u8,
            bytes,
        })
    }

    /// The chunk of `record` at `offset` (as many bytes as remain, at most [`CHUNK_BYTES`]);
    /// `None` past the end.
    pub fn of_record(record: &[u8; RECORD_BYTES], offset: u8) -> Option<Chunk> {
        let at = usize::from(offset);
        let end = (at + CHUNK_BYTES).min(RECORD_BYTES);
        Chunk::new(offset, record.get(at..end)?)
    }

    /// The bytes.
    pub fn data(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or_default()
    }
}

/// A calibration transfer request (the command task answers it; see the module table).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transfer {
    /// Read the chunk at this offset of the record the controller runs on.
    Read {
        /// Byte offset.
        offset: u8,
    },
    /// Stage a chunk of a new record.
    Write(Chunk),
    /// Check the staged record and load it; `crc` is its CRC-32 (its last four bytes).
    Commit {
        /// The record's CRC-32.
        crc: u32,
    },
}

/// A decoded down-channel frame: a controller command, a calibration transfer or a link
/// request.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Request {
    /// For the controller.
    Command(Command),
    /// For the command task's calibration transfer.
    Calibration(Transfer),
    /// For the command task: telemetry, ports, scope.
    Link(LinkRequest),
}

impl Transfer {
    /// What a verdict on this request names.
    pub fn id(&self) -> TransferId {
        match *self {
            Transfer::Read { offset } => TransferId {
                tag: tag::CALIBRATION_READ,
                arg: offset.into(),
            },
            Transfer::Write(chunk) => TransferId {
                tag: tag::CALIBRATION_WRITE,
                arg: chunk.offset.into(),
            },
            Transfer::Commit { crc } => TransferId {
                tag: tag::CALIBRATION_COMMIT,
                arg: crc,
            },
        }
    }
}

/// The command task's answer to a [`Transfer`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransferReply {
    /// An accepted read: the chunk asked for (`0x04 ‖ 0 ‖ 0x1B ‖ offset ‖ bytes`).
    Chunk(Chunk),
    /// The verdict on a write or a commit, or a refused read (`0x04 ‖ result ‖ tag ‖ arg`,
    /// arg u32 LE).
    Verdict {
        /// The request answered.
        transfer: TransferId,
        /// Accepted, or refused with the reason.
        result: Result<(), Refusal>,
    },
}

fn transfer_payload(transfer: &Transfer, w: &mut Writer) {
    match transfer {
        Transfer::Read { offset } => {
            w.byte(tag::CALIBRATION_READ);
            w.byte(*offset);
        }
        Transfer::Write(chunk) => {
            w.byte(tag::CALIBRATION_WRITE);
            w.byte(chunk.offset);
            for &b in chunk.data() {
                w.byte(b);
            }
        }
        Transfer::Commit { crc } => {
            w.byte(tag::CALIBRATION_COMMIT);
            for b in crc.to_le_bytes() {
                w.byte(b);
            }
        }
    }
}

/// Encodes a calibration transfer as a complete down-channel frame into `out`
/// ([`MAX_COMMAND_WIRE`] always suffice).
pub fn encode_transfer(transfer: &Transfer, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    let mut payload = [0; MAX_COMMAND_PAYLOAD];
    let mut w = Writer {
        out: &mut payload,
        len: 0,
    };
    transfer_payload(transfer, &mut w);
    let n = w.len;
    encode_frame(payload.get(..n).ok_or(BufferTooSmall)?, out)
}

/// Decodes a calibration transfer payload (tag ‖ fields); `None` if the tag is not one.
fn decode_transfer(payload: &[u8]) -> Option<Result<Transfer, FrameError>> {
    let (&t, fields) = payload.split_first()?;
    Some(match t {
        tag::CALIBRATION_READ => match fields {
            [offset] => Ok(Transfer::Read { offset: *offset }),
            _ => Err(FrameError::BadLength),
        },
        tag::CALIBRATION_WRITE => match fields {
            [offset, data @ ..] => Chunk::new(*offset, data)
                .map(Transfer::Write)
                .ok_or(FrameError::BadLength),
            [] => Err(FrameError::BadLength),
        },
        tag::CALIBRATION_COMMIT => match fields {
            &[a, b, c, d] => Ok(Transfer::Commit {
                crc: u32::from_le_bytes([a, b, c, d]),
            }),
            _ => Err(FrameError::BadLength),
        },
        _ => return None,
    })
}

/// Decodes a down-channel payload: a calibration transfer, a link request or a command.
pub fn decode_request(payload: &[u8]) -> Result<Request, FrameError> {
    if let Some(transfer) = decode_transfer(payload) {
        return transfer.map(Request::Calibration);
    }
    match decode_link_request(payload) {
        Some(request) => request.map(Request::Link),
        None => decode_command(payload).map(Request::Command),
    }
}

/// Encodes a transfer reply as a complete up-channel frame into `out` ([`MAX_REPLY_WIRE`]
/// suffice).
pub fn encode_transfer_reply(
    reply: &TransferReply,
    out: &mut [u8],
) -> Result<usize, BufferTooSmall> {
    // A chunk: kind, 0, the read tag, offset, then its bytes. A verdict: kind, result,
    // the request's tag, then its u32 (first byte in the head, three after).
    let arg;
    let (head, data) = match reply {
        TransferReply::Chunk(chunk) => (
            [KIND_CALIBRATION, 0, tag::CALIBRATION_READ, chunk.offset],
            chunk.data(),
        ),
        TransferReply::Verdict { transfer, result } => {
            let code = match result {
                Ok(()) => 0,
                Err(r) => refusal_code(*r),
            };
            arg = transfer.arg.to_le_bytes();
            let (first, rest) = arg.split_first().ok_or(BufferTooSmall)?;
            ([KIND_CALIBRATION, code, transfer.tag, *first], rest)
        }
    };
    let mut payload = [0; 4 + CHUNK_BYTES];
    let n = head.len() + data.len();
    let (h, d) = payload.split_at_mut(head.len());
    h.copy_from_slice(&head);
    d.get_mut(..data.len())
        .ok_or(BufferTooSmall)?
        .copy_from_slice(data);
    encode_frame(payload.get(..n).ok_or(BufferTooSmall)?, out)
}

/// Decodes a transfer reply (the payload after the kind `0x04`).
fn decode_transfer_reply(rest: &[u8]) -> Result<TransferReply, FrameError> {
    match rest {
        [0, tag::CALIBRATION_READ, offset, data @ ..] if !data.is_empty() => {
            Chunk::new(*offset, data)
                .map(TransferReply::Chunk)
                .ok_or(FrameError::BadLength)
        }
        &[code, t, a, b, c, d] => {
            let result = match code {
                0 => Ok(()),
                c => Err(refusal_from_code(c).ok_or(FrameError::BadValue)?),
            };
            if !matches!(
                t,
                tag::CALIBRATION_READ | tag::CALIBRATION_WRITE | tag::CALIBRATION_COMMIT
            ) && !is_link_tag(t)
            {
                return Err(FrameError::UnknownKind);
            }
            Ok(TransferReply::Verdict {
                transfer: TransferId {
                    tag: t,
                    arg: u32::from_le_bytes([a, b, c, d]),
                },
                result,
            })
        }
        _ => Err(FrameError::BadLength),
    }
}

/// Streaming reader of the down-channel as the command task reads it: bytes in, commands
/// and calibration transfers out, malformed frames rejected and counted.
#[derive(Clone, Debug, Default)]
pub struct RequestReader {
    deframer: Deframer<{ MAX_COMMAND_WIRE }>,
}

impl RequestReader {
    /// A reader waiting for the first frame.
    pub const fn new() -> Self {
        RequestReader {
            deframer: Deframer::new(),
        }
    }

    /// Feeds one byte; at the end of a frame returns the request or why it was rejected.
    pub fn push(&mut self, byte: u8) -> Option<Result<Request, FrameError>> {
        self.deframer.push_decoded(byte, decode_request)
    }
}

/// The command task's side of the calibration transfer: the staging buffer of a write in
/// progress and the bytes of the record the controller runs on. It answers reads and
/// writes itself; a commit that passes its checks returns the record for the controller.
#[derive(Clone, Debug)]
pub struct TransferState {
    staged: [u8; RECORD_BYTES],
    /// Bytes staged so far, in order from offset 0.
    filled: usize,
    current: Option<[u8; RECORD_BYTES]>,
}

impl Default for TransferState {
    fn default() -> Self {
        Self::new()
    }
}

/// What the command task does with a transfer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TransferStep {
    /// Send this reply now.
    Reply(TransferReply),
    /// The staged record passed every check: hand it to the controller, which answers.
    Load(crate::control::calibration::record::CalibrationRecord),
}

impl TransferState {
    /// Nothing staged, no current record known.
    pub const fn new() -> Self {
        TransferState {
            staged: [0; RECORD_BYTES],
            filled: 0,
            current: None,
        }
    }

    /// The controller now runs on `record`.
    pub fn set_current(&mut self, record: [u8; RECORD_BYTES]) {
        self.current = Some(record);
    }

    /// Handles one transfer request.
    #[inline(never)]
    pub fn handle(&mut self, transfer: Transfer) -> TransferStep {
        use crate::control::calibration::record::CalibrationRecord;
        let verdict = |result| {
            TransferStep::Reply(TransferReply::Verdict {
                transfer: transfer.id(),
                result,
            })
        };
        match transfer {
            Transfer::Read { offset } => match &self.current {
                None => verdict(Err(Refusal::Busy)),
                Some(record) => match Chunk::of_record(record, offset) {
                    Some(chunk) => TransferStep::Reply(TransferReply::Chunk(chunk)),
                    None => verdict(Err(Refusal::OutOfRange)),
                },
            },
            Transfer::Write(chunk) => {
                let at = usize::from(chunk.offset);
                let data = chunk.data();
                if at != 0 && at != self.filled {
                    return verdict(Err(Refusal::ChunkOutOfOrder));
                }
                match self.staged.get_mut(at..at + data.len()) {
                    Some(slot) => slot.copy_from_slice(data),
                    None => return verdict(Err(Refusal::OutOfRange)),
                }
                self.filled = at + data.len();
                verdict(Ok(()))
            }
            Transfer::Commit { crc } => {
                let filled = core::mem::take(&mut self.filled);
                if filled != RECORD_BYTES {
                    return verdict(Err(Refusal::ChunkOutOfOrder));
                }
                let sent = self.staged.get(RECORD_BYTES - 4..).unwrap_or_default();
                if sent != crc.to_le_bytes() {
                    return verdict(Err(Refusal::BadRecord));
                }
                match CalibrationRecord::decode(&self.staged) {
                    Ok(record) => TransferStep::Load(record),
                    Err(_) => verdict(Err(Refusal::BadRecord)),
                }
            }
        }
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
    use rand::{Rng as _, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Seeded ChaCha8 (`rand_chacha`): the fuzz inputs are the same on every run and every
    /// machine.
    pub(crate) struct Rng(ChaCha8Rng);
    impl Rng {
        pub fn new(seed: u64) -> Self {
            Rng(ChaCha8Rng::seed_from_u64(seed))
        }
        pub fn byte(&mut self) -> u8 {
            self.0.random()
        }
        pub fn word(&mut self) -> u32 {
            self.0.random()
        }
        pub fn below(&mut self, n: usize) -> usize {
            self.0.random_range(0..n.max(1))
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
            decode_command(&[tag::CALIBRATE, Routine::ALL.len() as u8]),
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

    fn record_bytes() -> [u8; RECORD_BYTES] {
        crate::control::calibration::record::CalibrationRecord::example().encode()
    }

    /// Writes `record` in chunks through `state`; the verdicts, then the commit's step.
    fn write_all(state: &mut TransferState, record: &[u8; RECORD_BYTES]) -> TransferStep {
        for (i, data) in record.chunks(CHUNK_BYTES).enumerate() {
            let chunk = Chunk::new((i * CHUNK_BYTES) as u8, data).unwrap();
            let t = Transfer::Write(chunk);
            assert_eq!(
                state.handle(t),
                TransferStep::Reply(TransferReply::Verdict {
                    transfer: t.id(),
                    result: Ok(())
                })
            );
        }
        let crc = u32::from_le_bytes(record[RECORD_BYTES - 4..].try_into().unwrap());
        state.handle(Transfer::Commit { crc })
    }

    fn refused(step: TransferStep) -> Option<Refusal> {
        match step {
            TransferStep::Reply(TransferReply::Verdict { result: Err(r), .. }) => Some(r),
            _ => None,
        }
    }

    #[test]
    fn calibration_transfers_and_their_replies_round_trip() {
        let record = record_bytes();
        let chunk = Chunk::of_record(&record, 128).unwrap();
        assert_eq!(chunk.data(), &record[128..]);
        assert_eq!(Chunk::of_record(&record, 136), None);
        let transfers = [
            Transfer::Read { offset: 16 },
            Transfer::Write(Chunk::of_record(&record, 0).unwrap()),
            Transfer::Write(chunk),
            Transfer::Commit { crc: 0xDEAD_BEEF },
        ];
        for t in transfers {
            let mut out = [0u8; MAX_COMMAND_WIRE];
            let n = encode_transfer(&t, &mut out).unwrap();
            let mut r = RequestReader::new();
            let got: Vec<_> = out[..n].iter().filter_map(|&b| r.push(b)).collect();
            assert_eq!(got, vec![Ok(Request::Calibration(t))]);
            for result in [
                Ok(()),
                Err(Refusal::ChunkOutOfOrder),
                Err(Refusal::BadRecord),
            ] {
                if matches!(t, Transfer::Read { .. }) && result.is_ok() {
                    // An accepted read is answered with its chunk, never a bare verdict.
                    continue;
                }
                let reply = TransferReply::Verdict {
                    transfer: t.id(),
                    result,
                };
                assert_eq!(answer_of(&reply), Answer::Calibration(reply));
            }
        }
        let reply = TransferReply::Chunk(chunk);
        assert_eq!(answer_of(&reply), Answer::Calibration(reply));
        // Commands still come through the same reader.
        let mut r = RequestReader::new();
        let got: Vec<_> = wire(&Command::Home)
            .iter()
            .filter_map(|&b| r.push(b))
            .collect();
        assert_eq!(got, vec![Ok(Request::Command(Command::Home))]);
        // Empty or oversized chunks and short commits are malformed.
        for payload in [
            &[tag::CALIBRATION_WRITE, 0][..],
            &[tag::CALIBRATION_WRITE][..],
            &[tag::CALIBRATION_READ][..],
            &[tag::CALIBRATION_COMMIT, 1, 2, 3][..],
        ] {
            assert_eq!(decode_request(payload), Err(FrameError::BadLength));
        }
        let mut long = vec![tag::CALIBRATION_WRITE, 0];
        long.extend([7; CHUNK_BYTES + 1]);
        assert_eq!(decode_request(&long), Err(FrameError::BadLength));
    }

    fn answer_of(reply: &TransferReply) -> Answer {
        let mut out = [0u8; MAX_REPLY_WIRE];
        let n = encode_transfer_reply(reply, &mut out).unwrap();
        let mut d = Deframer::<{ MAX_REPLY_WIRE }>::new();
        let got: Vec<_> = out[..n]
            .iter()
            .filter_map(|&b| d.push_decoded(b, decode_answer))
            .collect();
        assert_eq!(got.len(), 1);
        got[0].unwrap()
    }

    #[test]
    fn a_record_written_in_order_with_its_crc_is_loaded_and_read_back() {
        let record = record_bytes();
        let mut state = TransferState::new();
        assert_eq!(
            refused(state.handle(Transfer::Read { offset: 0 })),
            Some(Refusal::Busy),
            "no current record yet"
        );
        match write_all(&mut state, &record) {
            TransferStep::Load(r) => assert_eq!(r.encode(), record),
            other => panic!("{other:?}"),
        }
        state.set_current(record);
        let mut back = Vec::new();
        while back.len() < RECORD_BYTES {
            match state.handle(Transfer::Read {
                offset: back.len() as u8,
            }) {
                TransferStep::Reply(TransferReply::Chunk(c)) => back.extend_from_slice(c.data()),
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(back, record);
        assert_eq!(
            refused(state.handle(Transfer::Read { offset: 136 })),
            Some(Refusal::OutOfRange)
        );
    }

    #[test]
    fn out_of_order_missing_or_corrupt_chunks_are_refused_by_name() {
        let record = record_bytes();
        let crc = u32::from_le_bytes(record[RECORD_BYTES - 4..].try_into().unwrap());
        let mut state = TransferState::new();
        // A chunk that skips ahead is refused and leaves what was staged.
        let first = Chunk::of_record(&record, 0).unwrap();
        let _ = state.handle(Transfer::Write(first));
        let skip = Chunk::of_record(&record, 32).unwrap();
        assert_eq!(
            refused(state.handle(Transfer::Write(skip))),
            Some(Refusal::ChunkOutOfOrder)
        );
        // A commit before the whole record is staged.
        assert_eq!(
            refused(state.handle(Transfer::Commit { crc })),
            Some(Refusal::ChunkOutOfOrder)
        );
        // Past the end.
        let late = Chunk::new(130, &[1; 16]).unwrap();
        assert_eq!(
            refused(state.handle(Transfer::Write(late))),
            Some(Refusal::ChunkOutOfOrder)
        );
        // A corrupted byte: the record's own CRC fails.
        let mut bad = record;
        bad[20] ^= 0x40;
        assert_eq!(
            refused(write_all(&mut state, &bad)),
            Some(Refusal::BadRecord)
        );
        // A good record but another CRC sent.
        for chunk in record.chunks(CHUNK_BYTES).enumerate() {
            let c = Chunk::new((chunk.0 * CHUNK_BYTES) as u8, chunk.1).unwrap();
            let _ = state.handle(Transfer::Write(c));
        }
        assert_eq!(
            refused(state.handle(Transfer::Commit { crc: crc ^ 1 })),
            Some(Refusal::BadRecord)
        );
        // Another layout's version.
        let mut other = record;
        other[4] = 2;
        let c = crate::control::calibration::record::crc32(&other[..RECORD_BYTES - 4]);
        other[RECORD_BYTES - 4..].copy_from_slice(&c.to_le_bytes());
        assert_eq!(
            refused(write_all(&mut state, &other)),
            Some(Refusal::BadRecord)
        );
        // After all that, the good record still goes through.
        assert!(matches!(
            write_all(&mut state, &record),
            TransferStep::Load(_)
        ));
    }

    #[test]
    fn crc_matches_the_published_check_value() {
        assert_eq!(crc16(b"123456789"), 0x29B1);
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
        fn replies_round_trip(ci in 0usize..64, res in 0u8..16, p in any::<u32>()) {
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
        let mut rng = Rng::new(0x9E37_79B9_7F4A_7C15);
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
