//! `fpc-sim forces` (the paper's Fig. 8): the inertia force `m·a` estimated from the logged
//! position — unfiltered (second difference), zero-phase filtered (`filtfilt` of the second
//! difference: filtering the position instead would bend its curvature at the log's ends),
//! and by the firmware's own Savitzky–Golay differentiator — against the inertia force the
//! other forces imply, `m·a = F_motor + (p_a − p_b)·A_eff + F_cog − F_fr(v, ω·r)`: the
//! model's force balance along the log, the one `fpc-sim gap` starts from
//! ([`crate::balance`]). The delay of each estimate behind the expected force is what the
//! paper tuned its filters on.

use clap::Args;
use serde::Serialize;

use crate::cli::analysis::{
    column, default_window, finish, in_window, interior, read_force_balance, time_window,
    LogToolArgs, Steps, WindowArgs, ZeroPhaseArgs,
};
use crate::console::Num;
use crate::failure::{CmdResult, Failure};
use crate::outln;
use crate::plot::{self, Axes, Panel, Series};
use crate::signal::{rms_difference, strokes, xcorr_lag};

/// Inertia force from position vs expected (Fig. 8).
#[derive(Args, Debug)]
pub struct ForcesArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub io: LogToolArgs,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub filter: ZeroPhaseArgs,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub window: WindowArgs,
}

/// Runs `fpc-sim forces`.
pub fn main(args: ForcesArgs) -> CmdResult {
    let out = args.io.output("forces", &["forces.svg", "forces.json"])?;
    let steps = Steps::new(3, "reading");
    let (log, model, dt, fb) = read_force_balance(&args.io, &args.filter, &steps)?;
    steps.next("plotting");
    let t = column(&log, "t_s", "t_s")?;
    let window = time_window(
        t,
        args.window.from_s,
        args.window.to_s,
        default_window(t, &strokes(&fb.x_m, &fb.v_mps), dt),
    )?;
    let n = |v: &[f64]| in_window(v, window.clone());
    let tw = t.get(window.clone()).unwrap_or_default();
    let (raw, filtered, firmware, expected) = (
        n(&fb.inertia_raw_n),
        n(&fb.inertia_filtered_n),
        n(&fb.inertia_firmware_n),
        n(&fb.expected_inertia_n),
    );
    // The upper panel shows the comparison the figure exists for, the filtered estimates against
    // the force balance; the unfiltered trace, whose noise is far larger, has its own axis below.
    let path = out.path("forces.svg");
    plot::panels(
        &path,
        "Inertia force from position (Fig. 8)",
        "t, s",
        &[
            Panel {
                y_label: "m·a, N",
                series: vec![
                    Series::new("firmware Savitzky-Golay", tw, &firmware),
                    Series::new("filtered from position (filtfilt)", tw, &filtered),
                    Series::new("expected inertia force", tw, &expected).dashed(),
                ],
                axes: Axes::default(),
            },
            Panel {
                y_label: "m·a, N",
                series: vec![
                    Series::new("unfiltered from position", tw, &raw)
                        .faint()
                        .colour(3),
                    Series::new("expected inertia force", tw, &expected)
                        .dashed()
                        .colour(2),
                ],
                axes: Axes::default(),
            },
        ],
    )
    .map_err(Failure::runtime)?;
    steps.finish();

    let max_lag = Some(((0.05 / dt).round() as usize).max(2));
    let inner = interior(log.len(), dt);
    let expected = fb.expected_inertia_n.get(inner.clone()).unwrap_or_default();
    let estimates = [
        ("unfiltered from position", &fb.inertia_raw_n),
        ("filtered from position (filtfilt)", &fb.inertia_filtered_n),
        ("firmware Savitzky-Golay", &fb.inertia_firmware_n),
    ]
    .into_iter()
    .map(|(label, est)| {
        let est = est.get(inner.clone()).unwrap_or_default();
        ForceEstimate {
            label,
            rms_vs_expected_n: rms_difference(est, expected),
            delay_s: xcorr_lag(expected, est, dt, max_lag).map_or(f64::NAN, |l| l.seconds),
        }
    })
    .collect();
    let figures = ForcesFigures {
        mass_kg: model.piston.mass_kg,
        area_m2: model.piston_area_m2(),
        filter: args.filter.describe(),
        peak_expected_n: expected.iter().fold(0.0f64, |m, f| m.max(f.abs())),
        estimates,
    };
    finish(&args.io, "forces", out, &figures, &["forces.svg"], || {
        outln!(
            "mass {} kg, A_eff {:.4e} m², {}; peak expected |m·a| {:.0} N",
            figures.mass_kg,
            figures.area_m2,
            figures.filter,
            figures.peak_expected_n
        )?;
        outln!(
            "{:<36} {:>16} {:>18}",
            "m·a estimate",
            "rms vs expected N",
            "delay ms"
        )?;
        for e in &figures.estimates {
            outln!(
                "{:<36} {:>16.1} {:>18.4}",
                e.label,
                Num(e.rms_vs_expected_n),
                Num(e.delay_s * 1e3)
            )?;
        }
        Ok(())
    })
}

/// What `fpc-sim forces` reports (printed, `--json`, and `forces.json`).
#[derive(Debug, Serialize)]
pub struct ForcesFigures {
    /// The model's moving mass, kg.
    pub mass_kg: f64,
    /// The model's effective piston area, m².
    pub area_m2: f64,
    /// The reference low-pass.
    pub filter: String,
    /// Largest |m·a| the force balance expects in the log's interior, N.
    pub peak_expected_n: f64,
    /// Each estimate of m·a from the position.
    pub estimates: Vec<ForceEstimate>,
}

/// One estimate of the inertia force from the position, against the force balance.
#[derive(Debug, Serialize)]
pub struct ForceEstimate {
    /// What it is.
    pub label: &'static str,
    /// RMS difference to the expected inertia force, N.
    pub rms_vs_expected_n: f64,
    /// Its delay behind the expected force (cross-correlation), s.
    pub delay_s: f64,
}
