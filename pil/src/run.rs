//! `fpc-pil run`: the main job's scenario on the release ELF — boot, the calibration record
//! in the emulated flash store, home, start over the RTT command channel, N cycles at the
//! pressure ratio's speed on the machine model — with the same operator and figures as
//! `fpc-sim run` (`hal_sim::run::RunDriver`), and the same plant, sensors and seed driven by
//! the host build for comparison.

use std::io::Write;
use std::time::Instant;

use fpc::control::calibration::record::CalibrationRecord;
use fpc::control::command::Command;
use hal_sim::board::world::World;
use hal_sim::plant::chambers::PortMode;
use hal_sim::run::{HostLink, RunDriver, RunOptions, RunOutcome, Summary};
use serde::Serialize;

use crate::board::Board;
use crate::chip::{ChipOptions, DeadlineFigures, Milestone, PeriodLoad, Soc};
use crate::elf::Image;
use crate::session::{SentCommand, Session};

/// The SYSCLK the instruction figures are stated at, Hz.
pub const SYSCLK_HZ: f64 = 170e6;
/// The control period, s.
pub const PERIOD_S: f64 = 50e-6;

/// What `fpc-pil run` prints: `fpc-sim run --json`'s summary and the PIL's own figures.
#[derive(Clone, Debug, Serialize)]
pub struct PilSummary {
    /// The same summary as `fpc-sim run --json`.
    #[serde(flatten)]
    pub run: Summary,
    /// Mean instructions per control period from the first exception entry to the return to
    /// thread mode (the interrupt path: DMA end of burst, the control executor, any other
    /// interrupt that ran in the period), over the periods from Start to the end.
    pub instructions_per_cycle_mean: f64,
    /// The largest of those.
    pub instructions_per_cycle_max: u64,
    /// Thread-mode instructions per period (supervision, telemetry, commands, storage), mean.
    pub thread_instructions_per_cycle_mean: f64,
    /// Mean clock cycles of the interrupt path per control period, counted per instruction
    /// from the Cortex-M4 TRM with branch refills, exception entries and returns, and the
    /// flash wait states of what still runs from flash (`pil/README.md`, "Cycles").
    pub cycles_per_cycle_mean: f64,
    /// The largest of those.
    pub cycles_per_cycle_max: u64,
    /// The worst period's interrupt path at 170 MHz, µs (the budget is 50).
    pub worst_cycle_us: f64,
    /// Each sample's duties against the update event that puts them in force
    /// ([`crate::chip::deadline`]): `deadline_cycles`, `worst_cycle_cycles`,
    /// `mean_cycle_cycles`, `missed_updates`, `timed_samples`.
    #[serde(flatten)]
    pub deadline: DeadlineFigures,
    /// The part of the interrupt path's instructions fetched from program flash (the rest run
    /// from CCM SRAM), over the periods from Start on.
    pub flash_fetched_share: f64,
    /// Flash wait-state cycles in the worst period (instruction lines, flash data reads,
    /// vector fetches; 4 each).
    pub worst_cycle_flash_wait_cycles: u64,
    /// The emulated time's clock: `null` when it ran on the counted cycles (the default),
    /// or the CPI it ran at (`--cpi`).
    pub timeline_cpi: Option<f64>,
    /// RMS of the difference between the piston position (the plant's) of this run and of
    /// the host build on the same plant and seed, the same command taken by the same control
    /// step, cycle by cycle from the strokes' start, m.
    pub position_rms_diff_vs_host_m: Option<f64>,
    /// Wall-clock time of the emulated run alone, s.
    pub pil_wall_time_s: f64,
    /// Wall-clock time of everything (commissioning, the host run, the PIL run), s.
    pub total_wall_time_s: f64,
    /// Resets of the emulated chip after power-on.
    pub resets: usize,
    /// Telemetry frames received.
    pub telemetry_frames: u64,
    /// The stack's size, bytes (flip-link: SRAM's start to the initial stack pointer).
    pub stack_bytes: Option<u32>,
    /// The deepest the stack has been since the boot painted it, bytes (read from RAM as a
    /// probe would: the lowest word that lost the paint).
    pub stack_high_water_bytes: Option<u32>,
    /// Global critical sections the firmware entered at the control or end-of-burst
    /// priority (its `CONTROL_LEVEL_ENTRIES`, read from RAM; `None`: no such symbol): each
    /// could preempt a thread-mode holder, so 0 is the rule (`src/board/critical.rs`).
    pub control_level_critical_sections: Option<u32>,
}

/// A finished PIL run.
pub struct PilOutcome {
    /// The figures.
    pub summary: PilSummary,
    /// The run (log, per-cycle work) as `fpc-sim run` gives it.
    pub outcome: RunOutcome,
    /// The defmt log, with emulated times.
    pub defmt: Vec<(f64, String)>,
    /// The per-period loads from Start on.
    pub periods: Vec<PeriodLoad>,
    /// With [`PilOptions::profile`]: the worst period's interrupt path by function.
    pub profile: Vec<ProfileRow>,
}

/// Options of `fpc-pil run`.
pub struct PilOptions {
    /// The firmware.
    pub image: Image,
    /// The run (model, cycles, seed, pressure ratio...).
    pub run: RunOptions,
    /// The emulated chip.
    pub chip: ChipOptions,
    /// Also run the host build for `position_rms_diff_vs_host_m`.
    pub compare_with_host: bool,
    /// Keep where the worst period's interrupt path spent its cycles
    /// ([`PilOutcome::profile`]).
    pub profile: bool,
}

/// One function's part of the worst period's interrupt path.
#[derive(Clone, Debug, Serialize)]
pub struct ProfileRow {
    /// The function (the nearest symbol at or below the code; mangled).
    pub function: String,
    /// Its address (flash 0x08…, CCM SRAM 0x10…).
    pub address: u32,
    /// Instructions it executed in the period.
    pub instructions: u64,
    /// Cycles (wait states included).
    pub cycles: u64,
}

/// One of the periods with the most cycles, profiled ([`crate::faults::Options::profile_periods`]).
#[derive(Clone, Debug, Serialize)]
pub struct PeriodProfile {
    /// When the period ended, emulated s.
    pub end_s: f64,
    /// Its interrupt path's cycles.
    pub path_cycles: u64,
    /// By function, most cycles first.
    pub rows: Vec<ProfileRow>,
    /// By block of code (the emulator's translated blocks: a run of instructions up to a
    /// branch), most cycles first: where inside a function the cycles went.
    pub blocks: Vec<BlockRow>,
}

/// One block of code's part of a profiled period.
#[derive(Clone, Debug, Serialize)]
pub struct BlockRow {
    /// The block's first instruction.
    pub address: u32,
    /// The function it is in (the nearest symbol at or below it; mangled).
    pub function: String,
    /// Instructions it executed in the period.
    pub instructions: u64,
    /// Cycles (wait states included).
    pub cycles: u64,
}

/// The periods `top` by function and by block.
pub(crate) fn period_profiles(
    image: &Image,
    top: &[crate::chip::ProfiledPeriod],
) -> Vec<PeriodProfile> {
    let syms = symbol_table(image);
    top.iter()
        .map(|p| {
            let mut blocks: Vec<BlockRow> = p
                .blocks
                .iter()
                .map(|(&address, &(instructions, cycles))| BlockRow {
                    address,
                    function: symbol_at(&syms, address).1.to_string(),
                    instructions,
                    cycles,
                })
                .collect();
            blocks.sort_by_key(|b| (std::cmp::Reverse(b.cycles), b.address));
            PeriodProfile {
                end_s: p.end_s,
                path_cycles: p.path_cycles,
                rows: profile_rows(&syms, &p.blocks),
                blocks,
            }
        })
        .collect()
}

/// The image's function symbols by address (thumb bit cleared), linker markers of a region's
/// start or end first where they share an address with a function.
fn symbol_table(image: &Image) -> Vec<(u32, &str)> {
    let mut syms: Vec<(u32, &str)> = image
        .symbols
        .iter()
        .filter(|(n, a)| !n.is_empty() && !n.starts_with('$') && **a != 0)
        .map(|(n, a)| (*a & !1, n.as_str()))
        .collect();
    // A function sharing its address with a linker marker of a region's start or end
    // (`__sccmram`, `__eccmram_early`) is named by the function: markers sort first.
    let marker = |n: &str| n.starts_with("__s") || n.starts_with("__e");
    syms.sort_unstable_by_key(|&(a, n)| (a, !marker(n), n));
    syms
}

/// The nearest symbol at or below `addr` ((0, "?") below every symbol).
fn symbol_at<'a>(syms: &[(u32, &'a str)], addr: u32) -> (u32, &'a str) {
    let i = syms.partition_point(|(a, _)| *a <= addr);
    if i == 0 {
        (0, "?")
    } else {
        syms[i - 1]
    }
}

/// The worst period's profile ([`crate::chip::Soc::profile_top`]'s first), by function,
/// most cycles first (empty when nothing was profiled).
pub(crate) fn worst_profile_rows(image: &Image, soc: &crate::chip::Soc) -> Vec<ProfileRow> {
    soc.profile_top
        .first()
        .map(|p| profile_rows(&symbol_table(image), &p.blocks))
        .unwrap_or_default()
}

/// A period's profile by function (the blocks at their symbol in `syms`), most cycles first.
fn profile_rows(
    syms: &[(u32, &str)],
    blocks: &std::collections::HashMap<u32, (u64, u64)>,
) -> Vec<ProfileRow> {
    let mut rows: std::collections::HashMap<(u32, &str), (u64, u64)> = Default::default();
    for (&addr, &(n, c)) in blocks {
        let e = rows.entry(symbol_at(syms, addr)).or_default();
        e.0 += n;
        e.1 += c;
    }
    let mut rows: Vec<ProfileRow> = rows
        .into_iter()
        .map(|((address, f), (instructions, cycles))| ProfileRow {
            function: f.to_string(),
            address,
            instructions,
            cycles,
        })
        .collect();
    rows.sort_by_key(|r| std::cmp::Reverse(r.cycles));
    rows
}

/// The calibration the board's flash holds: the model commissioned by the host build's
/// routines (`fpc-sim calibrate`), saved by the firmware's own store code.
pub fn commissioned(run: &RunOptions) -> Result<CalibrationRecord, String> {
    hal_sim::calibration::commission(&run.model, run.seed).map(|(r, _)| r)
}

/// Runs the scenario; the run log goes to `csv` as it is made.
pub fn run(opts: &PilOptions, csv: Option<&mut dyn Write>) -> Result<PilOutcome, String> {
    let started = Instant::now();
    opts.run.validate()?;
    let (run_opts, record) = pil_run_options(&opts.run)?;
    let mut session = commissioned_session(opts, &run_opts, &record)?;
    let config = hal_sim::run::run_config(&run_opts);
    let mut driver = RunDriver::new(&run_opts, &config, "fpc-pil run", csv).log_each_status();
    let pil_started = Instant::now();
    let track = drive(&mut session, &mut driver, opts.profile)?;
    let pil_wall = pil_started.elapsed().as_secs_f64();
    let soc = session.chip.soc();
    let periods = std::mem::take(&mut soc.periods);
    let deadline = DeadlineFigures::of(&std::mem::take(&mut soc.samples));
    let resets = soc.resets.len();
    let first_control_us = first_control_us(soc);
    let profile = worst_profile_rows(&opts.image, soc);
    let world = soc.board.world.clone();
    let outcome = driver.finish(world, Default::default())?;
    let load = PathLoad::of(&periods);
    let rms = if opts.compare_with_host && opts.run.schedule.is_empty() {
        position_rms_diff_vs_host(&opts.run, record, &session.sent, &track, first_control_us)?
    } else {
        None
    };
    let stack = crate::stack::stack_use(&session.chip);
    let summary = PilSummary {
        run: outcome.summary.clone(),
        instructions_per_cycle_mean: load.mean,
        instructions_per_cycle_max: load.max,
        thread_instructions_per_cycle_mean: load.thread,
        cycles_per_cycle_mean: load.cycles_mean,
        cycles_per_cycle_max: load.worst.path_cycles,
        worst_cycle_us: load.worst.path_cycles as f64 / SYSCLK_HZ * 1e6,
        deadline,
        flash_fetched_share: load.flash_fetched_share,
        worst_cycle_flash_wait_cycles: load.worst.path_wait_cycles,
        timeline_cpi: opts.chip.cpi,
        position_rms_diff_vs_host_m: rms,
        pil_wall_time_s: pil_wall,
        total_wall_time_s: started.elapsed().as_secs_f64(),
        resets,
        telemetry_frames: session.frames,
        stack_bytes: stack.map(|s| s.size),
        stack_high_water_bytes: stack.map(|s| s.high_water),
        control_level_critical_sections: read_symbol_word(&session.chip, "CONTROL_LEVEL_ENTRIES"),
    };
    Ok(PilOutcome {
        summary,
        outcome,
        defmt: session.log.lines.clone(),
        periods,
        profile,
    })
}

/// The 32-bit word at the firmware's symbol `name`, read from the emulated RAM.
pub(crate) fn read_symbol_word(chip: &crate::chip::Chip, name: &str) -> Option<u32> {
    let addr = chip.image().symbol(name)?;
    let mut w = [0u8; 4];
    chip.read_mem(addr, &mut w).ok()?;
    Some(u32::from_le_bytes(w))
}

/// The run as the PIL makes it, with the calibration the board's flash holds: `run`'s own,
/// or the model commissioned ([`commissioned`]). The host can see the firmware's status
/// only through telemetry, so the log has a row per frame (the firmware's default
/// decimation, 1 kHz).
fn pil_run_options(run: &RunOptions) -> Result<(RunOptions, CalibrationRecord), String> {
    let mut run_opts = run.clone();
    let record = match &run_opts.calibration {
        Some(r) => *r,
        None => commissioned(&run_opts)?,
    };
    run_opts.calibration = Some(record);
    run_opts.log_rate_hz = 1_000_000
        / fpc::units::CONTROL_PERIOD_US
        / u32::from(fpc::link::telemetry::DEFAULT_DECIMATION);
    Ok((run_opts, record))
}

/// The board with `record` in its flash store, around the plant of `run_opts` (model, seed,
/// start, pressure ratio), and the host attached to it.
fn commissioned_session(
    opts: &PilOptions,
    run_opts: &RunOptions,
    record: &CalibrationRecord,
) -> Result<Session, String> {
    let flash = hal_sim::board::flash::holding(record)?;
    let mut world = hal_sim::run::world(
        &run_opts.model,
        run_opts.seed,
        run_opts.start_us,
        run_opts.start_position_m,
    );
    world
        .plant
        .lines
        .set_pressure_ratio(run_opts.pressure_ratio);
    let mut session = Session::new(opts.image.clone(), Board::new(world), opts.chip.clone())?;
    session.chip.soc().flash.load_image(flash.image());
    Ok(session)
}

/// Steps the board and the operator until the run ends, keeping the piston's track. The
/// chip records each period's load (and with `profile` the worst period's interrupt path)
/// from the first status in Running, before any compression cycle is done.
fn drive(
    session: &mut Session,
    driver: &mut RunDriver<'_, '_>,
    profile: bool,
) -> Result<Track, String> {
    let mut recording = false;
    let mut track = Track::default();
    loop {
        session.step()?;
        let fresh = session.fresh;
        let (world, mut link) = session.link();
        let mode = world.plant.port_mode;
        let flow = driver.cycle(world, &mut link, fresh, None);
        track.record(world, mode);
        if !recording
            && driver.cycles_done() == 0
            && session.status.mode == fpc::status::ModeKind::Running
        {
            let soc = session.chip.soc();
            soc.recording = true;
            soc.profile = profile;
            recording = true;
        }
        if flow.is_break() {
            return Ok(track);
        }
    }
}

/// The start, µs, of the plant cycle in which the ELF's control task first ran (its boot
/// from power-on); `None` if it never ran.
fn first_control_us(soc: &Soc) -> Option<u64> {
    // The host build starts its tasks in the same plant cycle, so that every rate the
    // firmware divides down from its control steps (the telemetry's decimation, the 1 kHz
    // work) has the same phase to the plant and to the commands as on the ELF.
    soc.milestones
        .iter()
        .find(|(_, m)| *m == Milestone::ControlTask)
        .map(|(t, _)| {
            let period = u64::from(fpc::units::CONTROL_PERIOD_US);
            (t * 1e6 / period as f64).floor() as u64 * period
        })
}

/// The interrupt path's load over the recorded periods, as [`PilSummary`] states it.
struct PathLoad {
    /// Instructions per period, mean.
    mean: f64,
    /// Instructions per period, the largest.
    max: u64,
    /// Thread-mode instructions per period, mean.
    thread: f64,
    /// Clock cycles per period, mean.
    cycles_mean: f64,
    /// The period with the most clock cycles.
    worst: PeriodLoad,
    /// The part of the path's instructions fetched from program flash.
    flash_fetched_share: f64,
}

impl PathLoad {
    /// The figures of `periods` (all zero if there are none).
    fn of(periods: &[PeriodLoad]) -> PathLoad {
        let n = periods.len().max(1) as f64;
        let path_total: u64 = periods.iter().map(|p| p.interrupt_path).sum();
        let path_flash: u64 = periods.iter().map(|p| p.path_flash_instructions).sum();
        PathLoad {
            mean: periods.iter().map(|p| p.interrupt_path as f64).sum::<f64>() / n,
            max: periods.iter().map(|p| p.interrupt_path).max().unwrap_or(0),
            thread: periods.iter().map(|p| p.thread as f64).sum::<f64>() / n,
            cycles_mean: periods.iter().map(|p| p.path_cycles as f64).sum::<f64>() / n,
            worst: periods
                .iter()
                .max_by_key(|p| p.path_cycles)
                .copied()
                .unwrap_or_default(),
            flash_fetched_share: path_flash as f64 / path_total.max(1) as f64,
        }
    }
}

/// [`PilSummary::position_rms_diff_vs_host_m`]: the host build replays `run` with `record`,
/// each command the ELF's operator sent (`sent`) taken by the same control step, against the
/// ELF's `track`.
fn position_rms_diff_vs_host(
    run: &RunOptions,
    record: CalibrationRecord,
    sent: &[SentCommand],
    track: &Track,
    first_control_us: Option<u64>,
) -> Result<Option<f64>, String> {
    let mut h = run.clone();
    h.calibration = Some(record);
    let mut taken: Vec<_> = sent
        .iter()
        .map(|c| (c.command, c.taken_after_cycle))
        .collect();
    // The read offset places each command's read within a period; the command task (thread
    // mode) may still be preempted by the next control step between reading a command and
    // posting it, which then takes it a cycle later. Of the two candidates the replay keeps
    // the one whose trajectory matches, command by command, up to the next one. A candidate
    // whose replay cannot follow the ELF (the host decides a later command after the ELF
    // took it) is not that one; if neither can, the run fails with the first's reason.
    for i in 0..taken.len() {
        let Some(c0) = taken[i].1 else { continue };
        let until = taken
            .get(i + 1)
            .and_then(|t| t.1)
            .unwrap_or(track.x_m.len() as u64);
        let mut best: Option<(f64, u64)> = None;
        let mut refused: Option<String> = None;
        for c in [c0, c0 + 1] {
            taken[i].1 = Some(c);
            let host = match host_replay(&h, &taken, track.bypass_closed, first_control_us) {
                Ok(host) => host,
                Err(e) => {
                    refused.get_or_insert(e);
                    continue;
                }
            };
            let d = window_rms_diff(&track.x_m, &host.x_m, c0, until);
            if best.is_none_or(|b| d < b.0) {
                best = Some((d, c));
            }
        }
        match best {
            Some((_, c)) => taken[i].1 = Some(c),
            None => return Err(refused.unwrap_or_default()),
        }
    }
    let host = host_replay(&h, &taken, track.bypass_closed, first_control_us)?;
    Ok(position_rms_diff(&track.x_m, &host.x_m, track.start_cycle))
}

/// The plant as the PIL run moved it: the piston position at every cycle, and when the
/// operator closed the bypass and the strokes began.
#[derive(Default)]
struct Track {
    /// Piston position (the plant's) at each cycle from 0, m.
    x_m: Vec<f64>,
    /// The cycle at which the run driver closed the start-up bypass.
    bypass_closed: Option<u64>,
    /// The first cycle of the strokes (the bypass closed), for the comparison.
    start_cycle: u64,
}

impl Track {
    /// Notes cycle `w.cycle()` after the run driver looked at it (`mode`: the port mode
    /// before it did).
    fn record(&mut self, w: &World, mode_before: PortMode) {
        let c = w.cycle() as usize;
        self.x_m.resize(c, f64::NAN);
        self.x_m.push(w.plant.x_m);
        if self.bypass_closed.is_none() && w.plant.port_mode != mode_before {
            self.bypass_closed = Some(w.cycle());
            self.start_cycle = w.cycle();
        }
    }
}

/// The host build's run of the same scenario: the same plant, seed and calibration, the same
/// operator ([`RunDriver`]), with each command taken by the same control step as on the ELF
/// (`taken`: each command the PIL's operator sent, in order, and the cycle after which its
/// control step took it) and the bypass closed at the same cycle. Otherwise the two runs
/// would differ by when things happened — the ELF's host sees the status one telemetry frame
/// late and its commands wait for the command task's 1 kHz poll — not by what the two
/// builds compute. Returns the piston position at every cycle.
fn host_replay(
    opts: &RunOptions,
    taken: &[(Command, Option<u64>)],
    bypass_closed: Option<u64>,
    first_control_us: Option<u64>,
) -> Result<Track, String> {
    use hal_sim::board::exec::{simulate_board, Execution, SimShared};
    let config = hal_sim::run::run_config(opts);
    let mut world =
        hal_sim::run::world(&opts.model, opts.seed, opts.start_us, opts.start_position_m);
    world.telemetry.decimation = opts.telemetry_decimation;
    world.plant.lines.set_pressure_ratio(opts.pressure_ratio);
    let mut driver = RunDriver::new(opts, &config, "fpc-pil host replay", None);
    let execution = Execution {
        watchdog_timeout_us: Some(opts.watchdog_timeout_us),
        flash: opts
            .calibration
            .as_ref()
            .map(hal_sim::board::flash::holding)
            .transpose()?,
        booting_until_us: first_control_us.map(|t| t + u64::from(opts.start_us)),
        ..Execution::default()
    };
    let mut track = Track::default();
    let mut replay = Replay {
        taken,
        posted: Vec::new(),
        delivered: 0,
        mismatch: None,
    };
    let each_cycle = |w: &mut World, shared: &SimShared, _: &mut Execution| {
        let cycle = w.cycle();
        replay.deliver(shared, cycle);
        let mode = w.plant.port_mode;
        let mut link = ReplayLink {
            shared,
            replay: &mut replay,
        };
        let flow = driver.cycle(w, &mut link, true, None);
        // The bypass closes when it closed on the ELF's plant.
        if w.plant.port_mode != mode && bypass_closed.is_some_and(|c| cycle < c) {
            w.plant.port_mode = mode;
        }
        if bypass_closed == Some(cycle) {
            w.plant.port_mode = PortMode::Timed;
        }
        replay.deliver(shared, cycle);
        track.x_m.push(w.plant.x_m);
        flow
    };
    let _ = simulate_board(world, config, execution, each_cycle);
    if let Some(why) = replay.mismatch {
        return Err(format!("the host build's replay of the commands: {why}"));
    }
    Ok(track)
}

/// The commands of a host-build run, held until the cycle the ELF took them at.
struct Replay<'t> {
    taken: &'t [(Command, Option<u64>)],
    posted: Vec<Command>,
    delivered: usize,
    mismatch: Option<String>,
}

impl Replay<'_> {
    /// Posts what is due at `cycle`.
    fn deliver(&mut self, shared: &hal_sim::board::exec::SimShared, cycle: u64) {
        while let (Some(&command), Some(&(sent, at))) = (
            self.posted.get(self.delivered),
            self.taken.get(self.delivered),
        ) {
            if command != sent {
                self.mismatch.get_or_insert(format!(
                    "command {} is {command:?} here, {sent:?} on the ELF",
                    self.delivered
                ));
                return;
            }
            let Some(at) = at else { return };
            if at > cycle {
                return;
            }
            if at < cycle {
                self.mismatch.get_or_insert(format!(
                    "{command:?} was decided at cycle {cycle}, after the ELF took it ({at})"
                ));
            }
            let _ = shared.post_command(command);
            self.delivered += 1;
        }
    }
}

/// [`HostLink`] of the host replay: the status at once, commands held by [`Replay`].
struct ReplayLink<'a, 't> {
    shared: &'a hal_sim::board::exec::SimShared,
    replay: &'a mut Replay<'t>,
}

impl HostLink for ReplayLink<'_, '_> {
    fn status(&self) -> fpc::status::Status {
        self.shared.status()
    }

    fn post_command(&mut self, command: Command) -> bool {
        self.replay.posted.push(command);
        true
    }
}

/// RMS difference of two position tracks over cycles `from..until` (0 if none compare).
fn window_rms_diff(a: &[f64], b: &[f64], from: u64, until: u64) -> f64 {
    let (from, until) = (from as usize, until as usize);
    let (mut sum, mut n) = (0.0, 0usize);
    for k in from..until.min(a.len()).min(b.len()) {
        let d = a[k] - b[k];
        if d.is_finite() {
            sum += d * d;
            n += 1;
        }
    }
    if n == 0 {
        f64::INFINITY
    } else {
        (sum / n as f64).sqrt()
    }
}

/// RMS difference of the piston position between the ELF's run and the host build's, over
/// the cycles from `from` (the strokes' start) to the end of the shorter run, m; `None`
/// with fewer than 1,000 cycles to compare.
pub fn position_rms_diff(pil_m: &[f64], host_m: &[f64], from: u64) -> Option<f64> {
    let from = usize::try_from(from).ok()?;
    let pairs = pil_m.get(from..)?.iter().zip(host_m.get(from..)?);
    let (mut sum, mut n) = (0.0, 0usize);
    for (a, b) in pairs {
        if a.is_finite() && b.is_finite() {
            sum += (a - b) * (a - b);
            n += 1;
        }
    }
    (n >= 1000).then(|| (sum / n as f64).sqrt())
}

/// A session at rest on the reference machine, `image` flashed with the calibration the
/// reference run commissions.
pub fn at_rest(image: &Image) -> Result<Session, String> {
    let opts = RunOptions::reference();
    let record = commissioned(&opts)?;
    let store = hal_sim::board::flash::holding(&record)?;
    let world = hal_sim::run::world(&opts.model, opts.seed, 0, 1e-3);
    let mut s = Session::new(image.clone(), Board::new(world), ChipOptions::default())?;
    s.chip.soc().flash.load_image(store.image());
    Ok(s)
}
