//! `fpc-sim energy` (the paper's Fig. 9): where the motor's work goes along one stroke —
//! into the gas, into friction, and into the piston's inertia (stored while accelerating,
//! given back while decelerating). The works and their balance are
//! [`crate::balance::stroke_energy`]'s, of the force balance `fpc-sim forces` plots.

use clap::Args;

use serde::Serialize;

use crate::balance::{stroke_energy, work, StrokeEnergy};
use crate::cli::analysis::{
    finish, in_window, read_force_balance, whole_strokes, LogToolArgs, Steps, ZeroPhaseArgs,
};
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
    /// Which stroke, counted from 0 (default: the last whole one, away from the log's ends).
    #[arg(long)]
    pub stroke: Option<usize>,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub filter: ZeroPhaseArgs,
}

/// Runs `fpc-sim energy`.
pub fn main(args: EnergyArgs) -> CmdResult {
    let out = args
        .io
        .output("energy", &["energy.svg", "energy_work.svg", "energy.json"])?;
    let steps = Steps::new(3, "reading");
    let (_, model, dt, fb) = read_force_balance(&args.io, &args.filter, &steps)?;
    let all = strokes(&fb.x_m, &fb.v_mps);
    // By default the last whole stroke: one that runs into the log's end (or starts at its
    // beginning) shows the filter's edge, not the machine.
    let whole = whole_strokes(&all, fb.x_m.len(), dt);
    let (index, r) = match args.stroke {
        Some(i) => (
            i,
            all.get(i).cloned().ok_or_else(|| {
                Failure::bad_input(format!("--stroke {i}: the log has {} strokes", all.len()))
            })?,
        ),
        None => whole
            .last()
            .and_then(|w| all.iter().position(|s| s == w).map(|i| (i, w.clone())))
            .ok_or_else(|| {
                Failure::bad_input(format!(
                    "{}: no whole stroke found (the piston must move from one reversal to \
                     the next, 20 ms or more from the log's ends); the log has {} strokes \
                     touching its ends: name one with --stroke to plot it anyway",
                    args.io.measured.display(),
                    all.len()
                ))
            })?,
    };
    let e = stroke_energy(&fb, &r, model.piston.mass_kg);
    steps.next("plotting");
    let x: Vec<f64> = in_window(&fb.x_m, r.clone())
        .iter()
        .map(|x| x * 1e3)
        .collect();
    let n = |f: &[f64]| in_window(f, r.clone());
    let forces = [
        ("motor force", n(&fb.motor_n)),
        ("inertia m·a", n(&fb.inertia_filtered_n)),
        ("gas force", n(&fb.gas_n)),
        ("friction force", n(&fb.friction_n)),
        ("cogging force", n(&fb.cogging_n)),
    ];
    let path = out.path("energy.svg");
    curves(
        &path,
        "Forces along one stroke (Fig. 9)",
        "x, mm",
        "force, N",
        &x,
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
        ("cogging work on the piston", cumulative(&fb.cogging_n)),
    ];
    let work_path = out.path("energy_work.svg");
    curves(
        &work_path,
        "Work along one stroke",
        "x, mm",
        "work, J",
        &x,
        &works,
    )
    .map_err(Failure::runtime)?;
    steps.finish();
    let figures = EnergyFigures {
        stroke: index,
        strokes: all.len(),
        duration_s: r.len() as f64 * dt,
        energy: e,
    };
    let plots = ["energy.svg", "energy_work.svg"];
    finish(&args.io, "energy", out, &figures, &plots, || {
        let e = &figures.energy;
        outln!(
            "stroke {} of {}: x {:.1} → {:.1} mm, {:.4} s",
            figures.stroke,
            figures.strokes,
            Num(e.from_m * 1e3),
            Num(e.to_m * 1e3),
            Num(figures.duration_s)
        )?;
        outln!(
            "motor {:.2} J (accelerating {:.2} J, decelerating {:.2} J), gas {:.2} J, cogging {:.2} J, friction {:.2} J",
            Num(e.motor_j),
            Num(e.motor_accelerating_j),
            Num(e.motor_decelerating_j),
            Num(e.gas_j),
            Num(e.cogging_j),
            Num(e.friction_j)
        )?;
        outln!(
            "inertia: peak kinetic energy {:.2} J, net over the stroke {:.3} J; balance {:.3} J",
            Num(e.peak_kinetic_j),
            Num(e.inertia_j),
            Num(e.balance_j)
        )
    })
}

/// What `fpc-sim energy` reports (printed, `--json`, and `energy.json`): the works on the
/// piston along one stroke (gas: the work the gas does on the piston, negative while
/// compressing).
#[derive(Debug, Serialize)]
pub struct EnergyFigures {
    /// Which stroke (0 = the first).
    pub stroke: usize,
    /// Strokes in the log.
    pub strokes: usize,
    /// The stroke's duration, s.
    pub duration_s: f64,
    /// Its works, J.
    #[serde(flatten)]
    pub energy: StrokeEnergy,
}
