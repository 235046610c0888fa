//! The fault scenarios of `docs/faults.md` applied to a running simulation, and what they did.
//!
//! A parsed [`FaultSpec`] acts where the fault would act on the rig:
//!
//! | where | scenarios | how |
//! |---|---|---|
//! | the sensors | encoder amplitude, stuck channel, phase glitch, noise burst; pressure open, short, stuck; quadrature wrap | [`SensorCorruption`], applied to every burst right after sampling |
//! | the machine | section loss, servo stall, gas loss (a chamber vented), load step, homing friction spike | [`PlantFaults`], read by the plant's sub-step |
//! | the board | overrun, task hang, power cut | [`Execution`]: the control task misses cycles, or a task is never polled again and the watchdog resets the board, or the board is off for a while and boots again |
//! | the host | command loss | heartbeats every 0.7 × the timeout, then none |
//! | the set-up | homing without a stop, time-base wrap | the world before the run starts |
//!
//! A fault takes effect from the first sample at or after its time `T`: the [`Injector`] is
//! called once per period after the tasks ran and before the plant advances, so what it
//! changes is first seen in the next burst — that sample's time is the fault's onset, from
//! which detection times are counted. The [`InjectionReport`] records what the firmware made
//! of it: every fault latched and when, the smallest head clearance, the travel until
//! detection, resets, the stop and the outputs.

use fpc::control::command::Command;
use fpc::control::config::ControlConfig;
use fpc::safety::faults::Fault;
use fpc::status::{ModeKind, Status};
use fpc::units::{PerSection, Section, CONTROL_PERIOD_US};

use crate::board::corruption::{NoiseBurst, PressureHold, SensorCorruption};
use crate::board::exec::{Execution, SimShared};
use crate::board::world::World;
use crate::faults::inject::{FaultKind, FaultSpec};

/// Control period, µs, as u64 (times here are µs since the start of the run).
const PERIOD_US: u64 = CONTROL_PERIOD_US as u64;

/// What the injected faults did, as the firmware showed it (times in µs since the start).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InjectionReport {
    /// Onset of each specification (the first sample it affects), in the order given;
    /// `None` if the run ended first.
    pub onset_us: Vec<Option<u64>>,
    /// Every fault the firmware latched, with the first status showing it, in order (after
    /// a watchdog reset the new boot's faults follow).
    pub faults: Vec<(u64, Fault)>,
    /// Smallest distance to a head from the first onset to the end, m.
    pub min_clearance_m: Option<f64>,
    /// Path the piston travelled from the first onset to the first fault latched after it, m.
    pub travel_to_fault_m: Option<f64>,
    /// Largest |firmware position − true position| while homed, before the first onset, m.
    pub position_error_before_m: f64,
    /// The same from the first onset on, m.
    pub position_error_after_m: f64,
    /// Watchdog resets.
    pub resets_us: Vec<u64>,
    /// When the host sent a heartbeat (command loss; the firmware takes it one period
    /// later).
    pub heartbeats_us: Vec<u64>,
    /// First status in the controlled-stop mode after the first onset.
    pub stop_began_us: Option<u64>,
    /// First period with the motor outputs off after the first fault following the onset.
    pub outputs_off_us: Option<u64>,
    /// Firmware position − true position when homing completed (first hold), m.
    pub zero_error_m: Option<f64>,
    /// When homing ended: the first hold after homing, or `homing_failed`.
    pub homing_ended_us: Option<u64>,
    /// Largest q-current of either section, A.
    pub peak_q_current_a: f64,
    /// Mode changes from the first onset on.
    pub modes: Vec<(u64, ModeKind)>,
    /// Mode of the last status seen.
    pub final_mode: Option<ModeKind>,
    /// True piston position at the end, m.
    pub final_x_m: f64,
    /// The DC link over a mains outage (`power_cut`), as it stood in the outage's last
    /// period; `None` without one.
    pub link: Option<LinkOutcome>,
    /// The samples of the noise burst (`encoder_noise_burst`) that were corrupted, counted
    /// from its first (1), as [`InjectionReport::samples_to_fault`] counts.
    pub burst_corrupted: Vec<u32>,
}

/// The DC link over a mains outage.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkOutcome {
    /// Energy the link held at the end of the outage (or of the run), J.
    pub energy_left_j: f64,
    /// Its lowest voltage over the outage, V.
    pub lowest_v: f64,
    /// Its highest voltage over the outage, V (the chopper's threshold at most).
    pub peak_v: f64,
    /// Energy the brake chopper burnt, J.
    pub chopped_j: f64,
    /// Whether the logic supply dropped out (the board went off).
    pub logic_dropped: bool,
}

impl InjectionReport {
    /// The first onset, µs.
    pub fn first_onset_us(&self) -> Option<u64> {
        self.onset_us.iter().flatten().copied().min()
    }

    /// The first fault latched at or after the first onset, and when.
    pub fn first_fault_after_onset(&self) -> Option<(u64, Fault)> {
        let onset = self.first_onset_us()?;
        self.faults.iter().copied().find(|(t, _)| *t >= onset)
    }

    /// Time from the first onset to the first fault latched after it, s.
    pub fn detection_s(&self) -> Option<f64> {
        let onset = self.first_onset_us()?;
        let (t, _) = self.first_fault_after_onset()?;
        Some((t - onset) as f64 * 1e-6)
    }

    /// Samples the firmware had seen with the fault when it latched (the onset sample
    /// counts as the first).
    pub fn samples_to_fault(&self) -> Option<u64> {
        let onset = self.first_onset_us()?;
        let (t, _) = self.first_fault_after_onset()?;
        Some((t - onset) / PERIOD_US + 1)
    }
}

/// One specification and its state.
#[derive(Clone, Debug)]
struct Armed {
    spec: FaultSpec,
    /// Time the fault starts, µs (rounded up to a whole µs).
    at_us: u64,
    onset_us: Option<u64>,
}

/// Applies fault specifications to a running simulation and records what they did.
#[derive(Clone, Debug)]
pub struct Injector {
    armed: Vec<Armed>,
    /// Host heartbeat period while the host is alive (command loss), µs.
    heartbeat_period_us: u64,
    next_heartbeat_us: u64,
    /// External force of a homing friction spike, N, and when it ends, µs.
    spike: Option<(f64, u64)>,
    seed: u64,
    report: InjectionReport,
    last_x_m: Option<f64>,
    travel_m: f64,
    last_mode: Option<ModeKind>,
    latched: fpc::safety::faults::FaultSet,
    homed_before: bool,
}

/// Time after its onset a scenario runs on (the stop and the piston coming to rest), µs.
fn run_on_us(spec: &FaultSpec, heartbeat_timeout_s: f32) -> Option<u64> {
    let s = |t: f64| Some((t * 1e6) as u64);
    match spec.kind {
        FaultKind::EncoderGlitch => s(0.1),
        FaultKind::EncoderNoiseBurst => s(spec.param("duration_s") + 0.6),
        // The stop, the turn to the venting phase (≤ 0.5 s) and the park move.
        FaultKind::CommandLoss => s(f64::from(heartbeat_timeout_s) + 3.0),
        // The outage, then the new boot sitting still.
        FaultKind::PowerCut => s(spec.param("off_s") + 0.6),
        // Ended by homing (or by the run itself).
        FaultKind::HomingNoStop | FaultKind::HomingSpike | FaultKind::CounterWrap => None,
        _ => s(0.6),
    }
}

impl Injector {
    /// An injector for `specs` on a controller configured with `config`; `seed` seeds the
    /// corrupt samples of noise bursts.
    pub fn new(specs: &[FaultSpec], config: &ControlConfig, seed: u64) -> Self {
        let heartbeat_period_us =
            (0.7 * f64::from(config.heartbeat_timeout_s) * 1e6).round() as u64;
        Injector {
            armed: specs
                .iter()
                .map(|spec| Armed {
                    at_us: (spec.at_s * 1e6).ceil() as u64,
                    spec: spec.clone(),
                    onset_us: None,
                })
                .collect(),
            heartbeat_period_us: heartbeat_period_us.max(PERIOD_US),
            next_heartbeat_us: 0,
            spike: None,
            seed,
            report: InjectionReport {
                onset_us: vec![None; specs.len()],
                ..Default::default()
            },
            last_x_m: None,
            travel_m: 0.0,
            last_mode: None,
            latched: fpc::safety::faults::FaultSet::new(),
            homed_before: false,
        }
    }

    /// Whether there is nothing to inject.
    pub fn is_empty(&self) -> bool {
        self.armed.is_empty()
    }

    fn has(&self, kind: FaultKind) -> Option<&FaultSpec> {
        self.armed.iter().map(|a| &a.spec).find(|s| s.kind == kind)
    }

    /// What the board's µs time base reads at the start: with `counter_wrap`, it wraps at
    /// the fault's time; otherwise `default`.
    pub fn start_us(&self, default: u32) -> u32 {
        match self.has(FaultKind::CounterWrap) {
            // 2³² − T: the time base reaches 2³² = 0 at T.
            Some(s) => 0u32.wrapping_sub((s.at_s * 1e6).round() as u64 as u32),
            None => default,
        }
    }

    /// Where the piston rests at the start, m: with `homing_no_stop`, 5 m from head A in a
    /// 10 m cylinder (no stop within the 0.25 m search); otherwise `default`.
    pub fn start_position_m(&self, default: f64) -> f64 {
        match self.has(FaultKind::HomingNoStop) {
            Some(_) => 5.0,
            None => default,
        }
    }

    /// Sets up the world before the run: the faults that are part of the machine or the
    /// board from the start.
    pub fn prepare(&self, w: &mut World) {
        w.corruption = SensorCorruption::seeded(self.seed);
        if self.has(FaultKind::HomingNoStop).is_some() {
            // Head A out of reach: only the travel limit of the stops moves (the chambers
            // stay bypassed while homing).
            w.plant.params.travel_m = 10.0;
        }
        if self.has(FaultKind::CounterWrap).is_some() {
            // The servo's 16-bit counter 64 counts (5.6°) before its wrap.
            w.corruption.quadrature_offset = 0u16.wrapping_sub(64);
        }
    }

    /// Called once per period after the tasks ran and before the plant advances: applies
    /// what is due, plays the host's heartbeat, and records what the firmware shows.
    pub fn step(&mut self, w: &mut World, shared: &SimShared, exec: &mut Execution) {
        let now = w.time_us();
        // What is set now is first seen by the sample taken at the end of this period.
        let next_sample = now + PERIOD_US;
        for i in 0..self.armed.len() {
            let due = self
                .armed
                .get(i)
                .is_some_and(|a| a.onset_us.is_none() && a.at_us <= next_sample);
            if due {
                if let Some(a) = self.armed.get_mut(i) {
                    a.onset_us = Some(next_sample);
                }
                if let Some(spec) = self.armed.get(i).map(|a| a.spec.clone()) {
                    self.start(&spec, w, exec);
                }
                if let Some(slot) = self.report.onset_us.get_mut(i) {
                    *slot = Some(next_sample);
                }
            }
        }
        if let Some((_, ends_us)) = self.spike {
            if now + PERIOD_US > ends_us {
                w.plant.injected.external_force_n = 0.0;
                self.spike = None;
            }
        }
        if let Some(loss) = self.has(FaultKind::CommandLoss) {
            let stops_us = (loss.at_s * 1e6).ceil() as u64;
            if now >= self.next_heartbeat_us && now < stops_us {
                let _ = shared.post_command(Command::Heartbeat);
                self.report.heartbeats_us.push(now);
                self.next_heartbeat_us = now + self.heartbeat_period_us;
            }
        }
        self.observe(w, &shared.status(), exec);
    }

    fn start(&mut self, spec: &FaultSpec, w: &mut World, exec: &mut Execution) {
        let p = |name: &str| spec.param(name);
        let chamber = usize::from(p("chamber") != 0.0);
        let c = &mut w.corruption;
        match spec.kind {
            FaultKind::EncoderAmplitude => {
                let which = p("encoder");
                let on = PerSection {
                    master: which != 1.0,
                    slave: which != 0.0,
                };
                c.gain = Some((p("gain"), on));
            }
            FaultKind::BothEncoders => {
                let on = PerSection {
                    master: true,
                    slave: true,
                };
                c.gain = Some((p("gain"), on));
            }
            FaultKind::EncoderStuck => c.master_stuck_channel = Some(p("channel") as u8),
            FaultKind::EncoderGlitch => c.master_phase_jump_rad = Some(p("jump_rad")),
            FaultKind::EncoderNoiseBurst => {
                let samples = (p("duration_s") * 1e6 / PERIOD_US as f64).round() as u32;
                c.burst = Some(NoiseBurst {
                    samples_left: samples.max(1),
                    fraction: p("fraction"),
                    started: false,
                    sample: 0,
                });
            }
            FaultKind::PressureOpen => {
                if let Some(h) = c.chambers.get_mut(chamber) {
                    *h = PressureHold::Code(0);
                }
            }
            FaultKind::PressureShort => {
                if let Some(h) = c.chambers.get_mut(chamber) {
                    *h = PressureHold::Code(fpc::units::ADC_FULL_SCALE);
                }
            }
            FaultKind::PressureStuck => {
                if let Some(h) = c.chambers.get_mut(chamber) {
                    *h = PressureHold::FreezeNext;
                }
            }
            FaultKind::SectionLoss => {
                let section = if p("section") == 0.0 {
                    Section::Master
                } else {
                    Section::Slave
                };
                *w.plant.injected.dead.get_mut(section) = true;
            }
            FaultKind::ServoStall => w.plant.injected.rotation_blocked = true,
            FaultKind::GasLoss => {
                if let Some(v) = w.plant.injected.vented.get_mut(chamber) {
                    *v = true;
                }
            }
            FaultKind::LoadStep => w.plant.injected.external_force_n = p("force_n"),
            // The step that starts now takes `cycles` periods: the control task misses the
            // next `cycles − 1` triggers.
            FaultKind::Overrun => {
                exec.control_busy_periods = (p("cycles") as u32).saturating_sub(1);
            }
            FaultKind::TaskHang => {
                if p("task") == 0.0 {
                    exec.control_hung = true;
                } else {
                    exec.supervision_hung = true;
                }
            }
            // The mains stops: the board runs on the DC link until its logic supply drops
            // out, then is off until the mains is back (`simulate_board`).
            FaultKind::PowerCut => {
                let off_us = (p("off_s") * 1e6).round() as u64;
                w.plant.supply.cut();
                exec.mains_off_until_us = Some(w.time_us() + PERIOD_US + off_us);
            }
            FaultKind::HomingSpike => {
                // A friction spike against the creep toward head A: a force toward +x.
                let ends = w.time_us() + PERIOD_US + (p("duration_s") * 1e6).round() as u64;
                w.plant.injected.external_force_n = p("force_n");
                self.spike = Some((p("force_n"), ends));
            }
            // Set up before the run, or played by the host heartbeat above.
            FaultKind::CommandLoss | FaultKind::HomingNoStop | FaultKind::CounterWrap => {}
        }
    }

    fn observe(&mut self, w: &World, status: &Status, exec: &Execution) {
        let now = w.time_us();
        let r = &mut self.report;
        r.resets_us.clone_from(&exec.resets_us);
        if exec.resets_us.last().is_some_and(|t| *t + PERIOD_US >= now) {
            // A new boot: its fault set starts empty.
            self.latched = fpc::safety::faults::FaultSet::new();
        }
        for fault in status.faults.iter() {
            if self.latched.latch(fault) {
                r.faults.push((now, fault));
            }
        }
        let q = w.plant.largest_q_current_a();
        r.peak_q_current_a = r.peak_q_current_a.max(q);
        let homed_hold = status.homed && status.mode == ModeKind::Holding;
        if homed_hold && r.zero_error_m.is_none() {
            r.zero_error_m = Some(f64::from(status.position_m) - w.plant.x_m);
        }
        if r.homing_ended_us.is_none()
            && (homed_hold || status.faults.contains(Fault::HomingFailed))
        {
            r.homing_ended_us = Some(now);
        }
        let x = w.plant.x_m;
        let error = if status.homed {
            (f64::from(status.position_m) - x).abs()
        } else {
            0.0
        };
        r.final_mode = Some(status.mode);
        r.final_x_m = x;
        if w.corruption.burst_corrupted.len() != r.burst_corrupted.len() {
            r.burst_corrupted.clone_from(&w.corruption.burst_corrupted);
        }
        let link = &w.plant.supply;
        if !link.mains {
            r.link = Some(LinkOutcome {
                energy_left_j: link.energy_j(),
                lowest_v: link.lowest_v,
                peak_v: link.peak_v,
                chopped_j: link.chopped_j,
                logic_dropped: link.lowest_v < link.params.logic_dropout_v,
            });
        }
        let Some(onset) = r.first_onset_us() else {
            if self.homed_before || status.homed {
                self.homed_before = true;
                r.position_error_before_m = r.position_error_before_m.max(error);
            }
            return;
        };
        if now < onset {
            return;
        }
        r.position_error_after_m = r.position_error_after_m.max(error);
        let c = w.plant.head_clearance_m();
        r.min_clearance_m = Some(r.min_clearance_m.map_or(c, |m| m.min(c)));
        if let Some(last) = self.last_x_m.replace(x) {
            self.travel_m += (x - last).abs();
        }
        let fault_after = r.faults.iter().any(|(t, _)| *t >= onset);
        if fault_after && r.travel_to_fault_m.is_none() {
            r.travel_to_fault_m = Some(self.travel_m);
        }
        if fault_after && r.outputs_off_us.is_none() && !w.enabled {
            r.outputs_off_us = Some(now);
        }
        if status.mode == ModeKind::Stopping && r.stop_began_us.is_none() {
            r.stop_began_us = Some(now);
        }
        if self.last_mode != Some(status.mode) {
            r.modes.push((now, status.mode));
            self.last_mode = Some(status.mode);
        }
    }

    /// Whether every fault has started and run on long enough for its outcome: the stop,
    /// the piston coming to rest, the end of homing. `heartbeat_timeout_s` is the
    /// controller's. Scenarios that only end with the run (counter wrap) never finish here.
    pub fn finished(&self, now_us: u64, heartbeat_timeout_s: f32) -> bool {
        !self.armed.is_empty()
            && self.armed.iter().all(|a| {
                let Some(onset) = a.onset_us else {
                    return false;
                };
                match run_on_us(&a.spec, heartbeat_timeout_s) {
                    Some(run_on) => now_us >= onset + run_on,
                    None => match a.spec.kind {
                        FaultKind::HomingNoStop | FaultKind::HomingSpike => self
                            .report
                            .homing_ended_us
                            .is_some_and(|t| now_us >= t + 50_000),
                        _ => false,
                    },
                }
            })
    }

    /// What happened so far.
    pub fn report(&self) -> &InjectionReport {
        &self.report
    }
}
