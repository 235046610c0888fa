//! Forward selection: at each step every candidate not yet added is fitted on top of the
//! current model, the one with the largest evidence is added if it is significant, each
//! effect added so far is fitted once more with the others in place (back-fitting), and the
//! step repeats until nothing significant is left.
//!
//! **Beyond the library** ([`super::discover`]): the discovery basis is one more candidate
//! (`extra_force`), judged by the same rules. A named force effect is eligible only if as
//! many basis parameters, fitted to the same residual, do not explain significantly more
//! (its parameters would absorb a force of another form), and the basis wins over an
//! eligible named effect only with [`MIN_DELTA_BIC`] more evidence (the named one is fewer
//! numbers and a physical name). Discovered terms that stop passing the rules once later
//! ones are in are pruned. Pressure candidates are judged with the channel's earlier effects
//! refitted around them ([`super::judge`]). Once the steps end, each discovered term is judged
//! again against the named force effects (`reconsider_terms`): a term that took a step from
//! a named effect it only resembled gives it back.
//!
//! **Collinearity.** Two candidates of one channel whose changes to the residual correlate
//! by more than [`COLLINEAR`], and that explain nearly as much (the other at least half of
//! what the added one does), cannot be told apart by this run; when one is added, a warning
//! says so.
//!
//! Each candidate is judged by the significance rules of [`super::judge`].

use rayon::prelude::*;

use std::cell::RefCell;

use super::doc::{Edit, ModelDoc};
use super::effects::{Ctx, EffectKind};
use super::fit::correlation;
use super::judge::{
    cached, cached_judge, outdone_by_basis, prune_terms, remember, uncached_judge, BasisFits,
    Cache, Judged, COLLINEAR, MAX_EFFECTS, MIN_DELTA_BIC,
};
use super::residuals::{residual, ChannelId, Residual};
use crate::plant::model::model_section;

/// The result of the selection.
#[derive(Clone, Debug)]
pub struct Selection {
    /// The augmented model.
    pub doc: ModelDoc,
    /// What was added, in the order added (most significant first), with final parameters.
    pub added: Vec<Judged>,
    /// The model just before and just after each was added (selection-time parameters).
    pub steps: Vec<(ModelDoc, ModelDoc)>,
    /// Every candidate judged at the first step (the report's table).
    pub first_step: Vec<Judged>,
    /// Warnings (collinear candidates).
    pub warnings: Vec<String>,
}

/// Runs the forward selection from `doc` over the channels this log has. `cache` keeps each
/// candidate's last judgement with the residual it was made on; it may be carried over
/// from an earlier selection on the same log (a judgement depends only on the candidate's
/// channel residual and the log, which a refitted force alignment leaves the same for every
/// channel but the force).
pub fn select(ctx: &Ctx<'_>, doc: &ModelDoc, cache: &mut Cache) -> Result<Selection, String> {
    let input = doc.clone();
    let mut doc = doc.clone();
    let mut added: Vec<Judged> = Vec::new();
    let mut steps: Vec<(ModelDoc, ModelDoc)> = Vec::new();
    let mut first_step: Vec<Judged> = Vec::new();
    // A candidate's fit depends only on its own channel: while that channel's residual is
    // unchanged (an effect was added elsewhere), its last judgement stands. The pressure
    // candidates replay the chambers tens of times each; this keeps the steps cheap.
    for step in 0..MAX_EFFECTS {
        let model = doc.model()?;
        let mut best: Option<Judged> = None;
        let mut judged = Vec::new();
        // Each channel's residual on its own core (the pressure replay is the long one).
        let befores: Vec<(ChannelId, Residual)> = ChannelId::ALL
            .par_iter()
            .filter_map(|&c| Some((c, residual(ctx.data, ctx.band, &model, c)?)))
            .collect();
        let mut best_extra: Option<Judged> = None;
        let fits = RefCell::new(BasisFits::new());
        // The candidates are independent given `doc`: judged on every core (the cached
        // ones reused), then taken in the library's order, as one thread would.
        let jobs = candidate_jobs(&added, &befores);
        let results: Vec<(Option<Judged>, bool)> = jobs
            .par_iter()
            .map(|(kind, before, joint)| match cached(cache, *kind, before) {
                Some(j) => (Some(j), true),
                None => (uncached_judge(ctx, &doc, *kind, before, joint), false),
            })
            .collect();
        for ((kind, before, _), (j, hit)) in jobs.iter().zip(results) {
            let kind = *kind;
            let Some(j) = j else { continue };
            if !hit {
                remember(cache, kind, before, &j);
            }
            if j.significant() {
                if !kind.named() {
                    best_extra = Some(j.clone());
                } else if best.as_ref().is_none_or(|b| j.delta_bic > b.delta_bic)
                    && !outdone_by_basis(ctx, &doc, &j, before, &fits)
                {
                    best = Some(j.clone());
                }
            }
            judged.push(j);
        }
        // A named effect is preferred where it explains as much (fewer numbers, a physical
        // name): the basis wins only with significantly more evidence, and never when all it
        // adds is a significant named effect's own form (then it has found that effect, and
        // the difference is the law's detail, such as a regularised sign).
        let own_form_of = |e: &Judged| -> Option<Judged> {
            let added = super::discover::added_terms(&doc, &e.proposal);
            if added.is_empty() {
                return None;
            }
            judged
                .iter()
                .filter(|n| n.proposal.kind.named() && n.significant())
                .filter(|n| {
                    let form = n.proposal.kind.basis_form();
                    added.iter().all(|t| form.contains(t))
                })
                .max_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic))
                .filter(|n| {
                    befores
                        .iter()
                        .find(|(c, _)| *c == n.proposal.kind.channel())
                        .is_some_and(|(_, before)| !outdone_by_basis(ctx, &doc, n, before, &fits))
                })
                .cloned()
        };
        let best = match (best, best_extra) {
            (Some(n), Some(e)) if e.delta_bic < n.delta_bic + MIN_DELTA_BIC => Some(n),
            (_, Some(e)) => own_form_of(&e).or(Some(e)),
            (n, None) => n,
        };
        if step == 0 {
            first_step = judged;
        }
        let Some(b) = best else { break };
        let next = doc.with(&b.proposal.edits);
        steps.push((doc, next.clone()));
        doc = next;
        added.push(b);
        // Back-fitting: each effect added so far once more with all the others in place,
        // so that one fitted while another was still missing is corrected before the next
        // step looks at what is left.
        if added.len() > 1 {
            doc = backfit(ctx, doc, &mut added, cache)?;
        }
        if added.iter().any(|a| !a.proposal.kind.named()) {
            doc = prune_terms(ctx, doc);
        }
    }
    if added.iter().any(|a| !a.proposal.kind.named()) {
        doc = super::reconsider::reconsider_terms(ctx, &input, doc, &mut added, &mut steps);
    }
    let mut notes = Vec::new();
    if let Some(note) = drop_unclean_terms(ctx, &mut doc, &mut added, &mut steps)? {
        notes.push(note);
        // The named effects were fitted beside the terms: once more without them.
        doc = backfit(ctx, doc, &mut added, cache)?;
    }
    if added.iter().filter(|a| a.proposal.kind.named()).count() > 1 {
        doc = super::reconsider::prune_named(ctx, &input, doc, &mut added, &mut steps);
    }
    sync_params(&doc, &mut added);
    let mut warnings = notes;
    warnings.extend(collinear_warnings(&added, &first_step));
    Ok(Selection {
        doc,
        added,
        steps,
        first_step,
        warnings,
    })
}

/// The candidates to judge at a step: every library effect not yet added (the basis always),
/// with its channel's residual and, for a pressure candidate, the pressure effects already
/// added, refitted around it (`judge_joint`).
fn candidate_jobs<'r>(
    added: &[Judged],
    befores: &'r [(ChannelId, Residual)],
) -> Vec<(EffectKind, &'r Residual, Vec<EffectKind>)> {
    let mut jobs = Vec::new();
    for kind in EffectKind::ALL {
        if kind.named() && added.iter().any(|a| a.proposal.kind == kind) {
            continue;
        }
        let Some((_, before)) = befores.iter().find(|(c, _)| *c == kind.channel()) else {
            continue;
        };
        // Pressure candidates are judged with the pressure effects already added
        // refitted around them (`judge_joint`).
        let joint: Vec<EffectKind> = if kind.channel() == ChannelId::Pressure {
            added
                .iter()
                .map(|a| a.proposal.kind)
                .filter(|k| k.channel() == ChannelId::Pressure)
                .collect()
        } else {
            Vec::new()
        };
        jobs.push((kind, before, joint));
    }
    jobs
}

/// Each named effect's parameters as the final model `doc` holds them: a later joint fit or
/// back-fitting may have refitted them after they were judged.
fn sync_params(doc: &ModelDoc, added: &mut [Judged]) {
    for a in added.iter_mut().filter(|a| a.proposal.kind.named()) {
        let keys: Vec<crate::plant::model::Key> = a
            .proposal
            .edits
            .iter()
            .filter_map(|e| match e {
                Edit::Set(k, _) => Some(*k),
                _ => None,
            })
            .collect();
        for (name, value) in a.proposal.params.iter_mut() {
            if let Some(v) = keys
                .iter()
                .rev()
                .find(|k| k.name == *name)
                .and_then(|k| doc.number(*k))
            {
                *value = v;
            }
        }
    }
}

/// A warning for each added named effect that another named candidate of its channel was,
/// at the first step, collinear with and nearly as good as.
fn collinear_warnings(added: &[Judged], first_step: &[Judged]) -> Vec<String> {
    let mut warnings = Vec::new();
    // Each pair once, whichever of the two was added.
    let mut pairs: Vec<(EffectKind, EffectKind)> = Vec::new();
    for a in added {
        for other in first_step {
            let k = other.proposal.kind;
            if k == a.proposal.kind
                || k.channel() != a.proposal.kind.channel()
                || !k.named()
                || !a.proposal.kind.named()
                || pairs.contains(&(k, a.proposal.kind))
            {
                continue;
            }
            let mine = first_step
                .iter()
                .find(|j| j.proposal.kind == a.proposal.kind);
            let Some(mine) = mine else { continue };
            let rho = correlation(&mine.change, &other.change);
            // Collinear *and* nearly as good: the run cannot tell them apart. (A candidate
            // that merely mimics the missing effect correlates too, but explains far less.)
            let gain = |j: &Judged| j.rss_before - j.rss_after;
            if rho.abs() > COLLINEAR && gain(other) >= 0.5 * gain(mine) {
                pairs.push((a.proposal.kind, k));
                warnings.push(format!(
                    "{} and {} are collinear in this run (|ρ| = {:.2}): it cannot tell them \
                     apart; a run with more varied motion (other speeds, strokes or pressure \
                     ratios) would separate them.",
                    a.proposal.kind.name(),
                    k.name(),
                    rho.abs()
                ));
            }
        }
    }
    warnings
}

/// Discovered terms are a reading of the force only where they leave no structure in the
/// variables they are functions of ([`super::unexplained::follows`]): a formula that misses
/// the dependence it describes (a periodic pair beside a constant for a hardening spring, a
/// line in `x·sgn(v)` for friction that grows both ways from mid-stroke) is a curve fitted,
/// not a description. Such terms are taken out of the model (the named effects stay) and the
/// force is reported as unexplained and structured; returns the note that says so.
fn drop_unclean_terms(
    ctx: &Ctx<'_>,
    doc: &mut ModelDoc,
    added: &mut Vec<Judged>,
    steps: &mut Vec<(ModelDoc, ModelDoc)>,
) -> Result<Option<String>, String> {
    let (terms, _) = super::discover::present_terms(doc);
    if terms.is_empty() {
        return Ok(None);
    }
    let model = doc.model()?;
    let Some(kept) = residual(ctx.data, ctx.band, &model, ChannelId::Force) else {
        return Ok(None);
    };
    let follows =
        super::unexplained::follows(ctx.data, ctx.band, &model, ChannelId::Force, &kept.kept);
    let overlap = follows
        .iter()
        .any(|v| terms.iter().any(|t| super::unexplained::term_reads(*t, *v)));
    if !overlap {
        return Ok(None);
    }
    let read = super::discover::reading(
        &model
            .effects
            .extra_force
            .as_ref()
            .and_then(|e| e.parsed().ok())
            .unwrap_or_default(),
        model.effects.extra_force.as_ref().and_then(|e| e.period_m),
    );
    *doc = doc.with(&[Edit::RemoveSection(model_section!(effects.extra_force))]);
    if let Some(i) = added.iter().position(|a| !a.proposal.kind.named()) {
        added.remove(i);
        if i < steps.len() {
            steps.remove(i);
        }
    }
    let names: Vec<&str> = follows.iter().map(|v| v.name()).collect();
    Ok(Some(format!(
        "the discovered terms ({read}) left a force that still follows {}: not a clean \
         reading, so none is written; the force is reported as unexplained and structured",
        names.join(", ")
    )))
}

/// Fits each effect of `added` again on top of `doc` (which holds them all), keeping a refit
/// that lowers its channel's residual; returns the updated model.
fn backfit(
    ctx: &Ctx<'_>,
    mut doc: ModelDoc,
    added: &mut [Judged],
    cache: &mut Cache,
) -> Result<ModelDoc, String> {
    for a in added.iter_mut() {
        let kind = a.proposal.kind;
        if !kind.named() {
            // The discovered terms: refitted jointly once (never one more term here).
            continue;
        }
        let model = doc.model()?;
        let Some(before) = residual(ctx.data, ctx.band, &model, kind.channel()) else {
            continue;
        };
        if let Some(j) = cached_judge(ctx, &doc, kind, &before, &[], cache) {
            if j.rss_after < j.rss_before {
                doc = doc.with(&j.proposal.edits);
                a.proposal.params = j.proposal.params;
                a.proposal.edits = j.proposal.edits;
            }
        }
    }
    if added.iter().any(|a| !a.proposal.kind.named()) {
        if let Some(p) = super::discover::refit(ctx, &doc) {
            let refitted = doc.with(&p.edits);
            let rss = |d: &ModelDoc| -> Option<f64> {
                let m = d.model().ok()?;
                Some(residual(ctx.data, ctx.band, &m, ChannelId::Force)?.rss())
            };
            if let (Some(a), Some(b)) = (rss(&refitted), rss(&doc)) {
                if a < b {
                    doc = refitted;
                }
            }
        }
    }
    Ok(doc)
}

/// Channels that this log has, with their residuals for `doc`.
pub fn channels(ctx: &Ctx<'_>, doc: &ModelDoc) -> Result<Vec<Residual>, String> {
    let model = doc.model()?;
    Ok(ChannelId::ALL
        .par_iter()
        .filter_map(|&c| residual(ctx.data, ctx.band, &model, c))
        .collect())
}
