//! Plots as SVG files (plotters' SVG backend: no fonts or system libraries needed).
//!
//! One look for every plot the tools write: the Okabe–Ito palette (told apart with the
//! common colour-vision deficiencies), a reference or model drawn dashed over the measured
//! solid line, the legend beside the data instead of on it, integer ticks for counts, and
//! the same units everywhere (`docs/fpc-sim.md`, "Plots"): s, mm, m/s, N, kPa, cm³, J.
//!
//! Scales tell the truth by default where a panel asks ([`Axes`]): a robust y range (the
//! central 98 % of the samples; the few beyond drawn at the edge as triangles and counted in
//! the legend), a floor on the y range relative to the values (a spread of 0.3 % is not
//! drawn as a zig-zag across the panel), markers on sparse points (a sweep's runs), and the
//! limit a quantity must keep drawn as a line.

use std::path::Path;

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;

/// How a series is drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Stroke {
    /// A solid line: what was measured or computed.
    #[default]
    Solid,
    /// A dashed line: a reference, a model, a prediction drawn over the measured line.
    Dashed,
    /// A thin, pale line: a raw, noisy trace behind the others.
    Faint,
}

/// One named series of (x, y) points.
#[derive(Clone, Copy)]
pub struct Series<'a> {
    /// Legend label.
    pub label: &'a str,
    /// x values.
    pub x: &'a [f64],
    /// y values (same length as x).
    pub y: &'a [f64],
    /// How it is drawn.
    pub stroke: Stroke,
    /// Its colour, as an index into the palette: the same quantity keeps its colour across
    /// the panels of a figure (`None`: by its place in the panel).
    pub colour: Option<usize>,
}

impl<'a> Series<'a> {
    /// A solid series.
    pub fn new(label: &'a str, x: &'a [f64], y: &'a [f64]) -> Self {
        Self {
            label,
            x,
            y,
            stroke: Stroke::Solid,
            colour: None,
        }
    }

    /// The same series in the palette's colour `index`.
    pub fn colour(self, index: usize) -> Self {
        Self {
            colour: Some(index),
            ..self
        }
    }

    /// The same series drawn dashed (a reference or a model).
    pub fn dashed(self) -> Self {
        Self {
            stroke: Stroke::Dashed,
            ..self
        }
    }

    /// The same series drawn thin and pale (a raw trace).
    pub fn faint(self) -> Self {
        Self {
            stroke: Stroke::Faint,
            ..self
        }
    }
}

/// Axis choices beyond the data's own range.
#[derive(Clone, Copy, Debug, Default)]
pub struct Axes {
    /// The y range to show (the data outside it is clipped), instead of the data's.
    pub y_range: Option<(f64, f64)>,
    /// The x range to show (a figure's panels share the first one given), instead of the
    /// data's.
    pub x_range: Option<(f64, f64)>,
    /// x counts something (cycles, runs): ticks at whole numbers only.
    pub integer_x: bool,
    /// y counts something: ticks at whole numbers only.
    pub integer_y: bool,
    /// The y range from the central 98 % of the samples (1st to 99th percentile), so a
    /// spike does not flatten the rest; samples beyond are drawn at the edge as triangles
    /// and counted in the legend.
    pub robust_y: bool,
    /// The y range spans at least this share of the largest |y| (a floor relative to the
    /// value: sweep figures that differ in their fourth digit stay flat).
    pub min_span_of_value: Option<f64>,
    /// Every point drawn as a marker too (sparse points: a sweep's runs).
    pub markers: bool,
    /// A limit drawn as a vertical line at this x, with its label.
    pub x_limit: Option<(f64, &'static str)>,
}

/// One chart of a figure: its y axis and its series, over the figure's shared x axis.
pub struct Panel<'a> {
    /// The y axis' label with its unit.
    pub y_label: &'a str,
    /// The series drawn.
    pub series: Vec<Series<'a>>,
    /// Axis choices.
    pub axes: Axes,
}

/// Draws named curves over one shared x axis as solid lines into an SVG at `path`.
pub fn curves(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    x: &[f64],
    curves: &[(&str, Vec<f64>)],
) -> Result<(), String> {
    let series: Vec<Series> = curves
        .iter()
        .map(|(label, y)| Series::new(label, x, y))
        .collect();
    lines(path, title, x_label, y_label, &series)
}

/// Draws `series` into an SVG at `path`, axes fitted to the data.
pub fn lines(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series<'_>],
) -> Result<(), String> {
    lines_with(path, title, x_label, y_label, series, Axes::default())
}

/// Draws `series` into an SVG at `path` with the axis choices `axes`.
pub fn lines_with(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series<'_>],
    axes: Axes,
) -> Result<(), String> {
    let panel = Panel {
        y_label,
        series: series.to_vec(),
        axes,
    };
    panels(path, title, x_label, &[panel])
}

/// Okabe & Ito's palette (blue, vermillion, bluish green, reddish purple, orange, sky blue,
/// black): distinct in print and for the common colour-vision deficiencies.
const PALETTE: [RGBColor; 7] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(0, 0, 0),
];

/// At most this many points per series: enough for the eye, small files.
const MAX_POINTS: usize = 4000;

/// Width of the legend column beside each panel, px.
fn legend_width(panels: &[Panel<'_>]) -> u32 {
    let longest = panels
        .iter()
        .flat_map(|p| p.series.iter().map(|s| s.label.chars().count()))
        .max()
        .unwrap_or(0);
    (56 + 8 * longest as u32).clamp(120, 320)
}

/// The range of the finite values `pick` yields, padded (by half a unit on a count axis).
fn range(values: impl Iterator<Item = f64>, integer: bool) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if integer {
        return (lo.floor() - 0.5, hi.ceil() + 0.5);
    }
    if hi > lo {
        let pad = 0.05 * (hi - lo);
        (lo - pad, hi + pad)
    } else {
        (lo - 1.0, lo + 1.0)
    }
}

/// The range of the central 98 % of the finite values (1st to 99th percentile), padded;
/// `None` when it is the whole range anyway.
fn robust_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let mut v: Vec<f64> = values.filter(|v| v.is_finite()).collect();
    if v.len() < 100 {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v.get(((v.len() - 1) as f64 * q).round() as usize).copied();
    let (lo, hi) = (at(0.01)?, at(0.99)?);
    let (min, max) = (v.first().copied()?, v.last().copied()?);
    if hi <= lo {
        return None;
    }
    let pad = 0.1 * (hi - lo);
    let (lo, hi) = ((lo - pad).max(min), (hi + pad).min(max));
    (lo > min || hi < max).then_some((lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo)))
}

/// Decimals that show `v` to four significant digits.
fn decimals_for(v: f64) -> usize {
    if v == 0.0 || !v.is_finite() {
        return 0;
    }
    (3 - v.abs().log10().floor() as i32).clamp(0, 12) as usize
}

/// `(lo, hi)` widened about its middle to span at least `share` of the largest |value|.
fn floored(range: (f64, f64), share: f64) -> (f64, f64) {
    let (lo, hi) = range;
    let biggest = lo.abs().max(hi.abs());
    let want = share * biggest;
    if hi - lo >= want || !want.is_finite() || want <= 0.0 {
        return range;
    }
    let mid = 0.5 * (lo + hi);
    (mid - 0.5 * want, mid + 0.5 * want)
}

/// Tick labels: whole numbers only on a count axis, else as many decimals as an axis of
/// `span` needs (every label of an axis with the same number of them).
fn tick(integer: bool, span: f64) -> impl Fn(&f64) -> String {
    let decimals = if span > 0.0 && span.is_finite() {
        (1.0 - span.log10().floor()).clamp(0.0, 9.0) as usize
    } else {
        0
    };
    move |v: &f64| {
        if !integer {
            format!("{v:.decimals$}")
        } else if (v - v.round()).abs() < 1e-9 {
            format!("{:.0}", v)
        } else {
            String::new()
        }
    }
}

/// Draws `panels` stacked over one shared x axis into an SVG at `path`, each with its legend
/// on its right.
pub fn panels(path: &Path, title: &str, x_label: &str, panels: &[Panel<'_>]) -> Result<(), String> {
    let height = 100 + if panels.len() > 1 { 400 } else { 500 } * panels.len().max(1) as u32;
    let legend = legend_width(panels);
    let root = SVGBackend::new(path, (900 + legend, height)).into_drawing_area();
    let draw = || -> Result<(), Box<dyn std::error::Error + '_>> {
        root.fill(&WHITE)?;
        let root = root.titled(title, ("sans-serif", 22))?;
        let rows = root.split_evenly((panels.len().max(1), 1));
        let integer_x = panels.iter().any(|p| p.axes.integer_x);
        let (x0, x1) = shared_x_range(panels, integer_x);
        for (row, panel) in rows.iter().zip(panels) {
            let (chart_area, legend_area) = row.split_horizontally(row.dim_in_pixel().0 - legend);
            let ys = || panel.series.iter().flat_map(|s| s.y.iter().copied());
            let (y0, y1) = y_range(panel);
            let mut chart = ChartBuilder::on(&chart_area)
                .margin(12)
                .x_label_area_size(45)
                .y_label_area_size(75)
                .build_cartesian_2d(x0..x1, y0..y1)?;
            let x_ticks = tick_count(integer_x, x1 - x0);
            let y_ticks = tick_count(panel.axes.integer_y, y1 - y0);
            chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc(panel.y_label)
                .x_labels(x_ticks)
                .y_labels(y_ticks)
                .x_label_formatter(&tick(integer_x, x1 - x0))
                .y_label_formatter(&tick(panel.axes.integer_y, y1 - y0))
                .light_line_style(WHITE.mix(0.0))
                .draw()?;
            for (i, s) in panel.series.iter().enumerate() {
                let color = PALETTE[s.colour.unwrap_or(i) % PALETTE.len()];
                let stride = (s.x.len() / MAX_POINTS).max(1);
                let points: Vec<(f64, f64)> =
                    s.x.iter()
                        .copied()
                        .zip(s.y.iter().copied())
                        .step_by(stride)
                        .filter(|(x, _)| (x0..=x1).contains(x))
                        .map(|(x, y)| (x, y.clamp(y0, y1)))
                        .collect();
                if panel.axes.markers {
                    chart.draw_series(points.iter().map(|&p| Circle::new(p, 4, color.filled())))?;
                }
                if panel.axes.robust_y {
                    // The samples beyond the axis, at its edge: ▲ above, ▼ below.
                    let beyond = s.x.iter().zip(s.y).filter(|(_, y)| **y > y1 || **y < y0);
                    chart.draw_series(beyond.step_by(stride).map(|(&x, &y)| {
                        let up = y > y1;
                        let (edge, dy) = if up { (y1, 1) } else { (y0, -1) };
                        TriangleMarker::new((x, edge), 5 * dy, color.filled())
                    }))?;
                }
                match s.stroke {
                    Stroke::Solid => {
                        chart.draw_series(LineSeries::new(points, color.stroke_width(2)))?;
                    }
                    Stroke::Dashed => {
                        chart.draw_series(DashedLineSeries::new(
                            points,
                            8,
                            5,
                            color.stroke_width(2),
                        ))?;
                    }
                    Stroke::Faint => {
                        chart.draw_series(LineSeries::new(points, color.mix(0.45)))?;
                    }
                }
            }
            if let Some((x, label)) = panel.axes.x_limit {
                if (x0..=x1).contains(&x) {
                    chart.draw_series(DashedLineSeries::new(
                        [(x, y0), (x, y1)],
                        6,
                        4,
                        BLACK.stroke_width(2),
                    ))?;
                    chart.draw_series(std::iter::once(Text::new(
                        label.to_string(),
                        (x, y1),
                        ("sans-serif", 14).into_font().color(&BLACK),
                    )))?;
                }
            }
            draw_legend(&legend_area, &panel.series)?;
            if panel.axes.robust_y {
                let beyond: Vec<f64> = ys().filter(|y| *y > y1 || *y < y0).collect();
                if !beyond.is_empty() {
                    let far = beyond
                        .iter()
                        .fold(0.0f64, |m, y| if y.abs() > m.abs() { *y } else { m });
                    let y = 30 + 22 * panel.series.len() as i32 + 10;
                    legend_area.draw(&Text::new(
                        format!("▲▼ {} samples beyond", beyond.len()),
                        (4, y),
                        ("sans-serif", 13).into_font().color(&BLACK),
                    ))?;
                    legend_area.draw(&Text::new(
                        format!("the axis (farthest {far:.0$})", decimals_for(far)),
                        (4, y + 16),
                        ("sans-serif", 13).into_font().color(&BLACK),
                    ))?;
                }
            }
        }
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| format!("cannot draw {}: {e}", path.display()))
}

/// The x range the stacked `panels` share: an explicit one wins; otherwise the data's, with
/// any limit drawn as a line inside it, however far from the data (whole numbers when
/// `integer_x`).
fn shared_x_range(panels: &[Panel<'_>], integer_x: bool) -> (f64, f64) {
    panels
        .iter()
        .find_map(|p| p.axes.x_range)
        .unwrap_or_else(|| {
            let limits = panels.iter().filter_map(|p| p.axes.x_limit.map(|l| l.0));
            range(
                panels
                    .iter()
                    .flat_map(|p| p.series.iter().flat_map(|s| s.x.iter().copied()))
                    .chain(limits),
                integer_x,
            )
        })
}

/// A panel's y range: an explicit one wins; otherwise its data's (robust when asked),
/// floored to the share of the value asked for.
fn y_range(panel: &Panel<'_>) -> (f64, f64) {
    let ys = || panel.series.iter().flat_map(|s| s.y.iter().copied());
    panel.axes.y_range.unwrap_or_else(|| {
        let full = range(ys(), panel.axes.integer_y);
        let chosen = if panel.axes.robust_y {
            robust_range(ys()).unwrap_or(full)
        } else {
            full
        };
        match panel.axes.min_span_of_value {
            Some(share) => floored(chosen, share),
            None => chosen,
        }
    })
}

/// Ticks on an axis spanning `span`: one per whole number (2 to 12) when `integer`, else 10.
fn tick_count(integer: bool, span: f64) -> usize {
    if integer {
        (span as usize + 1).clamp(2, 12)
    } else {
        10
    }
}

/// The legend of one panel, in its own column: a sample of each series' stroke and its label.
fn draw_legend<'b>(
    area: &DrawingArea<SVGBackend<'b>, Shift>,
    series: &[Series<'_>],
) -> Result<(), Box<dyn std::error::Error + 'b>> {
    for (i, s) in series.iter().enumerate() {
        let color = PALETTE[s.colour.unwrap_or(i) % PALETTE.len()];
        let y = 30 + 22 * i as i32;
        let sample = vec![(4, y), (34, y)];
        match s.stroke {
            Stroke::Solid => area.draw(&PathElement::new(sample, color.stroke_width(2)))?,
            Stroke::Dashed => {
                area.draw(&DashedPathElement::new(sample, 8, 5, color.stroke_width(2)))?
            }
            Stroke::Faint => area.draw(&PathElement::new(sample, color.mix(0.45)))?,
        }
        area.draw(&Text::new(
            s.label.to_string(),
            (40, y - 7),
            ("sans-serif", 14).into_font().color(&BLACK),
        ))?;
    }
    Ok(())
}
