//! `fpc-sim pv` (the paper's Fig. 3): the p–V diagram of both chambers from the logged
//! position and chamber pressures, with the model's piston area and dead lengths:
//!
//! `V_a = A_eff·(x + dead_a)`, `V_b = A_eff·(travel − x + dead_b)`.
//!
//! Prints each chamber's volume and pressure ranges, the pressure ratio reached and the
//! indicated work per compression cycle, as `fpc-sim run` reports it: the work done *on the
//! gas* (positive for a compressor), over complete cycles from one dead point A to the next
//! (homing and the last, unfinished cycle left out), the mean of the last five.

use std::path::Path;

use clap::Args;
use serde::Serialize;

use crate::cli::analysis::{column, finish, read_log_needing, read_model, LogToolArgs, Steps};
use crate::console::Num;
use crate::failure::{CmdResult, Failure};
use crate::outln;
use crate::plant::model::MachineModel;
use crate::plot::{lines, Series};
use crate::runlog::RunLog;
use crate::signal::strokes;

/// p–V diagram of both chambers (Fig. 3).
#[derive(Args, Debug)]
pub struct PvArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub io: LogToolArgs,
}

/// What `fpc-sim pv --json` prints.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct PvFigures {
    /// Chamber A.
    pub chamber_a: Chamber,
    /// Chamber B.
    pub chamber_b: Chamber,
    /// Complete compression cycles found (dead point A to dead point A).
    pub cycles: usize,
    /// Work done on the gas per cycle, both chambers, the mean of the last five complete
    /// cycles, J (positive: work done on the gas; `fpc-sim run`'s
    /// `indicated_work_j_per_cycle`); `null` without a complete cycle.
    pub indicated_work_j_per_cycle: Option<f64>,
}

/// Cycles averaged, as `fpc-sim run` averages them.
const LAST_CYCLES: usize = 5;

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
    /// Work done on the gas in this chamber per cycle, the mean of the last five complete
    /// cycles, J (positive: work done on the gas); `null` without a complete cycle.
    pub work_on_gas_j_per_cycle: Option<f64>,
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

/// The sample indices where a compression cycle ends: each reversal at dead point A (the end
/// of a stroke toward head A), found on the position alone so that any run log will do.
pub fn cycle_ends(x_m: &[f64], dt_s: f64) -> Vec<usize> {
    // Velocity by a central difference over ±0.5 ms: smooth enough that encoder noise makes
    // no reversal, short against a stroke.
    let w = ((0.5e-3 / dt_s).round() as usize).max(1);
    let v: Vec<f64> = (0..x_m.len())
        .map(|i| {
            let (lo, hi) = (
                i.saturating_sub(w),
                (i + w).min(x_m.len().saturating_sub(1)),
            );
            match (x_m.get(lo), x_m.get(hi)) {
                (Some(a), Some(b)) if hi > lo => (b - a) / ((hi - lo) as f64 * dt_s),
                _ => 0.0,
            }
        })
        .collect();
    strokes(x_m, &v)
        .into_iter()
        .filter(
            |r| match (x_m.get(r.start), x_m.get(r.end.saturating_sub(1))) {
                (Some(a), Some(b)) => b < a,
                _ => false,
            },
        )
        .map(|r| r.end.saturating_sub(1))
        .collect()
}

/// Work done on the gas between samples `from` and `to`, J: `−∫p dV` by the trapezoid rule.
fn work_on_gas(v: &[f64], p: &[f64], from: usize, to: usize) -> f64 {
    let (Some(v), Some(p)) = (v.get(from..=to), p.get(from..=to)) else {
        return 0.0;
    };
    -p.windows(2)
        .zip(v.windows(2))
        .map(|(p, v)| 0.5 * (p[0] + p[1]) * (v[1] - v[0]))
        .sum::<f64>()
}

/// The mean work on the gas per cycle over the last [`LAST_CYCLES`] complete cycles.
fn per_cycle(v: &[f64], p: &[f64], ends: &[usize]) -> Option<f64> {
    let works: Vec<f64> = ends
        .windows(2)
        .map(|e| work_on_gas(v, p, e[0], e[1]))
        .collect();
    let last = works.get(works.len().saturating_sub(LAST_CYCLES)..)?;
    (!last.is_empty()).then(|| last.iter().sum::<f64>() / last.len() as f64)
}

fn chamber(v: &[f64], p: &[f64], ends: &[usize]) -> Chamber {
    let range = |x: &[f64]| {
        x.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            })
    };
    let (v_min_m3, v_max_m3) = range(v);
    let (p_min_pa, p_max_pa) = range(p);
    Chamber {
        v_min_m3,
        v_max_m3,
        p_min_pa,
        p_max_pa,
        work_on_gas_j_per_cycle: per_cycle(v, p, ends),
    }
}

/// Draws the p–V diagram of `log` into `path`; returns its figures.
pub fn plot_pv(path: &Path, log: &RunLog, model: &MachineModel) -> Result<PvFigures, Failure> {
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
    let ends = cycle_ends(x, log.sample_time_s().unwrap_or(1.0));
    let (chamber_a, chamber_b) = (chamber(&va, pa, &ends), chamber(&vb, pb, &ends));
    let indicated_work_j_per_cycle = chamber_a
        .work_on_gas_j_per_cycle
        .zip(chamber_b.work_on_gas_j_per_cycle)
        .map(|(a, b)| a + b);
    Ok(PvFigures {
        chamber_a,
        chamber_b,
        cycles: ends.len().saturating_sub(1),
        indicated_work_j_per_cycle,
    })
}

/// Runs `fpc-sim pv`.
pub fn main(args: PvArgs) -> CmdResult {
    let out = args.io.output("pv", &["pv.svg", "pv.json"])?;
    let steps = Steps::new(2, "reading");
    let log = read_log_needing(&args.io.measured, &["x_m", "p_a_pa", "p_b_pa"])?;
    let model = read_model(args.io.model.as_deref())?;
    steps.next("plotting");
    let path = out.path("pv.svg");
    let figures = plot_pv(&path, &log, &model)?;
    steps.finish();
    let work = |w: Option<f64>| {
        w.map_or_else(
            || "no complete cycle".into(),
            |w| format!("{:.2} J", Num(w)),
        )
    };
    finish(&args.io, "pv", out, &figures, &["pv.svg"], || {
        for (name, c) in [("A", &figures.chamber_a), ("B", &figures.chamber_b)] {
            outln!(
                "chamber {name}: V {:.1}–{:.1} cm³ (ratio {:.2}), p {:.1}–{:.1} kPa (ratio {:.2}), work on the gas {} per cycle",
                Num(c.v_min_m3 * 1e6),
                Num(c.v_max_m3 * 1e6),
                Num(c.v_max_m3 / c.v_min_m3),
                Num(c.p_min_pa * 1e-3),
                Num(c.p_max_pa * 1e-3),
                Num(c.p_max_pa / c.p_min_pa),
                work(c.work_on_gas_j_per_cycle)
            )?;
        }
        outln!(
            "indicated work per cycle, both chambers: {} (work done on the gas, mean of the last {} of {} complete cycles, as `fpc-sim run` reports it)",
            work(figures.indicated_work_j_per_cycle),
            figures.cycles.min(LAST_CYCLES),
            figures.cycles
        )
    })
}
