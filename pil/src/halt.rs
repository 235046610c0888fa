//! A debugger halting the core while the machine strokes (issue #41): the release ELF on the
//! reference machine, stroking at the pressure ratio's speed; at each of `phases` instants
//! spread over one stroke cycle the scenario is forked ([`Session::fork`]) and, in each fork,
//! the core is halted through the debug port (DHCSR: C_DEBUGEN | C_HALT) for a given time
//! and resumed, with DBGMCU's freeze as the firmware set it (`chip::debug`). What the halt
//! and the firmware's reaction on resume leave: the head clearance from the halt on, the
//! faults reported, the piston at rest.

use fpc::control::command::Command;
use fpc::status::ModeKind;
use hal_sim::plant::chambers::PortMode;
use hal_sim::run::RunOptions;

use crate::board::Board;
use crate::chip::debug::{addr, C_DEBUGEN, C_HALT, DBGKEY};
use crate::chip::ChipOptions;
use crate::elf::Image;
use crate::session::Session;

/// One halt and what followed it.
#[derive(Clone, Debug)]
pub struct HaltCase {
    /// The phase's number (0 = the first instant, a fraction `phase / phases` of the cycle).
    pub phase: usize,
    /// When the halt began, emulated s.
    pub at_s: f64,
    /// How long the core stayed halted, s.
    pub halted_s: f64,
    /// The piston's speed when the halt began, m/s.
    pub speed_mps: f64,
    /// Smallest head clearance from the halt to the end, m.
    pub min_clearance_m: f64,
    /// Faults reported (telemetry and log) from the halt on, in order of number.
    pub faults: Vec<String>,
    /// The mode of the last telemetry frame.
    pub final_mode: ModeKind,
    /// The piston's speed at the end, m/s.
    pub final_speed_mps: f64,
}

/// Where the piston rests at power-on, m from head A (homing is then short).
const START_POSITION_M: f64 = 1e-3;

/// How long each fork runs after the resume, s: the brake from full speed and the hold (the
/// short-circuit brake of `encoder_signal` still leaves ≈ 0.05 m/s at 0.2 s).
pub const AFTER_RESUME_S: f64 = 0.3;

/// Boots the ELF on the reference machine at `pressure_ratio`, homes, starts the strokes,
/// runs `settle_s`, then halts at `phases` instants over one stroke cycle for each of
/// `durations_s`. Returns the cases in phase order, then duration order.
pub fn halts_over_a_cycle(
    image: &Image,
    pressure_ratio: f64,
    phases: std::ops::Range<usize>,
    of_phases: usize,
    durations_s: &[f64],
) -> Result<Vec<HaltCase>, String> {
    let opts = RunOptions {
        pressure_ratio,
        ..RunOptions::reference()
    };
    opts.validate()?;
    let record = crate::run::commissioned(&opts)?;
    let store = hal_sim::board::flash::holding(&record)?;
    let mut world = hal_sim::run::world(&opts.model, opts.seed, 0, START_POSITION_M);
    world.plant.lines.set_pressure_ratio(pressure_ratio);
    let mut s = Session::new(image.clone(), Board::new(world), ChipOptions::default())?;
    s.chip.soc().flash.load_image(store.image());
    while !s.send(Command::Home) {
        s.step()?;
    }
    while !(s.status.homed && s.status.mode == ModeKind::Holding) {
        s.step()?;
        if s.chip.time_s() > 30.0 {
            return Err("homing did not end".into());
        }
    }
    s.chip.soc().board.world.plant.port_mode = PortMode::Timed;
    s.send(Command::Start {
        peak_speed_mps: opts.peak_speed_mps() as f32,
    });
    // Steady strokes, then one cycle: dead point A to dead point A (the piston's position
    // turning from falling to rising).
    let settle = s.chip.time_s() + 0.25;
    while s.chip.time_s() < settle {
        s.step()?;
    }
    fork_agrees(&mut s, 1000)?;
    let settle = s.chip.time_s();
    let mut dead_points = Vec::new();
    let mut last = (f64::NAN, f64::NAN);
    while dead_points.len() < 2 {
        s.step()?;
        let x = s.chip.soc_ref().board.world.plant.x_m;
        if last.1 < last.0 && x > last.1 && last.1 < 0.05 {
            dead_points.push(s.chip.time_s());
        }
        last = (last.1, x);
        if s.chip.time_s() > settle + 2.0 {
            return Err("no stroke cycle within 2 s".into());
        }
    }
    if !s.faults.is_empty() {
        return Err(format!(
            "faults before any halt: {:?}",
            s.faults.iter().map(|f| f.name()).collect::<Vec<_>>()
        ));
    }
    let cycle_s = dead_points[1] - dead_points[0];
    let t0 = dead_points[1];
    let mut cases = Vec::new();
    for phase in phases {
        let at = t0 + cycle_s * phase as f64 / of_phases as f64;
        while s.chip.time_s() < at {
            s.step()?;
        }
        for &d in durations_s {
            let mut f = s.fork()?;
            cases.push(halt_once(&mut f, phase, d)?);
        }
    }
    Ok(cases)
}

/// The fork's witness: a fork of `s` and `s` itself run `periods` PWM periods side by side
/// and must agree bit for bit (the piston's position, the emulated time, the instructions
/// executed).
pub fn fork_agrees(s: &mut Session, periods: u32) -> Result<(), String> {
    let mut b = s.fork()?;
    for _ in 0..periods {
        s.step()?;
        b.step()?;
    }
    let a = &*s;
    let key = |x: &Session| {
        let soc = x.chip.soc_ref();
        (
            soc.board.world.plant.x_m.to_bits(),
            soc.time,
            soc.instructions,
        )
    };
    if key(a) != key(&b) {
        return Err(format!(
            "a fork and its original disagree after {periods} periods: {:?} / {:?}",
            key(a),
            key(&b)
        ));
    }
    Ok(())
}

/// Halts `s` for `halted_s` through the debug port, resumes it, and runs it on.
fn halt_once(s: &mut Session, phase: usize, halted_s: f64) -> Result<HaltCase, String> {
    let before = s.faults;
    let at_s = s.chip.time_s();
    let speed_mps = s.chip.soc_ref().board.world.plant.v_mps.abs();
    let mut min = f64::INFINITY;
    let mut watch = |s: &Session| {
        min = min.min(s.chip.soc_ref().board.world.plant.head_clearance_m());
    };
    let dap = |e: crate::chip::ChipError| e.to_string();
    s.chip
        .dap_write(addr::DHCSR, DBGKEY | C_DEBUGEN | C_HALT)
        .map_err(dap)?;
    while s.chip.time_s() < at_s + halted_s {
        s.step()?;
        watch(s);
    }
    s.chip
        .dap_write(addr::DHCSR, DBGKEY | C_DEBUGEN)
        .map_err(dap)?;
    let end = s.chip.time_s() + AFTER_RESUME_S;
    while s.chip.time_s() < end {
        s.step()?;
        watch(s);
    }
    let faults = s
        .faults
        .iter()
        .filter(|f| !before.contains(*f))
        .map(|f| f.name().to_string())
        .collect();
    Ok(HaltCase {
        phase,
        at_s,
        halted_s,
        speed_mps,
        min_clearance_m: min,
        faults,
        final_mode: s.status.mode,
        final_speed_mps: s.chip.soc_ref().board.world.plant.v_mps.abs(),
    })
}
