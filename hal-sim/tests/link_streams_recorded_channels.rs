//! The host link (`fpc-sim link`) on recorded channel contents: telemetry that the
//! simulator's firmware task wrote (decimation 1 and 20) gives through the replay transport
//! the same capture and run log as `fpc-sim decode`; garbage and truncated streams are
//! counted and never crash; and a command goes out as the library encodes it, through the
//! firmware's own command task and controller, and its reply comes back as text.

use std::future::Future;
use std::path::Path;
use std::pin::Pin;
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use fpc::control::calibration::record::CalibrationRecord;
use fpc::control::command::{Command, Refusal, Reply};
use fpc::control::config::ControlConfig;
use fpc::control::step::ControlStep;
use fpc::link::frame::DELIMITER;
use fpc::link::telemetry::{Frame, WIRE_BYTES};
use fpc::shared::Shared;
use fpc::status::{ModeKind, Status};
use fpc::units::Ticks;
use hal_sim::board::loopback::{ByteQueue, ByteSink, SteppedClock};
use hal_sim::link::defmt::DefmtLog;
use hal_sim::link::session::{
    outcome_text, read_calibration, send_command, write_calibration, CaptureSession, Outcome,
};
use hal_sim::link::{Channels, Replay};
use hal_sim::run::{run, RunOptions};
use tempfile::TempDir;

/// A scratch directory, removed with everything in it when the returned guard drops.
fn temp(name: &str) -> TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc-link-{name}-"))
        .tempdir()
        .unwrap()
}

/// Runs `fpc-sim` in-process; returns the exit code and what it printed.
fn fpc_sim(args: &[&dyn AsRef<std::ffi::OsStr>]) -> (u8, String) {
    let mut argv: Vec<std::ffi::OsString> = vec!["fpc-sim".into()];
    argv.extend(args.iter().map(|a| a.as_ref().to_os_string()));
    hal_sim::console::captured(|| hal_sim::cli::execute(argv))
}

/// `fpc-sim link capture --replay REC --out OUT`: the exit code and what it printed.
fn capture(rec: &Path, out: &Path) -> (u8, String) {
    fpc_sim(&[&"link", &"capture", &"--replay", &rec, &"--out", &out])
}

/// Telemetry bytes of a short simulated run at `decimation`.
fn recorded_telemetry(decimation: u16) -> Vec<u8> {
    let outcome = run(&RunOptions {
        cycles: 2,
        telemetry_decimation: decimation,
        ..RunOptions::reference()
    })
    .unwrap();
    assert!(!outcome.telemetry.is_empty());
    outcome.telemetry
}

/// A recording directory with these up-channels.
fn recording(name: &str, up0: &[u8], up1: &[u8], up2: &[u8]) -> TempDir {
    let dir = temp(name);
    for (i, bytes) in [up0, up1, up2].into_iter().enumerate() {
        std::fs::write(dir.path().join(format!("up{i}.bin")), bytes).unwrap();
    }
    dir
}

/// `link capture --replay` and `decode` on the same recorded bytes give the same files.
fn capture_equals_decode(decimation: u16) {
    let telemetry = recorded_telemetry(decimation);
    let rec = recording(
        &format!("rec{decimation}"),
        &[0x01, 0x02, 0x00],
        &telemetry,
        &[],
    );
    let out_dir = temp(&format!("out{decimation}"));
    let out = out_dir.path().join("cap");
    let (code, text) = capture(rec.path(), &out);
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("rejected 0"), "{text}");
    // Without the ELF (and the `probe` feature) defmt shows as hex, piece by piece.
    assert!(text.contains("defmt (undecoded): 01"), "{text}");
    assert_eq!(std::fs::read(out.join("up1.bin")).unwrap(), telemetry);
    assert_eq!(std::fs::read(out.join("up0.bin")).unwrap(), [1, 2, 0]);
    let decoded = out.with_file_name("decoded.csv");
    let (code, text) = fpc_sim(&[
        &"decode",
        &"--capture",
        &out.join("up1.bin"),
        &"--out",
        &decoded,
    ]);
    assert_eq!(code, 0, "{text}");
    let live = std::fs::read_to_string(out.join("run.csv")).unwrap();
    assert_eq!(live, std::fs::read_to_string(&decoded).unwrap());
    assert!(live.contains(&format!("# telemetry_decimation = {decimation}")));
    let rows = live.lines().filter(|l| !l.starts_with('#')).count() - 1;
    // The run's telemetry carries the firmware's default channels.
    assert_eq!(
        rows,
        telemetry.len() / fpc::link::telemetry::DEFAULT_CHANNELS.wire_bytes()
    );
    // A capture directory is itself a recording.
    let again = out.with_file_name("again");
    let (code, text) = capture(&out, &again);
    assert_eq!(code, 0, "{text}");
    assert_eq!(
        std::fs::read_to_string(again.join("run.csv")).unwrap(),
        live
    );
}

#[test]
fn recorded_telemetry_at_full_rate_gives_decodes_run_log() {
    capture_equals_decode(1);
}

#[test]
fn recorded_telemetry_at_decimation_20_gives_decodes_run_log() {
    capture_equals_decode(20);
}

/// A hand-made stream: `n` frames at decimation 1, the firmware's dropped counter at
/// `dropped` from frame `n / 2` on.
fn frames(n: u32, dropped: u16) -> Vec<Vec<u8>> {
    (0..n)
        .map(|i| {
            let status = Status {
                t: Ticks(1000 + 50 * i),
                mode: ModeKind::Running,
                position_m: i as f32 * 1e-4,
                ..Status::INIT
            };
            let d = if i >= n / 2 { dropped } else { 0 };
            let mut buf = [0u8; WIRE_BYTES];
            let len = Frame::from_status(i as u16, d, &status)
                .encode(&mut buf)
                .unwrap();
            buf[..len].to_vec()
        })
        .collect()
}

/// Plays `up1` through a capture session; returns the session.
fn play(up1: Vec<u8>) -> CaptureSession {
    let mut replay = Replay::new(vec![Vec::new(), up1, Vec::new()]);
    let mut session = CaptureSession::new(DefmtLog::hex());
    let (mut a, mut b, mut c) = (Vec::new(), Vec::new(), Vec::new());
    let mut raw: [&mut dyn std::io::Write; 3] = [&mut a, &mut b, &mut c];
    while !session.ended() {
        session.poll(&mut replay, &mut raw).unwrap();
    }
    session
}

#[test]
fn garbage_truncation_gaps_and_firmware_drops_are_counted() {
    let f = frames(600, 7);
    let mut stream = Vec::new();
    // Attached mid-frame: the tail of a frame first.
    stream.extend_from_slice(&f[0][20..]);
    for (i, frame) in f.iter().enumerate().skip(1) {
        match i {
            // A frame cut short by a lost piece of the channel (delimiter kept).
            100 => {
                stream.extend_from_slice(&frame[..30]);
                stream.push(DELIMITER);
            }
            // Garbage between frames, with and without delimiters.
            200 => stream.extend([0x55; 300]),
            201 => stream.extend([9, 8, 7, DELIMITER, 1, DELIMITER]),
            // A frame lost whole: a sequence gap.
            300 => {}
            _ => stream.extend_from_slice(frame),
        }
    }
    // The recording ends mid-frame.
    stream.extend_from_slice(&f[5][..17]);
    let session = play(stream);
    let c = session.counters();
    // 599 whole frames after the first: one cut, one lost whole, two replaced by garbage.
    assert_eq!(c.telemetry.accepted, 599 - 4, "{c}");
    // The partial first frame, the cut one, the overlong garbage run (up to the delimiter
    // after 9 8 7), the one-byte frame; the frame the recording ends in never completes.
    assert_eq!(c.telemetry.rejected, 4, "{c}");
    assert_eq!(c.firmware_dropped, 7, "{c}");
    // Steps 99→101, 199→202, 299→301.
    assert_eq!(c.gaps, 3, "{c}");
    let d = session.into_telemetry().finish().unwrap();
    assert_eq!(d.dropped, 7);
    assert_eq!(d.gaps, 3);
    // The longest gap-free stretch: frames 301..600 (299 frames).
    assert_eq!(d.log.len(), 299);
}

#[test]
fn garbage_only_and_truncated_only_recordings_end_cleanly() {
    let mut rng = 0x2545_F491_4F6C_DD1Du64;
    let mut garbage = Vec::new();
    for _ in 0..50_000 {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        garbage.push(rng as u8);
    }
    let c = play(garbage.clone()).counters();
    assert_eq!(c.telemetry.accepted, 0, "{c}");
    assert!(c.telemetry.rejected > 10, "{c}");

    let truncated = frames(1, 0)[0][..40].to_vec();
    let c = play(truncated.clone()).counters();
    assert_eq!((c.telemetry.accepted, c.telemetry.rejected), (0, 0), "{c}");

    // Through the tool: exit 1, one line, the raw channels kept, no run log.
    for (name, up1) in [("garbage", garbage), ("truncated", truncated)] {
        let rec = recording(name, &[], &up1, &[0x33, 0x00]);
        let out_dir = temp(&format!("{name}-out"));
        let out = out_dir.path().join("cap");
        let (code, text) = capture(rec.path(), &out);
        assert_eq!(code, 1, "{text}");
        assert!(text.contains("no telemetry frame"), "{text}");
        assert!(text.contains("the files are written"), "{text}");
        assert!(text.contains("reply frame rejected"), "{text}");
        assert_eq!(std::fs::read(out.join("up1.bin")).unwrap(), up1);
        assert!(!out.join("run.csv").exists());
    }
}

/// The board's command side, simulated: the firmware's command task on down 0 and up 2,
/// the controller answering in between (as the control task does each cycle). Everything
/// written to up 2 is also recorded.
struct SimBoard {
    down: ByteQueue,
    up2: ByteSink,
    clock: SteppedClock,
    shared: &'static Shared<NoopRawMutex>,
    step: ControlStep,
    task: Pin<Box<dyn Future<Output = std::convert::Infallible>>>,
    read: usize,
}

impl SimBoard {
    fn new() -> SimBoard {
        SimBoard::booted(None)
    }

    /// The board after a boot that loaded `stored` (as from flash), as the control task
    /// boots.
    fn booted(stored: Option<CalibrationRecord>) -> SimBoard {
        let shared: &'static Shared<NoopRawMutex> = Box::leak(Box::new(Shared::new()));
        let (down, up2, clock) = (
            ByteQueue::default(),
            ByteSink::default(),
            SteppedClock::default(),
        );
        let task = Box::pin(fpc::tasks::command_run(
            down.clone(),
            up2.clone(),
            clock.clone(),
            clock.clone(),
            shared,
        ));
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        if let Some(record) = stored {
            step.load_calibration(Ok(record));
        }
        shared.publish_calibration(step.calibration_record());
        SimBoard {
            down,
            up2,
            clock,
            shared,
            step,
            task,
            read: 0,
        }
    }

    /// One millisecond of the board.
    fn tick(&mut self) {
        self.clock.step(1000);
        let mut cx = Context::from_waker(Waker::noop());
        let _ = self.task.as_mut().poll(&mut cx);
        fpc::tasks::serve_commands(&mut self.step, self.shared);
        if let Some(record) = self.step.take_calibration_to_save() {
            self.shared.post_calibration(record);
        }
        let _ = self.task.as_mut().poll(&mut cx);
    }
}

impl Channels for SimBoard {
    fn read_up(&mut self, channel: usize, buf: &mut [u8]) -> std::io::Result<usize> {
        assert_eq!(channel, 2, "send reads replies only");
        self.tick();
        let all = self.up2.0.borrow();
        let n = buf.len().min(all.len() - self.read);
        buf[..n].copy_from_slice(&all[self.read..self.read + n]);
        self.read += n;
        Ok(n)
    }

    fn write_down(&mut self, channel: usize, bytes: &[u8]) -> std::io::Result<usize> {
        assert_eq!(channel, 0);
        self.down.push(bytes);
        Ok(bytes.len())
    }
}

fn round_trip(board: &mut SimBoard, command: Command) -> Outcome {
    send_command(board, &command, Duration::from_secs(5), |l| {
        panic!("unexpected answer {l}")
    })
    .unwrap()
}

#[test]
fn a_command_round_trip_prints_the_controllers_answer() {
    let mut board = SimBoard::new();
    let start = Command::Start {
        peak_speed_mps: 2.3,
    };
    // Not homed yet: the controller refuses, the reason comes back.
    let got = round_trip(&mut board, start);
    assert_eq!(
        got,
        Outcome::Reply(Reply {
            command: start,
            result: Err(Refusal::NotHomed)
        })
    );
    assert_eq!(
        outcome_text(&got),
        "refused: start --speed 2.3: not homed: home the axis first"
    );
    let got = round_trip(&mut board, Command::Home);
    assert_eq!(outcome_text(&got), "accepted: home");

    // The same replies, recorded, through the tool as an operator types it.
    let rec = recording("replies", &[], &[], &board.up2.0.borrow());
    let (code, text) = fpc_sim(&[
        &"link",
        &"send",
        &"--replay",
        &rec.path(),
        &"start",
        &"--speed",
        &"2.3",
    ]);
    assert_eq!(code, 1, "{text}");
    assert_eq!(
        text.trim(),
        "error: refused: start --speed 2.3: not homed: home the axis first"
    );
    let (code, text) = fpc_sim(&[&"link", &"send", &"--replay", &rec.path(), &"home"]);
    assert_eq!(code, 0, "{text}");
    assert_eq!(
        text.trim(),
        "earlier answer: refused: start --speed 2.3: not homed: home the axis first\naccepted: home"
    );
    // No answer in the recording: one line, exit 1.
    let (code, text) = fpc_sim(&[&"link", &"send", &"--replay", &rec.path(), &"stop"]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("ended without an answer to `stop`"), "{text}");
    // Typed arguments are checked before anything is sent.
    let (code, _) = fpc_sim(&[&"link", &"send", &"--replay", &rec.path(), &"start"]);
    assert_eq!(code, 2);
    let (code, _) = fpc_sim(&[
        &"link",
        &"send",
        &"--replay",
        &rec.path(),
        &"calibrate",
        &"x",
    ]);
    assert_eq!(code, 2);
}

/// The record the storage (or retaining) task was handed last, if any.
fn handed_to_storage(board: &SimBoard) -> Option<CalibrationRecord> {
    let mut save = Box::pin(board.shared.calibration_to_save());
    match save.as_mut().poll(&mut Context::from_waker(Waker::noop())) {
        Poll::Ready(record) => Some(record),
        Poll::Pending => None,
    }
}

#[test]
fn the_calibration_record_is_read_and_written_over_the_link() {
    let file =
        hal_sim::calibration::parse(include_str!("../../tests/data/calibration.toml")).unwrap();
    let mut board = SimBoard::booted(Some(file));
    let t = Duration::from_secs(5);
    let no_other = |l: String| panic!("unexpected answer {l}");

    // Read: the bytes of the record the controller runs on.
    let read = read_calibration(&mut board, t, no_other).unwrap();
    assert_eq!(read, file.encode());
    // The same answers, recorded, through the tool: the file it writes loads as that record.
    let rec = recording("cal-read", &[], &[], &board.up2.0.borrow());
    let out_dir = temp("cal-read-out");
    let out = out_dir.path().join("cal.toml");
    let (code, text) = fpc_sim(&[
        &"link",
        &"calibration",
        &"read",
        &"--replay",
        &rec.path(),
        &"--out",
        &out,
    ]);
    assert_eq!(code, 0, "{text}");
    assert_eq!(hal_sim::calibration::read(&out).unwrap(), file);

    // Write a changed record (through its file, as an operator would): loaded as a boot
    // load does, handed to the storage task, and read back equal.
    let mut changed = file;
    let map = changed.calibrated.cogging.as_mut().unwrap();
    map.sin_n[0] += 1.5;
    let changed_dir = temp("cal-write");
    let changed_file = changed_dir.path().join("changed.toml");
    std::fs::write(
        &changed_file,
        hal_sim::calibration::to_toml(&changed, "test").unwrap(),
    )
    .unwrap();
    let changed = hal_sim::calibration::read(&changed_file).unwrap();
    assert_ne!(changed, file);
    let before = board.up2.0.borrow().len();
    write_calibration(&mut board, &changed.encode(), t, no_other).unwrap();
    assert_eq!(board.step.calibration_record(), changed);
    assert_eq!(handed_to_storage(&board), Some(changed));
    assert_eq!(
        read_calibration(&mut board, t, no_other).unwrap(),
        changed.encode()
    );
    // The write's answers, recorded, through the tool.
    let rec = recording("cal-write-rec", &[], &[], &board.up2.0.borrow()[before..]);
    let (code, text) = fpc_sim(&[
        &"link",
        &"calibration",
        &"write",
        &"--replay",
        &rec.path(),
        &changed_file,
    ]);
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("accepted: calibration write"), "{text}");

    // A corrupted byte: the commit is refused by name and nothing changes.
    let mut bad = file.encode();
    bad[40] ^= 0x10;
    let e = write_calibration(&mut board, &bad, t, no_other).unwrap_err();
    assert!(e.contains("not a valid calibration record"), "{e}");
    assert_eq!(board.step.calibration_record(), changed);
    assert_eq!(handed_to_storage(&board), None);
    assert_eq!(
        read_calibration(&mut board, t, no_other).unwrap(),
        changed.encode()
    );

    // Refused while an operation is in progress (homing), nothing changes.
    let got = round_trip(&mut board, Command::Home);
    assert_eq!(outcome_text(&got), "accepted: home");
    let e = write_calibration(&mut board, &file.encode(), t, no_other).unwrap_err();
    assert!(
        e.contains("refused: calibration commit") && e.contains("busy"),
        "{e}"
    );
    assert_eq!(board.step.calibration_record(), changed);
}

#[test]
fn without_the_probe_feature_the_board_is_refused_in_one_line() {
    if cfg!(feature = "probe") {
        return;
    }
    let (code, text) = fpc_sim(&[&"link", &"send", &"home"]);
    assert_eq!(code, 2, "{text}");
    assert!(text.contains("--features probe"), "{text}");
}
