//! What `fpc-sim link` does with the channels, as ordinary code over any [`Channels`]:
//!
//! * [`CaptureSession`]: reads the up-channels as they fill, keeps each one's raw bytes
//!   (up 1 is exactly the capture `fpc-sim decode` reads), decodes telemetry incrementally
//!   with the same [`FrameCollector`] as `decode` (so the run log is the same), shows the
//!   defmt log and any answers, and counts what was lost.
//! * [`send_command`]: one command out on down 0 (the library's encoder), its answer awaited
//!   on up 2 with a timeout.
//! * [`read_calibration`], [`write_calibration`]: the calibration record in chunks, each
//!   answered before the next goes out, the write committed with the record's CRC.

use std::collections::VecDeque;
use std::io::{self, Write};
use std::time::{Duration, Instant};

use fpc::control::calibration::record::RECORD_BYTES;
use fpc::control::calibration::report::RoutineState;
use fpc::control::command::{BenchOp, Command, Refusal, Reply};
use fpc::link::commands::{
    decode_answer, encode_command, encode_transfer, Answer, Chunk, Transfer, TransferReply,
    CHUNK_BYTES, MAX_COMMAND_WIRE,
};
use fpc::link::frame::{Deframer, FrameError, LinkStats};
use fpc::link::report::ReportAnswer;
use fpc::link::scope::Trigger;
use fpc::link::scope::{decode_scope, MAX_SCOPE_WIRE};
use fpc::link::settings::{encode_link_request, LinkRequest};
use fpc::link::tag::{self, TransferId};
use fpc::link::telemetry::{ChannelSet, Ports, CHANNELS};
use fpc::motion::synchroniser::Rotation;
use fpc::motion::volume_ratio::RatioTarget;
use fpc::status::ModeKind;

use super::defmt::DefmtLog;
use super::scope::{trigger_text, ScopeCollector};
use super::{is_end, Channels, DOWN_COMMANDS, UP_DEFMT, UP_REPLIES, UP_TELEMETRY};
use crate::board::capture::FrameCollector;

/// Streaming reader of up 2: bytes in, answers out, scope recordings collected
/// ([`AnswerReader::scope`]), bad frames rejected and counted.
#[derive(Clone, Debug, Default)]
pub struct AnswerReader {
    deframer: Deframer<{ MAX_SCOPE_WIRE }>,
    scope: ScopeCollector,
    stats: LinkStats,
}

impl AnswerReader {
    /// A reader waiting for the first frame.
    pub fn new() -> Self {
        AnswerReader::default()
    }

    /// Feeds bytes; returns the answers (or why a frame was rejected) they complete.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<Result<Answer, FrameError>> {
        let mut out = Vec::new();
        for &b in bytes {
            let got = match self.deframer.push(b) {
                None => continue,
                Some(Err(e)) => Err(e),
                Some(Ok(payload)) => match decode_scope(payload) {
                    Some(Ok(message)) => {
                        self.scope.push(message);
                        self.stats.accepted += 1;
                        continue;
                    }
                    Some(Err(e)) => Err(e),
                    None => decode_answer(payload),
                },
            };
            match got {
                Ok(_) => self.stats.accepted += 1,
                Err(_) => self.stats.rejected += 1,
            }
            out.push(got);
        }
        out
    }

    /// Frames accepted and rejected so far.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// The scope recordings sent on up 2 so far.
    pub fn scope(&self) -> &ScopeCollector {
        &self.scope
    }
}

/// What the link has counted: the drop counters an operator watches.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Telemetry frames accepted and rejected (framing, CRC or payload).
    pub telemetry: LinkStats,
    /// Telemetry frames repeated (not later than the frame before), left out.
    pub repeated: usize,
    /// Sequence steps that differed from the first step seen (the decimation): frames lost
    /// between the firmware's queue and the host.
    pub gaps: usize,
    /// The firmware's own count of frames it could not send (the last frame's `dropped`).
    pub firmware_dropped: u16,
    /// Answer frames on up 2 accepted and rejected.
    pub answers: LinkStats,
    /// Bytes read from up 0 (defmt).
    pub defmt_bytes: usize,
    /// Bytes read from up 1 (telemetry).
    pub telemetry_bytes: usize,
    /// Scope recordings received whole on up 2.
    pub scope_recordings: usize,
}

impl std::fmt::Display for Counters {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "telemetry {} bytes: frames accepted {}, rejected {}, repeated {}, sequence gaps \
             {}, dropped by the firmware {}; replies accepted {}, rejected {}; scope recordings \
             {}; defmt {} bytes",
            self.telemetry_bytes,
            self.telemetry.accepted,
            self.telemetry.rejected,
            self.repeated,
            self.gaps,
            self.firmware_dropped,
            self.answers.accepted,
            self.answers.rejected,
            self.scope_recordings,
            self.defmt_bytes
        )
    }
}

/// Size of one read from a channel, bytes.
const READ_BYTES: usize = 4096;

/// A capture in progress: the up-channels read as they fill.
pub struct CaptureSession {
    telemetry: FrameCollector,
    answers: AnswerReader,
    defmt: DefmtLog,
    defmt_bytes: usize,
    ended: [bool; 3],
    received: Vec<Answer>,
}

impl CaptureSession {
    /// A session showing the defmt log with `defmt`.
    pub fn new(defmt: DefmtLog) -> CaptureSession {
        CaptureSession {
            telemetry: FrameCollector::new(),
            answers: AnswerReader::new(),
            defmt,
            defmt_bytes: 0,
            ended: [false; 3],
            received: Vec::new(),
        }
    }

    /// Reads what each up-channel holds now: its raw bytes go to `raw[channel]`, telemetry
    /// into the run log. Returns the bytes read and the lines to show (defmt, answers).
    pub fn poll<C: Channels + ?Sized>(
        &mut self,
        channels: &mut C,
        raw: &mut [&mut dyn Write; 3],
    ) -> io::Result<(usize, Vec<String>)> {
        let mut buf = [0u8; READ_BYTES];
        let mut total = 0;
        let mut lines = Vec::new();
        for channel in [UP_DEFMT, UP_TELEMETRY, UP_REPLIES] {
            let Some(ended) = self.ended.get_mut(channel) else {
                continue;
            };
            if *ended {
                continue;
            }
            let n = match channels.read_up(channel, &mut buf) {
                Ok(n) => n,
                Err(e) if is_end(&e) => {
                    *ended = true;
                    continue;
                }
                Err(e) => return Err(e),
            };
            let bytes = buf.get(..n).unwrap_or_default();
            if let Some(sink) = raw.get_mut(channel) {
                sink.write_all(bytes)?;
            }
            total += n;
            match channel {
                UP_TELEMETRY => self.telemetry.push(bytes),
                UP_DEFMT => {
                    self.defmt_bytes += n;
                    lines.extend(self.defmt.push(bytes));
                }
                _ => {
                    for a in self.answers.push(bytes) {
                        lines.push(match &a {
                            Ok(answer) => answer_text(answer),
                            Err(e) => format!("reply frame rejected: {}", frame_error_text(*e)),
                        });
                        if let Ok(answer) = a {
                            self.received.push(answer);
                        }
                    }
                }
            }
        }
        Ok((total, lines))
    }

    /// Whether every channel has ended (a recording played to its end).
    pub fn ended(&self) -> bool {
        self.ended.iter().all(|e| *e)
    }

    /// The counters so far.
    pub fn counters(&self) -> Counters {
        Counters {
            telemetry: self.telemetry.stats(),
            repeated: self.telemetry.duplicates(),
            gaps: self.telemetry.live_gaps(),
            firmware_dropped: self.telemetry.dropped(),
            answers: self.answers.stats(),
            defmt_bytes: self.defmt_bytes,
            telemetry_bytes: self.telemetry.bytes_read(),
            scope_recordings: self.answers.scope().recordings().len(),
        }
    }

    /// The scope recordings received so far.
    pub fn scope(&self) -> &ScopeCollector {
        self.answers.scope()
    }

    /// The last telemetry frame received, if any.
    pub fn last_frame(&self) -> Option<&fpc::link::telemetry::Frame> {
        self.telemetry.last()
    }

    /// The answers received since the last call, in order (also shown as lines by
    /// [`CaptureSession::poll`]).
    pub fn take_answers(&mut self) -> Vec<Answer> {
        std::mem::take(&mut self.received)
    }

    /// The telemetry collected, for the run log ([`FrameCollector::finish`]).
    pub fn into_telemetry(self) -> FrameCollector {
        self.telemetry
    }
}

/// How long [`machine_mode`] listens for a telemetry frame: a frame comes every 0.5 ms at
/// the firmware's default rate, every 50 ms at the slowest the link sets (20 Hz).
pub const MODE_WAIT: Duration = Duration::from_millis(300);

/// The machine's mode, from the first telemetry frame that comes on up 1 within `wait`
/// (`None`: none came — telemetry switched off, or no fpc firmware running). Reads the
/// up-channels as a capture does (what else they hold is dropped).
pub fn machine_mode<C: Channels + ?Sized>(
    channels: &mut C,
    wait: Duration,
) -> io::Result<Option<ModeKind>> {
    let mut session = CaptureSession::new(DefmtLog::hex());
    let (mut a, mut b, mut c) = (io::sink(), io::sink(), io::sink());
    let started = Instant::now();
    loop {
        let mut raw: [&mut dyn Write; 3] = [&mut a, &mut b, &mut c];
        let (n, _) = session.poll(channels, &mut raw)?;
        if let Some(frame) = session.last_frame() {
            return Ok(Some(frame.mode));
        }
        if session.ended() || started.elapsed() >= wait {
            return Ok(None);
        }
        if n == 0 {
            channels.pause(Duration::from_millis(1));
        }
    }
}

/// Whether `what`, which halts or resets the core, may go ahead with the machine in `mode`
/// (from [`machine_mode`]): only while the machine is idle — its outputs off, nothing
/// commanded to move — or when no firmware answers; in any other mode only with `force`. A
/// halt freezes the bridges' timers with their outputs off and a reset drops every output:
/// a moving piston is then left to coast into a head.
pub fn halting_allowed(what: &str, mode: Option<ModeKind>, force: bool) -> Result<(), String> {
    match mode {
        Some(m) if m != ModeKind::Idle && !force => Err(format!(
            "{what} halts or resets the core, and the machine is {}: stop it first \
             (`fpc-sim link send stop`, then wait for idle), or give --force",
            m.name()
        )),
        _ => Ok(()),
    }
}

/// How a command ended: the firmware's answer to it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// The controller's verdict.
    Reply(Reply),
    /// The firmware could not decode the command frame.
    Rejected(FrameError),
}

/// Sends `command` on down 0 and waits up to `timeout` for its answer on up 2. Answers to
/// other (earlier) commands that arrive first are passed to `other`, as text. An error is
/// one line: the channel failed, the down-channel stayed full, or no answer came.
pub fn send_command<C: Channels + ?Sized>(
    channels: &mut C,
    command: &Command,
    timeout: Duration,
    other: impl FnMut(String),
) -> Result<Outcome, String> {
    let mut wire = [0u8; MAX_COMMAND_WIRE];
    let n = encode_command(command, &mut wire)
        .map_err(|_| "the command does not fit a frame".to_string())?;
    let mut exchange = Exchange::new(channels, timeout, other);
    let got = exchange.ask(
        wire.get(..n).unwrap_or_default(),
        &describe(command),
        |a| match a {
            Answer::Reply(reply) if same_command(&reply.command, command) => Some(*reply),
            _ => None,
        },
    )?;
    Ok(match got {
        Ok(reply) => Outcome::Reply(reply),
        Err(reason) => Outcome::Rejected(reason),
    })
}

/// Requests on down 0 and their answers on up 2, one after the other: the answers are read
/// by one reader, so an answer that arrives in the same piece as the one before is kept.
pub(super) struct Exchange<'c, C: ?Sized, O> {
    channels: &'c mut C,
    reader: AnswerReader,
    pending: VecDeque<Result<Answer, FrameError>>,
    timeout: Duration,
    other: O,
}

impl<'c, C: Channels + ?Sized, O: FnMut(String)> Exchange<'c, C, O> {
    pub(super) fn new(channels: &'c mut C, timeout: Duration, other: O) -> Self {
        Exchange {
            channels,
            reader: AnswerReader::new(),
            pending: VecDeque::new(),
            timeout,
            other,
        }
    }

    /// Sends `wire` and waits for the answer `pick` recognises (or a rejection); answers it
    /// does not recognise go to `other`. `what` names the request in errors.
    pub(super) fn ask<T>(
        &mut self,
        wire: &[u8],
        what: &str,
        mut pick: impl FnMut(&Answer) -> Option<T>,
    ) -> Result<Result<T, FrameError>, String> {
        let started = Instant::now();
        let mut sent = 0;
        while sent < wire.len() {
            let rest = wire.get(sent..).unwrap_or_default();
            let n = self
                .channels
                .write_down(DOWN_COMMANDS, rest)
                .map_err(|e| format!("cannot write down-channel {DOWN_COMMANDS}: {e}"))?;
            sent += n;
            if n == 0 {
                if started.elapsed() > self.timeout {
                    return Err(format!(
                        "down-channel {DOWN_COMMANDS} stayed full for {} ms: is the firmware's \
                         command task running?",
                        self.timeout.as_millis()
                    ));
                }
                self.channels.pause(Duration::from_millis(1));
            }
        }
        let mut buf = [0u8; 256];
        loop {
            while let Some(answer) = self.pending.pop_front() {
                match answer {
                    Ok(Answer::Rejected(reason)) => return Ok(Err(reason)),
                    Ok(a) => match pick(&a) {
                        Some(t) => return Ok(Ok(t)),
                        None => (self.other)(format!("earlier answer: {}", answer_text(&a))),
                    },
                    Err(e) => {
                        (self.other)(format!("reply frame rejected: {}", frame_error_text(e)))
                    }
                }
            }
            let n = match self.channels.read_up(UP_REPLIES, &mut buf) {
                Ok(n) => n,
                Err(e) if is_end(&e) => {
                    return Err(format!(
                        "the recording of up-channel {UP_REPLIES} ended without an answer to \
                         `{what}`"
                    ))
                }
                Err(e) => return Err(format!("cannot read up-channel {UP_REPLIES}: {e}")),
            };
            self.pending
                .extend(self.reader.push(buf.get(..n).unwrap_or_default()));
            if n == 0 {
                if started.elapsed() > self.timeout {
                    return Err(format!(
                        "no answer to `{what}` within {} ms on up-channel {UP_REPLIES}: is the \
                         firmware running?",
                        self.timeout.as_millis()
                    ));
                }
                self.channels.pause(Duration::from_millis(1));
            }
        }
    }

    /// Sends a calibration transfer; the chunk read, or the verdict, or why it failed.
    fn transfer(&mut self, transfer: Transfer) -> Result<Result<Option<Chunk>, Refusal>, String> {
        let mut wire = [0u8; MAX_COMMAND_WIRE];
        let n = encode_transfer(&transfer, &mut wire)
            .map_err(|_| "the request does not fit a frame".to_string())?;
        let what = transfer_text(transfer.id());
        let got = self.ask(wire.get(..n).unwrap_or_default(), &what, |a| {
            match (a, transfer) {
                (Answer::Calibration(TransferReply::Chunk(c)), Transfer::Read { offset })
                    if c.offset == offset =>
                {
                    Some(Ok(Some(*c)))
                }
                (
                    Answer::Calibration(TransferReply::Verdict {
                        transfer: t,
                        result,
                    }),
                    _,
                ) if *t == transfer.id() => Some(result.map(|()| None)),
                _ => None,
            }
        })?;
        got.map_err(|reason| {
            format!(
                "rejected by the firmware: the `{what}` frame {}",
                frame_error_text(reason)
            )
        })
    }
}

/// Reads the calibration record the controller runs on, chunk by chunk; the bytes are
/// checked (magic, version, CRC) by the caller's decoding.
pub fn read_calibration<C: Channels + ?Sized>(
    channels: &mut C,
    timeout: Duration,
    other: impl FnMut(String),
) -> Result<[u8; RECORD_BYTES], String> {
    let mut exchange = Exchange::new(channels, timeout, other);
    let mut record = [0u8; RECORD_BYTES];
    let mut offset = 0;
    while offset < RECORD_BYTES {
        let transfer = Transfer::Read {
            offset: offset as u8,
        };
        let chunk = match exchange.transfer(transfer)? {
            Ok(Some(chunk)) => chunk,
            Ok(None) => {
                return Err(format!(
                    "no bytes in the answer to `{}`",
                    transfer_text(transfer.id())
                ))
            }
            Err(r) => {
                return Err(format!(
                    "refused: {}: {}",
                    transfer_text(transfer.id()),
                    r.reason()
                ))
            }
        };
        let data = chunk.data();
        record
            .get_mut(offset..offset + data.len())
            .ok_or_else(|| format!("the chunk at offset {offset} runs past the record"))?
            .copy_from_slice(data);
        offset += data.len();
    }
    Ok(record)
}

/// Writes `record` (its encoded bytes) chunk by chunk, then commits it with its CRC: the
/// firmware checks it and loads it, or refuses it and changes nothing.
pub fn write_calibration<C: Channels + ?Sized>(
    channels: &mut C,
    record: &[u8; RECORD_BYTES],
    timeout: Duration,
    other: impl FnMut(String),
) -> Result<(), String> {
    let mut exchange = Exchange::new(channels, timeout, other);
    let mut send = |transfer: Transfer| match exchange.transfer(transfer)? {
        Ok(_) => Ok(()),
        Err(r) => Err(format!(
            "refused: {}: {}",
            transfer_text(transfer.id()),
            r.reason()
        )),
    };
    for (i, data) in record.chunks(CHUNK_BYTES).enumerate() {
        let chunk = Chunk::new((i * CHUNK_BYTES) as u8, data)
            .ok_or_else(|| "a chunk does not fit a frame".to_string())?;
        send(Transfer::Write(chunk))?;
    }
    let crc = match record.get(RECORD_BYTES - 4..) {
        Some(&[a, b, c, d]) => u32::from_le_bytes([a, b, c, d]),
        _ => return Err("the record has no CRC".into()),
    };
    send(Transfer::Commit { crc })
}

/// A calibration transfer as one line of text.
pub fn transfer_text(id: TransferId) -> String {
    match id.tag {
        tag::CALIBRATION_READ => format!("calibration read at offset {}", id.arg),
        tag::CALIBRATION_WRITE => format!("calibration write at offset {}", id.arg),
        tag::CALIBRATION_COMMIT => format!("calibration commit, CRC {:08x}", id.arg),
        tag::SET_TELEMETRY => format!(
            "telemetry --decimation {} --channels {}",
            id.arg & 0xFFFF,
            channels_text(ChannelSet((id.arg >> 16) as u16))
        ),
        tag::DECLARE_PORTS => format!(
            "ports {}",
            Ports::from_code(id.arg as u8).map_or("?", Ports::name)
        ),
        tag::SCOPE_ARM => format!(
            "scope arm --trigger {}",
            Trigger::from_code(id.arg as u8, (id.arg >> 8) as u16)
                .map_or("?".to_string(), trigger_text)
        ),
        tag::SCOPE_FIRE => "scope fire".into(),
        tag::SCOPE_DISARM => "scope disarm".into(),
        tag::ROUTINE_REPORT => "routine report".into(),
        other => format!("request {other:#04x}"),
    }
}

/// A channel set as typed: `all`, `gap`, or the channels' names joined by commas.
pub fn channels_text(set: ChannelSet) -> String {
    if set == ChannelSet::ALL {
        "all".into()
    } else if set == ChannelSet::GAP {
        "gap".into()
    } else {
        CHANNELS
            .iter()
            .enumerate()
            .filter(|(i, _)| set.has(*i))
            .map(|(_, n)| *n)
            .collect::<Vec<_>>()
            .join(",")
    }
}

/// A channel set as typed: `all`, `gap`, or the channels' names joined by commas; the
/// error names what is not a channel.
pub fn parse_channels(text: &str) -> Result<ChannelSet, String> {
    match text {
        "all" => return Ok(ChannelSet::ALL),
        "gap" => return Ok(ChannelSet::GAP),
        _ => {}
    }
    let mut bits = 0u16;
    for name in text.split(',').map(str::trim) {
        let i = CHANNELS.iter().position(|c| *c == name).ok_or_else(|| {
            format!(
                "`{name}` is no channel; give all, gap, or names from {}",
                CHANNELS.join(", ")
            )
        })?;
        bits |= 1 << i;
    }
    Ok(ChannelSet(bits))
}

/// Sends a link request (telemetry, ports, scope) on down 0 and waits up to `timeout` for the
/// firmware's verdict on up 2: accepted, or refused with the reason. An error is one line.
pub fn send_link_request<C: Channels + ?Sized>(
    channels: &mut C,
    request: &LinkRequest,
    timeout: Duration,
    other: impl FnMut(String),
) -> Result<Result<(), Refusal>, String> {
    let mut wire = [0u8; MAX_COMMAND_WIRE];
    let n = encode_link_request(request, &mut wire)
        .map_err(|_| "the request does not fit a frame".to_string())?;
    let id = request.id();
    let what = transfer_text(id);
    let mut exchange = Exchange::new(channels, timeout, other);
    let got = exchange.ask(wire.get(..n).unwrap_or_default(), &what, |a| match a {
        Answer::Calibration(TransferReply::Verdict { transfer, result }) if *transfer == id => {
            Some(*result)
        }
        _ => None,
    })?;
    got.map_err(|reason| {
        format!(
            "rejected by the firmware: the `{what}` frame {}",
            frame_error_text(reason)
        )
    })
}

/// Whether two commands are the same on the wire (bit for bit, so NaN equals NaN).
fn same_command(a: &Command, b: &Command) -> bool {
    let mut x = [0u8; MAX_COMMAND_WIRE];
    let mut y = [0u8; MAX_COMMAND_WIRE];
    match (encode_command(a, &mut x), encode_command(b, &mut y)) {
        (Ok(n), Ok(m)) => x.get(..n) == y.get(..m),
        _ => false,
    }
}

/// A section's name as the host's commands and printouts spell it.
pub fn section_name(section: fpc::units::Section) -> &'static str {
    match section {
        fpc::units::Section::Master => "master",
        fpc::units::Section::Slave => "slave",
    }
}

/// A command as the operator types it after `fpc-sim link send`.
pub fn describe(command: &Command) -> String {
    match *command {
        Command::Home => "home".into(),
        Command::MoveTo {
            position_m,
            peak_speed_mps,
        } => format!("move-to --position {position_m} --speed {peak_speed_mps}"),
        Command::Stop => "stop".into(),
        Command::Heartbeat => "heartbeat".into(),
        Command::ClearFaults => "clear-faults".into(),
        Command::Start { peak_speed_mps } => format!("start --speed {peak_speed_mps}"),
        Command::SetSpeed { peak_speed_mps } => format!("set-speed --speed {peak_speed_mps}"),
        Command::SetRotation { rotation } => format!(
            "set-rotation {}",
            match rotation {
                Rotation::Compressor => "compressor",
                Rotation::Expander => "expander",
            }
        ),
        Command::SetVolumeRatio { target } => match target {
            RatioTarget::FollowMeasured => "set-volume-ratio --follow".into(),
            RatioTarget::Fixed { pressure_ratio } => {
                format!("set-volume-ratio --ratio {pressure_ratio}")
            }
        },
        Command::Calibrate { routine } => format!("calibrate {}", routine_name(routine as u8)),
        Command::SetParameter { parameter, value } => {
            format!("set-parameter {} {value}", parameter_name(parameter as u8))
        }
        Command::Bench { op, seconds } => match op {
            BenchOp::FixedDuty {
                section,
                phase,
                duty,
            } => format!(
                "bench fixed-duty --section {} --phase {} --duty {duty} --seconds {seconds}",
                section_name(section),
                ["u", "v", "w"].get(usize::from(phase)).unwrap_or(&"?"),
            ),
            BenchOp::ServoTorque { torque_nm } => {
                format!("bench servo-torque --torque {torque_nm} --seconds {seconds}")
            }
        },
    }
}

/// Operator names of the calibration routines, by wire number.
pub const ROUTINES: [&str; 6] = [
    "current-sense",
    "alignment",
    "misalignment",
    "cogging",
    "encoder-map",
    "commission",
];
/// Operator names of the parameters, by wire number (from 1).
pub const PARAMETERS: [&str; 5] = [
    "position-kp",
    "position-kd",
    "heartbeat-timeout",
    "park-position",
    "dead-point-gain",
];

fn routine_name(code: u8) -> &'static str {
    ROUTINES.get(usize::from(code)).copied().unwrap_or("?")
}

fn parameter_name(code: u8) -> &'static str {
    usize::from(code)
        .checked_sub(1)
        .and_then(|i| PARAMETERS.get(i))
        .copied()
        .unwrap_or("?")
}

/// An answer as one line of text.
pub fn answer_text(answer: &Answer) -> String {
    match answer {
        Answer::Reply(Reply {
            command,
            result: Ok(()),
        }) => format!("accepted: {}", describe(command)),
        Answer::Reply(Reply {
            command,
            result: Err(refusal),
        }) => format!("refused: {}: {}", describe(command), refusal.reason()),
        Answer::Rejected(reason) => format!(
            "rejected by the firmware: the command frame {}",
            frame_error_text(*reason)
        ),
        Answer::Calibration(TransferReply::Chunk(chunk)) => format!(
            "calibration chunk: {} bytes at offset {}",
            chunk.data().len(),
            chunk.offset
        ),
        Answer::Calibration(TransferReply::Verdict {
            transfer,
            result: Ok(()),
        }) => format!("accepted: {}", transfer_text(*transfer)),
        Answer::Calibration(TransferReply::Verdict {
            transfer,
            result: Err(refusal),
        }) => format!(
            "refused: {}: {}",
            transfer_text(*transfer),
            refusal.reason()
        ),
        Answer::Report(report) => report_text(report),
    }
}

/// A report as one line of text.
pub fn report_text(answer: &ReportAnswer) -> String {
    match answer {
        ReportAnswer::Nothing => "report: no routine since boot".into(),
        ReportAnswer::Left(r) => format!("report: {} left before it ended", r.name()),
        ReportAnswer::Report(r) => match r.state {
            RoutineState::Running => format!("report: {} running", r.routine.name()),
            RoutineState::Succeeded(_) => format!("report: {} done", r.routine.name()),
            RoutineState::Failed(e) => format!("report: {} failed: {e}", r.routine.name()),
        },
    }
}

/// An outcome as one line of text.
pub fn outcome_text(outcome: &Outcome) -> String {
    match outcome {
        Outcome::Reply(r) => answer_text(&Answer::Reply(*r)),
        Outcome::Rejected(e) => answer_text(&Answer::Rejected(*e)),
    }
}

/// What a frame error means, for an operator.
pub fn frame_error_text(e: FrameError) -> &'static str {
    match e {
        FrameError::Overlong => "was too long (garbage or a lost delimiter)",
        FrameError::Cobs => "had broken COBS framing",
        FrameError::TooShort => "was too short",
        FrameError::Crc => "failed its CRC (corrupted or truncated)",
        FrameError::UnknownKind => "had an unknown kind or command tag",
        FrameError::BadLength => "had the wrong length for its kind",
        FrameError::BadValue => "held a value with no meaning",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::Replay;
    use fpc::control::command::Refusal;
    use fpc::link::commands::{encode_rejection, encode_reply};

    fn reply_bytes(reply: &Reply) -> Vec<u8> {
        let mut out = [0u8; fpc::link::commands::MAX_REPLY_WIRE];
        let n = encode_reply(reply, &mut out).unwrap();
        out[..n].to_vec()
    }

    #[test]
    fn only_an_idle_or_silent_machine_may_be_halted_without_force() {
        assert!(halting_allowed("flashing", None, false).is_ok());
        assert!(halting_allowed("flashing", Some(ModeKind::Idle), false).is_ok());
        let e = halting_allowed("flashing", Some(ModeKind::Running), false).unwrap_err();
        assert!(
            e.contains("the machine is running") && e.contains("--force"),
            "{e}"
        );
        assert!(halting_allowed("flashing", Some(ModeKind::Faulted), false).is_err());
        assert!(halting_allowed("flashing", Some(ModeKind::Running), true).is_ok());
    }

    #[test]
    fn the_machines_mode_is_read_from_the_first_frame_or_none() {
        let status = fpc::status::Status {
            mode: ModeKind::Holding,
            ..fpc::status::Status::INIT
        };
        let mut buf = [0u8; fpc::link::telemetry::WIRE_BYTES];
        let n = fpc::link::telemetry::Frame::from_status(0, 0, &status)
            .encode(&mut buf)
            .unwrap();
        let mut replay = Replay::new(vec![Vec::new(), buf[..n].to_vec(), Vec::new()]);
        let mode = machine_mode(&mut replay, MODE_WAIT).unwrap();
        assert_eq!(mode, Some(ModeKind::Holding));
        let mut silent = Replay::new(vec![Vec::new(), Vec::new(), Vec::new()]);
        assert_eq!(machine_mode(&mut silent, MODE_WAIT).unwrap(), None);
    }

    #[test]
    fn the_answer_to_the_command_sent_is_found_behind_earlier_ones() {
        let start = Command::Start {
            peak_speed_mps: 2.3,
        };
        let mut up2 = reply_bytes(&Reply {
            command: Command::Home,
            result: Ok(()),
        });
        up2.extend([0x55, 0x66, 0x00]);
        up2.extend(reply_bytes(&Reply {
            command: start,
            result: Err(Refusal::NotHomed),
        }));
        let mut replay = Replay::new(vec![Vec::new(), Vec::new(), up2]);
        let mut others = Vec::new();
        let got = send_command(&mut replay, &start, Duration::from_secs(1), |l| {
            others.push(l)
        })
        .unwrap();
        assert_eq!(
            outcome_text(&got),
            "refused: start --speed 2.3: not homed: home the axis first"
        );
        assert_eq!(others.len(), 2, "{others:?}");
        assert_eq!(others[0], "earlier answer: accepted: home");
        let mut wire = [0u8; MAX_COMMAND_WIRE];
        let n = encode_command(&start, &mut wire).unwrap();
        assert_eq!(replay.down[DOWN_COMMANDS], wire[..n]);
    }

    #[test]
    fn a_rejection_ends_the_wait_and_no_answer_is_an_error() {
        let mut out = [0u8; 8];
        let n = encode_rejection(FrameError::Crc, &mut out).unwrap();
        let mut replay = Replay::new(vec![Vec::new(), Vec::new(), out[..n].to_vec()]);
        let got = send_command(&mut replay, &Command::Stop, Duration::from_secs(1), |_| {});
        assert_eq!(got, Ok(Outcome::Rejected(FrameError::Crc)));
        let mut empty = Replay::new(vec![Vec::new(), Vec::new(), vec![1, 2, 3]]);
        let e =
            send_command(&mut empty, &Command::Stop, Duration::from_secs(1), |_| {}).unwrap_err();
        assert!(e.contains("without an answer to `stop`"), "{e}");
    }

    #[test]
    fn every_command_reads_as_typed() {
        use fpc::control::calibration::Routine;
        use fpc::control::command::Parameter;
        for routine in Routine::ALL {
            assert_ne!(routine_name(routine as u8), "?");
        }
        for p in Parameter::ALL {
            assert_ne!(parameter_name(p as u8), "?");
        }
        assert_eq!(
            describe(&Command::SetParameter {
                parameter: Parameter::DeadPointGain,
                value: 0.6
            }),
            "set-parameter dead-point-gain 0.6"
        );
    }
}
