//! What every fit is handed: the measured run and the analysis band, and what they give
//! together.

use super::data::Measured;
use super::residuals::Band;

/// What the fits share: the measured run and the band.
pub struct Ctx<'a> {
    /// The measured run.
    pub data: &'a Measured,
    /// The analysis band.
    pub band: &'a Band,
}

/// The measured position at the force channel's kept samples, m.
pub(super) fn kept_x(ctx: &Ctx<'_>) -> Vec<f64> {
    ctx.band
        .idx_force
        .iter()
        .filter_map(|&i| ctx.data.x_m.get(i).copied())
        .collect()
}
