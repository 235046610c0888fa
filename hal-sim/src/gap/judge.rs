//! How one candidate is judged: the rules it must pass to be added by the forward selection
//! ([`super::select`]), and the competition of a named force effect with the discovery
//! basis ([`outdone_by_basis`]).
//!
//! **Significance.** An effect is added only if both hold:
//! - the Bayesian information criterion improves by at least [`MIN_DELTA_BIC`]:
//!   `ΔBIC = n_eff·ln(RSS₀/RSS₁) − k·ln n_eff` over the channel's kept samples (decimated to
//!   about one per half period of the band edge), with `n_eff` the effective number of
//!   independent samples of what is left after the fit ([`effective_n`]): the residual is
//!   coloured (differentiator, band filter, controller), and raw counts over-count evidence;
//! - it explains at least [`MIN_EXPLAINED_TOTAL`] of the channel's residual sum of squares,
//!   and at least [`MIN_EXPLAINED`] of it *where it acts* (the kept samples where it changes
//!   the residual by more than a tenth of its typical largest change): practical floors, so that a
//!   systematic but negligible mismatch (a logging offset of one sample, the rotation's
//!   quantised speed in the friction near a reversal) is not named on long, quiet logs;
//! - the sensors can tell it apart: it changes the channel's residual, in RMS where it acts,
//!   by more than the channel's resolution ([`resolution`]), or it changes at least
//!   [`MIN_RESOLVED_SHARE`] of the kept samples (and at least [`MIN_SUPPORT`]) each by more
//!   than what one reading resolves ([`sample_resolution`]). Where it acts, not over the
//!   whole log: a friction law that matters only near breakaway changes few samples by
//!   several newtons and most by nothing, and the share of slow motion in a log is not
//!   physics.
//!
//! **Two yardsticks of resolution.** An RMS over many samples resolves less than one sensor
//! code (the readings are dithered by the noise, and averaging them recovers a fraction of a
//! code): [`resolution`] is a third of a pressure code, half a current code. A single
//! sample does not: the sparse test counts a sample only if the effect changes it by a whole
//! code of the sensor behind the channel. Judged with the averaged yardstick, single samples
//! let a fitted value that is "no effect" within the sensors' resolution be named: on a run
//! of the modelled machine (PR 4.5, 0.6 m/s) the port-opening transients miss the replay by
//! a few codes, and a port area scaled by 0.996 moves 1 % of the kept samples by 100–260 Pa
//! (a third of a code to 0.86 of one; 53 Pa RMS where it acts), some toward the data and
//! about as many away: `port_restriction` was named for a change no reading can resolve.
//! A fitted effect is named only if its change from the no-effect value is resolved, in RMS
//! or sample by sample, by the sensors that see it.
//!
//! "Where it acts" is where the change exceeds a tenth of its 98th percentile
//! ([`robust_peak`]), not of its largest value.
//!
//! **A sensor's error is the last reading, not a remainder.** An offset or a gain of a
//! transducer is a constant of the reading: it cannot produce a pattern the gas's physics
//! leaves half explained, yet fitted on top of physical effects it absorbs part of what they
//! leave (a chamber replay off by a few percent, read through a shifted sensor). A sensor
//! effect is named only if it reads the channel better than every physical candidate judged
//! at the same step (each fitted with the physical effects already named, refitted around
//! it), and if what it leaves is noise: no structure, and an RMS above the channel's noise
//! floor by less than the channel resolves (in quadrature, `√(rms² − floor²) <`
//! [`resolution`]) ([`sensor_reading_holds`]). A force reading's error is judged on the force
//! channel against the physical force effects, and read where one reading is compared with
//! another: it must pass these rules on the slave-force channel too and leave noise there
//! ([`reading_channel`]). A force on the piston leaves both readings alike and fails there.
//!

use std::cell::RefCell;

use super::candidate::{EffectKind, Proposal};
use super::channel::{resolution, sample_resolution, ChannelId};
use super::ctx::Ctx;
use super::doc::{Edit, ModelDoc};
use super::effects::propose;
use super::residuals::{band_raw, full_of_raw, residual, Residual};
use crate::plant::model::extra_force::Term;

/// Smallest BIC improvement that adds an effect ("very strong" evidence on Kass and
/// Raftery's scale).
pub const MIN_DELTA_BIC: f64 = 10.0;

/// Smallest share of the residual's sum of squares, where the effect acts, it must explain.
pub const MIN_EXPLAINED: f64 = 0.20;

/// Smallest share of the channel's whole residual sum of squares it must explain.
pub const MIN_EXPLAINED_TOTAL: f64 = 0.05;

/// Fewest kept samples an effect must act on.
pub const MIN_SUPPORT: usize = 8;

/// Smallest share of the kept samples a sparse effect must change, each by more than
/// [`sample_resolution`] (see the module header).
pub const MIN_RESOLVED_SHARE: f64 = 0.01;

/// Most effects added to one model.
pub const MAX_EFFECTS: usize = 8;

/// Most rounds of back-fitting per selection step (`select::backfit`) and per swap of a
/// discovered term (`reconsider`): effects sharing a channel are refitted in turn until they
/// stop improving it, so that they stand at their joint optimum before the next candidate
/// is judged on what they leave.
pub const BACKFIT_ROUNDS: usize = 6;

/// Share of its channel's residual sum of squares a refit must remove for another round.
pub const BACKFIT_GAIN: f64 = 0.01;

/// One candidate judged at one step.
#[derive(Clone, Debug, PartialEq)]
pub struct Judged {
    /// The fitted candidate.
    pub proposal: Proposal,
    /// RSS of its channel before, at the kept samples.
    pub rss_before: f64,
    /// RSS after adding it.
    pub rss_after: f64,
    /// Kept samples of the channel.
    pub n: usize,
    /// BIC improvement.
    pub delta_bic: f64,
    /// Share of the residual's sum of squares explained where it acts.
    pub explained: f64,
    /// Share of the channel's whole residual sum of squares explained.
    pub explained_total: f64,
    /// Kept samples where it acts.
    pub support: usize,
    /// RMS of its change to the residual where it acts.
    pub change_rms: f64,
    /// The channel's resolution ([`resolution`]).
    pub resolution: f64,
    /// Kept samples it changes by more than one reading resolves ([`sample_resolution`]).
    pub resolved: usize,
    /// Its change to the residual at the kept samples (for the collinearity check).
    pub change: Vec<f64>,
    /// Effective number of independent samples of what it leaves ([`effective_n`]).
    pub n_eff: f64,
}

impl Judged {
    /// Whether it passes both tests of the module header.
    pub fn significant(&self) -> bool {
        self.delta_bic >= MIN_DELTA_BIC
            && self.explained >= MIN_EXPLAINED
            && self.explained_total >= MIN_EXPLAINED_TOTAL
            && self.support >= MIN_SUPPORT
            && (self.change_rms >= self.resolution
                || self.resolved as f64
                    >= (MIN_RESOLVED_SHARE * self.n as f64).max(MIN_SUPPORT as f64))
    }
}

/// Judges `kind` on top of `doc`, whose residual of the effect's channel is `before`.
pub fn judge(ctx: &Ctx<'_>, doc: &ModelDoc, kind: EffectKind, before: &Residual) -> Option<Judged> {
    let proposal = propose(kind, ctx, doc)?;
    judge_proposal(ctx, doc, proposal, before)
}

/// [`judge`], the effects already added on the candidate's channel refitted with it in
/// place (`joint`, pressure channel): the first effect fitted to a pressure residual holding
/// two absorbs what of the second its form can — a rod leak to ambient relaxes the chamber
/// pressures as wall heat transfer does — and the second, fitted on top of that with the
/// first held, explains nothing. Here the candidate, the earlier effects refitted with it,
/// and the candidate refitted once more are judged together, with the candidate's own
/// parameters counted (the earlier ones were already counted when they were added).
pub(super) fn judge_joint(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    kind: EffectKind,
    joint: &[EffectKind],
    before: &Residual,
) -> Option<Judged> {
    // The candidate on the model as it is, and fitted afresh (independent: side by side).
    // Nothing is judged where the fit afresh cannot be made.
    let (simple, fresh) = rayon::join(
        || judge(ctx, doc, kind, before),
        || judge_afresh(ctx, doc, kind, joint, before),
    );
    match (simple, fresh?) {
        (Some(a), Some(b)) => Some(if b.rss_after < a.rss_after { b } else { a }),
        (a, b) => a.or(b),
    }
}

/// [`judge_joint`]'s candidate fitted afresh: on the model without the channel's earlier
/// effects `joint`, then they on top of it, then it once more, judged together (the outer
/// `None`: the candidate could not be fitted).
fn judge_afresh(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    kind: EffectKind,
    joint: &[EffectKind],
    before: &Residual,
) -> Option<Option<Judged>> {
    let mut edits: Vec<Edit> = joint
        .iter()
        .filter_map(|k| k.section())
        .map(Edit::RemoveSection)
        .collect();
    let base = doc.with(&edits);
    let first = propose(kind, ctx, &base)?;
    edits.extend(first.edits.iter().cloned());
    let mut cur = doc.with(&edits);
    for other in joint {
        if let Some(p) = propose(*other, ctx, &cur) {
            cur = cur.with(&p.edits);
            edits.extend(p.edits);
        }
    }
    let last = propose(kind, ctx, &cur)?;
    edits.extend(last.edits.iter().cloned());
    let proposal = Proposal {
        kind,
        params: last.params,
        edits,
        k: last.k,
    };
    Some(judge_proposal(ctx, doc, proposal, before))
}

/// Judges `proposal` applied on top of `doc`, whose residual of its channel is `before`.
pub(super) fn judge_proposal(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    proposal: Proposal,
    before: &Residual,
) -> Option<Judged> {
    let ch = proposal.kind.judged_on(ctx.data);
    judge_on(ctx, doc, proposal, before, ch)
}

/// [`judge_proposal`] on the channel `ch`, whose residual on `doc` is `before`.
fn judge_on(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    proposal: Proposal,
    before: &Residual,
    ch: ChannelId,
) -> Option<Judged> {
    let model = doc.with(&proposal.edits).model().ok()?;
    let after = residual(ctx.data, ctx.band, &model, ch)?;
    let model = doc.model().ok()?;
    let n = before.kept.len().min(after.kept.len());
    if n < 2 {
        return None;
    }
    let rss_before = before.rss();
    let rss_after = after.rss();
    let change: Vec<f64> = after
        .kept
        .iter()
        .zip(&before.kept)
        .map(|(a, b)| a - b)
        .collect();
    let peak = robust_peak(&change);
    let (mut s0, mut s1, mut sc, mut support) = (0.0, 0.0, 0.0, 0usize);
    for ((c, b), a) in change.iter().zip(&before.kept).zip(&after.kept) {
        if peak > 0.0 && c.abs() > 0.1 * peak {
            s0 += b * b;
            s1 += a * a;
            sc += c * c;
            support += 1;
        }
    }
    let res = resolution(ch, &model);
    let sample_res = sample_resolution(ch, &model);
    let explained = if s0 > 0.0 { (s0 - s1) / s0 } else { 0.0 };
    let nf = effective_n(&after.kept);
    let delta_bic = if rss_after > 0.0 && rss_before > 0.0 {
        nf * (rss_before / rss_after).ln() - proposal.k as f64 * nf.ln()
    } else {
        f64::NEG_INFINITY
    };
    Some(Judged {
        proposal,
        rss_before,
        rss_after,
        n,
        delta_bic,
        explained,
        explained_total: if rss_before > 0.0 {
            (rss_before - rss_after) / rss_before
        } else {
            0.0
        },
        support,
        change_rms: if support > 0 {
            (sc / support as f64).sqrt()
        } else {
            0.0
        },
        resolution: res,
        resolved: change.iter().filter(|c| c.abs() > sample_res).count(),
        change,
        n_eff: nf,
    })
}

/// The number of independent samples a residual's kept samples are worth: `n / (1 + 2·Σρ_k)`
/// over its autocorrelation's initial positive sequence (Geyer's estimator).
///
/// What is left after a fit is not white: the differentiator and the band filter smooth
/// it, a controller colours it, and a slightly wrong model leaves slow patterns. Counting
/// raw samples in the BIC then over-counts the evidence in proportion to the sample rate
/// and the smoothing, so that null logs at 20 kHz named effects that 5 kHz logs did not;
/// the effective count makes `ΔBIC` the same evidence at any rate.
pub fn effective_n(kept: &[f64]) -> f64 {
    let n = kept.len();
    if n < 4 {
        return n as f64;
    }
    let mean = kept.iter().sum::<f64>() / n as f64;
    let c: Vec<f64> = kept.iter().map(|v| v - mean).collect();
    let g0 = sumsq_of(&c);
    if g0 <= 0.0 {
        return n as f64;
    }
    let rho = |k: usize| -> f64 {
        c.iter()
            .zip(c.iter().skip(k))
            .map(|(a, b)| a * b)
            .sum::<f64>()
            / g0
    };
    // Sum pairs ρ(2m−1) + ρ(2m) while they stay positive (the initial positive sequence).
    let mut sum = 0.0;
    let mut k = 1;
    while k + 1 < n / 4 {
        let pair = rho(k) + rho(k + 1);
        if pair <= 0.0 {
            break;
        }
        sum += pair;
        k += 2;
    }
    (n as f64 / (1.0 + 2.0 * sum)).clamp(2.0, n as f64)
}

fn sumsq_of(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum()
}

/// The size of a change "where it acts": the 98th percentile of its magnitude. The largest
/// value alone is the wrong yardstick: a lag's change follows dF/dt, and a handful of
/// Coulomb reversals make spikes that would shrink "where it acts" to a few samples.
pub fn robust_peak(change: &[f64]) -> f64 {
    let mut mags: Vec<f64> = change.iter().map(|c| c.abs()).collect();
    if mags.is_empty() {
        return 0.0;
    }
    let k = ((mags.len() - 1) as f64 * 0.98).round() as usize;
    let (_, v, _) = mags.select_nth_unstable_by(k, f64::total_cmp);
    *v
}

/// The basis fits of one selection step, by number of parameters ([`outdone_by_basis`]).
pub(super) type BasisFits = Vec<(usize, Option<(f64, Vec<Term>)>)>;

/// Whether `k` parameters of the discovery basis, fitted to the same residual at the same
/// samples, explain significantly more than the named force effect `j` of `k` parameters
/// (`n_eff·ln(RSS_named/RSS_basis) ≥ MIN_DELTA_BIC`): then the residual has a structure of
/// another form, which the named effect's parameters would absorb ([`super::discover`]).
///
/// `fits` keeps the basis fits of one selection step by their number of parameters: they
/// depend only on `doc`, the force residual and `k`, so effects of the same `k` share one.
pub(super) fn outdone_by_basis(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    j: &Judged,
    before: &Residual,
    fits: &RefCell<BasisFits>,
) -> bool {
    // A force reading's error is one number on the force channel, which reads the sections'
    // sum (a constant force, a share of the motor force); its second is the readings'
    // difference, fitted on the slave-force channel, which no basis term sees.
    let k = if j.proposal.kind.sensor() {
        1
    } else {
        j.proposal.k
    };
    if j.proposal.kind.channel() != ChannelId::Force || k == 0 {
        return false;
    }
    let known = fits
        .borrow()
        .iter()
        .find(|(n, _)| *n == k)
        .map(|(_, f)| f.clone());
    let fit = known.unwrap_or_else(|| {
        let f = super::discover::basis_rss(ctx, doc, &before.kept, k);
        fits.borrow_mut().push((k, f.clone()));
        f
    });
    let Some((rss_basis, terms)) = fit else {
        return false;
    };
    // The basis terms that do better are the effect's own form (with a constant at most):
    // the same form, fitted with a plainer law (a bare sign against a regularised one), not
    // another form its parameters would absorb.
    let own = j.proposal.kind.basis_form();
    if terms.iter().all(|t| *t == Term::One || own.contains(t)) {
        return false;
    }
    rss_basis > 0.0
        && j.rss_after > 0.0
        && j.n_eff * (j.rss_after / rss_basis).ln() >= MIN_DELTA_BIC
}

/// Whether the significant sensor candidate `j` (on top of `doc`) is the channel's reading
/// (module header): its residual below that of every candidate of `physical` (the step's
/// judgements of the physical effects of its channel), and what it leaves on the channel
/// that compares the readings themselves ([`reading_channel`]) at the noise floor. Where
/// that channel is another than its own (a force reading's, on the slave-force channel),
/// the candidate must also pass the selection's rules there: a reading error shows where
/// one reading is compared with another, a force on the piston does not.
pub(super) fn sensor_reading_holds(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    j: &Judged,
    physical: &[&Judged],
) -> bool {
    if physical.iter().any(|p| p.rss_after <= j.rss_after) {
        return false;
    }
    let ch = reading_channel(j.proposal.kind);
    if ch != j.proposal.kind.channel() {
        let Some(before) = doc
            .model()
            .ok()
            .and_then(|m| residual(ctx.data, ctx.band, &m, ch))
        else {
            return false;
        };
        let seen = judge_on(ctx, doc, j.proposal.clone(), &before, ch);
        if !seen.is_some_and(|r| r.significant()) {
            return false;
        }
    }
    let Ok(model) = doc.with(&j.proposal.edits).model() else {
        return false;
    };
    let Some(raw) = band_raw(ctx.data, ctx.band, &model, ch) else {
        return false;
    };
    let after = full_of_raw(ctx.data, ctx.band, ch, &raw);
    let u = super::unexplained::judge(ctx.data, ctx.band, &model, ch, &after, &after);
    let excess = (u.json.rms.powi(2) - u.json.noise_floor.powi(2))
        .max(0.0)
        .sqrt();
    !u.json.structured && excess < resolution(ch, &model)
}

/// The channel on which a sensor effect's readings are compared with each other: the
/// pressure transducers' on the pressure channel (read against the chambers' replay), the
/// force readings' on the slave-force channel (the slave section's reading against the
/// master's, which the slave follows). The force balance reads both sections' sum, so there
/// an offset is a constant force and a gain a share of the motor force; only the readings'
/// difference tells the sensor from the piston.
pub(super) fn reading_channel(kind: EffectKind) -> ChannelId {
    match kind {
        EffectKind::ForceOffset | EffectKind::ForceGain => ChannelId::SlaveForce,
        _ => kind.channel(),
    }
}
