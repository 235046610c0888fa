//! The console's side of the link: the board's clock, the recording of the raw channels,
//! and the host that decodes what the channels carry and batches it for the page.

use std::collections::VecDeque;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use fpc::link::commands::Answer;
use fpc::link::telemetry::{Frame, TelemetryDecoder};
use fpc::safety::faults::Fault;
use tokio::sync::broadcast;

use super::translate::Outgoing;
use super::{BATCH_EVERY, READ_BYTES};
use crate::link::scope::{trigger_text, ScopeRecording};
use crate::link::session::{answer_text, AnswerReader};
use crate::link::{is_end, Channels, DOWN_COMMANDS, UP_DEFMT, UP_REPLIES, UP_TELEMETRY};
use crate::output::{show, OutDir};
use crate::view::protocol::{Batch, Message, ScopeTrace};

/// Board time, s, from the firmware's wrapping µs stamps: continuous, from the first frame.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Clock {
    last_us: Option<u32>,
    elapsed_us: u64,
    /// Added to every time (the replay's earlier loops), s.
    offset_s: f64,
}

impl Clock {
    pub(super) fn time_s(&mut self, t_us: u32) -> f64 {
        if let Some(last) = self.last_us {
            self.elapsed_us += u64::from(t_us.wrapping_sub(last));
        }
        self.last_us = Some(t_us);
        self.offset_s + self.elapsed_us as f64 * 1e-6
    }

    /// The next frame starts a new pass `gap_s` after the last (a replay from its start).
    pub(super) fn restart(&mut self, gap_s: f64) {
        self.offset_s += self.elapsed_us as f64 * 1e-6 + gap_s;
        self.last_us = None;
        self.elapsed_us = 0;
    }
}

/// A recording in progress: the raw channels into a staged capture directory.
pub(super) struct Recorder {
    out: OutDir,
    dir: PathBuf,
    files: [io::BufWriter<std::fs::File>; 3],
}

impl Recorder {
    /// A recording into the first free `root/rec-N`.
    pub(super) fn start(root: &Path) -> Result<Recorder, String> {
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

    pub(super) fn write(&mut self, channel: usize, bytes: &[u8]) -> io::Result<()> {
        match self.files.get_mut(channel) {
            Some(f) => f.write_all(bytes),
            None => Ok(()),
        }
    }

    /// Ends the recording: the run log and the scope recordings decoded beside the raw
    /// channels, the directory moved into place. Returns what it wrote, in words.
    pub(super) fn finish(self) -> Result<String, String> {
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
pub(super) struct Host {
    pub(super) messages: broadcast::Sender<Arc<str>>,
    out: PathBuf,
    decoder: TelemetryDecoder,
    answers: AnswerReader,
    /// Scope recordings already shown.
    scopes_shown: usize,
    pub(super) clock: Clock,
    pub(super) batch: Batch,
    /// The last frame's sequence number and the step before it (the decimation).
    pub(super) seq: Option<(u16, Option<u16>)>,
    sent_at: Instant,
    pub(super) last_frame_at: Instant,
    down: VecDeque<u8>,
    recorder: Option<Recorder>,
}

impl Host {
    pub(super) fn new(messages: broadcast::Sender<Arc<str>>, out: PathBuf) -> Host {
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

    pub(super) fn send(&self, message: &Message) {
        if let Ok(text) = serde_json::to_string(message) {
            // No page connected is no error.
            let _ = self.messages.send(text.into());
        }
    }

    pub(super) fn log(&self, text: &str, level: &str) {
        self.send(&Message::Log {
            text: text.to_string(),
            level: level.to_string(),
        });
    }

    /// Queues the frames of `sends` for the down-channel and logs what goes.
    pub(super) fn queue(&mut self, sends: &[Outgoing]) {
        for s in sends {
            self.down.extend(s.wire());
        }
    }

    /// Starts or ends recording.
    pub(super) fn record(&mut self, on: bool) {
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
    pub(super) fn keep(&mut self, channel: usize, bytes: &[u8]) {
        if let Some(r) = &mut self.recorder {
            if let Err(e) = r.write(channel, bytes) {
                self.recorder = None;
                self.log(&format!("the recording stopped: {e}"), "refused");
            }
        }
    }

    /// Telemetry bytes: each frame decoded goes to `frame`.
    pub(super) fn telemetry(&mut self, bytes: &[u8], mut frame: impl FnMut(&mut Host, Frame)) {
        self.keep(UP_TELEMETRY, bytes);
        for &b in bytes {
            if let Some(Ok(f)) = self.decoder.push(b) {
                frame(self, f);
            }
        }
    }

    /// A frame for the page now.
    pub(super) fn show_frame(&mut self, f: &Frame, t_s: f64) {
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
        b.absent = f.absent.iter().map(|p| p.name().to_string()).collect();
        b.ports = f.ports.name().to_string();
        b.dropped = f.dropped;
        b.frames += 1;
        self.last_frame_at = Instant::now();
    }

    /// Answers on up 2: each logged; scope recordings received whole are shown.
    pub(super) fn replies(&mut self, bytes: &[u8]) {
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

    pub(super) fn answer(&self, answer: &Answer) {
        let text = answer_text(answer);
        let level = if text.starts_with("accepted") {
            "ok"
        } else {
            "refused"
        };
        self.log(&text, level);
    }

    pub(super) fn scope(&self, rec: &ScopeRecording) {
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
    pub(super) fn poll(&mut self, channels: &mut dyn Channels) -> io::Result<usize> {
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
    pub(super) fn flush(&mut self, behind_s: f64) {
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
            absent: self.batch.absent.clone(),
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
