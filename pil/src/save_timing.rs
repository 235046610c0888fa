//! The control step's period while a calibration save erases and programs flash (`fpc-pil
//! save-timing`). embassy-stm32 turns the flash data cache off around every erase and program
//! (FLASH_ACR.DCEN = 0; the firmware runs with ACR = 0x604: 4 wait states, instruction and data
//! cache on, prefetch off), so each read of a constant or a literal pool from program flash by the
//! interrupt path then waits for the flash. The emulator executes instructions, not cycles: this
//! scenario counts, per PWM period, what the interrupt path fetched and read from program flash,
//! and turns it into cycles with the wait states stated here.
//!
//! Scenario: the release ELF on the reference machine with a calibration in its store; the
//! `CurrentSense` routine, whose result the storage task saves (an erase and a record's
//! programs, in bank 2 while the code runs from bank 1: read-while-write, no stall of the
//! fetches themselves); then homing and 0.3 s of strokes, for the heaviest path.
//!
//! Cycle model, per period (RM0440 §3.3.3–3.3.4: a flash access is a 64-bit line and takes
//! LATENCY + 1 HCLK cycles; with LATENCY = 4 at 170 MHz, an access costs 4 cycles more than
//! a zero-wait one; PRFTEN = 0, so a sequential fetch into the next line waits too):
//! - the core's own cycles at zero wait states, counted per instruction (the chip's
//!   [`crate::chip::timing`], as for the `run` figure), plus 4 cycles per flash access;
//! - **caches on**: one access per distinct instruction line and per distinct data line of
//!   the period (each line missed once, then held; the period's code must fit the cache for
//!   this to hold, which is why the bound below is given too);
//! - **data cache off** (during a save): distinct instruction lines, plus *every* data read
//!   of program flash;
//! - **no cache at all** (the bound, whatever the caches hold): one access each time the
//!   fetch moves into another line, plus every data read.
//!
//! The vector fetch of each exception is one more flash read, counted in every model.

use fpc::control::calibration::Routine;
use fpc::control::command::Command;
use fpc::status::ModeKind;
use hal_sim::plant::chambers::PortMode;
use hal_sim::run::RunOptions;
use serde::Serialize;

use crate::board::Board;
use crate::chip::{ChipOptions, DeadlineFigures, PeriodLoad};
use crate::elf::Image;
use crate::run::{worst_profile_rows, ProfileRow, SYSCLK_HZ};
use crate::session::Session;

/// Flash wait states the firmware programs at 170 MHz (FLASH_ACR.LATENCY = 4, RM0440
/// Table 9, range 1 boost mode).
pub const FLASH_WAIT_STATES: f64 = 4.0;

/// The control period, µs (20 kHz).
pub const PERIOD_US: f64 = 50.0;

/// How long the strokes are watched, s.
const STROKING_S: f64 = 0.3;

/// The interrupt path of one class of periods, worst period of each cycle model.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PathFigures {
    /// Periods in the class.
    pub periods: usize,
    /// Largest interrupt path, instructions.
    pub instructions_max: u64,
    /// Largest count of distinct 64-bit instruction lines.
    pub lines_max: u32,
    /// Largest count of moves of the fetch into another line.
    pub line_entries_max: u32,
    /// Largest count of data reads of program flash.
    pub flash_reads_max: u32,
    /// Largest count of distinct 64-bit data lines read.
    pub data_lines_max: u32,
    /// Worst period with both caches on (each line missed once), µs.
    pub worst_us_caches_on: f64,
    /// Worst period with the data cache off (every flash data read waits), µs.
    pub worst_us_dcache_off: f64,
    /// Worst period with no cache at all (the bound), µs.
    pub worst_us_uncached: f64,
}

impl PathFigures {
    /// The figures of `periods`.
    pub fn of<'a>(periods: impl IntoIterator<Item = &'a PeriodLoad>) -> PathFigures {
        let mut f = PathFigures::default();
        let us = |cycles: f64| cycles / SYSCLK_HZ * 1e6;
        for p in periods {
            f.periods += 1;
            f.instructions_max = f.instructions_max.max(p.interrupt_path);
            f.lines_max = f.lines_max.max(p.path_lines);
            f.line_entries_max = f.line_entries_max.max(p.path_line_entries);
            f.flash_reads_max = f.flash_reads_max.max(p.path_flash_reads);
            f.data_lines_max = f.data_lines_max.max(p.path_data_lines);
            // The counted cycles without the chip's own (no-cache) flash wait states.
            let core = p.path_cycles.saturating_sub(p.path_wait_cycles) as f64;
            let vectors = f64::from(p.exceptions);
            let ws = FLASH_WAIT_STATES;
            let on = core + ws * (f64::from(p.path_lines + p.path_data_lines) + vectors);
            let dcache_off = core + ws * (f64::from(p.path_lines + p.path_flash_reads) + vectors);
            let none = core + ws * (f64::from(p.path_line_entries + p.path_flash_reads) + vectors);
            f.worst_us_caches_on = f.worst_us_caches_on.max(us(on));
            f.worst_us_dcache_off = f.worst_us_dcache_off.max(us(dcache_off));
            f.worst_us_uncached = f.worst_us_uncached.max(us(none));
        }
        f
    }
}

/// What the save-timing scenario measured.
#[derive(Clone, Debug, Serialize)]
pub struct SaveTiming {
    /// Flash wait states of the model.
    pub wait_states: f64,
    /// FLASH_ACR as the firmware left it while each erase or program ran.
    pub acr_during_operations: Vec<u32>,
    /// Idle and calibrating, no flash operation in the period.
    pub no_save: PathFigures,
    /// Periods during which an erase or program ran or the data cache was off.
    pub during_save: PathFigures,
    /// The strokes (no save): the heaviest path, and what it would take if a save
    /// overlapped it.
    pub stroking: PathFigures,
    /// The defmt line the save ended with.
    pub save_outcome: String,
    /// Where the interrupt path spent its cycles in the calibration phase's period with the
    /// most counted cycles (no cache: the chip's own count), by function, most cycles first.
    pub calibration_profile: Vec<ProfileRow>,
    /// The control period, µs.
    pub period_us: f64,
    /// The samples' duties against their update events while calibrating and saving, on
    /// the counted timeline ([`crate::chip::deadline`]).
    pub deadline_calibrating: DeadlineFigures,
    /// The same over the strokes.
    pub deadline_stroking: DeadlineFigures,
}

/// Runs the scenario on `image`.
pub fn run(image: &Image) -> Result<SaveTiming, String> {
    let opts = RunOptions::reference();
    let record = crate::run::commissioned(&opts)?;
    let store = hal_sim::board::flash::holding(&record)?;
    let mut world = hal_sim::run::world(&opts.model, opts.seed, 0, 1e-3);
    world.plant.lines.set_pressure_ratio(opts.pressure_ratio);
    let chip = ChipOptions {
        flash_timing: true,
        ..ChipOptions::default()
    };
    let mut s = Session::new(image.clone(), Board::new(world), chip)?;
    s.chip.soc().flash.load_image(store.image());
    let until = |s: &mut Session, t: f64| -> Result<(), String> {
        while s.chip.time_s() < t {
            s.step()?;
        }
        Ok(())
    };
    until(&mut s, 0.01)?;
    s.chip.soc().recording = true;
    s.chip.soc().profile = true;
    s.chip.soc().flash.acr_during_ops.clear();
    s.send(Command::Calibrate {
        routine: Routine::CurrentSense,
    });
    let deadline = s.chip.time_s() + 2.0;
    let outcome = loop {
        s.step()?;
        if let Some((_, line)) = s.log.lines.iter().find(|(_, l)| l.contains("saved")) {
            break line.clone();
        }
        if s.chip.time_s() > deadline {
            return Err("no save ended within 2 s of the Calibrate command".into());
        }
    };
    let t = s.chip.time_s() + 0.01;
    until(&mut s, t)?;
    let soc = s.chip.soc();
    soc.recording = false;
    soc.profile = false;
    let calibration_profile = worst_profile_rows(image, soc);
    let periods = std::mem::take(&mut soc.periods);
    let deadline_calibrating = DeadlineFigures::of(&std::mem::take(&mut soc.samples));
    let acr = soc.flash.acr_during_ops.clone();
    let (during, idle): (Vec<_>, Vec<_>) =
        periods.iter().partition(|p| p.flash_busy || p.dcache_off);
    if during.is_empty() {
        return Err("no period saw the save's flash operations".into());
    }

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
    s.chip.soc().recording = true;
    let t = s.chip.time_s() + STROKING_S;
    until(&mut s, t)?;
    if s.status.mode != ModeKind::Running {
        return Err(format!("not stroking after the Start: {:?}", s.status.mode));
    }
    let stroking = std::mem::take(&mut s.chip.soc().periods);
    let deadline_stroking = DeadlineFigures::of(&std::mem::take(&mut s.chip.soc().samples));

    Ok(SaveTiming {
        wait_states: FLASH_WAIT_STATES,
        acr_during_operations: acr,
        no_save: PathFigures::of(idle),
        during_save: PathFigures::of(during),
        stroking: PathFigures::of(&stroking),
        save_outcome: outcome,
        calibration_profile,
        period_us: PERIOD_US,
        deadline_calibrating,
        deadline_stroking,
    })
}
