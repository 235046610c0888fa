//! The pressure channel's candidates: clearance leakage, heat transfer to the wall and
//! restricted ports, each a replay of the chambers along the measured motion with the
//! effect, fitted on a stretch of the log.

use std::sync::Arc;

use crate::plant::model::{model_key, model_section};

use super::super::candidate::{EffectKind, Proposal};
use super::super::channel::ChannelId;
use super::super::ctx::Ctx;
use super::super::data::{Measured, PortsMeta};
use super::super::doc::{Edit, ModelDoc};
use super::super::fit::{gauss_newton_nonneg, minimise_1d_par};
use super::super::residuals::{channel_raw, kept_of_raw, Band};

/// Stretch of a log the pressure candidates' parameter searches replay, s: each search
/// replays the chambers 15–20 times, and [`PRESSURE_SEARCH_S`] of a compressor run (several
/// cycles) or of a closed-port campaign pins a leak gap, a UA or an area as well as the
/// whole log. On ports timed by the rotation it is lengthened to hold
/// [`PRESSURE_SEARCH_CYCLES`] cycles after the bypass closes ([`search_s`]). The candidate
/// is then judged on the whole log.
pub const PRESSURE_SEARCH_S: f64 = 1.5;

/// Fewest cycles of the ports timed by the rotation that the pressure searches see.
///
/// Why: 1.5 s is several cycles at the speeds the workflow was validated at, but at 0.3 m/s
/// a cycle lasts 1.27 s and our runs' bypass closes at 0.93 s: the search saw less than
/// half a compression. The piston seal's leak (A↔B) and the rod seals' (to ambient) are
/// then nearly one direction, and where the search had only the first port opening after
/// the bypass to tell them apart, it fitted 10.7 and 34.7 µm for 25 and 10 µm once that
/// opening was no longer judged ([`crate::gap::replay::ports_resolved`]): `heat_transfer`
/// was named in its place. Over two cycles: 25.0 and 10.2 µm.
pub const PRESSURE_SEARCH_CYCLES: f64 = 2.0;

/// How long the pressure searches' stretch is on `data`, s: [`PRESSURE_SEARCH_S`], or on
/// rotation-timed ports up to [`PRESSURE_SEARCH_CYCLES`] cycles after `# ports_from_s` (a
/// cycle is a turn of the ports' angle, at its mean speed over the timed part of the log).
fn search_s(data: &Measured) -> f64 {
    if data.ports != PortsMeta::Open {
        return PRESSURE_SEARCH_S;
    }
    let t_first = data.t_s.first().copied().unwrap_or(0.0);
    let from = data.ports_from_s.unwrap_or(t_first).max(t_first);
    let i0 = data.t_s.iter().position(|t| *t >= from).unwrap_or(0);
    let (Some(a0), Some(a1), Some(t0), Some(t1)) = (
        data.ports_angle_rad.get(i0),
        data.ports_angle_rad.last(),
        data.t_s.get(i0),
        data.t_s.last(),
    ) else {
        return PRESSURE_SEARCH_S;
    };
    let speed = (a1 - a0).abs() / (t1 - t0);
    if !(speed.is_finite() && speed > 0.0) {
        return PRESSURE_SEARCH_S;
    }
    PRESSURE_SEARCH_S.max(from - t_first + PRESSURE_SEARCH_CYCLES * std::f64::consts::TAU / speed)
}

/// The data and band the pressure searches run on: the first [`search_s`] (of a
/// closed-port log with `# ports_from_s`: from [`PRESSURE_SEARCH_LEAD_S`] before it) of the
/// log, or the whole log if it is shorter (then `None`: use `ctx` itself). Cut once per log
/// and kept with its band ([`Band::pressure_searches`]), with the replays made there.
pub(super) fn pressure_search(ctx: &Ctx<'_>) -> Arc<Option<(Measured, Band)>> {
    let n = (search_s(ctx.data) / ctx.data.dt_s).round() as usize;
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
        return Arc::new(None);
    }
    let n = n.min(rest);
    // The pressure channel never reads the force alignment (which the selection may fit
    // again): a stretch cut before it moved serves after.
    let key = (start, n, ctx.data.x_offset_m.to_bits());
    ctx.band.pressure_searches.get_or_make(key, || {
        let head = ctx.data.window(start, n);
        let band = Band::new(&head, ctx.band.band_hz).ok()?;
        Some((head, band))
    })
}

/// How long before a closed-port log's `# ports_from_s` the pressure searches begin, s: the
/// rest before the sealing, which the replay starts from.
pub const PRESSURE_SEARCH_LEAD_S: f64 = 0.1;

/// The pressure residual of `doc` at the kept samples.
pub(super) fn pressure_kept(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Vec<f64>> {
    let model = doc.model().ok()?;
    let raw = channel_raw(ctx.data, &model, ChannelId::Pressure)?;
    Some(kept_of_raw(ctx.data, ctx.band, ChannelId::Pressure, &raw))
}

/// Default seal lengths of a leakage effect the model did not have, m (`docs/machine.md`).
const PISTON_SEAL_LENGTH_M: f64 = 0.05;
const ROD_SEAL_LENGTH_M: f64 = 0.03;

pub(super) fn leakage(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let search = pressure_search(ctx);
    let owned = (*search).as_ref().map(|(data, band)| Ctx { data, band });
    let ctx = owned.as_ref().unwrap_or(ctx);
    ctx.data.ports.ne(&PortsMeta::Unknown).then_some(())?;
    let seal = doc
        .number(model_key!(effects.leakage / seal_length_m))
        .unwrap_or(PISTON_SEAL_LENGTH_M);
    let rod_seal = doc
        .number(model_key!(effects.leakage / rod_seal_length_m))
        .unwrap_or(ROD_SEAL_LENGTH_M);
    let base = doc.with(&[Edit::RemoveSection(model_section!(effects.leakage))]);
    // The effect at gap³ and rod gap³ `u`.
    let effect = |u: &[f64]| -> Proposal {
        let gap = u.first().copied().unwrap_or(0.0).max(0.0).cbrt();
        let rod = u.get(1).copied().unwrap_or(0.0).max(0.0).cbrt();
        Proposal::setting(
            EffectKind::Leakage,
            &[
                (model_key!(effects.leakage / gap_m), gap),
                (model_key!(effects.leakage / seal_length_m), seal),
                (model_key!(effects.leakage / rod_gap_m), rod),
                (model_key!(effects.leakage / rod_seal_length_m), rod_seal),
            ],
            2,
        )
    };
    // Leak flow is linear in gap³: fit in those units (µm³ scale keeps the steps sane).
    const UNIT: f64 = 1e-18; // (1 µm)³
    let res = |u: &[f64]| -> Option<Vec<f64>> {
        let si: Vec<f64> = u.iter().map(|v| v * UNIT).collect();
        pressure_kept(ctx, &base.with(&effect(&si).edits))
    };
    let start = vec![10f64.powi(3), 5f64.powi(3)];
    let (u, _) = gauss_newton_nonneg(start, &[2000.0, 500.0], 6, res)?;
    let si: Vec<f64> = u.iter().map(|v| v * UNIT).collect();
    Some(effect(&si))
}

pub(super) fn heat_transfer(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let search = pressure_search(ctx);
    let owned = (*search).as_ref().map(|(data, band)| Ctx { data, band });
    let ctx = owned.as_ref().unwrap_or(ctx);
    ctx.data.ports.ne(&PortsMeta::Unknown).then_some(())?;
    let base = doc.with(&[Edit::RemoveSection(model_section!(effects.heat_transfer))]);
    let wall = doc.number(model_key!(effects.heat_transfer / wall_temperature_k));
    let edits = |ua: f64| -> Vec<Edit> {
        let mut e = vec![Edit::Set(
            model_key!(effects.heat_transfer / ua_w_per_k),
            ua,
        )];
        if let Some(t) = wall {
            e.push(Edit::Set(
                model_key!(effects.heat_transfer / wall_temperature_k),
                t,
            ));
        }
        e
    };
    let (lua, _) = minimise_1d_par(0.01f64.ln(), 500f64.ln(), 6, 8, |l| {
        pressure_kept(ctx, &base.with(&edits(l.exp()))).map(|r| super::super::fit::sumsq(&r))
    })?;
    let ua = lua.exp();
    Some(Proposal {
        kind: EffectKind::HeatTransfer,
        params: vec![(model_key!(effects.heat_transfer / ua_w_per_k).name, ua)],
        edits: edits(ua),
        k: 1,
    })
}

pub(super) fn port_restriction(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let search = pressure_search(ctx);
    let owned = (*search).as_ref().map(|(data, band)| Ctx { data, band });
    let ctx = owned.as_ref().unwrap_or(ctx);
    (ctx.data.ports == PortsMeta::Open).then_some(())?;
    let base = doc.with(&[Edit::RemoveSection(model_section!(
        effects.port_restriction
    ))]);
    let effect = |s: f64| {
        Proposal::setting(
            EffectKind::PortRestriction,
            &[(model_key!(effects.port_restriction / area_scale), s)],
            1,
        )
    };
    let (ls, _) = minimise_1d_par(0.05f64.ln(), 10f64.ln(), 6, 8, |l| {
        pressure_kept(ctx, &base.with(&effect(l.exp()).edits)).map(|r| super::super::fit::sumsq(&r))
    })?;
    Some(effect(ls.exp()))
}
