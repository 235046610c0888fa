//! A capture on the running machine through a probe ([`crate::faults::Scenario::ProbeCapture`]):
//! the host's link, as `fpc-sim link capture` runs it — hal-sim's probe transport
//! ([`hal_sim::link::probe::attach_memory`]) over probe-rs's ARM debug interface, the RTT
//! channels, the capture session — on a thread of its own, its SWD transfers served by the
//! emulated chip's debug port ([`crate::probe`]), while the machine strokes.
//!
//! The witness ([`crate::faults::Scenario::ProbeSession`]) attaches as `probe-rs` tools do,
//! with a `probe_rs::Session`, over the same emulated port: the chip counts the halts that
//! session makes.

use std::io::Write;
use std::path::Path;
use std::sync::mpsc::{channel, Receiver, Sender};

use hal_sim::link::defmt::DefmtLog;
use hal_sim::link::memory::TargetMemory;
use hal_sim::link::probe::chain;
use hal_sim::link::rtt::RttChannels;
use hal_sim::link::session::{CaptureSession, Counters};
use probe_rs::probe::Probe;
use probe_rs::{MemoryInterface, Permissions, Session};

use crate::probe::{serve, Answer, EmulatedProbe, ToChip, Turn};

/// How the host attaches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Attach {
    /// hal-sim's link: the memory access port alone, no session.
    Link,
    /// A `probe_rs::Session`, as probe-rs's tools attach.
    Session,
}

/// The chip as probe-rs names it.
pub const CHIP: &str = "STM32G474RETx";

/// What the host's capture showed.
#[derive(Clone, Debug, Default)]
pub struct ProbeCapture {
    /// The capture's length, emulated s.
    pub seconds: f64,
    /// The host's turns (polls of the link), one per emulated millisecond.
    pub polls: u64,
    /// The link's counters at the end of the capture.
    pub counters: Counters,
    /// Rows of the run log the capture decoded.
    pub rows: usize,
    /// Dead points of the piston during the capture (from the plant).
    pub dead_points: u64,
    /// Halts of the core during the capture.
    pub halts: u32,
    /// Accesses of the probe to DHCSR and DEMCR: (address, written value or `None`).
    pub debug_register_touches: Vec<(u32, Option<u32>)>,
    /// DP and AP transfers the probe made.
    pub transfers: u64,
    /// `fpc-sim link flash`'s refusal (without `--force`) at the end, from the last frame.
    pub flash_refused: Option<String>,
    /// The host's error, if it failed.
    pub error: Option<String>,
}

impl std::fmt::Display for ProbeCapture {
    /// The figures in words, as `fpc-pil` and the PIL's tests print them.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:.1} s, {} polls, {} SWD transfers; core halted {} times; DHCSR/DEMCR accesses \
             {}; {} dead points; {} run-log rows; {}",
            self.seconds,
            self.polls,
            self.transfers,
            self.halts,
            self.debug_register_touches.len(),
            self.dead_points,
            self.rows,
            self.counters,
        )?;
        if let Some(e) = &self.error {
            write!(f, "; host failed: {e}")?;
        }
        Ok(())
    }
}

/// The host's side, on its thread: waits for its first turn, attaches as `how` says,
/// gives the turn back; then polls the channels at each turn; detaches in its last.
fn host(
    probe: Probe,
    how: Attach,
    elf: &[u8],
    turns: &Receiver<Turn>,
    done: &Sender<ToChip>,
) -> Result<HostEnd, String> {
    if turns.recv().is_err() {
        return Err("the emulator ended before the host's first turn".into());
    }
    let locate = hal_sim::link::probe::locate(CHIP, Some((elf, Path::new("fpc"))))?;
    let channels: Result<Box<dyn hal_sim::link::Channels>, String> = match how {
        Attach::Link => hal_sim::link::probe::attach_memory(probe, false)
            .and_then(|m| hal_sim::link::probe::rtt(m, &locate, CHIP))
            .map(|c| Box::new(c) as Box<dyn hal_sim::link::Channels>),
        Attach::Session => probe
            .attach(CHIP, Permissions::default())
            .map_err(|e| format!("probe-rs session: {}", chain(&e)))
            .and_then(|session| {
                RttChannels::attach(SessionMemory(session), &locate)
                    .map_err(|e| e.to_string())
                    .map(|c| Box::new(c) as Box<dyn hal_sim::link::Channels>)
            }),
    };
    let _ = done.send(ToChip::Done);
    let mut channels = channels?;
    let mut session = CaptureSession::new(DefmtLog::from_elf(elf)?);
    let (mut a, mut b, mut c) = (std::io::sink(), std::io::sink(), std::io::sink());
    loop {
        let Ok(turn) = turns.recv() else {
            return Err("the emulator ended without the host's last turn".into());
        };
        let mut raw: [&mut dyn Write; 3] = [&mut a, &mut b, &mut c];
        let polled = session.poll(&mut channels, &mut raw);
        if turn == Turn::Last {
            // Detaching: the probe's last transfers, in this turn.
            drop(channels);
            let _ = done.send(ToChip::Done);
            polled.map_err(|e| e.to_string())?;
            // What `fpc-sim link flash` would answer now, from the machine's mode.
            let mode = session.last_frame().map(|f| f.mode);
            let flash = hal_sim::link::session::halting_allowed("flashing", mode, false).err();
            let counters = session.counters();
            let rows = session.into_telemetry().finish()?.log.len();
            return Ok(HostEnd {
                counters,
                rows,
                flash_refused: flash,
            });
        }
        let _ = done.send(ToChip::Done);
        polled.map_err(|e| format!("the link failed: {e}"))?;
    }
}

/// What the host had at its detach.
pub struct HostEnd {
    /// The link's counters.
    pub counters: Counters,
    /// Rows of the run log decoded from the capture.
    pub rows: usize,
    /// The refusal `fpc-sim link flash` (without `--force`) gives on the last frame's mode.
    pub flash_refused: Option<String>,
}

/// The channels between the emulator and the host's thread.
pub struct Host {
    turns: Sender<Turn>,
    requests: Receiver<ToChip>,
    answers: Sender<Answer>,
    thread: std::thread::JoinHandle<Result<HostEnd, String>>,
}

impl Host {
    /// Starts the host's thread, attaching as `how` at its first turn, with the firmware's
    /// ELF `elf` (its RTT control block and defmt table).
    pub fn start(how: Attach, elf: Vec<u8>) -> Host {
        let (turns, turn_rx) = channel();
        let (request_tx, requests) = channel();
        let (answers, answer_rx) = channel();
        let probe = EmulatedProbe::new(request_tx.clone(), answer_rx).into_probe();
        let thread = std::thread::spawn(move || host(probe, how, &elf, &turn_rx, &request_tx));
        Host {
            turns,
            requests,
            answers,
            thread,
        }
    }

    /// Gives the host a turn on `chip`; false once it has gone.
    pub fn turn(&self, chip: &mut crate::chip::Chip, turn: Turn) -> bool {
        serve(chip, turn, &self.turns, &self.requests, &self.answers)
    }

    /// Waits for the host's thread: what it had at its detach.
    pub fn join(self) -> Result<HostEnd, String> {
        drop(self.turns);
        self.thread
            .join()
            .map_err(|_| "the host's thread panicked".to_string())?
    }
}

/// A `probe_rs::Session`'s view of memory (core 0's), for the witness.
struct SessionMemory(Session);

fn io(e: impl std::fmt::Display) -> std::io::Error {
    std::io::Error::other(e.to_string())
}

impl TargetMemory for SessionMemory {
    fn read(&mut self, address: u64, buf: &mut [u8]) -> std::io::Result<()> {
        self.0.core(0).map_err(io)?.read(address, buf).map_err(io)
    }

    fn write(&mut self, address: u64, bytes: &[u8]) -> std::io::Result<()> {
        self.0
            .core(0)
            .map_err(io)?
            .write(address, bytes)
            .map_err(io)
    }
}
