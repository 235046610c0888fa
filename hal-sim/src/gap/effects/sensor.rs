//! The sensors' own errors (`[sensors]`): a chamber's pressure transducer reading off by an
//! offset or a gain, a section's drive reporting its force off by an offset or a gain. What
//! a rig gets wrong first, and what the force effects imitate: a pressure offset is a
//! constant force through the gas area, a section's force gain is part of a force-constant
//! error. Each is fitted and judged on the channel where only a sensor can make it — the
//! pressure replay for the transducers, the slave section's force against the master's for
//! the drives (a force on the piston does not show there) — and the force balance, which
//! reads the same keys, follows.

use crate::plant::model::model_key;

use super::super::doc::{Edit, ModelDoc};
use super::super::fit::{gauss_newton_bounded, lstsq};
use super::super::residuals::{kept_of_raw, residual, slave_force_prediction, ChannelId};
use super::pressure::{pressure_kept, pressure_search};
use super::{Ctx, EffectKind, Proposal};

/// Largest transducer offset fitted, Pa (the key's range).
const MAX_OFFSET_PA: f64 = 1e5;

/// The gains fitted, (lowest, highest) (the keys' range).
const GAIN_RANGE: (f64, f64) = (0.5, 2.0);

/// The chambers' transducer offsets: a Gauss–Newton fit of both on the pressure channel (on
/// the pressure searches' stretch), from none.
pub(super) fn pressure_offset(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let (a, b) = (
        model_key!(sensors.pressure / offset_a_pa),
        model_key!(sensors.pressure / offset_b_pa),
    );
    let fitted = transducer_fit(ctx, doc, [a, b], 0.0, (-MAX_OFFSET_PA, MAX_OFFSET_PA), 1e2)?;
    Some(Proposal::setting(
        EffectKind::PressureOffset,
        &[(a, fitted[0]), (b, fitted[1])],
        2,
    ))
}

/// The chambers' transducer gains, as [`pressure_offset`] from unit gains.
pub(super) fn pressure_gain(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let (a, b) = (
        model_key!(sensors.pressure / gain_a),
        model_key!(sensors.pressure / gain_b),
    );
    let fitted = transducer_fit(ctx, doc, [a, b], 1.0, GAIN_RANGE, 1e-3)?;
    Some(Proposal::setting(
        EffectKind::PressureGain,
        &[(a, fitted[0]), (b, fitted[1])],
        2,
    ))
}

/// Both chambers' `keys` fitted from `none` (the no-error value) within `range` by
/// Gauss–Newton steps of `step` on the pressure channel's kept residual.
fn transducer_fit(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    keys: [crate::plant::model::Key; 2],
    none: f64,
    range: (f64, f64),
    step: f64,
) -> Option<[f64; 2]> {
    let search = pressure_search(ctx);
    let owned = search.as_ref().map(|(data, band)| Ctx { data, band });
    let ctx = owned.as_ref().unwrap_or(ctx);
    (ctx.data.ports != super::super::data::PortsMeta::Unknown).then_some(())?;
    let base = doc.with(&[Edit::Set(keys[0], none), Edit::Set(keys[1], none)]);
    let res = |u: &[f64]| -> Option<Vec<f64>> {
        let edits: Vec<Edit> = keys.iter().zip(u).map(|(k, v)| Edit::Set(*k, *v)).collect();
        pressure_kept(ctx, &base.with(&edits))
    };
    let (u, _) = gauss_newton_bounded(vec![none, none], &[range, range], &[step, step], 6, res)?;
    Some([u.first().copied()?, u.get(1).copied()?])
}

/// The slave channel's column `raw` at its kept samples, and the least-squares coefficient
/// of the residual `y` on it.
fn slave_coefficient(ctx: &Ctx<'_>, y: &[f64], raw: &[f64]) -> Option<f64> {
    let col = kept_of_raw(ctx.data, ctx.band, ChannelId::SlaveForce, raw);
    lstsq(&[col], y).and_then(|(th, _)| th.first().copied())
}

/// Of two ways to write the same reading error (on the master's section or the slave's:
/// the slave channel sees only their ratio or difference), the one the force balance
/// prefers.
fn better_for_the_force(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    options: [Vec<Edit>; 2],
) -> Option<Vec<Edit>> {
    let rss = |edits: &Vec<Edit>| -> Option<f64> {
        let m = doc.with(edits).model().ok()?;
        Some(residual(ctx.data, ctx.band, &m, ChannelId::Force)?.rss())
    };
    let [a, b] = options;
    match (rss(&a), rss(&b)) {
        (Some(ra), Some(rb)) => Some(if rb < ra { b } else { a }),
        (Some(_), None) => Some(a),
        (None, Some(_)) => Some(b),
        (None, None) => None,
    }
}

/// A section's force reading offset: the constant between the slave's reported force and
/// the master's (the slave acts what the master does), fitted on the slave channel and put
/// on the section the force balance prefers.
pub(super) fn force_offset(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let (km, ks) = (
        model_key!(sensors.force / offset_master_n),
        model_key!(sensors.force / offset_slave_n),
    );
    let base = doc.with(&[Edit::Set(km, 0.0), Edit::Set(ks, 0.0)]);
    let model = base.model().ok()?;
    let y = residual(ctx.data, ctx.band, &model, ChannelId::SlaveForce)?.kept;
    // Offsets (o_m, o_s) move the slave's prediction by c = o_s − ratio·o_m, its residual by
    // −c.
    let c = -slave_coefficient(ctx, &y, &vec![1.0; ctx.data.len()])?;
    let f = &model.sensors.force;
    let ratio = f.gain_slave / f.gain_master;
    let edits = better_for_the_force(
        ctx,
        &base,
        [vec![Edit::Set(km, -c / ratio)], vec![Edit::Set(ks, c)]],
    )?;
    let value = |k| {
        edits
            .iter()
            .find_map(|e| match e {
                Edit::Set(key, v) if *key == k => Some(*v),
                _ => None,
            })
            .unwrap_or(0.0)
    };
    let (om, os) = (value(km), value(ks));
    (om.abs() <= 1e4 && os.abs() <= 1e4)
        .then(|| Proposal::setting(EffectKind::ForceOffset, &[(km, om), (ks, os)], 1))
}

/// A section's force reading gain: the slave's reported force against the master's as a
/// ratio other than the modelled one, fitted on the slave channel and put on the section the
/// force balance prefers (a gain the two share is a force-constant error, which the slave
/// channel cannot see: the discovery basis's `f_motor`).
pub(super) fn force_gain(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let (km, ks) = (
        model_key!(sensors.force / gain_master),
        model_key!(sensors.force / gain_slave),
    );
    let base = doc.with(&[Edit::Set(km, 1.0), Edit::Set(ks, 1.0)]);
    let model = base.model().ok()?;
    let y = residual(ctx.data, ctx.band, &model, ChannelId::SlaveForce)?.kept;
    // The prediction is proportional to the ratio g_s/g_m (1 here).
    let pred = slave_force_prediction(ctx.data, &model);
    let off = model.sensors.force.offset_slave_n;
    let col: Vec<f64> = pred.iter().map(|p| p - off).collect();
    // A ratio 1 + δ moves the residual by −δ·col.
    let delta = -slave_coefficient(ctx, &y, &col)?;
    let ratio = 1.0 + delta;
    let (lo, hi) = GAIN_RANGE;
    if !(ratio > lo && ratio < hi && 1.0 / ratio > lo && 1.0 / ratio < hi) {
        return None;
    }
    let edits = better_for_the_force(
        ctx,
        &base,
        [vec![Edit::Set(km, 1.0 / ratio)], vec![Edit::Set(ks, ratio)]],
    )?;
    let value = |k| {
        edits
            .iter()
            .find_map(|e| match e {
                Edit::Set(key, v) if *key == k => Some(*v),
                _ => None,
            })
            .unwrap_or(1.0)
    };
    Some(Proposal::setting(
        EffectKind::ForceGain,
        &[(km, value(km)), (ks, value(ks))],
        1,
    ))
}
