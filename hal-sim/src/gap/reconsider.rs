//! The discovered terms judged again once others are in. After each selection step, a term
//! that no longer passes the rules with the later ones in place is dropped
//! ([`prune_terms`]). At the end of selection, each term is judged once more against the
//! named force effects not in the final model ([`reconsider_terms`]): forward selection adds
//! one candidate at a time, and a basis term can take a step from a named effect it only
//! resembles; here it gives it back where the named effect explains as much.

use rayon::prelude::*;
use std::cell::RefCell;

use super::candidate::EffectKind;
use super::channel::ChannelId;
use super::ctx::Ctx;
use super::doc::{Edit, ModelDoc};
use super::effects::propose;
use super::judge::{
    effective_n, judge_proposal, outdone_by_basis, sensor_reading_holds, Judged, BACKFIT_GAIN,
    BACKFIT_ROUNDS, MAX_EFFECTS, MIN_DELTA_BIC,
};
use super::residuals::residual;
use crate::plant::model::extra_force::Term;
use crate::plant::model::model_section;

/// Drops discovered terms that no longer pass the significance rules with the others in
/// place (forward selection can add a term that only stood in for one added later): each
/// term is judged as if it were added last, onto the others refitted without it, and the
/// least significant failing one is dropped, until every one passes.
pub(super) fn prune_terms(ctx: &Ctx<'_>, mut doc: ModelDoc) -> ModelDoc {
    loop {
        let Ok(model) = doc.model() else { return doc };
        let Some(terms) = model
            .effects
            .extra_force
            .as_ref()
            .and_then(|e| e.parsed().ok())
        else {
            return doc;
        };
        let mut worst: Option<(f64, ModelDoc)> = None;
        let present: Vec<Term> = terms.iter().map(|(t, _)| *t).collect();
        for (term, _) in terms
            .iter()
            .filter(|(t, _)| !below_a_higher_power(*t, &present))
        {
            let Some((without, back)) = super::discover::without_term(ctx, &doc, *term) else {
                continue;
            };
            let Some(before) = without
                .model()
                .ok()
                .and_then(|m| residual(ctx.data, ctx.band, &m, ChannelId::Force))
            else {
                continue;
            };
            let Some(j) = judge_proposal(ctx, &without, back, &before) else {
                continue;
            };
            if !j.significant() && worst.as_ref().is_none_or(|(d, _)| j.delta_bic < *d) {
                worst = Some((j.delta_bic, without));
            }
        }
        match worst {
            Some((_, without)) => doc = without,
            None => return doc,
        }
    }
}

/// Whether `term` is a lower power of x than one of `present`: a polynomial in x about a
/// point of its own (a spring about its rest point) is one form, whose lower terms are its
/// origin's expansion and nothing alone. Refitted without one of them, the others bend to
/// stand in for it over a stroke, so each would fail as if added last, and the form would be
/// dropped a term at a time. It is pruned from its highest power down.
fn below_a_higher_power(term: Term, present: &[Term]) -> bool {
    let power = |t: Term| match t {
        Term::X => Some(1),
        Term::X2 => Some(2),
        Term::X3 => Some(3),
        _ => None,
    };
    power(term).is_some_and(|p| present.iter().any(|t| power(*t).is_some_and(|q| q > p)))
}

/// The named force effects a discovered term can be judged against at the end of selection:
/// the library's named effects on the force channel.
fn force_named() -> impl Iterator<Item = EffectKind> {
    EffectKind::ALL
        .into_iter()
        .filter(|k| k.named() && k.channel() == ChannelId::Force)
}

/// The number of parameters of `doc`'s discovered terms (with the period, if fitted).
fn term_params(doc: &ModelDoc) -> usize {
    let (terms, period) = super::discover::present_terms(doc);
    terms.len() + usize::from(period.is_some())
}

/// `doc` without the named effect `kind`: its section removed, or the values it corrects
/// set back to `input`'s (`None` if it cannot be fitted here to know its keys).
fn without_named(
    ctx: &Ctx<'_>,
    input: &ModelDoc,
    doc: &ModelDoc,
    kind: EffectKind,
) -> Option<ModelDoc> {
    if let Some(section) = kind.section() {
        return Some(doc.with(&[Edit::RemoveSection(section)]));
    }
    let p = propose(kind, ctx, doc)?;
    let edits: Vec<Edit> = p
        .edits
        .iter()
        .filter_map(|e| match e {
            // A key the input file does not give takes its default again.
            Edit::Set(k, _) => Some(
                input
                    .number(*k)
                    .map_or(Edit::RemoveKey(*k), |v| Edit::Set(*k, v)),
            ),
            _ => None,
        })
        .collect();
    Some(doc.with(&edits))
}

/// One alternative of [`reconsider_terms`]: the discovered `term` (the periodic pair
/// together) replaced by the named force effect `kind`, everything refitted. Returns the
/// model just without and just with `kind`, its judgement as if added last, and the force
/// residual's RSS; `None` if `kind` then fails the selection's rules.
fn swap_term(
    ctx: &Ctx<'_>,
    input: &ModelDoc,
    doc: &ModelDoc,
    term: Term,
    kind: EffectKind,
    named: &[EffectKind],
) -> Option<(ModelDoc, ModelDoc, Option<Judged>, f64)> {
    let (without, _) = super::discover::without_term(ctx, doc, term)?;
    // A constant left alone was the removed term's origin (a form about a rest point).
    let (rest, _) = super::discover::present_terms(&without);
    let without = if rest.iter().all(|t| *t == Term::One) {
        without.with(&[Edit::RemoveSection(model_section!(effects.extra_force))])
    } else {
        without
    };
    let force_rss = |d: &ModelDoc| -> Option<f64> {
        Some(residual(ctx.data, ctx.band, &d.model().ok()?, ChannelId::Force)?.rss())
    };
    let first = propose(kind, ctx, &without)?;
    let mut alt = without.with(&first.edits);
    // Back-fitting, as the selection does ([`super::select::backfit`]): each named effect
    // once more with the others in place, then the discovered terms left refitted — never
    // one more term (`named` holds `extra_force` too, whose proposal adds one): a term
    // fitted here would be a free parameter the model with `term` never had, and `f_motor`
    // would lose to its own decomposition (module header). Rounds repeat until one removes
    // less than [`BACKFIT_GAIN`] of the residual, as in selection: the model with `term`
    // stood at the joint optimum the selection's back-fitting reached, and one round leaves
    // the alternative short of its own where its effects overlap (a mass refitted before the
    // Coulomb level that `f_motor`'s friction share had moved).
    // `alt`'s RSS is kept beside it: each refit is compared with it, not recomputed.
    let mut alt_rss = force_rss(&alt)?;
    for _ in 0..BACKFIT_ROUNDS {
        let start = alt_rss;
        for k in named.iter().copied().filter(|k| k.named()).chain([kind]) {
            if let Some(p) = propose(k, ctx, &alt) {
                let next = alt.with(&p.edits);
                let next_rss = force_rss(&next)?;
                if next_rss < alt_rss {
                    (alt, alt_rss) = (next, next_rss);
                }
            }
        }
        if let Some(p) = super::discover::refit(ctx, &alt) {
            let next = alt.with(&p.edits);
            let next_rss = force_rss(&next)?;
            if next_rss < alt_rss {
                (alt, alt_rss) = (next, next_rss);
            }
        }
        if alt_rss >= (1.0 - BACKFIT_GAIN) * start {
            break;
        }
    }
    let alt = prune_terms(ctx, alt);
    // The named effect judged as if added last, with the same competition as in selection.
    let base = without_named(ctx, input, &alt, kind)?;
    let before = residual(ctx.data, ctx.band, &base.model().ok()?, ChannelId::Force)?;
    let p = propose(kind, ctx, &base)?;
    let j = judge_proposal(ctx, &base, p, &before)?;
    if outdone_by_basis(ctx, &base, &j, &before, &RefCell::new(Vec::new())) {
        return None;
    }
    // A sensor's error is named only where its reading shows it, as in selection.
    if kind.sensor() && j.significant() && !sensor_reading_holds(ctx, &base, &j, &[]) {
        return None;
    }
    if !j.significant() {
        // Already named, and without the term it no longer passes: it only made up for the
        // term (a friction refitted around `f_motor`'s friction share). The alternative
        // is the model without either.
        return named.contains(&kind).then(|| {
            let rss = force_rss(&base).unwrap_or(f64::INFINITY);
            (base.clone(), base, None, rss)
        });
    }
    let alt = base.with(&j.proposal.edits);
    let rss = force_rss(&alt)?;
    Some((base, alt, Some(j), rss))
}

/// Discovered terms judged once more against the named force effects not in the final
/// model. Forward selection adds one candidate at a time, and a term can take a step from
/// a named effect it only resembles there, then keep it:
/// - `f_motor` (the motor force lower than logged) is nearly the mass's regressor where the
///   force is mostly inertia, and it also scales the force balancing a second hidden
///   effect, so on a log hiding a mass error and another force it explains more than the
///   mass at the first step; the friction is then refitted to make up for its friction
///   share, and the mass is never judged against it again;
/// - a bare `sgn(v)` has no sign bound, while Coulomb friction fitted with another effect
///   still missing (an actuator lag) can ask for a negative level and be dropped; once the
///   other effect is in, nothing turns the term back into the friction.
///
/// So, once selection ends, each discovered term (the periodic pair as one) is replaced in
/// turn by each named force effect not in the model, everything refitted; the named effect
/// must pass the selection's rules as if added last (significance, and no `k` basis
/// parameters explaining significantly more). The best such model replaces the current one
/// unless the current one is better by [`MIN_DELTA_BIC`] (`ΔBIC` over the force channel's
/// effective sample size, counting every parameter): the preference selection gives a
/// named effect.
///
/// The alternative's back-fitting refits the named effects and the terms left, and never
/// fits a new term: a term fitted there is a number the model with the term never had to
/// earn. On a vented log a force-constant error's `f_motor` is inertia plus friction, and
/// the mass with a free `v` term beside it (or the viscous friction with a free `a`) is its
/// decomposition in two free numbers where `f_motor` is one; the second number fitted the
/// plant's own small mismatch (3 % of the residual's sum of squares, which the best basis
/// term beside `f_motor` explains 0.07 % of), and the mass was named for a force-constant
/// error. Where the two forms cannot be told apart, they are not: a force-constant error
/// scales the whole motor force — what balances inertia, friction and the gas force —
/// while a mass error scales only the inertia; a log whose motor force is nearly all
/// inertia (vented, little friction) cannot tell a force-constant error from a mass error,
/// and there the mass is named.
pub(super) fn reconsider_terms(
    ctx: &Ctx<'_>,
    input: &ModelDoc,
    mut doc: ModelDoc,
    added: &mut Vec<Judged>,
    steps: &mut Vec<(ModelDoc, ModelDoc)>,
) -> ModelDoc {
    // Each swap removes a term: at most as many rounds as there are terms.
    for _ in 0..MAX_EFFECTS {
        let (terms, _) = super::discover::present_terms(&doc);
        let Some(cur) = doc
            .model()
            .ok()
            .and_then(|m| residual(ctx.data, ctx.band, &m, ChannelId::Force))
        else {
            return doc;
        };
        let named: Vec<EffectKind> = added.iter().map(|a| a.proposal.kind).collect();
        let mut pairs: Vec<(Term, EffectKind)> = Vec::new();
        for t in terms
            .iter()
            .copied()
            .filter(|t| *t != Term::One && *t != Term::Cos)
        {
            for k in force_named() {
                // A named effect not in the model, or one in it whose own form the term is
                // (folded into it: its law already holds that force).
                if !named.contains(&k) || k.basis_form().contains(&t) {
                    pairs.push((t, k));
                }
            }
        }
        if pairs.is_empty() {
            return doc;
        }
        let nf = effective_n(&cur.kept);
        let rss_cur = cur.rss();
        let k_cur = term_params(&doc) as f64;
        let best = pairs
            .par_iter()
            .filter_map(|&(t, k)| {
                let (base, alt, j, rss) = swap_term(ctx, input, &doc, t, k, &named)?;
                // The named effects in both are the same but `k`: new, refitted or dropped.
                let k_named = match (&j, named.contains(&k)) {
                    (Some(j), false) => j.proposal.k as f64,
                    (Some(_), true) => 0.0,
                    (None, _) => {
                        -(added
                            .iter()
                            .find(|a| a.proposal.kind == k)
                            .map_or(0, |a| a.proposal.k) as f64)
                    }
                };
                let k_alt = term_params(&alt) as f64 + k_named;
                let d = nf * (rss / rss_cur).ln() + (k_alt - k_cur) * nf.ln();
                (rss > 0.0 && rss_cur > 0.0 && d < MIN_DELTA_BIC).then_some((d, k, base, alt, j))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let Some((_, kind, base, alt, j)) = best else {
            return doc;
        };
        doc = alt;
        if !doc.has_section(model_section!(effects.extra_force)) {
            if let Some(i) = added.iter().position(|a| !a.proposal.kind.named()) {
                added.remove(i);
                steps.remove(i);
            }
        }
        match (j, added.iter().position(|a| a.proposal.kind == kind)) {
            // Folded into an effect already named: its parameters are refitted.
            (Some(j), Some(i)) => added[i].proposal = j.proposal,
            (Some(j), None) => {
                steps.push((base, doc.clone()));
                added.push(j);
            }
            // It only made up for the term: dropped with it.
            (None, Some(i)) => {
                added.remove(i);
                steps.remove(i);
            }
            (None, None) => {}
        }
    }
    doc
}
