//! The chambers replayed along the measured motion through the model: what the model's
//! pressure sensors would read, the pressure channel's prediction ([`super::residuals`]), and
//! where the replay resolves the ports' timing.

use fpc::angle::wrap_rad;

use crate::plant::chambers::{Chambers, Lines, PortMode};
use crate::plant::dynamics::PlantParams;
use crate::plant::model::MachineModel;
use crate::plant::sensing::Transducer;
use crate::plant::servo::through_play;

use super::channel::{sample_resolution, ChannelId};
use super::data::{
    count_quantum, count_spans_rows, Measured, PortsMeta, ThetaSource, PORTS_ANGLE_SPAN_S,
};

/// Longest chamber step of the replay, s: the plant's (one control period). Taken from the
/// whole microseconds: the `f32` period widened to `f64` is 4.99999987e-5 s, which made every
/// 50 µs log two half steps, a replay 70–190 Pa (rising with speed) away from the plant it
/// replays, which the leak and port candidates then explained.
pub const REPLAY_STEP_S: f64 = fpc::units::CONTROL_PERIOD_US as f64 / 1e6;

/// Most chamber sub-steps per log sample: enough for the slowest log the workflow analyses
/// ([`super::data::MIN_SAMPLE_RATE_HZ`]: 10 steps of [`REPLAY_STEP_S`]), and a bound on the
/// replay's cost per row whatever a log's sample time.
pub const MAX_REPLAY_SUBSTEPS: usize = 16;

/// The chambers replayed along the measured motion through the model, as the model's
/// pressure sensors would read them: (p_A, p_B), Pa. `None` without `# ports`.
///
/// The replay starts from what the sensors read while the piston still rests (up to
/// 20 ms), through their offsets and gains, at the wall temperature: the log is taken to start in
/// equilibrium. Sealed chambers never forget that start, so its noise (0.4 kPa over 20 ms
/// is ±30 Pa) comes back multiplied by the compression ratio at every stroke, a pattern the
/// leak and heat candidates would gladly explain. For a log sealed from its first row the
/// gas each chamber holds is therefore a nuisance fitted over the whole log: the replay's
/// least-squares scale against the measured pressures corrects the start, and the chambers
/// are replayed once more from there. Open or timed ports forget the start within a cycle.
pub fn replay_pressures(data: &Measured, model: &MachineModel) -> Option<(Vec<f64>, Vec<f64>)> {
    let kept = kept_replay(data, model)?;
    match kept.as_slice() {
        [a, b] => Some((a.clone(), b.clone())),
        _ => None,
    }
}

/// [`replay_pressures`] as the log keeps it, `[p_A, p_B]`, without a copy.
pub fn kept_replay(data: &Measured, model: &MachineModel) -> Option<std::sync::Arc<Vec<Vec<f64>>>> {
    if data.ports == PortsMeta::Unknown {
        return None;
    }
    // Everything of the model a replay reads: the same values, the same replay (a force
    // effect added by a selection step leaves the chambers as they were).
    let key = format!(
        "{:?}|{:?}|{:?}|{:?}|{:?}|{:e}",
        PlantParams::from_model(model).chambers,
        model.gas,
        model.sensors.pressure,
        model.lines,
        model.servo.backlash_rad,
        data.x_offset_m
    );
    let kept = data.replays.get_or_make(key, || {
        replay_pressures_anew(data, model, &data.ports_angle_rad)
            .map_or_else(Vec::new, |(a, b)| vec![a, b])
    });
    (kept.len() == 2).then_some(kept)
}

/// Where the pressure channel may be judged on a log whose ports are timed by a servo's
/// count (`# theta_source = servo_encoder`, open ports): 1 where the chambers' replay does
/// not hinge on where the angle lies within its count, 0 where it does. `None` where every
/// sample may be judged (the piston's own angle logged, or no timed ports).
///
/// Between two steps of the count the log says only that the angle is inside it; the
/// replay draws it through the crossings ([`super::data::ports_angle`]). That is close
/// where many crossings fall within the fit's span, but a count that lasts about as long
/// as the span leaves the angle anywhere in it, and a servo whose own loop closes on that
/// count does not turn evenly within it: on our runs at 0.3 m/s and PR 4.5 the servo turned
/// slowly after each step and quickly before the next (half-way through a count lasting
/// 3–100 ms it had covered 0.42–0.45 of it), on average 0.06–0.1 mrad (up to 0.3) behind
/// the estimate near the dead points, where a count lasts longer than 3 ms. A chamber
/// blowing down through its opening port follows the angle there within a few hundredths
/// of a count: the replay emptied it early and missed the plant by about 1 kPa at every
/// dead point, which `leakage` explained by closing the rod seals (50–69 % of the residual
/// on two null runs of three).
///
/// So each sample's angle is taken as known within `±u`, half a count times the count's
/// length over [`PORTS_ANGLE_SPAN_S`] (at most half a count), and a sample whose replay,
/// with every angle moved by `u`, changes by more than one sensor code
/// ([`sample_resolution`]) is not judged: what it shows is the angle's
/// position within its count, not the chambers' physics. (One moved replay beside the
/// model's own, which the selection reads anyway: on the 732k-row log two moved replays
/// cost 2.7 s of CPU and about 1.4 s of wall time.)
pub fn ports_resolved(data: &Measured, model: &MachineModel) -> Option<Vec<f64>> {
    if data.ports != PortsMeta::Open || data.theta_source != ThetaSource::ServoEncoder {
        return None;
    }
    let quantum = count_quantum(&data.theta_rad);
    if !quantum.is_finite() {
        return None;
    }
    let span_rows = PORTS_ANGLE_SPAN_S / data.dt_s;
    let unknown: Vec<f64> = count_spans_rows(&data.theta_rad)
        .iter()
        .map(|rows| 0.5 * quantum * (rows / span_rows).min(1.0))
        .collect();
    let moved = || -> Option<(Vec<f64>, Vec<f64>)> {
        let angle: Vec<f64> = data
            .ports_angle_rad
            .iter()
            .zip(&unknown)
            .map(|(a, u)| a + u)
            .collect();
        replay_pressures_anew(data, model, &angle)
    };
    // The model's own replay is kept with the log (the selection's first step reads it):
    // made here beside the moved one, it costs no extra time.
    let (nominal, ahead) = rayon::join(|| replay_pressures(data, model), moved);
    let ((a0, b0), (a1, b1)) = (nominal?, ahead?);
    let code = sample_resolution(ChannelId::Pressure, model);
    Some(
        (0..data.len())
            .map(|i| {
                let change = |hi: &[f64], lo: &[f64]| match (hi.get(i), lo.get(i)) {
                    (Some(h), Some(l)) => (h - l).abs(),
                    _ => 0.0,
                };
                f64::from(u8::from(change(&a1, &a0).max(change(&b1, &b0)) <= code))
            })
            .collect(),
    )
}

/// [`replay_pressures`] computed, with the ports timed by `angle_rad` (one per row: the
/// ports' angle before the spline's play, as [`Measured::ports_angle_rad`]).
fn replay_pressures_anew(
    data: &Measured,
    model: &MachineModel,
    angle_rad: &[f64],
) -> Option<(Vec<f64>, Vec<f64>)> {
    let mode = match data.ports {
        PortsMeta::Closed => PortMode::Closed,
        PortsMeta::Open => PortMode::Timed,
        PortsMeta::Unknown => return None,
    };
    let sensor = &model.sensors.pressure;
    let x0 = data.x_m.first().copied().unwrap_or(0.0);
    let rest = data
        .x_m
        .iter()
        .take((0.02 / data.dt_s).ceil() as usize)
        .take_while(|x| (*x - x0).abs() < 20e-6)
        .count()
        .max(1);
    let mean = |p: &[f64]| p.iter().take(rest).sum::<f64>() / rest as f64;
    let true_at_rest = |p: &[f64], t: Transducer| (mean(p) - t.offset_pa) / t.gain;
    let start = (
        true_at_rest(&data.p_a_pa, sensor.chamber_a()),
        true_at_rest(&data.p_b_pa, sensor.chamber_b()),
    );
    let (pa, pb) = replay_from(data, model, mode, start, angle_rad);
    if mode != PortMode::Closed || data.ports_from_s.is_some() {
        return Some((pa, pb));
    }
    let scale = |measured: &[f64], replayed: &[f64], offset: f64| -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        for (m, r) in measured.iter().zip(replayed) {
            num += (m - offset) * (r - offset);
            den += (r - offset) * (r - offset);
        }
        if den > 0.0 && num > 0.0 {
            num / den
        } else {
            1.0
        }
    };
    let sa = scale(&data.p_a_pa, &pa, sensor.offset_a_pa);
    let sb = scale(&data.p_b_pa, &pb, sensor.offset_b_pa);
    Some(replay_from(
        data,
        model,
        mode,
        (start.0 * sa, start.1 * sb),
        angle_rad,
    ))
}

/// The chambers replayed from the starting pressures `start` (A, B), Pa, at the wall
/// temperature, as [`replay_pressures`] describes.
fn replay_from(
    data: &Measured,
    model: &MachineModel,
    mode: PortMode,
    start: (f64, f64),
    angle_rad: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let n = data.len();
    let params = PlantParams::from_model(model).chambers;
    let gas = params.gas;
    let t_gas = model.gas.temperature_k;
    let sensor = &model.sensors.pressure;
    let off = data.x_offset_m;
    let x0 = data.x_m.first().copied().unwrap_or(0.0) - off;
    let (p0a, p0b) = start;
    let mut ch = Chambers::new(params, x0, p0a.max(1.0), t_gas);
    ch.b.pressure_pa = p0b.max(1.0);
    ch.b.mass_kg = ch.b.pressure_pa * ch.b.volume_m3 / (gas.gas_constant_j_per_kg_k * t_gas);
    let mut lines = Lines::new(
        model.lines.suction_pa,
        t_gas,
        model.lines.pressure_ratio,
        gas.gamma,
    );
    let (mut la, mut lb) = (ch.a.pressure_pa, ch.b.pressure_pa);
    let mut pa = Vec::with_capacity(n);
    let mut pb = Vec::with_capacity(n);
    // The plant steps its chambers every control period; a slower log is replayed in as
    // many sub-steps, along x and θ interpolated linearly (the chambers' port flow is stiff
    // and its step is made for 25–50 µs).
    // The count is capped, so that the replay's cost follows the log's rows and never its
    // duration (a log of huge sample times would otherwise be billions of sub-steps).
    let substeps = (data.dt_s / REPLAY_STEP_S - 1e-9)
        .ceil()
        .clamp(1.0, MAX_REPLAY_SUBSTEPS as f64) as usize;
    let h = data.dt_s / substeps as f64;
    let lag = data.ports_delay_s / data.dt_s;
    // The sensors' lag is stepped with the chambers, as the plant steps it every control
    // period: stepped once per sample of a slower log it would lag by τ − dt/2 instead of
    // τ − h/2 (25 µs less on a 10 kHz log, named as leakage at speed).
    let sensor_lag = sensor.lag(h);
    // The angle that times the ports ([`Measured::ports_angle_rad`]: for a servo count, the
    // angle estimated within its counts), and the piston carried within the spline's play
    // (a play operator, as the plant's spline; the piston starts centred).
    let half_play = match data.theta_source {
        ThetaSource::Piston => 0.0,
        ThetaSource::ServoEncoder => 0.5 * model.servo.backlash_rad,
    };
    let mut piston = angle_rad.first().copied().unwrap_or(0.0);
    for i in 0..n {
        if i > 0 {
            // Set the lines only when the logged pressures change (each set costs a powf).
            if let Some(ps) = data.p_suction_pa.as_ref().and_then(|p| p.get(i)) {
                if *ps > 0.0 && *ps != lines.suction_pa {
                    lines.set_suction_pa(*ps);
                }
            }
            if let Some(pd) = data.p_discharge_pa.as_ref().and_then(|p| p.get(i)) {
                if *pd > 0.0 && *pd != lines.discharge_pa {
                    lines.set_discharge_pa(*pd);
                }
            }
            let at = |v: &[f64], k: usize| v.get(k).copied().unwrap_or(0.0);
            let (x1, x2) = (at(&data.x_m, i - 1) - off, at(&data.x_m, i) - off);
            // The ports' phase: the logged angle `ports_delay_s` earlier (interpolated).
            let theta = |k: usize| -> f64 {
                let pos = (k as f64 - lag).max(0.0);
                let j = pos.floor() as usize;
                let f = pos - j as f64;
                let a = at(angle_rad, j);
                a + f * (angle_rad.get(j + 1).copied().unwrap_or(a) - a)
            };
            let (t1, t2) = (theta(i - 1), theta(i));
            let mode = match data.ports_from_s {
                Some(from) if at(&data.t_s, i) <= from => PortMode::Unloaded,
                _ => mode,
            };
            for k in 1..=substeps {
                let f = k as f64 / substeps as f64;
                let x = x1 + f * (x2 - x1);
                let angle = t1 + f * (t2 - t1);
                piston = through_play(piston, angle, half_play);
                let phase = wrap_rad(piston);
                ch.step(x, phase, &lines, mode, h);
                sensor_lag.step(&mut la, ch.a.pressure_pa);
                sensor_lag.step(&mut lb, ch.b.pressure_pa);
            }
        }
        pa.push(sensor.reading_pa(la, sensor.chamber_a()));
        pb.push(sensor.reading_pa(lb, sensor.chamber_b()));
    }
    (pa, pb)
}
