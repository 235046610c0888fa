//! The host's side of a run, one control period at a time: the operator that homes the axis,
//! starts the strokes, counts the cycles and stops, and decides when the run is over.

use std::io::Write;
use std::ops::ControlFlow;
use std::time::Instant;

use fpc::control::command::Command;
use fpc::motion::volume_ratio::RatioTarget;
use fpc::status::{ModeKind, Status};

use super::capture::Capture;
use super::metrics::{Metrics, RunEnd};
use super::{
    volume_ratio_name, Controller, HostAction, RunOptions, RunOutcome, COLUMNS, CONTROL_RATE_HZ,
    FIRMWARE_FORCE_DELAY_S,
};
use crate::board::exec::SimShared;
use crate::board::world::World;
use crate::faults::apply::InjectionReport;
use crate::plant::chambers::PortMode;
use crate::runlog::RunLog;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    Homing,
    /// The firmware strokes on its own; the host watches the reference turn at each dead
    /// point (it is noise-free; 20 µm of hysteresis ignores rounding at the ends).
    Running {
        toward_b: bool,
        ref_extreme_m: f64,
    },
    Stopping,
    Done,
}

/// The host's side of a board running the firmware, as [`RunDriver`] uses it: the status as
/// the host last saw it, and the command channel.
pub trait HostLink {
    /// The firmware's status as last seen.
    fn status(&self) -> Status;
    /// Sends a command; false if the channel refused it (full).
    fn post_command(&mut self, command: Command) -> bool;
    /// The start-up bypass has closed: the rotation times the ports from now on (a host
    /// that declares the ports to the firmware says so; by default nothing to do).
    fn ports_timed(&mut self) {}
}

impl HostLink for &SimShared {
    fn status(&self) -> Status {
        SimShared::status(self)
    }
    fn post_command(&mut self, command: Command) -> bool {
        SimShared::post_command(self, command).is_ok()
    }
}

/// The operator of a run and its bookkeeping, one control period at a time: homes the
/// axis, closes the bypass, starts the strokes, counts cycles, stops; collects the figures
/// and the run log. `fpc-sim run` drives it with the host build of the firmware on the
/// simulated board; `fpc-pil` with the release ELF in an emulated MCU.
pub struct RunDriver<'o, 's> {
    opts: &'o RunOptions,
    speed: f64,
    actions: std::iter::Peekable<std::vec::IntoIter<(u32, HostAction)>>,
    dead_a: f64,
    dead_b: f64,
    log: RunLog,
    phase: Phase,
    metrics: Metrics,
    cycles_done: u32,
    limit_s: f64,
    first_fault_s: f64,
    stage_deadline_s: f64,
    stop_reason: Option<String>,
    capture: Capture<'s>,
    log_stride: u64,
    /// A row for every fresh status, whatever the cycle ([`RunDriver::log_each_status`]).
    log_each_status: bool,
    last_mode: fpc::status::ModeKind,
    started: Instant,
    /// Told the cycles done each time one completes.
    pub(super) on_cycle: Option<&'s dyn Fn(u32)>,
}

impl<'o, 's> RunDriver<'o, 's> {
    /// A run of `opts` with the controller `config`, its log's `source` named so, streamed to
    /// `csv` if given.
    pub fn new(
        opts: &'o RunOptions,
        config: &fpc::control::config::ControlConfig,
        source: &str,
        csv: Option<&'s mut dyn Write>,
    ) -> Self {
        let mut actions = opts.schedule.clone();
        actions.sort_by_key(|(cycle, _)| *cycle);
        let mut log = RunLog::with_columns(&COLUMNS);
        log.meta.push(("source".into(), source.into()));
        log.meta
            .push(("sample_rate_hz".into(), opts.log_rate_hz.to_string()));
        log.meta.push(("model".into(), opts.model_name.clone()));
        log.meta.push(("seed".into(), opts.seed.to_string()));
        log.meta
            .push(("volume_ratio".into(), volume_ratio_name(opts.volume_ratio)));
        // The published drives report the force of the current sampled with the row's position.
        let force_delay_s = match opts.controller {
            Controller::Ours => FIRMWARE_FORCE_DELAY_S,
            Controller::Published => 0.0,
        };
        log.meta
            .push(("force_delay_s".into(), format!("{force_delay_s:e}")));
        if opts.controller == Controller::Published {
            log.meta.push(("controller".into(), "published".into()));
            // Its velocity column is the drive's reading (`filters` compares it, Fig. 7).
            for name in &mut log.names {
                if name == "v_mps" {
                    *name = "v_drive_mps".into();
                }
            }
        }
        let limit_s = opts.time_limit_s();
        let capture = Capture::new(limit_s, csv, &log);
        RunDriver {
            opts,
            speed: opts.peak_speed_mps(),
            actions: actions.into_iter().peekable(),
            dead_a: f64::from(config.target_clearance_m),
            dead_b: f64::from(config.travel_m - config.target_clearance_m),
            log,
            phase: Phase::Homing,
            metrics: Metrics::default(),
            cycles_done: 0,
            limit_s,
            // Each stage must finish in its own time (no waiting out the whole run's limit
            // when homing or a cycle stalls) until the first injected fault begins; after
            // it, the injector decides when the outcome is known.
            first_fault_s: opts
                .faults
                .iter()
                .map(|f| f.at_s)
                .fold(f64::INFINITY, f64::min),
            stage_deadline_s: opts.homing_limit_s(),
            stop_reason: None,
            capture,
            // One row every `log_stride` control cycles (`--log-rate`; checked to divide
            // evenly).
            log_stride: u64::from((CONTROL_RATE_HZ / opts.log_rate_hz.max(1)).max(1)),
            log_each_status: false,
            last_mode: Status::INIT.mode,
            started: Instant::now(),
            on_cycle: None,
        }
    }

    /// Logs a row for every fresh status instead of every `log_rate_hz`-th cycle: for a
    /// host that sees the status only in the firmware's telemetry frames (a real board's, at
    /// the firmware's own decimation, whose frames need not fall on those cycles).
    pub fn log_each_status(mut self) -> Self {
        self.log_each_status = true;
        self
    }

    /// Compression cycles completed so far.
    pub fn cycles_done(&self) -> u32 {
        self.cycles_done
    }

    /// One control period, after the firmware ran it and before the plant advances: looks
    /// at the status (`fresh`: seen this period; a stale one counts for the plant's figures
    /// only), acts, records. `injected`: the fault injector's verdict that the injected
    /// faults' outcome is known (`None` without injected faults). Breaks when the run is over.
    pub fn cycle(
        &mut self,
        w: &mut World,
        link: &mut dyn HostLink,
        fresh: bool,
        injected: Option<bool>,
    ) -> ControlFlow<()> {
        let status = link.status();
        let t = w.time_s();
        self.record(w, &status, fresh);
        let before = self.phase;
        self.phase = self.next_phase(w, link, &status, fresh, t);
        // A new stage (homing done, a cycle done, the stop begun) gets its own time.
        if begins_stage(before, self.phase) {
            self.stage_deadline_s = t + self.opts.cycle_limit_s();
        }
        self.last_mode = status.mode;
        self.verdict(&status, t, injected)
    }

    /// The log's row (at the log's rate, after the first period) and the figures of this
    /// period.
    fn record(&mut self, w: &World, status: &Status, fresh: bool) {
        if fresh
            && w.cycle() > 0
            && (self.log_each_status || w.cycle().is_multiple_of(self.log_stride))
        {
            self.capture.push(status, w);
        }
        self.metrics.observe(
            w,
            status,
            fresh,
            matches!(self.phase, Phase::Running { .. }),
            self.phase == Phase::Homing,
            self.cycles_done,
        );
    }

    /// The operator's next step from the current phase, at `t` s.
    fn next_phase(
        &mut self,
        w: &mut World,
        link: &mut dyn HostLink,
        status: &Status,
        fresh: bool,
        t: f64,
    ) -> Phase {
        match self.phase {
            // Home as soon as the link takes a command (the simulator's at once; a real
            // board's once its RTT channels are up).
            Phase::Homing if !self.metrics.home_sent => {
                self.metrics.home_sent = link.post_command(Command::Home);
                Phase::Homing
            }
            Phase::Homing if status.homed && status.mode == ModeKind::Holding => {
                self.start_strokes(w, link, status, t)
            }
            Phase::Running {
                toward_b,
                ref_extreme_m,
            } => self.stroke(w, link, status, fresh, t, toward_b, ref_extreme_m),
            Phase::Stopping if status.mode == ModeKind::Holding => Phase::Done,
            other => other,
        }
    }

    /// Homing is done: closes the bypass (from now on the rotation times the ports), sets
    /// the volume ratio, carries out the actions scheduled before the first cycle, starts.
    fn start_strokes(
        &mut self,
        w: &mut World,
        link: &mut dyn HostLink,
        status: &Status,
        t: f64,
    ) -> Phase {
        w.plant.port_mode = PortMode::Timed;
        link.ports_timed();
        self.capture.ports_timed_from(t);
        if self.opts.volume_ratio != RatioTarget::FollowMeasured {
            let _ = link.post_command(Command::SetVolumeRatio {
                target: self.opts.volume_ratio,
            });
        }
        while let Some((_, action)) = self.actions.next_if(|(c, _)| *c == 0) {
            act(w, link, action);
        }
        let _ = link.post_command(Command::Start {
            peak_speed_mps: self.speed as f32,
        });
        Phase::Running {
            toward_b: true,
            ref_extreme_m: f64::from(status.reference_m),
        }
    }

    /// A period of the stroke toward head B (`toward_b`) or A whose reference has reached
    /// `ref_extreme_m` so far: a dead point when the reference turns back past it by more
    /// than 20 µm (a cycle at each one at A), the stop once the cycles are done.
    #[allow(clippy::too_many_arguments)]
    fn stroke(
        &mut self,
        w: &mut World,
        link: &mut dyn HostLink,
        status: &Status,
        fresh: bool,
        t: f64,
        toward_b: bool,
        ref_extreme_m: f64,
    ) -> Phase {
        let x = w.plant.x_m;
        self.metrics.stroking(w, status, fresh, t, toward_b);
        let r = f64::from(status.reference_m);
        let turned = if toward_b {
            r < ref_extreme_m - 20e-6
        } else {
            r > ref_extreme_m + 20e-6
        };
        if fresh && turned && status.mode == ModeKind::Running {
            let target = if toward_b { self.dead_b } else { self.dead_a };
            self.metrics.dead_point(x, target, toward_b, t);
            if !toward_b {
                self.cycle_completed(w, link);
            }
            if self.cycles_done >= self.opts.cycles {
                let _ = link.post_command(Command::Stop);
                Phase::Stopping
            } else {
                Phase::Running {
                    toward_b: !toward_b,
                    ref_extreme_m: r,
                }
            }
        } else {
            let ref_extreme_m = if !fresh {
                ref_extreme_m
            } else if toward_b {
                ref_extreme_m.max(r)
            } else {
                ref_extreme_m.min(r)
            };
            Phase::Running {
                toward_b,
                ref_extreme_m,
            }
        }
    }

    /// A compression cycle completed: tells `on_cycle`, carries out the actions scheduled
    /// up to it, records its energies.
    fn cycle_completed(&mut self, w: &mut World, link: &mut dyn HostLink) {
        self.cycles_done += 1;
        let done = self.cycles_done;
        if let Some(tell) = self.on_cycle {
            tell(done);
        }
        while let Some((_, action)) = self.actions.next_if(|(c, _)| *c <= done) {
            act(w, link, action);
        }
        self.metrics.cycle_done(w);
    }

    /// Whether the run is over at `t` s: done, the injected faults' outcome known (else a
    /// latched fault), the time limit, Ctrl-C, or a stage that made no progress in its time
    /// (until the first injected fault begins). Sets the stop reason.
    fn verdict(&mut self, status: &Status, t: f64, injected: Option<bool>) -> ControlFlow<()> {
        let faulted = !status.faults.is_empty();
        let outcome_known = injected.unwrap_or(faulted);
        if self.phase == Phase::Done {
            return ControlFlow::Break(());
        }
        if outcome_known {
            if !faulted {
                self.stop_reason = Some("the injected faults' outcome was known".into());
            }
            return ControlFlow::Break(());
        }
        let limit_s = self.limit_s;
        if t > limit_s {
            self.stop_reason = Some(format!(
                "the time limit of {limit_s:.1} s simulated ran out"
            ));
            return ControlFlow::Break(());
        }
        // Ctrl-C, when the command keeps what ran (`run --keep-partial`).
        if crate::interrupt::interrupted() {
            self.stop_reason = Some(format!("interrupted (Ctrl-C) at {t:.3} s simulated"));
            return ControlFlow::Break(());
        }
        if t > self.stage_deadline_s && t < self.first_fault_s {
            self.stop_reason = Some(self.no_progress(status.mode));
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    }

    /// Why the current stage ran out of its time, the firmware in `mode`.
    fn no_progress(&self, mode: ModeKind) -> String {
        let opts = self.opts;
        let what = match self.phase {
            Phase::Homing => format!(
                "homing did not finish within {:.1} s simulated",
                opts.homing_limit_s()
            ),
            Phase::Stopping => format!(
                "the stop did not end in holding within {:.1} s simulated",
                opts.cycle_limit_s()
            ),
            _ => format!(
                "cycle {} did not complete within {:.1} s simulated",
                self.cycles_done + 1,
                opts.cycle_limit_s()
            ),
        };
        format!("no progress: {what} (mode {})", mode.name())
    }

    /// The figures and the log of the run that ended with `world`.
    pub fn finish(self, world: World, injection: InjectionReport) -> Result<RunOutcome, String> {
        let RunDriver {
            opts,
            mut log,
            mut metrics,
            cycles_done,
            stop_reason,
            capture,
            last_mode,
            started,
            ..
        } = self;
        // The loop alone: writing a streamed log is not part of it, as writing the CSV after
        // the loop is not.
        let wall = (started.elapsed().as_secs_f64() - capture.writing_s()).max(0.0);
        // Making the columns is part of writing the log, as the CSV is: outside the timing.
        capture.finish(&mut log)?;
        let end = RunEnd {
            sim_time_s: world.time_s(),
            wall_time_s: wall,
            cycles_done,
            stop_reason,
            last_mode,
        };
        let summary = metrics.summary(opts, &end, &injection);
        Ok(RunOutcome {
            summary,
            log,
            telemetry: world.telemetry.bytes,
            opening_errors: metrics.opening_errors,
            cycle_work_j: per_cycle(&metrics.work_at_cycle_j),
            cycle_motor_work_j: per_cycle(&metrics.motor_work_at_cycle_j),
            injection,
        })
    }
}

/// Whether going from phase `before` to `after` begins a stage with its own time: homing
/// done, a cycle done (the stroke toward B begins), the stop begun.
fn begins_stage(before: Phase, after: Phase) -> bool {
    match (before, after) {
        (
            Phase::Homing
            | Phase::Running {
                toward_b: false, ..
            },
            Phase::Running { toward_b, .. },
        ) => toward_b,
        (Phase::Running { .. }, Phase::Stopping) => true,
        _ => false,
    }
}

/// Each cycle's share of a quantity recorded cumulatively at every completed cycle.
fn per_cycle(cumulative: &[f64]) -> Vec<f64> {
    cumulative.windows(2).map(|w| w[1] - w[0]).collect()
}

/// Carries out a scheduled host action.
fn act(w: &mut World, link: &mut dyn HostLink, action: HostAction) {
    match action {
        HostAction::SetLinePressureRatio(pr) => w.plant.lines.set_pressure_ratio(pr),
        HostAction::UnloadPorts => w.plant.port_mode = PortMode::Unloaded,
        HostAction::Command(c) => {
            let _ = link.post_command(c);
        }
    }
}
