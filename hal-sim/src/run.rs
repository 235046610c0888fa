//! `fpc-sim run`: the closed-loop simulation of the machine with the firmware in the loop.
//!
//! The host side of the run plays the operator: it homes the axis, then commands strokes
//! between the two dead points (1 mm from each head) at the requested peak speed for the
//! requested number of cycles, exactly as it would over the RTT command channel. Everything
//! the firmware does, it does in its own task bodies against the simulated board.

use std::ops::ControlFlow;
use std::time::Instant;

use fpc::command::Command;
use fpc::controller::{ControlConfig, ModeKind, Status};
use fpc::faults::Fault;
use serde::Serialize;

use crate::exec::{simulate, SimShared};
use crate::model::MachineModel;
use crate::plant::{Plant, PlantParams};
use crate::runlog::{RunLog, REQUIRED};
use crate::world::{Sensors, World};

/// Pressure ratio → peak speed of the paper's Fig. 3 (PR, m/s).
pub const FIG3_SPEEDS: [(f64, f64); 4] = [(3.1, 2.3), (3.7, 2.8), (4.3, 3.5), (5.1, 4.1)];

/// Accepted pressure ratios.
pub const PRESSURE_RATIO_RANGE: (f64, f64) = (1.0, 6.0);
/// Accepted peak speeds, m/s.
pub const SPEED_RANGE_MPS: (f64, f64) = (0.05, 4.5);

/// Options of a run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The machine.
    pub model: MachineModel,
    /// Where the model came from (for the log's metadata).
    pub model_name: String,
    /// Target pressure ratio.
    pub pressure_ratio: f64,
    /// Peak speed, m/s (`None`: from the pressure ratio as in Fig. 3).
    pub speed_mps: Option<f64>,
    /// Compression cycles (A → B → A) to run.
    pub cycles: u32,
    /// Noise seed.
    pub seed: u64,
    /// What the board's µs time base reads at the start (to exercise its wrap).
    pub start_us: u32,
    /// Where the piston rests at power-up, m from head A.
    pub start_position_m: f64,
}

impl RunOptions {
    /// Defaults on the reference machine.
    pub fn reference() -> Self {
        RunOptions {
            model: MachineModel::reference(),
            model_name: "reference".into(),
            pressure_ratio: 3.1,
            speed_mps: None,
            cycles: 10,
            seed: 1,
            start_us: 0,
            start_position_m: 0.005,
        }
    }

    /// Peak speed to use, m/s.
    pub fn peak_speed_mps(&self) -> f64 {
        self.speed_mps
            .unwrap_or_else(|| speed_for_pressure_ratio(self.pressure_ratio))
    }

    /// Checks the options; the error names the flag at fault.
    pub fn validate(&self) -> Result<(), String> {
        let (lo, hi) = PRESSURE_RATIO_RANGE;
        if !(self.pressure_ratio.is_finite() && (lo..=hi).contains(&self.pressure_ratio)) {
            return Err(format!(
                "--pressure-ratio {} is outside [{lo}, {hi}]",
                self.pressure_ratio
            ));
        }
        let (lo, hi) = SPEED_RANGE_MPS;
        if let Some(v) = self.speed_mps {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(format!("--speed {v} is outside [{lo}, {hi}] m/s"));
            }
        }
        if self.cycles == 0 || self.cycles > 10_000 {
            return Err(format!("--cycles {} is outside [1, 10000]", self.cycles));
        }
        Ok(())
    }
}

/// Peak speed for a pressure ratio, interpolated (and held at the ends) in Fig. 3's table.
pub fn speed_for_pressure_ratio(pr: f64) -> f64 {
    let mut prev = FIG3_SPEEDS[0];
    if pr <= prev.0 {
        return prev.1;
    }
    for &(p, v) in &FIG3_SPEEDS[1..] {
        if pr <= p {
            return prev.1 + (v - prev.1) * (pr - prev.0) / (p - prev.0);
        }
        prev = (p, v);
    }
    prev.1
}

/// The JSON summary of a run (`formats.md` §3). `None` is printed as `null`: a figure that
/// this simulation cannot yet produce is never invented.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Summary {
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Wall-clock time of the simulation, s.
    pub wall_time_s: f64,
    /// Simulated seconds per wall second.
    pub realtime_factor: f64,
    /// Completed compression cycles.
    pub cycles: u32,
    /// Requested pressure ratio.
    pub pressure_ratio_target: f64,
    /// Max over the last 5 cycles of |p_chamber − p_discharge|/p_discharge at discharge
    /// opening (needs the chamber model).
    pub discharge_open_pressure_error: Option<f64>,
    /// Max over the last 5 cycles of |reached − target| dead point, m.
    pub dead_point_error_m: Option<f64>,
    /// Smallest distance to a head after homing, m.
    pub min_head_clearance_m: Option<f64>,
    /// Largest |velocity|, m/s.
    pub peak_speed_mps: f64,
    /// RMS of the master − slave force difference while stroking, N.
    pub master_slave_force_diff_rms_n: Option<f64>,
    /// Faults in the order latched.
    pub faults: Vec<String>,
    /// Final mode.
    pub state: String,
}

/// A finished run: the summary and the run log.
#[derive(Clone, Debug)]
pub struct RunOutcome {
    /// Figures.
    pub summary: Summary,
    /// The log (what `run.csv` holds).
    pub log: RunLog,
}

/// Columns of the simulator's run log: the required ones, then optional ones.
pub const COLUMNS: [&str; 12] = [
    REQUIRED[0],
    REQUIRED[1],
    REQUIRED[2],
    REQUIRED[3],
    REQUIRED[4],
    REQUIRED[5],
    REQUIRED[6],
    REQUIRED[7],
    "x_ref_m",
    "theta_ref_rad",
    "v_mps",
    "fault",
];

/// The controller's configuration for a model: the firmware's reference tuning with the
/// model's machine parameters.
pub fn control_config(model: &MachineModel) -> ControlConfig {
    let mut c = ControlConfig::reference();
    c.moving_mass_kg = model.piston.mass_kg as f32;
    c.travel_m = model.piston.travel_m as f32;
    c.piston_area_m2 = model.piston_area_m2() as f32;
    let f = model.friction();
    c.friction.coulomb_n = f.coulomb_n as f32;
    c.friction.static_n = f.static_n as f32;
    c.friction.viscous_ns_per_m = f.viscous_ns_per_m as f32;
    c.friction.stribeck_velocity_mps = f.stribeck_velocity_mps as f32;
    c.friction.stribeck_exponent = f.stribeck_exponent as f32;
    c.encoder_master.period_m = model.encoder.period_m as f32;
    c.encoder_slave.period_m = model.encoder.period_m as f32;
    c.motor.electrical_period_m = (2.0 * model.motor.pole_pitch_m) as f32;
    c
}

/// The simulated board for a model.
pub fn world(model: &MachineModel, seed: u64, start_us: u32, start_position_m: f64) -> World {
    let mut p = PlantParams::reference();
    p.mass_kg = model.piston.mass_kg;
    p.travel_m = model.piston.travel_m;
    p.friction = model.friction();
    p.motor.electrical_period_m = 2.0 * model.motor.pole_pitch_m;
    p.chamber_pressure_pa = model.gas.ambient_pa;
    let mut s = Sensors::reference();
    s.encoder_period_m = model.encoder.period_m;
    World::new(Plant::new(p, start_position_m), s, seed, start_us)
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    Homing,
    Stroking { toward_b: bool, seen_moving: bool },
    Done,
}

/// Collects the figures while the run goes on.
#[derive(Default)]
struct Metrics {
    dead_point_errors: Vec<f64>,
    extreme_m: Option<f64>,
    min_clearance_m: Option<f64>,
    peak_speed_mps: f64,
    force_diff_sq: f64,
    force_diff_n: u64,
    faults: Vec<Fault>,
}

/// Runs the simulation.
pub fn run(opts: &RunOptions) -> Result<RunOutcome, String> {
    opts.validate()?;
    let model = &opts.model;
    let speed = opts.peak_speed_mps();
    let config = control_config(model);
    let dead_a = f64::from(config.target_clearance_m);
    let dead_b = f64::from(config.travel_m - config.target_clearance_m);
    let world = world(model, opts.seed, opts.start_us, opts.start_position_m);

    let mut log = RunLog::with_columns(&COLUMNS);
    log.meta.push(("source".into(), "fpc-sim run".into()));
    log.meta.push(("sample_rate_hz".into(), "20000".into()));
    log.meta.push(("model".into(), opts.model_name.clone()));
    log.meta.push(("seed".into(), opts.seed.to_string()));

    let mut phase = Phase::Homing;
    let mut metrics = Metrics::default();
    let mut cycles_done = 0u32;
    // Homing creeps at 10 mm/s over at most the travel; strokes take well under 1 s each.
    let limit_s = 2.0 + model.piston.travel_m / 0.01 + f64::from(opts.cycles) * 2.0;
    let mut last = Status::INIT;
    let started = Instant::now();

    let world = simulate(world, config, |w, shared: &SimShared| {
        let status = shared.status();
        let t = w.time_s();
        if w.cycle() > 0 {
            log.push_row(&[
                t,
                f64::from(status.position_m),
                f64::from(status.slave_position_m),
                f64::from(status.theta_rad),
                f64::from(status.force_master_n),
                f64::from(status.force_slave_n),
                f64::from(status.pressure_a_pa),
                f64::from(status.pressure_b_pa),
                f64::from(status.reference_m),
                f64::from(status.theta_reference_rad),
                f64::from(status.velocity_mps),
                f64::from(status.faults.first().map_or(0, |f| f as u8)),
            ]);
        }
        for f in status.faults.iter() {
            if !metrics.faults.contains(&f) {
                metrics.faults.push(f);
            }
        }
        metrics.peak_speed_mps = metrics.peak_speed_mps.max(w.plant.v_mps.abs());
        let faulted = !status.faults.is_empty();
        phase = match phase {
            Phase::Homing if w.cycle() == 0 => {
                let _ = shared.post_command(Command::Home);
                Phase::Homing
            }
            Phase::Homing if status.homed && status.mode == ModeKind::Holding => {
                post_move(shared, dead_b, speed);
                Phase::Stroking {
                    toward_b: true,
                    seen_moving: false,
                }
            }
            Phase::Stroking {
                toward_b,
                seen_moving,
            } => {
                let x = w.plant.x_m;
                let c = w.plant.head_clearance_m();
                metrics.min_clearance_m =
                    Some(metrics.min_clearance_m.map_or(c, |m: f64| m.min(c)));
                let diff = f64::from(status.force_master_n - status.force_slave_n);
                metrics.force_diff_sq += diff * diff;
                metrics.force_diff_n += 1;
                metrics.extreme_m = Some(match metrics.extreme_m {
                    None => x,
                    Some(e) if toward_b => e.max(x),
                    Some(e) => e.min(x),
                });
                let moving = status.mode == ModeKind::Moving;
                if seen_moving && status.mode == ModeKind::Holding && last.mode == ModeKind::Holding
                {
                    let target = if toward_b { dead_b } else { dead_a };
                    let reached = metrics.extreme_m.take().unwrap_or(x);
                    metrics.dead_point_errors.push((reached - target).abs());
                    if !toward_b {
                        cycles_done += 1;
                    }
                    if cycles_done >= opts.cycles {
                        Phase::Done
                    } else {
                        post_move(shared, if toward_b { dead_a } else { dead_b }, speed);
                        Phase::Stroking {
                            toward_b: !toward_b,
                            seen_moving: false,
                        }
                    }
                } else {
                    Phase::Stroking {
                        toward_b,
                        seen_moving: seen_moving || moving,
                    }
                }
            }
            other => other,
        };
        last = status;
        if phase == Phase::Done || faulted || t > limit_s {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });

    let wall = started.elapsed().as_secs_f64();
    let sim_time_s = world.time_s();
    let last5 = metrics.dead_point_errors.len().saturating_sub(10);
    let summary = Summary {
        sim_time_s,
        wall_time_s: wall,
        realtime_factor: if wall > 0.0 {
            sim_time_s / wall
        } else {
            f64::INFINITY
        },
        cycles: cycles_done,
        pressure_ratio_target: opts.pressure_ratio,
        discharge_open_pressure_error: None,
        dead_point_error_m: metrics
            .dead_point_errors
            .get(last5..)
            .and_then(|e| e.iter().copied().reduce(f64::max)),
        min_head_clearance_m: metrics.min_clearance_m,
        peak_speed_mps: metrics.peak_speed_mps,
        master_slave_force_diff_rms_n: (metrics.force_diff_n > 0)
            .then(|| (metrics.force_diff_sq / metrics.force_diff_n as f64).sqrt()),
        faults: metrics
            .faults
            .iter()
            .map(|f| f.name().to_string())
            .collect(),
        state: last.mode.name().to_string(),
    };
    Ok(RunOutcome { summary, log })
}

fn post_move(shared: &SimShared, position_m: f64, speed_mps: f64) {
    let _ = shared.post_command(Command::MoveTo {
        position_m: position_m as f32,
        peak_speed_mps: speed_mps as f32,
    });
}
