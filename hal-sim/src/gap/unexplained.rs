//! What the augmented model still misses, judged (`docs/gap.md`, "What is left"): each
//! channel's band-limited residual after the selection against the channel's noise floor,
//! and how much of it a smooth function of the measured variables explains **out of
//! sample** — binned means per variable, fitted additively on one half of the log's time
//! blocks and scored on the other — and which variables it follows.

use serde::Serialize;

use crate::plant::model::MachineModel;

use super::channel::{resolution, ChannelId};
use super::data::Measured;
use super::fit::correlation;
use super::residuals::{rms_of_full, Band};

/// Bins per variable (quantiles of the variable over the judged samples).
pub const BINS: usize = 12;

/// Contiguous time blocks the judged samples are dealt into; even blocks make one fold, odd
/// blocks the other, so that a fit never scores the samples (or their neighbours, which the
/// band filter correlates) it was fitted on.
pub const BLOCKS: usize = 10;

/// Out-of-sample share of the residual's variance a smooth function must explain for the
/// residual to count as structured.
pub const STRUCTURED_SHARE: f64 = 0.2;

/// The structured part's RMS must also reach this many noise floors.
pub const FLOOR_MARGIN: f64 = 1.0;

/// Out-of-sample share a further variable must add to be counted as followed.
pub const FOLLOW_GAIN: f64 = 0.05;

/// Most variables an additive fit takes.
pub const MAX_FOLLOWS: usize = 3;

/// A measured variable the residual may follow (`docs/formats.md`, "What is left").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Variable {
    /// Position, m.
    X,
    /// Velocity, m/s.
    V,
    /// Speed, m/s.
    AbsV,
    /// Direction of motion (−1, 0, 1).
    SgnV,
    /// Position from the stroke's lower end times the direction of motion, m: its binned
    /// means are any function of position that differs by direction.
    XSgnV,
    /// Acceleration, m/s².
    A,
    /// Chamber-A pressure, Pa.
    PA,
    /// Chamber-B pressure, Pa.
    PB,
    /// Rotation angle, rad.
    Theta,
    /// Time from the log's first row, s.
    T,
}

impl Variable {
    /// Every variable, in the order ties are broken.
    pub const ALL: [Variable; 10] = [
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

    /// The name `gap.json` gives it.
    pub fn name(self) -> &'static str {
        match self {
            Variable::X => "x",
            Variable::V => "v",
            Variable::AbsV => "|v|",
            Variable::SgnV => "sgn v",
            Variable::XSgnV => "x·sgn v",
            Variable::A => "a",
            Variable::PA => "p_A",
            Variable::PB => "p_B",
            Variable::Theta => "θ",
            Variable::T => "t",
        }
    }

    /// What it is, in words.
    pub fn words(self) -> &'static str {
        match self {
            Variable::X => "position",
            Variable::V => "velocity",
            Variable::AbsV => "speed",
            Variable::SgnV => "the direction of motion",
            Variable::XSgnV => "position, differently by direction of motion",
            Variable::A => "acceleration",
            Variable::PA => "chamber A's pressure",
            Variable::PB => "chamber B's pressure",
            Variable::Theta => "the rotation angle",
            Variable::T => "time",
        }
    }

    /// Its value at sample `i`; `x_low` is the lowest judged position, m.
    fn at(self, d: &Measured, i: usize, x_low: f64) -> f64 {
        let get = |c: &[f64]| c.get(i).copied().unwrap_or(0.0);
        let sgn = |v: f64| {
            if v > 0.0 {
                1.0
            } else if v < 0.0 {
                -1.0
            } else {
                0.0
            }
        };
        match self {
            Variable::X => get(&d.x_m),
            Variable::V => get(&d.v_mps),
            Variable::AbsV => get(&d.v_mps).abs(),
            Variable::SgnV => sgn(get(&d.v_mps)),
            Variable::XSgnV => (get(&d.x_m) - x_low) * sgn(get(&d.v_mps)),
            Variable::A => get(&d.a_mps2),
            Variable::PA => get(&d.p_a_pa),
            Variable::PB => get(&d.p_b_pa),
            Variable::Theta => get(&d.theta_rad),
            Variable::T => get(&d.t_s) - d.t_s.first().copied().unwrap_or(0.0),
        }
    }
}

/// A channel's residual after the fit, judged (`gap.json`'s `unexplained`).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct UnexplainedJson {
    /// RMS of the band-limited residual with the augmented model, the channel's unit (the
    /// channel's `rms_after`).
    pub rms: f64,
    /// RMS the channel's noise alone leaves in the band, the channel's unit: the larger of
    /// the estimate from the data and the model's sensor noise (where it has one).
    pub noise_floor: f64,
    /// Share of the residual's variance the smooth function of `follows` explains out of
    /// sample (0 when it explains nothing).
    pub structured_share: f64,
    /// Whether a smooth function of the measured variables explains at least
    /// [`STRUCTURED_SHARE`] of it out of sample, that part's RMS reaches the noise floor, and
    /// taking it away would lower the channel's RMS by the channel's resolution (the least
    /// change the selection names an effect for, [`super::channel::resolution`]).
    pub structured: bool,
    /// The variables it follows, the strongest first (empty when it follows none).
    pub follows: Vec<String>,
    /// Residual RMS² after the fit over before it (1: the fit removed nothing).
    pub share_of_gap: f64,
}

/// A drawn curve: its label, the variable's values (SI) and the residual's means there.
pub type Curve = (String, Vec<f64>, Vec<f64>);

/// The judgement of one channel, with what the report draws.
#[derive(Clone, Debug)]
pub struct Unexplained {
    /// Which channel.
    pub channel: ChannelId,
    /// The JSON row.
    pub json: UnexplainedJson,
    /// The variables followed.
    pub follows: Vec<Variable>,
    /// How the residual's mean moves along the first of them, in words (empty if none).
    pub shape: String,
    /// Binned means of the residual along the first variable: (series label, centres in the
    /// variable's SI unit, means in the channel's unit); `x·sgn v` is drawn against `x` per
    /// direction.
    pub curves: Vec<Curve>,
}

/// The judged samples of a channel (decimated to the band's stride) as indices into its
/// full residual (pressure: chamber B's at `n + i`), with their row.
fn judged(band: &Band, ch: ChannelId, n: usize) -> Vec<(usize, usize)> {
    let rows: &[usize] = match ch {
        ChannelId::Force => &band.idx_force,
        ChannelId::Encoder | ChannelId::SlaveForce => &band.idx_encoder,
        ChannelId::Pressure => &band.idx_inner,
    };
    let mut out: Vec<(usize, usize)> = rows.iter().map(|&i| (i, i)).collect();
    if ch == ChannelId::Pressure {
        out.extend(rows.iter().map(|&i| (n + i, i)));
    }
    out
}

/// RMS of white noise of `sigma` (RMS at the log's rate) after the band's low-pass.
fn in_band(sigma: f64, d: &Measured, band: &Band) -> f64 {
    sigma * (2.0 * band.band_hz / d.sample_rate_hz()).min(1.0).sqrt()
}

/// Lags, in strides, the noise floor's differences are taken over.
pub const FLOOR_LAGS: [usize; 3] = [1, 2, 3];

/// Median of the square of a normal variable of unit variance.
const MEDIAN_CHI2_1: f64 = 0.454_936;

/// The noise floor from the data: the band-limited residual at samples one stride apart is
/// nearly independent noise (about one sample per half period at the band edge), while what
/// the machine's motion drives changes little between them, so the differences read the
/// band's upper part, above the motion's harmonics. Per lag, the median of the squared
/// differences (robust to the few steps a reversal leaves) over 2·[`MEDIAN_CHI2_1`] is twice
/// the noise's variance less its correlation at that lag; the band's filters correlate
/// neighbouring kept samples with alternating sign, and the mean over [`FLOOR_LAGS`] cancels
/// most of it.
fn floor_from_data(after: &[f64], samples: &[(usize, usize)], stride: usize) -> f64 {
    let mut variances = Vec::new();
    for lag in FLOOR_LAGS {
        let mut d2: Vec<f64> = samples
            .iter()
            .zip(samples.iter().skip(lag))
            .filter(|(a, b)| b.0 == a.0 + lag * stride)
            .filter_map(|(a, b)| Some((after.get(b.0)? - after.get(a.0)?).powi(2)))
            .collect();
        if d2.is_empty() {
            continue;
        }
        let mid = d2.len() / 2;
        let (_, m, _) = d2.select_nth_unstable_by(mid, f64::total_cmp);
        variances.push(*m / (2.0 * MEDIAN_CHI2_1));
    }
    if variances.is_empty() {
        0.0
    } else {
        (variances.iter().sum::<f64>() / variances.len() as f64).sqrt()
    }
}

/// Share of the log's peak speed above which a judged sample counts as moving in
/// [`moving_rms`].
pub const MOVING_SPEED_SHARE: f64 = 0.05;

/// RMS of the force channel's band-limited residual `after` (every sample) over its judged
/// samples where the speed exceeds [`MOVING_SPEED_SHARE`] of the log's peak, N (0 if none).
/// Friction, and most forces a description is of, act while the piston moves; a log of
/// holds and moves keeps the holds' samples where the controller dithers the piston about
/// its set point, and what they carry is the noise alone.
pub(super) fn moving_rms(d: &Measured, band: &Band, after: &[f64]) -> f64 {
    let peak = d.v_mps.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    let samples = judged(band, ChannelId::Force, d.len());
    rms_where_moving(
        samples
            .iter()
            .filter_map(|(i, row)| Some((*d.v_mps.get(*row)?, *after.get(*i)?))),
        peak,
    )
}

/// RMS of the residuals of the `(velocity, residual)` pairs whose speed exceeds
/// [`MOVING_SPEED_SHARE`] of `peak_mps` (0 if none).
fn rms_where_moving(samples: impl Iterator<Item = (f64, f64)>, peak_mps: f64) -> f64 {
    let (sum, count) = samples
        .filter(|(v, _)| v.abs() > MOVING_SPEED_SHARE * peak_mps)
        .fold((0.0, 0usize), |(s, c), (_, r)| (s + r * r, c + 1));
    if count > 0 {
        (sum / count as f64).sqrt()
    } else {
        0.0
    }
}

/// Bin edges (inner quantiles, distinct) of `keys`, `bins` bins.
fn edges(keys: &[f64], bins: usize) -> Vec<f64> {
    let mut sorted: Vec<f64> = keys.iter().copied().filter(|k| k.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let mut e: Vec<f64> = (1..bins)
        .filter_map(|b| sorted.get(b * sorted.len() / bins).copied())
        .collect();
    e.dedup();
    e
}

/// Bin edges of a key signed by the direction of motion ([`Variable::XSgnV`]): half the bins
/// over each sign's quantiles, split at zero, so that no bin mixes the two directions (their
/// keys meet at zero, where the residual's means by direction differ most); and the first
/// bin of the keys at or above zero.
fn signed_edges(keys: &[f64]) -> (Vec<f64>, usize) {
    let neg: Vec<f64> = keys.iter().copied().filter(|k| *k < 0.0).collect();
    let pos: Vec<f64> = keys.iter().copied().filter(|k| *k > 0.0).collect();
    let mut e = edges(&neg, BINS / 2);
    e.push(0.0);
    let split = e.len();
    e.extend(edges(&pos, BINS / 2));
    e.dedup();
    (e, split)
}

/// Per-sample bin of each variable, and the bin from which each variable's bins lie on the
/// other side of a split its means may not be carried across (`x·sgn v`'s zero; 0: none).
struct Binned {
    bins: Vec<Vec<usize>>,
    splits: Vec<usize>,
}

impl Binned {
    fn new(keys: &[Vec<f64>]) -> Self {
        let (bins, splits) = keys
            .iter()
            .zip(Variable::ALL)
            .map(|(k, var)| {
                let (e, split) = if var == Variable::XSgnV {
                    signed_edges(k)
                } else {
                    (edges(k, BINS), 0)
                };
                let b: Vec<usize> = k.iter().map(|v| e.partition_point(|x| x <= v)).collect();
                (b, split)
            })
            .unzip();
        Binned { bins, splits }
    }
}

/// Fewest samples of a fold in a bin for the fold's mean there to be taken. The judged
/// samples are one per half period at the band's edge, so about independent, but a bin the
/// fold barely visits holds one moment of the log — one start from a hold, say — and its
/// mean is that moment's, not the variable's.
pub const THIN_BIN: usize = 5;

/// Bin means of `r` over the samples of fold `f`. A bin the fold leaves empty or thin
/// ([`THIN_BIN`]) takes the mean of the fold's samples on its side of `split` (a log of holds
/// and moves visits different positions in different time blocks): where the fold saw
/// (nearly) nothing, the best it can say of `x·sgn v` is the mean of that direction of motion,
/// and of any other variable the mean.
fn bin_means(bins: &[usize], r: &[f64], fold: &[usize], f: usize, split: usize) -> [f64; BINS] {
    let (mut s, mut c) = ([0.0; BINS], [0usize; BINS]);
    for ((&b, &v), &k) in bins.iter().zip(r).zip(fold) {
        if k == f {
            if let (Some(s), Some(c)) = (s.get_mut(b), c.get_mut(b)) {
                *s += v;
                *c += 1;
            }
        }
    }
    let side = |b: usize| b >= split;
    let mut m = [0.0; BINS];
    for (b, m) in m.iter_mut().enumerate() {
        let (sum, count) = if c[b] >= THIN_BIN {
            (s[b], c[b])
        } else {
            (0..BINS)
                .filter(|&o| side(o) == side(b))
                .fold((0.0, 0), |(a, n), o| (a + s[o], n + c[o]))
        };
        if count > 0 {
            *m = sum / count as f64;
        }
    }
    m
}

/// Forward additive fit of binned means: at each stage the variable whose bin means (fitted
/// on one fold to what the earlier stages leave) lower the other fold's squared error most.
/// Returns the variables taken and the out-of-sample share explained.
fn additive(y: &[f64], fold: &[usize], binned: &Binned) -> (Vec<usize>, f64) {
    let mean_of = |f: usize| {
        let (s, c) = y
            .iter()
            .zip(fold)
            .filter(|(_, k)| **k == f)
            .fold((0.0, 0usize), |(s, c), (v, _)| (s + v, c + 1));
        if c > 0 {
            s / c as f64
        } else {
            0.0
        }
    };
    // pred[f][i]: the fit on fold f at sample i.
    let mut pred = [vec![mean_of(0); y.len()], vec![mean_of(1); y.len()]];
    let sse = |pred: &[Vec<f64>; 2]| -> f64 {
        y.iter()
            .enumerate()
            .map(|(i, v)| {
                let other = 1 - fold.get(i).copied().unwrap_or(0).min(1);
                (v - pred[other].get(i).copied().unwrap_or(0.0)).powi(2)
            })
            .sum()
    };
    let base = sse(&pred);
    if base <= 0.0 {
        return (Vec::new(), 0.0);
    }
    let mut taken = Vec::new();
    let mut current = base;
    for _ in 0..MAX_FOLLOWS {
        let mut best: Option<(usize, f64, [Vec<f64>; 2])> = None;
        for (j, bins) in binned.bins.iter().enumerate() {
            if taken.contains(&j) {
                continue;
            }
            let split = binned.splits.get(j).copied().unwrap_or(0);
            let next = [0usize, 1].map(|f| {
                let r: Vec<f64> = y.iter().zip(&pred[f]).map(|(v, p)| v - p).collect();
                let m = bin_means(bins, &r, fold, f, split);
                pred[f]
                    .iter()
                    .zip(bins)
                    .map(|(p, &b)| p + m.get(b).copied().unwrap_or(0.0))
                    .collect::<Vec<f64>>()
            });
            let e = sse(&next);
            if best.as_ref().is_none_or(|(_, be, _)| e < *be) {
                best = Some((j, e, next));
            }
        }
        match best {
            Some((j, e, next)) if (current - e) / base >= FOLLOW_GAIN => {
                taken.push(j);
                current = e;
                pred = next;
            }
            _ => break,
        }
    }
    (taken, (1.0 - current / base).max(0.0))
}

/// In-sample bin centres (mean key) and means of `r` by `bins`, bins with samples only.
fn curve(
    keys: &[f64],
    r: &[f64],
    bins: &[usize],
    pick: impl Fn(f64) -> bool,
) -> (Vec<f64>, Vec<f64>) {
    let (mut sk, mut sr, mut c) = ([0.0; BINS], [0.0; BINS], [0usize; BINS]);
    for ((&k, &v), &b) in keys.iter().zip(r).zip(bins) {
        if !pick(k) {
            continue;
        }
        if let (Some(sk), Some(sr), Some(c)) = (sk.get_mut(b), sr.get_mut(b), c.get_mut(b)) {
            *sk += k;
            *sr += v;
            *c += 1;
        }
    }
    (0..BINS)
        .filter(|&b| c.get(b).is_some_and(|&c| c > 0))
        .map(|b| (sk[b] / c[b] as f64, sr[b] / c[b] as f64))
        .unzip()
}

/// Strongest correlation that counts as a trend in words.
const TREND: f64 = 0.8;

/// The report's curves along `var` and how the residual moves along it, in words.
fn shape(
    var: Variable,
    keys: &[f64],
    r: &[f64],
    bins: &[usize],
    x_low: f64,
) -> (String, Vec<Curve>) {
    if var == Variable::XSgnV {
        // Against x per direction: |x·sgn v| is the distance from the stroke's lower end.
        let (kp, mp) = curve(keys, r, bins, |k| k > 0.0);
        let (kn, mn) = curve(keys, r, bins, |k| k < 0.0);
        let xp: Vec<f64> = kp.iter().map(|k| k + x_low).collect();
        let xn: Vec<f64> = kn.iter().map(|k| -k + x_low).collect();
        // Against the motion's sign, by distance from mid-stroke.
        let all_x: Vec<f64> = xp.iter().chain(&xn).copied().collect();
        let (lo, hi) = all_x
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(*x), b.max(*x))
            });
        let mid = 0.5 * (lo + hi);
        let dist: Vec<f64> = all_x.iter().map(|x| (x - mid).abs()).collect();
        let along: Vec<f64> = mp.iter().copied().chain(mn.iter().map(|m| -m)).collect();
        let r_mid = correlation(&dist, &along);
        let r_x = correlation(&all_x, &along);
        let words = if r_mid.abs() >= TREND && r_mid.abs() >= r_x.abs() {
            format!(
                "which grows with distance from mid-stroke while moving ({} the motion)",
                if r_mid > 0.0 { "with" } else { "against" }
            )
        } else if r_x.abs() >= TREND {
            format!(
                "which {} with position while moving ({} the motion)",
                if r_x > 0.0 { "rises" } else { "falls" },
                if r_x > 0.0 { "with" } else { "against" }
            )
        } else {
            format!("which follows {}", var.words())
        };
        return (
            words,
            vec![("moving +x".into(), xp, mp), ("moving −x".into(), xn, mn)],
        );
    }
    let (k, m) = curve(keys, r, bins, |_| true);
    let rr = correlation(&k, &m);
    let words = if rr.abs() >= TREND {
        format!(
            "which {} with {}",
            if rr > 0.0 { "rises" } else { "falls" },
            var.words()
        )
    } else {
        format!("which follows {}", var.words())
    };
    (words, vec![("residual".into(), k, m)])
}

/// Judges channel `ch`'s band-limited residuals `before` and `after` the fit (every sample,
/// [`super::residuals::full_of_raw`]) on the log `d`, with the augmented `model`.
pub fn judge(
    d: &Measured,
    band: &Band,
    model: &MachineModel,
    ch: ChannelId,
    before: &[f64],
    after: &[f64],
) -> Unexplained {
    let n = d.len();
    let samples = judged(band, ch, n);
    // Over every judged sample, as the channel's `rms_before` and `rms_after`.
    let rms_after = rms_of_full(d, band, ch, after);
    let rms_before = rms_of_full(d, band, ch, before);
    let model_floor = match ch {
        ChannelId::Pressure => in_band(model.sensors.pressure.noise_pa, d, band),
        _ => 0.0,
    };
    let noise_floor = floor_from_data(after, &samples, band.stride).max(model_floor);
    let x_low = samples
        .iter()
        .filter_map(|(_, i)| d.x_m.get(*i))
        .fold(f64::INFINITY, |a, x| a.min(*x));
    let x_low = if x_low.is_finite() { x_low } else { 0.0 };
    let y: Vec<f64> = samples
        .iter()
        .map(|(i, _)| after.get(*i).copied().unwrap_or(0.0))
        .collect();
    let fold: Vec<usize> = samples
        .iter()
        .map(|(_, row)| (row * BLOCKS / n.max(1)) % 2)
        .collect();
    let keys: Vec<Vec<f64>> = Variable::ALL
        .iter()
        .map(|v| {
            samples
                .iter()
                .map(|(_, row)| v.at(d, *row, x_low))
                .collect()
        })
        .collect();
    let binned = Binned::new(&keys);
    let (taken, share) = additive(&y, &fold, &binned);
    // Material, by the selection's yardstick: taking the structured part away would lower
    // the channel's RMS by what its sensors resolve.
    let material = rms_after * (1.0 - (1.0 - share).max(0.0).sqrt()) >= resolution(ch, model);
    let structured = share >= STRUCTURED_SHARE
        && share.sqrt() * rms_after >= FLOOR_MARGIN * noise_floor
        && material;
    let follows: Vec<Variable> = if structured {
        taken
            .iter()
            .filter_map(|&j| Variable::ALL.get(j).copied())
            .collect()
    } else {
        Vec::new()
    };
    let (shape, curves) = match (follows.first(), taken.first()) {
        (Some(&v), Some(&j)) => match (keys.get(j), binned.bins.get(j)) {
            (Some(k), Some(b)) => self::shape(v, k, &y, b, x_low),
            _ => (String::new(), Vec::new()),
        },
        _ => (String::new(), Vec::new()),
    };
    Unexplained {
        channel: ch,
        json: UnexplainedJson {
            rms: rms_after,
            noise_floor,
            structured_share: share,
            structured,
            follows: follows.iter().map(|v| v.name().to_string()).collect(),
            share_of_gap: if rms_before > 0.0 {
                (rms_after / rms_before).powi(2)
            } else {
                1.0
            },
        },
        follows,
        shape,
        curves,
    }
}

/// Noise floors above which a residual that follows no measured variable is still said to be
/// missed (something the model lacks that no smooth function of the variables describes).
pub const ABOVE_FLOOR: f64 = 2.0;

/// The judgement in words: "the model still misses 17.4 N RMS on the force (noise floor
/// 4.6 N), which grows with distance from mid-stroke while moving"; for a residual well above
/// its floor that follows no variable, that it is left unexplained and unstructured; else
/// that nothing structured is left.
pub fn sentence(u: &Unexplained, unit: &str) -> String {
    let j = &u.json;
    let eng = |v: f64| crate::console::eng(v, unit);
    if j.structured {
        format!(
            "the model still misses {} RMS on the {} (noise floor {}), {}",
            eng(j.rms),
            u.channel.name(),
            eng(j.noise_floor),
            u.shape
        )
    } else if j.rms > ABOVE_FLOOR * j.noise_floor {
        format!(
            "the model still misses {} RMS on the {} (noise floor {}), unexplained and \
             unstructured: no smooth function of the measured variables follows it",
            eng(j.rms),
            u.channel.name(),
            eng(j.noise_floor)
        )
    } else {
        format!(
            "nothing structured is left on the {}: {} RMS against a noise floor of {}",
            u.channel.name(),
            eng(j.rms),
            eng(j.noise_floor)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples in time order, half in each fold by blocks.
    fn folds(n: usize) -> Vec<usize> {
        (0..n).map(|i| (i * BLOCKS / n) % 2).collect()
    }

    /// A deterministic, nearly normal sequence of unit variance (the sum of six uniform
    /// draws in [−1, 1), each of variance 1/3, over √2).
    fn noise(n: usize, seed: u64) -> Vec<f64> {
        let mut s = seed;
        let mut uniform = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        (0..n)
            .map(|_| (0..6).map(|_| uniform()).sum::<f64>() / 2f64.sqrt())
            .collect()
    }

    /// A log of holds and moves: three quarters of the samples hold (the controller dithers
    /// the piston at 0.5 % of the peak speed) and carry unit noise alone, a quarter move and
    /// carry a force of 3 beside it. Over every sample the 3 is diluted to an RMS of 1.8;
    /// where the piston moves it reads √10.
    #[test]
    fn what_is_left_where_the_piston_moves_leaves_the_holds_out() {
        let n = 8000;
        let e = noise(n, 5);
        let peak = 1.2;
        let samples: Vec<(f64, f64)> = (0..n)
            .map(|i| {
                let phase = i as f64 * 0.01;
                if i % 4 == 0 {
                    (peak * phase.sin().signum().max(0.1), 3.0 + e[i])
                } else {
                    (0.006 * phase.sin(), e[i])
                }
            })
            .collect();
        let all = (samples.iter().map(|(_, r)| r * r).sum::<f64>() / n as f64).sqrt();
        let moving = rms_where_moving(samples.iter().copied(), peak);
        assert!((all - 1.8).abs() < 0.1, "{all}");
        assert!((moving - 10f64.sqrt()).abs() < 0.1, "{moving}");
        assert_eq!(rms_where_moving(samples.iter().copied(), 1e3), 0.0);
    }

    #[test]
    fn noise_alone_is_not_structured_and_a_function_of_a_variable_is() {
        let n = 4000;
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
        let binned = Binned::new(&[x.clone(), t]);
        let e = noise(n, 7);
        let (taken, share) = additive(&e, &folds(n), &binned);
        assert!(taken.is_empty() && share < 0.02, "{taken:?} {share}");
        let y: Vec<f64> = x.iter().zip(&e).map(|(x, e)| 3.0 * x * x + e).collect();
        let (taken, share) = additive(&y, &folds(n), &binned);
        assert_eq!(taken.first(), Some(&0), "{taken:?}");
        assert!(share > 0.5, "{share}");
    }

    /// Friction growing along the bore, `k·|x − x₀|` against the motion, on strokes that
    /// visit different positions in the even and the odd time blocks (as holds and moves
    /// do): followed by `x·sgn v` first, out of sample, and more closely than by `sgn v`.
    #[test]
    fn friction_along_the_bore_follows_position_by_direction_where_the_folds_visit_apart() {
        let n = 4000;
        let (k, x0) = (700.0, 0.05);
        let (mut x, mut v) = (Vec::new(), Vec::new());
        for i in 0..n {
            let block = i * BLOCKS / n;
            // Even blocks stroke over 0–80 mm, odd blocks over 20–100 mm.
            let low = if block.is_multiple_of(2) { 0.0 } else { 0.02 };
            let phase = i as f64 * 0.05;
            x.push(low + 0.04 * (1.0 - phase.cos()));
            v.push(0.04 * phase.sin());
        }
        let sgn: Vec<f64> = v.iter().map(|v| v.signum()).collect();
        let x_low = x.iter().fold(f64::INFINITY, |a, x| a.min(*x));
        let xs: Vec<f64> = x.iter().zip(&sgn).map(|(x, s)| (x - x_low) * s).collect();
        let abs_v: Vec<f64> = v.iter().map(|v| v.abs()).collect();
        let e = noise(n, 11);
        let y: Vec<f64> = x
            .iter()
            .zip(&sgn)
            .zip(&e)
            .map(|((x, s), e)| -k * (x - x0).abs() * s + e)
            .collect();
        let binned = Binned::new(&[x, v, abs_v, sgn, xs]);
        let folds = folds(n);
        let (taken, share) = additive(&y, &folds, &binned);
        assert_eq!(taken.first(), Some(&4), "{taken:?} {share}");
        assert!(share > 0.8, "{share}");
        let sgn_only = Binned {
            bins: vec![binned.bins[3].clone()],
            splits: vec![0],
        };
        let (_, by_sign) = additive(&y, &folds, &sgn_only);
        assert!(
            share > by_sign + 0.1,
            "{share} against {by_sign} by sgn v alone"
        );
    }

    /// A function of position where one fold visits the lowest positions once, in a single
    /// sample far off the function (a start from a hold): that bin's mean in the fold is the
    /// sample's, not the function's, so it is not carried to the other fold's many samples
    /// there, and the residual is still found following position.
    #[test]
    fn a_bin_one_fold_barely_visits_does_not_carry_its_moment_to_the_other() {
        let n = 4000;
        let folds = folds(n);
        let e = noise(n, 5);
        let x: Vec<f64> = (0..n)
            .map(|i| {
                let u = (i as f64 * 0.618_034).fract();
                // The even fold dwells near 0, so that the lowest bin is all its own; the odd
                // fold strokes over 0.1–1 but once, at its first sample, sits at 0.01.
                match folds[i] {
                    0 => u * u,
                    _ if i == n / BLOCKS => 0.01,
                    _ => 0.1 + 0.9 * u,
                }
            })
            .collect();
        let y: Vec<f64> = (0..n)
            .map(|i| {
                if i == n / BLOCKS {
                    60.0
                } else {
                    10.0 * x[i] + e[i]
                }
            })
            .collect();
        let binned = Binned::new(&[x]);
        let (taken, share) = additive(&y, &folds, &binned);
        assert_eq!(taken.first(), Some(&0), "{taken:?} {share}");
        assert!(share > 0.5, "{share}");
    }

    #[test]
    fn the_signed_keys_bins_never_mix_the_directions() {
        let keys: Vec<f64> = (0..1000).map(|i| (i as f64 - 300.0) * 1e-4).collect();
        let (e, split) = signed_edges(&keys);
        assert!(e.windows(2).all(|w| w[0] < w[1]), "{e:?}");
        assert!(e.len() < BINS, "{e:?}");
        for k in keys {
            let b = e.partition_point(|x| *x <= k);
            assert_eq!(k < 0.0, b < split, "{k} in bin {b}, split {split}");
        }
    }

    #[test]
    fn the_floor_from_the_data_reads_the_noise_not_a_slow_trend() {
        let n = 4000;
        let e = noise(n, 3);
        // Unit noise, and a slow sine ten times larger on top.
        let r: Vec<f64> = e
            .iter()
            .enumerate()
            .map(|(i, e)| e + 10.0 * (i as f64 * 0.002).sin())
            .collect();
        let samples: Vec<(usize, usize)> = (0..n).map(|i| (i, i)).collect();
        let f = floor_from_data(&r, &samples, 1);
        assert!((f - 1.0).abs() < 0.1, "{f} against 1");
    }
}
