//! The force balance along a run log, as `fpc-sim forces` (the paper's Fig. 8) and
//! `fpc-sim energy` (Fig. 9) show it: every force on the piston at every sample by the
//! model's laws, the inertia force `m·a` estimated three ways from the logged position, and
//! the works of one stroke.
//!
//! The model's forces are the model-gap workflow's own, sample for sample
//! ([`crate::gap::residuals::force_terms`], which evaluates [`fpc::physics::balance`]): the log
//! is read as the workflow reads it ([`Measured`]: the firmware's differentiator for `v` and
//! `Δ²x`, the rotation speed for the sliding friction of the turning piston, the pressure
//! readings' rates to undo the sensors' lag, the motor forces realigned by the log's
//! convention), so the force these plots leave unexplained is the one `fpc-sim gap` starts
//! from.
//!
//! Works are `∫F dx` along the stroke (trapezoid rule on the logged position): motor
//! `F_master + F_slave`, gas `(p_a − p_b)·A_eff` and cogging (work done *on* the piston),
//! friction (dissipated, positive) and inertia `m·a` (= the change of kinetic energy). Their
//! balance `W_motor + W_gas + W_cog − W_fr − W_inertia` measures how well the log and the
//! model agree.

use std::ops::Range;

use fpc::control::config::ControlConfig;
use serde::Serialize;

use crate::failure::Failure;
use crate::gap::data::Measured;
use crate::gap::residuals::force_terms;
use crate::plant::model::MachineModel;
use crate::runlog::RunLog;
use crate::signal::{filtfilt, firmware_derivatives, second_difference, Biquad, SgSettings};

/// Slowest log these analyses read, Hz: the workflow's differentiator is at least 5 samples
/// long, 10 ms at this rate — enough for the friction's velocity of a stroke, not for the
/// workflow's fits (which need [`crate::gap::data::MIN_SAMPLE_RATE_HZ`]).
pub const MIN_SAMPLE_RATE_HZ: f64 = 500.0;

/// The forces on the piston along a log, N, one per sample.
#[derive(Clone, Debug, PartialEq)]
pub struct ForceBalance {
    /// Position as logged, m.
    pub x_m: Vec<f64>,
    /// Velocity, the workflow's (the firmware's differentiator, centred), m/s.
    pub v_mps: Vec<f64>,
    /// Both motor sections as they act on the piston, `F_master + F_slave` realigned.
    pub motor_n: Vec<f64>,
    /// Gas force `(p_a − p_b)·A_eff` of the true pressures, toward +x.
    pub gas_n: Vec<f64>,
    /// Cogging, toward +x (zero without the model's `[effects.cogging]`).
    pub cogging_n: Vec<f64>,
    /// Axial friction of the sliding, turning piston (it opposes motion: subtracted).
    pub friction_n: Vec<f64>,
    /// What the forces imply for `m·a`: the model's net force.
    pub expected_inertia_n: Vec<f64>,
    /// `m·Δ²x − F_net`: the force the model does not explain (the raw force residual of
    /// `fpc-sim gap`, before its band).
    pub unexplained_n: Vec<f64>,
    /// `m·a` from the unfiltered position (second difference).
    pub inertia_raw_n: Vec<f64>,
    /// `m·a` from the zero-phase filtered position.
    pub inertia_filtered_n: Vec<f64>,
    /// `m·a` from the firmware's Savitzky–Golay differentiator (its own settings and lag).
    pub inertia_firmware_n: Vec<f64>,
}

/// Reads `log` as the workflow does, for these analyses (down to [`MIN_SAMPLE_RATE_HZ`]).
/// The error names the metadata key or column.
pub fn read_measured(log: &RunLog, model: &MachineModel) -> Result<Measured, String> {
    Measured::from_log_down_to(log, model.encoder.period_m, MIN_SAMPLE_RATE_HZ)
}

/// Computes the force balance of the measured run `data` with `model`'s parameters;
/// `sections` is the zero-phase low-pass of the filtered inertia estimate. The error (the
/// firmware's differentiator cannot run at the log's rate) is bad input.
pub fn force_balance(
    data: &Measured,
    model: &MachineModel,
    sections: &[Biquad],
) -> Result<ForceBalance, Failure> {
    let dt = data.dt_s;
    let x = &data.x_m;
    let m = model.piston.mass_kg;
    let terms = force_terms(data, model);
    let pick = |f: fn(&fpc::physics::balance::PistonForces<f64>) -> f64| -> Vec<f64> {
        terms.iter().map(f).collect()
    };
    let inertia = |a: Vec<f64>| a.into_iter().map(|a| m * a).collect::<Vec<f64>>();
    let c = ControlConfig::reference();
    let sg = SgSettings {
        window: c.sg_window,
        order: c.sg_order,
        lag: c.sg_lag,
    };
    // The settings are the firmware's: only the log's sample time can make them unusable.
    let (_, a_fw) = firmware_derivatives(x, dt, model.encoder.period_m, sg).map_err(|e| {
        Failure::bad_input(format!(
            "the log's sample time {dt:e} s: the firmware's differentiator cannot run at it ({e})"
        ))
    })?;
    Ok(ForceBalance {
        unexplained_n: terms
            .iter()
            .zip(&data.d2x_mps2)
            .map(|(f, a)| f.unexplained_n(m, *a))
            .collect(),
        motor_n: pick(|f| f.motor_n),
        gas_n: pick(|f| f.gas_n),
        cogging_n: pick(|f| f.cogging_n),
        friction_n: pick(|f| f.friction_n),
        expected_inertia_n: pick(|f| f.net_n()),
        inertia_raw_n: inertia(second_difference(x, dt)),
        inertia_filtered_n: inertia(filtfilt(sections, &second_difference(x, dt))),
        inertia_firmware_n: inertia(a_fw),
        v_mps: data.v_mps.clone(),
        x_m: data.x_m.clone(),
    })
}

/// The works of one stroke, J.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct StrokeEnergy {
    /// Where the stroke starts and ends, m.
    pub from_m: f64,
    /// End of the stroke, m.
    pub to_m: f64,
    /// Work of both motor sections.
    pub motor_j: f64,
    /// Motor work until the peak speed (acceleration).
    pub motor_accelerating_j: f64,
    /// Motor work after the peak speed (deceleration; negative: the motor brakes).
    pub motor_decelerating_j: f64,
    /// Work done on the piston by the gas.
    pub gas_j: f64,
    /// Work done on the piston by cogging (near zero over whole pitches).
    pub cogging_j: f64,
    /// Work dissipated by friction.
    pub friction_j: f64,
    /// Work into inertia over the stroke (kinetic energy at the end minus at the start).
    pub inertia_j: f64,
    /// Kinetic energy at the peak speed: what inertia stores and gives back.
    pub peak_kinetic_j: f64,
    /// `motor + gas + cogging − friction − inertia`: zero when log and model agree.
    pub balance_j: f64,
}

/// `∫ f dx` over `r` (trapezoid rule).
pub fn work(f: &[f64], x: &[f64], r: &Range<usize>) -> f64 {
    let f = f.get(r.clone()).unwrap_or_default();
    let x = x.get(r.clone()).unwrap_or_default();
    f.windows(2)
        .zip(x.windows(2))
        .map(|(f, x)| 0.5 * (f[0] + f[1]) * (x[1] - x[0]))
        .sum()
}

/// The works of stroke `r` of a force balance, for a piston of `mass_kg`.
pub fn stroke_energy(fb: &ForceBalance, r: &Range<usize>, mass_kg: f64) -> StrokeEnergy {
    let x = &fb.x_m;
    let peak_at = r
        .clone()
        .max_by(|&a, &b| {
            let va = fb.v_mps.get(a).map_or(0.0, |v| v.abs());
            let vb = fb.v_mps.get(b).map_or(0.0, |v| v.abs());
            va.total_cmp(&vb)
        })
        .unwrap_or(r.start);
    let v_peak = fb.v_mps.get(peak_at).copied().unwrap_or(0.0);
    let motor_j = work(&fb.motor_n, x, r);
    let gas_j = work(&fb.gas_n, x, r);
    let cogging_j = work(&fb.cogging_n, x, r);
    let friction_j = work(&fb.friction_n, x, r);
    let inertia_j = work(&fb.inertia_filtered_n, x, r);
    let left: Vec<f64> = fb
        .expected_inertia_n
        .iter()
        .zip(&fb.inertia_filtered_n)
        .map(|(net, inertia)| net - inertia)
        .collect();
    StrokeEnergy {
        from_m: x.get(r.start).copied().unwrap_or(0.0),
        to_m: x.get(r.end.saturating_sub(1)).copied().unwrap_or(0.0),
        motor_j,
        motor_accelerating_j: work(&fb.motor_n, x, &(r.start..peak_at + 1)),
        motor_decelerating_j: work(&fb.motor_n, x, &(peak_at..r.end)),
        gas_j,
        cogging_j,
        friction_j,
        inertia_j,
        peak_kinetic_j: 0.5 * mass_kg * v_peak * v_peak,
        // The work of what the balance leaves, F_net − m·a: by the trapezoid rule's
        // linearity, motor + gas + cogging − friction − inertia.
        balance_j: work(&left, x, r),
    }
}
