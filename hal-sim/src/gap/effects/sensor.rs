//! The sensors' own errors as candidates: each chamber pressure transducer's offset and gain
//! (`[sensors.pressure] offset_a_pa, offset_b_pa, gain_a, gain_b`), fitted on the pressure
//! channel by replaying the chambers through the transducers (a reading is
//! `gain·p + offset`, `plant::sensing`), and each section's force reading's offset and gain
//! (`[sensors.force] offset_master_n, offset_slave_n, gain_master, gain_slave`, a reading is
//! `gain·F + offset`), fitted on the force and slave-force channels together. A transducer's
//! gain on sealed chambers leaves the pressure channel as it is (the replay starts from the
//! reading at rest) and is fitted on the force channel instead
//! ([`EffectKind::judged_on`]). The force
//! balance reads the chambers through the same transducers and the sections' forces through
//! their readings ([`super::super::residuals::force_terms`]), so a sensor's error the force
//! channel showed as a constant, pressure-shaped or motor-shaped force is gone with it: a
//! sensor named here takes the place of the force it imitated.
//!
//! The force channel reads only the sections' sum: an offset of either reading is the same
//! constant force there, a gain the same share of the motor force. The slave-force channel
//! compares the slave's reading with the master's, which it follows, and sees their
//! difference; the two channels together tell each section's error. An error both readings
//! share alike leaves their difference as it is: it is a constant force, or a motor force
//! other than reported, on every channel, and not told from one.

use crate::plant::model::{model_key, Key};

use super::super::candidate::{EffectKind, Proposal};
use super::super::channel::ChannelId;
use super::super::ctx::Ctx;
use super::super::doc::{Edit, ModelDoc};
use super::super::fit::gauss_newton_nonneg;
use super::super::residuals::{band_raw, kept_of_raw};
use super::pressure::{pressure_kept, pressure_search};

/// The pressure offsets are fitted shifted by this much, Pa, so that they stay within the
/// keys' range (−1e5 … 1e5 Pa) as non-negative unknowns.
const OFFSET_SHIFT_PA: f64 = 1e5;

/// Step of the pressure offsets' finite differences, Pa.
const OFFSET_STEP_PA: f64 = 100.0;

/// The force offsets are fitted shifted by this much, N: the keys' range is −1000 … 1000 N.
const OFFSET_SHIFT_N: f64 = 1000.0;

/// Step of the force offsets' finite differences, N (the residuals are linear in them).
const OFFSET_STEP_N: f64 = 1.0;

/// Step of the gains' finite differences.
const GAIN_STEP: f64 = 0.005;

/// Gauss–Newton iterations of the pressure transducers' fits (through the chambers' replay).
const ITERATIONS: usize = 5;

/// Gauss–Newton iterations of the force readings' offsets: the residuals are linear in them,
/// and the first damped step lands within 0.1 % of the optimum, the second on it.
const FORCE_OFFSET_ITERATIONS: usize = 2;

/// Gauss–Newton iterations of the force readings' gains (a force is `reading/gain`).
const FORCE_GAIN_ITERATIONS: usize = 3;

/// One pair of sensor keys and how they are fitted.
struct Pair<F, G> {
    kind: EffectKind,
    /// The keys (chamber A's and B's, or the master's and the slave's).
    keys: [Key; 2],
    /// Their values in the model the fit starts from.
    now: [f64; 2],
    /// Finite-difference step of the unknowns.
    step: f64,
    /// Gauss–Newton iterations.
    iterations: usize,
    /// Key value of an unknown.
    to_key: F,
    /// Unknown of a key value.
    from_key: G,
}

/// Fits `pair`'s keys, the residual of a model being `res` (the vector whose squares are
/// minimised); the proposal of its kind setting them (two parameters).
fn fit_pair<F, G>(
    doc: &ModelDoc,
    pair: Pair<F, G>,
    res: impl Fn(&ModelDoc) -> Option<Vec<f64>> + Sync,
) -> Option<Proposal>
where
    F: Fn(f64) -> f64 + Sync,
    G: Fn(f64) -> f64,
{
    let Pair {
        kind,
        keys,
        now,
        step,
        iterations,
        to_key,
        from_key,
    } = pair;
    let edits = |u: &[f64]| -> Vec<Edit> {
        keys.iter()
            .zip(u)
            .map(|(k, v)| Edit::Set(*k, to_key(*v)))
            .collect()
    };
    let start: Vec<f64> = now.iter().map(|v| from_key(*v)).collect();
    let (u, _) = gauss_newton_nonneg(start, &[step, step], iterations, |u| {
        res(&doc.with(&edits(u)))
    })?;
    let values: Vec<(Key, f64)> = keys.iter().zip(&u).map(|(k, v)| (*k, to_key(*v))).collect();
    Some(Proposal::setting(kind, &values, 2))
}

/// The pressure transducers' pair of `kind` (keys `keys`, model values `model_now`), fitted
/// on the pressure channel.
fn pressure_pair<F, G>(ctx: &Ctx<'_>, doc: &ModelDoc, pair: Pair<F, G>) -> Option<Proposal>
where
    F: Fn(f64) -> f64 + Sync,
    G: Fn(f64) -> f64,
{
    let search = pressure_search(ctx);
    let owned = (*search).as_ref().map(|(data, band)| Ctx { data, band });
    let ctx = owned.as_ref().unwrap_or(ctx);
    fit_pair(doc, pair, |d| pressure_kept(ctx, d))
}

/// The current values of `keys` in `doc`, `model_now` where the file does not give them.
fn current(doc: &ModelDoc, keys: [Key; 2], model_now: [f64; 2]) -> [f64; 2] {
    [
        doc.number(keys[0]).unwrap_or(model_now[0]),
        doc.number(keys[1]).unwrap_or(model_now[1]),
    ]
}

pub(super) fn pressure_offset(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let s = doc.model().ok()?.sensors.pressure;
    let keys = [
        model_key!(sensors.pressure / offset_a_pa),
        model_key!(sensors.pressure / offset_b_pa),
    ];
    let pair = Pair {
        kind: EffectKind::PressureOffset,
        keys,
        now: current(doc, keys, [s.offset_a_pa, s.offset_b_pa]),
        step: OFFSET_STEP_PA,
        iterations: ITERATIONS,
        to_key: |u| u - OFFSET_SHIFT_PA,
        from_key: |v| v + OFFSET_SHIFT_PA,
    };
    pressure_pair(ctx, doc, pair)
}

pub(super) fn pressure_gain(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let s = doc.model().ok()?.sensors.pressure;
    let keys = [
        model_key!(sensors.pressure / gain_a),
        model_key!(sensors.pressure / gain_b),
    ];
    let pair = Pair {
        kind: EffectKind::PressureGain,
        keys,
        now: current(doc, keys, [s.gain_a, s.gain_b]),
        step: GAIN_STEP,
        iterations: ITERATIONS,
        to_key: |u| u,
        from_key: |v| v,
    };
    // Where the pressure channel cannot see a gain (sealed chambers, `EffectKind::judged_on`),
    // it is fitted where it shows: the force balance, which reads the chambers through it.
    match EffectKind::PressureGain.judged_on(ctx.data) {
        ChannelId::Pressure => pressure_pair(ctx, doc, pair),
        ch => fit_pair(doc, pair, |d| channel_kept(ctx, d, ch)),
    }
}

/// The channel `ch`'s kept residual for `doc`.
fn channel_kept(ctx: &Ctx<'_>, doc: &ModelDoc, ch: ChannelId) -> Option<Vec<f64>> {
    let model = doc.model().ok()?;
    let raw = band_raw(ctx.data, ctx.band, &model, ch)?;
    Some(kept_of_raw(ctx.data, ctx.band, ch, &raw))
}

/// The force channel's kept residual followed by the slave-force channel's, for `doc`.
fn force_readings_kept(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Vec<f64>> {
    let mut out = channel_kept(ctx, doc, ChannelId::Force)?;
    out.extend(channel_kept(ctx, doc, ChannelId::SlaveForce)?);
    Some(out)
}

pub(super) fn force_offset(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let s = doc.model().ok()?.sensors.force;
    let keys = [
        model_key!(sensors.force / offset_master_n),
        model_key!(sensors.force / offset_slave_n),
    ];
    let pair = Pair {
        kind: EffectKind::ForceOffset,
        keys,
        now: current(doc, keys, [s.offset_master_n, s.offset_slave_n]),
        step: OFFSET_STEP_N,
        iterations: FORCE_OFFSET_ITERATIONS,
        to_key: |u| u - OFFSET_SHIFT_N,
        from_key: |v| v + OFFSET_SHIFT_N,
    };
    fit_pair(doc, pair, |d| force_readings_kept(ctx, d))
}

pub(super) fn force_gain(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let s = doc.model().ok()?.sensors.force;
    let keys = [
        model_key!(sensors.force / gain_master),
        model_key!(sensors.force / gain_slave),
    ];
    let pair = Pair {
        kind: EffectKind::ForceGain,
        keys,
        now: current(doc, keys, [s.gain_master, s.gain_slave]),
        step: GAIN_STEP,
        iterations: FORCE_GAIN_ITERATIONS,
        to_key: |u| u,
        from_key: |v| v,
    };
    fit_pair(doc, pair, |d| force_readings_kept(ctx, d))
}
