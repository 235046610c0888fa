//! The library of named candidate effects (`docs/formats.md` §3, `docs/machine.md` "Signatures of
//! missing effects"): for each, the channel it shows in, how it is fitted from the residual,
//! and the model edits that add it — one module per channel ([`force`], [`slave_force`],
//! [`encoder`], [`pressure`]), each edit a typed key of the model
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
//!
//! Every fit starts from the current model with the effect itself removed (or, for the
//! corrections of mass and friction levels, from the current value), so fitting again after
//! other effects were added refines it (the selection's back-fitting pass).

use std::f64::consts::TAU;

use crate::plant::fastmath::sin_cos;
use crate::plant::model::{model_section, Key, SectionKey};

use super::channel::ChannelId;
use super::data::Measured;
use super::doc::{Edit, ModelDoc};
use super::residuals::Band;

mod encoder;
mod force;
mod pressure;
mod slave_force;

pub use force::{acting_force_lag, MAX_ACTUATOR_LAG_S};
pub use pressure::PRESSURE_SEARCH_S;
pub use slave_force::slave_force_lag;

/// What the fits share: the measured run and the band.
pub struct Ctx<'a> {
    /// The measured run.
    pub data: &'a Measured,
    /// The analysis band.
    pub band: &'a Band,
}

/// A fitted effect, ready to be judged and added.
#[derive(Clone, Debug, PartialEq)]
pub struct Proposal {
    /// The effect.
    pub kind: EffectKind,
    /// Fitted parameters, SI, with the model file's key names.
    pub params: Vec<(&'static str, f64)>,
    /// The model edits that add it.
    pub edits: Vec<Edit>,
    /// Number of parameters fitted (linear and nonlinear).
    pub k: usize,
}

impl Proposal {
    /// The effect `kind` added by setting each key of `values` to its fitted value (its
    /// parameters are those keys), `k` parameters fitted.
    fn setting(kind: EffectKind, values: &[(Key, f64)], k: usize) -> Self {
        Proposal {
            kind,
            params: values.iter().map(|(key, v)| (key.name, *v)).collect(),
            edits: values.iter().map(|&(key, v)| Edit::Set(key, v)).collect(),
            k,
        }
    }
}

/// The named effects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum EffectKind {
    /// Wrong moving mass.
    MassError,
    /// Wrong Coulomb friction level.
    CoulombFriction,
    /// Wrong viscous friction.
    ViscousFriction,
    /// Missing Stribeck (stiction) part of the friction.
    StribeckFriction,
    /// Missing cogging.
    Cogging,
    /// Both sections' force acts later than the drives report it.
    ActuatorLag,
    /// The slave section's force lags the master's.
    SlaveLag,
    /// The slave encoder's pitch error.
    EncoderPitchError,
    /// Clearance leakage.
    Leakage,
    /// Heat transfer to the wall.
    HeatTransfer,
    /// Ports passing less than designed.
    PortRestriction,
    /// Not a named effect: terms of the discovery basis ([`super::discover`]), one more
    /// at each proposal.
    ExtraForce,
}

impl EffectKind {
    /// Every effect of the library.
    pub const ALL: [EffectKind; 12] = [
        EffectKind::MassError,
        EffectKind::CoulombFriction,
        EffectKind::ViscousFriction,
        EffectKind::StribeckFriction,
        EffectKind::Cogging,
        EffectKind::ActuatorLag,
        EffectKind::SlaveLag,
        EffectKind::EncoderPitchError,
        EffectKind::Leakage,
        EffectKind::HeatTransfer,
        EffectKind::PortRestriction,
        EffectKind::ExtraForce,
    ];

    /// Whether it is a named effect of the library (not the discovered terms).
    pub fn named(self) -> bool {
        self != EffectKind::ExtraForce
    }

    /// The named force effect's own form among the discovery basis's terms: the plain
    /// term(s) its law is a detailed version of (Coulomb friction is a regularised `sgn(v)`,
    /// viscous friction `v`, a mass error `a`, cogging the periodic pair). Where the basis
    /// finds only this form, it has found this effect, and the named effect is preferred.
    pub fn basis_form(self) -> &'static [crate::plant::model::extra_force::Term] {
        use crate::plant::model::extra_force::Term;
        match self {
            EffectKind::CoulombFriction => &[Term::SgnV],
            EffectKind::ViscousFriction => &[Term::V],
            EffectKind::MassError => &[Term::A],
            EffectKind::Cogging => &[Term::Sin, Term::Cos],
            _ => &[],
        }
    }

    /// The name of `docs/formats.md` §3.
    pub fn name(self) -> &'static str {
        match self {
            EffectKind::MassError => "mass_error",
            EffectKind::CoulombFriction => "coulomb_friction",
            EffectKind::ViscousFriction => "viscous_friction",
            EffectKind::StribeckFriction => "stribeck_friction",
            EffectKind::Cogging => "cogging",
            EffectKind::ActuatorLag => "actuator_lag",
            EffectKind::SlaveLag => "slave_lag",
            EffectKind::EncoderPitchError => "encoder_pitch_error",
            EffectKind::Leakage => "leakage",
            EffectKind::HeatTransfer => "heat_transfer",
            EffectKind::PortRestriction => "port_restriction",
            EffectKind::ExtraForce => "extra_force",
        }
    }

    /// The model section that holds it alone (`None`: it corrects a value of a required
    /// section, or it is the discovered terms).
    pub fn section(self) -> Option<SectionKey> {
        Some(match self {
            EffectKind::StribeckFriction => model_section!(effects.stribeck_friction),
            EffectKind::Cogging => model_section!(effects.cogging),
            EffectKind::ActuatorLag => model_section!(effects.actuator_lag),
            EffectKind::SlaveLag => model_section!(effects.slave_lag),
            EffectKind::EncoderPitchError => model_section!(effects.encoder_pitch_error),
            EffectKind::Leakage => model_section!(effects.leakage),
            EffectKind::HeatTransfer => model_section!(effects.heat_transfer),
            EffectKind::PortRestriction => model_section!(effects.port_restriction),
            EffectKind::MassError
            | EffectKind::CoulombFriction
            | EffectKind::ViscousFriction
            | EffectKind::ExtraForce => return None,
        })
    }

    /// The channel it shows in.
    pub fn channel(self) -> ChannelId {
        match self {
            EffectKind::MassError
            | EffectKind::CoulombFriction
            | EffectKind::ViscousFriction
            | EffectKind::StribeckFriction
            | EffectKind::Cogging
            | EffectKind::ActuatorLag
            | EffectKind::ExtraForce => ChannelId::Force,
            EffectKind::SlaveLag => ChannelId::SlaveForce,
            EffectKind::EncoderPitchError => ChannelId::Encoder,
            EffectKind::Leakage | EffectKind::HeatTransfer | EffectKind::PortRestriction => {
                ChannelId::Pressure
            }
        }
    }

    /// Fits the effect to the run on top of the model `doc`; `None` when it cannot be fitted
    /// here (channel absent, no valid parameter).
    pub fn propose(self, ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
        match self {
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
            EffectKind::ExtraForce => super::discover::next_term(ctx, doc),
        }
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

/// The span of x over a channel's kept samples, m.
/// The measured position at the force channel's kept samples, m.
pub(super) fn kept_x(ctx: &Ctx<'_>) -> Vec<f64> {
    ctx.band
        .idx_force
        .iter()
        .filter_map(|&i| ctx.data.x_m.get(i).copied())
        .collect()
}

pub(super) fn kept_span(x: &[f64]) -> f64 {
    let (lo, hi) = x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    (hi - lo).max(1e-3)
}

/// Longest actuator or slave lag searched, s.
pub const MAX_LAG_S: f64 = 20e-3;
