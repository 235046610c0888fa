//! Benchmark: how fast `fpc-sim run` simulates the full closed loop (firmware tasks, plant,
//! sensors, run-log recording) on the reference machine, in simulated seconds per wall
//! second — the JSON's `realtime_factor` (issue 4 asks for ≥ 200× on one core).
//!
//! Not a check by default (a shared machine's timing is noise): it prints the best and the
//! median of `FPC_BENCH_RUNS` runs (default 9), and fails only below `FPC_MIN_REALTIME` when
//! that is set. Run it in release, alone on the machine if possible:
//!
//! ```text
//! cargo test --release -p hal-sim --test realtime -- --ignored --nocapture
//! ```

use std::time::Instant;

use hal_sim::run::{run, RunOptions};

fn env_number(name: &str) -> Option<f64> {
    std::env::var(name).ok().and_then(|v| v.trim().parse().ok())
}

#[test]
#[ignore = "benchmark: run with --release --ignored --nocapture"]
fn closed_loop_realtime_factor() {
    let runs = env_number("FPC_BENCH_RUNS").map_or(9, |n| n.max(1.0) as usize);
    let opts = RunOptions::reference();
    let mut loop_factors = Vec::with_capacity(runs);
    let mut whole_factors = Vec::with_capacity(runs);
    let mut sim_s = 0.0;
    for _ in 0..runs {
        let started = Instant::now();
        let outcome = run(&opts).expect("the reference run is valid");
        let whole_s = started.elapsed().as_secs_f64();
        let s = &outcome.summary;
        assert!(
            s.faults.is_empty(),
            "the reference run faulted: {:?}",
            s.faults
        );
        sim_s = s.sim_time_s;
        loop_factors.push(s.realtime_factor);
        whole_factors.push(s.sim_time_s / whole_s);
    }
    let best = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let (best_loop, best_whole) = (best(&loop_factors), best(&whole_factors));
    let cycles = sim_s / f64::from(fpc::units::CONTROL_PERIOD_S);
    println!(
        "realtime factor (simulation loop, `realtime_factor`): best {best_loop:.1}x, median \
         {:.1}x of {runs} runs = {:.0} ns per 50 us control cycle ({cycles:.0} cycles, {sim_s} s)",
        median(&mut loop_factors),
        1e9 * sim_s / best_loop / cycles,
    );
    println!(
        "realtime factor (whole run(), with the run log's columns, without CSV): best \
         {best_whole:.1}x, median {:.1}x",
        median(&mut whole_factors),
    );
    if let Some(min) = env_number("FPC_MIN_REALTIME") {
        assert!(
            best_loop >= min,
            "best realtime factor {best_loop:.1} is below FPC_MIN_REALTIME = {min}"
        );
    }
}
