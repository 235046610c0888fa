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
//! refitted around them (`judge_joint`). Once the steps end, each discovered term is judged
//! again against the named force effects (`reconsider_terms`): a term that took a step from
//! a named effect it only resembled gives it back. On a log whose force, slave-force and
//! encoder candidates were searched on a stretch ([`super::effects::SEARCH_MAX_S`]), the
//! named effects of those channels are then fitted once more on the whole log
//! (`refit_on_the_whole_log`).
//!
//! The rules a candidate must pass to be added (evidence, floors, the sensors' resolution,
//! the competition with the basis) are [`super::judge`]'s; the discovered terms' pruning and
//! reconsideration are [`super::reconsider`]'s.
//!
//! **Collinearity.** Two candidates of one channel whose changes to the residual correlate
//! by more than [`COLLINEAR`], and that explain nearly as much (the other at least half of
//! what the added one does), cannot be told apart by this run; when one is added, a warning
//! says so.

use rayon::prelude::*;

use std::cell::RefCell;

use super::candidate::EffectKind;
use super::channel::ChannelId;
use super::ctx::Ctx;
use super::doc::{Edit, ModelDoc};
use super::effects;
use super::fit::correlation;
use super::judge::{
    judge, judge_joint, judge_proposal, outdone_by_basis, sensor_reading_holds, BasisFits, Judged,
    BACKFIT_GAIN, BACKFIT_ROUNDS, MAX_EFFECTS, MIN_DELTA_BIC,
};
use super::reconsider::{prune_terms, reconsider_terms};
use super::residuals::{band_raw, full_of_raw, residual, Residual};
use crate::plant::model::extra_force::Term;

/// Correlation above which two candidates are reported as collinear.
pub const COLLINEAR: f64 = 0.9;

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

/// Judgements kept per candidate ([`remember`]).
const CACHED_PER_CANDIDATE: usize = 4;

/// Judgements by candidate, with the channel residual they were made on.
type Cache = Vec<(EffectKind, Vec<f64>, Judged)>;

/// The judgements of one log's selections, kept from one to the next ([`select`]): a
/// selection made again with the force alignment fitted anew finds the pressure channel's
/// residuals as they were, and with them its candidates' judgements.
#[derive(Default)]
pub struct Judgements(Cache);

/// The cached judgement of `kind`, if its channel's residual is still `before`.
fn cached(cache: &Cache, kind: EffectKind, before: &Residual) -> Option<Judged> {
    cache
        .iter()
        .find(|(k, kept, _)| *k == kind && *kept == before.kept)
        .map(|(_, _, j)| j.clone())
}

/// [`judge`], or [`judge_joint`] with the pressure effects `joint`, without the cache.
fn uncached_judge(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    kind: EffectKind,
    before: &Residual,
    joint: &[EffectKind],
) -> Option<Judged> {
    if joint.is_empty() {
        judge(ctx, doc, kind, before)
    } else {
        judge_joint(ctx, doc, kind, joint, before)
    }
}

/// Keeps `j` as the judgement of `kind` on the residual `before`.
fn remember(cache: &mut Cache, kind: EffectKind, before: &Residual, j: &Judged) {
    cache.retain(|(k, kept, _)| *k != kind || *kept != before.kept);
    // The last few residuals per candidate: the library-only pass repeats the first
    // pass's early steps.
    let mine = cache.iter().filter(|(k, _, _)| *k == kind).count();
    if mine >= CACHED_PER_CANDIDATE {
        if let Some(oldest) = cache.iter().position(|(k, _, _)| *k == kind) {
            cache.remove(oldest);
        }
    }
    cache.push((kind, before.kept.clone(), j.clone()));
}

/// [`judge`], reusing the last judgement of `kind` if its channel's residual is unchanged.
fn cached_judge(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    kind: EffectKind,
    before: &Residual,
    joint: &[EffectKind],
    cache: &mut Cache,
) -> Option<Judged> {
    if let Some(j) = cached(cache, kind, before) {
        return Some(j);
    }
    let j = uncached_judge(ctx, doc, kind, before, joint)?;
    remember(cache, kind, before, &j);
    Some(j)
}

/// Runs the forward selection from `doc` over the channels this log has.
///
/// **A formula only where it is a clean reading.** Discovered terms are kept only if the
/// force they leave is not structured ([`reading_is_clean`]): terms that describe part of a
/// force of another form (friction growing with |x − x₀| read as `x*sgn(v)`) are a curve
/// fit, not a description. Then the selection runs again with the library alone, and what
/// is left is reported as unexplained and structured ([`super::unexplained`]).
pub fn select(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    judgements: &mut Judgements,
) -> Result<Selection, String> {
    // A candidate's fit depends only on its own channel: while that channel's residual is
    // unchanged (an effect was added elsewhere, the library-only pass repeats a step of the
    // first, or a selection is made again with another force alignment), its last
    // judgement stands. The pressure candidates replay the chambers tens of times each;
    // this keeps the steps cheap.
    let cache = &mut judgements.0;
    match select_from(ctx, doc, true, cache)? {
        Some(s) => Ok(s),
        None => select_from(ctx, doc, false, cache)?.ok_or_else(|| "selection failed".to_string()),
    }
}

/// Noise variances a discovered description may leave beyond the noise itself where the
/// piston moves ([`reading_is_clean`]).
pub const CLEAN_EXCESS: f64 = 2.0;

/// Whether the force residual `doc` leaves is free of structure (what
/// [`super::unexplained::judge`] reports as not structured) and, where the piston moves
/// ([`super::unexplained::moving_rms`]), within `√(1 + CLEAN_EXCESS)` noise floors: a
/// description that leaves more has described part of a force of another form, whatever
/// the structure test resolves of the rest (a V about a point near one end of the
/// strokes, a force along the bore on a log that visits each position in one stretch of
/// time).
fn reading_is_clean(ctx: &Ctx<'_>, doc: &ModelDoc) -> Result<bool, String> {
    let model = doc.model()?;
    let Some(raw) = band_raw(ctx.data, ctx.band, &model, ChannelId::Force) else {
        return Ok(true);
    };
    let after = full_of_raw(ctx.data, ctx.band, ChannelId::Force, &raw);
    let u = super::unexplained::judge(ctx.data, ctx.band, &model, ChannelId::Force, &after, &after);
    let moving = super::unexplained::moving_rms(ctx.data, ctx.band, &after);
    Ok(!u.json.structured && moving.powi(2) <= (1.0 + CLEAN_EXCESS) * u.json.noise_floor.powi(2))
}

/// [`select`] with the discovery basis as a candidate (`with_terms`) or the library alone;
/// `None` when the terms it discovered are not a clean reading ([`reading_is_clean`]).
fn select_from(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    with_terms: bool,
    cache: &mut Cache,
) -> Result<Option<Selection>, String> {
    let input = doc.clone();
    let mut doc = doc.clone();
    let mut added: Vec<Judged> = Vec::new();
    let mut steps: Vec<(ModelDoc, ModelDoc)> = Vec::new();
    let mut first_step: Vec<Judged> = Vec::new();
    for step in 0..MAX_EFFECTS {
        let model = doc.model()?;
        // Each channel's residual on its own core (the pressure replay is the long one).
        let befores: Vec<(ChannelId, Residual)> = ChannelId::ALL
            .par_iter()
            .filter_map(|&c| Some((c, residual(ctx.data, ctx.band, &model, c)?)))
            .collect();
        let fits = RefCell::new(BasisFits::new());
        let (judged, best, best_extra) =
            judge_candidates(ctx, &doc, &befores, &added, cache, &fits, with_terms);
        let best = preferred(ctx, &doc, &befores, &judged, best, best_extra, &fits);
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
        if !reading_is_clean(ctx, &doc)? {
            return Ok(None);
        }
        doc = reconsider_terms(ctx, &input, doc, &mut added, &mut steps);
    }
    doc = refit_on_the_whole_log(ctx, doc, &mut added)?;
    final_parameters(&doc, &mut added);
    let warnings = collinear_warnings(&added, &first_step);
    Ok(Some(Selection {
        doc,
        added,
        steps,
        first_step,
        warnings,
    }))
}

/// Every candidate not yet added (a named effect once, the discovered terms at every step)
/// judged on top of `doc`, whose channels' residuals are `befores`: all the judgements, in
/// the library's order, with the significant named effect of the largest evidence that the
/// basis does not outdo, and the significant discovered terms.
fn judge_candidates(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    befores: &[(ChannelId, Residual)],
    added: &[Judged],
    cache: &mut Cache,
    fits: &RefCell<BasisFits>,
    with_terms: bool,
) -> (Vec<Judged>, Option<Judged>, Option<Judged>) {
    let mut best: Option<Judged> = None;
    let mut judged = Vec::new();
    let mut best_extra: Option<Judged> = None;
    // The candidates are independent given `doc`: judged on every core (the cached
    // ones reused), then taken in the library's order, as one thread would.
    let mut jobs: Vec<(EffectKind, &Residual, Vec<EffectKind>)> = Vec::new();
    for kind in EffectKind::ALL {
        if (kind.named() && added.iter().any(|a| a.proposal.kind == kind))
            || (!kind.named() && !with_terms)
        {
            continue;
        }
        let on = kind.judged_on(ctx.data);
        let Some((_, before)) = befores.iter().find(|(c, _)| *c == on) else {
            continue;
        };
        // Pressure candidates are judged with the pressure effects already added
        // refitted around them (`judge_joint`).
        let joint: Vec<EffectKind> = if on == ChannelId::Pressure {
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
    let results: Vec<(Option<Judged>, bool)> = jobs
        .par_iter()
        .map(|(kind, before, joint)| match cached(cache, *kind, before) {
            Some(j) => (Some(j), true),
            None => (uncached_judge(ctx, doc, *kind, before, joint), false),
        })
        .collect();
    for ((kind, before, _), (j, hit)) in jobs.iter().zip(results) {
        let kind = *kind;
        let Some(j) = j else { continue };
        if !hit {
            remember(cache, kind, before, &j);
        }
        let physical: Vec<&Judged> = judged
            .iter()
            .filter(|p: &&Judged| {
                let k = p.proposal.kind;
                k.named() && !k.sensor() && k.judged_on(ctx.data) == kind.judged_on(ctx.data)
            })
            .collect();
        if j.significant() && (!kind.sensor() || sensor_reading_holds(ctx, doc, &j, &physical)) {
            if !kind.named() {
                best_extra = Some(j.clone());
            } else if best.as_ref().is_none_or(|b| j.delta_bic > b.delta_bic)
                && !outdone_by_basis(ctx, doc, &j, before, fits)
            {
                best = Some(j.clone());
            }
        }
        judged.push(j);
    }
    (judged, best, best_extra)
}

/// The candidate a step adds, of the best named effect `best` and the discovered terms
/// `best_extra` (`judged`: the step's judgements, `befores`: its channels' residuals).
///
/// A named effect is preferred where it explains as much (fewer numbers, a physical
/// name): the basis wins only with significantly more evidence, and never when all it
/// adds is a significant named effect's own form (then it has found that effect, and
/// the difference is the law's detail, such as a regularised sign).
fn preferred(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    befores: &[(ChannelId, Residual)],
    judged: &[Judged],
    best: Option<Judged>,
    best_extra: Option<Judged>,
    fits: &RefCell<BasisFits>,
) -> Option<Judged> {
    let own_form_of = |e: &Judged| -> Option<Judged> {
        let added = super::discover::added_terms(doc, &e.proposal);
        if added.is_empty() {
            return None;
        }
        // A sensor's error takes its form's place only once its readings confirm it (below).
        judged
            .iter()
            .filter(|n| n.proposal.kind.named() && !n.proposal.kind.sensor() && n.significant())
            .filter(|n| {
                let form = n.proposal.kind.basis_form();
                added.iter().all(|t| form.contains(t))
            })
            .max_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic))
            .filter(|n| {
                befores
                    .iter()
                    .find(|(c, _)| *c == n.proposal.kind.channel())
                    .is_some_and(|(_, before)| !outdone_by_basis(ctx, doc, n, before, fits))
            })
            .cloned()
    };
    // A sensor's error that its own readings confirm ([`sensor_reading_holds`]) is preferred
    // to terms that hold its form (a constant, `f_motor`): the terms' evidence is then the
    // sensor's, and whatever else they add is judged on top of it at the next step.
    let holds_its_form = |n: &Judged, e: &Judged| {
        let form = n.proposal.kind.basis_form();
        n.proposal.kind.sensor()
            && n.proposal.kind.channel() == ChannelId::Force
            && e.proposal
                .params
                .iter()
                .filter_map(|(name, _)| Term::parse(name))
                .any(|t| form.contains(&t))
    };
    match (best, best_extra) {
        (Some(n), Some(e)) if e.delta_bic < n.delta_bic + MIN_DELTA_BIC => Some(n),
        (Some(n), Some(e)) if holds_its_form(&n, &e) => Some(n),
        (_, Some(e)) => own_form_of(&e).or(Some(e)),
        (n, None) => n,
    }
}

/// Sets each named effect of `added` to its parameters as the final model `doc` holds them:
/// a later joint fit or back-fitting may have refitted them after they were judged.
fn final_parameters(doc: &ModelDoc, added: &mut [Judged]) {
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

/// A warning for each named effect of `added` and named candidate of its channel at the
/// first step (`first_step`) that the run cannot tell apart ([`COLLINEAR`], module header),
/// each pair once whichever of the two was added.
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

/// Where the force, slave-force and encoder candidates were fitted on a stretch of the log
/// ([`effects::searches_a_stretch`]), each of those named in `added` fitted once more on the
/// whole log, on top of `doc` (which holds them all), kept where it lowers its channel's
/// residual: the selection decides on the stretch's fits, the values it reports are the
/// whole log's. Returns the updated model.
fn refit_on_the_whole_log(
    ctx: &Ctx<'_>,
    mut doc: ModelDoc,
    added: &mut [Judged],
) -> Result<ModelDoc, String> {
    if !effects::searches_a_stretch(ctx) {
        return Ok(doc);
    }
    for a in added.iter_mut() {
        let kind = a.proposal.kind;
        if !kind.named() || kind.channel() == ChannelId::Pressure {
            continue;
        }
        let model = doc.model()?;
        let Some(before) = residual(ctx.data, ctx.band, &model, kind.judged_on(ctx.data)) else {
            continue;
        };
        let Some(p) = effects::propose_on_the_whole_log(kind, ctx, &doc) else {
            continue;
        };
        if let Some(j) = judge_proposal(ctx, &doc, p, &before) {
            if j.rss_after < j.rss_before {
                doc = doc.with(&j.proposal.edits);
                a.proposal.params = j.proposal.params;
                a.proposal.edits = j.proposal.edits;
            }
        }
    }
    Ok(doc)
}

/// Fits each effect of `added` again on top of `doc` (which holds them all), keeping a refit
/// that lowers its channel's residual; returns the updated model.
fn backfit(
    ctx: &Ctx<'_>,
    mut doc: ModelDoc,
    added: &mut [Judged],
    cache: &mut Cache,
) -> Result<ModelDoc, String> {
    for round in 0..BACKFIT_ROUNDS {
        // After the first round only the channels holding two named effects or more: one
        // effect alone on its channel is at its optimum after one refit.
        let kinds: Vec<EffectKind> = added.iter().map(|a| a.proposal.kind).collect();
        let shared = |kind: EffectKind| {
            kinds
                .iter()
                .filter(|k| k.named() && k.judged_on(ctx.data) == kind.judged_on(ctx.data))
                .count()
                > 1
        };
        let mut improved = false;
        for i in 0..added.len() {
            let Some(kind) = added.get(i).map(|a| a.proposal.kind) else {
                continue;
            };
            if !kind.named() || (round > 0 && !shared(kind)) {
                // The discovered terms: refitted jointly once (never one more term here).
                continue;
            }
            let model = doc.model()?;
            let on = kind.judged_on(ctx.data);
            let Some(before) = residual(ctx.data, ctx.band, &model, on) else {
                continue;
            };
            if let Some(j) = cached_judge(ctx, &doc, kind, &before, &[], cache) {
                if j.rss_after < j.rss_before {
                    improved |= j.rss_after < (1.0 - BACKFIT_GAIN) * j.rss_before;
                    doc = doc.with(&j.proposal.edits);
                    if let Some(a) = added.get_mut(i) {
                        a.proposal.params = j.proposal.params;
                        a.proposal.edits = j.proposal.edits;
                    }
                }
            }
        }
        if !improved {
            break;
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
