//! The force channel's candidates: mass error, Coulomb, viscous and Stribeck friction (the
//! law's own shapes as regressors), cogging (a spatial periodogram, then the harmonic fit)
//! and an actuator lag.

use fpc::physics::friction::stribeck_shape;
use rayon::prelude::*;

use crate::plant::model::{model_key, model_section};
use crate::signal::xcorr_lag;

use super::super::candidate::{kept_span, EffectKind, Proposal};
use super::super::channel::ChannelId;
use super::super::ctx::{kept_x, Ctx};
use super::super::doc::{Edit, ModelDoc};
use super::super::fit::{lstsq, minimise_1d_par};
use super::super::residuals::{
    acting_motor_force_n, band_force_raw, band_motor_needed_n, motor_sum_n, shifted, tangential_mps,
};
use super::{harmonics, MAX_LAG_S};
use crate::plant::fastmath::sin_cos;
use std::f64::consts::TAU;

/// The force residual of `doc` at the kept samples.
fn force_kept(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Vec<f64>> {
    let model = doc.model().ok()?;
    let raw = band_force_raw(ctx.data, ctx.band, &model);
    Some(ctx.band.kept(ctx.data, ChannelId::Force, &raw))
}

/// Fits `y ≈ θ·reg` for one force-channel regressor given raw.
fn one_coefficient(ctx: &Ctx<'_>, y: &[f64], raw_regressor: &[f64]) -> Option<f64> {
    let reg = ctx.band.kept(ctx.data, ChannelId::Force, raw_regressor);
    lstsq(&[reg], y).map(|(th, _)| th.first().copied().unwrap_or(0.0))
}

pub(super) fn mass_error(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let model = doc.model().ok()?;
    let y = force_kept(ctx, doc)?;
    // r = (m_model − m_true)·ẍ.
    let theta = one_coefficient(ctx, &y, &ctx.data.d2x_mps2)?;
    let mass = model.piston.mass_kg - theta;
    // Outside half to twice the modelled mass it is not a mass error but something else
    // correlating with ẍ (a slow run barely accelerates).
    let plausible = mass > 0.5 * model.piston.mass_kg && mass < 2.0 * model.piston.mass_kg;
    plausible.then(|| {
        Proposal::setting(
            EffectKind::MassError,
            &[(model_key!(piston / mass_kg), mass)],
            1,
        )
    })
}

/// Per sample: the sliding speed `|u| = |(ẋ, ω·r)|` and the axial share of a unit friction
/// force along it, the sign regularised as the law does (the law's own shape,
/// [`fpc::physics::friction::FrictionParams::axial_direction`]).
fn friction_direction(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<(Vec<f64>, Vec<f64>)> {
    let model = doc.model().ok()?;
    let law = model.friction();
    let tang = tangential_mps(ctx.data, &model);
    let (slip, dir) = ctx
        .data
        .v_mps
        .iter()
        .zip(&tang)
        .map(|(v, t)| ((v * v + t * t).sqrt(), law.axial_direction(*v, *t)))
        .unzip();
    Some((slip, dir))
}

/// The edits that shift every friction level by `delta_n` (Coulomb and, where present, the
/// static levels: the Stribeck dip keeps its depth).
fn friction_level_edits(doc: &ModelDoc, delta_n: f64) -> Option<(f64, Vec<Edit>)> {
    let coulomb = doc.number(model_key!(friction / coulomb_n))? + delta_n;
    if coulomb < 0.0 {
        return None;
    }
    let mut edits = vec![Edit::Set(model_key!(friction / coulomb_n), coulomb)];
    if let Some(s) = doc.number(model_key!(friction / static_n)) {
        edits.push(Edit::Set(
            model_key!(friction / static_n),
            (s + delta_n).max(0.0),
        ));
    }
    if let Some(s) = doc.number(model_key!(effects.stribeck_friction / static_n)) {
        edits.push(Edit::Set(
            model_key!(effects.stribeck_friction / static_n),
            (s + delta_n).max(0.0),
        ));
    }
    Some((coulomb, edits))
}

pub(super) fn coulomb(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let y = force_kept(ctx, doc)?;
    let (_, dir) = friction_direction(ctx, doc)?;
    // More friction than modelled leaves −ΔF·direction in the residual.
    let neg: Vec<f64> = dir.iter().map(|d| -d).collect();
    let delta = one_coefficient(ctx, &y, &neg)?;
    let (coulomb, edits) = friction_level_edits(doc, delta)?;
    Some(Proposal {
        kind: EffectKind::CoulombFriction,
        params: vec![(model_key!(friction / coulomb_n).name, coulomb)],
        edits,
        k: 1,
    })
}

pub(super) fn viscous(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let y = force_kept(ctx, doc)?;
    let neg: Vec<f64> = ctx.data.v_mps.iter().map(|v| -v).collect();
    let delta = one_coefficient(ctx, &y, &neg)?;
    // A viscous coefficient is not negative: a fit below zero (a machine with almost none,
    // and noise) is held at zero rather than dropped.
    let b = (doc.number(model_key!(friction / viscous_ns_per_m))? + delta).max(0.0);
    Some(Proposal::setting(
        EffectKind::ViscousFriction,
        &[(model_key!(friction / viscous_ns_per_m), b)],
        1,
    ))
}

/// [`super::super::residuals::Band::search_columns`]'s tag of the Stribeck regressors.
const STRIBECK_SEARCH: u8 = 1;

/// [`super::super::residuals::Band::search_columns`]'s tag of the cogging regressors.
const COGGING_SEARCH: u8 = 2;

/// A 64-bit hash of the bits of `columns` (the same values give the same hash).
fn fingerprint(columns: &[&[f64]]) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for c in columns {
        c.len().hash(&mut h);
        for v in *c {
            v.to_bits().hash(&mut h);
        }
    }
    h.finish()
}

/// Stribeck velocities searched, m/s (log-spaced).
const STRIBECK_RANGE_MPS: (f64, f64) = (1e-3, 0.3);

pub(super) fn stribeck(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let base = doc.with(&[
        Edit::RemoveSection(model_section!(effects.stribeck_friction)),
        Edit::RemoveKey(model_key!(friction / static_n)),
    ]);
    let coulomb = base.number(model_key!(friction / coulomb_n))?;
    let y = force_kept(ctx, &base)?;
    let (slip, dir) = friction_direction(ctx, &base)?;
    // The regressors depend on the sliding speed and direction, not on the residual: kept
    // by them for the next selection step.
    let of_motion = fingerprint(&[&slip, &dir]);
    let fit = |log_vs: f64, zeta: f64| -> Option<(f64, f64)> {
        let key = (STRIBECK_SEARCH, log_vs.to_bits(), zeta.to_bits(), of_motion);
        let reg = ctx.band.search_columns.get_or_make(key, || {
            let vs = log_vs.exp();
            // The law's Stribeck shape along the friction's direction (more dip than
            // modelled leaves −ΔF·S·d in the residual).
            let raw: Vec<f64> = slip
                .iter()
                .zip(&dir)
                .map(|(s, d)| -stribeck_shape(*s, vs, zeta) * d)
                .collect();
            vec![ctx.band.kept(ctx.data, ChannelId::Force, &raw)]
        });
        let (th, rss) = lstsq(&reg, &y)?;
        let dip = th.first().copied()?;
        (dip > 0.0).then_some((dip, rss))
    };
    let (lo, hi) = (STRIBECK_RANGE_MPS.0.ln(), STRIBECK_RANGE_MPS.1.ln());
    let mut best: Option<(f64, f64, f64)> = None; // (rss, log v_s, ζ)
    for zeta in [0.5, 1.0, 2.0] {
        if let Some((lv, rss)) = minimise_1d_par(lo, hi, 13, 14, |lv| fit(lv, zeta).map(|f| f.1)) {
            if best.is_none_or(|b| rss < b.0) {
                best = Some((rss, lv, zeta));
            }
        }
    }
    let (_, lv, zeta) = best?;
    let (dip, _) = fit(lv, zeta)?;
    let (static_n, vs) = (coulomb + dip, lv.exp());
    let mut p = Proposal::setting(
        EffectKind::StribeckFriction,
        &[
            (model_key!(effects.stribeck_friction / static_n), static_n),
            (model_key!(effects.stribeck_friction / velocity_mps), vs),
            (model_key!(effects.stribeck_friction / exponent), zeta),
        ],
        3,
    );
    // The effect's static level replaces the section's.
    p.edits
        .insert(0, Edit::RemoveKey(model_key!(friction / static_n)));
    Some(p)
}

/// Spatial periodogram: for each spatial frequency (1/m) of `freqs`, how much of `y`'s sum
/// of squares sin and cos at that frequency, evaluated at the positions `x` (unfiltered: a
/// quick scan), explain by least squares. Returns the frequency that explains most (the
/// least residual sum of squares).
///
/// The explained sum `θᵀ·Xᵀy` of the two-column normal equations is summed in one pass over
/// the samples, no design matrix made: it ranks the frequencies as the residual does, without
/// the residual's cancellation against `yᵀy`.
fn periodogram(y: &[f64], x: &[f64], freqs: impl Iterator<Item = f64>) -> Option<f64> {
    // Every frequency on every core, then scanned in order (the first of equal ones wins,
    // as one thread would find it).
    let freqs: Vec<f64> = freqs.collect();
    let scan: Vec<Option<(f64, f64)>> = freqs
        .par_iter()
        .map(|&f| {
            let (mut ss, mut cc, mut sc, mut sy, mut cy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (xi, yi) in x.iter().zip(y) {
                let (s, c) = sin_cos(TAU * f * xi);
                ss += s * s;
                cc += c * c;
                sc += s * c;
                sy += s * yi;
                cy += c * yi;
            }
            let det = ss * cc - sc * sc;
            let explained = (cc * sy * sy - 2.0 * sc * sy * cy + ss * cy * cy) / det;
            (det > 0.0 && explained.is_finite()).then_some((f, explained))
        })
        .collect();
    let mut best: Option<(f64, f64)> = None;
    for (f, explained) in scan.into_iter().flatten() {
        if best.is_none_or(|b| explained > b.1) {
            best = Some((f, explained));
        }
    }
    best.map(|b| b.0)
}

pub(super) fn cogging(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let base = doc.with(&[Edit::RemoveSection(model_section!(effects.cogging))]);
    let pole = base.number(model_key!(motor / pole_pitch_m))?;
    let y = force_kept(ctx, &base)?;
    let xk = kept_x(ctx);
    let (f_lo, f_hi) = (1.0 / (2.5 * pole), 1.0 / (0.4 * pole));
    let df = 1.0 / (8.0 * kept_span(&xk));
    let steps = ((f_hi - f_lo) / df).ceil().min(4000.0) as usize;
    let f0 = periodogram(&y, &xk, (0..=steps).map(|i| f_lo + df * i as f64))?;
    // Refine with the regressors filtered exactly as the residual is (they depend on x
    // alone: kept for the next selection step).
    let fitf = |f: f64| -> Option<(Vec<f64>, f64)> {
        let cols = ctx
            .band
            .search_columns
            .get_or_make((COGGING_SEARCH, f.to_bits(), 0, 0), || {
                harmonics(&ctx.data.x_m, f, false)
                    .iter()
                    .map(|h| ctx.band.kept(ctx.data, ChannelId::Force, h))
                    .collect()
            });
        lstsq(&cols, &y)
    };
    let (f, _) = minimise_1d_par(f0 - df, f0 + df, 5, 16, |f| fitf(f).map(|r| r.1))?;
    let (th, _) = fitf(f)?;
    let (a, b) = (th.first().copied()?, th.get(1).copied()?);
    let (amp, phase, period) = (a.hypot(b), b.atan2(a), 1.0 / f);
    Some(Proposal::setting(
        EffectKind::Cogging,
        &[
            (model_key!(effects.cogging / amplitude_n), amp),
            (model_key!(effects.cogging / period_m), period),
            (model_key!(effects.cogging / phase_rad), phase),
        ],
        3,
    ))
}

/// How far the force that acts on the piston lags the force the drives report, by FFT
/// cross-correlation of the two (both through the force kernel): the acting force is
/// `m·ẍ` less every other modelled force. `None` if there is too little motion.
pub fn acting_force_lag(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<crate::signal::Lag> {
    let base = doc.with(&[Edit::RemoveSection(model_section!(effects.actuator_lag))]);
    let model = base.model().ok()?;
    let d = ctx.data;
    let motors = acting_motor_force_n(d, &model.sensors.force, d.force_align_s);
    // The motor force that closes the balance with every other modelled force.
    let acting = band_motor_needed_n(d, ctx.band, &model);
    let reported = ctx.band.full(d, ChannelId::Force, &motors);
    let acting = ctx.band.full(d, ChannelId::Force, &acting);
    let max = (MAX_LAG_S / d.dt_s).round() as usize;
    xcorr_lag(&reported, &acting, d.dt_s, Some(max)).ok()
}

/// Longest actuator lag searched, s.
pub const MAX_ACTUATOR_LAG_S: f64 = 5e-3;

pub(super) fn actuator_lag(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let base = doc.with(&[Edit::RemoveSection(model_section!(effects.actuator_lag))]);
    let model = base.model().ok()?;
    let d = ctx.data;
    // Everything but the motor forces, once: r(d) = m·Δ²x − others − motors acting at d.
    let fixed = band_motor_needed_n(d, ctx.band, &model);
    // The motor forces summed once; each delay only shifts them.
    let motors = motor_sum_n(d, &model.sensors.force);
    let rss = |delay: f64| -> Option<f64> {
        let mut raw = shifted(&motors, (delay.max(0.0) + d.force_align_s) / d.dt_s);
        for (r, f) in raw.iter_mut().zip(&fixed) {
            *r = f - *r;
        }
        Some(super::super::fit::sumsq(&ctx.band.kept(
            d,
            ChannelId::Force,
            &raw,
        )))
    };
    // A grid of about one step per sample (the cross-correlation's peak is too flat on smooth
    // strokes to pick the lag alone), then golden section.
    let grid = ((MAX_ACTUATOR_LAG_S / d.dt_s).round() as usize + 1).clamp(11, 201);
    let (delay, _) = minimise_1d_par(0.0, MAX_ACTUATOR_LAG_S, grid, 16, rss)?;
    Some(Proposal::setting(
        EffectKind::ActuatorLag,
        &[(model_key!(effects.actuator_lag / delay_s), delay)],
        1,
    ))
}
