//! The published rig's controller (the paper's master/slave drives, `--controller published`)
//! and ours, on the same reference plant at the four operating points of the paper's Fig. 3
//! (PR 3.1/3.7/4.3/5.1 at 2.3/2.8/3.5/4.1 m/s): the published one shows the paper's problems,
//! ours does not. Figures and reasoning: `docs/published-baseline.md`.
//!
//! - the force fight (§4.1, "exceed sometimes ±0.7 kN"): the slave applies the master's
//!   setpoint 0.75 ms late;
//! - the overshoot that grows with speed, and with it travel and volume ratio (§5).
//!
//! The self-excitation near 400 Hz when tuned harder, and the other claims the published rig
//! makes as results, are held by `tests/the_paper_side_by_side.rs`.

use hal_sim::plant::model::MachineModel;
use hal_sim::run::{run, speed_for_pressure_ratio, Controller, RunOptions, Summary};

const FIG3_RATIOS: [f64; 4] = [3.1, 3.7, 4.3, 5.1];

/// A line "above the noise floor": more than this many times the median amplitude around it.
/// The largest of the band's ≈ 390 bins of pure noise (Rayleigh amplitudes) stands ≈ 2.9
/// times above their median; 5 times happens by chance with a probability of ≈ 10⁻⁵.
const LINE_PROMINENCE: f64 = 5.0;

fn run_at(model: &MachineModel, controller: Controller, pr: f64, cycles: u32) -> Summary {
    let opts = RunOptions {
        model: model.clone(),
        controller,
        pressure_ratio: pr,
        cycles,
        ..RunOptions::reference()
    };
    let out = run(&opts).unwrap_or_else(|e| panic!("{controller:?} at PR {pr}: {e}"));
    assert_eq!(
        out.summary.cycles, cycles,
        "{:?}",
        out.summary.stopped_early
    );
    out.summary
}

fn f(v: Option<f64>) -> f64 {
    v.unwrap_or(f64::NAN)
}

#[test]
fn at_the_fig3_points_the_published_drives_fight_and_overshoot_more_with_speed_and_ours_do_not() {
    let model = MachineModel::reference();
    let mut published = Vec::new();
    for pr in FIG3_RATIOS {
        let p = run_at(&model, Controller::Published, pr, 8);
        let o = run_at(&model, Controller::Ours, pr, 8);
        println!(
            "PR {pr} at {:.1} m/s: force difference at the dead points {:.0} N published, {:.1} N \
             ours ({:.2} % / {:.3} % RMS of the total); overshoot {:+.3} / {:+.3} mm; dead-point \
             error {:.3} / {:.3} mm; travel {:.2} / {:.2} mm; volume ratio {:.0} / {:.0}; \
             p–V pressure ratio {:.2} / {:.2}; line {:.0} Hz {:.3} µm ({:.1}× floor) / {:.0} Hz \
             {:.3} µm ({:.1}× floor)",
            speed_for_pressure_ratio(pr),
            f(p.dead_point_force_diff_n),
            f(o.dead_point_force_diff_n),
            100.0 * f(p.force_diff_rms_fraction),
            100.0 * f(o.force_diff_rms_fraction),
            1e3 * f(p.overshoot_m),
            1e3 * f(o.overshoot_m),
            1e3 * f(p.dead_point_error_m),
            1e3 * f(o.dead_point_error_m),
            1e3 * f(p.travel_m),
            1e3 * f(o.travel_m),
            f(p.volume_ratio_reached),
            f(o.volume_ratio_reached),
            f(p.pv_pressure_ratio),
            f(o.pv_pressure_ratio),
            f(p.line_hz),
            1e6 * f(p.line_m),
            f(p.line_m) / f(p.line_floor_m),
            f(o.line_hz),
            1e6 * f(o.line_m),
            f(o.line_m) / f(o.line_floor_m),
        );
        // Ours: both sections share one force, no vibration, the dead points within 0.1 mm.
        assert!(f(o.force_diff_rms_fraction) <= 0.01);
        assert!(f(o.line_m) / f(o.line_floor_m) < LINE_PROMINENCE);
        assert!(f(o.dead_point_error_m) <= 0.1e-3);
        published.push(p);
    }
    // The paper's force fight at its fastest point (PR 5.1, 4.1 m/s).
    let top = f(published[3].dead_point_force_diff_n);
    assert!((500.0..=1000.0).contains(&top), "{top} N");
    // Overshoot, travel and volume ratio grow with the speed, point after point.
    for w in published.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        assert!(f(b.overshoot_m) > f(a.overshoot_m));
        assert!(f(b.travel_m) > f(a.travel_m));
        assert!(f(b.volume_ratio_reached) > f(a.volume_ratio_reached));
        assert!(f(b.dead_point_force_diff_n) > f(a.dead_point_force_diff_n));
    }
}
