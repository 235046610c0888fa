//! The plots a person looks at after a sweep, drawn from its table: indicated work per cycle
//! and the discharge-opening pressure error against the pressure ratio (one curve per peak
//! speed and volume-ratio mode, the mean over the other axes), and the histogram of the
//! minimum head clearance.

use std::collections::BTreeMap;
use std::path::Path;

use super::Table;
use crate::plant::model::MachineModel;
use crate::plot::{lines_with, Axes, Series};

/// The plot files [`plots`] writes.
pub const PLOTS: [&str; 5] = [
    "work.svg",
    "opening_error.svg",
    "clearance.svg",
    "force_difference.svg",
    "overshoot.svg",
];

/// The y range of a figure spans at least this share of its largest value: differences
/// smaller than that (the runs' noise) are drawn nearly flat, not as a zig-zag.
pub const MIN_SPAN_OF_VALUE: f64 = 0.1;

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

/// Column `name`'s cells as they are (`None` when the table has no such column).
fn text_column(t: &Table, name: &str) -> Option<Vec<String>> {
    let i = t.cell_index(name)?;
    Some(
        t.rows
            .iter()
            .map(|r| r.cells.get(i).cloned().unwrap_or_default())
            .collect(),
    )
}

/// Each row's curve: its controller, peak speed, volume-ratio mode and rotation, when they
/// are axes.
fn groups(t: &Table) -> Vec<String> {
    let controller = text_column(t, "controller");
    let speed = text_column(t, "speed_mps");
    let mode = text_column(t, "volume_ratio");
    let rotation = text_column(t, "rotation");
    (0..t.rows.len())
        .map(|k| {
            let mut parts = Vec::new();
            if let Some(c) = controller.as_ref().and_then(|c| c.get(k)) {
                parts.push(c.clone());
            }
            if let Some(v) = speed.as_ref().and_then(|c| c.get(k)) {
                parts.push(format!("{v} m/s"));
            }
            if let Some(m) = mode.as_ref().and_then(|c| c.get(k)) {
                parts.push(m.clone());
            }
            if let Some(r) = rotation.as_ref().and_then(|c| c.get(k)) {
                parts.push(r.clone());
            }
            if parts.is_empty() {
                "all".to_string()
            } else {
                parts.join(", ")
            }
        })
        .collect()
}

/// Mean of `y` at each x, one curve per value of `group` (printed as labels).
fn curves(
    x: &[Option<f64>],
    y: &[Option<f64>],
    group: &[String],
) -> Vec<(String, Vec<f64>, Vec<f64>)> {
    let mut acc: BTreeMap<String, BTreeMap<u64, (f64, f64, usize)>> = BTreeMap::new();
    for ((x, y), g) in x.iter().zip(y).zip(group) {
        let (Some(x), Some(y)) = (x, y) else { continue };
        let e = acc
            .entry(g.clone())
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
    let group = groups(t);
    for (file, field, title, unit, scale) in [
        (
            "work.svg",
            "indicated_work_j_per_cycle",
            "Indicated work per cycle",
            "work on the gas per cycle, J",
            1.0,
        ),
        (
            "opening_error.svg",
            "discharge_open_pressure_error",
            "Chamber pressure at discharge opening vs line",
            "|p − p_d| / p_d, %",
            100.0,
        ),
        (
            "force_difference.svg",
            "dead_point_force_diff_n",
            "Section force difference at the dead points (±5 ms)",
            "|F_master − F_slave|, N",
            1.0,
        ),
        (
            "overshoot.svg",
            "overshoot_m",
            "Overshoot past the dead points (largest of the last 5 cycles)",
            "overshoot, mm",
            1e3,
        ),
    ] {
        let y: Vec<Option<f64>> = column(t, field)
            .unwrap_or_else(|| none.clone())
            .into_iter()
            .map(|v| v.map(|v| v * scale))
            .collect();
        let c = curves(&pr, &y, &group);
        let series: Vec<Series> = c
            .iter()
            .map(|(label, x, y)| Series::new(label, x, y))
            .collect();
        // Each run's mean a marker; a spread under a tenth of the value stays flat.
        let axes = Axes {
            markers: true,
            min_span_of_value: Some(MIN_SPAN_OF_VALUE),
            ..Axes::default()
        };
        lines_with(
            &dir.join(file),
            title,
            "pressure ratio",
            unit,
            &series,
            axes,
        )?;
    }
    let c: Vec<f64> = column(t, "min_head_clearance_m")
        .unwrap_or_default()
        .into_iter()
        .flatten()
        .map(|m| m * 1e3)
        .collect();
    histogram(
        &dir.join("clearance.svg"),
        "Minimum head clearance over the runs",
        "clearance, mm",
        &c,
    )
}

/// Writes the histogram of `values` (40 bins over their range, drawn as steps) to `path`,
/// with the reference machine's least head clearance (0.3 mm) as a line.
pub fn histogram(path: &Path, title: &str, unit: &str, values: &[f64]) -> Result<(), String> {
    let (lo, hi) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    let (x, y) = if lo.is_finite() {
        let bins = 40usize;
        let w = ((hi - lo) / bins as f64).max(1e-6);
        let mut counts = vec![0.0; bins];
        for v in values {
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
    lines_with(
        path,
        title,
        unit,
        "runs",
        &[Series::new("runs", &x, &y)],
        Axes {
            integer_y: true,
            x_limit: Some((
                MachineModel::reference().limits.min_head_clearance_m * 1e3,
                " the least clearance allowed",
            )),
            ..Axes::default()
        },
    )
}
