//! What real logs have must not make the workflow name what is not there, nor miss what is:
//! extra sensor noise, coarse quantisation, a constant offset between the encoders, missing
//! optional columns, a 10 kHz log.

mod support;

use hal_sim::gap::synth::decimate;
use hal_sim::plant::noise::Noise;
use hal_sim::runlog::{RunLog, REQUIRED};
use support::gap::*;

/// Applies `f` to column `name` of `log`, row by row.
fn map_column(log: &mut RunLog, name: &str, mut f: impl FnMut(f64) -> f64) {
    let i = log.names.iter().position(|n| n == name).unwrap();
    for v in &mut log.columns[i] {
        *v = f(*v);
    }
}

/// The real-log treatments, each applied to a copy.
fn treatments(log: &RunLog) -> Vec<(&'static str, RunLog)> {
    let mut out = Vec::new();
    let mut noisy = log.clone();
    let mut n = Noise::new(7);
    map_column(&mut noisy, "x_m", |v| v + n.scaled(1e-6));
    map_column(&mut noisy, "x_slave_m", |v| v + n.scaled(1e-6));
    map_column(&mut noisy, "f_master_n", |v| v + n.scaled(5.0));
    map_column(&mut noisy, "f_slave_n", |v| v + n.scaled(5.0));
    map_column(&mut noisy, "p_a_pa", |v| v + n.scaled(1000.0));
    map_column(&mut noisy, "p_b_pa", |v| v + n.scaled(1000.0));
    out.push(("noise", noisy));
    let mut coarse = log.clone();
    for (c, q) in [
        ("x_m", 1e-6),
        ("x_slave_m", 1e-6),
        ("f_master_n", 1.0),
        ("f_slave_n", 1.0),
    ] {
        map_column(&mut coarse, c, |v| (v / q).round() * q);
    }
    out.push(("quantised", coarse));
    // A constant offset between the two encoders (zeroed apart): not a pitch error. (Both
    // zeros moved together would move the model's cogging phase and chamber volumes with
    // them: the workflow takes x as homed.)
    let mut offset = log.clone();
    map_column(&mut offset, "x_slave_m", |v| v + 0.2e-3);
    out.push(("encoder offset", offset));
    let mut bare = RunLog::with_columns(&REQUIRED);
    bare.meta = log.meta.clone();
    for (name, col) in REQUIRED.iter().zip(bare.columns.iter_mut()) {
        *col = log.column(name).unwrap().to_vec();
    }
    out.push(("required columns only", bare));
    out.push(("10 kHz", decimate(log, 2)));
    out
}

#[test]
fn gap_stays_quiet_on_real_looking_logs_of_the_modelled_machine() {
    let log = closed_loop(&reference(), 2.3, 2, 41);
    for (what, l) in treatments(&log) {
        let j = gap(&reference(), &l);
        assert!(j.effects.is_empty(), "{what}: named {:?}", names(&j));
    }
}

#[test]
#[ignore = "slow: five treatments of a closed-loop run"]
fn gap_still_names_cogging_on_real_looking_logs() {
    let truth = cogging_truth();
    let model = without_section(&reference(), "effects.cogging");
    let log = closed_loop(&truth, 2.3, 2, 42);
    for (what, l) in treatments(&log) {
        let j = gap(&model, &l);
        assert_eq!(names(&j), ["cogging"], "{what}");
        let p = param(&j, "cogging", "period_m");
        assert!((p - 0.024).abs() < 0.02 * 0.024, "{what}: period {p}");
    }
}
