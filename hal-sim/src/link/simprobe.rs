//! A host on the simulated board, attached the way `fpc-sim link` attaches to the real one:
//! it finds the RTT control block by scanning the board's RAM, reads the up-channels and
//! writes the down-channel there through [`RttChannels`] — the transport a probe runs —
//! and handles what it reads with the same [`CaptureSession`] as `fpc-sim link capture`.
//! Simulated time passes only as the host runs the board ([`SimProbe::run_cycles`]), so a
//! whole bench session — commands, telemetry, scope recordings — is deterministic.
//!
//! The host polls every [`SimProbe::poll_cycles`] control periods (1 ms by default, as the
//! link's capture loop sleeps) and may read at most [`SimProbe::poll_bytes`] of each channel
//! per poll, what a slow probe carries: the firmware then drops and counts what did not fit,
//! as on the bench.

use std::io::{self, Write};

use fpc::control::command::{Command, Refusal, Reply};
use fpc::link::commands::{encode_command, tag, Answer, TransferReply, MAX_COMMAND_WIRE};
use fpc::link::settings::{encode_link_request, LinkRequest};

use super::defmt::DefmtLog;
use super::rtt::{ControlBlock, Locate, RttChannels};
use super::session::{CaptureSession, Counters};
use super::{Channels, DOWN_COMMANDS};
use crate::board::exec::LinkedBoard;
use crate::board::ram::SimRam;
use crate::board::world::World;

/// Control periods per second.
const CYCLES_PER_S: f64 = 20_000.0;

/// The host and the board it is attached to.
pub struct SimProbe<'s> {
    board: LinkedBoard<'s>,
    block: ControlBlock,
    session: CaptureSession,
    /// Raw bytes read from each up-channel (up 1 is the capture `fpc-sim decode` reads, up 2
    /// the one holding the scope recordings).
    pub raw: [Vec<u8>; 3],
    /// Control periods between two polls of the host.
    pub poll_cycles: u32,
    /// Most bytes the host reads of each up-channel per poll (`None`: no limit).
    pub poll_bytes: Option<usize>,
    cycles: u64,
}

/// At most `limit` bytes of each up-channel per poll, from `inner`.
struct Limited<'a, C> {
    inner: &'a mut C,
    limit: Option<usize>,
}

impl<C: Channels> Channels for Limited<'_, C> {
    fn read_up(&mut self, channel: usize, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.limit.map_or(buf.len(), |l| l.min(buf.len()));
        self.inner
            .read_up(channel, buf.get_mut(..n).unwrap_or_default())
    }

    fn write_down(&mut self, channel: usize, bytes: &[u8]) -> io::Result<usize> {
        self.inner.write_down(channel, bytes)
    }
}

impl<'s> SimProbe<'s> {
    /// Attaches to `board`: the control block is searched for in the whole RAM, as probe-rs
    /// does without an ELF.
    pub fn attach(board: LinkedBoard<'s>) -> Result<SimProbe<'s>, String> {
        let block =
            ControlBlock::find(&mut board.world().ram, &Locate::Scan(vec![SimRam::range()]))?;
        Ok(SimProbe {
            board,
            block,
            session: CaptureSession::new(DefmtLog::hex()),
            raw: Default::default(),
            poll_cycles: 20,
            poll_bytes: None,
            cycles: 0,
        })
    }

    /// The board (its plant, between periods).
    pub fn world(&self) -> std::cell::RefMut<'_, World> {
        self.board.world()
    }

    /// What the host has read and counted.
    pub fn session(&self) -> &CaptureSession {
        &self.session
    }

    /// The link's counters.
    pub fn counters(&self) -> Counters {
        self.session.counters()
    }

    /// Simulated seconds since attaching.
    pub fn time_s(&self) -> f64 {
        self.cycles as f64 / CYCLES_PER_S
    }

    /// Runs the board `n` control periods, the host polling on its schedule.
    pub fn run_cycles(&mut self, n: u64) -> Result<(), String> {
        for _ in 0..n {
            self.board.step();
            self.cycles += 1;
            if self
                .cycles
                .is_multiple_of(u64::from(self.poll_cycles.max(1)))
            {
                self.poll()?;
            }
        }
        Ok(())
    }

    /// Runs the board for `seconds` of simulated time.
    pub fn run_for(&mut self, seconds: f64) -> Result<(), String> {
        self.run_cycles((seconds * CYCLES_PER_S).round() as u64)
    }

    /// Runs until `done` says so (checked after each poll), at most `limit_s`; the error
    /// names `what` was awaited.
    pub fn run_until(
        &mut self,
        what: &str,
        limit_s: f64,
        mut done: impl FnMut(&CaptureSession) -> bool,
    ) -> Result<(), String> {
        let end = self.cycles + (limit_s * CYCLES_PER_S) as u64;
        while self.cycles < end {
            self.run_cycles(u64::from(self.poll_cycles.max(1)))?;
            if done(&self.session) {
                return Ok(());
            }
        }
        Err(format!(
            "{what}: not within {limit_s} s simulated (last frame: {:?})",
            self.session.last_frame().map(|f| f.mode)
        ))
    }

    /// One poll of the host: every up-channel read through the RTT transport.
    fn poll(&mut self) -> Result<(), String> {
        let mut world = self.board.world();
        let mut rtt = RttChannels::with_block(&mut world.ram, self.block.clone());
        let mut channels = Limited {
            inner: &mut rtt,
            limit: self.poll_bytes,
        };
        let [up0, up1, up2] = &mut self.raw;
        let mut raw: [&mut dyn Write; 3] = [up0, up1, up2];
        self.session
            .poll(&mut channels, &mut raw)
            .map_err(|e| format!("link failed: {e}"))?;
        Ok(())
    }

    /// Writes `frame` to the command channel (all of it, polling while it is full).
    fn send(&mut self, frame: &[u8]) -> Result<(), String> {
        let mut sent = 0;
        let mut waited = 0;
        while sent < frame.len() {
            let n = {
                let mut world = self.board.world();
                let mut rtt = RttChannels::with_block(&mut world.ram, self.block.clone());
                rtt.write_down(DOWN_COMMANDS, frame.get(sent..).unwrap_or_default())
                    .map_err(|e| format!("cannot write the command channel: {e}"))?
            };
            sent += n;
            if n == 0 {
                waited += 1;
                if waited > 100 {
                    return Err("the command channel stayed full for 100 ms".into());
                }
                self.run_cycles(u64::from(self.poll_cycles.max(1)))?;
            }
        }
        Ok(())
    }

    /// Waits for the answer `pick` recognises, at most `limit_s` simulated.
    fn answer<T>(
        &mut self,
        what: &str,
        limit_s: f64,
        mut pick: impl FnMut(&Answer) -> Option<T>,
    ) -> Result<T, String> {
        let end = self.cycles + (limit_s * CYCLES_PER_S) as u64;
        while self.cycles < end {
            self.run_cycles(u64::from(self.poll_cycles.max(1)))?;
            for a in self.session.take_answers() {
                if let Answer::Rejected(e) = a {
                    return Err(format!("`{what}` rejected by the firmware: {e:?}"));
                }
                if let Some(t) = pick(&a) {
                    return Ok(t);
                }
            }
        }
        Err(format!(
            "no answer to `{what}` within {limit_s} s simulated"
        ))
    }

    /// Sends a command and returns the controller's answer to it.
    pub fn command(&mut self, command: &Command) -> Result<Reply, String> {
        let mut wire = [0u8; MAX_COMMAND_WIRE];
        let n = encode_command(command, &mut wire).map_err(|_| "the command does not fit")?;
        self.send(wire.get(..n).unwrap_or_default())?;
        let want = *command;
        self.answer(&format!("{command:?}"), 0.5, |a| match a {
            Answer::Reply(r) if r.command == want => Some(*r),
            _ => None,
        })
    }

    /// Sends a command that must be accepted.
    pub fn command_ok(&mut self, command: &Command) -> Result<(), String> {
        let reply = self.command(command)?;
        reply
            .result
            .map_err(|r| format!("{command:?} refused: {}", r.reason()))
    }

    /// Sends a link request and returns the firmware's verdict.
    pub fn request(&mut self, request: &LinkRequest) -> Result<Result<(), Refusal>, String> {
        let mut wire = [0u8; MAX_COMMAND_WIRE];
        let n = encode_link_request(request, &mut wire).map_err(|_| "the request does not fit")?;
        self.send(wire.get(..n).unwrap_or_default())?;
        let id = request.id();
        debug_assert!(id.tag >= tag::SET_TELEMETRY);
        self.answer(&format!("{request:?}"), 0.5, |a| match a {
            Answer::Calibration(TransferReply::Verdict { transfer, result }) if *transfer == id => {
                Some(*result)
            }
            _ => None,
        })
    }

    /// Sends a link request that must be accepted.
    pub fn request_ok(&mut self, request: &LinkRequest) -> Result<(), String> {
        self.request(request)?
            .map_err(|r| format!("{request:?} refused: {}", r.reason()))
    }
}
