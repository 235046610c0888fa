//! Faults on the real binary (`docs/faults.md`, issue #28 C): each scenario boots the release ELF
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
//! | [`Scenario::SaveError`] | the flash controller ends a save's program with PROGERR |
//! | [`Scenario::SingleBank`] | option bytes with DBANK = 0 |
//! | [`Scenario::SupplyLoss`] | the mains stops while stroking: the board runs on the plant's DC link, PB5 (power good) falls with it |

use fpc::control::calibration::Routine;
use fpc::control::command::Command;
use fpc::status::ModeKind;
use hal_sim::plant::chambers::PortMode;
use hal_sim::plant::model::MachineModel;
use hal_sim::run::RunOptions;

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
    /// Item 5: a flash error flag during a save.
    SaveError,
    /// Item 6: DBANK = 0.
    SingleBank,
    /// A supply loss while stroking (`docs/faults.md` #24): the firmware reads PB5 low and
    /// brakes on the DC link's energy.
    SupplyLoss,
}

impl Scenario {
    /// Every scenario.
    pub const ALL: [Scenario; 8] = [
        Scenario::BootWindow,
        Scenario::HungControl,
        Scenario::FaultPath,
        Scenario::PanicOnStop,
        Scenario::TornSave,
        Scenario::SaveError,
        Scenario::SingleBank,
        Scenario::SupplyLoss,
    ];

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::BootWindow => "boot-window",
            Scenario::HungControl => "hung-control",
            Scenario::FaultPath => "fault-path",
            Scenario::PanicOnStop => "panic-on-stop",
            Scenario::TornSave => "torn-save",
            Scenario::SaveError => "save-error",
            Scenario::SingleBank => "single-bank",
            Scenario::SupplyLoss => "supply-loss",
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
/// watchdog's 3 ms, the boot's 1.4 ms, the brake from full speed (≈ 10 ms), with room.
const AFTER_INJECTION_S: f64 = 0.15;

/// Where and how hard a scenario with the machine stroking injects its fault.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// The fault comes this long after the Start command, s.
    pub inject_after_start_s: f64,
    /// Pressure ratio (the peak speed follows it, as in `fpc-sim run`).
    pub pressure_ratio: f64,
    /// `Some(cpi)`: emulated time runs at this CPI; `None`: on the counted cycles
    /// ([`ChipOptions::cpi`]).
    pub cpi: Option<f64>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            inject_after_start_s: 0.25,
            pressure_ratio: RunOptions::reference().pressure_ratio,
            cpi: Some(crate::DEFAULT_CPI),
        }
    }
}

/// Runs `scenario` on `image` with the default [`Options`].
pub fn run(image: &Image, scenario: Scenario) -> Result<Report, String> {
    run_with(image, scenario, &Options::default())
}

/// Runs `scenario` on `image`.
pub fn run_with(image: &Image, scenario: Scenario, opts: &Options) -> Result<Report, String> {
    let scenario_opts = opts;
    let opts = RunOptions {
        pressure_ratio: scenario_opts.pressure_ratio,
        ..RunOptions::reference()
    };
    opts.validate()?;
    let record = crate::run::commissioned(&opts)?;
    let store = hal_sim::board::flash::holding(&record)?;
    // The piston rests 1 mm from head A, so that homing (which creeps to it) is short.
    let mut world = hal_sim::run::world(&opts.model, opts.seed, 0, START_POSITION_M);
    world.plant.lines.set_pressure_ratio(opts.pressure_ratio);
    let mut chip = ChipOptions {
        cpi: scenario_opts.cpi,
        ..ChipOptions::default()
    };
    if scenario == Scenario::SingleBank {
        chip.optr &= !flash::OPTR_DBANK;
    }
    let mut s = Session::new(image.clone(), Board::new(world), chip)?;
    s.chip.soc().flash.load_image(store.image());
    let mut min_clearance = (f64::INFINITY, 0.0);
    let mut after_injection = f64::INFINITY;
    let mut injected_at = None;
    let speed = opts.peak_speed_mps() as f32;
    let step = |s: &mut Session, min: &mut (f64, f64)| -> Result<(), String> {
        s.step()?;
        let c = s.chip.soc_ref().board.world.plant.head_clearance_m();
        if c < min.0 {
            *min = (c, s.chip.time_s());
        }
        Ok(())
    };
    let until = |s: &mut Session, min: &mut (f64, f64), t: f64| -> Result<(), String> {
        while s.chip.time_s() < t {
            step(s, min)?;
        }
        Ok(())
    };
    match scenario {
        Scenario::BootWindow => {
            s.chip.soc().adc_dead = true;
            injected_at = Some(0.0);
            while s.chip.soc_ref().resets.is_empty() && s.chip.time_s() < 0.7 {
                step(&mut s, &mut min_clearance)?;
            }
        }
        Scenario::SingleBank => until(&mut s, &mut min_clearance, 0.1)?,
        Scenario::HungControl
        | Scenario::FaultPath
        | Scenario::PanicOnStop
        | Scenario::SupplyLoss => {
            // Home, close the bypass, start the strokes, and inject at full speed.
            let _ = MachineModel::reference;
            while !s.send(Command::Home) {
                step(&mut s, &mut min_clearance)?;
            }
            while !(s.status.homed && s.status.mode == ModeKind::Holding) {
                step(&mut s, &mut min_clearance)?;
                if s.chip.time_s() > 30.0 {
                    return Err("homing did not end".into());
                }
            }
            s.chip.soc().board.world.plant.port_mode = PortMode::Timed;
            s.send(Command::Start {
                peak_speed_mps: speed,
            });
            // Homing touches head A on purpose: the clearance counts from the strokes.
            min_clearance = (f64::INFINITY, 0.0);
            let t = s.chip.time_s() + scenario_opts.inject_after_start_s;
            until(&mut s, &mut min_clearance, t)?;
            injected_at = Some(s.chip.time_s());
            match scenario {
                Scenario::HungControl => s.chip.soc().hang_pending = true,
                Scenario::FaultPath => s.chip.soc().bus_fault_pending = true,
                Scenario::SupplyLoss => s.chip.soc().board.world.plant.supply.cut(),
                _ => {
                    s.send(Command::Stop);
                }
            }
            let before = min_clearance;
            min_clearance = (f64::INFINITY, 0.0);
            let t = s.chip.time_s() + AFTER_INJECTION_S;
            until(&mut s, &mut min_clearance, t)?;
            after_injection = min_clearance.0;
            if before.0 < min_clearance.0 {
                min_clearance = before;
            }
        }
        Scenario::TornSave | Scenario::SaveError => {
            until(&mut s, &mut min_clearance, 0.01)?;
            if scenario == Scenario::TornSave {
                // The save appends an item: its third double word tears.
                let steps = s.chip.soc_ref().flash.steps;
                s.chip.soc().flash.faults.cut_power_at_step = Some(steps + 3);
            } else {
                // The save's fourth program step fails with PROGERR (a step whose loss the
                // storage crate does not notice by itself).
                let steps = s.chip.soc_ref().flash.steps;
                s.chip.soc().flash.faults.error_on_program =
                    flash::error_flag("progerr").map(|f| (steps + save_error_step(), f));
            }
            s.send(Command::Calibrate {
                routine: Routine::CurrentSense,
            });
            let deadline = s.chip.time_s() + 2.0;
            while s.chip.time_s() < deadline {
                step(&mut s, &mut min_clearance)?;
                if scenario == Scenario::TornSave && !s.chip.soc_ref().powered {
                    injected_at = Some(s.chip.time_s());
                    break;
                }
                if scenario == Scenario::SaveError
                    && s.log.contains("calibration")
                    && s.log.lines.iter().any(|(_, l)| l.contains("saved"))
                {
                    injected_at = Some(s.chip.time_s());
                    break;
                }
            }
            if scenario == Scenario::TornSave {
                if injected_at.is_none() {
                    return Err("the save never reached the armed flash step".into());
                }
                // 20 ms without supply, then power again: the boots that follow.
                let t = s.chip.time_s() + 0.02;
                until(&mut s, &mut min_clearance, t)?;
                s.chip.power_on().map_err(|e| e.to_string())?;
            }
            let t = s.chip.time_s() + 1.0;
            until(&mut s, &mut min_clearance, t)?;
        }
    }
    let soc = s.chip.soc_ref();
    Ok(Report {
        scenario,
        injected_at_s: injected_at,
        resets: soc.resets.clone(),
        log: s.log.lines.clone(),
        final_mode: (s.frames > 0).then_some(s.status.mode),
        faults: s.faults.iter().map(|f| f.name().to_string()).collect(),
        min_clearance_m: min_clearance.0,
        min_clearance_at_s: min_clearance.1,
        min_clearance_after_m: after_injection,
        end_s: s.chip.time_s(),
        milestones: soc.milestones.clone(),
    })
}

/// Which program step of the save fails in [`Scenario::SaveError`] (counted from 1).
fn save_error_step() -> u64 {
    std::env::var("FPC_PIL_SAVE_ERROR_STEP")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4)
}
