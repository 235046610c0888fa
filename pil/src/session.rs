//! A debug session on the emulated board: the chip, and the host's side of its RTT
//! channels — the defmt log of up 0, telemetry frames from up 1 (the status the host sees),
//! command answers from up 2, commands out on down 0 — period by period.

use std::collections::VecDeque;

use fpc::control::command::Command;
use fpc::link::commands::{encode_command, MAX_COMMAND_WIRE};
use fpc::link::telemetry::{Frame, TelemetryDecoder};
use fpc::safety::faults::{Fault, FaultSet};
use fpc::status::Status;
use hal_sim::link::rtt::{ControlBlock, Locate};
use hal_sim::link::session::AnswerReader;
use hal_sim::run::HostLink;

use crate::board::Board;
use crate::chip::{Chip, ChipOptions};
use crate::elf::Image;
use crate::log::DefmtLog;

use fpc::link::channels::{DOWN_COMMANDS, UP_DEFMT, UP_REPLIES, UP_TELEMETRY};

/// The board running, and the host attached to it.
pub struct Session {
    /// The emulated board.
    pub chip: Chip,
    rtt_base: u32,
    rtt: Option<ControlBlock>,
    /// The defmt log so far.
    pub log: DefmtLog,
    telemetry: TelemetryDecoder,
    answers: AnswerReader,
    /// The status of the last telemetry frame.
    pub status: Status,
    /// A frame arrived in the last period.
    pub fresh: bool,
    /// Telemetry frames received.
    pub frames: u64,
    /// Answers received on up 2: (accepted, refused).
    pub answers_seen: (u32, u32),
    /// Faults seen in frames or logged, in order.
    pub faults: FaultSet,
    outbox: VecDeque<u8>,
    resets_seen: usize,
    buf: Vec<u8>,
}

/// The status a telemetry frame carries (what the host knows of the firmware's status).
pub fn status_of(frame: &Frame, faults: FaultSet) -> Status {
    Status {
        t: frame.t,
        mode: frame.mode,
        homed: frame.homed,
        position_m: frame.x_m,
        slave_position_m: frame.x_slave_m,
        velocity_mps: frame.v_mps,
        reference_m: frame.x_ref_m,
        theta_rad: frame.theta_rad,
        theta_reference_rad: frame.theta_ref_rad,
        force_master_n: frame.f_master_n,
        force_slave_n: frame.f_slave_n,
        pressure_a_pa: frame.p_a_pa,
        pressure_b_pa: frame.p_b_pa,
        faults,
        ..Status::INIT
    }
}

impl Session {
    /// The board with `image` flashed and `board` around it, powered on.
    pub fn new(image: Image, board: Board, options: ChipOptions) -> Result<Session, String> {
        let rtt_base = image
            .symbol("_SEGGER_RTT")
            .ok_or("the ELF has no RTT control block (_SEGGER_RTT)")?;
        let log = DefmtLog::new(&image.bytes)?;
        let mut chip = Chip::new(image, board, options).map_err(|e| e.to_string())?;
        chip.boot().map_err(|e| e.to_string())?;
        Ok(Session {
            chip,
            rtt_base,
            rtt: None,
            log,
            telemetry: TelemetryDecoder::new(),
            answers: AnswerReader::new(),
            status: Status::INIT,
            fresh: false,
            frames: 0,
            answers_seen: (0, 0),
            faults: FaultSet::new(),
            outbox: VecDeque::new(),
            resets_seen: 0,
            buf: Vec::new(),
        })
    }

    /// Runs one period (to the next plant step), then reads the channels and writes what
    /// is waiting for down 0.
    pub fn step(&mut self) -> Result<(), String> {
        self.chip.run_period().map_err(|e| {
            format!(
                "emulation stopped at {:.6} s (pc {:#010x}): {e}",
                self.chip.time_s(),
                self.chip.pc()
            )
        })?;
        self.poll()
    }

    /// Reads the up-channels and writes down 0.
    pub fn poll(&mut self) -> Result<(), String> {
        let t = self.chip.time_s();
        let resets = self.chip.soc_ref().resets.len();
        if resets != self.resets_seen {
            // A reset: the firmware sets its channels up afresh; what was in flight is lost.
            self.resets_seen = resets;
            self.rtt = None;
            self.log.restart();
            self.telemetry = TelemetryDecoder::new();
            self.answers = AnswerReader::new();
            self.outbox.clear();
        }
        self.fresh = false;
        if self.rtt.is_none() {
            // Until the firmware has set its control block up, there is none to find.
            let at = Locate::At(u64::from(self.rtt_base));
            self.rtt = ControlBlock::find(&mut self.chip, &at).ok();
        }
        let Some(rtt) = self.rtt.clone() else {
            return Ok(());
        };
        self.read(&rtt, UP_DEFMT)?;
        if !self.buf.is_empty() {
            self.log.push(t, &self.buf);
            for (_, line) in &self.log.lines[self.log.seen..] {
                if let Some(f) = logged_fault(line) {
                    self.faults.latch(f);
                }
            }
            self.log.seen = self.log.lines.len();
        }
        self.read(&rtt, UP_TELEMETRY)?;
        for i in 0..self.buf.len() {
            if let Some(Ok(frame)) = self.telemetry.push(self.buf[i]) {
                if let Some(f) = Fault::from_code(frame.fault) {
                    self.faults.latch(f);
                }
                self.status = status_of(&frame, self.faults);
                self.fresh = true;
                self.frames += 1;
            }
        }
        self.read(&rtt, UP_REPLIES)?;
        for answer in self.answers.push(&self.buf) {
            match answer {
                Ok(fpc::link::commands::Answer::Reply(r)) if r.result.is_err() => {
                    self.answers_seen.1 += 1
                }
                Ok(_) => self.answers_seen.0 += 1,
                Err(_) => self.answers_seen.1 += 1,
            }
        }
        if !self.outbox.is_empty() {
            let pending: Vec<u8> = self.outbox.iter().copied().collect();
            let n = rtt
                .write_down(&mut self.chip, DOWN_COMMANDS, &pending)
                .map_err(|e| e.to_string())?;
            self.outbox.drain(..n);
        }
        Ok(())
    }

    /// Drains up-channel `n` into `self.buf`.
    fn read(&mut self, rtt: &ControlBlock, n: usize) -> Result<(), String> {
        self.buf.clear();
        let mut chunk = [0u8; 1024];
        loop {
            let got = rtt
                .read_up(&mut self.chip, n, &mut chunk)
                .map_err(|e| e.to_string())?;
            self.buf.extend_from_slice(&chunk[..got]);
            if got < chunk.len() {
                return Ok(());
            }
        }
    }

    /// Queues `command` for down 0; false until the firmware's channels are up.
    pub fn send(&mut self, command: Command) -> bool {
        if self.rtt.is_none() {
            return false;
        }
        let mut out = [0u8; MAX_COMMAND_WIRE];
        match encode_command(&command, &mut out) {
            Ok(n) => {
                self.outbox.extend(&out[..n]);
                true
            }
            Err(_) => false,
        }
    }

    /// The run driver's view of this session.
    pub fn link(&mut self) -> (&mut hal_sim::board::world::World, SessionLink<'_>) {
        let Session {
            chip,
            rtt,
            outbox,
            status,
            ..
        } = self;
        (
            &mut chip.soc().board.world,
            SessionLink {
                status: *status,
                up: rtt.is_some(),
                outbox,
            },
        )
    }
}

/// The fault a defmt line reports latched ("fault latched: NAME (CODE)").
fn logged_fault(line: &str) -> Option<Fault> {
    let rest = line.split("fault latched: ").nth(1)?;
    let code = rest.rsplit('(').next()?.trim_end_matches(')').trim();
    Fault::from_code(code.parse().ok()?)
}

/// [`HostLink`] over a [`Session`]'s channels.
pub struct SessionLink<'a> {
    status: Status,
    up: bool,
    outbox: &'a mut VecDeque<u8>,
}

impl HostLink for SessionLink<'_> {
    fn status(&self) -> Status {
        self.status
    }

    fn post_command(&mut self, command: Command) -> bool {
        if !self.up {
            return false;
        }
        let mut out = [0u8; MAX_COMMAND_WIRE];
        match encode_command(&command, &mut out) {
            Ok(n) => {
                self.outbox.extend(&out[..n]);
                true
            }
            Err(_) => false,
        }
    }
}
