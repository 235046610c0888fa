//! The paper's figures redrawn from the simulator (`fpc-sim paper`): Figs. 3–9 of Gusev et
//! al. on their own quantities and units, the published rig's controller ([`crate::published::Rig`])
//! and ours on the same plant side by side, the paper's stated values drawn as dashed
//! reference lines; and the electrical cost of both at the Fig. 3 points.
//!
//! The runs (`docs/paper.md` says what each figure shows and why it agrees or not):
//! - the four Fig. 3 points (PR 3.1/3.7/4.3/5.1 at 2.3/2.8/3.5/4.1 m/s), each controller;
//! - the published drives at PR 5.1's speed with both chambers open to suction ("no
//!   compression", Figs. 5 and 6);
//! - the published drives on the paper rig's encoders (`docs/studies/paper-rig.toml`) with and
//!   without compression (Fig. 6), and the firmware's encoder-map routine on the same machine
//!   (its map applied to the logged difference by the firmware's own law).
//!
//! Every figure here is measured on a log; the inputs the model takes from the paper (the
//! 0.75 ms slave lag, the 8.5 ms reading) are printed as "read back" where they show.

use std::path::Path;

use fpc::control::calibration::EncoderMap;
use serde::Serialize;

use crate::balance::{force_balance, read_measured, stroke_energy};
use crate::plant::model::MachineModel;
use crate::plot::{panels, Axes, Panel, Series};
use crate::run::{run, speed_for_pressure_ratio, Controller, HostAction, RunOptions, RunOutcome};
use crate::runlog::RunLog;
use crate::signal::{
    backward_difference, butterworth_lowpass, central_difference, filtfilt, firmware_derivatives,
    second_difference, strokes, xcorr_lag, SgSettings,
};

/// The pressure ratios of the paper's Fig. 3 (each run at its figure's speed).
pub const FIG3_RATIOS: [f64; 4] = [3.1, 3.7, 4.3, 5.1];

/// The reference machine with the published rig's encoders (`docs/studies/paper-rig.toml`).
pub const PAPER_RIG_TOML: &str = include_str!("../../docs/studies/paper-rig.toml");

/// The SVG files [`write_figures`] writes, in figure order.
pub const FIGURES: [&str; 7] = [
    "fig3-pv.svg",
    "fig4-section-forces.svg",
    "fig5-force-difference.svg",
    "fig6-encoder-difference.svg",
    "fig7-velocity.svg",
    "fig8-forces.svg",
    "fig9-motor-force.svg",
];

/// Three series of a log's samples (x, and two values at each).
type Trace = (Vec<f64>, Vec<f64>, Vec<f64>);

/// A labelled p–V loop: volumes, pressures.
type Loop = (String, Vec<f64>, Vec<f64>);

/// The runs the figures are drawn from.
pub struct PaperRuns {
    /// Ours at the Fig. 3 points, in [`FIG3_RATIOS`] order.
    pub ours: Vec<RunOutcome>,
    /// The published drives at the same points.
    pub published: Vec<RunOutcome>,
    /// The published drives at PR 5.1's speed, both chambers open to suction.
    pub published_unloaded: RunOutcome,
    /// The published drives on the paper rig's encoders, PR 5.1 / 4.1 m/s.
    pub rig: RunOutcome,
    /// The same without compression.
    pub rig_unloaded: RunOutcome,
    /// The firmware's encoder map of the paper rig.
    pub map: EncoderMap,
    /// The closed-port test (§4) to [`CLOSED_PORT_STOP_M`]: under the position loop, and its
    /// force command replayed open loop.
    pub closed_port: (RunOutcome, RunOutcome),
}

/// Where the closed-port test stops the piston, m from head A (≈ 4 bar in chamber B).
pub const CLOSED_PORT_STOP_M: f64 = 0.17;

/// Runs everything the figures need, `cycles` compression cycles a run.
pub fn paper_runs(cycles: u32, seed: u64) -> Result<PaperRuns, String> {
    let opts = |model: &MachineModel, controller, pr: f64| RunOptions {
        model: model.clone(),
        controller,
        pressure_ratio: pr,
        cycles,
        seed,
        ..RunOptions::reference()
    };
    let go = |o: RunOptions, what: String| -> Result<RunOutcome, String> {
        let out = run(&o).map_err(|e| format!("{what}: {e}"))?;
        match &out.summary.stopped_early {
            Some(why) => Err(format!("{what} stopped early: {why}")),
            None => Ok(out),
        }
    };
    let reference = MachineModel::reference();
    let rig_model = MachineModel::parse(PAPER_RIG_TOML).map_err(|e| format!("paper rig: {e}"))?;
    let mut ours = Vec::new();
    let mut published = Vec::new();
    for pr in FIG3_RATIOS {
        ours.push(go(
            opts(&reference, Controller::Ours, pr),
            format!("ours at PR {pr}"),
        )?);
        published.push(go(
            opts(&reference, Controller::Published, pr),
            format!("published at PR {pr}"),
        )?);
    }
    let unloaded = |model: &MachineModel| RunOptions {
        schedule: vec![(0, HostAction::UnloadPorts)],
        speed_mps: Some(speed_for_pressure_ratio(5.1)),
        ..opts(model, Controller::Published, 5.1)
    };
    Ok(PaperRuns {
        ours,
        published,
        published_unloaded: go(unloaded(&reference), "published, no compression".into())?,
        rig: go(
            opts(&rig_model, Controller::Published, 5.1),
            "published on the paper rig".into(),
        )?,
        rig_unloaded: go(
            unloaded(&rig_model),
            "published on the paper rig, no compression".into(),
        )?,
        map: crate::calibration::map_encoders(&rig_model, seed)
            .map_err(|e| format!("the encoder map on the paper rig: {e}"))?,
        closed_port: crate::run::closed::closed_and_open_loop(
            &opts(&reference, Controller::Published, 3.1),
            crate::run::closed::ClosedPort {
                stop_m: CLOSED_PORT_STOP_M,
                hold_s: 0.5,
            },
        )
        .map_err(|e| format!("the closed-port test: {e}"))?,
    })
}

/// One Fig. 3 point, both controllers.
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    /// Target (line) pressure ratio.
    pub pressure_ratio: f64,
    /// Peak speed, m/s.
    pub speed_mps: f64,
    /// p_max/p_min of the loops (ours, published).
    pub loop_ratio: [f64; 2],
    /// Highest chamber pressure read over the last cycles, MPa (ours, published).
    pub p_max_mpa: [f64; 2],
    /// Indicated work per cycle, J (ours, published).
    pub indicated_j: [f64; 2],
    /// Electrical input per cycle, J (ours, published).
    pub electrical_j: [f64; 2],
    /// Copper loss per cycle, J (ours, published).
    pub copper_j: [f64; 2],
    /// Bridge loss per cycle, J (ours, published).
    pub bridge_j: [f64; 2],
    /// Servo draw per cycle, J (ours, published).
    pub servo_j: [f64; 2],
    /// The fight's I²-loss per cycle, J (ours, published).
    pub fight_j: [f64; 2],
    /// Indicated work ÷ electrical input (ours, published).
    pub efficiency: [f64; 2],
    /// Motor work on the piston per cycle, J (ours, published): mean of the last 5 cycles.
    pub motor_work_j: [f64; 2],
}

/// Everything `fpc-sim paper` reports (printed, `--json`, `paper.json`).
#[derive(Clone, Debug, Serialize)]
pub struct PaperFigures {
    /// The Fig. 3 points with their electrical cost.
    pub points: Vec<Point>,
    /// Fig. 4: the published sections' largest force in the window, kN (master, slave).
    pub fig4_section_peak_kn: [f64; 2],
    /// Fig. 4: the slave's lag behind the master by the paper's FFT method, ms (an input read
    /// back).
    pub fig4_lag_ms: f64,
    /// Fig. 5: largest |F_master − F_slave| along the strokes, kN (published with and
    /// without compression, ours).
    pub fig5_peak_difference_kn: [f64; 3],
    /// Fig. 6: slave − master reading of the paper rig, RMS about its mean while moving, µm
    /// (with compression, without, after the firmware's map).
    pub fig6_rms_um: [f64; 3],
    /// Fig. 6: the largest jump of the difference between neighbouring samples, µm.
    pub fig6_step_um: f64,
    /// Fig. 6: mean difference moving toward +x minus toward −x, µm.
    pub fig6_direction_um: f64,
    /// Fig. 7: how late each velocity is behind the zero-phase one, ms (unfiltered,
    /// Savitzky–Golay, the drive's reading).
    pub fig7_lag_ms: [f64; 3],
    /// Fig. 7: RMS of each velocity's difference from the zero-phase one, m/s.
    pub fig7_rms_mps: [f64; 3],
    /// Fig. 8: largest |m·a| expected from the forces, kN; RMS of the unfiltered m·a's
    /// difference from it, kN; the same for the filtered.
    pub fig8_kn: [f64; 3],
    /// Fig. 9: the largest motor force along a stroke, kN (ours, published).
    pub fig9_motor_peak_kn: [f64; 2],
    /// Fig. 9: the motor's work accelerating and decelerating over that stroke, J
    /// (published).
    pub fig9_motor_work_j: [f64; 2],
    /// §4.3: the Savitzky–Golay window that minimises the inertia force's error against the
    /// forces, its delay (ms) and that error (N RMS); the firmware's window and its.
    pub filter_tuning: FilterTuning,
    /// §4's closed-port test: the move under the position loop against the same force
    /// command replayed open loop.
    pub closed_port: ClosedPortReplay,
}

/// The closed-port test both ways.
#[derive(Clone, Debug, Serialize)]
pub struct ClosedPortReplay {
    /// The stop the position loop moved to, m.
    pub stop_m: f64,
    /// Where the piston ended, m (closed loop, open loop).
    pub end_m: [f64; 2],
    /// Chamber B's highest pressure, bar (closed loop, open loop).
    pub peak_bar: [f64; 2],
    /// The least head clearance, mm (closed loop, open loop).
    pub min_clearance_mm: [f64; 2],
}

/// The closed-port test's figures.
fn closed_port(runs: &PaperRuns) -> Result<ClosedPortReplay, String> {
    let (closed, open) = &runs.closed_port;
    let end = |o: &RunOutcome| -> Result<f64, String> {
        col(&o.log, "x_m")?
            .last()
            .copied()
            .ok_or_else(|| "an empty closed-port log".to_string())
    };
    Ok(ClosedPortReplay {
        stop_m: CLOSED_PORT_STOP_M,
        end_m: [end(closed)?, end(open)?],
        peak_bar: [closed, open].map(|o| 1e-5 * f(o.summary.closed_port_peak_pa)),
        min_clearance_mm: [closed, open].map(|o| 1e3 * f(o.summary.min_head_clearance_m)),
    })
}

/// The §4.3 tuning: Savitzky–Golay windows compared on the inertia force.
#[derive(Clone, Debug, Serialize)]
pub struct FilterTuning {
    /// (window, delay ms, RMS error N) per window tried.
    pub rows: Vec<(usize, f64, f64)>,
    /// The window with the least RMS error.
    pub best_window: usize,
    /// The firmware's window.
    pub firmware_window: usize,
}

fn col<'a>(log: &'a RunLog, name: &str) -> Result<&'a [f64], String> {
    log.column(name)
        .ok_or_else(|| format!("the run log has no column {name}"))
}

fn f(v: Option<f64>) -> f64 {
    v.unwrap_or(f64::NAN)
}

/// Samples of the last `n_s` seconds of the strokes (before the final stop).
fn last_strokes(log: &RunLog, n: usize) -> Result<std::ops::Range<usize>, String> {
    let x = col(log, "x_m")?;
    let v = central_difference(x, log.sample_time_s().unwrap_or(50e-6));
    let s = strokes(x, &v);
    let k = s.len();
    if k < n + 1 {
        return Err(format!("{k} strokes in the log, {} needed", n + 1));
    }
    // The last stroke ends in the stop: the n before it.
    Ok(s[k - 1 - n].start..s[k - 2].end)
}

/// Writes the seven figures into `dir` and returns their figures.
pub fn write_figures(runs: &PaperRuns, dir: &Path) -> Result<PaperFigures, String> {
    let points = fig3(runs, &dir.join(FIGURES[0]))?;
    let (fig4_section_peak_kn, fig4_lag_ms) = fig4(runs, &dir.join(FIGURES[1]))?;
    let fig5_peak_difference_kn = fig5(runs, &dir.join(FIGURES[2]))?;
    let (fig6_rms_um, fig6_step_um, fig6_direction_um) = fig6(runs, &dir.join(FIGURES[3]))?;
    let (fig7_lag_ms, fig7_rms_mps) = fig7(runs, &dir.join(FIGURES[4]))?;
    let (fig8_kn, filter_tuning) = fig8(runs, &dir.join(FIGURES[5]))?;
    let (fig9_motor_peak_kn, fig9_motor_work_j) = fig9(runs, &dir.join(FIGURES[6]))?;
    Ok(PaperFigures {
        points,
        fig4_section_peak_kn,
        fig4_lag_ms,
        fig5_peak_difference_kn,
        fig6_rms_um,
        fig6_step_um,
        fig6_direction_um,
        fig7_lag_ms,
        fig7_rms_mps,
        fig8_kn,
        fig9_motor_peak_kn,
        fig9_motor_work_j,
        filter_tuning,
        closed_port: closed_port(runs)?,
    })
}

/// A horizontal dashed reference line at `y` over `x0..x1`.
fn hline(y: f64, x0: f64, x1: f64) -> (Vec<f64>, Vec<f64>) {
    (vec![x0, x1], vec![y, y])
}

/// Mean of the last 5 of `per_cycle`.
fn last5_mean(per_cycle: &[f64]) -> f64 {
    let k = per_cycle.len().min(5);
    if k == 0 {
        return f64::NAN;
    }
    per_cycle[per_cycle.len() - k..].iter().sum::<f64>() / k as f64
}

/// Fig. 3: p–V loops of chamber A at the four points, pressure as read.
fn fig3(runs: &PaperRuns, path: &Path) -> Result<Vec<Point>, String> {
    let mut points = Vec::new();
    let mut loops: [Vec<Loop>; 2] = [Vec::new(), Vec::new()];
    for (i, pr) in FIG3_RATIOS.iter().enumerate() {
        let pair = [&runs.ours[i], &runs.published[i]];
        let mut p_max = [0.0; 2];
        for (k, out) in pair.iter().enumerate() {
            let log = &out.log;
            let r = last_strokes(log, 2)?;
            let v: Vec<f64> = col(log, "vol_a_m3")?[r.clone()]
                .iter()
                .map(|v| v * 1e3)
                .collect();
            let p: Vec<f64> = col(log, "p_a_pa")?[r.clone()]
                .iter()
                .map(|p| p * 1e-6)
                .collect();
            p_max[k] = p.iter().copied().fold(f64::MIN, f64::max);
            let s = &out.summary;
            loops[k].push((
                format!(
                    "PR {pr} at {} m/s: loop {:.2}",
                    speed_for_pressure_ratio(*pr),
                    f(s.pv_pressure_ratio)
                ),
                v,
                p,
            ));
        }
        let sum = |g: &dyn Fn(&crate::run::Summary) -> Option<f64>| {
            [f(g(&pair[0].summary)), f(g(&pair[1].summary))]
        };
        points.push(Point {
            pressure_ratio: *pr,
            speed_mps: speed_for_pressure_ratio(*pr),
            loop_ratio: sum(&|s| s.pv_pressure_ratio),
            p_max_mpa: p_max,
            indicated_j: sum(&|s| s.indicated_work_j_per_cycle),
            electrical_j: sum(&|s| s.electrical_energy_j_per_cycle),
            copper_j: sum(&|s| s.copper_loss_j_per_cycle),
            bridge_j: sum(&|s| s.bridge_loss_j_per_cycle),
            servo_j: sum(&|s| s.servo_energy_j_per_cycle),
            fight_j: sum(&|s| s.fight_loss_j_per_cycle),
            efficiency: sum(&|s| s.efficiency),
            motor_work_j: [
                last5_mean(&pair[0].cycle_motor_work_j),
                last5_mean(&pair[1].cycle_motor_work_j),
            ],
        });
    }
    let (rx, ry) = hline(0.5, 0.0, 1.25);
    let mut panel_list = Vec::new();
    for (k, name) in ["ours", "published drives"].iter().enumerate() {
        let mut series: Vec<Series> = loops[k]
            .iter()
            .enumerate()
            .map(|(i, (label, v, p))| Series::new(label, v, p).colour(i))
            .collect();
        series.push(
            Series::new("Fig. 3's axis top, 0.5 MPa", &rx, &ry)
                .dashed()
                .colour(6),
        );
        panel_list.push((format!("{name}: pressure, MPa"), series));
    }
    let panels_v: Vec<Panel> = panel_list
        .iter()
        .map(|(label, series)| Panel {
            y_label: label,
            series: series.clone(),
            axes: Axes {
                y_range: Some((0.0, 0.8)),
                x_range: Some((0.0, 1.25)),
                ..Axes::default()
            },
        })
        .collect();
    panels(
        path,
        "Fig. 3: p–V loops of chamber A at the paper's four points",
        "volume, m³ ×10⁻³",
        &panels_v,
    )?;
    Ok(points)
}

/// The 25 ms window of the paper's Fig. 4, centred on the last dead point B before the stop.
fn dead_point_window(log: &RunLog, half_s: f64) -> Result<std::ops::Range<usize>, String> {
    let x = col(log, "x_m")?;
    let dt = log.sample_time_s().unwrap_or(50e-6);
    let r = last_strokes(log, 2)?;
    let (i, _) =
        x[r.clone()].iter().enumerate().fold(
            (0, f64::MIN),
            |b, (i, v)| if *v > b.1 { (i, *v) } else { b },
        );
    let centre = r.start + i;
    let h = (half_s / dt).round() as usize;
    Ok(centre.saturating_sub(h)..(centre + h).min(x.len()))
}

/// Fig. 4: master and slave forces over 25 ms at a dead point, PR 5.1 / 4.1 m/s.
fn fig4(runs: &PaperRuns, path: &Path) -> Result<([f64; 2], f64), String> {
    let mut panel_data = Vec::new();
    let mut peak = [0.0; 2];
    let mut lag_ms = f64::NAN;
    for (k, out) in [&runs.published[3], &runs.ours[3]].iter().enumerate() {
        let log = &out.log;
        let w = dead_point_window(log, 0.0125)?;
        let t = col(log, "t_s")?[w.clone()].to_vec();
        let fm: Vec<f64> = col(log, "f_master_n")?[w.clone()]
            .iter()
            .map(|v| v * 1e-3)
            .collect();
        let fs: Vec<f64> = col(log, "f_slave_n")?[w.clone()]
            .iter()
            .map(|v| v * 1e-3)
            .collect();
        if k == 0 {
            let m = |v: &[f64]| v.iter().fold(0.0f64, |a, b| a.max(b.abs()));
            peak = [m(&fm), m(&fs)];
            let dt = log.sample_time_s().unwrap_or(50e-6);
            lag_ms = xcorr_lag(&fm, &fs, dt, Some(100))?.seconds * 1e3;
        }
        panel_data.push((t, fm, fs));
    }
    // Each controller's window on its own clock, drawn from the published one's start.
    let t0 = panel_data[0].0.first().copied().unwrap_or(0.0);
    let shifted: Vec<Vec<f64>> = panel_data
        .iter()
        .map(|(t, _, _)| {
            let first = t.first().copied().unwrap_or(0.0);
            t.iter().map(|v| v - first + t0).collect()
        })
        .collect();
    let t1 = shifted[0].last().copied().unwrap_or(t0 + 0.025);
    let (b0x, b0y) = hline(0.8, t0, t1);
    let (b1x, b1y) = hline(1.6, t0, t1);
    let names = ["published drives", "ours"];
    let labels: Vec<String> = names.iter().map(|n| format!("{n}: force, kN")).collect();
    let panel_v: Vec<Panel> = panel_data
        .iter()
        .enumerate()
        .map(|(k, (_, fm, fs))| {
            let t = &shifted[k];
            let mut series = vec![
                Series::new("master force", t, fm).colour(0),
                Series::new("slave force", t, fs).colour(1),
            ];
            if k == 0 {
                series.push(
                    Series::new("Fig. 4's range, 0.8 kN", &b0x, &b0y)
                        .dashed()
                        .colour(6),
                );
                series.push(Series::new("and 1.6 kN", &b1x, &b1y).dashed().colour(6));
            }
            Panel {
                y_label: &labels[k],
                series,
                axes: Axes::default(),
            }
        })
        .collect();
    panels(
        path,
        "Fig. 4: master and slave forces at dead point B, PR 5.1 / 4.1 m/s, 25 ms",
        "time, s",
        &panel_v,
    )?;
    Ok((peak, lag_ms))
}

/// Fig. 5: master − slave force against the master position over the last strokes.
fn fig5(runs: &PaperRuns, path: &Path) -> Result<[f64; 3], String> {
    let sets = [
        ("published, compression (PR 5.1)", &runs.published[3]),
        ("published, no compression", &runs.published_unloaded),
        ("ours, compression (PR 5.1)", &runs.ours[3]),
    ];
    let mut data = Vec::new();
    let mut peak = [0.0; 3];
    for (k, (_, out)) in sets.iter().enumerate() {
        let log = &out.log;
        let r = last_strokes(log, 4)?;
        let x = col(log, "x_m")?[r.clone()].to_vec();
        let d: Vec<f64> = col(log, "f_master_n")?[r.clone()]
            .iter()
            .zip(&col(log, "f_slave_n")?[r])
            .map(|(m, s)| (m - s) * 1e-3)
            .collect();
        peak[k] = d.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        data.push((x, d));
    }
    let (p0x, p0y) = hline(0.7, 0.0, 0.205);
    let (n0x, n0y) = hline(-0.7, 0.0, 0.205);
    let panel_v = vec![
        Panel {
            y_label: "published: master − slave, kN",
            series: vec![
                Series::new(sets[0].0, &data[0].0, &data[0].1).colour(0),
                Series::new(sets[1].0, &data[1].0, &data[1].1).colour(1),
                Series::new("§4.1: \"exceed sometimes ±0.7 kN\"", &p0x, &p0y)
                    .dashed()
                    .colour(6),
                Series::new("−0.7 kN", &n0x, &n0y).dashed().colour(6),
            ],
            axes: Axes {
                y_range: Some((-0.8, 0.8)),
                ..Axes::default()
            },
        },
        Panel {
            y_label: "ours: master − slave, kN",
            series: vec![Series::new(sets[2].0, &data[2].0, &data[2].1).colour(2)],
            axes: Axes {
                y_range: Some((-0.8, 0.8)),
                ..Axes::default()
            },
        },
    ];
    panels(
        path,
        "Fig. 5: master/slave force difference against position, 4.1 m/s",
        "master position, m",
        &panel_v,
    )?;
    Ok(peak)
}

/// The slave − master difference of `log` over its last strokes while moving faster than
/// 0.1 m/s: (positions, differences, velocities).
fn encoder_difference(log: &RunLog) -> Result<Trace, String> {
    let r = last_strokes(log, 4)?;
    let x = col(log, "x_m")?;
    let xs = col(log, "x_slave_m")?;
    let v = central_difference(x, log.sample_time_s().unwrap_or(50e-6));
    let (mut px, mut pd, mut pv) = (Vec::new(), Vec::new(), Vec::new());
    for i in r {
        if v[i].abs() > 0.1 {
            px.push(x[i]);
            pd.push(xs[i] - x[i]);
            pv.push(v[i]);
        }
    }
    Ok((px, pd, pv))
}

/// RMS about the mean (a constant offset is the zeroing's, not the pattern's).
fn rms(v: &[f64]) -> f64 {
    let n = v.len().max(1) as f64;
    let mean = v.iter().sum::<f64>() / n;
    (v.iter().map(|d| (d - mean) * (d - mean)).sum::<f64>() / n).sqrt()
}

/// Fig. 6: slave − master reading against the master position, paper rig.
fn fig6(runs: &PaperRuns, path: &Path) -> Result<([f64; 3], f64, f64), String> {
    let (x, d, v) = encoder_difference(&runs.rig.log)?;
    let (xu, du, _) = encoder_difference(&runs.rig_unloaded.log)?;
    // The firmware's correction law, at the master's phase and the velocity.
    let period = f64::from(runs.map.period_m);
    let mut corrected: Vec<f64> = x
        .iter()
        .zip(&d)
        .zip(&v)
        .map(|((x, d), v)| {
            let phase = fpc::angle::turns((x / period) as f32);
            d - f64::from(runs.map.difference_m(phase, *v as f32))
        })
        .collect();
    // Each zeroing leaves the encoders their own constant offset (the firmware's homing, the
    // drives' start-up): the corrected trace is drawn and compared about its mean.
    let offset = corrected.iter().sum::<f64>() / corrected.len().max(1) as f64;
    corrected.iter_mut().for_each(|c| *c -= offset);
    let step = d
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(0.0f64, f64::max);
    let mean = |sel: &dyn Fn(f64) -> bool| {
        let s: Vec<f64> = d
            .iter()
            .zip(&v)
            .filter(|(_, v)| sel(**v))
            .map(|(d, _)| *d)
            .collect();
        s.iter().sum::<f64>() / s.len().max(1) as f64
    };
    let direction = mean(&|v| v > 0.0) - mean(&|v| v < 0.0);
    let mm = |v: &[f64]| v.iter().map(|d| d * 1e3).collect::<Vec<f64>>();
    let (dm, dum, cm) = (mm(&d), mm(&du), mm(&corrected));
    let (rx, ry) = hline(0.1, 0.0, 0.205);
    let panel_v = vec![Panel {
        y_label: "slave − master reading, mm",
        series: vec![
            Series::new("compression (PR 5.1, 4.1 m/s)", &x, &dm).colour(0),
            Series::new("no compression", &xu, &dum).colour(1),
            Series::new("compression, the map applied (mean removed)", &x, &cm).colour(2),
            Series::new("declared discrepancy, 0.1 mm", &rx, &ry)
                .dashed()
                .colour(6),
        ],
        axes: Axes {
            y_range: Some((-0.15, 0.15)),
            ..Axes::default()
        },
    }];
    panels(
        path,
        "Fig. 6: difference between the master and slave encoders, paper rig",
        "master position, m",
        &panel_v,
    )?;
    Ok((
        [rms(&d) * 1e6, rms(&du) * 1e6, rms(&corrected) * 1e6],
        step * 1e6,
        direction * 1e6,
    ))
}

/// Fig. 7: the velocity four ways over 60 ms of a published run at PR 3.7 / 2.8 m/s.
fn fig7(runs: &PaperRuns, path: &Path) -> Result<([f64; 3], [f64; 3]), String> {
    let log = &runs.published[1].log;
    let dt = log.sample_time_s().unwrap_or(50e-6);
    let x = col(log, "x_m")?;
    let t = col(log, "t_s")?;
    let drive = col(log, "v_drive_mps")?;
    let sections = butterworth_lowpass(4, 100.0, 1.0 / dt)?;
    let zero_phase = filtfilt(&sections, &central_difference(x, dt));
    let raw = backward_difference(x, dt);
    let c = fpc::control::config::ControlConfig::reference();
    let sg = SgSettings {
        window: c.sg_window,
        order: c.sg_order,
        lag: c.sg_lag,
    };
    let (v_sg, _) = firmware_derivatives(x, dt, 0.024, sg)?;
    let r = last_strokes(log, 2)?;
    let mut lags = [0.0; 3];
    let mut errs = [0.0; 3];
    for (k, v) in [&raw, &v_sg, &drive.to_vec()].iter().enumerate() {
        let a = &zero_phase[r.clone()];
        let b = &v[r.clone()];
        lags[k] = xcorr_lag(a, b, dt, Some(400))?.seconds * 1e3;
        errs[k] = crate::signal::rms_difference(a, b);
    }
    // 60 ms from the start of the last full stroke's acceleration, as Fig. 7.
    let s = r.start;
    let w = s..(s + (0.06 / dt) as usize).min(x.len());
    let tt = t[w.clone()].to_vec();
    let pick = |v: &[f64]| v[w.clone()].iter().map(|v| v.abs()).collect::<Vec<f64>>();
    let (a, b, c2, d) = (pick(&raw), pick(&zero_phase), pick(&v_sg), pick(drive));
    panels(
        path,
        "Fig. 7: piston velocity four ways, published drives, PR 3.7 / 2.8 m/s",
        "time, s",
        &[Panel {
            y_label: "piston speed, m/s",
            series: vec![
                Series::new("no filtering (Eq. 5)", &tt, &a)
                    .faint()
                    .colour(0),
                Series::new("filtfilt", &tt, &b).colour(1),
                Series::new("Savitzky–Golay (the firmware's)", &tt, &c2).colour(2),
                Series::new("readings from drive", &tt, &d).colour(3),
            ],
            axes: Axes::default(),
        }],
    )?;
    Ok((lags, errs))
}

/// Fig. 8: the inertia force from the position against the one the forces imply, published
/// PR 5.1; with the §4.3 tuning of the Savitzky–Golay window on the same stroke.
fn fig8(runs: &PaperRuns, path: &Path) -> Result<([f64; 3], FilterTuning), String> {
    let model = MachineModel::reference();
    let log = &runs.published[3].log;
    let dt = log.sample_time_s().unwrap_or(50e-6);
    let data = read_measured(log, &model)?;
    let sections = butterworth_lowpass(4, 100.0, 1.0 / dt)?;
    let fb = force_balance(&data, &model, &sections).map_err(|e| e.message)?;
    let r = last_strokes(log, 2)?;
    let expected = &fb.expected_inertia_n[r.clone()];
    let peak = expected.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    let raw_err = crate::signal::rms_difference(expected, &fb.inertia_raw_n[r.clone()]);
    let filt_err = crate::signal::rms_difference(expected, &fb.inertia_filtered_n[r.clone()]);
    // §4.3: the Savitzky–Golay windows, each m·a against the expected inertia force.
    let x = col(log, "x_m")?;
    let mass = model.piston.mass_kg;
    let mut rows = Vec::new();
    for window in [5usize, 9, 15, 25, 33, 41] {
        let s = SgSettings {
            window,
            order: 2,
            lag: 0,
        };
        let (_, a) = firmware_derivatives(x, dt, model.encoder.period_m, s)?;
        let ma: Vec<f64> = a[r.clone()].iter().map(|a| mass * a).collect();
        let lag = xcorr_lag(expected, &ma, dt, Some(400))?.seconds * 1e3;
        rows.push((window, lag, crate::signal::rms_difference(expected, &ma)));
    }
    let best_window = rows
        .iter()
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .map_or(0, |r| r.0);
    let t = col(log, "t_s")?;
    let w = r.start..(r.start + (0.15 / dt) as usize).min(t.len());
    let kn = |v: &[f64]| v[w.clone()].iter().map(|v| v * 1e-3).collect::<Vec<f64>>();
    let tt = t[w.clone()].to_vec();
    let (raw, filt, exp) = (
        kn(&second_difference(x, dt)
            .iter()
            .map(|a| mass * a)
            .collect::<Vec<_>>()),
        kn(&fb.inertia_filtered_n),
        kn(&fb.expected_inertia_n),
    );
    let (p0x, p0y) = hline(10.0, tt[0], tt[tt.len() - 1]);
    let (n0x, n0y) = hline(-10.0, tt[0], tt[tt.len() - 1]);
    panels(
        path,
        "Fig. 8: inertia force from the position, published drives, PR 5.1 / 4.1 m/s",
        "time, s",
        &[Panel {
            y_label: "force, kN",
            series: vec![
                Series::new("unfiltered from position", &tt, &raw)
                    .faint()
                    .colour(0),
                Series::new("filtered from position", &tt, &filt).colour(1),
                Series::new("expected inertia force", &tt, &exp).colour(2),
                Series::new("Fig. 8's axis, ±10 kN", &p0x, &p0y)
                    .dashed()
                    .colour(6),
                Series::new("−10 kN", &n0x, &n0y).dashed().colour(6),
            ],
            axes: Axes {
                y_range: Some((-12.0, 12.0)),
                ..Axes::default()
            },
        }],
    )?;
    Ok((
        [peak * 1e-3, raw_err * 1e-3, filt_err * 1e-3],
        FilterTuning {
            rows,
            best_window,
            firmware_window: fpc::control::config::ControlConfig::reference().sg_window,
        },
    ))
}

/// Fig. 9: motor, inertia, gas and friction forces along one stroke toward B, PR 5.1.
fn fig9(runs: &PaperRuns, path: &Path) -> Result<([f64; 2], [f64; 2]), String> {
    let model = MachineModel::reference();
    let mut peak = [0.0; 2];
    let mut work = [0.0; 2];
    let mut panel_data = Vec::new();
    for (k, out) in [&runs.ours[3], &runs.published[3]].iter().enumerate() {
        let log = &out.log;
        let dt = log.sample_time_s().unwrap_or(50e-6);
        let data = read_measured(log, &model)?;
        let sections = butterworth_lowpass(4, 100.0, 1.0 / dt)?;
        let fb = force_balance(&data, &model, &sections).map_err(|e| e.message)?;
        let all = strokes(&fb.x_m, &fb.v_mps);
        // The last full stroke toward B (the gas of chamber B compressed).
        let r = all
            .iter()
            .rev()
            .skip(1)
            .find(|r| {
                fb.v_mps
                    .get(r.start + r.len() / 2)
                    .is_some_and(|v| *v > 0.0)
            })
            .cloned()
            .ok_or("no stroke toward B")?;
        let e = stroke_energy(&fb, &r, model.piston.mass_kg);
        peak[k] = fb.motor_n[r.clone()]
            .iter()
            .fold(0.0f64, |a, b| a.max(b.abs()))
            * 1e-3;
        if k == 1 {
            work = [e.motor_accelerating_j, e.motor_decelerating_j];
        }
        let kn = |v: &[f64]| v[r.clone()].iter().map(|v| v * 1e-3).collect::<Vec<f64>>();
        panel_data.push((
            fb.x_m[r.clone()].to_vec(),
            kn(&fb.motor_n),
            kn(&fb.inertia_filtered_n),
            kn(&fb.gas_n.iter().map(|g| -g).collect::<Vec<_>>()),
            kn(&fb.friction_n),
        ));
    }
    let (rx, ry) = hline(6.0, 0.0, 0.205);
    let names = ["ours", "published drives"];
    let list: Vec<(String, Vec<Series>)> = panel_data
        .iter()
        .enumerate()
        .map(|(k, (x, m, i, g, fr))| {
            (
                format!("{}: force, kN", names[k]),
                vec![
                    Series::new("motor force", x, m).colour(0),
                    Series::new("inertia m·a", x, i).colour(1),
                    Series::new("gas force (against the motion)", x, g).colour(2),
                    Series::new("friction", x, fr).colour(3),
                    Series::new("Fig. 9's motor force, ≈ 6 kN", &rx, &ry)
                        .dashed()
                        .colour(6),
                ],
            )
        })
        .collect();
    let panel_v: Vec<Panel> = list
        .iter()
        .map(|(label, series)| Panel {
            y_label: label,
            series: series.clone(),
            axes: Axes {
                y_range: Some((-4.0, 7.0)),
                x_range: Some((0.0, 0.205)),
                ..Axes::default()
            },
        })
        .collect();
    panels(
        path,
        "Fig. 9: forces along one stroke toward B, PR 5.1 / 4.1 m/s",
        "piston position, m",
        &panel_v,
    )?;
    Ok((peak, work))
}
