//! The sensors' own errors as candidates: each chamber pressure transducer's offset and gain
//! (`[sensors.pressure] offset_a_pa, offset_b_pa, gain_a, gain_b`), fitted on the pressure
//! channel by replaying the chambers through the transducers (a reading is
//! `gain·p + offset`, `plant::sensing`). The force balance reads the chambers through the
//! same transducers ([`super::super::residuals::force_terms`]), so a transducer's error the
//! force channel showed as a constant or pressure-shaped force is gone with it: a sensor
//! named here takes the place of the force it imitated.

use crate::plant::model::{model_key, Key};

use super::super::candidate::{Ctx, EffectKind, Proposal};
use super::super::doc::{Edit, ModelDoc};
use super::super::fit::gauss_newton_nonneg;
use super::pressure::{pressure_kept, pressure_search};

/// The offsets are fitted shifted by this much, Pa, so that they stay within the keys'
/// range (−1e5 … 1e5 Pa) as non-negative unknowns.
const OFFSET_SHIFT_PA: f64 = 1e5;

/// Step of the offsets' finite differences, Pa.
const OFFSET_STEP_PA: f64 = 100.0;

/// Step of the gains' finite differences.
const GAIN_STEP: f64 = 0.005;

/// Gauss–Newton iterations of either fit.
const ITERATIONS: usize = 5;

/// Fits the pair of keys `keys` (chamber A's, B's) from `start` with finite-difference
/// steps `step`, each value passed to the model as `to_key(u)` and back as `from_key(v)`;
/// the proposal of `kind` setting them (two parameters).
fn fit_pair(
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
    kind: EffectKind,
    keys: [Key; 2],
    step: f64,
    to_key: impl Fn(f64) -> f64 + Sync,
    from_key: impl Fn(f64) -> f64,
) -> Option<Proposal> {
    let search = pressure_search(ctx);
    let owned = search.as_ref().map(|(data, band)| Ctx { data, band });
    let ctx = owned.as_ref().unwrap_or(ctx);
    let model = doc.model().ok()?;
    let current = |k: Key| doc.number(k);
    let sensor = &model.sensors.pressure;
    let now = [
        current(keys[0]).unwrap_or(match kind {
            EffectKind::PressureGain => sensor.gain_a,
            _ => sensor.offset_a_pa,
        }),
        current(keys[1]).unwrap_or(match kind {
            EffectKind::PressureGain => sensor.gain_b,
            _ => sensor.offset_b_pa,
        }),
    ];
    let edits = |u: &[f64]| -> Vec<Edit> {
        keys.iter()
            .zip(u)
            .map(|(k, v)| Edit::Set(*k, to_key(*v)))
            .collect()
    };
    let res = |u: &[f64]| pressure_kept(ctx, &doc.with(&edits(u)));
    let start: Vec<f64> = now.iter().map(|v| from_key(*v)).collect();
    let (u, _) = gauss_newton_nonneg(start, &[step, step], ITERATIONS, res)?;
    let values: Vec<(Key, f64)> = keys.iter().zip(&u).map(|(k, v)| (*k, to_key(*v))).collect();
    Some(Proposal::setting(kind, &values, 2))
}

pub(super) fn pressure_offset(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    fit_pair(
        ctx,
        doc,
        EffectKind::PressureOffset,
        [
            model_key!(sensors.pressure / offset_a_pa),
            model_key!(sensors.pressure / offset_b_pa),
        ],
        OFFSET_STEP_PA,
        |u| u - OFFSET_SHIFT_PA,
        |v| v + OFFSET_SHIFT_PA,
    )
}

pub(super) fn pressure_gain(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    fit_pair(
        ctx,
        doc,
        EffectKind::PressureGain,
        [
            model_key!(sensors.pressure / gain_a),
            model_key!(sensors.pressure / gain_b),
        ],
        GAIN_STEP,
        |u| u,
        |v| v,
    )
}
