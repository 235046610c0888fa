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

use crate::control::calibration::Routine;
use crate::control::command::Reply;
use crate::control::command::{Command, Parameter, Refusal};
use crate::motion::synchroniser::Rotation;
use crate::motion::volume_ratio::RatioTarget;

use super::frame::*;

/// Command tags (first payload byte of a down-channel frame).
pub mod tag {
    /// [`crate::control::command::Command::Home`].
    pub const HOME: u8 = 0x10;
    /// [`crate::control::command::Command::MoveTo`].
    pub const MOVE_TO: u8 = 0x11;
    /// [`crate::control::command::Command::Stop`].
    pub const STOP: u8 = 0x12;
    /// [`crate::control::command::Command::Heartbeat`].
    pub const HEARTBEAT: u8 = 0x13;
    /// [`crate::control::command::Command::ClearFaults`].
    pub const CLEAR_FAULTS: u8 = 0x14;
    /// [`crate::control::command::Command::Start`].
    pub const START: u8 = 0x15;
    /// [`crate::control::command::Command::SetSpeed`].
    pub const SET_SPEED: u8 = 0x16;
    /// [`crate::control::command::Command::SetRotation`].
    pub const SET_ROTATION: u8 = 0x17;
    /// [`crate::control::command::Command::SetVolumeRatio`].
    pub const SET_VOLUME_RATIO: u8 = 0x18;
    /// [`crate::control::command::Command::Calibrate`].
    pub const CALIBRATE: u8 = 0x19;
    /// [`crate::control::command::Command::SetParameter`].
    pub const SET_PARAMETER: u8 = 0x1A;
}

/// Largest command payload (tag + two f32).
pub const MAX_COMMAND_PAYLOAD: usize = 9;
/// Largest encoded command frame, delimiter included.
pub const MAX_COMMAND_WIRE: usize = max_wire_len(MAX_COMMAND_PAYLOAD);
/// Largest encoded reply frame, delimiter included (kind, result, command payload).
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
        Refusal::NotCalibrated => 8,
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
        Refusal::NotCalibrated,
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
        fn replies_round_trip(ci in 0usize..64, res in 0u8..9, p in any::<u32>()) {
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
