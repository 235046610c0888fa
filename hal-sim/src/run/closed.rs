//! The paper's first campaign (§4), as a run: both ports closed, the published drives
//! accelerate the piston from the middle of the travel toward head B with the
//! accelerate-then-stop profile (the force it takes, logged, is "the same force as a function
//! of time" the paper replayed), stop it at a chosen position so that chamber B reaches
//! 3–7 bar, and hold it there while the pressure equalises through the leaks. The log says
//! `# ports = closed`, so `fpc-sim gap` replays the chambers along it and names the leak a
//! model lacks.

use std::io::Write;
use std::ops::ControlFlow;
use std::time::Instant;

use super::capture::Capture;
use super::{world, RunOptions, RunOutcome, Summary, COLUMNS, CONTROL_RATE_HZ};
use crate::plant::chambers::PortMode;
use crate::published::Rig;
use crate::runlog::RunLog;

/// Rest before the move, s (the replay starts from what the sensors read at rest).
pub const REST_BEFORE_S: f64 = 0.1;

/// A closed-port test: where to stop and how long to hold.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClosedPort {
    /// Stop position, m from head A.
    pub stop_m: f64,
    /// Hold at the stop, s.
    pub hold_s: f64,
}

/// Accepted holds, s.
pub const HOLD_RANGE_S: (f64, f64) = (0.1, 60.0);

impl ClosedPort {
    /// Checks the test against the model's travel and clearances; the error names the flag.
    pub fn validate(&self, opts: &RunOptions) -> Result<(), String> {
        let m = &opts.model;
        let mid = 0.5 * m.piston.travel_m;
        let hi = m.piston.travel_m - m.limits.target_head_clearance_m;
        if !(self.stop_m.is_finite() && self.stop_m > mid && self.stop_m <= hi) {
            return Err(format!(
                "--closed-port {}: the stop must lie between the middle of the travel ({} m) \
                 and the dead point B ({} m): the test compresses chamber B",
                crate::failure::num(self.stop_m),
                crate::failure::num(mid),
                crate::failure::num(hi)
            ));
        }
        let (lo, hi) = HOLD_RANGE_S;
        if !(self.hold_s.is_finite() && (lo..=hi).contains(&self.hold_s)) {
            return Err(format!(
                "--hold {}: must be in [{lo}, {hi}] s",
                crate::failure::num(self.hold_s)
            ));
        }
        Ok(())
    }
}

/// The closed-port run of `opts` (its `closed_port` is `test`); streamed to `csv` if given.
pub(super) fn simulate(
    opts: &RunOptions,
    test: ClosedPort,
    csv: Option<&mut dyn Write>,
) -> Result<RunOutcome, String> {
    simulate_replaying(opts, test, csv, None).map(|(out, _)| out)
}

/// The paper's closed-port test both ways (§4): the move to `test.stop_m` under the position
/// loop, then the same master force command as a function of time replayed open loop on a
/// fresh plant (same seed). Returns (closed loop, open loop).
pub fn closed_and_open_loop(
    opts: &RunOptions,
    test: ClosedPort,
) -> Result<(RunOutcome, RunOutcome), String> {
    let (closed, force_n) = simulate_replaying(opts, test, None, None)?;
    let (open, _) = simulate_replaying(opts, test, None, Some(force_n))?;
    Ok((closed, open))
}

/// [`simulate`], its force command recorded each period from the move's start, or (with
/// `replay`) that record driven open loop instead of the move.
fn simulate_replaying(
    opts: &RunOptions,
    test: ClosedPort,
    csv: Option<&mut dyn Write>,
    mut replay: Option<Vec<f64>>,
) -> Result<(RunOutcome, Vec<f64>), String> {
    let model = &opts.model;
    let start = 0.5 * model.piston.travel_m;
    let mut w = world(model, opts.seed, opts.start_us, start);
    w.plant.port_mode = PortMode::Closed;
    let mut rig = Rig::new(model, &w, opts.pressure_ratio, opts.volume_ratio);
    let mut log = RunLog::with_columns(&COLUMNS);
    for (k, v) in [
        ("source", "fpc-sim run --closed-port".to_string()),
        ("sample_rate_hz", opts.log_rate_hz.to_string()),
        ("model", opts.model_name.clone()),
        ("seed", opts.seed.to_string()),
        ("force_delay_s", format!("{:e}", 0.0)),
        ("controller", "published".to_string()),
        ("ports", "closed".to_string()),
        ("closed_port_stop_m", test.stop_m.to_string()),
    ] {
        log.meta.push((k.into(), v));
    }
    for name in &mut log.names {
        if name == "v_mps" {
            *name = "v_drive_mps".into();
        }
    }
    let speed = opts.peak_speed_mps();
    let move_s = 2.0 * (test.stop_m - start) / speed;
    let end_s = REST_BEFORE_S + move_s + test.hold_s;
    let mut capture = Capture::new(end_s + 0.01, csv, &log);
    let stride = u64::from((CONTROL_RATE_HZ / opts.log_rate_hz.max(1)).max(1));
    let mut moved = false;
    let mut recorded = Vec::new();
    let (mut peak_pa, mut peak_speed, mut min_clear) = (0.0f64, 0.0f64, f64::INFINITY);
    let started = Instant::now();
    let world = crate::published::simulate(w, &mut rig, |w, rig| {
        let t = w.time_s();
        if w.cycle() > 0 && w.cycle().is_multiple_of(stride) {
            capture.push(&rig.status(), w);
        }
        if !moved && t >= REST_BEFORE_S {
            match replay.take() {
                Some(force_n) => rig.replay_force(force_n, w.cycle() + 1),
                None => rig.move_to(test.stop_m, speed, t),
            }
            moved = true;
        } else if moved {
            recorded.push(f64::from(rig.status().force_command_n));
        }
        peak_pa = peak_pa.max(w.plant.chambers.b.pressure_pa);
        peak_speed = peak_speed.max(w.plant.v_mps.abs());
        min_clear = min_clear.min(w.plant.head_clearance_m());
        if t >= end_s {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    let wall = (started.elapsed().as_secs_f64() - capture.writing_s()).max(0.0);
    capture.finish(&mut log)?;
    let end_pa = world.plant.chambers.b.pressure_pa;
    let sim_time_s = world.time_s();
    let summary = Summary {
        sim_time_s,
        wall_time_s: wall,
        realtime_factor: super::summary::realtime_factor(sim_time_s, wall),
        cycles: 0,
        cycles_requested: 0,
        stopped_early: None,
        faults_not_injected: Vec::new(),
        pressure_ratio_target: opts.pressure_ratio,
        discharge_open_pressure_error: None,
        tracking_error_rms_m: None,
        indicated_work_j_per_cycle: None,
        dead_point_error_m: Some((world.plant.x_m - test.stop_m).abs()),
        min_head_clearance_m: Some(min_clear),
        peak_speed_mps: peak_speed,
        master_slave_force_diff_rms_n: None,
        faults: Vec::new(),
        state: rig.status().mode.name().to_string(),
        controller: "published".into(),
        closed_port_peak_pa: Some(peak_pa),
        closed_port_end_pa: Some(end_pa),
        ..Summary::default()
    };
    Ok((
        RunOutcome {
            summary,
            log,
            telemetry: Vec::new(),
            opening_errors: Vec::new(),
            cycle_work_j: Vec::new(),
            cycle_motor_work_j: Vec::new(),
            injection: Default::default(),
        },
        recorded,
    ))
}
