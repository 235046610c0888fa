//! Synthetic "measured" runs for the model-gap proofs, the benchmark and the docs: the plant
//! of a *truth* model driven along a prescribed motion (`Plant::advance_kinematic`), sensed
//! as the rig senses it (encoder noise, pressure-sensor lag, offset, noise and 12-bit
//! codes), with the motor force the motion needed logged as the drives would report it.
//!
//! Closed-loop runs with the firmware in the loop come from [`crate::run::run`]; these
//! prescribed runs cover what the closed loop cannot do: the paper's closed-port campaign
//! (compress, hold, let the pressure decay) and timed ports along a known rotation.

use crate::logmeta::{LogMeta, PortsDeclared};
use std::f64::consts::PI;

use fpc::physics::balance::PistonState;
use fpc::sensing::pressure::PressureCalibration;

use crate::plant::chambers::PortMode;
use crate::plant::dynamics::{Plant, PlantParams};
use crate::plant::kinematic::CycleDrive;
use crate::plant::model::MachineModel;
use crate::plant::noise::Noise;
use crate::plant::sensing::Transducer;
use crate::runlog::{RunLog, REQUIRED};

/// Sample time of the synthetic runs, s (the simulator's 20 kHz).
pub const SAMPLE_TIME_S: f64 = 50e-6;

/// Encoder noise after interpolation, m RMS (`docs/machine.md`: σ ≈ 1 µm).
pub const ENCODER_NOISE_M: f64 = 1e-6;

/// Noise of a reported section force, N RMS.
pub const FORCE_NOISE_N: f64 = 2.0;

/// One segment of a prescribed closed-port motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Move {
    /// Where to go, m.
    pub to_m: f64,
    /// How long the move takes (cosine profile), s.
    pub duration_s: f64,
    /// How long to hold there afterwards, s.
    pub hold_s: f64,
}

/// The paper's first campaign, reproduced: from the middle, compress chamber B to ≈ 5 bar
/// and hold while it leaks, back to the middle, compress A, hold, back — `repeats` times.
pub fn closed_port_moves(model: &MachineModel, repeats: usize) -> (f64, Vec<Move>) {
    let travel = model.piston.travel_m;
    let mid = 0.5 * travel;
    let one = [
        Move {
            to_m: 0.82 * travel,
            duration_s: 0.06,
            hold_s: 0.5,
        },
        Move {
            to_m: mid,
            duration_s: 0.06,
            hold_s: 0.2,
        },
        Move {
            to_m: 0.18 * travel,
            duration_s: 0.06,
            hold_s: 0.5,
        },
        Move {
            to_m: mid,
            duration_s: 0.06,
            hold_s: 0.2,
        },
    ];
    (
        mid,
        one.iter()
            .copied()
            .cycle()
            .take(4 * repeats.max(1))
            .collect(),
    )
}

/// Position (m), velocity (m/s), acceleration (m/s²) along `moves` at `t_s`.
fn along(start_m: f64, moves: &[Move], t_s: f64) -> (f64, f64, f64) {
    let mut from = start_m;
    let mut t0 = 0.1; // rest first: the replay starts from what the sensors read at rest
    if t_s < t0 {
        return (from, 0.0, 0.0);
    }
    for m in moves {
        let tau = t_s - t0;
        if tau < m.duration_s {
            let w = PI / m.duration_s;
            let h = 0.5 * (m.to_m - from);
            return (
                from + h * (1.0 - (w * tau).cos()),
                h * w * (w * tau).sin(),
                h * w * w * (w * tau).cos(),
            );
        }
        if tau < m.duration_s + m.hold_s {
            return (m.to_m, 0.0, 0.0);
        }
        t0 += m.duration_s + m.hold_s;
        from = m.to_m;
    }
    (from, 0.0, 0.0)
}

/// Duration of a closed-port motion, s.
pub fn moves_duration_s(moves: &[Move]) -> f64 {
    0.1 + moves.iter().map(|m| m.duration_s + m.hold_s).sum::<f64>()
}

/// A closed-port run of the truth model along `moves` from `start_m` (`# ports = closed`).
pub fn closed_port_run(truth: &MachineModel, start_m: f64, moves: &[Move], seed: u64) -> RunLog {
    let end = moves_duration_s(moves);
    prescribed(truth, seed, PortMode::Closed, end, start_m, |t| {
        let (x, v, a) = along(start_m, moves, t);
        (x, v, a, 0.0, 0.0)
    })
}

/// An open-port compressor run of the truth model: the prescribed cycle of
/// [`CycleDrive`] (sinusoidal stroke, discharge timed for `pressure_ratio`) for `cycles`
/// cycles at peak speed `v_max_mps` (`# ports = open`, line pressures logged).
pub fn open_port_run(
    truth: &MachineModel,
    pressure_ratio: f64,
    v_max_mps: f64,
    cycles: f64,
    seed: u64,
) -> RunLog {
    let drive = CycleDrive::new(
        truth,
        truth.limits.target_head_clearance_m,
        v_max_mps,
        pressure_ratio,
    );
    let end = cycles * drive.period_s();
    let dt = SAMPLE_TIME_S;
    let x0 = drive.at(0.0).0;
    let mut log = prescribed(truth, seed, PortMode::Timed, end, x0, |t| {
        let (x, th) = drive.at(t);
        let (xp, thp) = drive.at(t + 0.5 * dt);
        let (xm, thm) = drive.at(t - 0.5 * dt);
        let v = (xp - xm) / dt;
        let a = drive.omega_rad_s * drive.omega_rad_s * (drive.x_mid_m - x);
        (x, v, a, th, (thp - thm) / dt)
    });
    log.meta
        .push(("pressure_ratio".into(), pressure_ratio.to_string()));
    log
}

/// Drives the truth plant along `path(t) = (x, v, a, θ, ω)` and logs it as sensed.
fn prescribed(
    truth: &MachineModel,
    seed: u64,
    mode: PortMode,
    end_s: f64,
    x0: f64,
    path: impl Fn(f64) -> (f64, f64, f64, f64, f64),
) -> RunLog {
    let dt = SAMPLE_TIME_S;
    let mut plant = Plant::new(PlantParams::from_model(truth), x0);
    plant.port_mode = mode;
    // The transducers' laws (plant::sensing) and the firmware's calibration of their codes,
    // as the simulated board has them.
    let pressure = &truth.sensors.pressure;
    let calibration = PressureCalibration::reference();
    let mut noise = Noise::new(seed);
    let lag = pressure.lag(dt);
    let transducers = pressure.transducers();
    let laws = truth.piston_laws();
    let r = truth.friction_radius_m();
    let mut cols = REQUIRED.to_vec();
    cols.extend(["p_suction_pa", "p_discharge_pa"]);
    let mut log = RunLog::with_columns(&cols);
    LogMeta {
        source: Some("fpc-sim gap synth (prescribed motion)".into()),
        sample_rate_hz: Some((1.0 / dt).round()),
        force_delay_s: Some(crate::run::FIRMWARE_FORCE_DELAY_S),
        ports: Some(if mode == PortMode::Closed {
            PortsDeclared::Closed
        } else {
            PortsDeclared::Open
        }),
        ..LogMeta::default()
    }
    .write(&mut log);
    let mut lagged = [plant.chambers.a.pressure_pa, plant.chambers.b.pressure_pa];
    // The drives' forces are reported as the firmware reports them: one control period
    // behind the row's position (declared as `# force_delay_s`).
    let mut reported: Option<f64> = None;
    let steps = (end_s / dt).round() as usize;
    for k in 0..=steps {
        let t = k as f64 * dt;
        let (x, v, a, theta, omega) = path(t);
        if k > 0 {
            plant.advance_kinematic(x, theta, dt);
        }
        let (pa, pb) = (plant.chambers.a.pressure_pa, plant.chambers.b.pressure_pa);
        // The motor force the prescribed motion needs: the balance inverted.
        let now = laws
            .forces(&PistonState {
                x_m: x,
                v_mps: v,
                tangential_mps: omega * r,
                pressure_a_pa: pa,
                pressure_b_pa: pb,
                motor_n: 0.0,
            })
            .motor_needed_n(laws.mass_kg, a);
        let motors = reported.replace(now).unwrap_or(now);
        let mut read = |i: usize, p: f64, noise: &mut Noise| {
            let l = lagged.get_mut(i).map_or(p, |l| {
                lag.step(l, p);
                *l
            });
            let t = transducers.get(i).copied().unwrap_or(Transducer {
                offset_pa: 0.0,
                gain: 1.0,
            });
            let code = calibration.code_for(pressure.noisy_reading_pa(l, t, noise) as f32);
            f64::from(calibration.convert(code).pressure_pa)
        };
        let p_a = read(0, pa, &mut noise);
        let p_b = read(1, pb, &mut noise);
        let xm = x + noise.scaled(ENCODER_NOISE_M);
        let x_true_slave = truth
            .effects
            .encoder_pitch_error
            .as_ref()
            .map_or(x, |e| e.reading_m(x, v));
        let xs = x_true_slave + noise.scaled(ENCODER_NOISE_M);
        let fm = 0.5 * motors + noise.scaled(FORCE_NOISE_N);
        let fs = 0.5 * motors + noise.scaled(FORCE_NOISE_N);
        log.push_row(&[
            t,
            xm,
            xs,
            theta,
            fm,
            fs,
            p_a,
            p_b,
            plant.lines.suction_pa,
            plant.lines.discharge_pa,
        ]);
    }
    log
}

/// Resamples a run log to every `factor`-th row (e.g. 20 kHz → 10 kHz), metadata kept.
pub fn decimate(log: &RunLog, factor: usize) -> RunLog {
    let f = factor.max(1);
    let mut out = log.clone();
    for c in &mut out.columns {
        *c = c.iter().copied().step_by(f).collect();
    }
    // (Our own logs: their metadata reads.)
    if let Ok(mut meta) = LogMeta::read(log) {
        meta.sample_rate_hz = meta.sample_rate_hz.map(|r| r / f as f64);
        meta.write(&mut out);
    }
    out
}
