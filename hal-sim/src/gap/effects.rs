//! The library of named candidate effects (`formats.md` §3, `machine.md` "Signatures of
//! missing effects"): for each, the channel it shows in, how it is fitted from the residual,
//! and the model edits that add it.
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
use crate::signal::{delayed, xcorr_lag};

use super::data::{Measured, PortsMeta};
use super::doc::{Edit, ModelDoc};
use super::fit::{gauss_newton_nonneg, lstsq, minimise_1d};
use super::residuals::{
    acting_motor_force_n, channel_raw, force_raw, kept_of_raw, model_force_n, tangential_mps, Band,
    ChannelId,
};

/// What the fits share: the measured run and the band.
pub struct Ctx<'a> {
    /// The measured run.
    pub data: &'a Measured,
    /// The analysis band.
    pub band: &'a Band,
}

/// Longest stretch of a log the pressure candidates' parameter searches replay, s: each
/// search replays the chambers 15–20 times, and [`PRESSURE_SEARCH_S`] of a compressor run
/// (several cycles) or of a closed-port campaign pins a leak gap, a UA or an area as well as
/// the whole log. The candidate is then judged on the whole log.
pub const PRESSURE_SEARCH_S: f64 = 1.5;

/// The data and band the pressure searches run on: the first [`PRESSURE_SEARCH_S`] (of a
/// closed-port log with `# ports_from_s`: from [`PRESSURE_SEARCH_LEAD_S`] before it) of the
/// log, or the whole log if it is shorter (then `None`: use `ctx` itself).
fn pressure_search(ctx: &Ctx<'_>) -> Option<(Measured, Band)> {
    let n = (PRESSURE_SEARCH_S / ctx.data.dt_s).round() as usize;
    // A closed-port campaign's leak and heat transfer show only while the chambers are
    // sealed: its search begins where the sealing does (a bench log starts with the homing,
    // bypassed), less a little rest the replay starts from. An open-port log's search keeps
    // the log's start, as it was validated (beginning it at the bypass's closing instead
    // made `leakage` fit 19.6 µm for 25 µm on a compressor run with a slave lag: a false
    // name).
    let start = match (ctx.data.ports, ctx.data.ports_from_s) {
        (PortsMeta::Closed, Some(from)) => ctx
            .data
            .t_s
            .iter()
            .position(|t| *t >= from - PRESSURE_SEARCH_LEAD_S)
            .unwrap_or(0),
        _ => 0,
    };
    let rest = ctx.data.len().saturating_sub(start);
    if start == 0 && rest <= n + n / 4 {
        return None;
    }
    let head = ctx.data.window(start, n.min(rest));
    let band = Band::new(&head, ctx.band.band_hz).ok()?;
    Some((head, band))
}

/// How long before a closed-port log's `# ports_from_s` the pressure searches begin, s: the
/// rest before the sealing, which the replay starts from.
pub const PRESSURE_SEARCH_LEAD_S: f64 = 0.1;

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
}

impl EffectKind {
    /// Every effect of the library.
    pub const ALL: [EffectKind; 11] = [
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
    ];

    /// The name of `formats.md` §3.
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
        }
    }

    /// The channel it shows in.
    pub fn channel(self) -> ChannelId {
        match self {
            EffectKind::MassError
            | EffectKind::CoulombFriction
            | EffectKind::ViscousFriction
            | EffectKind::StribeckFriction
            | EffectKind::Cogging
            | EffectKind::ActuatorLag => ChannelId::Force,
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
            EffectKind::MassError => mass_error(ctx, doc),
            EffectKind::CoulombFriction => coulomb(ctx, doc),
            EffectKind::ViscousFriction => viscous(ctx, doc),
            EffectKind::StribeckFriction => stribeck(ctx, doc),
            EffectKind::Cogging => cogging(ctx, doc),
            EffectKind::ActuatorLag => actuator_lag(ctx, doc),
            EffectKind::SlaveLag => slave_lag(ctx, doc),
            EffectKind::EncoderPitchError => pitch_error(ctx, doc),
            EffectKind::Leakage => leakage(ctx, doc),
            EffectKind::HeatTransfer => heat_transfer(ctx, doc),
            EffectKind::PortRestriction => port_restriction(ctx, doc),
        }
    }
}

/// The force residual of `doc` at the kept samples.
fn force_kept(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Vec<f64>> {
    let model = doc.model().ok()?;
    let raw = force_raw(ctx.data, &model);
    Some(ctx.band.kept(ctx.data, ChannelId::Force, &raw))
}

/// Fits `y ≈ θ·reg` for one force-channel regressor given raw.
fn one_coefficient(ctx: &Ctx<'_>, y: &[f64], raw_regressor: &[f64]) -> Option<f64> {
    let reg = ctx.band.kept(ctx.data, ChannelId::Force, raw_regressor);
    lstsq(&[reg], y).map(|(th, _)| th.first().copied().unwrap_or(0.0))
}

fn mass_error(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let model = doc.model().ok()?;
    let y = force_kept(ctx, doc)?;
    // r = (m_model − m_true)·ẍ.
    let theta = one_coefficient(ctx, &y, &ctx.data.d2x_mps2)?;
    let mass = model.piston.mass_kg - theta;
    // Outside half to twice the modelled mass it is not a mass error but something else
    // correlating with ẍ (a slow run barely accelerates).
    let plausible = mass > 0.5 * model.piston.mass_kg && mass < 2.0 * model.piston.mass_kg;
    plausible.then(|| Proposal {
        kind: EffectKind::MassError,
        params: vec![("mass_kg", mass)],
        edits: vec![Edit::Set("piston", "mass_kg", mass)],
        k: 1,
    })
}

/// Per sample: the sliding speed and the axial share of a unit friction force with the sign
/// regularised as the law does (`tanh(|u|/v_reg)·ẋ/|u|`).
fn friction_direction(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<(Vec<f64>, Vec<f64>)> {
    let model = doc.model().ok()?;
    let vreg = model.friction().sign_velocity_mps;
    let tang = tangential_mps(ctx.data, &model);
    let mut slip = Vec::with_capacity(ctx.data.len());
    let mut dir = Vec::with_capacity(ctx.data.len());
    for (v, t) in ctx.data.v_mps.iter().zip(&tang) {
        let s = (v * v + t * t).sqrt();
        slip.push(s);
        dir.push(if s > 0.0 {
            (s / vreg).tanh() * v / s
        } else {
            0.0
        });
    }
    Some((slip, dir))
}

/// The edits that shift every friction level by `delta_n` (Coulomb and, where present, the
/// static levels: the Stribeck dip keeps its depth).
fn friction_level_edits(doc: &ModelDoc, delta_n: f64) -> Option<(f64, Vec<Edit>)> {
    let coulomb = doc.number("friction", "coulomb_n")? + delta_n;
    if coulomb < 0.0 {
        return None;
    }
    let mut edits = vec![Edit::Set("friction", "coulomb_n", coulomb)];
    if let Some(s) = doc.number("friction", "static_n") {
        edits.push(Edit::Set("friction", "static_n", (s + delta_n).max(0.0)));
    }
    if let Some(s) = doc.number("effects.stribeck_friction", "static_n") {
        edits.push(Edit::Set(
            "effects.stribeck_friction",
            "static_n",
            (s + delta_n).max(0.0),
        ));
    }
    Some((coulomb, edits))
}

fn coulomb(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let y = force_kept(ctx, doc)?;
    let (_, dir) = friction_direction(ctx, doc)?;
    // More friction than modelled leaves −ΔF·direction in the residual.
    let neg: Vec<f64> = dir.iter().map(|d| -d).collect();
    let delta = one_coefficient(ctx, &y, &neg)?;
    let (coulomb, edits) = friction_level_edits(doc, delta)?;
    Some(Proposal {
        kind: EffectKind::CoulombFriction,
        params: vec![("coulomb_n", coulomb)],
        edits,
        k: 1,
    })
}

fn viscous(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let y = force_kept(ctx, doc)?;
    let neg: Vec<f64> = ctx.data.v_mps.iter().map(|v| -v).collect();
    let delta = one_coefficient(ctx, &y, &neg)?;
    // A viscous coefficient is not negative: a fit below zero (a machine with almost none,
    // and noise) is held at zero rather than dropped.
    let b = (doc.number("friction", "viscous_ns_per_m")? + delta).max(0.0);
    Some(Proposal {
        kind: EffectKind::ViscousFriction,
        params: vec![("viscous_ns_per_m", b)],
        edits: vec![Edit::Set("friction", "viscous_ns_per_m", b)],
        k: 1,
    })
}

/// Stribeck velocities searched, m/s (log-spaced).
const STRIBECK_RANGE_MPS: (f64, f64) = (1e-3, 0.3);

fn stribeck(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let base = doc.with(&[
        Edit::RemoveSection("effects.stribeck_friction"),
        Edit::RemoveKey("friction", "static_n"),
    ]);
    let coulomb = base.number("friction", "coulomb_n")?;
    let y = force_kept(ctx, &base)?;
    let (slip, dir) = friction_direction(ctx, &base)?;
    let fit = |log_vs: f64, zeta: f64| -> Option<(f64, f64)> {
        let vs = log_vs.exp();
        let raw: Vec<f64> = slip
            .iter()
            .zip(&dir)
            .map(|(s, d)| {
                let r = s / vs;
                // ζ ∈ {0.5, 1, 2}: no powf; far past v_s the term is nil (skip the exp).
                let shaped = if zeta == 1.0 {
                    r
                } else if zeta == 2.0 {
                    r * r
                } else {
                    r.powf(zeta)
                };
                if shaped > 40.0 {
                    0.0
                } else {
                    -(-shaped).exp() * d
                }
            })
            .collect();
        let reg = ctx.band.kept(ctx.data, ChannelId::Force, &raw);
        let (th, rss) = lstsq(&[reg], &y)?;
        let dip = th.first().copied()?;
        (dip > 0.0).then_some((dip, rss))
    };
    let (lo, hi) = (STRIBECK_RANGE_MPS.0.ln(), STRIBECK_RANGE_MPS.1.ln());
    let mut best: Option<(f64, f64, f64)> = None; // (rss, log v_s, ζ)
    for zeta in [0.5, 1.0, 2.0] {
        if let Some((lv, rss)) = minimise_1d(lo, hi, 13, 14, |lv| fit(lv, zeta).map(|f| f.1)) {
            if best.is_none_or(|b| rss < b.0) {
                best = Some((rss, lv, zeta));
            }
        }
    }
    let (_, lv, zeta) = best?;
    let (dip, _) = fit(lv, zeta)?;
    let (static_n, vs) = (coulomb + dip, lv.exp());
    Some(Proposal {
        kind: EffectKind::StribeckFriction,
        params: vec![
            ("static_n", static_n),
            ("velocity_mps", vs),
            ("exponent", zeta),
        ],
        edits: vec![
            Edit::RemoveKey("friction", "static_n"),
            Edit::Set("effects.stribeck_friction", "static_n", static_n),
            Edit::Set("effects.stribeck_friction", "velocity_mps", vs),
            Edit::Set("effects.stribeck_friction", "exponent", zeta),
        ],
        k: 3,
    })
}

/// `sin` and `cos` of `2π·f·x` for every x, and of twice that angle when `second` (the
/// plant's own fast `sin_cos`; the second harmonic by the double-angle formulas).
fn harmonics(x: &[f64], f: f64, second: bool) -> Vec<Vec<f64>> {
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

/// Spatial periodogram: for each spatial frequency (1/m) of `freqs`, the residual sum of
/// squares of `y` against `base` columns plus sin/cos at that frequency (and at twice it
/// when `second`) evaluated at the positions `x` (unfiltered: a quick scan). Returns the
/// best frequency.
fn periodogram(
    y: &[f64],
    x: &[f64],
    base: &[Vec<f64>],
    freqs: impl Iterator<Item = f64>,
    second: bool,
) -> Option<f64> {
    let mut best: Option<(f64, f64)> = None;
    for f in freqs {
        let mut cols = base.to_vec();
        cols.extend(harmonics(x, f, second));
        if let Some((_, rss)) = lstsq(&cols, y) {
            if best.is_none_or(|b| rss < b.1) {
                best = Some((f, rss));
            }
        }
    }
    best.map(|b| b.0)
}

/// The span of x over a channel's kept samples, m.
fn kept_span(x: &[f64]) -> f64 {
    let (lo, hi) = x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    (hi - lo).max(1e-3)
}

fn cogging(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let base = doc.with(&[Edit::RemoveSection("effects.cogging")]);
    let pole = base.number("motor", "pole_pitch_m")?;
    let y = force_kept(ctx, &base)?;
    let xk: Vec<f64> = ctx
        .band
        .idx_force
        .iter()
        .filter_map(|&i| ctx.data.x_m.get(i).copied())
        .collect();
    let (f_lo, f_hi) = (1.0 / (2.5 * pole), 1.0 / (0.4 * pole));
    let df = 1.0 / (8.0 * kept_span(&xk));
    let steps = ((f_hi - f_lo) / df).ceil().min(4000.0) as usize;
    let f0 = periodogram(
        &y,
        &xk,
        &[],
        (0..=steps).map(|i| f_lo + df * i as f64),
        false,
    )?;
    // Refine with the regressors filtered exactly as the residual is.
    let fitf = |f: f64| -> Option<(Vec<f64>, f64)> {
        let cols: Vec<Vec<f64>> = harmonics(&ctx.data.x_m, f, false)
            .iter()
            .map(|h| ctx.band.kept(ctx.data, ChannelId::Force, h))
            .collect();
        lstsq(&cols, &y)
    };
    let (f, _) = minimise_1d(f0 - df, f0 + df, 5, 16, |f| fitf(f).map(|r| r.1))?;
    let (th, _) = fitf(f)?;
    let (a, b) = (th.first().copied()?, th.get(1).copied()?);
    let (amp, phase, period) = (a.hypot(b), b.atan2(a), 1.0 / f);
    Some(Proposal {
        kind: EffectKind::Cogging,
        params: vec![
            ("amplitude_n", amp),
            ("period_m", period),
            ("phase_rad", phase),
        ],
        edits: vec![
            Edit::Set("effects.cogging", "amplitude_n", amp),
            Edit::Set("effects.cogging", "period_m", period),
            Edit::Set("effects.cogging", "phase_rad", phase),
        ],
        k: 3,
    })
}

/// Longest actuator or slave lag searched, s.
pub const MAX_LAG_S: f64 = 20e-3;

/// How far the force that acts on the piston lags the force the drives report, by FFT
/// cross-correlation of the two (both through the force kernel): the acting force is
/// `m·ẍ` less every other modelled force. `None` if there is too little motion.
pub fn acting_force_lag(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<crate::signal::Lag> {
    let base = doc.with(&[Edit::RemoveSection("effects.actuator_lag")]);
    let model = base.model().ok()?;
    let d = ctx.data;
    let motors = acting_motor_force_n(d, 0.0);
    let others: Vec<f64> = model_force_n(d, &model)
        .iter()
        .zip(&motors)
        .map(|(all, m)| all - m)
        .collect();
    let acting: Vec<f64> = d
        .d2x_mps2
        .iter()
        .zip(&others)
        .map(|(a, o)| model.piston.mass_kg * a - o)
        .collect();
    let reported = ctx.band.full(d, ChannelId::Force, &motors);
    let acting = ctx.band.full(d, ChannelId::Force, &acting);
    let max = (MAX_LAG_S / d.dt_s).round() as usize;
    xcorr_lag(&reported, &acting, d.dt_s, Some(max)).ok()
}

/// Longest actuator lag searched, s.
pub const MAX_ACTUATOR_LAG_S: f64 = 5e-3;

fn actuator_lag(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let base = doc.with(&[Edit::RemoveSection("effects.actuator_lag")]);
    let model = base.model().ok()?;
    let d = ctx.data;
    let motors = acting_motor_force_n(d, 0.0);
    // Everything but the motor forces, once: r(d) = m·Δ²x − others − motors acting at d.
    let fixed: Vec<f64> = model_force_n(d, &model)
        .iter()
        .zip(&motors)
        .zip(&d.d2x_mps2)
        .map(|((all, m), a)| model.piston.mass_kg * a - (all - m))
        .collect();
    let rss = |delay: f64| -> Option<f64> {
        let late = acting_motor_force_n(d, delay.max(0.0));
        let raw: Vec<f64> = fixed.iter().zip(&late).map(|(f, m)| f - m).collect();
        Some(super::fit::sumsq(&ctx.band.kept(d, ChannelId::Force, &raw)))
    };
    // A grid of about one step per sample (the cross-correlation's peak is too flat on smooth
    // strokes to pick the lag alone), then golden section.
    let grid = ((MAX_ACTUATOR_LAG_S / d.dt_s).round() as usize + 1).clamp(11, 201);
    let (delay, _) = minimise_1d(0.0, MAX_ACTUATOR_LAG_S, grid, 16, rss)?;
    Some(Proposal {
        kind: EffectKind::ActuatorLag,
        params: vec![("delay_s", delay)],
        edits: vec![Edit::Set("effects.actuator_lag", "delay_s", delay)],
        k: 1,
    })
}

/// How far the slave force lags the master's (the paper's FFT method).
pub fn slave_force_lag(data: &Measured) -> Option<crate::signal::Lag> {
    let max = (MAX_LAG_S / data.dt_s).round() as usize;
    xcorr_lag(&data.f_master_n, &data.f_slave_n, data.dt_s, Some(max)).ok()
}

/// The slave lag is fitted on the measured forces alone (the model's own lag, if any, is
/// replaced), so the model document is not needed.
fn slave_lag(ctx: &Ctx<'_>, _doc: &ModelDoc) -> Option<Proposal> {
    let d = ctx.data;
    let lag = slave_force_lag(d)?;
    if lag.seconds <= 0.0 {
        return None;
    }
    let rss = |delay: f64| -> Option<f64> {
        let pred = delayed(&d.f_master_n, delay.max(0.0) / d.dt_s);
        let raw: Vec<f64> = d.f_slave_n.iter().zip(&pred).map(|(s, p)| s - p).collect();
        Some(super::fit::sumsq(&ctx.band.kept(
            d,
            ChannelId::SlaveForce,
            &raw,
        )))
    };
    let (lo, hi) = (
        (lag.seconds - 2.0 * d.dt_s).max(0.0),
        lag.seconds + 2.0 * d.dt_s,
    );
    let (delay, _) = minimise_1d(lo, hi, 9, 14, rss)?;
    Some(Proposal {
        kind: EffectKind::SlaveLag,
        params: vec![("delay_s", delay)],
        edits: vec![
            Edit::SetBool("motor", "slave_follows_master", true),
            Edit::Set("effects.slave_lag", "delay_s", delay),
        ],
        k: 1,
    })
}

fn pitch_error(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let base = doc.with(&[Edit::RemoveSection("effects.encoder_pitch_error")]);
    let model = base.model().ok()?;
    let d = ctx.data;
    let raw = channel_raw(d, &model, ChannelId::Encoder)?;
    let y = kept_of_raw(d, ctx.band, ChannelId::Encoder, &raw);
    let lambda = model.encoder.period_m;
    let idx = &ctx.band.idx_encoder;
    let xk: Vec<f64> = idx.iter().filter_map(|&i| d.x_m.get(i).copied()).collect();
    // The quick scan demeans its columns per motion stretch at the kept samples, as the
    // residual is demeaned per stretch at every sample.
    let seg_of: Vec<usize> = idx
        .iter()
        .map(|&i| {
            d.segments
                .iter()
                .position(|s| s.contains(&i))
                .unwrap_or(usize::MAX)
        })
        .collect();
    let demean_kept = |col: Vec<f64>| -> Vec<f64> {
        let mut sums: std::collections::BTreeMap<usize, (f64, usize)> = Default::default();
        for (v, s) in col.iter().zip(&seg_of) {
            let e = sums.entry(*s).or_insert((0.0, 0));
            e.0 += v;
            e.1 += 1;
        }
        col.iter()
            .zip(&seg_of)
            .map(|(v, s)| v - sums.get(s).map_or(0.0, |(t, c)| t / (*c).max(1) as f64))
            .collect()
    };
    let lin = demean_kept(xk.clone());
    let (f_lo, f_hi) = (1.0 / (2.0 * lambda), 1.0 / (0.5 * lambda));
    let df = 1.0 / (8.0 * kept_span(&xk));
    let steps = ((f_hi - f_lo) / df).ceil().min(4000.0) as usize;
    let mut best: Option<(f64, f64)> = None;
    for i in 0..=steps {
        let f = f_lo + df * i as f64;
        let mut cols = vec![lin.clone()];
        cols.extend(harmonics(&xk, f, true).into_iter().map(&demean_kept));
        if let Some((_, rss)) = lstsq(&cols, &y) {
            if best.is_none_or(|b| rss < b.1) {
                best = Some((f, rss));
            }
        }
    }
    let f0 = best?.0;
    // Refine with the columns demeaned and filtered exactly as the residual is.
    let fitf = |f: f64| -> Option<(Vec<f64>, f64)> {
        let filt =
            |col: Vec<f64>| kept_of_raw(d, ctx.band, ChannelId::Encoder, &d.demean_segments(&col));
        let mut cols = vec![filt(d.x_m.clone())];
        let hs = harmonics(&d.x_m, f, true);
        // Columns in the order sin f, cos f, sin 2f, cos 2f.
        cols.extend(hs.into_iter().map(filt));
        lstsq(&cols, &y)
    };
    let (f, _) = minimise_1d(f0 - df, f0 + df, 5, 16, |f| fitf(f).map(|r| r.1))?;
    let (th, _) = fitf(f)?;
    let g = |i: usize| th.get(i).copied().unwrap_or(0.0);
    let (scale, a1, b1, a2, b2) = (g(0), g(1), g(2), g(3), g(4));
    let params = vec![
        ("amplitude_m", a1.hypot(b1)),
        ("period_m", 1.0 / f),
        ("phase_rad", b1.atan2(a1)),
        ("scale", scale),
        ("amplitude2_m", a2.hypot(b2)),
        ("phase2_rad", b2.atan2(a2)),
    ];
    let edits = params
        .iter()
        .map(|&(k, v)| Edit::Set("effects.encoder_pitch_error", k, v))
        .collect();
    Some(Proposal {
        kind: EffectKind::EncoderPitchError,
        params,
        edits,
        k: 6,
    })
}

/// The pressure residual of `doc` at the kept samples.
fn pressure_kept(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Vec<f64>> {
    let model = doc.model().ok()?;
    let raw = channel_raw(ctx.data, &model, ChannelId::Pressure)?;
    Some(kept_of_raw(ctx.data, ctx.band, ChannelId::Pressure, &raw))
}

/// Default seal lengths of a leakage effect the model did not have, m (`machine.md`).
const PISTON_SEAL_LENGTH_M: f64 = 0.05;
const ROD_SEAL_LENGTH_M: f64 = 0.03;

fn leakage(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let search = pressure_search(ctx);
    let owned = search.as_ref().map(|(data, band)| Ctx { data, band });
    let ctx = owned.as_ref().unwrap_or(ctx);
    ctx.data.ports.ne(&PortsMeta::Unknown).then_some(())?;
    let seal = doc
        .number("effects.leakage", "seal_length_m")
        .unwrap_or(PISTON_SEAL_LENGTH_M);
    let rod_seal = doc
        .number("effects.leakage", "rod_seal_length_m")
        .unwrap_or(ROD_SEAL_LENGTH_M);
    let base = doc.with(&[Edit::RemoveSection("effects.leakage")]);
    let edits = |u: &[f64]| -> Vec<Edit> {
        let gap = u.first().copied().unwrap_or(0.0).max(0.0).cbrt();
        let rod = u.get(1).copied().unwrap_or(0.0).max(0.0).cbrt();
        vec![
            Edit::Set("effects.leakage", "gap_m", gap),
            Edit::Set("effects.leakage", "seal_length_m", seal),
            Edit::Set("effects.leakage", "rod_gap_m", rod),
            Edit::Set("effects.leakage", "rod_seal_length_m", rod_seal),
        ]
    };
    // Leak flow is linear in gap³: fit in those units (µm³ scale keeps the steps sane).
    const UNIT: f64 = 1e-18; // (1 µm)³
    let res = |u: &[f64]| -> Option<Vec<f64>> {
        let si: Vec<f64> = u.iter().map(|v| v * UNIT).collect();
        pressure_kept(ctx, &base.with(&edits(&si)))
    };
    let start = vec![10f64.powi(3), 5f64.powi(3)];
    let (u, _) = gauss_newton_nonneg(start, &[2000.0, 500.0], 6, res)?;
    let si: Vec<f64> = u.iter().map(|v| v * UNIT).collect();
    let e = edits(&si);
    let gap = si.first().copied().unwrap_or(0.0).cbrt();
    let rod = si.get(1).copied().unwrap_or(0.0).cbrt();
    Some(Proposal {
        kind: EffectKind::Leakage,
        params: vec![
            ("gap_m", gap),
            ("seal_length_m", seal),
            ("rod_gap_m", rod),
            ("rod_seal_length_m", rod_seal),
        ],
        edits: e,
        k: 2,
    })
}

fn heat_transfer(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let search = pressure_search(ctx);
    let owned = search.as_ref().map(|(data, band)| Ctx { data, band });
    let ctx = owned.as_ref().unwrap_or(ctx);
    ctx.data.ports.ne(&PortsMeta::Unknown).then_some(())?;
    let base = doc.with(&[Edit::RemoveSection("effects.heat_transfer")]);
    let wall = doc.number("effects.heat_transfer", "wall_temperature_k");
    let edits = |ua: f64| -> Vec<Edit> {
        let mut e = vec![Edit::Set("effects.heat_transfer", "ua_w_per_k", ua)];
        if let Some(t) = wall {
            e.push(Edit::Set("effects.heat_transfer", "wall_temperature_k", t));
        }
        e
    };
    let (lua, _) = minimise_1d(0.01f64.ln(), 500f64.ln(), 6, 8, |l| {
        pressure_kept(ctx, &base.with(&edits(l.exp()))).map(|r| super::fit::sumsq(&r))
    })?;
    let ua = lua.exp();
    Some(Proposal {
        kind: EffectKind::HeatTransfer,
        params: vec![("ua_w_per_k", ua)],
        edits: edits(ua),
        k: 1,
    })
}

fn port_restriction(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let search = pressure_search(ctx);
    let owned = search.as_ref().map(|(data, band)| Ctx { data, band });
    let ctx = owned.as_ref().unwrap_or(ctx);
    (ctx.data.ports == PortsMeta::Open).then_some(())?;
    let base = doc.with(&[Edit::RemoveSection("effects.port_restriction")]);
    let edits = |s: f64| vec![Edit::Set("effects.port_restriction", "area_scale", s)];
    let (ls, _) = minimise_1d(0.05f64.ln(), 10f64.ln(), 6, 8, |l| {
        pressure_kept(ctx, &base.with(&edits(l.exp()))).map(|r| super::fit::sumsq(&r))
    })?;
    let s = ls.exp();
    Some(Proposal {
        kind: EffectKind::PortRestriction,
        params: vec![("area_scale", s)],
        edits: edits(s),
        k: 1,
    })
}
