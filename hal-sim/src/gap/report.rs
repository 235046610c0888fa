//! Where the model and the run disagree, and what adding the effects changed: residual maps
//! (binned means), lags by FFT cross-correlation, and the report in `--out` — Markdown and
//! HTML ([`super::page`]) with SVG plots (residual maps, before/after overlays, the p–V
//! replay).

use crate::console::{eng, eng_pm, Num};
use rayon::prelude::*;
use std::path::Path;

use crate::plant::model::MachineModel;
use crate::plot::{lines, panels, Axes, Panel, Series};

use super::channel::ChannelId;
use super::ctx::Ctx;
use super::effects::{acting_force_lag, slave_force_lag};
use super::page::Block;
use super::replay::kept_replay;
use super::uncertainty::{fitted, key_unit};
use super::{ChannelResiduals, GapOutcome};

/// Bins of a residual map.
pub const BINS: usize = 24;

/// What a map bins the residual by.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapBy {
    /// Position, m.
    Position,
    /// Position modulo the pole pitch, m.
    PolePitch,
    /// Position modulo the N–N pitch (twice the pole pitch), m.
    NnPitch,
    /// Velocity (signed), m/s.
    Velocity,
    /// Acceleration, m/s².
    Acceleration,
    /// Pressure difference p_A − p_B, Pa.
    PressureDifference,
}

impl MapBy {
    /// Every map.
    pub const ALL: [MapBy; 6] = [
        MapBy::Position,
        MapBy::PolePitch,
        MapBy::NnPitch,
        MapBy::Velocity,
        MapBy::Acceleration,
        MapBy::PressureDifference,
    ];

    /// Label with the unit the plots use (`docs/fpc-sim.md`, "Plots"), and the factor from
    /// SI to it.
    pub fn label(self) -> (&'static str, f64) {
        match self {
            MapBy::Position => ("x, mm", 1e3),
            MapBy::PolePitch => ("x mod pole pitch, mm", 1e3),
            MapBy::NnPitch => ("x mod N–N pitch, mm", 1e3),
            MapBy::Velocity => ("v, m/s", 1.0),
            MapBy::Acceleration => ("a, m/s²", 1.0),
            MapBy::PressureDifference => ("p_A − p_B, kPa", 1e-3),
        }
    }

    fn slug(self) -> &'static str {
        match self {
            MapBy::Position => "x",
            MapBy::PolePitch => "x_mod_pole",
            MapBy::NnPitch => "x_mod_nn",
            MapBy::Velocity => "v",
            MapBy::Acceleration => "a",
            MapBy::PressureDifference => "dp",
        }
    }
}

/// The unit a channel's residual is plotted in (`docs/fpc-sim.md`, "Plots"), and the factor
/// from SI to it: forces in N, position errors in µm, pressures in kPa.
fn plot_unit(ch: ChannelId) -> (&'static str, f64) {
    match ch {
        ChannelId::Force | ChannelId::SlaveForce => ("N", 1.0),
        ChannelId::Encoder => ("µm", 1e6),
        ChannelId::Pressure => ("kPa", 1e-3),
    }
}

/// A residual map: bin centres, mean residual per bin, and the share of the residual's
/// variance the bin means explain (near 0: no structure along this variable).
#[derive(Clone, Debug, PartialEq)]
pub struct Map {
    /// By what.
    pub by: MapBy,
    /// Bin centres.
    pub centres: Vec<f64>,
    /// Mean residual in each bin (NaN where empty).
    pub means: Vec<f64>,
    /// Variance share explained by the bin means.
    pub structure: f64,
}

/// Bins `resid` (judged where `mask > 0`) by `key`.
pub fn map(by: MapBy, key: &[f64], resid: &[f64], mask: &[f64], range: (f64, f64)) -> Map {
    let (lo, hi) = range;
    let width = (hi - lo) / BINS as f64;
    let mut sum = [0.0; BINS];
    let mut cnt = [0usize; BINS];
    let (mut total, mut total_sq, mut n) = (0.0, 0.0, 0usize);
    for ((k, r), w) in key.iter().zip(resid).zip(mask) {
        if *w <= 0.0 || width.is_nan() || width <= 0.0 {
            continue;
        }
        let b = ((k - lo) / width).floor();
        if b < 0.0 || b >= BINS as f64 {
            continue;
        }
        let b = b as usize;
        if let (Some(s), Some(c)) = (sum.get_mut(b), cnt.get_mut(b)) {
            *s += r;
            *c += 1;
        }
        total += r;
        total_sq += r * r;
        n += 1;
    }
    let means: Vec<f64> = sum
        .iter()
        .zip(&cnt)
        .map(|(s, &c)| if c > 0 { s / c as f64 } else { f64::NAN })
        .collect();
    let mean = if n > 0 { total / n as f64 } else { 0.0 };
    let var = if n > 0 {
        total_sq / n as f64 - mean * mean
    } else {
        0.0
    };
    let between: f64 = means
        .iter()
        .zip(&cnt)
        .filter(|(m, _)| m.is_finite())
        .map(|(m, &c)| c as f64 * (m - mean) * (m - mean))
        .sum::<f64>()
        / n.max(1) as f64;
    Map {
        by,
        centres: (0..BINS).map(|i| lo + width * (i as f64 + 0.5)).collect(),
        means,
        structure: if var > 0.0 {
            (between / var).clamp(0.0, 1.0)
        } else {
            0.0
        },
    }
}

/// The keys of every map for the samples of one channel half (pressure: per chamber).
fn keys(ctx: &Ctx<'_>, model: &MachineModel, by: MapBy) -> (Vec<f64>, (f64, f64)) {
    let d = ctx.data;
    let range = |v: &[f64]| {
        let (lo, hi) = v
            .iter()
            .zip(&d.inner)
            .filter(|(_, w)| **w > 0.0)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), (x, _)| {
                (a.min(*x), b.max(*x))
            });
        if lo.is_finite() && hi > lo {
            (lo, hi + 1e-12 * (hi - lo).abs().max(1.0))
        } else {
            (0.0, 1.0)
        }
    };
    let pole = model.motor.pole_pitch_m;
    match by {
        MapBy::Position => (d.x_m.clone(), range(&d.x_m)),
        MapBy::PolePitch => (
            d.x_m.iter().map(|x| x.rem_euclid(pole)).collect(),
            (0.0, pole),
        ),
        MapBy::NnPitch => (
            d.x_m.iter().map(|x| x.rem_euclid(2.0 * pole)).collect(),
            (0.0, 2.0 * pole),
        ),
        MapBy::Velocity => (d.v_mps.clone(), range(&d.v_mps)),
        MapBy::Acceleration => (d.a_mps2.clone(), range(&d.a_mps2)),
        MapBy::PressureDifference => {
            let dp: Vec<f64> = d.p_a_pa.iter().zip(&d.p_b_pa).map(|(a, b)| a - b).collect();
            let r = range(&dp);
            (dp, r)
        }
    }
}

/// Maps of one channel's band-limited residual `full` (pressure: A's half then B's).
pub fn maps(ctx: &Ctx<'_>, model: &MachineModel, ch: ChannelId, full: &[f64]) -> Vec<Map> {
    let n = ctx.data.len();
    let mask = ctx.band.mask(ctx.data, ch);
    MapBy::ALL
        .iter()
        .map(|&by| {
            let (key, range) = keys(ctx, model, by);
            if ch == ChannelId::Pressure {
                // Both chambers on one map: keys repeat for B's half.
                let key2: Vec<f64> = key.iter().chain(key.iter()).copied().collect();
                let mask2: Vec<f64> = mask.iter().chain(mask.iter()).copied().collect();
                map(by, &key2, full, &mask2, range)
            } else {
                map(by, &key, full.get(..n).unwrap_or(full), mask, range)
            }
        })
        .collect()
}

/// Writes the report into `dir`: `report.md` and `report.html` (the same blocks, the plots
/// embedded) and the SVG plots — residual maps, before/after overlays, the p–V replay.
pub fn write(dir: &Path, out: &GapOutcome) -> Result<(), String> {
    let ctx = Ctx {
        data: &out.measured,
        band: &out.band,
    };
    // The sections read the outcome and write files of their own: made on every core,
    // placed in order.
    let ((left, lags), (maps, pv)) = rayon::join(
        || rayon::join(|| what_is_left(dir, out), || candidates_and_lags(&ctx, out)),
        || rayon::join(|| maps_and_overlays(dir, &ctx, out), || pv_replay(dir, out)),
    );
    let mut blocks = summary(out);
    blocks.extend(effect_tables(out));
    blocks.extend(left?);
    blocks.extend(lags);
    if !out.json.warnings.is_empty() {
        blocks.push(Block::Heading(2, "Warnings".into()));
        blocks.push(Block::List(out.json.warnings.clone()));
    }
    blocks.extend(maps?);
    blocks.extend(pv?);
    blocks.push(Block::Para(
        "Maps: `map_<channel>_<variable>.svg`. Augmented model: `model.toml`.".into(),
    ));
    let md = super::page::markdown(&blocks);
    std::fs::write(dir.join("report.md"), md)
        .map_err(|e| format!("cannot write {}: {e}", dir.join("report.md").display()))?;
    let html = super::page::html("Model-gap report", &blocks);
    std::fs::write(dir.join("report.html"), html)
        .map_err(|e| format!("cannot write {}: {e}", dir.join("report.html").display()))
}

/// The run's figures and each channel's RMS before and after.
fn summary(out: &GapOutcome) -> Vec<Block> {
    let d = &out.measured;
    let mut blocks = vec![
        Block::Heading(1, "Model-gap report".into()),
        Block::Para(format!(
            "{} samples at {:.0} Hz ({:.2} s); differentiator window {} samples (centred); \
             analysis band 0–{:.0} Hz; ports: {}.",
            d.len(),
            d.sample_rate_hz(),
            d.dt_s * d.len() as f64,
            d.sg_window,
            out.band.band_hz,
            match d.ports {
                super::data::PortsMeta::Open => "open",
                super::data::PortsMeta::Closed => "closed",
                super::data::PortsMeta::Unknown => "not stated",
            }
        )),
        Block::Heading(2, "Channels (band-limited residual RMS)".into()),
    ];
    let rows = out
        .json
        .channels
        .iter()
        .map(|c| {
            let change = if c.rms_before > 0.0 {
                format!("{:+.0} %", Num(100.0 * (c.rms_after / c.rms_before - 1.0)))
            } else {
                "—".into()
            };
            vec![
                c.name.clone(),
                c.unit.clone(),
                format!("{:.4e}", Num(c.rms_before)),
                format!("{:.4e}", Num(c.rms_after)),
                change,
            ]
        })
        .collect();
    blocks.push(table(
        &["channel", "unit", "before", "after", "change"],
        rows,
    ));
    blocks
}

/// What the augmented model still misses per channel ([`super::unexplained`]): in words, as
/// a table, and each structured residual drawn against the variable it follows.
fn what_is_left(dir: &Path, out: &GapOutcome) -> Result<Vec<Block>, String> {
    let mut blocks = vec![Block::Heading(2, "What is left".into())];
    let mut said = Vec::new();
    let mut rows = Vec::new();
    let mut images = Vec::new();
    for u in &out.unexplained {
        let j = &u.json;
        let ch = u.channel;
        said.push(super::unexplained::sentence(u, ch.unit()));
        rows.push(vec![
            ch.name().to_string(),
            eng(j.rms, ch.unit()),
            eng(j.noise_floor, ch.unit()),
            format!("{:.2}", Num(j.structured_share)),
            if j.structured { "yes" } else { "no" }.into(),
            j.follows.join(", "),
            format!("{:.2}", Num(j.share_of_gap)),
        ]);
        let file = format!("left_{}.svg", ch.name());
        let Some(var) = u.follows.first() else {
            // A plot an earlier analysis left in the directory would describe another model.
            match std::fs::remove_file(dir.join(&file)) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(format!("cannot remove {}: {e}", dir.join(&file).display()))
                }
                _ => {}
            }
            continue;
        };
        let (res_unit, res_k) = plot_unit(ch);
        let scaled: Vec<super::unexplained::Curve> = u
            .curves
            .iter()
            .map(|(label, k, m)| {
                let kk = if *var == super::unexplained::Variable::XSgnV
                    || *var == super::unexplained::Variable::X
                {
                    k.iter().map(|v| v * 1e3).collect()
                } else {
                    k.clone()
                };
                (label.clone(), kk, m.iter().map(|v| v * res_k).collect())
            })
            .collect();
        let series: Vec<Series<'_>> = scaled
            .iter()
            .map(|(label, k, m)| Series::new(label, k, m))
            .collect();
        let x_label = match var {
            super::unexplained::Variable::XSgnV | super::unexplained::Variable::X => {
                "x, mm".to_string()
            }
            v => format!("{} (SI)", v.name()),
        };
        lines(
            &dir.join(&file),
            &format!("{} residual left, by {}", ch.name(), var.name()),
            &x_label,
            &format!("mean residual, {res_unit}"),
            &series,
        )?;
        images.push((
            format!("{} residual left by {}", ch.name(), var.name()),
            file,
        ));
    }
    blocks.push(Block::List(said));
    blocks.push(table(
        &[
            "channel",
            "RMS left",
            "noise floor",
            "structured share",
            "structured",
            "follows",
            "RMS² after / before",
        ],
        rows,
    ));
    if !images.is_empty() {
        blocks.push(Block::Images(images));
    }
    Ok(blocks)
}

/// A fitted parameter as the report writes it: rounded to its uncertainty (`amplitude_n =
/// 45.1 ± 0.2 N`); one set rather than fitted, held at zero, or without an uncertainty says
/// so.
fn param_cell(key: &str, value: f64, sigma: Option<f64>) -> String {
    let unit = key_unit(key);
    match sigma {
        Some(s) => format!("{key} = {}", eng_pm(value, s, unit)),
        None if !fitted(key) => format!("{key} = {} (set, not fitted)", eng(value, unit)),
        None if value == 0.0 => format!("{key} = 0 {unit} (held at its bound)"),
        None => format!("{key} = {} (uncertainty not known)", eng(value, unit)),
    }
}

/// A table block from string headers.
fn table(head: &[&str], rows: Vec<Vec<String>>) -> Block {
    Block::Table {
        head: head.iter().map(|h| h.to_string()).collect(),
        rows,
    }
}

/// The effects added and the discovered terms.
fn effect_tables(out: &GapOutcome) -> Vec<Block> {
    let mut blocks = vec![Block::Heading(
        2,
        "Effects added (most significant first)".into(),
    )];
    if out.json.effects.is_empty() {
        blocks.push(Block::Para(
            "None: nothing significant is missing from the model.".into(),
        ));
    } else {
        let rows = out
            .json
            .effects
            .iter()
            .map(|e| {
                let params: Vec<String> = e
                    .params
                    .iter()
                    .map(|(k, v)| param_cell(k, *v, e.uncertainty.get(k).copied()))
                    .collect();
                vec![
                    e.name.clone(),
                    e.channel.clone(),
                    params.join(", "),
                    format!("{:.4e}", Num(e.rms_before)),
                    format!("{:.4e}", Num(e.rms_after)),
                    format!("{:.0}", Num(e.delta_bic)),
                    format!("{:.0} %", Num(100.0 * e.explained)),
                ]
            })
            .collect();
        blocks.push(table(
            &[
                "effect",
                "channel",
                "parameters",
                "RMS before",
                "RMS after",
                "ΔBIC",
                "explained",
            ],
            rows,
        ));
    }
    blocks.push(Block::Heading(
        2,
        "Discovered terms (a force no named effect describes, `[effects.extra_force]`)".into(),
    ));
    if out.json.discovered.is_empty() {
        blocks.push(Block::Para(
            "None: no force is left that the basis describes.".into(),
        ));
        return blocks;
    }
    let rows = out
        .json
        .discovered
        .iter()
        .map(|d| {
            let mut terms: Vec<String> = d
                .terms
                .iter()
                .map(|(k, v)| format!("`{k}` = {:.5}", Num(*v)))
                .collect();
            if let Some(p) = d.period_m {
                terms.push(format!("period_m = {:.5}", Num(p)));
            }
            vec![
                d.channel.clone(),
                terms.join(", "),
                d.reading.clone(),
                format!("{:.4e}", Num(d.rms_before)),
                format!("{:.4e}", Num(d.rms_after)),
                format!("{:.1} %", Num(100.0 * d.explained)),
            ]
        })
        .collect();
    blocks.push(table(
        &[
            "channel",
            "terms (SI)",
            "reading",
            "RMS before",
            "RMS after",
            "explained",
        ],
        rows,
    ));
    blocks.push(Block::Para(
        "The force maps below (`map_force_*`) show the residual with and without them.".into(),
    ));
    blocks
}

/// Every candidate judged at the first step, and the lags by FFT cross-correlation.
fn candidates_and_lags(ctx: &Ctx<'_>, out: &GapOutcome) -> Vec<Block> {
    let rows = out
        .selection
        .first_step
        .iter()
        .map(|j| {
            let fitted: Vec<String> = j
                .proposal
                .params
                .iter()
                .map(|(k, v)| format!("{k} = {:.4e}", Num(*v)))
                .collect();
            vec![
                j.proposal.kind.name().into(),
                // The channel it was judged on (a sealed chamber's transducer gain: the force).
                j.proposal.kind.judged_on(ctx.data).name().into(),
                fitted.join(", "),
                format!("{:.1}", Num(j.delta_bic)),
                format!("{:.1} %", Num(100.0 * j.explained_total)),
                format!("{:.1} %", Num(100.0 * j.explained)),
                j.support.to_string(),
                format!(
                    "{:.2}",
                    Num(j.change_rms / j.resolution.max(f64::MIN_POSITIVE))
                ),
                if j.significant() { "yes" } else { "no" }.into(),
            ]
        })
        .collect();
    let mut blocks = vec![
        Block::Heading(2, "Every candidate at the first step".into()),
        table(
            &[
                "candidate",
                "channel",
                "fitted",
                "ΔBIC",
                "explained (all)",
                "explained where it acts",
                "acts on (kept samples)",
                "change RMS where it acts / resolution",
                "significant",
            ],
            rows,
        ),
        Block::Heading(2, "Lags (FFT cross-correlation)".into()),
    ];
    let d = &out.measured;
    // The three cross-correlations are independent: computed side by side.
    let docs = [
        ("input model", &out.input),
        ("augmented model", &out.selection.doc),
    ];
    let (slave, acting) = rayon::join(
        || slave_force_lag(d),
        || {
            docs.par_iter()
                .map(|(label, doc)| (*label, acting_force_lag(ctx, doc)))
                .collect::<Vec<_>>()
        },
    );
    let mut rows = Vec::new();
    if let Some(l) = slave {
        rows.push(vec![
            "slave force behind master force".into(),
            format!("{:.4}", Num(l.seconds * 1e3)),
            format!("{:.3}", Num(l.correlation)),
        ]);
    }
    for (label, lag) in acting {
        if let Some(l) = lag {
            rows.push(vec![
                format!("acting force behind reported force ({label})"),
                format!("{:.4}", Num(l.seconds * 1e3)),
                format!("{:.3}", Num(l.correlation)),
            ]);
        }
    }
    blocks.push(table(&["what", "lag, ms", "correlation"], rows));
    blocks
}

/// The residual maps (share of each channel's variance its mean along each variable
/// explains, before → after; each map embedded) and the before/after overlays in time.
fn maps_and_overlays(dir: &Path, ctx: &Ctx<'_>, out: &GapOutcome) -> Result<Vec<Block>, String> {
    let before = out.input.model()?;
    let after = out.selection.doc.model()?;
    // Each channel's maps are independent: computed on every core, written in order.
    let computed: Vec<_> = out
        .filtered
        .par_iter()
        .map(|c| {
            let (mb, ma) = rayon::join(
                || maps(ctx, &before, c.channel, &c.before),
                || maps(ctx, &after, c.channel, &c.after),
            );
            (c, mb, ma)
        })
        .collect();
    let map_file =
        |c: &ChannelResiduals, m: &Map| format!("map_{}_{}.svg", c.channel.name(), m.by.slug());
    let overlay_file = |c: &ChannelResiduals| format!("overlay_{}.svg", c.channel.name());
    // Every plot is a file of its own: drawn on every core.
    computed.par_iter().try_for_each(|(c, mb, ma)| {
        mb.par_iter()
            .zip(ma)
            .try_for_each(|(b, a)| map_plot(&dir.join(map_file(c, b)), c.channel, b, a))?;
        overlay_plot(&dir.join(overlay_file(c)), ctx.data, c)
    })?;
    let mut rows = Vec::new();
    let mut images = Vec::new();
    for (c, mb, ma) in &computed {
        let cells: Vec<String> = std::iter::once(c.channel.name().to_string())
            .chain(
                mb.iter()
                    .zip(ma)
                    .map(|(b, a)| format!("{:.2} → {:.2}", Num(b.structure), Num(a.structure))),
            )
            .collect();
        rows.push(cells);
        let mut files: Vec<(String, String)> = mb
            .iter()
            .map(|b| {
                (
                    format!("{} by {}", c.channel.name(), b.by.label().0),
                    map_file(c, b),
                )
            })
            .collect();
        files.push((format!("{} overlay", c.channel.name()), overlay_file(c)));
        images.push(files);
    }
    let mut blocks = vec![
        Block::Heading(2, "Residual maps".into()),
        Block::Para(
            "Share of each channel's residual variance explained by its mean along each \
             variable (input model → augmented model); the input model solid, the augmented \
             model dashed."
                .into(),
        ),
        table(
            &[
                "channel",
                "x",
                "x mod pole",
                "x mod N–N",
                "v",
                "a",
                "p_A − p_B",
            ],
            rows,
        ),
    ];
    for ((c, _, _), files) in computed.iter().zip(images) {
        blocks.push(Block::Heading(3, c.channel.name().to_string()));
        blocks.push(Block::Images(files));
    }
    Ok(blocks)
}

/// One residual map, input model solid and augmented model dashed over it.
fn map_plot(path: &Path, ch: ChannelId, b: &Map, a: &Map) -> Result<(), String> {
    let keep = |m: &Map| -> (Vec<f64>, Vec<f64>) {
        m.centres
            .iter()
            .zip(&m.means)
            .filter(|(_, v)| v.is_finite())
            .map(|(c, v)| (*c, *v))
            .unzip()
    };
    let (res_unit, res_k) = plot_unit(ch);
    let (by_label, by_k) = b.by.label();
    let scale = |v: Vec<f64>, k: f64| -> Vec<f64> { v.into_iter().map(|v| v * k).collect() };
    let (xb, yb) = keep(b);
    let (xa, ya) = keep(a);
    let (xb, yb, xa, ya) = (
        scale(xb, by_k),
        scale(yb, res_k),
        scale(xa, by_k),
        scale(ya, res_k),
    );
    lines(
        path,
        &format!("{} residual by {}", ch.name(), by_label),
        by_label,
        &format!("mean residual, {res_unit}"),
        &[
            Series::new("input model", &xb, &yb),
            Series::new("augmented model", &xa, &ya).dashed(),
        ],
    )
}

/// A channel's band-limited residual in time, the input model solid and the augmented model
/// dashed over it (as the maps: `docs/gap.md`).
fn overlay_plot(
    path: &Path,
    d: &super::data::Measured,
    c: &ChannelResiduals,
) -> Result<(), String> {
    let n = d.len();
    let (res_unit, res_k) = plot_unit(c.channel);
    let in_unit = |v: &[f64]| -> Vec<f64> { v.iter().map(|v| v * res_k).collect() };
    let (yb, ya) = (
        in_unit(c.before.get(..n).unwrap_or(&c.before)),
        in_unit(c.after.get(..n).unwrap_or(&c.after)),
    );
    lines(
        path,
        &format!(
            "{} residual (band-limited){}",
            c.channel.name(),
            if c.channel == ChannelId::Pressure {
                ", chamber A"
            } else {
                ""
            }
        ),
        "t, s",
        &format!("residual, {res_unit}"),
        &[
            Series::new("input model", &d.t_s, &yb),
            Series::new("augmented model", &d.t_s, &ya).dashed(),
        ],
    )
}

/// One p–V panel's series: the measured pressure (if `measured`), the input model's replay
/// `first` dashed, and the augmented model's `second` where it differs.
fn pv_series<'a>(
    model_label: &'a str,
    differ: bool,
    v: &'a [f64],
    measured: Option<&'a [f64]>,
    first: &'a [f64],
    second: &'a [f64],
) -> Vec<Series<'a>> {
    let mut s = Vec::new();
    if let Some(m) = measured {
        s.push(Series::new("measured", v, m).colour(6));
    }
    let line = Series::new(model_label, v, first).colour(0);
    s.push(if measured.is_some() {
        line.dashed()
    } else {
        line
    });
    if differ {
        s.push(Series::new("augmented model", v, second).dashed().colour(1));
    }
    s
}

/// The p–V replay of a port-state log: each chamber's measured pressure against its volume
/// with the input model's replay dashed over it (and the augmented model's where it differs:
/// three equal traces drawn over each other show one), and what the replay misses against
/// the volume beneath it, where a difference of a few hundred pascals shows.
fn pv_replay(dir: &Path, out: &GapOutcome) -> Result<Vec<Block>, String> {
    let d = &out.measured;
    let before = out.input.model()?;
    let after = out.selection.doc.model()?;
    let (Some(kept0), Some(kept1)) =
        rayon::join(|| kept_replay(d, &before), || kept_replay(d, &after))
    else {
        return Ok(Vec::new());
    };
    let ([pa0, pb0], [pa1, pb1]) = (kept0.as_slice(), kept1.as_slice()) else {
        return Ok(Vec::new());
    };
    let cyl = after.cylinder();
    let k = |v: &[f64], k: f64| -> Vec<f64> { v.iter().map(|v| v * k).collect() };
    let va: Vec<f64> = d.x_m.iter().map(|&x| cyl.volume_a_m3(x) * 1e6).collect();
    let vb: Vec<f64> = d.x_m.iter().map(|&x| cyl.volume_b_m3(x) * 1e6).collect();
    let differ = pa0 != pa1 || pb0 != pb1;
    let miss = |m: &[f64], r: &[f64]| -> Vec<f64> {
        m.iter().zip(r).map(|(m, r)| (m - r) * 1e-3).collect()
    };
    let (ma, mb) = (k(&d.p_a_pa, 1e-3), k(&d.p_b_pa, 1e-3));
    let (ra0, rb0) = (k(pa0, 1e-3), k(pb0, 1e-3));
    let (ea0, eb0) = (miss(&d.p_a_pa, pa0), miss(&d.p_b_pa, pb0));
    let (ra1, rb1, ea1, eb1) = if differ {
        (
            k(pa1, 1e-3),
            k(pb1, 1e-3),
            miss(&d.p_a_pa, pa1),
            miss(&d.p_b_pa, pb1),
        )
    } else {
        Default::default()
    };
    let model_label = if differ {
        "input model"
    } else {
        "model (input = augmented)"
    };
    let chamber = |v, m, r0, r1| pv_series(model_label, differ, v, Some(m), r0, r1);
    let misses = |v, e0, e1| pv_series(model_label, differ, v, None, e0, e1);
    panels(
        &dir.join("pv_replay.svg"),
        "p-V: measured and replayed along the measured motion",
        "V, cm³",
        &[
            Panel {
                y_label: "chamber A: p, kPa",
                series: chamber(&va, &ma, &ra0, &ra1),
                axes: Axes::default(),
            },
            Panel {
                y_label: "A: measured − replay, kPa",
                series: misses(&va, &ea0, &ea1),
                axes: Axes::default(),
            },
            Panel {
                y_label: "chamber B: p, kPa",
                series: chamber(&vb, &mb, &rb0, &rb1),
                axes: Axes::default(),
            },
            Panel {
                y_label: "B: measured − replay, kPa",
                series: misses(&vb, &eb0, &eb1),
                axes: Axes::default(),
            },
        ],
    )?;
    Ok(vec![
        Block::Heading(2, "p–V replay".into()),
        Block::Images(vec![("p-V replay".into(), "pv_replay.svg".into())]),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plot::Stroke;

    /// (label, stroke) of each series, in drawing order.
    fn drawn(s: &[Series<'_>]) -> Vec<(String, Stroke)> {
        s.iter().map(|s| (s.label.to_string(), s.stroke)).collect()
    }

    #[test]
    fn a_pv_panel_draws_one_replay_when_both_models_give_the_same() {
        let (v, m, r) = ([1.0, 2.0], [3.0, 4.0], [3.5, 4.5]);
        let same = pv_series("model (input = augmented)", false, &v, Some(&m), &r, &r);
        assert_eq!(
            drawn(&same),
            vec![
                ("measured".into(), Stroke::Solid),
                ("model (input = augmented)".into(), Stroke::Dashed),
            ]
        );
        let r2 = [3.6, 4.6];
        let differ = pv_series("input model", true, &v, Some(&m), &r, &r2);
        assert_eq!(
            drawn(&differ),
            vec![
                ("measured".into(), Stroke::Solid),
                ("input model".into(), Stroke::Dashed),
                ("augmented model".into(), Stroke::Dashed),
            ]
        );
        // The three keep their colours apart, so the dashed two stay distinguishable.
        let colours: Vec<_> = differ.iter().map(|s| s.colour).collect();
        assert_eq!(colours, vec![Some(6), Some(0), Some(1)]);
        // The misses panel (no measured trace): the input model's line solid under the dashed
        // augmented model.
        let misses = pv_series("input model", true, &v, None, &r, &r2);
        assert_eq!(
            drawn(&misses),
            vec![
                ("input model".into(), Stroke::Solid),
                ("augmented model".into(), Stroke::Dashed),
            ]
        );
    }
}
