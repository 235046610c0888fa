//! The logged position's zero as a nuisance of the pressure replay: how far homing can
//! leave it from the chambers' own ([`position_offset_bounds`]) and its fit to the pressures,
//! once per log before the selection ([`fit_position_offset`]).

use crate::plant::model::MachineModel;

use super::channel::{resolution, ChannelId};
use super::data::Measured;
use super::replay::ports_resolved;
use super::residuals::{residual, Band};

/// Widest offset of the logged position from the chambers' own that
/// [`fit_position_offset`] accepts whatever the model says, m: a homing push's contact and
/// an encoder's zero are microns; tens of microns would be another machine.
pub const MAX_POSITION_OFFSET_M: f64 = 50e-6;

/// The offsets of the logged position from the chambers' own that homing can leave, m:
/// from 0 (a log that was not homed on head A) to the contact's give under the largest
/// homing push — the homing force limit ([`fpc::sensing::homing::HomingConfig::reference`],
/// 400 N: the current never exceeds it, the command stays 5 % below) on the heads' contact
/// stiffness (`piston.stop_stiffness_n_per_m`, 5e7 N/m: 8 µm) — plus one step of the
/// encoder's interpolation ([`resolution`], ≈ 2.4 µm: where within a step
/// the zero was declared), and never more than [`MAX_POSITION_OFFSET_M`]. One sign: homing
/// pushes the piston *into* head A, so the logged position reads more than the chambers'.
/// Bounded so, the offset cannot take up a pressure effect's pattern: at ±50 µm it ran to
/// the bound on logs with a hidden leak, port restriction or pair.
pub fn position_offset_bounds(model: &MachineModel) -> (f64, f64) {
    let push_n = f64::from(fpc::sensing::homing::HomingConfig::reference().force_limit_n);
    let contact_m = push_n / model.piston.stop_stiffness_n_per_m;
    let step_m = resolution(ChannelId::Encoder, model);
    (0.0, (contact_m + step_m).min(MAX_POSITION_OFFSET_M))
}

/// The offset of the logged position from the chambers' own, m (the logged `x_m` reads this
/// much more), fitted to the pressures once per log as a nuisance; `None` without `# ports`
/// or with nothing to judge.
///
/// Why: the zero of `x_m` is where homing declared the piston on head A, pushed into the
/// head's contact by the homing force. In our plant that push is 250–380 N (the detection
/// level to the command limit, `fpc::sensing::homing::HomingConfig::reference`) on a
/// 5e7 N/m contact: the zero lies 5–8 µm inside head A, and every logged position reads that
/// much more than the plant's (7–10 µm measured on our runs). A rig's homing is the same. Near
/// a dead point, where a chamber's volume is its ~1 mm clearance, 10 µm is 1 % of the volume
/// and hundreds of Pa at a port opening: on a null run at 2.3 m/s, PR 6 (`docs/gap.md`)
/// `port_restriction` took it up. Fitted here, before the selection, no named effect absorbs
/// it; bounded by [`position_offset_bounds`].
///
/// Gauss–Newton steps from the log's offset (0) on the pressure residual as the selection
/// judges it (band-filtered, at `band`'s kept samples of both chambers), each sensitivity
/// from one replay moved by 2 µm; a step is kept only while it lowers the residual, at most
/// [`MAX_OFFSET_STEPS`] (two replays each). On the raw residual, which the sensor's
/// rounding dominates, the steps stopped at 3.9–4.9 µm on that run and `port_restriction`
/// was still named; on the band-filtered one they reach 7.35 µm and nothing is.
/// `None`: no pressure channel, or no step lowered the residual.
pub fn fit_position_offset(data: &Measured, band: &Band, model: &MachineModel) -> Option<f64> {
    const PROBE_M: f64 = 2e-6;
    let (lo, hi) = position_offset_bounds(model);
    let kept_at = |offset: f64| -> Option<Vec<f64>> {
        let mut moved = data.clone();
        moved.x_offset_m = offset;
        residual(&moved, band, model, ChannelId::Pressure).map(|r| r.kept)
    };
    let rss = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>();
    // Each step's probe replay is made beside the replay it follows from (the one at the
    // log's offset, then each step's trial, whose probe the next step reads if the trial
    // is kept): the same replays are read in the same order, on two cores.
    let (r0, mut probe) = rayon::join(
        || kept_at(data.x_offset_m),
        || kept_at(data.x_offset_m + PROBE_M),
    );
    let mut r0 = r0?;
    let mut best = (data.x_offset_m, rss(&r0));
    for step in 1..=MAX_OFFSET_STEPS {
        let r1 = probe.take()?;
        let (mut num, mut den) = (0.0, 0.0);
        for (a, b) in r0.iter().zip(&r1) {
            let d = (b - a) / PROBE_M;
            num += a * d;
            den += d * d;
        }
        if den.is_nan() || den <= 0.0 {
            break;
        }
        let offset = (best.0 - num / den).clamp(lo, hi);
        if offset == best.0 {
            break;
        }
        let (r2, next) = if step < MAX_OFFSET_STEPS {
            rayon::join(|| kept_at(offset), || kept_at(offset + PROBE_M))
        } else {
            (kept_at(offset), None)
        };
        let r2 = r2?;
        let r = rss(&r2);
        if r >= best.1 {
            break;
        }
        let moved = (offset - best.0).abs();
        best = (offset, r);
        r0 = r2;
        probe = next;
        if moved < 0.1e-6 {
            break;
        }
    }
    (best.0 != data.x_offset_m).then_some(best.0)
}

/// Fits the logged position's offset ([`fit_position_offset`]) and sets it on `measured`,
/// with the pressure channel's angle-resolution mask ([`ports_resolved`]) made with it in
/// place; `band_hz` is the analysis band's upper edge, Hz.
///
/// The logged position's zero (homing's push into head A) is a nuisance of the pressure
/// replay: fitted once, before any effect may take it up, on the log's first
/// `MAX_OFFSET_FIT_ROWS` with their own angle-resolution mask (each step replays the
/// chambers twice: on the 732k-row log the whole log would cost seconds). The whole
/// log's mask is then made with the offset in place: its nominal replay, made beside the
/// moved one, is the one the selection's first step reads.
pub fn set_position_offset(measured: &mut Measured, model: &MachineModel, band_hz: f64) {
    let fit_offset = |head: &mut Measured| -> Option<f64> {
        if let Some(judged) = ports_resolved(head, model) {
            head.pressure_judged = judged;
        }
        Band::new(head, band_hz)
            .ok()
            .and_then(|b| fit_position_offset(head, &b, model))
    };
    let long = measured.len() > MAX_OFFSET_FIT_ROWS;
    let offset = if long {
        fit_offset(&mut measured.head(MAX_OFFSET_FIT_ROWS))
    } else {
        fit_offset(measured)
    };
    if let Some(offset) = offset {
        measured.x_offset_m = offset;
    }
    // (A short log's mask is already the whole log's where the offset stayed at 0.)
    if long || offset.is_some() {
        if let Some(judged) = ports_resolved(measured, model) {
            measured.pressure_judged = judged;
        }
    }
}

/// Most rows of a log [`fit_position_offset`] is fitted on (its first ones): 5 s at 20 kHz,
/// three cycles of timed ports at 0.3 m/s. The fit replays the chambers up to
/// 2 × [`MAX_OFFSET_STEPS`] times; the offset of a homing holds for the whole log.
/// (The pressure searches' stretch, 1.5 s with the bypass's first 0.93 s in it, was too
/// short: it fitted 0.66 µm on that run, where the whole log gives 7.35 µm.)
pub const MAX_OFFSET_FIT_ROWS: usize = 100_000;

/// Most Gauss–Newton steps of [`fit_position_offset`].
const MAX_OFFSET_STEPS: usize = 6;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_homing_offset_is_bounded_by_the_push_on_the_heads_contact() {
        let mut model = MachineModel::reference();
        let step = resolution(ChannelId::Encoder, &model);
        let push = f64::from(fpc::sensing::homing::HomingConfig::reference().force_limit_n);
        // One sign (into head A), and a few microns on the reference contact (5e7 N/m).
        let (lo, hi) = position_offset_bounds(&model);
        assert_eq!(lo, 0.0);
        let contact = push / model.piston.stop_stiffness_n_per_m;
        assert!((hi - (contact + step)).abs() < 1e-12, "{hi}");
        assert!(
            hi > 5e-6 && hi < 15e-6,
            "{hi}: the reference's 8 µm contact + one step"
        );
        // A stiffer head gives less; a soft one never more than the outer bound.
        model.piston.stop_stiffness_n_per_m *= 10.0;
        assert!(position_offset_bounds(&model).1 < hi);
        model.piston.stop_stiffness_n_per_m = 1e3;
        assert_eq!(position_offset_bounds(&model).1, MAX_POSITION_OFFSET_M);
    }
}
