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

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use fpc::link::settings::LinkRequest;
use fpc::link::telemetry::CONTROL_PERIOD_US;
use fpc::motion::synchroniser::Rotation;
use tokio::sync::broadcast;

use super::protocol::Control;
use crate::link::Channels;
use crate::output::show;
use crate::plant::model::MachineModel;

mod host;
mod replay;
mod translate;

use host::Host;
use replay::run_replay;
use translate::{translate, Known, Outgoing, PlantAction};

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

#[cfg(test)]
mod tests {
    use std::io;

    use fpc::control::command::Command;
    use fpc::link::telemetry::Ports;

    use super::host::Clock;
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
