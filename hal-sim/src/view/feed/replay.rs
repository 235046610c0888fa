//! A recorded session as the console's source: its frames played at the pace they were
//! sent, again from the start when it ends, the page's controls answered from the recording.
//!
//! Stop plays on to the recording's own stop (the first holding after running) and holds
//! there; the next control plays the recording again from its start.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use fpc::link::commands::Answer;
use fpc::link::settings::LinkRequest;
use fpc::link::telemetry::Frame;
use fpc::motion::synchroniser::Rotation;
use fpc::status::ModeKind;

use super::host::Host;
use super::translate::{translate, Known, Outgoing};
use super::READ_BYTES;
use crate::link::scope::ScopeRecording;
use crate::link::session::{answer_text, AnswerReader};
use crate::link::{is_end, Channels, Replay, UP_REPLIES, UP_TELEMETRY};
use crate::output::show;
use crate::view::protocol::Control;

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
pub(super) fn run_replay(
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
    let mut player = Player::new(dir, recording, Recorded::read(&up2));
    let started = Instant::now();
    while !stop.load(Ordering::SeqCst) {
        while let Ok(control) = controls.try_recv() {
            player.control(host, &control);
        }
        if player.halted.is_some() {
            // Holding at the recording's stop: the page shows that state, not a silence.
            host.last_frame_at = Instant::now();
            host.flush(0.0);
            std::thread::sleep(Duration::from_millis(1));
            continue;
        }
        let now_s = started.elapsed().as_secs_f64() - player.paused_s;
        player.read_ahead(host, now_s)?;
        player.play_due(host, now_s);
        host.flush(0.0);
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(())
}

/// A replay in progress: the recording's frames read ahead of the wall clock, its answers,
/// and where the pass stands.
struct Player<'d> {
    dir: &'d Path,
    /// The recording as opened, to play again from its start.
    recording: Replay,
    /// The pass being read.
    replay: Replay,
    recorded: Recorded,
    known: Known,
    /// Frames read and not yet shown, with their board time, s.
    pending: VecDeque<(f64, Frame)>,
    /// Passes begun (the first is 1).
    passes: u32,
    frames_this_pass: u64,
    /// Stop was asked: play on to the recording's own stop.
    stop_asked: bool,
    /// The recording ran since the stop was asked (or was running then).
    ran: bool,
    /// Holding at the recording's stop since then.
    halted: Option<Instant>,
    /// Wall time spent holding, s (the clock of the frames stands still meanwhile).
    paused_s: f64,
}

impl<'d> Player<'d> {
    fn new(dir: &'d Path, recording: Replay, recorded: Recorded) -> Self {
        Player {
            dir,
            replay: recording.clone(),
            recording,
            recorded,
            known: Known {
                rotation: Rotation::Compressor,
                ports_timed: false,
            },
            pending: VecDeque::new(),
            passes: 1,
            frames_this_pass: 0,
            stop_asked: false,
            ran: false,
            halted: None,
            paused_s: 0.0,
        }
    }

    /// A page control: recording is the console's; the telemetry control is refused; any
    /// other plays the recording again if it is holding at its stop, and is answered from
    /// the recording.
    fn control(&mut self, host: &mut Host, control: &Control) {
        match control {
            Control::Record { on } => host.record(*on),
            Control::Telemetry { .. } => host.log(
                "a replay plays at the rate it was recorded (the telemetry control is the \
                 board's)",
                "refused",
            ),
            _ => {
                if let Some(since) = self.halted.take() {
                    self.paused_s += since.elapsed().as_secs_f64();
                    self.pending.clear();
                    self.play_again(host, 1e-3);
                }
                if *control == Control::Stop {
                    self.stop_asked = true;
                    self.ran = host.batch.mode == "running";
                }
                match translate(control, "replay", None, &mut self.known) {
                    Ok(sends) => {
                        for s in &sends.items {
                            self.recorded.answer(s, host);
                        }
                    }
                    Err(e) => host.log(&e, "refused"),
                }
            }
        }
    }

    /// Begins the next pass from the recording's start, its first frame `gap_s` after the
    /// last one shown; what the console knew of the machine is forgotten.
    fn play_again(&mut self, host: &mut Host, gap_s: f64) {
        host.clock.restart(gap_s);
        host.seq = None;
        self.replay = self.recording.clone();
        self.recorded.next = 0;
        self.recorded.next_scope = 0;
        self.known.ports_timed = false;
        self.known.rotation = Rotation::Compressor;
        self.passes += 1;
        self.frames_this_pass = 0;
        host.log(
            &format!("the recording plays again (pass {})", self.passes),
            "info",
        );
    }

    /// Reads frames until 0.2 s past `now_s` wait (or the recording ends: the next pass
    /// then starts one frame period after its last frame). A recording without a frame is
    /// an error.
    fn read_ahead(&mut self, host: &mut Host, now_s: f64) -> Result<(), String> {
        while self.pending.back().is_none_or(|(t, _)| *t < now_s + 0.2) {
            let mut buf = [0u8; READ_BYTES];
            let n = match self.replay.read_up(UP_TELEMETRY, &mut buf) {
                Ok(n) => n,
                Err(e) if is_end(&e) => {
                    if self.frames_this_pass == 0 {
                        return Err(format!(
                            "{}: the recording holds no telemetry frame",
                            show(self.dir)
                        ));
                    }
                    let pending = &self.pending;
                    let period = pending
                        .len()
                        .checked_sub(2)
                        .and_then(|i| pending.get(i).zip(pending.back()))
                        .map_or(5e-4, |(a, b)| (b.0 - a.0).max(1e-6));
                    self.play_again(host, period);
                    break;
                }
                Err(e) => return Err(format!("{}: {e}", show(self.dir))),
            };
            let (pending, frames) = (&mut self.pending, &mut self.frames_this_pass);
            host.telemetry(buf.get(..n).unwrap_or_default(), |h, f| {
                let t = h.clock.time_s(f.t.0);
                pending.push_back((t, f));
                *frames += 1;
            });
        }
        Ok(())
    }

    /// Shows the frames due by `now_s` (the recording's own time starts at its first
    /// frame); after a stop was asked, halts at the first holding after running.
    fn play_due(&mut self, host: &mut Host, now_s: f64) {
        while let Some((t, f)) = self.pending.front().copied() {
            if t > now_s {
                break;
            }
            self.pending.pop_front();
            host.show_frame(&f, t);
            if self.stop_asked {
                self.ran |= f.mode == ModeKind::Running;
                if self.ran && f.mode == ModeKind::Holding {
                    self.stop_asked = false;
                    self.halted = Some(Instant::now());
                    host.log(
                        "the recording's stop: holding (the replay waits here; a control plays \
                         it again from its start)",
                        "info",
                    );
                    break;
                }
            }
        }
    }
}
