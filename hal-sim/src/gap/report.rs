//! Where the model and the run disagree, and what adding the effects changed: residual maps
//! (binned means), lags by FFT cross-correlation, and the report in `--out` — Markdown with
//! SVG plots (residual maps, before/after overlays, the p–V replay).

use crate::console::Num;
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

use crate::plant::model::MachineModel;
use crate::plot::{lines, panels, Axes, Panel, Series};

use super::effects::{acting_force_lag, slave_force_lag, Ctx};
use super::residuals::{replay_pressures, ChannelId};
use super::GapOutcome;

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

/// Writes the report (`report.md` and SVGs) into `dir`.
pub fn write(dir: &Path, out: &GapOutcome) -> Result<(), String> {
    let ctx = Ctx {
        data: &out.measured,
        band: &out.band,
    };
    let d = &out.measured;
    let before = out.input.model()?;
    let after = out.selection.doc.model()?;
    let mut md = String::new();
    let _ = writeln!(md, "# Model-gap report\n");
    let _ = writeln!(
        md,
        "{} samples at {:.0} Hz ({:.2} s); differentiator window {} samples (centred); \
         analysis band 0–{:.0} Hz; ports: {}.\n",
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
    );
    let _ = writeln!(md, "## Channels (band-limited residual RMS)\n");
    let _ = writeln!(
        md,
        "| channel | unit | before | after | change |\n|---|---|---|---|---|"
    );
    for c in &out.json.channels {
        let change = if c.rms_before > 0.0 {
            format!("{:+.0} %", Num(100.0 * (c.rms_after / c.rms_before - 1.0)))
        } else {
            "—".into()
        };
        let _ = writeln!(
            md,
            "| {} | {} | {:.4e} | {:.4e} | {change} |",
            c.name,
            c.unit,
            Num(c.rms_before),
            Num(c.rms_after)
        );
    }
    let _ = writeln!(md, "\n## Effects added (most significant first)\n");
    if out.json.effects.is_empty() {
        let _ = writeln!(md, "None: nothing significant is missing from the model.\n");
    } else {
        let _ = writeln!(md, "| effect | channel | parameters | RMS before | RMS after | ΔBIC | explained |\n|---|---|---|---|---|---|---|");
        for e in &out.json.effects {
            let params: Vec<String> = e
                .params
                .iter()
                .map(|(k, v)| format!("{k} = {:.5}", Num(*v)))
                .collect();
            let _ = writeln!(
                md,
                "| {} | {} | {} | {:.4e} | {:.4e} | {:.0} | {:.0} % |",
                e.name,
                e.channel,
                params.join(", "),
                Num(e.rms_before),
                Num(e.rms_after),
                Num(e.delta_bic),
                Num(100.0 * e.explained)
            );
        }
    }
    let _ = writeln!(
        md,
        "\n## Discovered terms (a force no named effect describes, `[effects.extra_force]`)\n"
    );
    if out.json.discovered.is_empty() {
        let _ = writeln!(md, "None: no force is left that the basis describes.\n");
    } else {
        let _ = writeln!(md, "| channel | terms (SI) | reading | RMS before | RMS after | explained |\n|---|---|---|---|---|---|");
        for d in &out.json.discovered {
            let mut terms: Vec<String> = d
                .terms
                .iter()
                .map(|(k, v)| format!("`{k}` = {:.5}", Num(*v)))
                .collect();
            if let Some(p) = d.period_m {
                terms.push(format!("period_m = {:.5}", Num(p)));
            }
            let _ = writeln!(
                md,
                "| {} | {} | {} | {:.4e} | {:.4e} | {:.1} % |",
                d.channel,
                terms.join(", "),
                d.reading,
                Num(d.rms_before),
                Num(d.rms_after),
                Num(100.0 * d.explained)
            );
        }
        let _ = writeln!(
            md,
            "\nThe force maps below (`map_force_*`) show the residual with and without them."
        );
    }
    let _ = writeln!(md, "\n## Every candidate at the first step\n");
    let _ = writeln!(md, "| candidate | channel | fitted | ΔBIC | explained (all) | explained where it acts | acts on (kept samples) | change RMS where it acts / resolution | significant |\n|---|---|---|---|---|---|---|---|---|");
    for j in &out.selection.first_step {
        let fitted: Vec<String> = j
            .proposal
            .params
            .iter()
            .map(|(k, v)| format!("{k} = {:.4e}", Num(*v)))
            .collect();
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.1} | {:.1} % | {:.1} % | {} | {:.2} | {} |",
            j.proposal.kind.name(),
            j.proposal.kind.channel().name(),
            fitted.join(", "),
            Num(j.delta_bic),
            Num(100.0 * j.explained_total),
            Num(100.0 * j.explained),
            j.support,
            Num(j.change_rms / j.resolution.max(f64::MIN_POSITIVE)),
            if j.significant() { "yes" } else { "no" }
        );
    }
    let _ = writeln!(md, "\n## Lags (FFT cross-correlation)\n");
    let _ = writeln!(md, "| what | lag, ms | correlation |\n|---|---|---|");
    // The three cross-correlations are independent: computed side by side.
    let docs = [
        ("input model", &out.input),
        ("augmented model", &out.selection.doc),
    ];
    let (slave, acting) = rayon::join(
        || slave_force_lag(d),
        || {
            docs.par_iter()
                .map(|(label, doc)| (*label, acting_force_lag(&ctx, doc)))
                .collect::<Vec<_>>()
        },
    );
    if let Some(l) = slave {
        let _ = writeln!(
            md,
            "| slave force behind master force | {:.4} | {:.3} |",
            Num(l.seconds * 1e3),
            Num(l.correlation)
        );
    }
    for (label, lag) in acting {
        if let Some(l) = lag {
            let _ = writeln!(
                md,
                "| acting force behind reported force ({label}) | {:.4} | {:.3} |",
                Num(l.seconds * 1e3),
                Num(l.correlation)
            );
        }
    }
    if !out.json.warnings.is_empty() {
        let _ = writeln!(md, "\n## Warnings\n");
        for w in &out.json.warnings {
            let _ = writeln!(md, "- {w}");
        }
    }
    let _ = writeln!(md, "\n## Residual maps\n");
    let _ = writeln!(md, "Share of each channel's residual variance explained by its mean along each variable (before → after).\n");
    let _ = writeln!(md, "| channel | x | x mod pole | x mod N–N | v | a | p_A − p_B |\n|---|---|---|---|---|---|---|");
    let mut overlays = Vec::new();
    // Each channel's replays, filtering and maps are independent: computed on every core,
    // then written in the channels' order.
    // (The residuals are the analysis' own, band-filtered once there.)
    let computed: Vec<_> = out
        .filtered
        .par_iter()
        .map(|c| {
            let (fb, fa) = (&c.before, &c.after);
            let (mb, ma) = rayon::join(
                || maps(&ctx, &before, c.channel, fb),
                || maps(&ctx, &after, c.channel, fa),
            );
            (c.channel, fb, fa, mb, ma)
        })
        .collect();
    for (ch, fb, fa, mb, ma) in computed {
        let (res_unit, res_k) = plot_unit(ch);
        let cells: Vec<String> = mb
            .iter()
            .zip(&ma)
            .map(|(b, a)| format!("{:.2} → {:.2}", Num(b.structure), Num(a.structure)))
            .collect();
        let _ = writeln!(md, "| {} | {} |", ch.name(), cells.join(" | "));
        for (b, a) in mb.iter().zip(&ma) {
            let file = format!("map_{}_{}.svg", ch.name(), b.by.slug());
            let keep = |m: &super::report::Map| -> (Vec<f64>, Vec<f64>) {
                m.centres
                    .iter()
                    .zip(&m.means)
                    .filter(|(_, v)| v.is_finite())
                    .map(|(c, v)| (*c, *v))
                    .unzip()
            };
            let (by_label, by_k) = b.by.label();
            let scale =
                |v: Vec<f64>, k: f64| -> Vec<f64> { v.into_iter().map(|v| v * k).collect() };
            let (xb, yb) = keep(b);
            let (xa, ya) = keep(a);
            let (xb, yb, xa, ya) = (
                scale(xb, by_k),
                scale(yb, res_k),
                scale(xa, by_k),
                scale(ya, res_k),
            );
            lines(
                &dir.join(&file),
                &format!("{} residual by {}", ch.name(), by_label),
                by_label,
                &format!("mean residual, {res_unit}"),
                &[
                    Series::new("input model", &xb, &yb),
                    Series::new("augmented model", &xa, &ya).dashed(),
                ],
            )?;
        }
        // Before/after overlay in time.
        let n = d.len();
        let t = &d.t_s;
        let file = format!("overlay_{}.svg", ch.name());
        let in_unit = |v: &[f64]| -> Vec<f64> { v.iter().map(|v| v * res_k).collect() };
        let (yb, ya) = (
            in_unit(fb.get(..n).unwrap_or(fb)),
            in_unit(fa.get(..n).unwrap_or(fa)),
        );
        lines(
            &dir.join(&file),
            &format!(
                "{} residual (band-limited){}",
                ch.name(),
                if ch == ChannelId::Pressure {
                    ", chamber A"
                } else {
                    ""
                }
            ),
            "t, s",
            &format!("residual, {res_unit}"),
            &[
                Series::new("input model", t, &yb).faint(),
                Series::new("augmented model", t, &ya),
            ],
        )?;
        overlays.push(format!("![{0} overlay](overlay_{0}.svg)", ch.name()));
    }
    for o in &overlays {
        let _ = writeln!(md, "\n{o}");
    }
    if let (Some((pa0, pb0)), Some((pa1, pb1))) = rayon::join(
        || replay_pressures(d, &before),
        || replay_pressures(d, &after),
    ) {
        let cyl = after.cylinder();
        let va: Vec<f64> = d.x_m.iter().map(|&x| cyl.volume_a_m3(x)).collect();
        let vb: Vec<f64> = d.x_m.iter().map(|&x| cyl.volume_b_m3(x)).collect();
        let k = |v: &[f64], k: f64| -> Vec<f64> { v.iter().map(|v| v * k).collect() };
        let (va, vb) = (k(&va, 1e6), k(&vb, 1e6));
        let (ma, mb) = (k(&d.p_a_pa, 1e-3), k(&d.p_b_pa, 1e-3));
        let (pa0, pa1, pb0, pb1) = (k(&pa0, 1e-3), k(&pa1, 1e-3), k(&pb0, 1e-3), k(&pb1, 1e-3));
        panels(
            &dir.join("pv_replay.svg"),
            "p-V: measured and replayed along the measured motion",
            "V, cm³",
            &[
                Panel {
                    y_label: "chamber A: p, kPa",
                    series: vec![
                        Series::new("measured", &va, &ma),
                        Series::new("input model", &va, &pa0).dashed(),
                        Series::new("augmented model", &va, &pa1).dashed(),
                    ],
                    axes: Axes::default(),
                },
                Panel {
                    y_label: "chamber B: p, kPa",
                    series: vec![
                        Series::new("measured", &vb, &mb),
                        Series::new("input model", &vb, &pb0).dashed(),
                        Series::new("augmented model", &vb, &pb1).dashed(),
                    ],
                    axes: Axes::default(),
                },
            ],
        )?;
        let _ = writeln!(md, "\n![p-V replay](pv_replay.svg)\n");
    }
    let _ = writeln!(
        md,
        "\nMaps: `map_<channel>_<variable>.svg`. Augmented model: `model.toml`."
    );
    std::fs::write(dir.join("report.md"), md)
        .map_err(|e| format!("cannot write {}: {e}", dir.join("report.md").display()))
}
