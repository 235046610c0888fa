//! Both motor sections push together: with this board commutating both from one force
//! command per cycle, the sections' true forces (the plant's) differ by ≤ 1 % RMS of the
//! force during 4 m/s strokes — on a machine whose misalignment and current-sense offsets
//! were calibrated, not given. The published rig's case is set up for contrast: the
//! slave's drive following the master's force setpoint 0.75 ms late
//! (`[motor] slave_follows_master = true` with `[effects.slave_lag]` 0.75 ms, planted: the
//! lag measured back is a read-back of it) and the force difference that follows from it,
//! largest where the force changes fastest.

mod support;

use fpc::control::calibration::Calibrated;
use hal_sim::plant::model::{DelayEffect, MachineModel, PAPER_SLAVE_LAG_S};
use support::drive::*;

/// The true section forces over 4 strokes, from the cycle the first stroke is under way.
struct Forces {
    t_s: Vec<f64>,
    x_m: Vec<f64>,
    master_n: Vec<f64>,
    slave_n: Vec<f64>,
}

impl Forces {
    /// RMS of master − slave, % of the RMS section force (the mean of the two).
    fn difference_percent(&self) -> f64 {
        let (mut d, mut f) = (0.0, 0.0);
        for (m, s) in self.master_n.iter().zip(&self.slave_n) {
            d += (m - s).powi(2);
            f += (0.5 * (m + s)).powi(2);
        }
        (d / f).sqrt() * 100.0
    }

    /// Largest |master − slave|, N, and where it happened, m.
    fn peak_difference(&self) -> (f64, f64) {
        self.master_n
            .iter()
            .zip(&self.slave_n)
            .zip(&self.x_m)
            .map(|((m, s), x)| ((m - s).abs(), *x))
            .fold((0.0, 0.0), |a, b| if b.0 > a.0 { b } else { a })
    }

    /// Largest |master + slave|, N.
    fn peak_total(&self) -> f64 {
        self.master_n
            .iter()
            .zip(&self.slave_n)
            .map(|(m, s)| (m + s).abs())
            .fold(0.0, f64::max)
    }

    /// Lag of the slave's force behind the master's: the peak of the cross-correlation of
    /// their changes (what a lag shifts), s.
    fn lag_s(&self) -> f64 {
        let d = |v: &[f64]| v.windows(2).map(|w| w[1] - w[0]).collect::<Vec<f64>>();
        let (dm, ds) = (d(&self.master_n), d(&self.slave_n));
        let mut best = (0usize, f64::MIN);
        for lag in 0..60 {
            let n = dm.len() - lag;
            let c = dm.iter().zip(&ds[lag..]).map(|(a, b)| a * b).sum::<f64>() / n as f64;
            if c > best.1 {
                best = (lag, c);
            }
        }
        best.0 as f64 * (self.t_s[1] - self.t_s[0])
    }

    fn show(&self, label: &str) {
        let (peak, at) = self.peak_difference();
        println!(
            "{label}: master − slave {:.2} % RMS, peak {:.0} N at x = {:.1} mm (peak total {:.0} N), \
             slave lag {:.2} ms",
            self.difference_percent(),
            peak,
            at * 1e3,
            self.peak_total(),
            self.lag_s() * 1e3
        );
    }
}

/// Homes `model` controlled with `loaded` on top of the uncalibrated configuration, strokes
/// at `speed_mps` against `pressure_ratio` and records the true forces.
fn stroke(
    model: &MachineModel,
    loaded: &Calibrated,
    pressure_ratio: f64,
    speed_mps: f32,
) -> Forces {
    let mut config = uncalibrated_config(model);
    loaded.apply(&mut config);
    let mut bench = Bench::new(model, config, 21, 0.05);
    bench.home();
    let mut f = Forces {
        t_s: Vec::new(),
        x_m: Vec::new(),
        master_n: Vec::new(),
        slave_n: Vec::new(),
    };
    bench.strokes(pressure_ratio, speed_mps, 4, |w, _| {
        f.t_s.push(w.time_s());
        f.x_m.push(w.plant.x_m);
        f.master_n.push(w.plant.force_n.master);
        f.slave_n.push(w.plant.force_n.slave);
    });
    f
}

#[test]
fn the_planted_slave_lag_reads_back_and_parts_the_forces_at_high_force_rates() {
    // The published rig: PR 5.1 at 4.1 m/s (Fig. 3), where the gas forces are largest.
    let mut model = MachineModel::reference();
    model.motor.slave_follows_master = true;
    model.effects.slave_lag = Some(DelayEffect {
        delay_s: PAPER_SLAVE_LAG_S,
    });
    let paper = stroke(&model, &Calibrated::default(), 5.1, 4.1);
    paper.show("slave follows the master (the paper's rig), PR 5.1 at 4.1 m/s");
    println!(
        "  (paper: 0.75 ms lag, differences beyond ±0.7 kN for a ±10 kN total; here ±{:.1} kN total)",
        paper.peak_total() / 1e3
    );
    assert!((paper.lag_s() - 0.75e-3).abs() <= 0.1e-3);
    // The difference is the lag times the force rate: the same order as the paper's for a
    // total force a quarter of theirs.
    assert!(paper.peak_difference().0 >= 200.0);
    assert!(paper.difference_percent() >= 5.0);

    // The same machine with this board commutating both sections: no lag, no difference.
    model.motor.slave_follows_master = false;
    model.effects.slave_lag = None;
    let ours = stroke(&model, &Calibrated::default(), 5.1, 4.1);
    ours.show("both commutated by this board, same strokes");
    assert!(ours.lag_s() < 0.1e-3);
    assert!(ours.difference_percent() <= 1.0);
    assert!(ours.peak_difference().0 < 0.1 * paper.peak_difference().0);
}

#[test]
fn a_calibrated_machine_s_sections_differ_by_at_most_one_percent_at_4_m_s() {
    // The slave's magnets 1.5 mm off and offsets on the current sensors: commissioned by the
    // calibration routines, then stroked at 4 m/s and more.
    let model = machine_with_unknowns();
    println!("commissioning:");
    let (_, found) = commission(&model, 13);
    for (pr, speed) in [(5.1, 4.1), (4.3, 4.0)] {
        let raw = stroke(&model, &Calibrated::default(), pr, speed);
        raw.show(&format!("uncalibrated, PR {pr} at {speed} m/s"));
        let calibrated = stroke(&model, &found, pr, speed);
        calibrated.show(&format!("calibrated,   PR {pr} at {speed} m/s"));
        assert!(raw.difference_percent() > 5.0, "the unknowns must matter");
        assert!(calibrated.difference_percent() <= 1.0);
    }
}
