//! The measured run as the workflow sees it: the columns it needs, the firmware's velocity
//! and acceleration (centred Savitzky–Golay), the rotation speed, and the masks that say
//! which samples each channel may be judged on.

pub use crate::logmeta::ThetaSource;
use crate::logmeta::{LogMeta, PortsDeclared};
use crate::runlog::RunLog;
use crate::signal::{firmware_derivatives, SgSettings};

use super::band::{sg_weights, Kernel};

/// Length of the differentiator window, s (the firmware's 21 samples at 20 kHz is 1 ms; the
/// offline analysis may look both ways and uses 2 ms, capped at the firmware's 41 samples).
pub const SG_SPAN_S: f64 = 2e-3;

/// Shortest and longest rotation-speed window, s.
pub const ROTATION_SPAN_S: (f64, f64) = (4e-3, 50e-3);

/// Angle counts the rotation-speed window should span at the run's typical speed.
pub const ROTATION_COUNTS: f64 = 16.0;

/// Span of the local quadratic that estimates a counted rotation angle between and within
/// its counts for the ports' timing ([`ports_angle`]), s.
///
/// Measured against the simulator's own piston angle (reference machine, 2.3 m/s, seeds 16
/// and 17, RMS over the running part; the play operator applied to both): from a 2 kHz log
/// 0.232 counts for the staircase interpolated, 0.161 through the crossings, and through
/// the crossings then fitted over 4.5 / 8 / 16 ms 0.137 / 0.113 / 0.100 counts; from a
/// 20 kHz log 0.285, 0.155 and 0.058 / 0.053 / 0.052. The chambers' replay follows: a
/// 2 kHz log's pressure residual, 316 Pa with the staircase (274 Pa is its sensor noise
/// in the band), falls to 280 Pa at 8 ms. 8 ms keeps the fit's curvature error small at
/// the fastest strokes (a cycle of 0.2 s at 4.1 m/s).
pub const PORTS_ANGLE_SPAN_S: f64 = 8e-3;

/// Below this speed for longer than [`STOP_MIN_S`] the piston is taken as stopped: friction
/// is then undetermined (stiction holds anything up to F_s) and a head may be touching.
pub const STOP_SPEED_MPS: f64 = 2e-3;

/// Shortest standstill excluded from the force balance, s (a reversal passes zero speed in
/// tens of µs and stays in).
pub const STOP_MIN_S: f64 = 5e-3;

/// Widest alignment between the logged forces and the logged position a logging
/// convention can explain, in sample periods either way: one period late (a firmware
/// reporting last cycle's current), on time, half a period (a command held over the period
/// acts, on average, half a period after its row).
pub const ALIGN_WINDOW_SAMPLES: f64 = 1.5;

/// The alignment taken for a log that does not declare `# force_delay_s`, in sample
/// periods: the forces act half a period after their row — the common case of a sampled
/// controller logging the command it holds over the next period. It is only the reference
/// an actuator lag is reported from; the alignment itself is estimated ([`Measured`]).
pub const UNDECLARED_ALIGN_SAMPLES: f64 = 0.5;

/// Longest `# force_delay_s` accepted, s (a logging convention is samples, not strokes).
pub use crate::logmeta::MAX_FORCE_DELAY_S;

/// Slowest sample rate the workflow analyses, Hz: its differentiator spans 2 ms and needs
/// at least 5 samples there; a coarser log cannot resolve a stroke's acceleration.
pub const MIN_SAMPLE_RATE_HZ: f64 = 2_000.0;

/// Fastest sample rate accepted, Hz: far above any drive's logger (the time column of a
/// faster log is more likely in the wrong unit).
pub const MAX_SAMPLE_RATE_HZ: f64 = 1.0e6;

/// How far outside the heads a logged position may lie, m (encoder noise, homing offset):
/// beyond it the row is not a position of this machine.
pub const POSITION_MARGIN_M: f64 = 0.01;

/// How far a step of the time column may differ from the log's sample time, as a share.
pub const MAX_STEP_JITTER: f64 = 0.1;

/// How far the rate read from a log's time stamps may lie outside
/// [`MIN_SAMPLE_RATE_HZ`]..=[`MAX_SAMPLE_RATE_HZ`] and still be taken as inside, as a share:
/// the rate is (last − first stamp) / rows, and stamps rounded to their printed digits (or
/// summed in floating point) put a log sampled at exactly 2 kHz a hair under 2000 Hz. A
/// rounding error is far below 0.1 %; a logger set to another rate is percents away.
pub const RATE_TOLERANCE: f64 = 1e-3;

/// Largest derived value (velocity, acceleration, rate) the fits accept: their squares
/// summed over any log stay finite.
pub const MAX_DERIVED: f64 = 1e100;

/// The optional columns the workflow reads besides the log's required ones (the line
/// pressures, when logged).
pub const LINE_COLUMNS: [&str; 2] = ["p_suction_pa", "p_discharge_pa"];

/// Refuses a value outside the column's physical range (`runlog::physical_range`; NaN and
/// infinities included), naming the column and the data row (counted from 1).
pub fn check_range(name: &str, column: &[f64]) -> Result<(), String> {
    let (lo, hi) = crate::runlog::physical_range(name);
    match column.iter().position(|v| !(lo..=hi).contains(v)) {
        None => Ok(()),
        Some(i) => Err(format!(
            "column `{name}`, data row {}: {} is outside the physical range {lo:e}..={hi:e}",
            i + 1,
            column.get(i).copied().unwrap_or(f64::NAN)
        )),
    }
}

/// How the chambers were connected while the log was taken (`# ports = …`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PortsMeta {
    /// `closed`: both chambers sealed — the pressure channel is replayed.
    Closed,
    /// `open`: ports timed by the logged rotation — the pressure channel is replayed with
    /// the lines' pressures.
    Open,
    /// No `ports` metadata: no pressure channel.
    Unknown,
}

/// The measured run, with what the workflow derives from it.
#[derive(Clone, Debug)]
pub struct Measured {
    /// Sample time, s.
    pub dt_s: f64,
    /// Time, s.
    pub t_s: Vec<f64>,
    /// Master-encoder position, m.
    pub x_m: Vec<f64>,
    /// Slave-encoder position, m.
    pub x_slave_m: Vec<f64>,
    /// Rotation angle, rad.
    pub theta_rad: Vec<f64>,
    /// The rotation angle that times the ports, rad: the logged angle where it is the
    /// piston's, and for a servo count the angle estimated within its counts
    /// ([`ports_angle`]).
    pub ports_angle_rad: Vec<f64>,
    /// Master-section force, N.
    pub f_master_n: Vec<f64>,
    /// Slave-section force, N.
    pub f_slave_n: Vec<f64>,
    /// Chamber A pressure, Pa.
    pub p_a_pa: Vec<f64>,
    /// Chamber B pressure, Pa.
    pub p_b_pa: Vec<f64>,
    /// Suction-line pressure, Pa, if logged.
    pub p_suction_pa: Option<Vec<f64>>,
    /// Discharge-line pressure, Pa, if logged.
    pub p_discharge_pa: Option<Vec<f64>>,
    /// Port state of the run.
    pub ports: PortsMeta,
    /// `# ports_from_s`: the time from which `ports` holds, s; before it both chambers
    /// breathe to the suction line through their intakes (the start-up unloader of our own
    /// runs, `PortMode::Unloaded`). Absent: `ports` holds for the whole log.
    pub ports_from_s: Option<f64>,
    /// `# theta_source`: what `theta_rad` measures.
    pub theta_source: ThetaSource,
    /// `# force_delay_s`, if the log declares how far its forces lag its position, s.
    pub force_delay_s: Option<f64>,
    /// `# ports_delay_s`: how far the ports' rotation phase lags the logged `theta_rad`, s
    /// (0 when not declared), for a logger that stamps its angle late.
    pub ports_delay_s: f64,
    /// How far the forces act behind the row they are logged in, by the log's convention
    /// (a nuisance, not physics), s: `−force_delay_s` when declared, else estimated by the
    /// workflow within ±[`ALIGN_WINDOW_SAMPLES`] (starting at
    /// [`UNDECLARED_ALIGN_SAMPLES`]). The force balance realigns the forces by it.
    pub force_align_s: f64,
    /// Differentiator window, samples.
    pub sg_window: usize,
    /// Velocity from the firmware's differentiator, centred, m/s.
    pub v_mps: Vec<f64>,
    /// Acceleration from the firmware's differentiator, centred, m/s².
    pub a_mps2: Vec<f64>,
    /// Raw centred second difference of x, m/s² (what the force kernel smooths).
    pub d2x_mps2: Vec<f64>,
    /// Rotation speed (SG over a window fitted to the angle's resolution), rad/s.
    pub omega_rad_s: Vec<f64>,
    /// Rate of the chamber-A reading (SG, the differentiator's window), Pa/s.
    pub dp_a_pa_per_s: Vec<f64>,
    /// Rate of the chamber-B reading, Pa/s.
    pub dp_b_pa_per_s: Vec<f64>,
    /// 1 where the force balance may be judged (moving, away from the log's ends), else 0.
    pub moving: Vec<f64>,
    /// 1 away from the log's ends, else 0.
    pub inner: Vec<f64>,
    /// 1 where the pressure channel may be judged (also `inner`), 0 where the chambers'
    /// replay hinges on a port angle the log does not resolve
    /// ([`super::replay::ports_resolved`]); all 1 until the workflow sets it.
    pub pressure_judged: Vec<f64>,
    /// How far the logged position reads beyond the chambers' own, m: what the pressure
    /// replay subtracts from `x_m` ([`super::offset::fit_position_offset`], fitted once
    /// per log before the selection; 0 until the workflow sets it).
    pub x_offset_m: f64,
    /// Stretches of motion between standstills (runs of `moving`): an encoder may be zeroed
    /// again at a standstill (homing), so each stretch has its own encoder offset.
    pub segments: Vec<std::ops::Range<usize>>,
    /// The chambers' replays of this log, by the model values they read
    /// ([`super::replay::replay_pressures`]): the columns above are never changed after
    /// they are made (only the force alignment is, which no replay reads), and a clone starts
    /// with none.
    pub replays: super::band::ColumnCache<String>,
}

impl Measured {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// Sample rate, Hz.
    pub fn sample_rate_hz(&self) -> f64 {
        1.0 / self.dt_s
    }

    /// Reads what the workflow needs from a validated log; `encoder_period_m` scales the
    /// firmware differentiator's counts. The error names the metadata key or column.
    pub fn from_log(log: &RunLog, encoder_period_m: f64) -> Result<Self, String> {
        Self::from_log_down_to(log, encoder_period_m, MIN_SAMPLE_RATE_HZ)
    }

    /// [`Measured::from_log`] for a log sampled at `min_rate_hz` or faster (the plots of
    /// `fpc-sim forces` and `energy` read slower logs than the workflow fits).
    pub fn from_log_down_to(
        log: &RunLog,
        encoder_period_m: f64,
        min_rate_hz: f64,
    ) -> Result<Self, String> {
        let col = |name: &str| -> Result<Vec<f64>, String> {
            log.column(name)
                .map(<[f64]>::to_vec)
                .ok_or_else(|| format!("column `{name}`: required column is missing"))
        };
        // Every value the workflow reads must be one a machine can log (the reader's
        // physical ranges): a NaN, an infinity or a finite 1e300 would otherwise travel
        // through the derivatives into the fits' normal equations.
        for name in crate::runlog::REQUIRED.iter().chain(&LINE_COLUMNS) {
            if let Some(c) = log.column(name) {
                check_range(name, c)?;
            }
        }
        let t_s = col("t_s")?;
        let n = t_s.len();
        let dt_s = uniform_sample_time(&t_s, min_rate_hz)?;
        let meta = LogMeta::read(log)?;
        let ports = match meta.ports {
            Some(PortsDeclared::Closed) => PortsMeta::Closed,
            Some(PortsDeclared::Open) => PortsMeta::Open,
            None => PortsMeta::Unknown,
        };
        let force_delay_s = meta.force_delay_s;
        let ports_delay_s = meta.ports_delay_s.unwrap_or(0.0);
        let theta_source = meta.theta_source.unwrap_or(ThetaSource::Piston);
        let ports_from_s = meta.ports_from_s;
        let force_align_s = force_delay_s.map_or(UNDECLARED_ALIGN_SAMPLES * dt_s, |d| -d);
        let x_m = col("x_m")?;
        let theta_rad = col("theta_rad")?;
        let fs = 1.0 / dt_s;
        let sg_window = ((SG_SPAN_S * fs).round() as usize | 1)
            .clamp(5, fpc::sensing::differentiator::MAX_WINDOW);
        if n < 4 * sg_window {
            return Err(format!(
                "{n} rows: at least {} needed for a {sg_window}-sample differentiator",
                4 * sg_window
            ));
        }
        let settings = SgSettings {
            window: sg_window,
            order: 2,
            lag: sg_window / 2,
        };
        let w_p = Kernel::new(sg_weights(sg_window, 2, 1, dt_s).ok_or("pressure-rate weights")?);
        let p_a_pa = col("p_a_pa")?;
        let p_b_pa = col("p_b_pa")?;
        // The derived columns are independent: made on every core, errors named in order.
        let ((motion, rotated), ((dp_a_pa_per_s, dp_b_pa_per_s), d2x_mps2)) = rayon::join(
            || {
                rayon::join(
                    || firmware_derivatives(&x_m, dt_s, encoder_period_m, settings),
                    || rotation(&theta_rad, dt_s, n, theta_source),
                )
            },
            || {
                rayon::join(
                    || rayon::join(|| w_p.apply(&p_a_pa), || w_p.apply(&p_b_pa)),
                    || second_difference(&x_m, dt_s, n),
                )
            },
        );
        let (v_mps, a_mps2) = motion?;
        let (omega_rad_s, ports_angle_rad) = rotated?;
        let edge = 2 * sg_window;
        let inner: Vec<f64> = (0..n)
            .map(|i| f64::from(u8::from(i >= edge && i + edge < n)))
            .collect();
        // What the fits see: the derivatives of values in range are finite, and this says
        // which row made one that is not (a last guard before any solver).
        check_derived(&[
            ("velocity of `x_m`", &v_mps),
            ("acceleration of `x_m`", &a_mps2),
            ("second difference of `x_m`", &d2x_mps2),
            ("rate of `theta_rad`", &omega_rad_s),
            ("rate of `p_a_pa`", &dp_a_pa_per_s),
            ("rate of `p_b_pa`", &dp_b_pa_per_s),
        ])?;
        let moving = moving_mask(&v_mps, &inner, dt_s, sg_window);
        let segments = runs(&moving);
        Ok(Measured {
            dt_s,
            t_s,
            x_slave_m: col("x_slave_m")?,
            f_master_n: col("f_master_n")?,
            f_slave_n: col("f_slave_n")?,
            p_a_pa,
            p_b_pa,
            dp_a_pa_per_s,
            dp_b_pa_per_s,
            p_suction_pa: log.column("p_suction_pa").map(<[f64]>::to_vec),
            p_discharge_pa: log.column("p_discharge_pa").map(<[f64]>::to_vec),
            x_m,
            theta_rad,
            ports_angle_rad,
            ports,
            ports_from_s,
            theta_source,
            force_delay_s,
            ports_delay_s,
            force_align_s,
            sg_window,
            v_mps,
            a_mps2,
            d2x_mps2,
            omega_rad_s,
            moving,
            pressure_judged: vec![1.0; inner.len()],
            x_offset_m: 0.0,
            inner,
            segments,
            replays: Default::default(),
        })
    }

    /// Refuses a log that is not of the machine `model` describes, naming the first row
    /// (counted from 1 over the data rows) that is not: a position outside the heads by more
    /// than [`POSITION_MARGIN_M`], a force beyond ten times the sections' peak, a pressure
    /// outside 0–100 MPa. Such values are not noise: left in, they poison every fit.
    pub fn check_against(&self, model: &crate::plant::model::MachineModel) -> Result<(), String> {
        let travel = model.piston.travel_m;
        let (lo, hi) = (-POSITION_MARGIN_M, travel + POSITION_MARGIN_M);
        let force_max = 10.0 * model.limits.force_limit_n.abs().max(1.0);
        let checks: [(&str, &[f64], f64, f64); 6] = [
            ("x_m", &self.x_m, lo, hi),
            ("x_slave_m", &self.x_slave_m, lo, hi),
            ("f_master_n", &self.f_master_n, -force_max, force_max),
            ("f_slave_n", &self.f_slave_n, -force_max, force_max),
            ("p_a_pa", &self.p_a_pa, 0.0, 1e8),
            ("p_b_pa", &self.p_b_pa, 0.0, 1e8),
        ];
        for (name, column, lo, hi) in checks {
            if let Some((row, v)) = column
                .iter()
                .enumerate()
                .find(|(_, v)| !(lo..=hi).contains(*v))
            {
                return Err(format!(
                    "column `{name}`, data row {}: {v:e} is outside {lo:e}…{hi:e} for this \
                     machine",
                    row + 1
                ));
            }
        }
        Ok(())
    }

    /// The first `n` samples (for the pressure candidates' parameter searches, which replay
    /// the chambers tens of times: a few seconds of a long log pin the parameter as well).
    /// The end of the copy is an end: its last samples leave the masks like the log's.
    pub fn head(&self, n: usize) -> Measured {
        self.window(0, n)
    }

    /// `n` samples from sample `start` on, as [`Measured::head`] (times kept, so
    /// `ports_from_s` still says when the ports' state begins); both ends of the copy are
    /// ends, leaving the masks like the log's.
    pub fn window(&self, start: usize, n: usize) -> Measured {
        let start = start.min(self.len());
        let n = n.min(self.len() - start);
        let cut = |v: &Vec<f64>| v.get(start..start + n).unwrap_or(v).to_vec();
        let edge = 2 * self.sg_window;
        let mut inner = cut(&self.inner);
        let mut moving = cut(&self.moving);
        for v in [&mut inner, &mut moving] {
            if let Some(tail) = v.get_mut(n.saturating_sub(edge)..) {
                tail.fill(0.0);
            }
            if start > 0 {
                if let Some(head) = v.get_mut(..edge.min(n)) {
                    head.fill(0.0);
                }
            }
        }
        let segments = runs(&moving);
        Measured {
            dt_s: self.dt_s,
            t_s: cut(&self.t_s),
            x_m: cut(&self.x_m),
            x_slave_m: cut(&self.x_slave_m),
            theta_rad: cut(&self.theta_rad),
            ports_angle_rad: cut(&self.ports_angle_rad),
            f_master_n: cut(&self.f_master_n),
            f_slave_n: cut(&self.f_slave_n),
            p_a_pa: cut(&self.p_a_pa),
            p_b_pa: cut(&self.p_b_pa),
            p_suction_pa: self.p_suction_pa.as_ref().map(cut),
            p_discharge_pa: self.p_discharge_pa.as_ref().map(cut),
            ports: self.ports,
            ports_from_s: self.ports_from_s,
            theta_source: self.theta_source,
            force_delay_s: self.force_delay_s,
            ports_delay_s: self.ports_delay_s,
            force_align_s: self.force_align_s,
            sg_window: self.sg_window,
            v_mps: cut(&self.v_mps),
            a_mps2: cut(&self.a_mps2),
            d2x_mps2: cut(&self.d2x_mps2),
            omega_rad_s: cut(&self.omega_rad_s),
            dp_a_pa_per_s: cut(&self.dp_a_pa_per_s),
            dp_b_pa_per_s: cut(&self.dp_b_pa_per_s),
            moving,
            inner,
            pressure_judged: cut(&self.pressure_judged),
            x_offset_m: self.x_offset_m,
            segments,
            replays: Default::default(),
        }
    }

    /// `raw` with its mean over each motion stretch removed inside that stretch (samples
    /// outside every stretch are left as they are: no channel judges them).
    pub fn demean_segments(&self, raw: &[f64]) -> Vec<f64> {
        let mut out = raw.to_vec();
        for seg in &self.segments {
            if let Some(s) = out.get_mut(seg.clone()) {
                let mean = s.iter().sum::<f64>() / s.len().max(1) as f64;
                s.iter_mut().for_each(|v| *v -= mean);
            }
        }
        out
    }
}

/// The log's sample time, s, from the ends of `t_s`: every step must be it within
/// [`MAX_STEP_JITTER`] (the workflow needs a uniform rate), and its rate between
/// `min_rate_hz` and [`MAX_SAMPLE_RATE_HZ`] (each within [`RATE_TOLERANCE`]).
fn uniform_sample_time(t_s: &[f64], min_rate_hz: f64) -> Result<f64, String> {
    let n = t_s.len();
    let dt_s = match (t_s.first(), t_s.last()) {
        (Some(a), Some(b)) if n > 1 && b > a => (b - a) / (n - 1) as f64,
        _ => return Err("column `t_s`: no usable time step".into()),
    };
    // The step is taken from the ends: each step must be it (a log of uniform rate).
    if let Some(i) = t_s.windows(2).position(|w| {
        let step = w.get(1).copied().unwrap_or(0.0) - w.first().copied().unwrap_or(0.0);
        !((1.0 - MAX_STEP_JITTER) * dt_s..=(1.0 + MAX_STEP_JITTER) * dt_s).contains(&step)
    }) {
        return Err(format!(
            "column `t_s`, data row {}: the step from the previous row is not the log's \
             sample time {dt_s:e} s within {:.0} % (the workflow needs a uniform rate)",
            i + 2,
            100.0 * MAX_STEP_JITTER
        ));
    }
    let rate = 1.0 / dt_s;
    let accepted =
        min_rate_hz * (1.0 - RATE_TOLERANCE)..=MAX_SAMPLE_RATE_HZ * (1.0 + RATE_TOLERANCE);
    if !accepted.contains(&rate) {
        return Err(format!(
            "column `t_s`: sample rate {rate:.6e} Hz; the workflow analyses logs sampled at \
             {min_rate_hz} Hz to {MAX_SAMPLE_RATE_HZ:e} Hz"
        ));
    }
    Ok(dt_s)
}

/// The rotation's speed, rad/s, and the angle that times the ports, rad (the logged angle,
/// or the one drawn through the servo encoder's crossings: [`ports_angle`]), from the logged
/// angle `theta_rad` of `n` rows at the sample time `dt_s`, s.
///
/// The rotation's angle is coarse (4096 counts per turn: at 1.5 rad/s one count per
/// millisecond) and its motion slow (servo bandwidth ≈ 30 Hz), so its speed is a
/// Savitzky–Golay slope (f64: hundreds of radians exceed the firmware
/// differentiator's counts) over a window that spans about [`ROTATION_COUNTS`]
/// counts at the run's typical speed, within [`ROTATION_SPAN_S`], of the angle
/// drawn through the count's crossings ([`angle_through_crossings`]).
fn rotation(
    theta_rad: &[f64],
    dt_s: f64,
    n: usize,
    theta_source: ThetaSource,
) -> Result<(Vec<f64>, Vec<f64>), String> {
    let rot_window = rotation_window(theta_rad, dt_s, n);
    let w1 = sg_weights(rot_window, 2, 1, dt_s).ok_or("rotation-speed weights")?;
    let through = angle_through_crossings(theta_rad);
    let omega_rad_s = Kernel::new(w1).apply(&through);
    let ports_angle_rad = match theta_source {
        ThetaSource::Piston => theta_rad.to_vec(),
        ThetaSource::ServoEncoder => ports_angle(&through, dt_s),
    };
    Ok((omega_rad_s, ports_angle_rad))
}

/// The raw second difference of `x_m` over its `n` rows at the sample time `dt_s`, m/s²
/// (0 at the ends): the force channel's acceleration before its kernel.
fn second_difference(x_m: &[f64], dt_s: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| {
            match (
                i.checked_sub(1).and_then(|k| x_m.get(k)),
                x_m.get(i),
                x_m.get(i + 1),
            ) {
                (Some(a), Some(b), Some(c)) => (a - 2.0 * b + c) / (dt_s * dt_s),
                _ => 0.0,
            }
        })
        .collect()
}

/// Refuses a derived column (`derived`: its name, its values) with a value beyond
/// ±[`MAX_DERIVED`], naming the first data row (counted from 1) that has one.
fn check_derived(derived: &[(&str, &[f64])]) -> Result<(), String> {
    for (name, v) in derived {
        if let Some(i) = v
            .iter()
            .position(|x| !(-MAX_DERIVED..=MAX_DERIVED).contains(x))
        {
            return Err(format!(
                "data row {}: the {name} there is {}, beyond what the fits can use \
                 (±{MAX_DERIVED:e})",
                i + 1,
                v.get(i).copied().unwrap_or(f64::NAN)
            ));
        }
    }
    Ok(())
}

/// The rotation-speed window, samples (odd): the angle's step (its smallest nonzero change
/// between samples) times [`ROTATION_COUNTS`] over its median speed while turning, clamped to
/// [`ROTATION_SPAN_S`] and to a quarter of the log.
fn rotation_window(theta_rad: &[f64], dt_s: f64, n: usize) -> usize {
    let steps: Vec<f64> = theta_rad
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 1e-12)
        .collect();
    let quantum = steps.iter().copied().fold(f64::INFINITY, f64::min);
    // Median speed over 10 ms spans, counting only spans that turn.
    let span = ((0.01 / dt_s).round() as usize).max(1);
    let mut speeds: Vec<f64> = theta_rad
        .chunks(span)
        .filter_map(|c| Some((c.last()? - c.first()?).abs() / (dt_s * c.len() as f64)))
        .filter(|w| *w > 0.0)
        .collect();
    speeds.sort_by(f64::total_cmp);
    let median = speeds.get(speeds.len() / 2).copied().unwrap_or(0.0);
    let (lo, hi) = ROTATION_SPAN_S;
    let t = if quantum.is_finite() && median > 0.0 {
        (ROTATION_COUNTS * quantum / median).clamp(lo, hi)
    } else {
        lo
    };
    ((t / dt_s).round() as usize | 1).clamp(5, (n / 4) | 1)
}

/// The angle a coarse counter logs (`theta_rad`: whole counts), drawn through the instants
/// the count changes: the speed of a counter is in the times of its steps, not in its
/// staircase.
///
/// A step between rows `k−1` and `k` says the angle crossed a count's edge about half a
/// sample before row `k`; there the angle is taken as the middle of the two readings plus
/// half a count (a reading is the lower edge of its count: `n·q` stands for `[n·q,
/// (n+1)·q)`, so a step from `n` to `n+1`, either way, crosses `(n+1)·q`, and a step of
/// several counts in one sample lands at its middle). Between crossings the angle is
/// interpolated linearly, so between two steps the speed is their mean speed; before the
/// first and after the last it is held. An angle that changes at every row (a fine or
/// continuous one) is only smoothed a little (`(θ₋ + 2θ + θ₊)/4`, plus the constant), and
/// one that never changes stays as it is.
///
/// Why: the slope of the staircase itself over a window reads *zero* wherever no step falls
/// in the window, and a whole count over the window where one does. At the dead points of
/// our runs the piston still turns at 0.01–0.6 rad/s (one count of the servo's 4096 every
/// 10–100 ms) and the 4 ms window read exactly 0 rad/s for 6 ms at each of them, the
/// tangential sliding speed `ω·r` 0 instead of 0.6–7 mm/s, inside the Stribeck band of the
/// friction law: the force balance then missed the friction of every reversal by the law's
/// shape, and `stribeck_friction` explained 18–22 % of the residual where it acts on the
/// simulator's own runs (the modelled machine, where nothing is missing). Through the
/// crossings it explains 2–3 % there, and the fitted law moves to the true one.
pub fn angle_through_crossings(theta_rad: &[f64]) -> Vec<f64> {
    let crossings = count_crossings(theta_rad).unwrap_or_default();
    let (Some(&first), Some(&last)) = (crossings.first(), crossings.last()) else {
        return theta_rad.to_vec();
    };
    around_crossings(&crossings, theta_rad.len())
        .map(|(t, before, after)| match (before, after) {
            (Some(&(t0, a0)), Some(&(t1, a1))) => a0 + (a1 - a0) * (t - t0) / (t1 - t0),
            (None, _) => first.1,
            (_, None) => last.1,
        })
        .collect()
}

/// A counted angle's crossing: (row, angle).
type Crossing = (f64, f64);

/// Each of `rows` rows with the crossings just before and after it, in order.
fn around_crossings(
    crossings: &[Crossing],
    rows: usize,
) -> impl Iterator<Item = (f64, Option<&Crossing>, Option<&Crossing>)> {
    let mut next = 0;
    (0..rows).map(move |i| {
        let t = i as f64;
        while crossings.get(next).is_some_and(|c| c.0 <= t) {
            next += 1;
        }
        (
            t,
            next.checked_sub(1).and_then(|k| crossings.get(k)),
            crossings.get(next),
        )
    })
}

/// The crossings of a counted angle's edges, as [`angle_through_crossings`] places them:
/// (row, angle), the row half a sample before the one that shows the step; `None` if the
/// angle never steps.
fn count_crossings(theta_rad: &[f64]) -> Option<Vec<(f64, f64)>> {
    let quantum = count_quantum(theta_rad);
    let crossings: Vec<(f64, f64)> = theta_rad
        .windows(2)
        .enumerate()
        .filter(|(_, w)| (w[1] - w[0]).abs() >= 0.5 * quantum)
        .map(|(k, w)| (k as f64 + 0.5, 0.5 * (w[0] + w[1]) + 0.5 * quantum))
        .collect();
    (!crossings.is_empty()).then_some(crossings)
}

/// A counted angle's quantum, rad; infinite if it never steps.
///
/// The smallest step, but not a rounding flicker. A logged count is a float, and a few of
/// its rows differ from their neighbours by an ulp of the angle (4 of 40,303 steps of a
/// 10-cycle run, 0.0025 counts): taken as the quantum, they put every crossing half a count
/// low. Steps below a tenth of the lower quartile's (a whole count or a few: flickers are
/// rare) are such.
pub fn count_quantum(theta_rad: &[f64]) -> f64 {
    let mut steps: Vec<f64> = theta_rad
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 0.0)
        .collect();
    steps.sort_by(f64::total_cmp);
    let floor = 0.1 * steps.get(steps.len() / 4).copied().unwrap_or(0.0);
    steps
        .iter()
        .copied()
        .find(|d| *d >= floor)
        .unwrap_or(f64::INFINITY)
}

/// How long each row's count lasts: the rows between the crossings before and after it
/// ([`count_crossings`]); infinite before the first crossing and after the last.
pub fn count_spans_rows(theta_rad: &[f64]) -> Vec<f64> {
    let crossings = count_crossings(theta_rad).unwrap_or_default();
    around_crossings(&crossings, theta_rad.len())
        .map(|(_, before, after)| match (before, after) {
            (Some(&(t0, _)), Some(&(t1, _))) => t1 - t0,
            _ => f64::INFINITY,
        })
        .collect()
}

/// A counted angle drawn through its count's crossings (`through`, from
/// [`angle_through_crossings`]) as the ports need it: the value of a local quadratic
/// least-squares fit over [`PORTS_ANGLE_SPAN_S`] (a Savitzky–Golay smoothing; within half
/// a window of either end, the crossings' angle itself).
///
/// Why: the ports close over a 6° ramp whose open fraction goes as the square of the
/// angle past its edge, and the slot still passes the chamber's flow a few milliradians
/// before it closes; the re-expansion after each dead point is timed by fractions of a
/// servo count (1.53 mrad). A log sampled about as fast as the count steps (one count per
/// row at 2 kHz after a dead point) places each crossing only within its row, and that
/// error stays of one sign over several rows while the sampling and the steps drift
/// slowly apart: the staircase interpolated linearly between rows was 0.3 counts behind
/// for 2 ms of a discharge port's closing, its chamber replayed 2–3 kPa high at every
/// dead point, which `leakage` then explained (42.7 % of a null run's residual). The
/// rotation is smooth (servo bandwidth ≈ 30 Hz), so a fit over many crossings averages
/// those errors out.
pub fn ports_angle(through: &[f64], dt_s: f64) -> Vec<f64> {
    let window = ((PORTS_ANGLE_SPAN_S / dt_s).round() as usize | 1).max(5);
    let Some(kernel) = sg_weights(window, 2, 0, dt_s).map(Kernel::new) else {
        return through.to_vec();
    };
    let h = kernel.half();
    (0..through.len())
        .map(|i| {
            if i >= h && i + h < through.len() {
                kernel.at(through, i)
            } else {
                through.get(i).copied().unwrap_or(0.0)
            }
        })
        .collect()
}

/// Maximal runs of samples where `mask > 0`.
fn runs(mask: &[f64]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, w) in mask.iter().enumerate() {
        match (start, *w > 0.0) {
            (None, true) => start = Some(i),
            (Some(s), false) => {
                out.push(s..i);
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push(s..mask.len());
    }
    out
}

/// 1 where the piston moves: `inner`, minus every standstill longer than [`STOP_MIN_S`]
/// widened by the differentiator window on both sides (its estimates there mix the stop in).
fn moving_mask(v_mps: &[f64], inner: &[f64], dt_s: f64, window: usize) -> Vec<f64> {
    let n = v_mps.len();
    let mut w = inner.to_vec();
    let min_len = (STOP_MIN_S / dt_s).ceil() as usize;
    let mut i = 0;
    while i < n {
        if v_mps.get(i).is_some_and(|v| v.abs() < STOP_SPEED_MPS) {
            let start = i;
            while v_mps.get(i).is_some_and(|v| v.abs() < STOP_SPEED_MPS) {
                i += 1;
            }
            if i - start >= min_len {
                let lo = start.saturating_sub(window);
                let hi = (i + window).min(n);
                if let Some(s) = w.get_mut(lo..hi) {
                    s.fill(0.0);
                }
            }
        } else {
            i += 1;
        }
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 5 kHz log of a sine stroke with the given metadata.
    fn log(meta: &[(&str, &str)]) -> RunLog {
        let mut log = RunLog::with_columns(&crate::runlog::REQUIRED);
        for (k, v) in meta {
            log.meta.push(((*k).into(), (*v).into()));
        }
        for i in 0..2000 {
            let t = i as f64 * 2e-4;
            let x = 0.1 + 0.05 * (std::f64::consts::TAU * t).sin();
            log.push_row(&[t, x, x, 0.0, 0.0, 0.0, 1e5, 1e5]);
        }
        log
    }

    /// A log of `rows` rows at `rate_hz` whose time stamps are printed to the 10 µs, as
    /// `fpc-sim decode` prints a 2 kHz stream's (`0.00005`, `0.00055`, …: the control
    /// cycle's 50 µs after the first frame, no whole number of periods).
    fn log_at(rate_hz: f64, rows: usize) -> RunLog {
        let mut log = RunLog::with_columns(&crate::runlog::REQUIRED);
        for i in 0..rows {
            let t: f64 = format!("{:.5}", 5e-5 + i as f64 / rate_hz).parse().unwrap();
            let x = 0.1 + 0.05 * (std::f64::consts::TAU * t).sin();
            log.push_row(&[t, x, x, 0.0, 0.0, 0.0, 1e5, 1e5]);
        }
        log
    }

    #[test]
    fn a_log_sampled_at_the_slowest_rate_is_read_and_a_slower_one_is_refused() {
        // The rate read from such stamps lies a hair either side of 2000 Hz depending on
        // the length (4165 rows: the decoded 3-cycle run of docs/rig-to-model.md); every
        // length is accepted.
        let mut under = 0;
        for rows in (2001..2400).step_by(7).chain([4165]) {
            let log = log_at(MIN_SAMPLE_RATE_HZ, rows);
            let t = log.column("t_s").unwrap();
            // As `from_log` reads it.
            let rate = 1.0 / ((t[rows - 1] - t[0]) / (rows - 1) as f64);
            under += usize::from(rate < MIN_SAMPLE_RATE_HZ);
            let m = Measured::from_log(&log, 1e-6);
            assert!(m.is_ok(), "{rows} rows at 2 kHz: {:?}", m.err());
        }
        // The case the tolerance is for does occur among these lengths.
        assert!(under > 0, "no length put the rate under 2000 Hz");
        let err = Measured::from_log(&log_at(1_900.0, 2000), 1e-6).unwrap_err();
        // (1.899991e3 Hz from stamps rounded to 10 µs.)
        assert!(
            err.starts_with("column `t_s`: sample rate 1.89999")
                && err.ends_with(" Hz; the workflow analyses logs sampled at 2000 Hz to 1e6 Hz"),
            "{err}"
        );
    }

    #[test]
    fn a_slow_rotation_s_speed_is_read_from_its_count_s_steps() {
        // 4096 counts per turn, logged at 20 kHz as the count's lower edge; the rotation
        // turns at 0.15 rad/s (a count every 10 ms), from a phase inside a count.
        let (q, dt, w) = (std::f64::consts::TAU / 4096.0, 5e-5, 0.15);
        let theta: Vec<f64> = (0..4000)
            .map(|i| ((0.3 * q + w * i as f64 * dt) / q).floor() * q)
            .collect();
        let through = angle_through_crossings(&theta);
        let kernel = Kernel::new(sg_weights(81, 2, 1, dt).unwrap());
        let (steps, crossings) = (kernel.apply(&theta), kernel.apply(&through));
        // Between the first and the last step: the staircase's slope reads 0 most of the
        // time and whole counts over the window near a step; the crossings read the speed.
        let inner = 400..3400;
        assert!(
            steps[inner.clone()]
                .iter()
                .filter(|v| v.abs() < 1e-6)
                .count()
                > 1000
        );
        for i in inner {
            assert!((crossings[i] - w).abs() < 0.01 * w, "{i}: {}", crossings[i]);
        }
        // Each crossing lies on the edge the count crossed, whichever way it turns.
        let back: Vec<f64> = theta.iter().rev().copied().collect();
        // (the second step: between two crossings, not where the angle is held before the first)
        let step_at = theta
            .windows(2)
            .enumerate()
            .filter(|(_, p)| p[1] != p[0])
            .nth(1)
            .unwrap()
            .0
            + 1;
        let edge = theta[step_at];
        assert!((0.5 * (through[step_at - 1] + through[step_at]) - edge).abs() < 1e-3 * q);
        let back_through = angle_through_crossings(&back);
        let j = theta.len() - step_at;
        assert!((0.5 * (back_through[j - 1] + back_through[j]) - edge).abs() < 1e-3 * q);
        // An angle that never changes is left as it is.
        assert_eq!(angle_through_crossings(&[0.5; 10]), vec![0.5; 10]);
        // A row whose float differs from its neighbours' by an ulp-sized flicker is no
        // count: the crossings stay where they were.
        let still = (1..theta.len() - 1)
            .find(|&i| theta[i - 1] == theta[i] && theta[i] == theta[i + 1])
            .expect("a row between two of the same count");
        let mut flicker = theta.clone();
        flicker[still] += 4e-6;
        for (a, b) in angle_through_crossings(&flicker).iter().zip(&through) {
            assert!((a - b).abs() < 1e-12, "{a} against {b}");
        }
    }

    #[test]
    fn each_row_knows_how_long_its_count_lasts() {
        // Steps shown at rows 10, 30 and 35 (crossings half a row before each).
        let q = std::f64::consts::TAU / 4096.0;
        let theta: Vec<f64> = (0..50)
            .map(|i| q * [10, 30, 35].iter().filter(|&&s| i >= s).count() as f64)
            .collect();
        assert!((count_quantum(&theta) - q).abs() < 1e-15);
        let spans = count_spans_rows(&theta);
        for (i, s) in spans.iter().enumerate() {
            let want = match i {
                0..=9 | 35.. => f64::INFINITY,
                10..=29 => 20.0,
                _ => 5.0,
            };
            assert_eq!(*s, want, "row {i}");
        }
        // A piston angle that never steps: no count, no span.
        assert!(count_spans_rows(&[0.1; 5]).iter().all(|s| s.is_infinite()));
    }

    #[test]
    fn a_count_logged_about_as_fast_as_it_steps_times_the_ports_within_a_fraction_of_a_count() {
        // The servo's 4096 counts logged at 2 kHz as the count's lower edge while the
        // rotation speeds up from 2 to 10 rad/s (0.65 to 3.3 counts a row), as after a dead
        // point.
        let (q, dt) = (std::f64::consts::TAU / 4096.0, 5e-4);
        let truth: Vec<f64> = (0..200)
            .map(|i| {
                let t = i as f64 * dt;
                0.3 * q + 2.0 * t + 40.0 * t * t
            })
            .collect();
        let counts: Vec<f64> = truth.iter().map(|a| (a / q).floor() * q).collect();
        let estimate = ports_angle(&angle_through_crossings(&counts), dt);
        // Judged where the fit's whole window lies inside the log.
        let half = ((PORTS_ANGLE_SPAN_S / dt).round() as usize | 1) / 2;
        let inner = half..truth.len() - half;
        let error = |angle: &dyn Fn(usize) -> f64| -> (f64, f64) {
            let e: Vec<f64> = inner.clone().map(|i| (angle(i) - truth[i]) / q).collect();
            let mean = e.iter().sum::<f64>() / e.len() as f64;
            let rms = (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
            (mean, rms)
        };
        let (mean, rms) = error(&|i| estimate[i]);
        let (_, staircase_rms) = error(&|i| counts[i] + 0.5 * q);
        // (measured: mean −0.04, RMS 0.10 counts; the staircase and its half count 0.29)
        assert!(
            mean.abs() < 0.06 && rms < 0.15 && rms < 0.5 * staircase_rms,
            "mean {mean}, RMS {rms} counts; the staircase's RMS {staircase_rms}"
        );
    }

    #[test]
    fn the_log_s_timing_metadata_is_read_or_refused_by_name() {
        let m = Measured::from_log(&log(&[]), 0.024).unwrap();
        assert_eq!(m.force_delay_s, None);
        assert!((m.force_align_s - UNDECLARED_ALIGN_SAMPLES * 2e-4).abs() < 1e-12);
        let m = Measured::from_log(
            &log(&[
                ("force_delay_s", "5e-5"),
                ("ports_from_s", "0.5"),
                ("ports_delay_s", "5e-5"),
            ]),
            0.024,
        )
        .unwrap();
        assert_eq!(m.force_delay_s, Some(5e-5));
        assert!((m.force_align_s + 5e-5).abs() < 1e-15);
        assert_eq!(m.ports_from_s, Some(0.5));
        assert_eq!(m.ports_delay_s, 5e-5);
        assert_eq!(m.theta_source, ThetaSource::Piston);
        for (value, source) in [
            ("piston", ThetaSource::Piston),
            (" servo_encoder ", ThetaSource::ServoEncoder),
        ] {
            let m = Measured::from_log(&log(&[("theta_source", value)]), 0.024).unwrap();
            assert_eq!(m.theta_source, source);
        }
        for (key, value) in [
            ("theta_source", "servo"),
            ("ports_delay_s", "-1e-4"),
            ("force_delay_s", "1"),
            ("force_delay_s", "soon"),
            ("ports_from_s", "NaN"),
        ] {
            let e = Measured::from_log(&log(&[(key, value)]), 0.024).unwrap_err();
            assert!(e.contains(key), "{e}");
        }
    }
}
