//! Beyond the library (`docs/formats.md`, "Beyond the library — discovered terms"): the force the
//! model lacks, when no named effect describes it, as a sparse sum over a fixed basis
//! ([`Term`]) — `1`, `x`, `x^2`, `v`, `v|v|`, `sgn(v)`, `a`, `f_motor`, `p_a-p_b`, `t`,
//! `t*sgn(v)` and `sin, cos(2πx/p)` with `p` fitted.
//!
//! The terms are a candidate of the forward selection like any named effect
//! ([`super::effects::EffectKind::ExtraForce`]): each proposal adds the one term (or the
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

use std::fmt::Write as _;

use crate::plant::model::extra_force::Term;
use crate::plant::model::{model_section, MachineModel};

use super::columns::{force_combination, motor_shift, term_columns};
use super::doc::{Edit, ModelDoc};
use super::effects::{kept_span, kept_x, Ctx, EffectKind, Proposal};
use super::fit::{lstsq, minimise_1d_par};

/// Shortest period of the periodic pair, m.
pub const MIN_PERIOD_M: f64 = 2e-3;

/// Harmonics and sub-harmonics of the machine's own periods the periodic pair may take: the
/// pole pitch and the encoder's period times and over 1..=`MACHINE_HARMONICS`.
pub const MACHINE_HARMONICS: u32 = 4;

/// How far a peak of the residual's spatial periodogram must stand above the periodogram's
/// median to be a period of its own ([`Basis::spectral_peak`]): a ripple's power over the
/// noise's, measured on the residual before any fit at that period.
pub const PEAK_OVER_MEDIAN: f64 = 25.0;

/// Spatial-frequency steps of the periodogram per inverse span of x.
const PERIODOGRAM_STEPS_PER_SPAN: f64 = 8.0;

/// Most kept samples the periodogram reads.
const PERIODOGRAM_SAMPLES: usize = 4096;

/// The share of `y`'s sum of squares the sine and cosine of spatial frequency `f` (1/m) at
/// positions `x` explain (least squares on the two columns).
fn pair_power(x: &[f64], y: &[f64], f: f64) -> f64 {
    let (mut ss, mut cc, mut sc, mut sy, mut cy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (xi, yi) in x.iter().zip(y) {
        let (s, c) = crate::plant::fastmath::sin_cos(std::f64::consts::TAU * f * xi);
        ss += s * s;
        cc += c * c;
        sc += s * c;
        sy += s * yi;
        cy += c * yi;
    }
    let det = ss * cc - sc * sc;
    if det <= 0.0 {
        return 0.0;
    }
    // The projection's sum of squares: [sy cy]·G⁻¹·[sy cy]ᵀ.
    (cc * sy * sy - 2.0 * sc * sy * cy + ss * cy * cy) / det
}

/// The sets a term may enter with (each with the term first): alone; with the constant (a
/// form about an origin of its own, as a spring about its rest point: alone, `x` cannot fit
/// `−k·(x − x0)` over a stroke far from x = 0); a power of x with every lower power and the
/// constant (a polynomial about an unknown point: `x^3` alone puts a hardening spring's
/// centre at the head, where none is); and the friction varying along the bore with its own
/// level (`x·sgn(v)` with `sgn(v)`).
fn families(t: Term) -> Vec<&'static [Term]> {
    match t {
        Term::One => vec![&[Term::One]],
        Term::X2 => vec![
            &[Term::X2],
            &[Term::X2, Term::One],
            &[Term::X2, Term::X, Term::One],
        ],
        Term::X3 => vec![
            &[Term::X3],
            &[Term::X3, Term::One],
            &[Term::X3, Term::X2, Term::X, Term::One],
        ],
        Term::XSgnV => vec![
            &[Term::XSgnV],
            &[Term::XSgnV, Term::One],
            &[Term::XSgnV, Term::SgnV],
        ],
        Term::X => vec![&[Term::X], &[Term::X, Term::One]],
        Term::V => vec![&[Term::V], &[Term::V, Term::One]],
        Term::VAbsV => vec![&[Term::VAbsV], &[Term::VAbsV, Term::One]],
        Term::SgnV => vec![&[Term::SgnV], &[Term::SgnV, Term::One]],
        Term::A => vec![&[Term::A], &[Term::A, Term::One]],
        Term::FMotor => vec![&[Term::FMotor], &[Term::FMotor, Term::One]],
        Term::DeltaP => vec![&[Term::DeltaP], &[Term::DeltaP, Term::One]],
        Term::T => vec![&[Term::T], &[Term::T, Term::One]],
        Term::TSgnV => vec![&[Term::TSgnV], &[Term::TSgnV, Term::One]],
        Term::Sin | Term::Cos => vec![],
    }
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

/// What the basis is evaluated on: the log's columns at the force channel's kept samples
/// (kept by the band for every later step) and the span of x there.
struct Basis<'a> {
    ctx: &'a Ctx<'a>,
    /// The motor forces' shift of the model the terms are fitted on, samples (`f_motor`).
    shift: f64,
    /// x at the force channel's kept samples, m.
    x_kept: Vec<f64>,
    span_m: f64,
    /// The periods the machine itself can produce ([`machine_periods`]).
    machine: Vec<f64>,
}

/// The periods at which the machine can produce a force periodic in x, m: the pole pitch
/// and the encoder's period (the N–N pitch), their harmonics and sub-harmonics up to
/// [`MACHINE_HARMONICS`], between [`MIN_PERIOD_M`] and half the span of x.
///
/// A periodic pair at any other period is a curve-fitting device: on a log hiding a
/// hardening spring (d09) a free period search fitted 49 N at 56 mm beside a constant and
/// an `x^2` term, a ripple no part of the machine makes, and a reader would have looked for
/// it. Another period is taken only where the residual's own spectrum shows it
/// ([`Basis::spectral_peak`]).
pub fn machine_periods(model: &MachineModel, span_m: f64) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::new();
    for base in [model.motor.pole_pitch_m, model.encoder.period_m] {
        for k in 1..=MACHINE_HARMONICS {
            for p in [base / f64::from(k), base * f64::from(k)] {
                let known = out.iter().any(|q| (q / p - 1.0).abs() < 1e-9);
                if !known && p >= MIN_PERIOD_M && p <= 0.5 * span_m {
                    out.push(p);
                }
            }
        }
    }
    out.sort_by(f64::total_cmp);
    out
}

impl<'a> Basis<'a> {
    fn new(ctx: &'a Ctx<'a>, model: &MachineModel) -> Self {
        let x_kept = kept_x(ctx);
        let span_m = kept_span(&x_kept);
        Basis {
            ctx,
            shift: motor_shift(ctx.data, model),
            machine: machine_periods(model, span_m),
            x_kept,
            span_m,
        }
    }

    /// The band-filtered column of `term` at the force channel's kept samples.
    fn column(&self, term: Term, period_m: f64) -> Vec<f64> {
        let mut out = vec![0.0; self.ctx.band.idx_force.len()];
        for (w, col) in term_columns(term, self.shift, period_m) {
            let kept = self.ctx.band.force_column(self.ctx.data, col);
            for (o, v) in out.iter_mut().zip(kept.iter()) {
                *o += w * v;
            }
        }
        out
    }

    /// The band-filtered sin and cos columns of period `period_m` (kept by the band: the
    /// period search visits the same grid at every selection step).
    fn periodic_pair(&self, period_m: f64) -> [Vec<f64>; 2] {
        [
            self.column(Term::Sin, period_m),
            self.column(Term::Cos, period_m),
        ]
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

    /// The best period for the periodic pair on top of `fixed` columns: one the machine
    /// can produce ([`machine_periods`]), or a peak of the residual's own spatial spectrum
    /// ([`Self::spectral_peak`]).
    fn periodic(&self, fixed: &[(Term, Vec<f64>)], y: &[f64]) -> Option<TermFit> {
        let with = |p: f64| -> Option<TermFit> {
            let mut cols = fixed.to_vec();
            let [sin, cos] = self.periodic_pair(p);
            cols.push((Term::Sin, sin));
            cols.push((Term::Cos, cos));
            Basis::fit(&cols, y, Some(p))
        };
        let mut periods = self.machine.clone();
        if let Some(p) = self.spectral_peak(fixed, y) {
            periods.push(p);
        }
        periods
            .iter()
            .filter_map(|&p| with(p))
            .min_by(|a, b| a.rss.total_cmp(&b.rss))
    }

    /// A period of its own in what `fixed` leaves of `y`: the highest local maximum of the
    /// spatial periodogram (sin and cos of x at the kept samples, a quick unfiltered scan)
    /// between [`MIN_PERIOD_M`] and half the span of x, inside the scanned range and at
    /// least [`PEAK_OVER_MEDIAN`] times the periodogram's median, refined on the filtered
    /// columns. A smooth force (a spring, a cubic) has its power at the longest periods and
    /// no peak inside; a ripple of a part of the machine the model does not name has one.
    fn spectral_peak(&self, fixed: &[(Term, Vec<f64>)], y: &[f64]) -> Option<f64> {
        let left: Vec<f64> = if fixed.is_empty() {
            y.to_vec()
        } else {
            let f = Basis::fit(fixed, y, None)?;
            let mut r = y.to_vec();
            for ((_, col), (_, c)) in fixed.iter().zip(&f.terms) {
                for (ri, v) in r.iter_mut().zip(col) {
                    *ri -= c * v;
                }
            }
            r
        };
        let (f_lo, f_hi) = (2.0 / self.span_m, 1.0 / MIN_PERIOD_M);
        let df = 1.0 / (PERIODOGRAM_STEPS_PER_SPAN * self.span_m);
        let steps = ((f_hi - f_lo) / df).ceil().min(4000.0) as usize;
        if steps < 3 {
            return None;
        }
        // At most `PERIODOGRAM_SAMPLES` of the kept samples, evenly spread: the scan's
        // resolution is the span's, not the count's.
        let every = self.x_kept.len().div_ceil(PERIODOGRAM_SAMPLES).max(1);
        let xs: Vec<f64> = self.x_kept.iter().step_by(every).copied().collect();
        let ys: Vec<f64> = left.iter().step_by(every).copied().collect();
        let power: Vec<f64> = (0..=steps)
            .map(|i| pair_power(&xs, &ys, f_lo + df * i as f64))
            .collect();
        let mut sorted = power.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
        let (i, peak) = power
            .windows(3)
            .enumerate()
            .filter(|(_, w)| w[1] > w[0] && w[1] >= w[2])
            .map(|(i, w)| (i + 1, w[1]))
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
        if !(median > 0.0 && peak >= PEAK_OVER_MEDIAN * median) {
            return None;
        }
        let f0 = f_lo + df * i as f64;
        let rss = |f: f64| -> Option<f64> {
            let mut cols = fixed.to_vec();
            let [sin, cos] = self.periodic_pair(1.0 / f);
            cols.push((Term::Sin, sin));
            cols.push((Term::Cos, cos));
            Basis::fit(&cols, y, None).map(|t| t.rss)
        };
        let (f, _) = minimise_1d_par(f0 - df, f0 + df, 3, 10, rss)?;
        Some(1.0 / f)
    }

    /// The best fit of `present` (refitted) plus one more term with one of its
    /// [`families`], or the periodic pair, on `y`; `None` if nothing fits. Returns the fit
    /// and the number of new parameters. Candidates of different sizes are ranked by
    /// `n·ln(RSS₀/RSS) − k·ln n`; whether the chosen one is significant is the selection's
    /// judgement, and a term that brings nothing is pruned there.
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
        for t in plain_terms() {
            if present.iter().any(|(p, _)| *p == t) {
                continue;
            }
            for family in families(t) {
                let mut cols = present.to_vec();
                let mut k = 0;
                for f in family {
                    if !cols.iter().any(|(p, _)| p == f) {
                        cols.push((*f, self.column(*f, 1.0)));
                        k += 1;
                    }
                }
                if k > 0 {
                    consider(Basis::fit(&cols, y, period_m), k);
                }
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
    let kept = ctx
        .band
        .combine(ctx.data, &force_combination(ctx.data, &model));
    Some((kept, model))
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
/// x = 0.090 m"; "cubic in x: a hardening spring of 9.00e5 N/m³ about x = 0.095 m";
/// "∝ f_motor: the motor force is 5.0 % lower than logged"; …).
pub fn reading(terms: &[(Term, f64)], period_m: Option<f64>) -> String {
    let c = |t: Term| terms.iter().find(|(p, _)| *p == t).map(|(_, c)| *c);
    let mut parts = Vec::new();
    let cubic = c(Term::X3).filter(|a3| *a3 != 0.0);
    match (cubic, c(Term::X), c(Term::One)) {
        (Some(a3), _, _) => {
            // a₃x³ + a₂x² + a₁x + a₀ about its inflection x₀ = −a₂/(3a₃):
            // a₃(x − x₀)³ + b₁(x − x₀) + b₀.
            let (a2, a1, a0) = (
                c(Term::X2).unwrap_or(0.0),
                c(Term::X).unwrap_or(0.0),
                c(Term::One).unwrap_or(0.0),
            );
            let x0 = -a2 / (3.0 * a3);
            let b1 = a1 - 3.0 * a3 * x0 * x0;
            let b0 = ((a3 * x0 + a2) * x0 + a1) * x0 + a0;
            let mut s = format!(
                "cubic in x: a {} spring of {:.3e} N/m³ about x = {x0:.3} m",
                if a3 < 0.0 { "hardening" } else { "softening" },
                a3.abs()
            );
            if b1.abs() >= 0.5 {
                let _ = write!(s, ", with {:.0} N/m linear about it", -b1);
            }
            if b0.abs() >= 0.05 {
                let _ = write!(s, " and {b0:.1} N there");
            }
            parts.push(s);
        }
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
            Term::One | Term::X | Term::Cos => continue,
            Term::X2 | Term::X3 if cubic.is_some() => continue,
            Term::X2 => format!("quadratic in x: {v:.1} N/m²"),
            Term::X3 => continue,
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
            Term::XSgnV => format!(
                "friction {} {:.0} N/m toward +x",
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
        // −9e5·(x − 0.095)³ expanded (d09's truth).
        let r = reading(
            &[
                (Term::X3, -900_000.0),
                (Term::X2, 256_500.0),
                (Term::X, -24_367.5),
                (Term::One, 771.6375),
            ],
            None,
        );
        assert!(
            r.contains("hardening spring of 9.000e5 N/m³ about x = 0.095 m")
                && !r.contains("linear"),
            "{r}"
        );
        let r = reading(&[(Term::XSgnV, -700.0), (Term::SgnV, -10.0)], None);
        assert!(r.contains("friction rising 700 N/m toward +x"), "{r}");
    }
}
