//! What the model still does not explain once the selection ends (`gap.json`'s
//! `unexplained`, `docs/formats.md` §4): per channel, the residual's RMS against the
//! channel's noise floor, and whether what is left is structured — how much of it a smooth
//! function of the measured variables explains, and which variables it follows.
//!
//! **Noise floor.** The noise the band lets through, estimated from the data: each sensor's
//! white noise measured in its reading's highest band (the fourth difference, robustly) and
//! carried through the channel's own filter — on the force channel the motor forces' noise
//! and the position's through `m·Δ²x` ([`super::noise`]). Beside it, the floor the model's
//! `[sensors]` noise would give through the same filter (`noise_floor_model`).
//!
//! **Structure.** The residual at the kept samples against a smooth function (piecewise
//! linear on [`KNOTS`] knots at the variable's quantiles) of each measured variable — `x`,
//! `v`, `|v|`, `sgn(v)`, `x·sgn(v)` (a function of x whose sign follows the motion: friction
//! varying along the bore), `a`, `p_a`, `p_b`, the rotation's phase `theta`, `t` — or a
//! constant, added greedily while each passes the selection's own rules
//! ([`super::judge`]): `ΔBIC ≥ 10` over the effective sample size, at least
//! [`super::judge::MIN_EXPLAINED_TOTAL`] of the residual explained, and an RMS the channel's
//! sensors resolve ([`super::channel::resolution`]). What passes is "structured": a smooth
//! function of what the log measured, which no effect of the model describes; what does not
//! is noise and the sensors' rounding.

use std::fmt::Write as _;

use serde::Serialize;

use crate::plant::model::extra_force::Term;
use crate::plant::model::MachineModel;

use super::band::Band;
use super::channel::{resolution, ChannelId};
use super::data::Measured;
use super::fit::lstsq;
use super::judge::{effective_n, MIN_DELTA_BIC, MIN_EXPLAINED_TOTAL};

/// Knots of the piecewise-linear function of one variable.
pub const KNOTS: usize = 8;

/// Most variables a structure is described by.
pub const MAX_FOLLOWED: usize = 3;

/// What a channel's residual still holds after the selection (`docs/formats.md` §4).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct UnexplainedJson {
    /// The channel.
    pub channel: String,
    /// Unit of the residual.
    pub unit: String,
    /// RMS of the band-limited residual with the augmented model.
    pub rms: f64,
    /// RMS the channel's noise would leave in the band, estimated from the data's high band.
    pub noise_floor: f64,
    /// The same from the model's `[sensors]` noise.
    pub noise_floor_model: f64,
    /// Whether a smooth function of the measured variables explains a significant part.
    pub structured: bool,
    /// RMS of that part (0 when not structured).
    pub structured_rms: f64,
    /// The variables it follows, most evidence first (empty when not structured).
    pub follows: Vec<String>,
    /// Share of the original gap (the input model's mean square) still unexplained.
    pub share: f64,
    /// The same in words.
    pub description: String,
}

/// A measured variable a structure can follow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Variable {
    /// A constant.
    Constant,
    /// Position, m.
    X,
    /// Velocity, m/s.
    V,
    /// Speed, m/s.
    AbsV,
    /// Direction of motion.
    SgnV,
    /// A function of position whose sign follows the direction of motion.
    XSgnV,
    /// Acceleration, m/s².
    A,
    /// Chamber A's pressure, Pa.
    PA,
    /// Chamber B's pressure, Pa.
    PB,
    /// The rotation's phase, rad (0 … 2π).
    Theta,
    /// Time from the log's start, s.
    T,
}

impl Variable {
    /// Every variable, in the order ties are broken.
    pub const ALL: [Variable; 11] = [
        Variable::Constant,
        Variable::X,
        Variable::V,
        Variable::AbsV,
        Variable::SgnV,
        Variable::XSgnV,
        Variable::A,
        Variable::PA,
        Variable::PB,
        Variable::Theta,
        Variable::T,
    ];

    /// Its name in `follows`.
    pub fn name(self) -> &'static str {
        match self {
            Variable::Constant => "1",
            Variable::X => "x",
            Variable::V => "v",
            Variable::AbsV => "|v|",
            Variable::SgnV => "sgn(v)",
            Variable::XSgnV => "x*sgn(v)",
            Variable::A => "a",
            Variable::PA => "p_a",
            Variable::PB => "p_b",
            Variable::Theta => "theta",
            Variable::T => "t",
        }
    }

    /// The variable named `name` (as in `follows`).
    pub fn parse(name: &str) -> Option<Variable> {
        Variable::ALL.into_iter().find(|v| v.name() == name)
    }

    /// Its value at row `i` (for `x·sgn(v)`: x, the sign applied by [`Self::columns`]).
    pub fn value_at(self, data: &Measured, i: usize) -> f64 {
        self.value(data, i)
    }

    /// Its value at row `i` (for `x·sgn(v)`: x, the sign applied by [`Self::columns`]).
    fn value(self, data: &Measured, i: usize) -> f64 {
        let g = |v: &[f64]| v.get(i).copied().unwrap_or(0.0);
        match self {
            Variable::Constant => 1.0,
            Variable::X | Variable::XSgnV => g(&data.x_m),
            Variable::V => g(&data.v_mps),
            Variable::AbsV => g(&data.v_mps).abs(),
            Variable::SgnV => g(&data.v_mps).signum(),
            Variable::A => g(&data.a_mps2),
            Variable::PA => g(&data.p_a_pa),
            Variable::PB => g(&data.p_b_pa),
            Variable::Theta => g(&data.theta_rad).rem_euclid(std::f64::consts::TAU),
            Variable::T => g(&data.t_s) - data.t_s.first().copied().unwrap_or(0.0),
        }
    }

    /// The smooth function's columns at `rows` and its knots: hat functions on the
    /// variable's quantiles (for `x·sgn(v)` times the direction of motion; for `sgn(v)` one
    /// level per direction; a constant one column).
    fn columns(self, data: &Measured, rows: &[usize]) -> (Vec<Vec<f64>>, Vec<f64>) {
        let values: Vec<f64> = rows.iter().map(|&i| self.value(data, i)).collect();
        match self {
            Variable::Constant => (vec![vec![1.0; rows.len()]], vec![]),
            Variable::SgnV => {
                let up = values
                    .iter()
                    .map(|s| f64::from(u8::from(*s > 0.0)))
                    .collect();
                let down = values
                    .iter()
                    .map(|s| f64::from(u8::from(*s < 0.0)))
                    .collect();
                (vec![up, down], vec![1.0, -1.0])
            }
            _ => {
                let knots = quantile_knots(&values);
                let mut cols = hats(&values, &knots);
                if self == Variable::XSgnV {
                    for col in &mut cols {
                        for (c, &i) in col.iter_mut().zip(rows) {
                            *c *= data.v_mps.get(i).copied().unwrap_or(0.0).signum();
                        }
                    }
                }
                (cols, knots)
            }
        }
    }
}

/// [`KNOTS`] knots at the quantiles of `values` (fewer where values repeat).
fn quantile_knots(values: &[f64]) -> Vec<f64> {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let mut knots: Vec<f64> = Vec::new();
    if sorted.is_empty() {
        return knots;
    }
    for k in 0..KNOTS {
        let q = k as f64 / (KNOTS - 1) as f64;
        let v = sorted
            .get(((sorted.len() - 1) as f64 * q).round() as usize)
            .copied()
            .unwrap_or(0.0);
        if knots.last().is_none_or(|l| v > *l) {
            knots.push(v);
        }
    }
    knots
}

/// The hat functions on `knots` at `values` (each 1 at its knot, 0 at its neighbours,
/// held flat beyond the ends): they sum to 1.
fn hats(values: &[f64], knots: &[f64]) -> Vec<Vec<f64>> {
    let mut cols = vec![vec![0.0; values.len()]; knots.len()];
    for (r, &v) in values.iter().enumerate() {
        let j = knots.partition_point(|k| *k <= v);
        let (lo, hi) = (j.saturating_sub(1), j.min(knots.len().saturating_sub(1)));
        let w = match (knots.get(lo), knots.get(hi)) {
            (Some(a), Some(b)) if b > a => ((v - a) / (b - a)).clamp(0.0, 1.0),
            _ => 0.0,
        };
        if let Some(c) = cols.get_mut(lo).and_then(|c| c.get_mut(r)) {
            *c += 1.0 - w;
        }
        if hi != lo {
            if let Some(c) = cols.get_mut(hi).and_then(|c| c.get_mut(r)) {
                *c += w;
            }
        }
    }
    cols
}

/// The rows of the log behind each of `ch`'s kept samples (pressure: A's then B's).
fn kept_rows(band: &Band, ch: ChannelId) -> Vec<usize> {
    match ch {
        ChannelId::Force => band.idx_force.clone(),
        ChannelId::SlaveForce | ChannelId::Encoder => band.idx_encoder.clone(),
        ChannelId::Pressure => band
            .idx_inner
            .iter()
            .chain(&band.idx_inner)
            .copied()
            .collect(),
    }
}

/// A structure found: the variables, the fit's columns per variable and coefficients.
struct Structure {
    followed: Vec<(Variable, Vec<f64>, Vec<f64>)>,
    fitted: Vec<f64>,
}

/// Greedy structure search on the kept residual `y` (module header).
fn structure(data: &Measured, rows: &[usize], y: &[f64], floor_rms: f64) -> Option<Structure> {
    let rss0: f64 = y.iter().map(|v| v * v).sum();
    if rss0 <= 0.0 || y.len() < 4 * KNOTS {
        return None;
    }
    let candidates: Vec<(Variable, Vec<Vec<f64>>, Vec<f64>)> = Variable::ALL
        .iter()
        .map(|&v| {
            let (cols, knots) = v.columns(data, rows);
            (v, cols, knots)
        })
        .filter(|(_, cols, _)| !cols.is_empty())
        .collect();
    let mut chosen: Vec<usize> = Vec::new();
    let mut best_fit: Option<(Vec<f64>, f64)> = None; // fitted values, rss
    for _ in 0..MAX_FOLLOWED {
        let rss_now = best_fit.as_ref().map_or(rss0, |f| f.1);
        let mut step: Option<(usize, Vec<f64>, f64, f64)> = None; // (candidate, fitted, rss, dbic)
        for (c, (_, cols, _)) in candidates.iter().enumerate() {
            if chosen.contains(&c) {
                continue;
            }
            let mut all: Vec<Vec<f64>> = chosen
                .iter()
                .flat_map(|&k| candidates.get(k).map(|x| x.1.clone()).unwrap_or_default())
                .collect();
            all.extend(cols.iter().cloned());
            let Some((theta, rss)) = lstsq(&all, y) else {
                continue;
            };
            let fitted: Vec<f64> = (0..y.len())
                .map(|r| {
                    all.iter()
                        .zip(&theta)
                        .map(|(col, t)| t * col.get(r).copied().unwrap_or(0.0))
                        .sum()
                })
                .collect();
            let left: Vec<f64> = y.iter().zip(&fitted).map(|(a, b)| a - b).collect();
            let nf = effective_n(&left);
            let k = cols.len() as f64;
            let dbic = nf * (rss_now / rss.max(f64::MIN_POSITIVE)).ln() - k * nf.ln();
            if step.as_ref().is_none_or(|s| dbic > s.3) {
                step = Some((c, fitted, rss, dbic));
            }
        }
        let Some((c, fitted, rss, dbic)) = step else {
            break;
        };
        let gained = (rss_now - rss) / rss0;
        let part_rms = (fitted.iter().map(|v| v * v).sum::<f64>() / y.len() as f64).sqrt();
        if dbic < MIN_DELTA_BIC || gained < MIN_EXPLAINED_TOTAL || part_rms < floor_rms {
            break;
        }
        chosen.push(c);
        best_fit = Some((fitted, rss));
    }
    let (fitted, _) = best_fit?;
    // Each followed variable's own part, for the words: its knots and the function's
    // values there (the coefficients of its hats), refitted jointly.
    let all: Vec<Vec<f64>> = chosen
        .iter()
        .flat_map(|&k| candidates.get(k).map(|x| x.1.clone()).unwrap_or_default())
        .collect();
    let theta = lstsq(&all, y).map(|t| t.0).unwrap_or_default();
    let mut at = 0;
    let mut followed = Vec::new();
    for &k in &chosen {
        if let Some((v, cols, knots)) = candidates.get(k) {
            let coef = theta.get(at..at + cols.len()).unwrap_or_default().to_vec();
            at += cols.len();
            followed.push((*v, knots.clone(), coef));
        }
    }
    Some(Structure { followed, fitted })
}

/// The variables the kept residual `kept` of channel `ch` follows (empty: not structured).
pub fn follows(
    data: &Measured,
    band: &Band,
    model: &MachineModel,
    ch: ChannelId,
    kept: &[f64],
) -> Vec<Variable> {
    structure(data, &kept_rows(band, ch), kept, resolution(ch, model))
        .map(|s| s.followed.iter().map(|f| f.0).collect())
        .unwrap_or_default()
}

/// Whether the discovery basis's `term` is a function of the measured variable `v` (so that
/// a structure left in `v` is a dependence the term misdescribes).
pub fn term_reads(term: Term, v: Variable) -> bool {
    let reads: &[Variable] = match term {
        Term::One => &[Variable::Constant],
        Term::X | Term::X2 | Term::X3 | Term::Sin | Term::Cos => &[Variable::X],
        Term::V | Term::VAbsV => &[Variable::V, Variable::AbsV],
        Term::SgnV => &[Variable::SgnV],
        Term::XSgnV => &[Variable::X, Variable::SgnV, Variable::XSgnV],
        Term::TSgnV => &[Variable::T, Variable::SgnV],
        Term::T => &[Variable::T],
        Term::A | Term::FMotor => &[Variable::A],
        Term::DeltaP => &[Variable::PA, Variable::PB],
    };
    reads.contains(&v)
        || (v == Variable::XSgnV
            && reads
                .iter()
                .any(|r| matches!(r, Variable::X | Variable::SgnV)))
}

/// Judges what `raw` (the channel's raw residual with the augmented model, every row;
/// pressure: A's rows then B's) and `kept` (its band-filtered kept samples) leave, against
/// the input model's RMS `rms_before` and the augmented model's `rms_after`.
pub fn judge_left(
    data: &Measured,
    band: &Band,
    model: &MachineModel,
    ch: ChannelId,
    raw: &[f64],
    kept: &[f64],
    (rms_before, rms_after): (f64, f64),
) -> UnexplainedJson {
    let noise_floor = super::noise::floor_from_data(data, band, model, ch, raw);
    let noise_floor_model = super::noise::floor_from_model(data, band, model, ch);
    let rows = kept_rows(band, ch);
    let found = structure(data, &rows, kept, resolution(ch, model));
    let share = if rms_before > 0.0 {
        (rms_after / rms_before).powi(2)
    } else {
        0.0
    };
    let (unit, k) = display_unit(ch);
    let structured_rms = found.as_ref().map_or(0.0, |s| {
        (s.fitted.iter().map(|v| v * v).sum::<f64>() / s.fitted.len().max(1) as f64).sqrt()
    });
    let mut description = format!(
        "the model still misses {:.3} {unit} RMS in the {} channel (noise floor {:.3} {unit})",
        rms_after * k,
        ch.name(),
        noise_floor * k
    );
    match &found {
        Some(s) => {
            let words: Vec<String> = s
                .followed
                .iter()
                .map(|(v, knots, coef)| shape_words(*v, knots, coef, unit, k))
                .collect();
            let _ = write!(
                description,
                ", structured: {:.3} {unit} RMS of it {}",
                structured_rms * k,
                words.join(", and ")
            );
        }
        None => description.push_str(", not structured: no smooth function of the measured variables explains a significant part of it"),
    }
    UnexplainedJson {
        channel: ch.name().into(),
        unit: ch.unit().into(),
        rms: rms_after,
        noise_floor,
        noise_floor_model,
        structured: found.is_some(),
        structured_rms,
        follows: found
            .as_ref()
            .map(|s| s.followed.iter().map(|f| f.0.name().to_string()).collect())
            .unwrap_or_default(),
        share,
        description,
    }
}

/// The unit the words use and the factor from SI to it.
fn display_unit(ch: ChannelId) -> (&'static str, f64) {
    match ch {
        ChannelId::Force | ChannelId::SlaveForce => ("N", 1.0),
        ChannelId::Encoder => ("µm", 1e6),
        ChannelId::Pressure => ("Pa", 1.0),
    }
}

/// A variable's value in words ("x = 0.090 m").
fn at_words(v: Variable, value: f64) -> String {
    match v {
        Variable::X | Variable::XSgnV => format!("x = {value:.3} m"),
        Variable::V => format!("v = {value:.2} m/s"),
        Variable::AbsV => format!("|v| = {value:.2} m/s"),
        Variable::A => format!("a = {value:.0} m/s²"),
        Variable::PA => format!("p_a = {:.0} kPa", value * 1e-3),
        Variable::PB => format!("p_b = {:.0} kPa", value * 1e-3),
        Variable::Theta => format!("theta = {value:.2} rad"),
        Variable::T => format!("t = {value:.2} s"),
        Variable::Constant | Variable::SgnV => String::new(),
    }
}

/// The shape of a followed variable's function in words: constant, rising, falling,
/// growing with distance from a point, or peaking at one; for the direction-signed
/// variables, the part against the motion.
fn shape_words(v: Variable, knots: &[f64], coef: &[f64], unit: &str, k: f64) -> String {
    match v {
        Variable::Constant => {
            let c = coef.first().copied().unwrap_or(0.0) * k;
            return format!("is a constant {c:.2} {unit} toward +x");
        }
        Variable::SgnV => {
            let up = coef.first().copied().unwrap_or(0.0) * k;
            let down = coef.get(1).copied().unwrap_or(0.0) * k;
            let against = 0.5 * (down - up);
            return format!(
                "follows the direction of motion: {:.2} {unit} {} the motion",
                against.abs(),
                if against >= 0.0 { "against" } else { "along" }
            );
        }
        _ => {}
    }
    // For x·sgn(v), the part against the motion: −g(x).
    let signed = v == Variable::XSgnV;
    let g: Vec<f64> = coef
        .iter()
        .map(|c| if signed { -c * k } else { c * k })
        .collect();
    let name = if signed { "x" } else { v.name() };
    let what = if signed {
        "the force against the motion"
    } else {
        "it"
    };
    let (lo, hi) = g.iter().enumerate().fold((0, 0), |(lo, hi), (i, val)| {
        let lo = if *val < g.get(lo).copied().unwrap_or(f64::MAX) {
            i
        } else {
            lo
        };
        let hi = if *val > g.get(hi).copied().unwrap_or(f64::MIN) {
            i
        } else {
            hi
        };
        (lo, hi)
    });
    let last = g.len().saturating_sub(1);
    let range = g.get(hi).copied().unwrap_or(0.0) - g.get(lo).copied().unwrap_or(0.0);
    let tail = if signed { " while moving" } else { "" };
    let shape = if lo > 0 && lo < last {
        format!(
            "{what} grows with distance from {}{tail}",
            at_words(v, knots.get(lo).copied().unwrap_or(0.0))
        )
    } else if hi > 0 && hi < last {
        format!(
            "{what} peaks at {}{tail}",
            at_words(v, knots.get(hi).copied().unwrap_or(0.0))
        )
    } else if hi > lo {
        format!("{what} rises with {name}{tail}")
    } else {
        format!("{what} falls with {name}{tail}")
    };
    format!("{shape} (over {range:.2} {unit})")
}
