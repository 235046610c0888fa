//! The published rig's encoders (`docs/studies/paper-rig.toml`, opt-in): the slave encoder
//! reads a saw of the declared 0.1 mm stepping once per magnetic pitch, 0.05 mm more moving
//! toward head B (paper §2, §4.2, Fig. 6). Our controller runs on it unchanged (it positions
//! on the master encoder), the logged difference shows the pattern, and `gap` names
//! `encoder_pitch_error` — fitting the saw's first two harmonics (S/π and S/2π), which is all
//! its basis holds: the direction part and the saw's higher harmonics stay in the residual.

mod support;

use hal_sim::plant::model::MachineModel;
use hal_sim::run::{run, RunOptions};
use support::gap::*;

const PAPER_RIG: &str = include_str!("../docs/studies/paper-rig.toml");

#[test]
fn the_slave_encoder_steps_once_a_pitch_and_gap_names_the_pitch_error() {
    let model = MachineModel::parse(PAPER_RIG).unwrap();
    let e = model.effects.encoder_pitch_error.clone().unwrap();
    let opts = RunOptions {
        model,
        pressure_ratio: 5.1,
        cycles: 10,
        ..RunOptions::reference()
    };
    let out = run(&opts).unwrap();
    let s = &out.summary;
    assert!(s.faults.is_empty(), "{:?}", s.faults);
    assert!(s.dead_point_error_m.unwrap_or(1.0) <= 0.1e-3);
    let log = &out.log;
    let (x, xs, v) = (
        log.column("x_m").unwrap(),
        log.column("x_slave_m").unwrap(),
        log.column("v_mps").unwrap(),
    );
    // The difference by direction, away from the reversals.
    let mean = |sel: &dyn Fn(f64) -> bool| {
        let d: Vec<f64> = (0..x.len())
            .filter(|&i| sel(v[i]))
            .map(|i| xs[i] - x[i])
            .collect();
        d.iter().sum::<f64>() / d.len().max(1) as f64
    };
    let toward_b = mean(&|v| v > 0.5);
    let toward_a = mean(&|v| v < -0.5);
    // The step: the largest jump of the difference between neighbouring samples while
    // moving, against the encoders' noise.
    let step = (1..x.len())
        .filter(|&i| v[i].abs() > 0.5)
        .map(|i| ((xs[i] - x[i]) - (xs[i - 1] - x[i - 1])).abs())
        .fold(0.0, f64::max);
    println!(
        "x_slave − x: {:.1} µm moving toward B, {:.1} µm toward A; largest jump {:.1} µm",
        toward_b * 1e6,
        toward_a * 1e6,
        step * 1e6
    );
    assert!((toward_b - toward_a - e.direction_m).abs() < 0.2 * e.direction_m);
    assert!((step - e.step_m).abs() < 0.25 * e.step_m, "{step} m");

    let j = gap(&reference(), log);
    show("paper-rig encoders", &j);
    assert!(names(&j).contains(&"encoder_pitch_error".to_string()));
    let a1 = param(&j, "encoder_pitch_error", "amplitude_m");
    let fundamental = e.step_m / std::f64::consts::PI;
    assert!((a1 - fundamental).abs() < 0.15 * fundamental, "{a1} m");
    let p = param(&j, "encoder_pitch_error", "period_m");
    assert!((p - 0.024).abs() < 0.001, "{p} m");
}
