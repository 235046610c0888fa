//! The slave-force channel's candidate: the slave section's force late behind the master's
//! (the paper's FFT cross-correlation, then golden section).

use crate::plant::model::model_key;
use crate::signal::{delayed, xcorr_lag};

use super::super::candidate::{EffectKind, Proposal};
use super::super::channel::ChannelId;
use super::super::ctx::Ctx;
use super::super::data::Measured;
use super::super::doc::{Edit, ModelDoc};
use super::super::fit::minimise_1d_par;
use super::MAX_LAG_S;

/// How far the slave force lags the master's (the paper's FFT method).
pub fn slave_force_lag(data: &Measured) -> Option<crate::signal::Lag> {
    let max = (MAX_LAG_S / data.dt_s).round() as usize;
    xcorr_lag(&data.f_master_n, &data.f_slave_n, data.dt_s, Some(max)).ok()
}

/// The slave lag is fitted on the measured forces alone (the model's own lag, if any, is
/// replaced), so the model document is not needed.
pub(super) fn slave_lag(ctx: &Ctx<'_>, _doc: &ModelDoc) -> Option<Proposal> {
    let d = ctx.data;
    let lag = slave_force_lag(d)?;
    if lag.seconds <= 0.0 {
        return None;
    }
    let rss = |delay: f64| -> Option<f64> {
        let pred = delayed(&d.f_master_n, delay.max(0.0) / d.dt_s);
        let raw: Vec<f64> = d.f_slave_n.iter().zip(&pred).map(|(s, p)| s - p).collect();
        Some(super::super::fit::sumsq(&ctx.band.kept(
            d,
            ChannelId::SlaveForce,
            &raw,
        )))
    };
    let (lo, hi) = (
        (lag.seconds - 2.0 * d.dt_s).max(0.0),
        lag.seconds + 2.0 * d.dt_s,
    );
    let (delay, _) = minimise_1d_par(lo, hi, 9, 14, rss)?;
    let mut p = Proposal::setting(
        EffectKind::SlaveLag,
        &[(model_key!(effects.slave_lag / delay_s), delay)],
        1,
    );
    // A lagging slave follows the master's force.
    p.edits.insert(
        0,
        Edit::SetBool(model_key!(motor / slave_follows_master), true),
    );
    Some(p)
}
