//! `fpc-sim pv` (the paper's Fig. 3): the p–V diagram of both chambers from the logged
//! position and chamber pressures, with the model's piston area and dead lengths:
//!
//! `V_a = A_eff·(x + dead_a)`, `V_b = A_eff·(travel − x + dead_b)`.
//!
//! Prints each chamber's volume and pressure ranges, the pressure ratio reached and the
//! `∮p dV` work over the log. [`plot_pv`] is also what `fpc-sim run` can call for its plot.

use std::path::Path;

use clap::Args;
use serde::Serialize;

use crate::cli::analysis::{column, read_log, read_model, LogToolArgs, Steps};
use crate::console::Num;
use crate::failure::{CmdResult, Failure};
use crate::outln;
use crate::plant::model::MachineModel;
use crate::plot::{lines, Series};
use crate::runlog::RunLog;

/// p–V diagram of both chambers (Fig. 3).
#[derive(Args, Debug)]
pub struct PvArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub io: LogToolArgs,
}

/// Figures of one chamber.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Chamber {
    /// Smallest volume, m³.
    pub v_min_m3: f64,
    /// Largest volume, m³.
    pub v_max_m3: f64,
    /// Lowest pressure, Pa.
    pub p_min_pa: f64,
    /// Highest pressure, Pa.
    pub p_max_pa: f64,
    /// `∫p dV` over the log, J (negative: work done on the gas).
    pub p_dv_j: f64,
}

/// Both chambers' volumes, m³, one per sample.
pub fn volumes(x_m: &[f64], model: &MachineModel) -> (Vec<f64>, Vec<f64>) {
    let a = model.piston_area_m2();
    let p = &model.piston;
    let va = x_m.iter().map(|x| a * (x + p.dead_length_a_m)).collect();
    let vb = x_m
        .iter()
        .map(|x| a * (p.travel_m - x + p.dead_length_b_m))
        .collect();
    (va, vb)
}

fn chamber(v: &[f64], p: &[f64]) -> Chamber {
    let range = |x: &[f64]| {
        x.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            })
    };
    let (v_min_m3, v_max_m3) = range(v);
    let (p_min_pa, p_max_pa) = range(p);
    let p_dv_j = p
        .windows(2)
        .zip(v.windows(2))
        .map(|(p, v)| 0.5 * (p[0] + p[1]) * (v[1] - v[0]))
        .sum();
    Chamber {
        v_min_m3,
        v_max_m3,
        p_min_pa,
        p_max_pa,
        p_dv_j,
    }
}

/// Draws the p–V diagram of `log` into `path`; returns both chambers' figures.
pub fn plot_pv(
    path: &Path,
    log: &RunLog,
    model: &MachineModel,
) -> Result<(Chamber, Chamber), Failure> {
    let x = column(log, "x_m", "x_m")?;
    let pa = column(log, "p_a_pa", "p_a_pa")?;
    let pb = column(log, "p_b_pa", "p_b_pa")?;
    let (va, vb) = volumes(x, model);
    let cm3 = |v: &[f64]| v.iter().map(|v| v * 1e6).collect::<Vec<f64>>();
    let kpa = |p: &[f64]| p.iter().map(|p| p * 1e-3).collect::<Vec<f64>>();
    let (la, lb, ma, mb) = (cm3(&va), cm3(&vb), kpa(pa), kpa(pb));
    lines(
        path,
        "p-V diagram of both chambers (Fig. 3)",
        "V, cm³",
        "p, kPa",
        &[
            Series::new("chamber A", &la, &ma),
            Series::new("chamber B", &lb, &mb).dashed(),
        ],
    )
    .map_err(Failure::runtime)?;
    Ok((chamber(&va, pa), chamber(&vb, pb)))
}

/// Runs `fpc-sim pv`.
pub fn main(args: PvArgs) -> CmdResult {
    let out = args.io.output(&["pv.svg"])?;
    let steps = Steps::new(2, "reading");
    let log = read_log(&args.io.measured)?;
    let model = read_model(args.io.model.as_deref())?;
    steps.next("plotting");
    let path = out.path("pv.svg");
    let (a, b) = plot_pv(&path, &log, &model)?;
    steps.finish();
    for (name, c) in [("A", &a), ("B", &b)] {
        outln!(
            "chamber {name}: V {:.4}–{:.4} L (ratio {:.2}), p {:.4}–{:.4} MPa (ratio {:.2}), ∮p dV {:.2} J",
            Num(c.v_min_m3 * 1e3),
            Num(c.v_max_m3 * 1e3),
            Num(c.v_max_m3 / c.v_min_m3),
            Num(c.p_min_pa * 1e-6),
            Num(c.p_max_pa * 1e-6),
            Num(c.p_max_pa / c.p_min_pa),
            Num(c.p_dv_j)
        )?;
    }
    let shown = out.final_path("pv.svg");
    out.commit()?;
    outln!("wrote {}", shown.display())?;
    Ok(())
}
