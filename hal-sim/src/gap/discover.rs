//! Beyond the library (`docs/formats.md`, "Beyond the library — discovered terms"): the force the
//! model lacks, when no named effect describes it, as a sparse sum over a fixed basis
//! ([`Term`]) — `1`, `x`, `x^2`, `x^3`, `v`, `v|v|`, `sgn(v)`, `x*sgn(v)`, `a`, `f_motor`,
//! `p_a-p_b`, `t`, `t*sgn(v)` and `sin, cos(2πx/p)` with `p` one of the machine's own
//! periods ([`machine_periods`]).
//!
//! **Only periods the machine can produce.** A sine in x fitted at any period is a
//! curve-fitting device: over a stroke a few periods long it bends to any smooth force (a
//! cubic spring read as "periodic in x at 56 mm"). The periodic pair is therefore offered
//! only at the pole pitch and the encoder period of the model, their harmonics (½, ⅓, ¼)
//! and the magnetic period of a pole pair (twice the pitch, with its ⅔), each refined by at
//! most [`PERIOD_REFINE`] either way: a force periodic in x comes from the magnets or the
//! scale, or it is not a periodic force.
//!
//! The terms are a candidate of the forward selection like any named effect
//! ([`super::candidate::EffectKind::ExtraForce`]): each proposal adds the one term (or the
//! periodic pair with its period) that lowers the force residual most, all present terms
//! refitted jointly with it, and it is added only under the same significance rules
//! ([`super::select`]). The terms enter the model as `[effects.extra_force]`, so the force
//! replay subtracts them ([`super::residuals::force_raw`]) and every later fit sees what is
//! left.
//!
//! **Competition** ([`basis_rss`]): a named force effect of `k` parameters is eligible only
//! if no `k` parameters of the basis, fitted to the same residual at the same samples,
//! explain significantly more (`n_eff·ln(RSS_named/RSS_basis) ≥ MIN_DELTA_BIC`, the
//! selection's own evidence yardstick at equal `k`). A v|v| drag then does not become a
//! viscous correction, nor a rising friction a viscous plus Stribeck friction: the named
//! effect would absorb a force of another form.
//!
//! The least squares are nalgebra's ([`super::fit::lstsq`]) on columns scaled to unit RMS
//! (x in metres, t in seconds and f_motor in kilonewtons differ by orders of magnitude).

use rayon::prelude::*;

use crate::plant::fastmath::sin_cos;
use crate::plant::model::extra_force::Term;
use crate::plant::model::{model_section, MachineModel};

use super::candidate::{kept_span, EffectKind, Proposal};
use super::channel::ChannelId;
use super::ctx::{kept_x, Ctx};
use super::doc::{Edit, ModelDoc};
use super::fit::{lstsq, minimise_1d_par};
use super::residuals::{band_force_raw, basis_key, extra_states};

/// Shortest period of the periodic pair searched, m.
pub const MIN_PERIOD_M: f64 = 2e-3;

/// How far either way of a machine period ([`machine_periods`]) the periodic pair's period
/// is refined, as a share of it.
pub const PERIOD_REFINE: f64 = 0.02;

/// Grid points of the refinement around the best machine period, before the golden section.
pub const PERIOD_GRID: usize = 5;

/// The periods the machine can produce a force at, m (module header): the pole pitch and
/// the encoder period of `model`, each with its harmonics ½, ⅓, ¼ and the sub-harmonics
/// 2 and ⅔ (a pole pair's period and its third harmonic), at least [`MIN_PERIOD_M`],
/// ascending, each once.
pub fn machine_periods(model: &MachineModel) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::new();
    for base in [model.motor.pole_pitch_m, model.encoder.period_m] {
        for (m, n) in [
            (1.0, 1.0),
            (1.0, 2.0),
            (1.0, 3.0),
            (1.0, 4.0),
            (2.0, 1.0),
            (2.0, 3.0),
        ] {
            let p = base * m / n;
            let known = out.iter().any(|q| (q / p - 1.0).abs() < 1e-9);
            if p.is_finite() && p >= MIN_PERIOD_M && !known {
                out.push(p);
            }
        }
    }
    out.sort_by(f64::total_cmp);
    out
}

/// The non-periodic terms, in the order of [`Term::ALL`].
fn plain_terms() -> impl Iterator<Item = Term> {
    Term::ALL.into_iter().filter(|t| !t.periodic())
}

/// A set of terms fitted to a residual.
#[derive(Clone, Debug, PartialEq)]
pub struct TermFit {
    /// Each term with its coefficient, SI.
    pub terms: Vec<(Term, f64)>,
    /// Period of the periodic pair, m, if it is in.
    pub period_m: Option<f64>,
    /// Residual sum of squares left at the kept samples.
    pub rss: f64,
}

/// What the basis is evaluated on: the states of every row (made from the log and the model
/// when a column is filtered anew) and the kept samples' x.
struct Basis<'a> {
    ctx: &'a Ctx<'a>,
    model: MachineModel,
    span_m: f64,
    /// The periods the periodic pair may take ([`machine_periods`]).
    periods: Vec<f64>,
    /// The band-filtered columns of the non-periodic terms, computed once.
    plain: Vec<(Term, Vec<f64>)>,
}

impl<'a> Basis<'a> {
    fn new(ctx: &'a Ctx<'a>, model: &MachineModel) -> Self {
        let xk = kept_x(ctx);
        let mut b = Basis {
            ctx,
            model: model.clone(),
            span_m: kept_span(&xk),
            periods: machine_periods(model),
            plain: Vec::new(),
        };
        // The columns depend on the log, and `f_motor`'s on the actuator lag: the band keeps
        // them for every later proposal, refit and competition.
        b.plain = plain_terms()
            .collect::<Vec<_>>()
            .par_iter()
            .map(|&t| {
                let key = basis_key(t, ctx.data, model);
                let kept = ctx
                    .band
                    .basis_columns
                    .get_or_make(key, || vec![b.filtered(t, 1.0)]);
                (t, kept.first().cloned().unwrap_or_default())
            })
            .collect();
        b
    }

    /// The band-filtered column of `term` at the force channel's kept samples.
    fn column(&self, term: Term, period_m: f64) -> Vec<f64> {
        if let Some((_, c)) = self.plain.iter().find(|(t, _)| *t == term) {
            return c.clone();
        }
        let pair = self.periodic_pair(period_m);
        match (term, pair.as_slice()) {
            (Term::Sin, [sin, _]) => sin.clone(),
            (Term::Cos, [_, cos]) => cos.clone(),
            _ => self.filtered(term, period_m),
        }
    }

    /// [`Self::column`], filtered anew.
    fn filtered(&self, term: Term, period_m: f64) -> Vec<f64> {
        let raw: Vec<f64> = extra_states(
            self.ctx.data,
            &self.model,
            (term == Term::FMotor).then_some(self.ctx.data.force_align_s),
        )
        .map(|s| term.value(&s, period_m))
        .collect();
        self.ctx.band.kept(self.ctx.data, ChannelId::Force, &raw)
    }

    /// The band-filtered sin and cos columns of period `period_m`: both from one angle per
    /// row (the values of [`Term::Sin`] and [`Term::Cos`] to within 10⁻¹⁴, by the plant's
    /// fast sine), the two filters side by side. They depend on x and the band alone, and the
    /// period search visits the same grid at every selection step: the band keeps them.
    fn periodic_pair(&self, period_m: f64) -> std::sync::Arc<Vec<Vec<f64>>> {
        let band = self.ctx.band;
        band.columns.get_or_make(period_m.to_bits(), || {
            let (sin, cos): (Vec<f64>, Vec<f64>) = self
                .ctx
                .data
                .x_m
                .iter()
                .map(|x| sin_cos(std::f64::consts::TAU * x / period_m))
                .unzip();
            let filter = |raw: &[f64]| band.kept(self.ctx.data, ChannelId::Force, raw);
            let (s, c) = rayon::join(|| filter(&sin), || filter(&cos));
            vec![s, c]
        })
    }

    /// Least squares of `y` on `terms` (their columns given), the columns scaled to unit
    /// RMS; coefficients back in SI.
    fn fit(cols: &[(Term, Vec<f64>)], y: &[f64], period_m: Option<f64>) -> Option<TermFit> {
        let scales: Vec<f64> = cols
            .iter()
            .map(|(_, c)| {
                let ms = c.iter().map(|v| v * v).sum::<f64>() / c.len().max(1) as f64;
                ms.sqrt()
            })
            .collect();
        if scales.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return None;
        }
        let scaled: Vec<Vec<f64>> = cols
            .iter()
            .zip(&scales)
            .map(|((_, c), s)| c.iter().map(|v| v / s).collect())
            .collect();
        let (theta, rss) = lstsq(&scaled, y)?;
        Some(TermFit {
            terms: cols
                .iter()
                .zip(theta.iter().zip(&scales))
                .map(|((t, _), (th, s))| (*t, th / s))
                .collect(),
            period_m,
            rss,
        })
    }

    /// The best period for the periodic pair on top of `fixed` columns: each machine period
    /// ([`machine_periods`]) no longer than half the span of x, the best refined within
    /// [`PERIOD_REFINE`] of it by a grid and golden section on ln p.
    fn periodic(&self, fixed: &[(Term, Vec<f64>)], y: &[f64]) -> Option<TermFit> {
        let hi = 0.5 * self.span_m;
        let with = |p: f64| -> Option<TermFit> {
            let mut cols = fixed.to_vec();
            let pair = self.periodic_pair(p);
            let (sin, cos) = match pair.as_slice() {
                [sin, cos] => (sin.clone(), cos.clone()),
                _ => return None,
            };
            cols.push((Term::Sin, sin));
            cols.push((Term::Cos, cos));
            Basis::fit(&cols, y, Some(p))
        };
        let candidates: Vec<f64> = self.periods.iter().copied().filter(|p| *p <= hi).collect();
        let scan: Vec<Option<(f64, f64)>> = candidates
            .par_iter()
            .map(|&p| with(p).map(|f| (p, f.rss)))
            .collect();
        let mut best: Option<(f64, f64)> = None;
        for (p, rss) in scan.into_iter().flatten() {
            if best.is_none_or(|b| rss < b.1) {
                best = Some((p, rss));
            }
        }
        let (p0, _) = best?;
        let (lo, up) = (
            (p0 * (1.0 - PERIOD_REFINE)).ln(),
            (p0 * (1.0 + PERIOD_REFINE)).ln(),
        );
        let (lnp, _) = minimise_1d_par(lo, up, PERIOD_GRID, 10, |lnp| {
            with(lnp.exp()).map(|f| f.rss)
        })?;
        with(lnp.exp())
    }

    /// The best fit of `present` (refitted) plus one more term, or one more term with the
    /// constant, or a whole polynomial in x of degree 2 or 3, or the periodic pair, on `y`;
    /// `None` if nothing fits. Returns the fit and the number of new parameters. A term comes with the constant because most forms are
    /// about an origin of their own (a spring about its rest point x0): alone, `x` cannot
    /// fit `−k·(x − x0)` over a stroke far from x = 0. Candidates of different sizes are
    /// ranked by `n·ln(RSS₀/RSS) − k·ln n`; whether the chosen one is significant is the
    /// selection's judgement, and a constant that brings nothing is pruned there.
    fn extend(
        &self,
        present: &[(Term, Vec<f64>)],
        y: &[f64],
        period_m: Option<f64>,
    ) -> Option<(TermFit, usize)> {
        let n = y.len().max(2) as f64;
        let rss0 = match Basis::fit(present, y, period_m) {
            Some(f) => f.rss,
            None => y.iter().map(|v| v * v).sum(),
        };
        let score =
            |rss: f64, k: usize| n * (rss0 / rss.max(f64::MIN_POSITIVE)).ln() - k as f64 * n.ln();
        let mut best: Option<(TermFit, usize)> = None;
        let mut consider = |f: Option<TermFit>, k: usize| {
            if let Some(f) = f {
                if best
                    .as_ref()
                    .is_none_or(|(b, bk)| score(f.rss, k) > score(b.rss, *bk))
                {
                    best = Some((f, k));
                }
            }
        };
        let has_one = present.iter().any(|(p, _)| *p == Term::One);
        for t in plain_terms() {
            if present.iter().any(|(p, _)| *p == t) {
                continue;
            }
            let mut cols = present.to_vec();
            cols.push((t, self.column(t, 1.0)));
            consider(Basis::fit(&cols, y, period_m), 1);
            if !has_one && t != Term::One {
                cols.push((Term::One, self.column(Term::One, 1.0)));
                consider(Basis::fit(&cols, y, period_m), 2);
            }
        }
        // A polynomial in x about a point of its own (a hardening spring −k₃·(x − x₀)³) is
        // one form: its expansion's terms are only worth anything together, and one at a
        // time the first (x³ alone) would bend to fit what the others should.
        for degree in [Term::X2, Term::X3] {
            let mut cols = present.to_vec();
            let mut new = 0usize;
            for t in [Term::One, Term::X, Term::X2, Term::X3] {
                if !cols.iter().any(|(p, _)| *p == t) {
                    cols.push((t, self.column(t, 1.0)));
                    new += 1;
                }
                if t == degree {
                    break;
                }
            }
            if new > 2 {
                consider(Basis::fit(&cols, y, period_m), new);
            }
        }
        if !present.iter().any(|(p, _)| p.periodic()) {
            consider(self.periodic(present, y), 3);
        }
        best
    }
}

/// The force residual of `doc` without its extra force, at the kept samples, and that
/// model.
fn residual_without_extra(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<(Vec<f64>, MachineModel)> {
    let base = doc.with(&[Edit::RemoveSection(model_section!(effects.extra_force))]);
    let model = base.model().ok()?;
    let raw = band_force_raw(ctx.data, ctx.band, &model);
    Some((ctx.band.kept(ctx.data, ChannelId::Force, &raw), model))
}

/// The terms present in `doc`'s extra force, with the period.
pub fn present_terms(doc: &ModelDoc) -> (Vec<Term>, Option<f64>) {
    let Ok(model) = doc.model() else {
        return (Vec::new(), None);
    };
    match &model.effects.extra_force {
        Some(e) => (
            e.parsed()
                .unwrap_or_default()
                .iter()
                .map(|(t, _)| *t)
                .collect(),
            e.period_m,
        ),
        None => (Vec::new(), None),
    }
}

/// The terms `proposal` (an extra-force proposal) adds to those `doc` already has; the
/// constant is left out (a form's origin, as a spring's rest point, comes with it).
pub fn added_terms(doc: &ModelDoc, proposal: &Proposal) -> Vec<Term> {
    let (present, _) = present_terms(doc);
    proposal
        .params
        .iter()
        .filter_map(|(name, _)| Term::parse(name))
        .filter(|t| *t != Term::One && !present.contains(t))
        .collect()
}

/// The proposal setting the extra force to `fit`, `k` new parameters.
fn proposal(fit: &TermFit, k: usize) -> Proposal {
    let mut params: Vec<(&'static str, f64)> =
        fit.terms.iter().map(|(t, c)| (t.name(), *c)).collect();
    if let Some(p) = fit.period_m {
        params.push(("period_m", p));
    }
    Proposal {
        kind: EffectKind::ExtraForce,
        params,
        edits: vec![Edit::SetExtraForce {
            terms: fit.terms.iter().map(|(t, c)| (t.name(), *c)).collect(),
            period_m: fit.period_m,
        }],
        k,
    }
}

/// The columns of the present terms (the periodic ones at `period_m`).
fn present_columns(
    basis: &Basis<'_>,
    terms: &[Term],
    period_m: Option<f64>,
) -> Vec<(Term, Vec<f64>)> {
    terms
        .iter()
        .map(|&t| (t, basis.column(t, period_m.unwrap_or(1.0))))
        .collect()
}

/// The extra force of `doc` with one more term (or the periodic pair), every term refitted:
/// the selection's `extra_force` candidate.
pub fn next_term(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let (y, model) = residual_without_extra(ctx, doc)?;
    let basis = Basis::new(ctx, &model);
    let (terms, period) = present_terms(doc);
    let cols = present_columns(&basis, &terms, period);
    let (fit, k) = basis.extend(&cols, &y, period)?;
    Some(proposal(&fit, k))
}

/// The extra force of `doc`, its terms refitted with everything else in place (the
/// selection's back-fitting); `None` if it has none.
pub fn refit(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let (terms, period) = present_terms(doc);
    if terms.is_empty() {
        return None;
    }
    let (y, model) = residual_without_extra(ctx, doc)?;
    let basis = Basis::new(ctx, &model);
    let cols = present_columns(&basis, &terms, period);
    let fit = Basis::fit(&cols, &y, period)?;
    Some(proposal(&fit, 0))
}

/// `doc` without the discovered `term` (the periodic pair together), the other terms
/// refitted, and the proposal that puts it back (its own parameters counted): for judging
/// each present term as if it were added last. `None` if `term` is not present.
pub fn without_term(ctx: &Ctx<'_>, doc: &ModelDoc, term: Term) -> Option<(ModelDoc, Proposal)> {
    let (terms, period) = present_terms(doc);
    if !terms.contains(&term) {
        return None;
    }
    let (y, model) = residual_without_extra(ctx, doc)?;
    let basis = Basis::new(ctx, &model);
    let all = present_columns(&basis, &terms, period);
    let rest: Vec<(Term, Vec<f64>)> = all
        .iter()
        .filter(|(t, _)| *t != term && !(term.periodic() && t.periodic()))
        .cloned()
        .collect();
    let rest_period = period.filter(|_| rest.iter().any(|(t, _)| t.periodic()));
    let without = if rest.is_empty() {
        doc.with(&[Edit::RemoveSection(model_section!(effects.extra_force))])
    } else {
        let fit = Basis::fit(&rest, &y, rest_period)?;
        doc.with(&proposal(&fit, 0).edits)
    };
    let back = Basis::fit(&all, &y, period)?;
    let k = if term.periodic() { 3 } else { 1 };
    Some((without, proposal(&back, k)))
}

/// The smallest RSS `k` new basis parameters leave on the kept residual `y` of `doc`'s
/// model (greedy: the best term, then the best next one, …; the periodic pair counts 3),
/// for the competition with a named effect of `k` parameters (module header).
/// Returns the RSS and the terms that reach it.
pub fn basis_rss(ctx: &Ctx<'_>, doc: &ModelDoc, y: &[f64], k: usize) -> Option<(f64, Vec<Term>)> {
    let model = doc.model().ok()?;
    let basis = Basis::new(ctx, &model);
    let (present, _) = present_terms(doc);
    let mut cols: Vec<(Term, Vec<f64>)> = Vec::new();
    let mut used = 0usize;
    let mut best_rss: Option<(f64, Vec<Term>)> = None;
    while used < k {
        let mut best: Option<(TermFit, usize)> = None;
        for t in plain_terms() {
            if present.contains(&t) || cols.iter().any(|(p, _)| *p == t) {
                continue;
            }
            let mut c = cols.clone();
            c.push((t, basis.column(t, 1.0)));
            if let Some(f) = Basis::fit(&c, y, None) {
                if best.as_ref().is_none_or(|(b, _)| f.rss < b.rss) {
                    best = Some((f, 1));
                }
            }
        }
        let periodic_in =
            present.iter().any(|t| t.periodic()) || cols.iter().any(|(t, _)| t.periodic());
        if !periodic_in && used + 3 <= k {
            if let Some(f) = basis.periodic(&cols, y) {
                if best.as_ref().is_none_or(|(b, _)| f.rss < b.rss) {
                    best = Some((f, 3));
                }
            }
        }
        let Some((f, n)) = best else { break };
        used += n;
        best_rss = Some((f.rss, f.terms.iter().map(|(t, _)| *t).collect()));
        let period = f.period_m.unwrap_or(1.0);
        cols = f
            .terms
            .iter()
            .map(|(t, _)| (*t, basis.column(*t, period)))
            .collect();
    }
    best_rss
}

/// A physical reading of a set of terms ("linear in x: a spring of 1800 N/m about
/// x = 0.090 m"; "∝ f_motor: the motor force is 5.0 % lower than logged"; …).
pub fn reading(terms: &[(Term, f64)], period_m: Option<f64>) -> String {
    let c = |t: Term| terms.iter().find(|(p, _)| *p == t).map(|(_, c)| *c);
    let mut parts = Vec::new();
    let cubic = c(Term::X3).filter(|k| *k != 0.0);
    match (cubic, c(Term::X), c(Term::One)) {
        (Some(k3), kx, one) => parts.push(cubic_reading(
            k3,
            c(Term::X2).unwrap_or(0.0),
            kx.unwrap_or(0.0),
            one.unwrap_or(0.0),
        )),
        (None, Some(kx), one) if kx != 0.0 => {
            let x0 = -one.unwrap_or(0.0) / kx;
            parts.push(format!(
                "linear in x: a spring of {:.0} N/m about x = {:.3} m",
                -kx, x0
            ));
        }
        (None, _, Some(one)) => parts.push(format!("a constant force of {one:.1} N toward +x")),
        _ => {}
    }
    for &(t, v) in terms {
        let s = match t {
            Term::One | Term::X | Term::X3 | Term::Cos => continue,
            Term::X2 if cubic.is_some() => continue,
            Term::X2 => format!("quadratic in x: {v:.1} N/m²"),
            Term::XSgnV => format!(
                "∝ x·sgn(v): a friction against the motion that {} by {:.0} N per m of x",
                if v < 0.0 { "grows" } else { "shrinks" },
                v.abs()
            ),
            Term::V => format!("∝ v: a viscous force of {:.2} N·s/m", -v),
            Term::VAbsV => format!("∝ v|v|: a quadratic drag of {:.2} N·s²/m²", -v),
            Term::SgnV => format!("∝ sgn(v): a friction of {:.1} N against the motion", -v),
            Term::A => format!("∝ a: {:.3} kg more moving mass than modelled", -v),
            Term::FMotor => format!(
                "∝ f_motor: the motor force is {:.1} % {} than logged",
                100.0 * v.abs(),
                if v < 0.0 { "lower" } else { "higher" }
            ),
            Term::DeltaP => format!("∝ p_a-p_b: {:.3e} m² more gas area", v),
            Term::T => format!("a force drifting {v:.2} N/s toward +x"),
            Term::TSgnV => format!(
                "friction {} {:.2} N/s",
                if v < 0.0 { "rising" } else { "falling" },
                v.abs()
            ),
            Term::Sin => {
                let a = v.hypot(c(Term::Cos).unwrap_or(0.0));
                format!(
                    "periodic in x: {a:.1} N at a period of {:.4} m",
                    period_m.unwrap_or(0.0)
                )
            }
        };
        parts.push(s);
    }
    parts.join("; ")
}

/// The reading of the cubic `k3·x³ + k2·x² + k1·x + k0`, N, about its point of
/// inflection `x0 = −k2/(3·k3)`: `k3·(x − x0)³ + k·(x − x0) + F0`, a spring that hardens
/// (`k3 < 0`: the restoring force grows faster than linearly) or softens.
fn cubic_reading(k3: f64, k2: f64, k1: f64, k0: f64) -> String {
    let x0 = -k2 / (3.0 * k3);
    let k = k1 - 3.0 * k3 * x0 * x0;
    let f0 = ((k3 * x0 + k2) * x0 + k1) * x0 + k0;
    format!(
        "cubic in x: a {} spring of {:.3e} N/m³ about x = {:.3} m, with {:.0} N/m linear and \
         {:.1} N toward +x there",
        if k3 < 0.0 { "hardening" } else { "softening" },
        -k3,
        x0,
        // Rounded first, so that a tiny negative reads 0 rather than −0.
        (-k).round() + 0.0,
        (10.0 * f0).round() / 10.0 + 0.0
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readings_give_the_physical_quantities() {
        let r = reading(&[(Term::X, -1800.0), (Term::One, 162.0)], None);
        assert!(r.contains("1800 N/m") && r.contains("x = 0.090 m"), "{r}");
        let r = reading(&[(Term::FMotor, -0.05)], None);
        assert!(r.contains("5.0 % lower"), "{r}");
        let r = reading(&[(Term::TSgnV, -5.4)], None);
        assert!(r.contains("rising 5.40 N/s"), "{r}");
        let r = reading(&[(Term::VAbsV, -9.0)], None);
        assert!(r.contains("9.00 N·s²/m²"), "{r}");
        // −9e5·(x − 0.095)³ expanded: a hardening spring about 0.095 m, nothing linear.
        let r = reading(
            &[
                (Term::X3, -9e5),
                (Term::X2, 256_500.0),
                (Term::X, -24_367.5),
                (Term::One, 771.6375),
            ],
            None,
        );
        assert!(
            r.contains("hardening spring of 9.000e5 N/m³ about x = 0.095 m")
                && r.contains("with 0 N/m linear and 0.0 N"),
            "{r}"
        );
        let r = reading(&[(Term::XSgnV, -700.0), (Term::SgnV, 63.0)], None);
        assert!(r.contains("grows by 700 N per m of x"), "{r}");
    }
}
