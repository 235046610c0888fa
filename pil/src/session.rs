//! A debug session on the emulated board: the chip, and the host's side of its RTT
//! channels — the defmt log of up 0, telemetry frames from up 1 (the status the host sees),
//! command answers from up 2, commands out on down 0 — period by period.

use std::collections::VecDeque;

use fpc::control::command::{Command, Refusal};
use fpc::link::commands::{encode_command, MAX_COMMAND_WIRE};
use fpc::link::settings::{encode_link_request, LinkRequest};
use fpc::link::telemetry::{ChannelSet, Ports};
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
    /// The commands refused, with the refusal, in order.
    pub refused: Vec<(Command, Refusal)>,
    outbox: VecDeque<u8>,
    resets_seen: usize,
    buf: Vec<u8>,
    /// Every command the host sent, in order, and when the firmware took it.
    pub sent: Vec<SentCommand>,
    /// Bytes queued for down 0 since the channels came up.
    queued: u64,
    /// Bytes of down 0 the firmware has read since the channels came up.
    consumed: u64,
    /// Down 0's read offset at the last poll.
    read_offset: u32,
    /// The ports as the host declares them to the firmware (a link request at every boot).
    ports: Ports,
    /// The host stops reading up 0 (the defmt log), as a stalled or detached probe does.
    pub defmt_paused: bool,
    /// The host has detached: another (a probe's, [`crate::capture`]) reads the channels.
    pub host_detached: bool,
}

/// A command the host sent over down 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SentCommand {
    /// The command.
    pub command: Command,
    /// Where its last byte is in the stream of down 0.
    end: u64,
    /// The plant cycle after whose control step the firmware's command task had read it, so
    /// that the next control step took it: the cycle at which a host build, whose commands
    /// are taken at the next cycle, must post it to be taken by the same step.
    pub taken_after_cycle: Option<u64>,
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
        absent: frame.absent,
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
            refused: Vec::new(),
            outbox: VecDeque::new(),
            resets_seen: 0,
            buf: Vec::new(),
            sent: Vec::new(),
            queued: 0,
            consumed: 0,
            read_offset: 0,
            ports: Ports::Bypassed,
            defmt_paused: false,
            host_detached: false,
        })
    }

    /// Steps until emulated time `t`, s.
    pub fn run_until(&mut self, t: f64) -> Result<(), String> {
        while self.chip.time_s() < t {
            self.step()?;
        }
        Ok(())
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
            self.queued = 0;
            self.consumed = 0;
            self.read_offset = 0;
        }
        self.fresh = false;
        if self.host_detached {
            return Ok(());
        }
        if self.rtt.is_none() {
            // Until the firmware has set its control block up, there is none to find.
            let at = Locate::At(u64::from(self.rtt_base));
            self.rtt = ControlBlock::find(&mut self.chip, &at).ok();
            if self.rtt.is_some() {
                // What the host asks of the link at every boot, as `fpc-sim link` does: every
                // channel (the run driver reads the references and the velocity) at the
                // default rate, and the ports as they are.
                for request in [
                    LinkRequest::SetTelemetry {
                        decimation: fpc::link::telemetry::DEFAULT_DECIMATION,
                        channels: ChannelSet::ALL,
                    },
                    LinkRequest::DeclarePorts(self.ports),
                ] {
                    queue_link(&request, &mut self.outbox, &mut self.queued);
                }
            }
        }
        let Some(rtt) = self.rtt.clone() else {
            return Ok(());
        };
        self.track_commands(&rtt)?;
        if self.defmt_paused {
            self.buf.clear();
        } else {
            self.read(&rtt, UP_DEFMT)?;
        }
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
                    if let Err(refusal) = r.result {
                        self.refused.push((r.command, refusal));
                    }
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

    /// Follows the firmware's reads of down 0 (its read offset): a command whose last byte
    /// was read in this period was taken by the control step of the next cycle — or of this
    /// one, if the read came before this cycle's control step (the read offset then already
    /// included it when the control executor was entered).
    fn track_commands(&mut self, rtt: &ControlBlock) -> Result<(), String> {
        let Some(down) = rtt.down_channel(DOWN_COMMANDS) else {
            return Ok(());
        };
        let word = u32::try_from(down.descriptor + DOWN_READ_OFFSET)
            .map_err(|_| "the down-channel descriptor is outside the 32-bit space")?;
        let soc = self.chip.soc();
        if soc.watch_word != Some(word) {
            soc.watch_word = Some(word);
            soc.control_entry = None;
        }
        let mut w = [0u8; 4];
        self.chip
            .read_mem(word, &mut w)
            .map_err(|e| e.to_string())?;
        let read = u32::from_le_bytes(w);
        let size = down.size.max(1);
        let delta = u64::from((read + size - self.read_offset % size) % size);
        if delta == 0 {
            return Ok(());
        }
        let soc = self.chip.soc_ref();
        let cycle = soc.board.world.cycle();
        let before_step = match soc.control_entry {
            Some((c, at_entry)) if c == cycle => {
                u64::from((at_entry + size - self.read_offset % size) % size)
            }
            _ => 0,
        };
        let (from, to) = (self.consumed, self.consumed + delta);
        for c in &mut self.sent {
            if c.end > from && c.end <= to && c.taken_after_cycle.is_none() {
                c.taken_after_cycle = Some(if c.end <= from + before_step {
                    cycle.saturating_sub(1)
                } else {
                    cycle
                });
            }
        }
        self.consumed = to;
        self.read_offset = read;
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

    /// The firmware's RTT control block, once the host has found it.
    pub fn rtt(&self) -> Option<ControlBlock> {
        self.rtt.clone()
    }

    /// Queues the link request `request` for down 0; false until the firmware's channels
    /// are up.
    pub fn request(&mut self, request: &LinkRequest) -> bool {
        if self.rtt.is_none() {
            return false;
        }
        queue_link(request, &mut self.outbox, &mut self.queued);
        true
    }

    /// Queues `command` for down 0; false until the firmware's channels are up.
    pub fn send(&mut self, command: Command) -> bool {
        if self.rtt.is_none() {
            return false;
        }
        queue(command, &mut self.outbox, &mut self.sent, &mut self.queued)
    }

    /// The run driver's view of this session.
    pub fn link(&mut self) -> (&mut hal_sim::board::world::World, SessionLink<'_>) {
        let Session {
            chip,
            rtt,
            outbox,
            status,
            sent,
            queued,
            ports,
            ..
        } = self;
        (
            &mut chip.soc().board.world,
            SessionLink {
                status: *status,
                up: rtt.is_some(),
                outbox,
                sent,
                queued,
                ports,
            },
        )
    }
}

/// Encodes a link request onto `outbox` (counted in the stream of down 0, not a command).
fn queue_link(request: &LinkRequest, outbox: &mut VecDeque<u8>, queued: &mut u64) {
    let mut out = [0u8; MAX_COMMAND_WIRE];
    if let Ok(n) = encode_link_request(request, &mut out) {
        outbox.extend(&out[..n]);
        *queued += n as u64;
    }
}

/// Offset of the read offset in an RTT buffer descriptor (name, buffer, size, write, read,
/// flags).
const DOWN_READ_OFFSET: u64 = 16;

/// Encodes `command` onto `outbox` and notes it in `sent`.
fn queue(
    command: Command,
    outbox: &mut VecDeque<u8>,
    sent: &mut Vec<SentCommand>,
    queued: &mut u64,
) -> bool {
    let mut out = [0u8; MAX_COMMAND_WIRE];
    match encode_command(&command, &mut out) {
        Ok(n) => {
            outbox.extend(&out[..n]);
            *queued += n as u64;
            sent.push(SentCommand {
                command,
                end: *queued,
                taken_after_cycle: None,
            });
            true
        }
        Err(_) => false,
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
    sent: &'a mut Vec<SentCommand>,
    queued: &'a mut u64,
    ports: &'a mut Ports,
}

impl HostLink for SessionLink<'_> {
    fn status(&self) -> Status {
        self.status
    }

    fn post_command(&mut self, command: Command) -> bool {
        if !self.up {
            return false;
        }
        queue(command, self.outbox, self.sent, self.queued)
    }

    fn ports_timed(&mut self) {
        *self.ports = Ports::Timed;
        if self.up {
            queue_link(
                &LinkRequest::DeclarePorts(Ports::Timed),
                self.outbox,
                self.queued,
            );
        }
    }
}
