//! The plots a person looks at after a sweep, drawn from its table: indicated work per cycle
//! and the discharge-opening pressure error against the pressure ratio (one curve per peak
//! speed, the mean over the other axes), and the histogram of the minimum head clearance.

use std::collections::BTreeMap;
use std::path::Path;

use super::Table;
use crate::plot::{lines, Series};

/// The plot files [`plots`] writes.
pub const PLOTS: [&str; 3] = ["work.svg", "opening_error.svg", "clearance.svg"];

/// Column `name`'s values as numbers (`None` where empty or not a number).
fn column(t: &Table, name: &str) -> Option<Vec<Option<f64>>> {
    let i = t.cell_index(name)?;
    Some(
        t.rows
            .iter()
            .map(|r| r.cells.get(i).and_then(|c| c.parse::<f64>().ok()))
            .collect(),
    )
}

/// Mean of `y` at each x, one curve per value of `group` (keys printed as labels).
fn curves(
    x: &[Option<f64>],
    y: &[Option<f64>],
    group: &[Option<f64>],
) -> Vec<(String, Vec<f64>, Vec<f64>)> {
    let mut acc: BTreeMap<String, BTreeMap<u64, (f64, f64, usize)>> = BTreeMap::new();
    for ((x, y), g) in x.iter().zip(y).zip(group) {
        let (Some(x), Some(y)) = (x, y) else { continue };
        let label = g.map_or_else(|| "all".to_string(), |g| format!("{g} m/s"));
        let e = acc
            .entry(label)
            .or_default()
            .entry(x.to_bits())
            .or_insert((*x, 0.0, 0));
        e.1 += y;
        e.2 += 1;
    }
    acc.into_iter()
        .map(|(label, points)| {
            let mut p: Vec<(f64, f64)> = points
                .values()
                .map(|(x, s, n)| (*x, s / *n as f64))
                .collect();
            p.sort_by(|a, b| a.0.total_cmp(&b.0));
            (
                label,
                p.iter().map(|q| q.0).collect(),
                p.iter().map(|q| q.1).collect(),
            )
        })
        .collect()
}

/// Writes [`PLOTS`] into `dir` from the table `t`.
pub fn plots(dir: &Path, t: &Table) -> Result<(), String> {
    let n = t.rows.len();
    let none = vec![None; n];
    let pr = column(t, "pressure_ratio")
        .or_else(|| column(t, "pressure_ratio_target"))
        .unwrap_or_else(|| none.clone());
    let speed = column(t, "speed_mps").unwrap_or_else(|| none.clone());
    for (file, field, title, unit, scale) in [
        (
            "work.svg",
            "indicated_work_j_per_cycle",
            "Indicated work per cycle",
            "J",
            1.0,
        ),
        (
            "opening_error.svg",
            "discharge_open_pressure_error",
            "Chamber pressure at discharge opening vs line",
            "|p − p_d| / p_d, %",
            100.0,
        ),
    ] {
        let y: Vec<Option<f64>> = column(t, field)
            .unwrap_or_else(|| none.clone())
            .into_iter()
            .map(|v| v.map(|v| v * scale))
            .collect();
        let c = curves(&pr, &y, &speed);
        let series: Vec<Series> = c
            .iter()
            .map(|(label, x, y)| Series { label, x, y })
            .collect();
        lines(&dir.join(file), title, "pressure ratio", unit, &series)?;
    }
    // Histogram of the minimum head clearance, mm, in 40 bins over its range.
    let c: Vec<f64> = column(t, "min_head_clearance_m")
        .unwrap_or_default()
        .into_iter()
        .flatten()
        .map(|m| m * 1e3)
        .collect();
    let (lo, hi) = c
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    let (x, y) = if lo.is_finite() {
        let bins = 40usize;
        let w = ((hi - lo) / bins as f64).max(1e-6);
        let mut counts = vec![0.0; bins];
        for v in &c {
            let i = (((v - lo) / w) as usize).min(bins - 1);
            if let Some(k) = counts.get_mut(i) {
                *k += 1.0;
            }
        }
        // Drawn as steps: each bin's count from its left edge to its right.
        let mut x = Vec::with_capacity(2 * bins);
        let mut y = Vec::with_capacity(2 * bins);
        for (i, k) in counts.iter().enumerate() {
            x.extend([lo + i as f64 * w, lo + (i + 1) as f64 * w]);
            y.extend([*k, *k]);
        }
        (x, y)
    } else {
        (Vec::new(), Vec::new())
    };
    lines(
        &dir.join("clearance.svg"),
        "Minimum head clearance over the runs",
        "clearance, mm",
        "runs",
        &[Series {
            label: "runs",
            x: &x,
            y: &y,
        }],
    )
}
