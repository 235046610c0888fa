//! How the logged forces line up with the logged position: a property of the logger, not of
//! the machine, and so a nuisance parameter of the force balance.
//!
//! Loggers differ: our firmware reports last cycle's current (the forces are one period
//! late, `# force_delay_s = 5e-5`); another logs the command it is about to hold (on time,
//! but the held force acts half a period later on average); a third logs after a filter.
//! Left as an assumption, any difference reads as an actuator lag. So a log that declares
//! `# force_delay_s` is realigned by it exactly, and one that does not has its alignment
//! fitted: the shift of the reported forces, within ±[`ALIGN_WINDOW_SAMPLES`] periods, that
//! best closes the input model's force balance.
//!
//! A physical actuator lag and a logging convention are the same shift of the same signal,
//! so they cannot be told apart below the window: a lag shorter than the window's reach is
//! absorbed here (the workflow's detection floor for `actuator_lag` on undeclared logs). A
//! longer one drives the fit to the window's edge; the alignment is then taken as the
//! common convention ([`UNDECLARED_ALIGN_SAMPLES`]) and the excess left for `actuator_lag`
//! to explain and report.

use crate::plant::model::MachineModel;

use super::channel::ChannelId;
use super::data::{Measured, ALIGN_WINDOW_SAMPLES, UNDECLARED_ALIGN_SAMPLES};
use super::fit::{minimise_1d_par, sumsq};
use super::residuals::{band_force_raw_aligned, Band};

/// What the alignment fit found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Alignment {
    /// The best shift within the window, s (forces act this long after their row).
    pub fitted_s: f64,
    /// Whether it lies at the window's edge (a longer delay than a convention explains).
    pub at_edge: bool,
    /// The alignment used from now on, s.
    pub used_s: f64,
}

/// Fits the alignment of `data` (which must not declare one) for `model`.
pub fn estimate(data: &Measured, band: &Band, model: &MachineModel) -> Option<Alignment> {
    let dt = data.dt_s;
    let (lo, hi) = (-ALIGN_WINDOW_SAMPLES, ALIGN_WINDOW_SAMPLES);
    let (samples, _) = minimise_1d_par(lo, hi, 13, 18, |s| {
        let raw = band_force_raw_aligned(data, band, model, s * dt);
        Some(sumsq(&band.kept(data, ChannelId::Force, &raw)))
    })?;
    let at_edge = samples <= lo + 0.05 || samples >= hi - 0.05;
    Some(Alignment {
        fitted_s: samples * dt,
        at_edge,
        used_s: if at_edge {
            UNDECLARED_ALIGN_SAMPLES * dt
        } else {
            samples * dt
        },
    })
}
