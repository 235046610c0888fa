//! How well the log pins down each fitted parameter: one standard deviation from the
//! least-squares covariance of the augmented model's channel residual, the parameters of
//! every named effect on that channel taken together (`docs/gap.md`, "How exact the fitted
//! values are").
//!
//! The Jacobian is taken numerically on the final model, each parameter moved by a central
//! difference of [`REL_STEP`] of its value, so the same code serves the linear fits, the
//! periodogram-and-golden-section ones and the chamber replays; the residual's sample count
//! is its effective one ([`super::judge::effective_n`]), since the band filter and the
//! differentiator spread each independent sample over many rows.

use std::collections::BTreeMap;

use rayon::prelude::*;

use crate::plant::model::Key;

use super::candidate::EffectKind;
use super::channel::ChannelId;
use super::ctx::Ctx;
use super::doc::{Edit, ModelDoc};
use super::fit::{standard_errors, sumsq};
use super::judge::{effective_n, reading_channel, Judged};
use super::residuals::{band_raw, kept_of_raw};
use super::select::Selection;

/// Central-difference step, relative to the parameter's value.
pub const REL_STEP: f64 = 1e-4;

/// Keys an effect sets but does not fit (a seal length taken from the model, a Stribeck
/// exponent chosen from a short list): they carry no uncertainty.
const SET_NOT_FITTED: [&str; 3] = ["seal_length_m", "rod_seal_length_m", "exponent"];

/// Whether an effect's parameter `key` is fitted (rather than set from the model or a list).
pub fn fitted(key: &str) -> bool {
    !SET_NOT_FITTED.contains(&key)
}

/// The unit of a model key, from its name's suffix (`amplitude_n`: N, `delay_s`: s,
/// `viscous_ns_per_m`: N·s/m); empty for a ratio (`area_scale`, `scale`).
pub fn key_unit(key: &str) -> &'static str {
    const SUFFIXES: [(&str, &str); 9] = [
        ("_ns_per_m", "N·s/m"),
        ("_w_per_k", "W/K"),
        ("_mps", "m/s"),
        ("_rad", "rad"),
        ("_kg", "kg"),
        ("_n", "N"),
        ("_m", "m"),
        ("_s", "s"),
        ("_k", "K"),
    ];
    SUFFIXES
        .iter()
        .find(|(s, _)| key.ends_with(s))
        .map_or("", |(_, u)| *u)
}

/// One standard deviation of each fitted parameter of each added named effect, by effect and
/// key (SI, as the parameters). A parameter held at zero, one the residual does not move, or a
/// channel whose parameters the log cannot separate, has none. A force reading's pair is
/// taken on the force and slave-force residuals together, as it is fitted
/// ([`reading_channel`]): the force channel alone sees only the sections' sum.
pub fn of_selection(
    ctx: &Ctx<'_>,
    selection: &Selection,
) -> BTreeMap<EffectKind, BTreeMap<String, f64>> {
    let named: Vec<&Judged> = selection
        .added
        .iter()
        .filter(|a| a.proposal.kind.named())
        .collect();
    let read_apart = |k: EffectKind| reading_channel(k) != k.channel();
    // Every channel's named effects together, then each force reading on its own channels.
    let mut groups: Vec<(Vec<ChannelId>, Vec<&Judged>)> = ChannelId::ALL
        .iter()
        .map(|&ch| {
            let on = |a: &&&Judged| {
                a.proposal.kind.judged_on(ctx.data) == ch && !read_apart(a.proposal.kind)
            };
            (vec![ch], named.iter().filter(on).copied().collect())
        })
        .collect();
    for a in named.iter().filter(|a| read_apart(a.proposal.kind)) {
        let k = a.proposal.kind;
        groups.push((vec![k.channel(), reading_channel(k)], vec![*a]));
    }
    let mut out: BTreeMap<EffectKind, BTreeMap<String, f64>> = BTreeMap::new();
    for (chs, effects) in groups {
        let params = fitted_params(selection, &effects);
        if params.is_empty() {
            continue;
        }
        let Some(se) = channel_errors(ctx, &selection.doc, &chs, &params) else {
            continue;
        };
        for ((kind, key, _), s) in params.iter().zip(se) {
            out.entry(*kind)
                .or_default()
                .insert(key.name.to_string(), s);
        }
    }
    out
}

/// Every fitted parameter of `effects` with its key and its value in the final model.
fn fitted_params(selection: &Selection, effects: &[&Judged]) -> Vec<(EffectKind, Key, f64)> {
    effects
        .iter()
        .flat_map(|a| {
            let kind = a.proposal.kind;
            a.proposal
                .params
                .iter()
                .filter_map(move |(name, _)| {
                    if !fitted(name) {
                        return None;
                    }
                    a.proposal.edits.iter().find_map(|e| match e {
                        Edit::Set(key, _) if key.name == *name => Some(*key),
                        _ => None,
                    })
                })
                .filter_map(move |key| {
                    // A parameter held at zero (a bound) has no spread to give.
                    let v = selection.doc.number(key).filter(|v| *v != 0.0)?;
                    Some((kind, key, v))
                })
        })
        .collect()
}

/// `doc` with each fitted parameter of `sigma` commented with its value rounded to its
/// uncertainty (`amplitude_n = 45.052022518793216  # 45.05 ± 0.19 N, one standard deviation
/// of gap's fit`): the value itself keeps every digit, so that a rerun reproduces exactly.
pub fn annotated(
    doc: &ModelDoc,
    selection: &Selection,
    sigma: &BTreeMap<EffectKind, BTreeMap<String, f64>>,
) -> ModelDoc {
    let mut out = doc.clone();
    for a in &selection.added {
        let Some(by_key) = sigma.get(&a.proposal.kind) else {
            continue;
        };
        for e in &a.proposal.edits {
            let Edit::Set(key, _) = e else {
                continue;
            };
            let (Some(s), Some(v)) = (by_key.get(key.name), doc.number(*key)) else {
                continue;
            };
            let text = format!(
                "{}, one standard deviation of gap's fit",
                crate::console::eng_pm(v, *s, key_unit(key.name))
            );
            out = out.with_comment(*key, &text);
        }
    }
    out
}

/// The kept residuals of `chs` for `doc`, one after the other (`None`: the model does not
/// load or a channel cannot be formed).
fn kept(ctx: &Ctx<'_>, doc: &ModelDoc, chs: &[ChannelId]) -> Option<Vec<f64>> {
    let model = doc.model().ok()?;
    let mut out = Vec::new();
    for &ch in chs {
        let raw = band_raw(ctx.data, ctx.band, &model, ch)?;
        out.extend(kept_of_raw(ctx.data, ctx.band, ch, &raw));
    }
    Some(out)
}

/// Standard errors of `params` (at their values in `doc`) jointly, from the residuals of
/// `chs`.
fn channel_errors(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    chs: &[ChannelId],
    params: &[(EffectKind, Key, f64)],
) -> Option<Vec<f64>> {
    let r0 = kept(ctx, doc, chs)?;
    let cols: Vec<Vec<f64>> = params
        .par_iter()
        .map(|&(_, key, v)| {
            let h = REL_STEP * v.abs();
            let (up, down) = rayon::join(
                || kept(ctx, &doc.with(&[Edit::Set(key, v + h)]), chs),
                || kept(ctx, &doc.with(&[Edit::Set(key, v - h)]), chs),
            );
            let (up, down) = (up?, down?);
            (up.len() == r0.len() && down.len() == r0.len()).then(|| {
                up.iter()
                    .zip(&down)
                    .map(|(u, d)| (u - d) / (2.0 * h))
                    .collect()
            })
        })
        .collect::<Option<Vec<_>>>()?;
    standard_errors(&cols, sumsq(&r0), effective_n(&r0))
}
