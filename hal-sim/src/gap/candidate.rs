//! What a candidate effect is, shared by the library's fits ([`super::effects`]), the
//! discovered terms ([`super::discover`]) and the selection that judges them
//! ([`super::select`]): which effect ([`EffectKind`], with its name, model section, channel
//! and form among the discovery basis's terms), what every fit is handed
//! ([`super::ctx::Ctx`]) and what it returns ([`Proposal`]).

use crate::plant::model::extra_force::Term;
use crate::plant::model::{model_section, Key, SectionKey};

use super::channel::ChannelId;
use super::data::{Measured, PortsMeta};
use super::doc::Edit;

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
    pub(super) fn setting(kind: EffectKind, values: &[(Key, f64)], k: usize) -> Self {
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
    /// The chamber pressure transducers read offset.
    PressureOffset,
    /// The chamber pressure transducers read with a gain other than 1.
    PressureGain,
    /// The sections' force readings are offset.
    ForceOffset,
    /// The sections' force readings have a gain other than 1.
    ForceGain,
    /// Not a named effect: terms of the discovery basis ([`super::discover`]), one more
    /// at each proposal.
    ExtraForce,
}

impl EffectKind {
    /// Every effect of the library.
    pub const ALL: [EffectKind; 16] = [
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
        EffectKind::PressureOffset,
        EffectKind::PressureGain,
        EffectKind::ForceOffset,
        EffectKind::ForceGain,
        EffectKind::ExtraForce,
    ];

    /// Whether it is an error of a sensor's reading, not of the machine
    /// ([`super::judge::sensor_reading_holds`]).
    pub fn sensor(self) -> bool {
        matches!(
            self,
            EffectKind::PressureOffset
                | EffectKind::PressureGain
                | EffectKind::ForceOffset
                | EffectKind::ForceGain
        )
    }

    /// Whether it is a named effect of the library (not the discovered terms).
    pub fn named(self) -> bool {
        self != EffectKind::ExtraForce
    }

    /// The named force effect's own form among the discovery basis's terms: the plain
    /// term(s) its law is a detailed version of (Coulomb friction is a regularised `sgn(v)`,
    /// viscous friction `v`, a mass error `a`, cogging the periodic pair). Where the basis
    /// finds only this form, it has found this effect, and the named effect is preferred.
    pub fn basis_form(self) -> &'static [Term] {
        match self {
            EffectKind::CoulombFriction => &[Term::SgnV],
            EffectKind::ViscousFriction => &[Term::V],
            EffectKind::MassError => &[Term::A],
            EffectKind::Cogging => &[Term::Sin, Term::Cos],
            EffectKind::ForceOffset => &[Term::One],
            EffectKind::ForceGain => &[Term::FMotor],
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
            EffectKind::PressureOffset => "pressure_offset",
            EffectKind::PressureGain => "pressure_gain",
            EffectKind::ForceOffset => "force_offset",
            EffectKind::ForceGain => "force_gain",
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
            | EffectKind::PressureOffset
            | EffectKind::PressureGain
            | EffectKind::ForceOffset
            | EffectKind::ForceGain
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
            | EffectKind::ForceOffset
            | EffectKind::ForceGain
            | EffectKind::ExtraForce => ChannelId::Force,
            EffectKind::SlaveLag => ChannelId::SlaveForce,
            EffectKind::EncoderPitchError => ChannelId::Encoder,
            EffectKind::Leakage
            | EffectKind::HeatTransfer
            | EffectKind::PortRestriction
            | EffectKind::PressureOffset
            | EffectKind::PressureGain => ChannelId::Pressure,
        }
    }

    /// The channel its evidence is judged on in the log `data`: its own ([`Self::channel`]),
    /// except a pressure transducer's gain on sealed chambers. Their replay starts from the
    /// chambers' reading at rest (`replay::replay_pressures`), so a reading `gain·p`
    /// replays as a charge `gain` times the true one and the pressure channel reads it
    /// exactly: the gain leaves no trace there. The force balance reads the chambers
    /// through the same transducers, and there `(gain − 1)·p·A` is a force following the
    /// chamber's pressure: the gain is fitted and judged on the force channel, its own
    /// channel being where its reading must leave noise ([`super::judge::reading_channel`]).
    pub fn judged_on(self, data: &Measured) -> ChannelId {
        if self == EffectKind::PressureGain && data.ports == PortsMeta::Closed {
            ChannelId::Force
        } else {
            self.channel()
        }
    }
}

/// The span of x over a channel's kept samples, m (at least 1 mm).
pub(super) fn kept_span(x: &[f64]) -> f64 {
    let (lo, hi) = x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    (hi - lo).max(1e-3)
}
