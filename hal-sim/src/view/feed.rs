//! The console's link to the machine: one thread owns the source — the simulated board
//! stepped in real time, a recorded session played at its own pace, or the board through a
//! probe — reads its RTT channels as `fpc-sim link` does, turns the page's controls into the
//! link's commands and requests, and hands the page batches of telemetry, the firmware's
//! answers and scope recordings (as JSON text, to every connected page).
//!
//! * **Simulated board**: the firmware's four tasks on the plant ([`LinkedBoard`]), reached
//!   only through its RAM with the RTT transport a probe runs; stepped to the wall clock, the
//!   host polling every millisecond of board time. The stream starts at 2 kHz with all ten
//!   channels (the reference too). Start sets the discharge line to the pressure ratio and
//!   closes the start-up bypass, as the rig's operator does.
//! * **Replay**: a capture directory (`up0.bin`, `up1.bin`, `up2.bin`) played at the pace
//!   its frames were sent, from the start again when it ends. The controls are answered from
//!   the recording, as `fpc-sim link send --replay` answers them: the recording decides what
//!   the machine does. Stop plays on to the recording's own stop and holds there; the next
//!   control plays it again from its start.
//! * **Board** (cargo feature `probe`): the probe transport of `fpc-sim link`, attached by
//!   the caller before the console starts (no probe: one error, nothing started) and handed
//!   over as a [`LiveLink`]: any transport with the link's interface ([`Channels`]) runs the
//!   same way, polled every millisecond.
//!
//! Recording writes the raw channels as `fpc-sim link capture` does — `DIR/rec-N/up0.bin`,
//! `up1.bin`, `up2.bin` — and, when it ends, the run log `run.csv` (`fpc-sim decode`'s) and
//! each scope recording as `scope-N.csv`, so `decode`, `gap` and `view --replay` read it.

use std::collections::VecDeque;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use fpc::control::calibration::Routine;
use fpc::control::command::Command;
use fpc::link::commands::{encode_command, Answer, TransferReply, MAX_COMMAND_WIRE};
use fpc::link::settings::{encode_link_request, LinkRequest};
use fpc::link::telemetry::{Frame, Ports, TelemetryDecoder, CONTROL_PERIOD_US};
use fpc::motion::synchroniser::Rotation;
use fpc::safety::faults::Fault;
use tokio::sync::broadcast;

use super::protocol::{Batch, Control, Message, ScopeTrace};
use crate::link::scope::{trigger_text, ScopeRecording};
use crate::link::session::{answer_text, describe, parse_channels, transfer_text, AnswerReader};
use crate::link::{is_end, Channels, Replay, DOWN_COMMANDS, UP_DEFMT, UP_REPLIES, UP_TELEMETRY};
use crate::output::{show, OutDir};
use crate::plant::model::MachineModel;

/// Control periods per second.
const CYCLES_PER_S: u64 = 1_000_000 / CONTROL_PERIOD_US as u64;
/// The host polls the simulated board every this many control periods (1 ms).
const POLL_CYCLES: u64 = 20;
/// A batch goes to the page at most this often (≈ 30 per second).
const BATCH_EVERY: Duration = Duration::from_millis(33);
/// Most board time stepped between two looks at the controls, s.
const MOST_STEPPED_S: f64 = 0.05;
/// Bytes read from a channel at once.
const READ_BYTES: usize = 4096;

/// A live board's channels, opened once in the link thread: the board's RTT channels
/// behind a probe ([`crate::link::probe::attach`]), or any transport with the same interface.
pub struct LiveLink {
    /// What is on the other end, in words (the page's title).
    pub what: String,
    /// Opens the channels.
    pub open: Box<dyn FnOnce() -> Result<Box<dyn Channels>, String> + Send>,
}

impl std::fmt::Debug for LiveLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveLink")
            .field("what", &self.what)
            .finish()
    }
}

/// Where the console's stream comes from.
#[derive(Debug)]
pub enum Source {
    /// The simulated board on a machine model.
    Sim {
        /// The machine (boxed: a model is large beside the other sources).
        model: Box<MachineModel>,
        /// Its name, for the title.
        model_name: String,
        /// The noise seed.
        seed: u64,
    },
    /// A recorded session (a capture directory).
    Replay {
        /// The directory.
        dir: PathBuf,
    },
    /// The board through a debug probe (or a transport with its interface).
    Probe(LiveLink),
}

impl Source {
    /// `sim`, `replay` or `probe`.
    pub fn mode(&self) -> &'static str {
        match self {
            Source::Sim { .. } => "sim",
            Source::Replay { .. } => "replay",
            Source::Probe(_) => "probe",
        }
    }

    /// What is on the other end, in words.
    pub fn describe(&self) -> String {
        match self {
            Source::Sim { model_name, .. } => format!("simulated board, {model_name} machine"),
            Source::Replay { dir } => format!("recorded session {}", show(dir)),
            Source::Probe(link) => link.what.clone(),
        }
    }
}

/// The link thread's handles: controls in, messages out, the stop flag.
pub struct Feed {
    /// The page's controls, to the link thread.
    pub controls: mpsc::Sender<Control>,
    /// Every message for the pages (JSON text).
    pub messages: broadcast::Sender<Arc<str>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<Result<(), String>>>,
}

impl Feed {
    /// Starts the link thread on `source`; recordings go into `out`.
    pub fn start(source: Source, out: PathBuf) -> Feed {
        let (controls, rx) = mpsc::channel();
        // ≈ 8 s of batches: a page that falls further behind loses batches and says so.
        let (messages, _) = broadcast::channel(256);
        let stop = Arc::new(AtomicBool::new(false));
        let host = Host::new(messages.clone(), out);
        let flag = stop.clone();
        let thread = std::thread::spawn(move || run(source, host, rx, &flag));
        Feed {
            controls,
            messages,
            stop,
            thread: Some(thread),
        }
    }

    /// Whether the link thread has ended (a source that failed).
    pub fn ended(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Ends the link thread (a recording in progress is written) and returns how it ended.
    pub fn finish(mut self) -> Result<(), String> {
        self.stop.store(true, Ordering::SeqCst);
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err("the link thread panicked".into()),
            None => Ok(()),
        }
    }
}

/// The link thread: runs the source until `stop`, then ends a recording in progress.
fn run(
    source: Source,
    mut host: Host,
    controls: mpsc::Receiver<Control>,
    stop: &AtomicBool,
) -> Result<(), String> {
    let result = match source {
        Source::Sim { model, seed, .. } => run_sim(&model, seed, &mut host, &controls, stop),
        Source::Replay { dir } => run_replay(&dir, &mut host, &controls, stop),
        Source::Probe(link) => match (link.open)() {
            Ok(mut channels) => run_board(&mut *channels, &mut host, &controls, stop),
            Err(e) => Err(e),
        },
    };
    if let Err(e) = &result {
        host.log(&format!("the link ended: {e}"), "refused");
    }
    host.record(false);
    result
}

/// What the simulated board's operator does besides sending commands.
#[derive(Clone, Copy, Debug, PartialEq)]
enum PlantAction {
    /// Set the discharge line to this pressure ratio and close the start-up bypass.
    Load(f64),
}

/// The page's control as the link's frames (and the plant's change on the simulated
/// board), or the console's answer when it cannot be sent.
struct Sends {
    /// Commands and requests, in order.
    items: Vec<Outgoing>,
    /// A change of the simulated plant before them.
    plant: Option<PlantAction>,
}

/// One command or link request.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Outgoing {
    Command(Command),
    Request(LinkRequest),
}

impl Outgoing {
    fn wire(&self) -> Vec<u8> {
        let mut wire = [0u8; MAX_COMMAND_WIRE];
        let n = match self {
            Outgoing::Command(c) => encode_command(c, &mut wire).unwrap_or(0),
            Outgoing::Request(r) => encode_link_request(r, &mut wire).unwrap_or(0),
        };
        wire.get(..n).unwrap_or_default().to_vec()
    }

    fn text(&self) -> String {
        match self {
            Outgoing::Command(c) => describe(c),
            Outgoing::Request(r) => transfer_text(r.id()),
        }
    }

    /// Whether `answer` answers it.
    fn answered_by(&self, answer: &Answer) -> bool {
        match (self, answer) {
            (Outgoing::Command(c), Answer::Reply(r)) => r.command == *c,
            (
                Outgoing::Request(q),
                Answer::Calibration(TransferReply::Verdict { transfer, .. }),
            ) => *transfer == q.id(),
            _ => false,
        }
    }
}

/// What the console knows of the machine it controls, to turn a control into frames.
#[derive(Clone, Copy, Debug)]
struct Known {
    /// The rotation last set (the firmware boots as a compressor).
    rotation: Rotation,
    /// The ports declared timed (the simulated board's bypass closed).
    ports_timed: bool,
}

/// Turns a page control into what is sent, or the reason it is not.
fn translate(
    control: &Control,
    mode: &str,
    model: Option<&MachineModel>,
    known: &mut Known,
) -> Result<Sends, String> {
    let one = |s: Outgoing| {
        Ok(Sends {
            items: vec![s],
            plant: None,
        })
    };
    match control {
        Control::Home => one(Outgoing::Command(Command::Home)),
        Control::Stop => one(Outgoing::Command(Command::Stop)),
        Control::ClearFaults => one(Outgoing::Command(Command::ClearFaults)),
        Control::Calibrate { routine } => {
            let routine = match routine.as_str() {
                "current-sense" => Routine::CurrentSense,
                "alignment" => Routine::Alignment,
                "misalignment" => Routine::Misalignment,
                "cogging" => Routine::Cogging,
                other => {
                    return Err(format!(
                        "calibrate {}: give current-sense, alignment, misalignment or cogging",
                        crate::output::clip(other, 40)
                    ))
                }
            };
            one(Outgoing::Command(Command::Calibrate { routine }))
        }
        Control::Start {
            pressure_ratio,
            speed_mps,
            rotation,
        } => {
            let rotation = match rotation.as_str() {
                "compressor" => Rotation::Compressor,
                "expander" => Rotation::Expander,
                other => {
                    return Err(format!(
                        "rotation {}: give compressor or expander",
                        crate::output::clip(other, 40)
                    ))
                }
            };
            // The ratio and speed are checked as `fpc-sim run` checks its flags.
            let opts = crate::run::RunOptions {
                model: model.cloned().unwrap_or_else(MachineModel::reference),
                pressure_ratio: *pressure_ratio,
                speed_mps: *speed_mps,
                ..crate::run::RunOptions::reference()
            };
            opts.validate()?;
            let mut items = Vec::new();
            let mut plant = None;
            if mode != "probe" && !known.ports_timed {
                // The operator closes the start-up bypass and says so.
                items.push(Outgoing::Request(LinkRequest::DeclarePorts(Ports::Timed)));
                known.ports_timed = true;
            }
            if mode == "sim" {
                plant = Some(PlantAction::Load(*pressure_ratio));
            }
            if rotation != known.rotation {
                items.push(Outgoing::Command(Command::SetRotation { rotation }));
                known.rotation = rotation;
            }
            items.push(Outgoing::Command(Command::Start {
                peak_speed_mps: opts.peak_speed_mps() as f32,
            }));
            Ok(Sends { items, plant })
        }
        Control::Telemetry { rate_hz, channels } => {
            let per_s = CYCLES_PER_S as f64;
            let decimation = per_s / rate_hz;
            if !(rate_hz.is_finite()
                && *rate_hz >= 1.0
                && decimation.fract() == 0.0
                && decimation <= f64::from(fpc::link::telemetry::MAX_DECIMATION))
            {
                return Err(format!(
                    "telemetry rate {rate_hz} Hz: give {per_s} Hz divided by a whole number \
                     (20000, 10000, 5000, 4000, 2000, 1000, …)"
                ));
            }
            let channels = parse_channels(channels)?;
            one(Outgoing::Request(LinkRequest::SetTelemetry {
                decimation: decimation as u16,
                channels,
            }))
        }
        Control::ScopeArm { trigger, pre } => {
            let trigger = parse_trigger(trigger)?;
            one(Outgoing::Request(LinkRequest::ScopeArm {
                trigger,
                pre: *pre,
            }))
        }
        Control::ScopeFire => one(Outgoing::Request(LinkRequest::ScopeFire)),
        Control::Record { .. } => Ok(Sends {
            items: Vec::new(),
            plant: None,
        }),
    }
}

/// A scope trigger as typed: `command`, `fault`, `mode-change` or `strokes:N`.
fn parse_trigger(text: &str) -> Result<fpc::link::scope::Trigger, String> {
    use fpc::link::scope::Trigger;
    match text.trim() {
        "command" => Ok(Trigger::Command),
        "fault" => Ok(Trigger::Fault),
        "mode-change" => Ok(Trigger::ModeChange),
        t => match t.strip_prefix("strokes:").map(str::parse::<u16>) {
            Some(Ok(n)) if n >= 1 => Ok(Trigger::Strokes(n)),
            _ => Err(format!(
                "trigger {}: give command, fault, mode-change or strokes:N (N from 1)",
                crate::output::clip(t, 40)
            )),
        },
    }
}

/// Board time, s, from the firmware's wrapping µs stamps: continuous, from the first frame.
#[derive(Clone, Copy, Debug, Default)]
struct Clock {
    last_us: Option<u32>,
    elapsed_us: u64,
    /// Added to every time (the replay's earlier loops), s.
    offset_s: f64,
}

impl Clock {
    fn time_s(&mut self, t_us: u32) -> f64 {
        if let Some(last) = self.last_us {
            self.elapsed_us += u64::from(t_us.wrapping_sub(last));
        }
        self.last_us = Some(t_us);
        self.offset_s + self.elapsed_us as f64 * 1e-6
    }

    /// The next frame starts a new pass `gap_s` after the last (a replay from its start).
    fn restart(&mut self, gap_s: f64) {
        self.offset_s += self.elapsed_us as f64 * 1e-6 + gap_s;
        self.last_us = None;
        self.elapsed_us = 0;
    }
}

/// A recording in progress: the raw channels into a staged capture directory.
struct Recorder {
    out: OutDir,
    dir: PathBuf,
    files: [io::BufWriter<std::fs::File>; 3],
}

impl Recorder {
    /// A recording into the first free `root/rec-N`.
    fn start(root: &Path) -> Result<Recorder, String> {
        let dir = (1..)
            .map(|n| root.join(format!("rec-{n}")))
            .find(|d| d.symlink_metadata().is_err())
            .unwrap_or_else(|| root.join("rec"));
        let names = ["up0.bin", "up1.bin", "up2.bin"];
        let out = OutDir::prepare(&dir, &names, false, &[]).map_err(|f| f.message)?;
        let open = |name: &str| {
            std::fs::File::create(out.path(name))
                .map(io::BufWriter::new)
                .map_err(|e| format!("cannot write {}: {e}", show(&out.path(name))))
        };
        let files = [open(names[0])?, open(names[1])?, open(names[2])?];
        Ok(Recorder { out, dir, files })
    }

    fn write(&mut self, channel: usize, bytes: &[u8]) -> io::Result<()> {
        match self.files.get_mut(channel) {
            Some(f) => f.write_all(bytes),
            None => Ok(()),
        }
    }

    /// Ends the recording: the run log and the scope recordings decoded beside the raw
    /// channels, the directory moved into place. Returns what it wrote, in words.
    fn finish(self) -> Result<String, String> {
        let Recorder { out, dir, files } = self;
        for f in files {
            f.into_inner()
                .map_err(|e| format!("cannot write {}: {e}", show(&dir)))?;
        }
        let up1 = std::fs::read(out.path("up1.bin"))
            .map_err(|e| format!("cannot read the recording back: {e}"))?;
        let log = match crate::board::capture::decode_capture(&up1, |_| {}) {
            Ok(d) => {
                d.log
                    .write(&out.path("run.csv"))
                    .map_err(|e| format!("cannot write run.csv: {e}"))?;
                format!("run.csv ({} rows)", d.log.len())
            }
            Err(e) => format!("no run.csv ({e})"),
        };
        let up2 = std::fs::read(out.path("up2.bin")).unwrap_or_default();
        let (scopes, _) = crate::link::scope::decode_scope_capture(&up2);
        for rec in &scopes {
            if let Ok(log) = rec.to_log() {
                let name = format!("scope-{}.csv", rec.recording.id);
                log.write(&out.path(&name))
                    .map_err(|e| format!("cannot write {name}: {e}"))?;
            }
        }
        out.commit().map_err(|f| f.message)?;
        Ok(format!(
            "recorded to {}: up0.bin, up1.bin, up2.bin, {log}{}",
            show(&dir),
            match scopes.len() {
                0 => String::new(),
                n => format!(", {n} scope recording(s)"),
            }
        ))
    }
}

/// The console's side of the link: decodes what the channels carry, batches it for the
/// page, keeps the raw bytes when recording.
struct Host {
    messages: broadcast::Sender<Arc<str>>,
    out: PathBuf,
    decoder: TelemetryDecoder,
    answers: AnswerReader,
    /// Scope recordings already shown.
    scopes_shown: usize,
    clock: Clock,
    batch: Batch,
    /// The last frame's sequence number and the step before it (the decimation).
    seq: Option<(u16, Option<u16>)>,
    sent_at: Instant,
    last_frame_at: Instant,
    down: VecDeque<u8>,
    recorder: Option<Recorder>,
}

impl Host {
    fn new(messages: broadcast::Sender<Arc<str>>, out: PathBuf) -> Host {
        let now = Instant::now();
        Host {
            messages,
            out,
            decoder: TelemetryDecoder::new(),
            answers: AnswerReader::new(),
            scopes_shown: 0,
            clock: Clock::default(),
            batch: Batch {
                mode: "—".into(),
                ports: "—".into(),
                ..Batch::default()
            },
            seq: None,
            sent_at: now,
            last_frame_at: now,
            down: VecDeque::new(),
            recorder: None,
        }
    }

    fn send(&self, message: &Message) {
        if let Ok(text) = serde_json::to_string(message) {
            // No page connected is no error.
            let _ = self.messages.send(text.into());
        }
    }

    fn log(&self, text: &str, level: &str) {
        self.send(&Message::Log {
            text: text.to_string(),
            level: level.to_string(),
        });
    }

    /// Queues the frames of `sends` for the down-channel and logs what goes.
    fn queue(&mut self, sends: &[Outgoing]) {
        for s in sends {
            self.down.extend(s.wire());
        }
    }

    /// Starts or ends recording.
    fn record(&mut self, on: bool) {
        match (on, self.recorder.take()) {
            (true, None) => match Recorder::start(&self.out) {
                Ok(r) => {
                    self.send(&Message::Recording {
                        on: true,
                        dir: show(&r.dir),
                    });
                    self.log(&format!("recording to {}", show(&r.dir)), "info");
                    self.recorder = Some(r);
                }
                Err(e) => self.log(&format!("cannot record: {e}"), "refused"),
            },
            (false, Some(r)) => {
                let dir = show(&r.dir);
                match r.finish() {
                    Ok(text) => self.log(&text, "ok"),
                    Err(e) => self.log(&format!("the recording failed: {e}"), "refused"),
                }
                self.send(&Message::Recording { on: false, dir });
            }
            (_, r) => self.recorder = r,
        }
    }

    /// Keeps the raw bytes of a channel when recording.
    fn keep(&mut self, channel: usize, bytes: &[u8]) {
        if let Some(r) = &mut self.recorder {
            if let Err(e) = r.write(channel, bytes) {
                self.recorder = None;
                self.log(&format!("the recording stopped: {e}"), "refused");
            }
        }
    }

    /// Telemetry bytes: each frame decoded goes to `frame`.
    fn telemetry(&mut self, bytes: &[u8], mut frame: impl FnMut(&mut Host, Frame)) {
        self.keep(UP_TELEMETRY, bytes);
        for &b in bytes {
            if let Some(Ok(f)) = self.decoder.push(b) {
                frame(self, f);
            }
        }
    }

    /// A frame for the page now.
    fn show_frame(&mut self, f: &Frame, t_s: f64) {
        if let Some((last, step)) = self.seq {
            let s = f.seq.wrapping_sub(last);
            match step {
                Some(d) if d > 0 && s > d && s % d == 0 => {
                    self.batch.gaps += u64::from(s / d - 1);
                }
                _ => {}
            }
            self.seq = Some((f.seq, Some(s).filter(|&s| s > 0)));
        } else {
            self.seq = Some((f.seq, None));
        }
        let b = &mut self.batch;
        b.t.push(t_s);
        b.x.push(f.x_m * 1e3);
        if f.channels.has(7) {
            b.x_ref.push(f.x_ref_m * 1e3);
        }
        b.f_master.push(f.f_master_n);
        b.f_slave.push(f.f_slave_n);
        b.p_a.push(f.p_a_pa * 1e-3);
        b.p_b.push(f.p_b_pa * 1e-3);
        b.theta
            .push(f.theta_rad.rem_euclid(std::f32::consts::TAU).to_degrees());
        b.mode = f.mode.name().to_string();
        b.homed = f.homed;
        b.fault = (f.fault != 0).then(|| {
            Fault::from_code(f.fault)
                .map_or_else(|| format!("fault {}", f.fault), |x| x.name().to_string())
        });
        b.ports = f.ports.name().to_string();
        b.dropped = f.dropped;
        b.frames += 1;
        self.last_frame_at = Instant::now();
    }

    /// Answers on up 2: each logged; scope recordings received whole are shown.
    fn replies(&mut self, bytes: &[u8]) {
        self.keep(UP_REPLIES, bytes);
        for a in self.answers.push(bytes) {
            match a {
                Ok(answer) => self.answer(&answer),
                Err(e) => self.log(
                    &format!(
                        "reply frame rejected: {}",
                        crate::link::session::frame_error_text(e)
                    ),
                    "refused",
                ),
            }
        }
        let recordings: Vec<ScopeRecording> = self
            .answers
            .scope()
            .recordings()
            .get(self.scopes_shown..)
            .unwrap_or_default()
            .to_vec();
        for rec in recordings {
            self.scopes_shown += 1;
            self.scope(&rec);
        }
    }

    fn answer(&self, answer: &Answer) {
        let text = answer_text(answer);
        let level = if text.starts_with("accepted") {
            "ok"
        } else {
            "refused"
        };
        self.log(&text, level);
    }

    fn scope(&self, rec: &ScopeRecording) {
        let log = match rec.to_log() {
            Ok(log) => log,
            Err(e) => return self.log(&format!("scope: {e}"), "refused"),
        };
        let col = |name: &str, k: f64| -> Vec<f64> {
            log.column(name)
                .unwrap_or_default()
                .iter()
                .map(|v| v * k)
                .collect()
        };
        let t = log.column("t_s").unwrap_or_default();
        let trigger_at = t
            .get(usize::from(rec.recording.pre))
            .copied()
            .unwrap_or(0.0);
        self.send(&Message::Scope(ScopeTrace {
            id: rec.recording.id,
            trigger: trigger_text(rec.recording.trigger),
            t_ms: t.iter().map(|v| (v - trigger_at) * 1e3).collect(),
            x: col("x_m", 1e3),
            f_master: col("f_master_n", 1.0),
            f_slave: col("f_slave_n", 1.0),
            p_a: col("p_a_pa", 1e-3),
            p_b: col("p_b_pa", 1e-3),
        }));
        self.log(
            &format!(
                "scope recording {} (trigger {}, {} samples at 20 kHz)",
                rec.recording.id,
                trigger_text(rec.recording.trigger),
                rec.recording.samples
            ),
            "ok",
        );
    }

    /// Reads every up-channel once and writes what waits for the down-channel. Returns
    /// the bytes read; an ended recording of up 1 is `Err(UnexpectedEof)`.
    fn poll(&mut self, channels: &mut dyn Channels) -> io::Result<usize> {
        let mut buf = [0u8; READ_BYTES];
        let mut total = 0;
        if !self.down.is_empty() {
            let pending: Vec<u8> = self.down.iter().copied().collect();
            let n = channels.write_down(DOWN_COMMANDS, &pending)?;
            self.down.drain(..n.min(self.down.len()));
        }
        for channel in [UP_DEFMT, UP_TELEMETRY, UP_REPLIES] {
            let n = match channels.read_up(channel, &mut buf) {
                Ok(n) => n,
                Err(e) if is_end(&e) && channel != UP_TELEMETRY => continue,
                Err(e) => return Err(e),
            };
            let bytes = buf.get(..n).unwrap_or_default();
            total += n;
            match channel {
                UP_TELEMETRY => self.telemetry(bytes, |h, f| {
                    let t = h.clock.time_s(f.t.0);
                    h.show_frame(&f, t);
                }),
                UP_REPLIES => self.replies(bytes),
                _ => self.keep(UP_DEFMT, bytes),
            }
        }
        Ok(total)
    }

    /// Sends the batch when it is due.
    fn flush(&mut self, behind_s: f64) {
        if self.sent_at.elapsed() < BATCH_EVERY {
            return;
        }
        self.sent_at = Instant::now();
        self.batch.behind_s = behind_s;
        self.batch.silent_s = self.last_frame_at.elapsed().as_secs_f64();
        self.batch.rejected = u64::from(self.decoder.stats().rejected);
        let next = Batch {
            mode: self.batch.mode.clone(),
            homed: self.batch.homed,
            fault: self.batch.fault.clone(),
            ports: self.batch.ports.clone(),
            dropped: self.batch.dropped,
            frames: self.batch.frames,
            gaps: self.batch.gaps,
            ..Batch::default()
        };
        let batch = std::mem::replace(&mut self.batch, next);
        self.send(&Message::Frames(batch));
    }
}

/// The simulated board in real time.
fn run_sim(
    model: &MachineModel,
    seed: u64,
    host: &mut Host,
    controls: &mpsc::Receiver<Control>,
    stop: &AtomicBool,
) -> Result<(), String> {
    use crate::board::exec::{LinkedBoard, SimShared};
    use crate::board::ram::SimRam;
    use crate::link::rtt::{ControlBlock, Locate, RttChannels};
    let opts = crate::run::RunOptions::reference();
    let mut world = crate::run::world(model, seed, 0, opts.start_position_m);
    world.plant.lines.set_pressure_ratio(opts.pressure_ratio);
    let shared = SimShared::new();
    let mut board = LinkedBoard::boot(
        world,
        crate::run::control_config(model),
        &shared,
        fpc::link::telemetry::DEFAULT_DECIMATION,
    );
    let block = ControlBlock::find(&mut board.world().ram, &Locate::Scan(vec![SimRam::range()]))?;
    // All ten channels at 2 kHz: the position's reference shows too.
    host.queue(&[Outgoing::Request(LinkRequest::SetTelemetry {
        decimation: fpc::link::telemetry::DEFAULT_DECIMATION,
        channels: fpc::link::telemetry::ChannelSet::ALL,
    })]);
    let mut known = Known {
        rotation: Rotation::Compressor,
        ports_timed: false,
    };
    let started = Instant::now();
    let mut cycles: u64 = 0;
    while !stop.load(Ordering::SeqCst) {
        while let Ok(control) = controls.try_recv() {
            if let Control::Record { on } = control {
                host.record(on);
                continue;
            }
            match translate(&control, "sim", Some(model), &mut known) {
                Ok(sends) => {
                    if let Some(PlantAction::Load(pr)) = sends.plant {
                        let mut w = board.world();
                        w.plant.lines.set_pressure_ratio(pr);
                        w.plant.port_mode = crate::plant::chambers::PortMode::Timed;
                    }
                    host.queue(&sends.items);
                }
                Err(e) => host.log(&e, "refused"),
            }
        }
        let due = (started.elapsed().as_secs_f64() * CYCLES_PER_S as f64) as u64;
        let most = cycles + (MOST_STEPPED_S * CYCLES_PER_S as f64) as u64;
        while cycles < due.min(most) {
            board.step();
            cycles += 1;
            if cycles.is_multiple_of(POLL_CYCLES) {
                let mut world = board.world();
                let mut rtt = RttChannels::with_block(&mut world.ram, block.clone());
                host.poll(&mut rtt)
                    .map_err(|e| format!("the simulated board's channels: {e}"))?;
            }
        }
        let behind_s = due.saturating_sub(cycles) as f64 / CYCLES_PER_S as f64;
        host.flush(behind_s);
        if cycles >= due {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    Ok(())
}

/// The board (or any live transport): polled every millisecond.
fn run_board(
    channels: &mut dyn Channels,
    host: &mut Host,
    controls: &mpsc::Receiver<Control>,
    stop: &AtomicBool,
) -> Result<(), String> {
    let mut known = Known {
        rotation: Rotation::Compressor,
        ports_timed: true,
    };
    while !stop.load(Ordering::SeqCst) {
        while let Ok(control) = controls.try_recv() {
            if let Control::Record { on } = control {
                host.record(on);
                continue;
            }
            match translate(&control, "probe", None, &mut known) {
                Ok(sends) => host.queue(&sends.items),
                Err(e) => host.log(&e, "refused"),
            }
        }
        let n = host
            .poll(channels)
            .map_err(|e| format!("link failed: {e}"))?;
        host.flush(0.0);
        if n == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    Ok(())
}

/// The recorded answers of a replay, handed out as the page's controls ask for them.
struct Recorded {
    answers: Vec<Answer>,
    next: usize,
    scopes: Vec<ScopeRecording>,
    next_scope: usize,
}

impl Recorded {
    fn read(bytes: &[u8]) -> Recorded {
        let mut reader = AnswerReader::new();
        let answers = reader
            .push(bytes)
            .into_iter()
            .filter_map(Result::ok)
            .collect();
        Recorded {
            answers,
            next: 0,
            scopes: reader.scope().recordings().to_vec(),
            next_scope: 0,
        }
    }

    /// The recording's answer to `send`, after the ones before it (shown as earlier).
    fn answer(&mut self, send: &Outgoing, host: &Host) {
        let found = self
            .answers
            .get(self.next..)
            .unwrap_or_default()
            .iter()
            .position(|a| send.answered_by(a));
        let Some(i) = found else {
            return host.log(
                &format!(
                    "the recording holds no answer to `{}` (a replay plays what was recorded)",
                    send.text()
                ),
                "refused",
            );
        };
        let upto = self.next + i;
        for a in self.answers.get(self.next..upto).unwrap_or_default() {
            host.log(&format!("earlier answer: {}", answer_text(a)), "info");
        }
        if let Some(a) = self.answers.get(upto) {
            host.answer(a);
        }
        self.next = upto + 1;
        if matches!(
            send,
            Outgoing::Request(LinkRequest::ScopeArm { .. } | LinkRequest::ScopeFire)
        ) {
            if let Some(rec) = self.scopes.get(self.next_scope) {
                self.next_scope += 1;
                host.scope(rec);
            }
        }
    }
}

/// A recorded session, played at the pace its frames were sent, again from the start when
/// it ends.
fn run_replay(
    dir: &Path,
    host: &mut Host,
    controls: &mpsc::Receiver<Control>,
    stop: &AtomicBool,
) -> Result<(), String> {
    let recording = Replay::from_dir(dir)?;
    // The session plays from its start when the first page connects.
    while host.messages.receiver_count() == 0 {
        if stop.load(Ordering::SeqCst) {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let up2 = std::fs::read(dir.join(crate::link::replay::up_file(UP_REPLIES))).unwrap_or_default();
    let mut recorded = Recorded::read(&up2);
    let mut known = Known {
        rotation: Rotation::Compressor,
        ports_timed: false,
    };
    let mut replay = recording.clone();
    let mut pending: VecDeque<(f64, Frame)> = VecDeque::new();
    let started = Instant::now();
    let mut passes = 1;
    let mut frames_this_pass = 0u64;
    // Stop plays on to the recording's own stop (the first holding after running) and holds
    // there; the next control plays the recording again from its start.
    let mut stop_asked = false;
    let mut ran = false;
    let mut halted: Option<Instant> = None;
    let mut paused_s = 0.0;
    while !stop.load(Ordering::SeqCst) {
        while let Ok(control) = controls.try_recv() {
            match &control {
                Control::Record { on } => host.record(*on),
                Control::Telemetry { .. } => host.log(
                    "a replay plays at the rate it was recorded (the telemetry control is the \
                     board's)",
                    "refused",
                ),
                _ => {
                    if let Some(since) = halted.take() {
                        paused_s += since.elapsed().as_secs_f64();
                        host.clock.restart(1e-3);
                        host.seq = None;
                        replay = recording.clone();
                        pending.clear();
                        recorded.next = 0;
                        recorded.next_scope = 0;
                        known.ports_timed = false;
                        known.rotation = Rotation::Compressor;
                        passes += 1;
                        frames_this_pass = 0;
                        host.log(
                            &format!("the recording plays again (pass {passes})"),
                            "info",
                        );
                    }
                    if control == Control::Stop {
                        stop_asked = true;
                        ran = host.batch.mode == "running";
                    }
                    match translate(&control, "replay", None, &mut known) {
                        Ok(sends) => {
                            for s in &sends.items {
                                recorded.answer(s, host);
                            }
                        }
                        Err(e) => host.log(&e, "refused"),
                    }
                }
            }
        }
        if halted.is_some() {
            // Holding at the recording's stop: the page shows that state, not a silence.
            host.last_frame_at = Instant::now();
            host.flush(0.0);
            std::thread::sleep(Duration::from_millis(1));
            continue;
        }
        let now_s = started.elapsed().as_secs_f64() - paused_s;
        // Read ahead while less than 0.2 s of frames wait.
        while pending.back().is_none_or(|(t, _)| *t < now_s + 0.2) {
            let mut buf = [0u8; READ_BYTES];
            let n = match replay.read_up(UP_TELEMETRY, &mut buf) {
                Ok(n) => n,
                Err(e) if is_end(&e) => {
                    if frames_this_pass == 0 {
                        return Err(format!(
                            "{}: the recording holds no telemetry frame",
                            show(dir)
                        ));
                    }
                    // From the start again, one frame period after the last frame.
                    let period = pending
                        .len()
                        .checked_sub(2)
                        .and_then(|i| pending.get(i).zip(pending.back()))
                        .map_or(5e-4, |(a, b)| (b.0 - a.0).max(1e-6));
                    host.clock.restart(period);
                    host.seq = None;
                    replay = recording.clone();
                    recorded.next = 0;
                    recorded.next_scope = 0;
                    known.ports_timed = false;
                    known.rotation = Rotation::Compressor;
                    passes += 1;
                    frames_this_pass = 0;
                    host.log(
                        &format!("the recording plays again (pass {passes})"),
                        "info",
                    );
                    break;
                }
                Err(e) => return Err(format!("{}: {e}", show(dir))),
            };
            host.telemetry(buf.get(..n).unwrap_or_default(), |h, f| {
                let t = h.clock.time_s(f.t.0);
                pending.push_back((t, f));
                frames_this_pass += 1;
            });
        }
        // The recording's own time starts at its first frame.
        while let Some((t, f)) = pending.front().copied() {
            if t > now_s {
                break;
            }
            pending.pop_front();
            host.show_frame(&f, t);
            if stop_asked {
                ran |= f.mode == fpc::status::ModeKind::Running;
                if ran && f.mode == fpc::status::ModeKind::Holding {
                    stop_asked = false;
                    halted = Some(Instant::now());
                    host.log(
                        "the recording's stop: holding (the replay waits here; a control plays \
                         it again from its start)",
                        "info",
                    );
                    break;
                }
            }
        }
        host.flush(0.0);
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The messages of `feed` until `done` says so (each parsed as JSON), at most
    /// `limit_s` of wall time.
    fn until(
        rx: &mut broadcast::Receiver<Arc<str>>,
        limit_s: f64,
        mut done: impl FnMut(&serde_json::Value) -> bool,
    ) -> Vec<serde_json::Value> {
        let end = Instant::now() + Duration::from_secs_f64(limit_s);
        let mut seen = Vec::new();
        while Instant::now() < end {
            match rx.try_recv() {
                Ok(text) => {
                    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
                    let stop = done(&v);
                    seen.push(v);
                    if stop {
                        return seen;
                    }
                }
                Err(broadcast::error::TryRecvError::Empty) => {
                    std::thread::sleep(Duration::from_millis(5))
                }
                Err(e) => panic!("{e}"),
            }
        }
        let logs: Vec<&serde_json::Value> = seen.iter().filter(|m| m["type"] == "log").collect();
        panic!("not within {limit_s} s; the log: {logs:?}");
    }

    fn sim() -> Source {
        Source::Sim {
            model: Box::new(MachineModel::reference()),
            model_name: "reference".into(),
            seed: 1,
        }
    }

    /// The simulated board in real time, through its RAM: Home is answered, the frames
    /// show it homing and then holding homed, with the reference streamed; a recording
    /// writes the capture and its run log.
    #[test]
    fn the_simulated_board_homes_streams_and_records() {
        let out = tempfile::tempdir().unwrap();
        let feed = Feed::start(sim(), out.path().to_path_buf());
        let mut rx = feed.messages.subscribe();
        feed.controls.send(Control::Home).unwrap();
        feed.controls.send(Control::Record { on: true }).unwrap();
        until(&mut rx, 20.0, |m| {
            m["type"] == "log" && m["text"] == "accepted: home"
        });
        let seen = until(&mut rx, 30.0, |m| {
            m["type"] == "frames" && m["mode"] == "holding" && m["homed"] == true
        });
        let batch = seen.iter().rev().find(|m| m["type"] == "frames").unwrap();
        let n = batch["t"].as_array().unwrap().len();
        assert!(
            n > 0 && batch["x_ref"].as_array().unwrap().len() == n,
            "{batch}"
        );
        feed.controls.send(Control::Record { on: false }).unwrap();
        until(&mut rx, 20.0, |m| {
            m["type"] == "log" && m["text"].as_str().unwrap().starts_with("recorded to")
        });
        feed.finish().unwrap();
        let rec = out.path().join("rec-1");
        let log = crate::runlog::RunLog::read(&rec.join("run.csv")).unwrap();
        assert!(log.len() >= 100, "{} rows", log.len());
        assert!(rec.join("up1.bin").is_file() && rec.join("up2.bin").is_file());
    }

    /// The simulated board behind a stand-in for the probe: its firmware runs on in wall-clock
    /// time whether or not anyone looks, and each access through the probe's interface
    /// ([`TargetMemory`]) first lets it catch up — what a probe reading a running board's
    /// RAM sees. The rig's lines are the rig's: the discharge at pressure ratio 3.1 and the
    /// ports timed from the start, since the console does not touch them on a board.
    struct RunningBoard {
        board: crate::board::exec::LinkedBoard<'static>,
        started: Instant,
        cycles: u64,
    }

    impl RunningBoard {
        fn boot() -> RunningBoard {
            let model = MachineModel::reference();
            let opts = crate::run::RunOptions::reference();
            let mut world = crate::run::world(&model, 3, 0, opts.start_position_m);
            world.plant.lines.set_pressure_ratio(3.1);
            world.plant.port_mode = crate::plant::chambers::PortMode::Timed;
            // The board's shared state lives as long as the board (the test's whole run).
            let shared = Box::leak(Box::new(crate::board::exec::SimShared::new()));
            let board = crate::board::exec::LinkedBoard::boot(
                world,
                crate::run::control_config(&model),
                shared,
                fpc::link::telemetry::DEFAULT_DECIMATION,
            );
            RunningBoard {
                board,
                started: Instant::now(),
                cycles: 0,
            }
        }

        fn catch_up(&mut self) {
            let due = (self.started.elapsed().as_secs_f64() * CYCLES_PER_S as f64) as u64;
            while self.cycles < due {
                self.board.step();
                self.cycles += 1;
            }
        }
    }

    impl crate::link::memory::TargetMemory for RunningBoard {
        fn read(&mut self, address: u64, buf: &mut [u8]) -> io::Result<()> {
            self.catch_up();
            crate::link::memory::TargetMemory::read(&mut self.board.world().ram, address, buf)
        }

        fn write(&mut self, address: u64, bytes: &[u8]) -> io::Result<()> {
            self.catch_up();
            crate::link::memory::TargetMemory::write(&mut self.board.world().ram, address, bytes)
        }
    }

    /// `--probe`'s path with the probe's transport over the stand-in: the RTT block found by
    /// scanning RAM, as [`crate::link::probe::attach`] does without an ELF.
    fn stand_in_probe() -> Source {
        Source::Probe(LiveLink {
            what: "simulated board through the probe's transport".into(),
            open: Box::new(|| {
                let locate =
                    crate::link::rtt::Locate::Scan(vec![crate::board::ram::SimRam::range()]);
                crate::link::rtt::RttChannels::attach(RunningBoard::boot(), &locate)
                    .map(|c| Box::new(c) as Box<dyn Channels>)
            }),
        })
    }

    /// The console's board path over the probe's interface: Home, then Start at pressure
    /// ratio 3.1 strokes the piston over ≥ 150 mm and reads `running`, and Stop brings it
    /// to `holding` — the same controls, frames and answers a board behind a probe gives.
    #[test]
    fn the_board_path_runs_the_console_over_the_probes_transport() {
        let out = tempfile::tempdir().unwrap();
        let source = stand_in_probe();
        assert_eq!(source.mode(), "probe");
        let feed = Feed::start(source, out.path().to_path_buf());
        let mut rx = feed.messages.subscribe();
        feed.controls.send(Control::Home).unwrap();
        until(&mut rx, 30.0, |m| {
            m["type"] == "log" && m["text"] == "accepted: home"
        });
        until(&mut rx, 30.0, |m| {
            m["type"] == "frames" && m["mode"] == "holding" && m["homed"] == true
        });
        feed.controls
            .send(Control::Start {
                pressure_ratio: 3.1,
                speed_mps: None,
                rotation: "compressor".into(),
            })
            .unwrap();
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        until(&mut rx, 30.0, |m| {
            if m["type"] == "frames" && m["mode"] == "running" {
                for x in m["x"].as_array().unwrap() {
                    let x = x.as_f64().unwrap();
                    (lo, hi) = (lo.min(x), hi.max(x));
                }
            }
            hi - lo >= 0.150
        });
        feed.controls.send(Control::Stop).unwrap();
        until(&mut rx, 30.0, |m| {
            m["type"] == "frames" && m["mode"] == "holding"
        });
        feed.finish().unwrap();
        // Nothing recorded, nothing written.
        assert_eq!(std::fs::read_dir(out.path()).unwrap().count(), 0);
    }

    /// A live link that cannot be opened ends the link thread with its error, said on the
    /// page.
    #[test]
    fn a_live_link_that_does_not_open_ends_with_its_error() {
        let out = tempfile::tempdir().unwrap();
        let feed = Feed::start(
            Source::Probe(LiveLink {
                what: "nothing".into(),
                open: Box::new(|| Err("no debug probe found".into())),
            }),
            out.path().to_path_buf(),
        );
        let mut rx = feed.messages.subscribe();
        let end = Instant::now() + Duration::from_secs(10);
        while !feed.ended() && Instant::now() < end {
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(feed.finish(), Err("no debug probe found".to_string()));
        let _ = rx.try_recv();
        assert_eq!(std::fs::read_dir(out.path()).unwrap().count(), 0);
    }

    /// A replay answers the controls from its recording, the answers before shown as
    /// earlier ones, and plays its frames.
    #[test]
    fn a_replay_answers_from_its_recording() {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/examples/bench-session");
        let out = tempfile::tempdir().unwrap();
        let feed = Feed::start(Source::Replay { dir }, out.path().to_path_buf());
        let mut rx = feed.messages.subscribe();
        feed.controls.send(Control::Home).unwrap();
        let seen = until(&mut rx, 10.0, |m| m["text"] == "accepted: home");
        assert!(
            seen.iter()
                .any(|m| m["text"] == "earlier answer: accepted: ports bypassed"),
            "{seen:?}"
        );
        feed.controls
            .send(Control::Telemetry {
                rate_hz: 5000.0,
                channels: "all".into(),
            })
            .unwrap();
        until(&mut rx, 10.0, |m| {
            m["level"] == "refused" && m["text"].as_str().unwrap().contains("recorded")
        });
        until(&mut rx, 10.0, |m| {
            m["type"] == "frames" && m["mode"] == "running"
        });
        // Stop: on to the recording's stop, then holding, and no frame after it.
        feed.controls.send(Control::Stop).unwrap();
        until(&mut rx, 10.0, |m| {
            m["type"] == "log"
                && m["text"]
                    .as_str()
                    .unwrap()
                    .starts_with("the recording's stop")
        });
        std::thread::sleep(Duration::from_millis(500));
        let mut frames = Vec::new();
        while let Ok(text) = rx.try_recv() {
            let m: serde_json::Value = serde_json::from_str(&text).unwrap();
            if m["type"] == "frames" {
                frames.push(m);
            }
        }
        // The batch with the holding frame itself may come after the line; none after it.
        assert!(frames.len() > 3, "{frames:?}");
        assert!(frames.iter().all(|m| m["mode"] == "holding"), "{frames:?}");
        assert!(
            frames
                .iter()
                .skip(1)
                .all(|m| m["t"].as_array().unwrap().is_empty()),
            "{frames:?}"
        );
        feed.finish().unwrap();
    }

    #[test]
    fn the_clock_unrolls_the_microsecond_wrap_and_replay_passes() {
        let mut c = Clock::default();
        assert_eq!(c.time_s(u32::MAX - 499), 0.0);
        assert!((c.time_s(500) - 1e-3).abs() < 1e-12);
        c.restart(5e-4);
        assert!((c.time_s(123) - 1.5e-3).abs() < 1e-12);
    }

    #[test]
    fn start_closes_the_bypass_once_and_sets_the_rotation_only_when_it_changes() {
        let mut known = Known {
            rotation: Rotation::Compressor,
            ports_timed: false,
        };
        let start = |rotation: &str| Control::Start {
            pressure_ratio: 3.1,
            speed_mps: None,
            rotation: rotation.into(),
        };
        let s = translate(&start("compressor"), "sim", None, &mut known).unwrap();
        assert_eq!(s.plant, Some(PlantAction::Load(3.1)));
        assert_eq!(
            s.items,
            vec![
                Outgoing::Request(LinkRequest::DeclarePorts(Ports::Timed)),
                Outgoing::Command(Command::Start {
                    peak_speed_mps: 2.3
                })
            ]
        );
        let s = translate(&start("expander"), "sim", None, &mut known).unwrap();
        assert_eq!(
            s.items.first(),
            Some(&Outgoing::Command(Command::SetRotation {
                rotation: Rotation::Expander
            }))
        );
        assert_eq!(s.items.len(), 2);
        let e = translate(
            &Control::Start {
                pressure_ratio: 9.0,
                speed_mps: None,
                rotation: "compressor".into(),
            },
            "sim",
            None,
            &mut known,
        );
        assert!(e.is_err_and(|e| e.contains("--pressure-ratio 9")));
        let e = translate(
            &Control::Telemetry {
                rate_hz: 3000.0,
                channels: "all".into(),
            },
            "sim",
            None,
            &mut known,
        );
        assert!(e.is_err_and(|e| e.contains("whole number")));
    }
}
