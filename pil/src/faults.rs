//! Faults on the real binary (`docs/faults.md`): each scenario boots the release ELF
//! on the reference machine with a calibration in its flash, injects one fault in the
//! emulated hardware, and reports what the firmware did — resets, its defmt log, what the
//! host saw over telemetry, the head clearance.
//!
//! | scenario | injected |
//! |---|---|
//! | [`Scenario::BootWindow`] | the ADCs never convert: the control task never checks in |
//! | [`Scenario::HungControl`] | the control executor spins for ever while stroking |
//! | [`Scenario::FaultPath`] | a bus error (HardFault) in the control executor while stroking |
//! | [`Scenario::PanicOnStop`] | the `Stop` command while stroking, to the `test-panic-on-stop` build (it panics) |
//! | [`Scenario::TornSave`] | the supply cut during a calibration save, the torn double word ECC-poisoned |
//! | [`Scenario::TornSaveStaleFlag`] | the same, with a stale PGSERR in FLASH_SR when the next boot's read meets the torn word (a stray write to the array between operations, ERRIE off) |
//! | [`Scenario::TornSaveInMotion`] | a save started as the strokes start: one of its double words fails (ECC-poisoned, the power on), and its read-back meets it at speed |
//! | [`Scenario::SaveError`] | the flash controller ends a save's program with PROGERR |
//! | [`Scenario::EraseError`] | a save that must erase a page: the erase ends with OPERR |
//! | [`Scenario::SingleBank`] | option bytes with DBANK = 0 |
//! | [`Scenario::FactoryBrownOut`] | option bytes as shipped: BOR_LEV = 0 (≈ 1.7 V) |
//! | [`Scenario::SupplyLoss`] | the mains stops while stroking: the board runs on the plant's DC link, PB5 (power good) falls with it |
//! | [`Scenario::Overcurrent`] | section 1's phase U current steps to 120 A while stroking (the comparator trips at 85 A) |
//! | [`Scenario::DebugHalt`] | a debugger halts the core while stroking, for [`Options::halt_s`] (DBGMCU's freezes as the firmware set them) |
//! | [`Scenario::BareBench`] | nothing connected for 2 s after reset (PB5 low, the encoders' inputs flat, the pressure inputs at 0 V), then the DC link and the sensors appear |
//! | [`Scenario::ProbeCapture`] | no fault: while stroking, the host captures the link for [`Options::capture_s`] through a probe on the emulated SWD port, as `fpc-sim link` attaches (the memory access port alone) |
//! | [`Scenario::ProbeSession`] | the same through a `probe_rs::Session`, as probe-rs's tools attach: the witness that the chip sees a halting attach |
//! | [`Scenario::BusyLink`] | no fault at first: telemetry every control cycle (20 kHz) with the scope armed (recording, never fired) while stroking; then the over-current for 2 ms, and `ClearFaults` once it is gone |

use fpc::control::calibration::Routine;
use fpc::control::command::{Command, Refusal};
use fpc::link::scope::Trigger;
use fpc::link::settings::LinkRequest;
use fpc::link::telemetry::ChannelSet;
use fpc::safety::absent::Absent;
use fpc::status::ModeKind;
use fpc::units::DacCode;
use hal_sim::plant::chambers::PortMode;
use hal_sim::run::RunOptions;

use fpc::control::calibration::record::CalibrationRecord;
use hal_sim::board::flash::SimFlash;

use crate::board::Board;
use crate::chip::{flash, ChipOptions, ResetRecord};
use crate::elf::Image;
use crate::session::Session;

/// A fault scenario.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scenario {
    /// Item 1: the boot window.
    BootWindow,
    /// A hung control task: watchdog reset, then the brake after it.
    HungControl,
    /// Item 2: a fault while running ends in the fault path's own reset, its cause logged
    /// by the next boot.
    FaultPath,
    /// A panic while stroking (the `test-panic-on-stop` test build panics on `Stop`): the
    /// fault path's reset, the panic's place kept across it and logged by the next boot.
    PanicOnStop,
    /// Item 4: a power cut during a save.
    TornSave,
    /// A power cut during a save, and a stale error flag when the NMI repairs the torn word.
    TornSaveStaleFlag,
    /// A double word of a save fails while the piston strokes: the NMI at speed.
    TornSaveInMotion,
    /// Item 5: a flash error flag during a save.
    SaveError,
    /// A page erase inside a save fails (OPERR).
    EraseError,
    /// Item 6: DBANK = 0.
    SingleBank,
    /// The brown-out reset at the factory's level 0.
    FactoryBrownOut,
    /// A supply loss while stroking (`docs/faults.md` #24): the firmware reads PB5 low and
    /// brakes on the DC link's energy.
    SupplyLoss,
    /// A phase current above the hardware trip's threshold while stroking: the comparator
    /// and the timer's break switch the bridge off, the firmware reports `Overcurrent`.
    Overcurrent,
    /// The link at its busiest while stroking (telemetry at 20 kHz, the scope armed), an
    /// over-current, then `ClearFaults`: the control period's deadline under the most the
    /// link asks of the firmware.
    BusyLink,
    /// The first power-up on the bench: nothing connected but the probe for 2 s (the DC
    /// link off, the encoders and the pressure sensors absent), then they appear and the
    /// machine is calibrated, homed and started.
    BareBench,
    /// A debugger halts the core while stroking ([`Options::halt_s`]), then resumes it.
    DebugHalt,
    /// No fault: a capture through the host's probe link while stroking.
    ProbeCapture,
    /// The witness: the same through a `probe_rs::Session`.
    ProbeSession,
}

impl Scenario {
    /// Every scenario.
    pub const ALL: [Scenario; 18] = [
        Scenario::BootWindow,
        Scenario::HungControl,
        Scenario::FaultPath,
        Scenario::PanicOnStop,
        Scenario::TornSave,
        Scenario::TornSaveStaleFlag,
        Scenario::TornSaveInMotion,
        Scenario::SaveError,
        Scenario::EraseError,
        Scenario::SingleBank,
        Scenario::FactoryBrownOut,
        Scenario::SupplyLoss,
        Scenario::Overcurrent,
        Scenario::BusyLink,
        Scenario::BareBench,
        Scenario::DebugHalt,
        Scenario::ProbeCapture,
        Scenario::ProbeSession,
    ];

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::BootWindow => "boot-window",
            Scenario::HungControl => "hung-control",
            Scenario::FaultPath => "fault-path",
            Scenario::PanicOnStop => "panic-on-stop",
            Scenario::TornSave => "torn-save",
            Scenario::TornSaveStaleFlag => "torn-save-stale-flag",
            Scenario::TornSaveInMotion => "torn-save-in-motion",
            Scenario::SaveError => "save-error",
            Scenario::EraseError => "erase-error",
            Scenario::SingleBank => "single-bank",
            Scenario::FactoryBrownOut => "factory-brown-out",
            Scenario::SupplyLoss => "supply-loss",
            Scenario::Overcurrent => "overcurrent",
            Scenario::BusyLink => "busy-link",
            Scenario::BareBench => "bare-bench",
            Scenario::DebugHalt => "debug-halt",
            Scenario::ProbeCapture => "probe-capture",
            Scenario::ProbeSession => "probe-session",
        }
    }
}

/// What a scenario showed.
#[derive(Clone, Debug)]
pub struct Report {
    /// The scenario.
    pub scenario: Scenario,
    /// When the fault was injected, emulated s.
    pub injected_at_s: Option<f64>,
    /// Resets after power-on.
    pub resets: Vec<ResetRecord>,
    /// The defmt log, with emulated times.
    pub log: Vec<(f64, String)>,
    /// The last telemetry status's mode and first fault, if any frame came.
    pub final_mode: Option<ModeKind>,
    /// Faults seen (frames and log).
    pub faults: Vec<String>,
    /// Smallest head clearance over the scenario (from the strokes' start where the machine
    /// strokes: homing touches head A on purpose), m.
    pub min_clearance_m: f64,
    /// When it was reached, emulated s.
    pub min_clearance_at_s: f64,
    /// Smallest head clearance from the injection on, m (infinite if nothing was injected
    /// while the machine stroked).
    pub min_clearance_after_m: f64,
    /// Emulated time at the end, s.
    pub end_s: f64,
    /// The boots' milestones.
    pub milestones: Vec<(f64, crate::chip::Milestone)>,
    /// The calibration record the board held before the scenario (its encoded bytes).
    pub record_before: Vec<u8>,
    /// The calibration store's pages at the end.
    pub store_after: Vec<u8>,
    /// Telemetry frames the host received.
    pub telemetry_frames: u64,
    /// Answers on up 2: (accepted, refused).
    pub answers: (u32, u32),
    /// The breaks the bridges' timers took from their break inputs.
    pub breaks: Vec<crate::chip::BreakRecord>,
    /// Plant periods after the first break in which the tripped bridge switched again.
    pub switched_after_break: u64,
    /// The stack's use at the end (since the last boot's paint).
    pub stack: Option<crate::stack::StackUse>,
    /// Every sample's duties against their update event, over the whole scenario
    /// ([`crate::chip::deadline`]).
    pub deadline: crate::chip::DeadlineFigures,
    /// What [`Scenario::BareBench`] showed.
    pub bare: Option<BareBench>,
    /// Halts of the core (a debugger's), since power-on.
    pub halts: u32,
    /// What [`Scenario::ProbeCapture`] or [`Scenario::ProbeSession`] showed.
    pub capture: Option<crate::capture::ProbeCapture>,
    /// With [`Options::profile_periods`]: the periods with the most cycles, most first.
    pub profile: Vec<crate::run::PeriodProfile>,
    /// The samples that missed their update: (their burst's end, emulated s; the write,
    /// cycles after it).
    pub missed: Vec<(f64, Option<u64>)>,
}

/// What the bare bench showed ([`Scenario::BareBench`]).
#[derive(Clone, Debug, Default)]
pub struct BareBench {
    /// PWM periods with nothing connected.
    pub periods: u64,
    /// Of them, periods in which a bridge's gates switched, as TIM1's and TIM8's output
    /// stages drive them from their registers (MOE, OSSI/OSSR, OISx, CCxE/CCxNE, the modes).
    pub gates_on: u64,
    /// Of them, periods in which the servo's DAC was not at zero torque.
    pub servo_driven: u64,
    /// The parts the last telemetry frame with nothing connected reported absent.
    pub absent: Absent,
    /// The faults seen with nothing connected (frames and log).
    pub faults: Vec<String>,
    /// The commands refused with nothing connected (`ClearFaults`, `Calibrate`), and why.
    pub refused: Vec<(Command, Refusal)>,
    /// Once the parts appeared: the frames reported none absent, s after they appeared.
    pub present_after_s: Option<f64>,
    /// Then: `Calibrate current_sense` ran and ended without a fault.
    pub calibrated: bool,
    /// Then homed and started: the mode of the last frame, 1 s after `Start`.
    pub mode_at_end: Option<ModeKind>,
    /// The commands refused after the parts appeared.
    pub refused_after: Vec<(Command, Refusal)>,
}

impl Report {
    /// Log lines containing `text`.
    pub fn lines(&self, text: &str) -> Vec<&(f64, String)> {
        self.log.iter().filter(|(_, l)| l.contains(text)).collect()
    }
}

/// Where the piston rests at power-on, m from head A.
const START_POSITION_M: f64 = 1e-3;

/// How long a scenario with the machine stroking goes on after the injection, s: the
/// watchdog's 2 ms, the boot's 2.4 ms, the brake from full speed (≈ 10 ms), with room.
const AFTER_INJECTION_S: f64 = 0.15;

/// Where and how hard a scenario with the machine stroking injects its fault.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// The fault comes this long after the Start command, s.
    pub inject_after_start_s: f64,
    /// Pressure ratio (the peak speed follows it, as in `fpc-sim run`).
    pub pressure_ratio: f64,
    /// `None` (the default): emulated time runs on the counted cycles; `Some(cpi)`: at this
    /// CPI ([`ChipOptions::cpi`]).
    pub cpi: Option<f64>,
    /// How long [`Scenario::DebugHalt`] halts the core, s.
    pub halt_s: f64,
    /// How long [`Scenario::ProbeCapture`] and [`Scenario::ProbeSession`] capture, s.
    pub capture_s: f64,
    /// Profile this many of the periods whose interrupt path took the most cycles, over the
    /// whole scenario ([`Report::profile`]; 0: none).
    pub profile_periods: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            inject_after_start_s: 0.25,
            pressure_ratio: RunOptions::reference().pressure_ratio,
            cpi: None,
            halt_s: 0.005,
            capture_s: 10.0,
            profile_periods: 0,
        }
    }
}

/// Runs `scenario` on `image` with the default [`Options`].
pub fn run(image: &Image, scenario: Scenario) -> Result<Report, String> {
    run_with(image, scenario, &Options::default())
}

/// The smallest head clearance over a stretch of the scenario, and when.
#[derive(Clone, Copy, Debug)]
struct Clearance {
    min_m: f64,
    at_s: f64,
}

impl Clearance {
    const NONE: Clearance = Clearance {
        min_m: f64::INFINITY,
        at_s: 0.0,
    };
}

/// A scenario in progress: the session and what is measured along it.
struct Run {
    s: Session,
    clearance: Clearance,
    after_injection_m: f64,
    injected_at: Option<f64>,
    speed: f32,
    /// Periods after the first break in which the bridge it tripped switched again.
    switched_after_break: u64,
}

impl Run {
    /// One PWM period, the clearance noted.
    fn step(&mut self) -> Result<(), String> {
        // The period in which a break comes ends with its crossing (the comparators see the
        // plant step's currents): only the periods that start after it count.
        let broken_before = !self.s.chip.soc_ref().breaks.is_empty();
        self.s.step()?;
        let soc = self.s.chip.soc_ref();
        if let Some(b) = soc.breaks.first().filter(|_| broken_before) {
            let on = soc.board.world.sections_on;
            if [on.master, on.slave][b.timer] {
                self.switched_after_break += 1;
            }
        }
        let c = self.s.chip.soc_ref().board.world.plant.head_clearance_m();
        if c < self.clearance.min_m {
            self.clearance = Clearance {
                min_m: c,
                at_s: self.s.chip.time_s(),
            };
        }
        Ok(())
    }

    /// Steps until emulated time `t`, s.
    fn until(&mut self, t: f64) -> Result<(), String> {
        while self.s.chip.time_s() < t {
            self.step()?;
        }
        Ok(())
    }

    /// Homes the machine and closes the bypass (the ports timed by the rotation).
    fn home(&mut self) -> Result<(), String> {
        while !self.s.send(Command::Home) {
            self.step()?;
        }
        while !(self.s.status.homed && self.s.status.mode == ModeKind::Holding) {
            self.step()?;
            if self.s.chip.time_s() > 30.0 {
                return Err("homing did not end".into());
            }
        }
        self.s.chip.soc().board.world.plant.port_mode = PortMode::Timed;
        Ok(())
    }

    /// Starts the strokes; the clearance counts from here (homing touches head A on purpose).
    fn start_strokes(&mut self) {
        self.s.send(Command::Start {
            peak_speed_mps: self.speed,
        });
        self.clearance = Clearance::NONE;
    }

    /// Marks the injection now and runs `for_s` more; the clearance after it is kept apart.
    fn inject_and_follow(&mut self, for_s: f64) -> Result<(), String> {
        self.injected_at = Some(self.s.chip.time_s());
        let before = self.clearance;
        self.clearance = Clearance::NONE;
        let t = self.s.chip.time_s() + for_s;
        self.until(t)?;
        self.after_injection_m = self.clearance.min_m;
        if before.min_m < self.clearance.min_m {
            self.clearance = before;
        }
        Ok(())
    }
}

/// Runs `scenario` on `image`.
pub fn run_with(image: &Image, scenario: Scenario, opts: &Options) -> Result<Report, String> {
    let run_opts = RunOptions {
        pressure_ratio: opts.pressure_ratio,
        ..RunOptions::reference()
    };
    run_opts.validate()?;
    let record = crate::run::commissioned(&run_opts)?;
    let store = match scenario {
        // A store whose next save must erase a page (the save then outlasts the strokes'
        // start by that erase's 22 ms).
        Scenario::EraseError | Scenario::TornSaveInMotion => store_before_an_erase(&record)?,
        _ => hal_sim::board::flash::holding(&record)?,
    };
    // The piston rests 1 mm from head A, so that homing (which creeps to it) is short.
    let mut world = hal_sim::run::world(&run_opts.model, run_opts.seed, 0, START_POSITION_M);
    world
        .plant
        .lines
        .set_pressure_ratio(run_opts.pressure_ratio);
    let mut chip = ChipOptions {
        cpi: opts.cpi,
        ..ChipOptions::default()
    };
    if scenario == Scenario::SingleBank {
        chip.optr &= !flash::OPTR_DBANK;
    }
    if scenario == Scenario::FactoryBrownOut {
        chip.optr = flash::OPTR_FACTORY;
    }
    let mut s = Session::new(image.clone(), Board::new(world), chip)?;
    s.chip.soc().flash.load_image(store.image());
    s.chip.soc().recording = true;
    if opts.profile_periods > 0 {
        s.chip.soc().profile = true;
        s.chip.soc().profile_keep = opts.profile_periods;
    }
    let mut r = Run {
        s,
        clearance: Clearance::NONE,
        after_injection_m: f64::INFINITY,
        injected_at: None,
        speed: run_opts.peak_speed_mps() as f32,
        switched_after_break: 0,
    };
    let mut bare = None;
    let mut capture = None;
    match scenario {
        Scenario::BootWindow => {
            r.s.chip.soc().adc_dead = true;
            r.injected_at = Some(0.0);
            while r.s.chip.soc_ref().resets.is_empty() && r.s.chip.time_s() < 0.7 {
                r.step()?;
            }
        }
        Scenario::SingleBank | Scenario::FactoryBrownOut => r.until(0.1)?,
        Scenario::HungControl
        | Scenario::FaultPath
        | Scenario::PanicOnStop
        | Scenario::SupplyLoss
        | Scenario::DebugHalt
        | Scenario::Overcurrent => stroke_then_inject(&mut r, scenario, opts)?,
        Scenario::TornSave | Scenario::TornSaveStaleFlag => torn_save(&mut r, scenario)?,
        Scenario::TornSaveInMotion => torn_save_in_motion(&mut r)?,
        Scenario::SaveError | Scenario::EraseError => save_error(&mut r, scenario)?,
        Scenario::BusyLink => busy_link(&mut r)?,
        Scenario::BareBench => bare = Some(bare_bench(&mut r)?),
        Scenario::ProbeCapture => {
            let how = crate::capture::Attach::Link;
            let figures = probe_capture(&mut r, &image.bytes, how, opts.capture_s)?;
            capture = Some(figures);
        }
        Scenario::ProbeSession => {
            let how = crate::capture::Attach::Session;
            let figures = probe_capture(&mut r, &image.bytes, how, opts.capture_s)?;
            capture = Some(figures);
        }
    }
    let soc = r.s.chip.soc_ref();
    Ok(Report {
        scenario,
        injected_at_s: r.injected_at,
        resets: soc.resets.clone(),
        log: r.s.log.lines.clone(),
        final_mode: (r.s.frames > 0).then_some(r.s.status.mode),
        faults: r.s.faults.iter().map(|f| f.name().to_string()).collect(),
        min_clearance_m: r.clearance.min_m,
        min_clearance_at_s: r.clearance.at_s,
        min_clearance_after_m: r.after_injection_m,
        end_s: r.s.chip.time_s(),
        milestones: soc.milestones.clone(),
        record_before: record.encode().to_vec(),
        store_after: soc.flash.store.clone(),
        breaks: soc.breaks.clone(),
        switched_after_break: r.switched_after_break,
        stack: crate::stack::stack_use(&r.s.chip),
        deadline: crate::chip::DeadlineFigures::of(&soc.samples),
        telemetry_frames: r.s.frames,
        answers: r.s.answers_seen,
        bare,
        halts: soc.halts,
        capture,
        profile: crate::run::period_profiles(image, &soc.profile_top),
        missed: soc
            .samples
            .iter()
            .filter(|s| s.missed)
            .map(|s| (crate::time::seconds(s.end), s.write_cycles))
            .collect(),
    })
}

/// How long [`Scenario::BareBench`] keeps the bench bare after reset, s.
const BARE_S: f64 = 2.0;

/// [`Scenario::BareBench`]: nothing connected for [`BARE_S`] after reset, the outputs and the
/// servo watched every period; at 1 s the host sends `ClearFaults` and `Calibrate
/// current_sense`. Then the DC link and the sensors appear: once the frames report nothing
/// absent, `Calibrate current_sense`, `Home`, `Start`, and 1 s of strokes.
fn bare_bench(r: &mut Run) -> Result<BareBench, String> {
    r.s.chip.soc().board.bare = true;
    let mut b = BareBench::default();
    let mut asked = false;
    while r.s.chip.time_s() < BARE_S {
        r.step()?;
        let w = &r.s.chip.soc_ref().board.world;
        b.periods += 1;
        b.gates_on += u64::from(w.enabled);
        b.servo_driven += u64::from(w.servo_code != DacCode::MID);
        if !asked && r.s.chip.time_s() >= 1.0 {
            asked = r.s.send(Command::ClearFaults)
                && r.s.send(Command::Calibrate {
                    routine: Routine::CurrentSense,
                });
        }
    }
    b.absent = r.s.status.absent;
    b.faults = r.s.faults.iter().map(|f| f.name().to_string()).collect();
    b.refused = r.s.refused.clone();
    r.s.chip.soc().board.bare = false;
    r.injected_at = Some(r.s.chip.time_s());
    let appeared = r.s.chip.time_s();
    while b.present_after_s.is_none() && r.s.chip.time_s() < appeared + 0.5 {
        r.step()?;
        if r.s.fresh && r.s.status.absent.is_empty() {
            b.present_after_s = Some(r.s.chip.time_s() - appeared);
        }
    }
    r.s.send(Command::Calibrate {
        routine: Routine::CurrentSense,
    });
    let deadline = r.s.chip.time_s() + 2.0;
    let mut began = false;
    while r.s.chip.time_s() < deadline {
        r.step()?;
        began |= r.s.status.mode == ModeKind::Calibrating;
        if began && r.s.status.mode != ModeKind::Calibrating {
            break;
        }
    }
    b.calibrated = began && r.s.status.faults.is_empty();
    let refused_before = r.s.refused.len();
    r.home()?;
    r.start_strokes();
    let t = r.s.chip.time_s() + 1.0;
    r.until(t)?;
    b.mode_at_end = Some(r.s.status.mode);
    b.refused_after = r.s.refused[refused_before..].to_vec();
    Ok(b)
}

/// [`Scenario::BusyLink`]: homes, asks for every channel at every control cycle and arms
/// the scope (recording every cycle, fired by the host's command, which never comes),
/// strokes for 0.3 s, steps section 1's phase U to 120 A for 2 ms (the hardware trip,
/// `Overcurrent`), and 50 ms after the current is gone sends `ClearFaults`, then follows
/// 0.1 s.
fn busy_link(r: &mut Run) -> Result<(), String> {
    r.home()?;
    r.s.request(&LinkRequest::SetTelemetry {
        decimation: 1,
        channels: ChannelSet::ALL,
    });
    r.s.request(&LinkRequest::ScopeArm {
        trigger: Trigger::Command,
        pre: 100,
    });
    r.start_strokes();
    let t = r.s.chip.time_s() + 0.3;
    r.until(t)?;
    r.s.chip.soc().board.current_step = Some(crate::board::CurrentStep {
        section: 0,
        phase: 0,
        amps: 120.0,
    });
    r.injected_at = Some(r.s.chip.time_s());
    let t = r.s.chip.time_s() + 0.002;
    r.until(t)?;
    r.s.chip.soc().board.current_step = None;
    let t = r.s.chip.time_s() + 0.05;
    r.until(t)?;
    r.s.send(Command::ClearFaults);
    let t = r.s.chip.time_s() + 0.1;
    r.until(t)
}

/// Homes, starts the strokes and injects `scenario`'s fault at full speed.
fn stroke_then_inject(r: &mut Run, scenario: Scenario, opts: &Options) -> Result<(), String> {
    r.home()?;
    r.start_strokes();
    let t = r.s.chip.time_s() + opts.inject_after_start_s;
    r.until(t)?;
    match scenario {
        Scenario::HungControl => r.s.chip.soc().hang_pending = true,
        Scenario::FaultPath => r.s.chip.soc().bus_fault_pending = true,
        Scenario::SupplyLoss => r.s.chip.soc().board.world.plant.supply.cut(),
        Scenario::DebugHalt => {
            let units = (opts.halt_s * 1e6) as u64 * crate::time::UNITS_PER_US;
            r.s.chip.soc().halt_for(units);
        }
        Scenario::Overcurrent => {
            r.s.chip.soc().board.current_step = Some(crate::board::CurrentStep {
                section: 0,
                phase: 0,
                amps: 120.0,
            });
        }
        _ => {
            r.s.send(Command::Stop);
        }
    }
    r.inject_and_follow(AFTER_INJECTION_S)
}

/// A `Calibrate current_sense` whose save the supply cuts at its third flash step, leaving a
/// torn, ECC-poisoned double word; 20 ms later the power is back, and the boots that follow.
/// With [`Scenario::TornSaveStaleFlag`], a stray write into the flash array (PG clear, ERRIE
/// off between operations: no interrupt clears it) leaves PGSERR standing when the boot's
/// read meets the torn word.
fn torn_save(r: &mut Run, scenario: Scenario) -> Result<(), String> {
    r.until(0.01)?;
    let steps = r.s.chip.soc_ref().flash.steps;
    r.s.chip.soc().flash.faults.cut_power_at_step = Some(steps + 3);
    r.s.send(Command::Calibrate {
        routine: Routine::CurrentSense,
    });
    let deadline = r.s.chip.time_s() + 2.0;
    while r.s.chip.soc_ref().powered {
        r.step()?;
        if r.s.chip.time_s() > deadline {
            return Err("the save never reached the armed flash step".into());
        }
    }
    r.injected_at = Some(r.s.chip.time_s());
    // 20 ms without supply, then power again: the boots that follow.
    let t = r.s.chip.time_s() + 0.02;
    r.until(t)?;
    r.s.chip.power_on().map_err(|e| e.to_string())?;
    if scenario == Scenario::TornSaveStaleFlag {
        let now = r.s.chip.soc_ref().time;
        r.s.chip
            .soc()
            .flash
            .write_array(flash::STORE_BASE + 0x100, 0, 4, now);
    }
    let t = r.s.chip.time_s() + 1.0;
    r.until(t)
}

/// Homes, runs `Calibrate current_sense` and starts the strokes as soon as it ends, while its
/// save (which must erase a page first) still runs; the save's fifth double word fails
/// (ECC-poisoned, the power on), and the save's read-back meets it with the piston moving.
fn torn_save_in_motion(r: &mut Run) -> Result<(), String> {
    r.home()?;
    r.s.chip.soc().flash.faults.tear_on_program = Some(5);
    r.s.send(Command::Calibrate {
        routine: Routine::CurrentSense,
    });
    let deadline = r.s.chip.time_s() + 2.0;
    while r.s.status.mode != ModeKind::Calibrating {
        r.step()?;
        if r.s.chip.time_s() > deadline {
            return Err("the calibration never began".into());
        }
    }
    while r.s.status.mode == ModeKind::Calibrating {
        r.step()?;
        if r.s.chip.time_s() > deadline {
            return Err("the calibration never ended".into());
        }
    }
    r.start_strokes();
    while r.s.chip.soc_ref().flash.poisoned.is_empty() {
        r.step()?;
        if r.s.chip.time_s() > deadline + 1.0 {
            return Err("the save never reached its fifth double word".into());
        }
    }
    r.inject_and_follow(AFTER_INJECTION_S)
}

/// A `Calibrate current_sense` whose save meets a flash error: [`Scenario::SaveError`], its
/// fourth program step ends with PROGERR (a step whose loss the storage crate does not notice
/// by itself); [`Scenario::EraseError`], its page erase ends with OPERR.
fn save_error(r: &mut Run, scenario: Scenario) -> Result<(), String> {
    r.until(0.01)?;
    let faults = &mut r.s.chip.soc().flash.faults;
    if scenario == Scenario::EraseError {
        faults.error_on_erase = Some(1);
    } else {
        let steps = r.s.chip.soc_ref().flash.steps;
        r.s.chip.soc().flash.faults.error_on_program =
            flash::error_flag("progerr").map(|f| (steps + save_error_step(), f));
    }
    r.s.send(Command::Calibrate {
        routine: Routine::CurrentSense,
    });
    let deadline = r.s.chip.time_s() + 2.0;
    while r.s.chip.time_s() < deadline {
        r.step()?;
        if r.s
            .log
            .lines
            .iter()
            .any(|(_, l)| l.contains("calibration") && l.contains("saved"))
        {
            r.injected_at = Some(r.s.chip.time_s());
            break;
        }
    }
    let t = r.s.chip.time_s() + 1.0;
    r.until(t)
}

/// A store holding `record` saved as many times as leaves the next save to erase a page
/// first (the store's pages then all hold items), by the firmware's own store on hal-sim's
/// simulated flash.
fn store_before_an_erase(record: &CalibrationRecord) -> Result<SimFlash, String> {
    use hal_sim::board::flash::{block_on, store};
    let mut flash = SimFlash::new(hal_sim::board::flash::STORE_PAGES);
    for _ in 0..400 {
        let mut next = store(flash.reboot())?;
        let wear: u32 = flash.wear().iter().sum();
        block_on(next.save(record)).map_err(|e| format!("saving to the simulated flash: {e:?}"))?;
        let after = next.into_flash();
        if after.wear().iter().sum::<u32>() > wear {
            return Ok(flash);
        }
        flash = after;
    }
    Err("400 saves never erased a page".into())
}

/// Which program step of the save fails in [`Scenario::SaveError`] (counted from 1).
fn save_error_step() -> u64 {
    std::env::var("FPC_PIL_SAVE_ERROR_STEP")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4)
}

/// The host polls every this many PWM periods (1 ms, as `fpc-sim link capture` does).
const POLL_PERIODS: u64 = 20;

/// A dead point: the clearance turns from falling to rising below this, m.
const DEAD_POINT_BELOW_M: f64 = 0.01;

/// [`Scenario::ProbeCapture`], [`Scenario::ProbeSession`]: homes, starts the strokes and, 0.3 s on, hands the channels from the in-process host
/// to the host's thread, which attaches as `how` and captures for `seconds`; the machine
/// strokes on throughout.
fn probe_capture(
    r: &mut Run,
    elf: &[u8],
    how: crate::capture::Attach,
    seconds: f64,
) -> Result<crate::capture::ProbeCapture, String> {
    r.home()?;
    r.start_strokes();
    let t = r.s.chip.time_s() + 0.3;
    r.until(t)?;
    r.s.host_detached = true;
    let halts_before = r.s.chip.soc_ref().halts;
    let host = crate::capture::Host::start(how, elf.to_vec());
    let end = r.s.chip.time_s() + seconds;
    let mut polls = 0u64;
    let mut periods = 0u64;
    let mut dead_points = 0u64;
    let (mut last, mut falling) = (f64::INFINITY, false);
    let mut alive = host.turn(&mut r.s.chip, crate::probe::Turn::Go);
    while alive && r.s.chip.time_s() < end {
        r.step()?;
        periods += 1;
        let c = r.s.chip.soc_ref().board.world.plant.head_clearance_m();
        if falling && c > last && last < DEAD_POINT_BELOW_M {
            dead_points += 1;
        }
        falling = c < last;
        last = c;
        if periods.is_multiple_of(POLL_PERIODS) {
            alive = host.turn(&mut r.s.chip, crate::probe::Turn::Go);
            polls += 1;
        }
    }
    if alive {
        host.turn(&mut r.s.chip, crate::probe::Turn::Last);
    }
    let soc = r.s.chip.soc_ref();
    let mut figures = crate::capture::ProbeCapture {
        seconds,
        polls,
        dead_points,
        halts: soc.halts - halts_before,
        debug_register_touches: soc
            .dap
            .touches
            .iter()
            .map(|t| (t.address, t.written))
            .collect(),
        transfers: soc.dap.transfers,
        ..crate::capture::ProbeCapture::default()
    };
    match host.join() {
        Ok(end) => {
            figures.counters = end.counters;
            figures.rows = end.rows;
            figures.flash_refused = end.flash_refused;
        }
        Err(e) => figures.error = Some(e),
    }
    Ok(figures)
}
