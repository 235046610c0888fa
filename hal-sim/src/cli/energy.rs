//! `fpc-sim energy` (the paper's Fig. 9): where the motor's work goes along one stroke —
//! into the gas, into friction, and into the piston's inertia (stored while accelerating,
//! given back while decelerating).
//!
//! Works are `∫F dx` along the stroke (trapezoid rule on the logged position):
//! motor `F_master + F_slave`, gas `(p_a − p_b)·A_eff` (work done *on* the piston; negative
//! while it compresses), friction `F_fr(v)` (dissipated, positive) and inertia `m·a`
//! (= the change of kinetic energy). Their balance `W_motor + W_gas − W_fr − W_inertia`
//! measures how well the log and the model agree.

use std::ops::Range;

use clap::Args;
use serde::Serialize;

use crate::cli::analysis::{LogToolArgs, Steps, ZeroPhaseArgs};
use crate::cli::forces::{kilonewtons, read_force_balance, ForceBalance};
use crate::console::Num;
use crate::failure::{CmdResult, Failure};
use crate::outln;
use crate::plot::curves;
use crate::signal::strokes;

/// Energy transformation during one stroke (Fig. 9).
#[derive(Args, Debug)]
pub struct EnergyArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub io: LogToolArgs,
    /// Which stroke, counted from 0 (default: the last complete one).
    #[arg(long)]
    pub stroke: Option<usize>,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub filter: ZeroPhaseArgs,
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
    /// Work dissipated by friction.
    pub friction_j: f64,
    /// Work into inertia over the stroke (kinetic energy at the end minus at the start).
    pub inertia_j: f64,
    /// Kinetic energy at the peak speed: what inertia stores and gives back.
    pub peak_kinetic_j: f64,
    /// `motor + gas − friction − inertia`: zero when log and model agree.
    pub balance_j: f64,
}

/// `∫ f dx` over `r` (trapezoid rule).
fn work(f: &[f64], x: &[f64], r: &Range<usize>) -> f64 {
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
    let friction_j = work(&fb.friction_n, x, r);
    let inertia_j = work(&fb.inertia_filtered_n, x, r);
    StrokeEnergy {
        from_m: x.get(r.start).copied().unwrap_or(0.0),
        to_m: x.get(r.end.saturating_sub(1)).copied().unwrap_or(0.0),
        motor_j,
        motor_accelerating_j: work(&fb.motor_n, x, &(r.start..peak_at + 1)),
        motor_decelerating_j: work(&fb.motor_n, x, &(peak_at..r.end)),
        gas_j,
        friction_j,
        inertia_j,
        peak_kinetic_j: 0.5 * mass_kg * v_peak * v_peak,
        balance_j: motor_j + gas_j - friction_j - inertia_j,
    }
}

/// Runs `fpc-sim energy`.
pub fn main(args: EnergyArgs) -> CmdResult {
    let out = args.io.output(&["energy.svg", "energy_work.svg"])?;
    let steps = Steps::new(3, "reading");
    let (_, model, dt, fb) = read_force_balance(&args.io, &args.filter, &steps)?;
    let all = strokes(&fb.x_m, &fb.v_mps);
    let r = match args.stroke {
        Some(i) => all.get(i).cloned().ok_or_else(|| {
            Failure::bad_input(format!("--stroke {i}: the log has {} strokes", all.len()))
        })?,
        None => all.last().cloned().ok_or_else(|| {
            Failure::bad_input(format!(
                "{}: no stroke found (the piston must move from one reversal to the next)",
                args.io.measured.display()
            ))
        })?,
    };
    let e = stroke_energy(&fb, &r, model.piston.mass_kg);
    steps.next("plotting");
    let x = fb.x_m.get(r.clone()).unwrap_or_default();
    let kn = |f: &[f64]| kilonewtons(f, r.clone());
    let forces = [
        ("motor force", kn(&fb.motor_n)),
        ("inertia m·a", kn(&fb.inertia_filtered_n)),
        ("gas force", kn(&fb.gas_n)),
        ("friction force", kn(&fb.friction_n)),
    ];
    let path = out.path("energy.svg");
    curves(
        &path,
        "Forces along one stroke (Fig. 9)",
        "x, m",
        "force, kN",
        x,
        &forces,
    )
    .map_err(Failure::runtime)?;
    let cumulative = |f: &[f64]| -> Vec<f64> {
        (r.start..r.end)
            .map(|i| work(f, &fb.x_m, &(r.start..i + 1)))
            .collect()
    };
    let works = [
        ("motor work", cumulative(&fb.motor_n)),
        (
            "inertia (kinetic energy)",
            cumulative(&fb.inertia_filtered_n),
        ),
        ("gas work on the piston", cumulative(&fb.gas_n)),
        ("friction work", cumulative(&fb.friction_n)),
    ];
    let work_path = out.path("energy_work.svg");
    curves(
        &work_path,
        "Work along one stroke",
        "x, m",
        "work, J",
        x,
        &works,
    )
    .map_err(Failure::runtime)?;
    steps.finish();
    outln!(
        "stroke {} of {}: x {:.4} → {:.4} m, {:.4} s",
        args.stroke.unwrap_or(all.len().saturating_sub(1)),
        all.len(),
        Num(e.from_m),
        Num(e.to_m),
        Num(r.len() as f64 * dt)
    )?;
    outln!(
        "motor {:.2} J (accelerating {:.2} J, decelerating {:.2} J), gas {:.2} J, friction {:.2} J",
        Num(e.motor_j),
        Num(e.motor_accelerating_j),
        Num(e.motor_decelerating_j),
        Num(e.gas_j),
        Num(e.friction_j)
    )?;
    outln!(
        "inertia: peak kinetic energy {:.2} J, net over the stroke {:.3} J; balance {:.3} J",
        Num(e.peak_kinetic_j),
        Num(e.inertia_j),
        Num(e.balance_j)
    )?;
    let shown = [
        out.final_path("energy.svg"),
        out.final_path("energy_work.svg"),
    ];
    out.commit()?;
    outln!("wrote {} and {}", shown[0].display(), shown[1].display())?;
    Ok(())
}
