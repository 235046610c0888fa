//! The library of named candidate effects (`docs/formats.md` §3, `docs/machine.md` "Signatures of
//! missing effects"): for each, the channel it shows in, how it is fitted from the residual,
//! and the model edits that add it — one module per channel ([`force`], [`slave_force`],
//! [`encoder`], [`pressure`]) and one for the sensors' own errors ([`sensor`]), each edit a typed key of the model
//! ([`crate::plant::model::model_key!`]).
//!
//! | effect | channel | regressor or sub-model | fit |
//! |---|---|---|---|
//! | `mass_error` | force | ẍ (in phase) | linear |
//! | `coulomb_friction` | force | the friction direction, `sgn`-like | linear |
//! | `viscous_friction` | force | ẋ | linear |
//! | `stribeck_friction` | force | `e^{−(|u|/v_s)^ζ}·sgn`: lives at low speed | linear in F_s − F_c; grid + golden section over v_s, ζ ∈ {0.5, 1, 2} |
//! | `cogging` | force | `sin, cos(2πx/p)` | linear; periodogram over p ∈ [0.4, 2.5]·pole pitch, then golden section |
//! | `actuator_lag` | force | motor forces acting late by d | FFT cross-correlation of logged and acting force, then golden section |
//! | `slave_lag` | slave_force | master force late by d | FFT cross-correlation (the paper's Fig. 4), then golden section |
//! | `encoder_pitch_error` | encoder | `x, sin, cos(2πx/p), sin, cos(4πx/p)` | linear; periodogram over p ∈ [0.5, 2]·λ, then golden section |
//! | `leakage` | pressure | chamber replay with clearance leaks | damped Gauss–Newton on gap³ (piston and rod seals) |
//! | `heat_transfer` | pressure | chamber replay with wall heat transfer | grid + golden section on log UA |
//! | `port_restriction` | pressure (open ports) | chamber replay with scaled port areas | grid + golden section on log scale |
//! | `pressure_offset` | pressure | chamber replay read through transducers offset per chamber | damped Gauss–Newton on the two offsets |
//! | `pressure_gain` | pressure | chamber replay read through transducers of gain per chamber | damped Gauss–Newton on the two gains |
//! | `force_offset` | force (and slave_force) | each section's force reading `F + offset` | damped Gauss–Newton on the two offsets, force and slave-force residuals together |
//! | `force_gain` | force (and slave_force) | each section's force reading `gain·F` | damped Gauss–Newton on the two gains, force and slave-force residuals together |
//!
//! Every fit starts from the current model with the effect itself removed (or, for the
//! corrections of mass and friction levels, from the current value), so fitting again after
//! other effects were added refines it (the selection's back-fitting pass).

use std::f64::consts::TAU;

use crate::plant::fastmath::sin_cos;

use super::candidate::{EffectKind, Proposal};
use super::channel::ChannelId;
use super::ctx::Ctx;
use super::data::Measured;
use super::discover;
use super::doc::ModelDoc;
use super::residuals::Band;

mod encoder;
mod force;
mod pressure;
mod sensor;
mod slave_force;

pub use force::{acting_force_lag, MAX_ACTUATOR_LAG_S};
pub use pressure::PRESSURE_SEARCH_S;
pub use slave_force::slave_force_lag;

/// Fits the effect `kind` to the run on top of the model `doc` (the named ones by this
/// library's fits, the discovered terms by [`super::discover`]); `None` when it cannot be
/// fitted here (channel absent, no valid parameter).
///
/// A candidate of the force, slave-force or encoder channel is fitted on at most
/// [`SEARCH_MAX_S`] of the log ([`search_stretch`]); the pressure channel's candidates cut
/// their own stretch (`pressure::pressure_search`). Every proposal is judged on the whole
/// log.
///
/// A pressure candidate's fit is kept with the log's band ([`Band::proposals`]): fitted
/// again on the same model text, it is the same fit.
pub fn propose(kind: EffectKind, ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    if kind.channel() == ChannelId::Pressure {
        let Ok(text) = doc.to_text() else {
            return propose_on_the_whole_log(kind, ctx, doc);
        };
        let d = ctx.data;
        let key = (
            kind,
            text,
            d.x_offset_m.to_bits(),
            d.force_align_s.to_bits(),
        );
        let kept = ctx
            .band
            .proposals
            .get_or_make(key, || propose_on_the_whole_log(kind, ctx, doc));
        return (*kept).clone();
    }
    if let Some((data, band)) = search_stretch(ctx).as_ref() {
        return propose_on_the_whole_log(kind, &Ctx { data, band }, doc);
    }
    propose_on_the_whole_log(kind, ctx, doc)
}

/// Whether [`propose`] fits the force, slave-force and encoder candidates on a stretch of
/// the log of `ctx` rather than on all of it.
pub fn searches_a_stretch(ctx: &Ctx<'_>) -> bool {
    search_stretch(ctx).is_some()
}

/// Longest stretch of a log that the searches of the force, slave-force and encoder
/// candidates see, s: at the rig's speeds 4 s is 2–20 strokes, each over the whole travel.
/// A cogging or pitch period, a lag or a friction level is pinned by the strokes, not by how
/// many times they repeat: a longer stretch costs in proportion and tells the search little
/// more. The proposal is then judged on the whole log.
pub const SEARCH_MAX_S: f64 = 4.0;

/// The first [`SEARCH_MAX_S`] of the log of `ctx` with its band, or `None` where the log is
/// not a quarter longer than that (the searches then see it all). Cut once per log, force
/// alignment and position offset, and kept with its band ([`super::residuals::Band`]).
fn search_stretch(ctx: &Ctx<'_>) -> std::sync::Arc<Option<(Measured, Band)>> {
    let d = ctx.data;
    let n = (SEARCH_MAX_S / d.dt_s).round() as usize;
    if d.len() <= n + n / 4 {
        return std::sync::Arc::new(None);
    }
    let key = (n, d.x_offset_m.to_bits(), d.force_align_s.to_bits());
    ctx.band.force_searches.get_or_make(key, || {
        let head = d.window(0, n);
        let band = Band::new(&head, ctx.band.band_hz).ok()?;
        Some((head, band))
    })
}

/// [`propose`] on the whole log of `ctx`, whatever its length.
pub fn propose_on_the_whole_log(
    kind: EffectKind,
    ctx: &Ctx<'_>,
    doc: &ModelDoc,
) -> Option<Proposal> {
    match kind {
        EffectKind::MassError => force::mass_error(ctx, doc),
        EffectKind::CoulombFriction => force::coulomb(ctx, doc),
        EffectKind::ViscousFriction => force::viscous(ctx, doc),
        EffectKind::StribeckFriction => force::stribeck(ctx, doc),
        EffectKind::Cogging => force::cogging(ctx, doc),
        EffectKind::ActuatorLag => force::actuator_lag(ctx, doc),
        EffectKind::SlaveLag => slave_force::slave_lag(ctx, doc),
        EffectKind::EncoderPitchError => encoder::pitch_error(ctx, doc),
        EffectKind::Leakage => pressure::leakage(ctx, doc),
        EffectKind::HeatTransfer => pressure::heat_transfer(ctx, doc),
        EffectKind::PortRestriction => pressure::port_restriction(ctx, doc),
        EffectKind::PressureOffset => sensor::pressure_offset(ctx, doc),
        EffectKind::PressureGain => sensor::pressure_gain(ctx, doc),
        EffectKind::ForceOffset => sensor::force_offset(ctx, doc),
        EffectKind::ForceGain => sensor::force_gain(ctx, doc),
        EffectKind::ExtraForce => discover::next_term(ctx, doc),
    }
}

/// `sin` and `cos` of `2π·f·x` for every x, and of twice that angle when `second` (the
/// plant's own fast `sin_cos`; the second harmonic by the double-angle formulas).
pub(super) fn harmonics(x: &[f64], f: f64, second: bool) -> Vec<Vec<f64>> {
    let n = x.len();
    let mut out = vec![Vec::with_capacity(n); if second { 4 } else { 2 }];
    for &v in x {
        let (s, c) = sin_cos(TAU * f * v);
        let vals = [s, c, 2.0 * s * c, c * c - s * s];
        for (col, val) in out.iter_mut().zip(vals) {
            col.push(val);
        }
    }
    out
}

/// Longest actuator or slave lag searched, s.
pub const MAX_LAG_S: f64 = 20e-3;
