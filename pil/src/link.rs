//! `fpc-sim link capture` against the emulated board: the host link's own code — the RTT
//! transport ([`RttChannels`]) on the non-halting memory access ([`NonHalting`]) through the
//! emulated debug port ([`EmulatedDap`]), the capture session (`hal_sim::link::session`) —
//! while the release ELF strokes. What the debug port saw (halts, DHCSR and DEMCR accesses)
//! is counted by the chip (`chip::debug`).

use fpc::control::command::Command;
use fpc::link::channels::DOWN_COMMANDS;
use fpc::link::commands::{encode_command, MAX_COMMAND_WIRE};
use fpc::link::settings::{encode_link_request, LinkRequest};
use fpc::link::telemetry::Ports;
use fpc::safety::faults::Fault;
use fpc::status::ModeKind;
use hal_sim::link::debugport::NonHalting;
use hal_sim::link::defmt::DefmtLog;
use hal_sim::link::rtt::{ControlBlock, Locate, RttChannels};
use hal_sim::link::session::CaptureSession;
use hal_sim::link::Channels;
use hal_sim::plant::chambers::PortMode;
use hal_sim::run::RunOptions;

use crate::board::Board;
use crate::chip::{Chip, ChipOptions};
use crate::dap::EmulatedDap;
use crate::elf::Image;

/// A halting debug session's attach (probe-rs's, as [`crate::dap`] replays it): the saved
/// DBGMCU_CR.
pub type AttachFn = fn(&mut EmulatedDap, f64) -> Result<u32, String>;
/// Its detach.
pub type DetachFn = fn(&mut EmulatedDap, f64, u32) -> Result<(), String>;

/// How the capture runs.
#[derive(Clone, Debug)]
pub struct CaptureOptions {
    /// Pressure ratio (the peak speed follows it, as in `fpc-sim run`).
    pub pressure_ratio: f64,
    /// How long the capture records once the machine strokes, emulated s.
    pub capture_s: f64,
    /// The host reads the channels every this many PWM periods (20: 1 kHz).
    pub poll_every_periods: u32,
    /// The witness: a halting debug session attached a third of the way into the capture
    /// and dropped at two thirds.
    pub halting_session: Option<(AttachFn, DetachFn)>,
    /// One round trip to the probe, s (the halting session's halts last a few of them).
    pub round_trip_s: f64,
}

impl Default for CaptureOptions {
    fn default() -> Self {
        CaptureOptions {
            pressure_ratio: RunOptions::reference().pressure_ratio,
            capture_s: 10.0,
            poll_every_periods: 20,
            halting_session: None,
            round_trip_s: 0.5e-3,
        }
    }
}

/// What the capture showed.
#[derive(Clone, Debug, Default)]
pub struct CaptureReport {
    /// How long it recorded, emulated s.
    pub capture_s: f64,
    /// Telemetry frames accepted over the whole session.
    pub frames: u32,
    /// Sequence gaps (frames lost between the firmware and the host).
    pub gaps: usize,
    /// Times the core entered Debug state.
    pub halts: u32,
    /// Time the core spent halted, ms.
    pub halted_ms: f64,
    /// DHCSR reads and writes, DEMCR reads and writes, through the debug port.
    pub dhcsr_reads: u32,
    /// See [`CaptureReport::dhcsr_reads`].
    pub dhcsr_writes: u32,
    /// See [`CaptureReport::dhcsr_reads`].
    pub demcr_reads: u32,
    /// See [`CaptureReport::dhcsr_reads`].
    pub demcr_writes: u32,
    /// Words moved through the debug port.
    pub words: u64,
    /// Faults the telemetry reported during the capture.
    pub faults: Vec<String>,
    /// Dead points at head A the piston reached during the capture.
    pub dead_points: u32,
    /// Smallest head clearance during the capture, m.
    pub min_clearance_m: f64,
}

fn send(ch: &mut RttChannels<NonHalting<EmulatedDap>>, bytes: &[u8]) -> Result<(), String> {
    let mut rest = bytes;
    while !rest.is_empty() {
        let n = ch
            .write_down(DOWN_COMMANDS, rest)
            .map_err(|e| e.to_string())?;
        rest = &rest[n..];
        if !rest.is_empty() {
            period(ch)?;
        }
    }
    Ok(())
}

fn command(ch: &mut RttChannels<NonHalting<EmulatedDap>>, c: Command) -> Result<(), String> {
    let mut out = [0u8; MAX_COMMAND_WIRE];
    let n = encode_command(&c, &mut out).map_err(|_| "command does not encode")?;
    send(ch, &out[..n])
}

fn chip(ch: &mut RttChannels<NonHalting<EmulatedDap>>) -> &mut Chip {
    &mut ch.memory_mut().port_mut().chip
}

fn period(ch: &mut RttChannels<NonHalting<EmulatedDap>>) -> Result<(), String> {
    chip(ch).run_period().map_err(|e| e.to_string())
}

/// Boots the ELF on the reference machine (a calibration in flash), attaches the host link,
/// homes, starts the strokes and captures for `opts.capture_s`.
pub fn capture(image: &Image, opts: &CaptureOptions) -> Result<CaptureReport, String> {
    let run = RunOptions {
        pressure_ratio: opts.pressure_ratio,
        ..RunOptions::reference()
    };
    run.validate()?;
    let record = crate::run::commissioned(&run)?;
    let store = hal_sim::board::flash::holding(&record)?;
    let mut world = hal_sim::run::world(&run.model, run.seed, 0, 1e-3);
    world.plant.lines.set_pressure_ratio(opts.pressure_ratio);
    let rtt = image
        .symbol("_SEGGER_RTT")
        .ok_or("the ELF has no RTT control block")?;
    let mut c = Chip::new(image.clone(), Board::new(world), ChipOptions::default())
        .map_err(|e| e.to_string())?;
    c.boot().map_err(|e| e.to_string())?;
    c.soc().flash.load_image(store.image());
    let mut mem = NonHalting::attach(EmulatedDap::new(c)).map_err(|e| e.to_string())?;
    let locate = Locate::At(u64::from(rtt));
    let block = loop {
        mem.port_mut()
            .chip
            .run_period()
            .map_err(|e| e.to_string())?;
        if let Ok(b) = ControlBlock::find(&mut mem, &locate) {
            break b;
        }
        if mem.port().chip.time_s() > 1.0 {
            return Err("no RTT control block within 1 s".into());
        }
    };
    let mut ch = RttChannels::with_block(mem, block);
    let mut session = CaptureSession::new(DefmtLog::hex());
    let (mut a, mut b, mut d) = (std::io::sink(), std::io::sink(), std::io::sink());
    let every = opts.poll_every_periods.max(1);
    let mut n = 0u32;
    // Poll one period; the last frame if one was read.
    macro_rules! step {
        () => {{
            period(&mut ch)?;
            n += 1;
            if n % every == 0 {
                session
                    .poll(&mut ch, &mut [&mut a, &mut b, &mut d])
                    .map_err(|e| e.to_string())?;
            }
            session.last_frame().copied()
        }};
    }
    command(&mut ch, Command::Home)?;
    loop {
        let f = step!();
        if f.is_some_and(|f| f.homed && f.mode == ModeKind::Holding) {
            break;
        }
        if chip(&mut ch).time_s() > 30.0 {
            return Err("homing did not end within 30 s".into());
        }
    }
    chip(&mut ch).soc().board.world.plant.port_mode = PortMode::Timed;
    let mut out = [0u8; MAX_COMMAND_WIRE];
    let len = encode_link_request(&LinkRequest::DeclarePorts(Ports::Timed), &mut out)
        .map_err(|_| "link request does not encode")?;
    send(&mut ch, &out[..len])?;
    command(
        &mut ch,
        Command::Start {
            peak_speed_mps: run.peak_speed_mps() as f32,
        },
    )?;
    loop {
        let f = step!();
        if f.is_some_and(|f| f.mode == ModeKind::Running) {
            break;
        }
        if chip(&mut ch).time_s() > 40.0 {
            return Err("the strokes did not start".into());
        }
    }
    let t0 = chip(&mut ch).time_s();
    let mut r = CaptureReport {
        min_clearance_m: f64::INFINITY,
        ..CaptureReport::default()
    };
    let mut attached: Option<u32> = None;
    let mut detached = false;
    let mut last = (f64::NAN, f64::NAN);
    while chip(&mut ch).time_s() < t0 + opts.capture_s {
        let f = step!();
        let t = chip(&mut ch).time_s();
        if let Some(f) = f.filter(|f| f.fault != 0) {
            let name = Fault::from_code(f.fault)
                .map_or("?", |x| x.name())
                .to_string();
            if !r.faults.contains(&name) {
                r.faults.push(name);
            }
        }
        let x = chip(&mut ch).soc_ref().board.world.plant.x_m;
        r.min_clearance_m = r
            .min_clearance_m
            .min(chip(&mut ch).soc_ref().board.world.plant.head_clearance_m());
        if last.1 < last.0 && x > last.1 && last.1 < 0.05 {
            r.dead_points += 1;
        }
        last = (last.1, x);
        if let Some((attach, detach)) = opts.halting_session {
            let dap = ch.memory_mut().port_mut();
            if attached.is_none() && t >= t0 + opts.capture_s / 3.0 {
                attached = Some(attach(dap, opts.round_trip_s)?);
            } else if !detached && t >= t0 + 2.0 * opts.capture_s / 3.0 {
                if let Some(saved) = attached {
                    detach(dap, opts.round_trip_s, saved)?;
                    detached = true;
                }
            }
        }
    }
    session
        .poll(&mut ch, &mut [&mut a, &mut b, &mut d])
        .map_err(|e| e.to_string())?;
    let counters = session.counters();
    r.capture_s = chip(&mut ch).time_s() - t0;
    let dbg_now = chip(&mut ch).soc_ref().debug.clone();
    r.frames = counters.telemetry.accepted;
    r.gaps = counters.gaps;
    r.halts = dbg_now.halts;
    r.halted_ms = crate::time::seconds(dbg_now.halted_units) * 1e3;
    r.dhcsr_reads = dbg_now.dhcsr_reads;
    r.dhcsr_writes = dbg_now.dhcsr_writes;
    r.demcr_reads = dbg_now.demcr_reads;
    r.demcr_writes = dbg_now.demcr_writes;
    r.words = ch.memory_mut().port().words;
    Ok(r)
}
