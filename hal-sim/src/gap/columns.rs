//! The force channel's residual as a weighted sum of band-filtered columns.
//!
//! The force the model does not explain, `m·Δ²x − F_motor − F_gas − F_cog + F_fr − F_extra`
//! ([`super::residuals::force_raw`], sample by sample), is linear in every level the workflow
//! fits once the shape of each law is fixed: the mass; the friction's levels (the law is
//! `F_c·d + (F_s − F_c)·S·d + b·v`, its direction `d` and Stribeck shape `S` fixed by the
//! regularisation, the Stribeck velocity and exponent:
//! [`fpc::physics::friction::FrictionParams::axial_direction`]); the cogging's sine and
//! cosine at its period; the pressure sensors' offsets and gains; the force readings' offsets
//! and gains; the discovered terms' coefficients. The band filter is linear too. So every
//! force residual is a few coefficients times [`Column`]s that depend on the log and a shape
//! parameter only (a period, a shift, a Stribeck velocity), and each column is computed and
//! filtered once per log and kept ([`super::band::Band::force_column`], [`super::band::Band::combine`]): a candidate's
//! residual is then a sum over the kept samples, not a pass over every row.

use std::f64::consts::TAU;

use fpc::physics::friction::{stribeck_shape, FrictionParams};
use fpc::units::Section;

use crate::plant::fastmath::sin_cos;
use crate::plant::model::extra_force::{ExtraState, Term};
use crate::plant::model::MachineModel;

use super::data::Measured;

/// A chamber of the cylinder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Chamber {
    /// Chamber A (x-small side).
    A,
    /// Chamber B.
    B,
}

/// One column of the force balance along the log, before the band filter. Shape parameters
/// are kept as the bits of their `f64` (the key of the cache).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Column {
    /// The raw second difference of x, m/s² (times the mass: the inertia).
    Accel,
    /// 1.
    One,
    /// The differentiator's velocity, m/s.
    Velocity,
    /// The friction's axial direction `tanh(|u|/v_reg)·v/|u|`, `u = (v, ω·r)`.
    FrictionDirection {
        /// `v_reg`, m/s.
        sign_velocity: u64,
        /// `r`, m.
        radius: u64,
    },
    /// The Stribeck dip along it, `e^{−(|u|/v_s)^ζ}·d`.
    Stribeck {
        /// `v_reg`, m/s.
        sign_velocity: u64,
        /// `r`, m.
        radius: u64,
        /// `v_s`, m/s.
        velocity: u64,
        /// `ζ`.
        exponent: u64,
    },
    /// One section's reported force (`None`: both sections' summed), shifted later by
    /// `shift` samples (fractional: linear interpolation), N.
    Motor {
        /// Which section (`None`: both).
        section: Option<Section>,
        /// Samples.
        shift: u64,
    },
    /// One chamber's pressure reading with its sensor's lag undone, `p + τ·ṗ`, Pa.
    Pressure {
        /// Which chamber.
        chamber: Chamber,
        /// `τ`, s.
        time_constant: u64,
    },
    /// `sin(2πx/p)`.
    Sine {
        /// `p`, m.
        period: u64,
    },
    /// `cos(2πx/p)`.
    Cosine {
        /// `p`, m.
        period: u64,
    },
    /// A term of the discovery basis that reads no model value (not `f_motor`, which is the
    /// motor columns, nor the periodic pair).
    Term(Term),
}

/// A weighted sum of columns.
pub type Combination = Vec<(f64, Column)>;

impl Column {
    /// The motor column of `section` (`None`: both) shifted by `shift` samples.
    pub fn motor(section: Option<Section>, shift: f64) -> Self {
        Column::Motor {
            section,
            shift: shift.to_bits(),
        }
    }

    /// The friction direction of `law` on a piston of friction radius `radius_m`.
    pub fn direction(law: &FrictionParams<f64>, radius_m: f64) -> Self {
        Column::FrictionDirection {
            sign_velocity: law.sign_velocity_mps.to_bits(),
            radius: radius_m.to_bits(),
        }
    }

    /// The Stribeck dip of `law` at velocity `velocity_mps` and exponent `exponent`.
    pub fn stribeck(
        law: &FrictionParams<f64>,
        radius_m: f64,
        velocity_mps: f64,
        exponent: f64,
    ) -> Self {
        Column::Stribeck {
            sign_velocity: law.sign_velocity_mps.to_bits(),
            radius: radius_m.to_bits(),
            velocity: velocity_mps.to_bits(),
            exponent: exponent.to_bits(),
        }
    }

    /// The sine and cosine of period `period_m`.
    pub fn pair(period_m: f64) -> [Self; 2] {
        let period = period_m.to_bits();
        [Column::Sine { period }, Column::Cosine { period }]
    }

    /// The column at every row of `data`.
    pub fn raw(self, data: &Measured) -> Vec<f64> {
        let f = f64::from_bits;
        match self {
            Column::Accel => data.d2x_mps2.clone(),
            Column::One => vec![1.0; data.len()],
            Column::Velocity => data.v_mps.clone(),
            Column::FrictionDirection {
                sign_velocity,
                radius,
            } => sliding(data, f(sign_velocity), f(radius), |_, d| d),
            Column::Stribeck {
                sign_velocity,
                radius,
                velocity,
                exponent,
            } => sliding(data, f(sign_velocity), f(radius), |slip, d| {
                if d == 0.0 {
                    0.0
                } else {
                    stribeck_shape(slip, f(velocity), f(exponent)) * d
                }
            }),
            Column::Motor { section, shift } => shifted(&motor_n(data, section), f(shift)),
            Column::Pressure {
                chamber,
                time_constant,
            } => {
                let (p, rate) = match chamber {
                    Chamber::A => (&data.p_a_pa, &data.dp_a_pa_per_s),
                    Chamber::B => (&data.p_b_pa, &data.dp_b_pa_per_s),
                };
                let tau = f(time_constant);
                p.iter().zip(rate).map(|(p, r)| p + tau * r).collect()
            }
            Column::Sine { period } => data
                .x_m
                .iter()
                .map(|x| sin_cos(TAU * x / f(period)).0)
                .collect(),
            Column::Cosine { period } => data
                .x_m
                .iter()
                .map(|x| sin_cos(TAU * x / f(period)).1)
                .collect(),
            Column::Term(term) => {
                let t0 = data.t_s.first().copied().unwrap_or(0.0);
                (0..data.len())
                    .map(|i| {
                        let g = |v: &[f64]| v.get(i).copied().unwrap_or(0.0);
                        let state = ExtraState {
                            x_m: g(&data.x_m),
                            v_mps: g(&data.v_mps),
                            a_mps2: g(&data.d2x_mps2),
                            f_motor_n: 0.0,
                            dp_pa: g(&data.p_a_pa) - g(&data.p_b_pa),
                            t_s: g(&data.t_s) - t0,
                        };
                        term.value(&state, 1.0)
                    })
                    .collect()
            }
        }
    }
}

/// The reported force of `section` at every row, as logged (`None`: both sections'
/// summed), N.
pub fn motor_n(data: &Measured, section: Option<Section>) -> Vec<f64> {
    match section {
        Some(Section::Master) => data.f_master_n.clone(),
        Some(Section::Slave) => data.f_slave_n.clone(),
        None => data
            .f_master_n
            .iter()
            .zip(&data.f_slave_n)
            .map(|(a, b)| a + b)
            .collect(),
    }
}

/// `each(|u|, d)` at every row, with `u = (v, ω·r)` the sliding velocity and `d` the
/// friction's axial direction at the regularisation `sign_velocity`.
fn sliding(
    data: &Measured,
    sign_velocity: f64,
    radius: f64,
    each: impl Fn(f64, f64) -> f64,
) -> Vec<f64> {
    let law = FrictionParams {
        sign_velocity_mps: sign_velocity,
        ..FrictionParams::<f64>::reference()
    };
    data.v_mps
        .iter()
        .zip(&data.omega_rad_s)
        .map(|(&v, &w)| {
            let t = w * radius;
            let slip = (v * v + t * t).sqrt();
            each(slip, law.axial_direction(v, t))
        })
        .collect()
}

/// `x` shifted later by `samples` (fractional: linear interpolation; negative: earlier),
/// holding the end values beyond the ends.
pub fn shifted(x: &[f64], samples: f64) -> Vec<f64> {
    let n = x.len();
    let (first, last) = match (x.first(), x.last()) {
        (Some(&f), Some(&l)) => (f, l),
        _ => return Vec::new(),
    };
    if !samples.is_finite() {
        return vec![f64::NAN; n];
    }
    // `x` at `i − samples` = `x` at `j + f` with one whole shift `j − i` and one fraction
    // `f` for every sample.
    let whole = (-samples).floor();
    let f = -samples - whole;
    let whole = whole as isize;
    let last_index = n as isize - 1;
    (0..n)
        .map(|i| {
            let j = i as isize + whole;
            if j < 0 {
                return first;
            }
            if j >= last_index {
                return last;
            }
            let k = j as usize;
            match (x.get(k), x.get(k + 1)) {
                (Some(a), Some(b)) => a + f * (b - a),
                _ => last,
            }
        })
        .collect()
}

/// How far the motor forces act behind their row by `model`, in samples: the log's
/// convention (`force_align_s`) and the model's actuator lag.
pub fn motor_shift(data: &Measured, model: &MachineModel) -> f64 {
    let delay = model
        .effects
        .actuator_lag
        .as_ref()
        .map_or(0.0, |l| l.delay_s);
    (delay + data.force_align_s) / data.dt_s
}

/// The columns of `term` of the discovery basis at the motor shift `shift` and the period
/// `period_m` (the periodic pair), with their weights.
pub fn term_columns(term: Term, shift: f64, period_m: f64) -> Combination {
    let [sine, cosine] = Column::pair(period_m);
    match term {
        Term::FMotor => vec![(1.0, Column::motor(None, shift))],
        Term::Sin => vec![(1.0, sine)],
        Term::Cos => vec![(1.0, cosine)],
        Term::One => vec![(1.0, Column::One)],
        Term::A => vec![(1.0, Column::Accel)],
        Term::V => vec![(1.0, Column::Velocity)],
        t => vec![(1.0, Column::Term(t))],
    }
}

/// The force residual of `model` as a combination of columns (module header).
pub fn force_combination(data: &Measured, model: &MachineModel) -> Combination {
    let shift = motor_shift(data, model);
    let mut out: Combination = vec![(model.piston.mass_kg, Column::Accel)];
    // The motor forces as they act: each section's reading through its gain and offset,
    // `(F − o)/g` (`[sensors.force]`).
    let f = &model.sensors.force;
    if f.exact() {
        out.push((-1.0, Column::motor(None, shift)));
    } else {
        out.push((
            -1.0 / f.gain_master,
            Column::motor(Some(Section::Master), shift),
        ));
        out.push((
            -1.0 / f.gain_slave,
            Column::motor(Some(Section::Slave), shift),
        ));
        out.push((
            f.offset_master_n / f.gain_master + f.offset_slave_n / f.gain_slave,
            Column::One,
        ));
    }
    // The gas force of the chambers' true pressures, `(p − o + τ·ṗ)/g·A_eff` each.
    let sensor = &model.sensors.pressure;
    let area = model.cylinder().area_m2;
    let tau = sensor.time_constant_s.to_bits();
    let (ta, tb) = (sensor.chamber_a(), sensor.chamber_b());
    out.push((
        -area / ta.gain,
        Column::Pressure {
            chamber: Chamber::A,
            time_constant: tau,
        },
    ));
    out.push((
        area / tb.gain,
        Column::Pressure {
            chamber: Chamber::B,
            time_constant: tau,
        },
    ));
    out.push((
        area * (ta.offset_pa / ta.gain - tb.offset_pa / tb.gain),
        Column::One,
    ));
    if let Some(c) = model.cogging() {
        let [sine, cosine] = Column::pair(c.period_m);
        out.push((-c.amplitude_n * c.phase_rad.cos(), sine));
        out.push((-c.amplitude_n * c.phase_rad.sin(), cosine));
    }
    let law = model.friction();
    let radius = model.friction_radius_m();
    out.push((law.coulomb_n, Column::direction(&law, radius)));
    if law.static_n != law.coulomb_n {
        out.push((
            law.static_n - law.coulomb_n,
            Column::stribeck(
                &law,
                radius,
                law.stribeck_velocity_mps,
                law.stribeck_exponent,
            ),
        ));
    }
    out.push((law.viscous_ns_per_m, Column::Velocity));
    if let Some(extra) = &model.effects.extra_force {
        let period = extra.period_m.unwrap_or(1.0);
        for (term, c) in extra.parsed().unwrap_or_default() {
            for (w, col) in term_columns(term, shift, period) {
                out.push((-c * w, col));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gap::band::Band;
    use crate::gap::channel::ChannelId;
    use crate::gap::residuals::force_raw;
    use crate::runlog::RunLog;

    /// A 10 kHz log of sine strokes with a turning piston, noisy forces and pressures.
    fn measured() -> Measured {
        let mut log = RunLog::with_columns(&crate::runlog::REQUIRED);
        for i in 0..6000 {
            let t = i as f64 * 1e-4;
            let x = 0.1 + 0.06 * (7.0 * t).sin() + 1e-6 * ((i * 7919) as f64).sin();
            let f = 400.0 * (7.0 * t).cos() + 3.0 * ((i * 104_729) as f64).sin();
            let p = 1e5 + 2e4 * (7.0 * t).sin();
            log.push_row(&[t, x, x, 0.3 * t, f, 0.9 * f, p, 2e5 - p]);
        }
        Measured::from_log(&log, 0.024).unwrap()
    }

    #[test]
    fn the_columns_sum_to_the_filtered_force_balance() {
        let data = measured();
        let band = Band::new(&data, 300.0).unwrap();
        let text = crate::plant::model::REFERENCE_TOML.to_string()
            + "\n[effects.stribeck_friction]\nstatic_n = 70.0\nvelocity_mps = 0.03\nexponent = 2.0\n\
               [effects.actuator_lag]\ndelay_s = 3.3e-4\n\
               [effects.extra_force]\nterms = { \"x\" = -1800.0, \"1\" = 162.0, \"f_motor\" = 0.05, \
               \"sin(2πx/p)\" = 4.0, \"cos(2πx/p)\" = -3.0, \"t*sgn(v)\" = 2.0 }\nperiod_m = 0.018\n";
        let mut model = crate::plant::model::MachineModel::parse(&text).unwrap();
        model.sensors.pressure.offset_a_pa = 700.0;
        model.sensors.pressure.time_constant_s = 2e-4;
        let direct = band.kept(&data, ChannelId::Force, &force_raw(&data, &model));
        let summed = band.combine(&data, &force_combination(&data, &model));
        let scale = direct.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 10.0);
        for (a, b) in direct.iter().zip(&summed) {
            assert!((a - b).abs() < 1e-9 * scale, "{a} {b}");
        }
    }
}
