//! The stroke cycle of a fault-free run, for tests that place a fault at phases of it.

use hal_sim::run::{run, RunOptions};

/// Speed toward head B whose first upward crossing in a cycle marks the cycle's start, m/s.
const START_SPEED_MPS: f64 = 0.5;

/// One stroke cycle of a fault-free run.
#[derive(Clone, Debug)]
pub struct StrokeCycle {
    /// Where the velocity toward head B first exceeds 0.5 m/s in the second cycle (the
    /// first starts from the park position), s.
    pub start_s: f64,
    /// Time to the same crossing in the next cycle, s.
    pub period_s: f64,
    /// The run's peak speed, m/s.
    pub peak_mps: f64,
    /// The faults the run latched (a fault-free run: none).
    pub faults: Vec<String>,
}

/// The stroke cycle of `o` run for 4 cycles without its faults. Panics, naming what is
/// wrong, if the run has fewer than three strokes toward head B.
pub fn stroke_cycle(o: &RunOptions) -> StrokeCycle {
    let mut o = o.clone();
    o.cycles = 4;
    o.faults = vec![];
    let out = run(&o).expect("fault-free run");
    let t = out.log.column("t_s").expect("t_s logged");
    let v = out.log.column("v_mps").expect("v_mps logged");
    let ups: Vec<f64> = t
        .windows(2)
        .zip(v.windows(2))
        .filter(|(_, v)| v[0] <= START_SPEED_MPS && v[1] > START_SPEED_MPS)
        .map(|(t, _)| t[1])
        .collect();
    assert!(
        ups.len() >= 3,
        "only {} strokes toward head B in 4 cycles",
        ups.len()
    );
    let peak_mps = v.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    println!("fault-free: peak speed {peak_mps:.2} m/s, strokes toward head B start at {ups:?} s");
    StrokeCycle {
        start_s: ups[1],
        period_s: ups[2] - ups[1],
        peak_mps,
        faults: out.summary.faults,
    }
}
