//! With `[motor] slave_follows_master = true` and the paper's `[effects.slave_lag]` the slave section is driven as on the
//! published rig: its drive imposes the master's q-current 0.75 ms late. The logged forces
//! then show the paper's lag (Fig. 4) and the master–slave force difference it causes
//! (Fig. 5); our own commutation of both sections (the reference) shows neither.

use hal_sim::plant::model::{DelayEffect, MachineModel, PAPER_SLAVE_LAG_S};
use hal_sim::run::{run, RunOptions};

/// (lag of f_slave behind f_master from the cross-correlation, s; peak |difference|, N;
/// peak |total force|, N) over the strokes.
fn forces(slave_follows_master: bool) -> (f64, f64, f64) {
    let mut model = MachineModel::reference();
    model.motor.slave_follows_master = slave_follows_master;
    if slave_follows_master {
        model.effects.slave_lag = Some(DelayEffect {
            delay_s: PAPER_SLAVE_LAG_S,
        });
    }
    let opts = RunOptions {
        model,
        pressure_ratio: 5.1,
        cycles: 2,
        ..RunOptions::reference()
    };
    let out = run(&opts).unwrap();
    let log = &out.log;
    let (t, m, s) = (
        log.column("t_s").unwrap(),
        log.column("f_master_n").unwrap(),
        log.column("f_slave_n").unwrap(),
    );
    let v = log.column("v_mps").unwrap();
    // The strokes: from the first sample above 0.5 m/s on.
    let start = v.iter().position(|v| v.abs() > 0.5).unwrap_or(0);
    let (m, s) = (&m[start..], &s[start..]);
    let dt = t[1] - t[0];
    // Cross-correlation of the force *changes* (what a lag shifts), per overlapping sample.
    let (dm, ds): (Vec<f64>, Vec<f64>) = (
        m.windows(2).map(|w| w[1] - w[0]).collect(),
        s.windows(2).map(|w| w[1] - w[0]).collect(),
    );
    let mut best = (0usize, f64::MIN);
    for lag in 0..60 {
        let n = dm.len() - lag;
        let c: f64 = dm.iter().zip(&ds[lag..]).map(|(a, b)| a * b).sum::<f64>() / n as f64;
        if c > best.1 {
            best = (lag, c);
        }
    }
    let peak_diff = m
        .iter()
        .zip(s)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    let peak_total = m
        .iter()
        .zip(s)
        .map(|(a, b)| (a + b).abs())
        .fold(0.0, f64::max);
    (best.0 as f64 * dt, peak_diff, peak_total)
}

#[test]
fn the_following_slave_lags_0_75_ms_and_the_forces_differ_as_in_the_paper() {
    let (lag, diff, total) = forces(true);
    let (lag0, diff0, _) = forces(false);
    println!(
        "slave follows master: lag {:.2} ms, peak |F_m − F_s| {:.0} N (peak total {:.0} N); \
         both commutated here: lag {:.2} ms, peak difference {:.0} N",
        lag * 1e3,
        diff,
        total,
        lag0 * 1e3,
        diff0
    );
    assert!((lag - 0.75e-3).abs() <= 0.1e-3);
    // The difference is the lag times the rate of change of the force: with the chambers
    // unloaded (no rotary synchroniser yet) the forces stay below 2 kN, so it is ≈ 0.1 kN
    // here; with the gas forces of PR 5.1 it grows toward the paper's ±0.7 kN.
    assert!(diff > 50.0, "the lag must show as a force difference");
    assert!(lag0 < 0.1e-3 && diff0 < 0.25 * diff);
}
