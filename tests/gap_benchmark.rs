//! The model-gap workflow's speed: 10 s of data at 10 kHz analysed in ≤ 3 s. Two cases: a
//! closed-loop run with the firmware in the loop (force, slave-force and encoder channels:
//! the acceptance figure) and an open-port compressor run (every channel; each pressure
//! candidate replays the chambers some twenty times). Each analysis runs alone and is timed
//! by the CPU time of the whole process over it (`/proc/self/stat`: every thread, the rayon
//! pool's included), not by the wall clock, because the build machine is shared: the wall
//! time of a job on an idle machine is at most its CPU time, so a CPU time within the limit
//! is the limit met. The limit is asserted in an optimised build (`--profile slow-tests` or
//! `--release`); the open-port case only with `FPC_GAP_STRICT` set (it runs close to the
//! limit). Every build asserts what the analyses find (the cogging the model lacks; the
//! restricted port), so CI runs it on its test build too, for that.

mod support;

use std::time::Instant;

use hal_sim::gap::synth::{decimate, open_port_run};
use hal_sim::gap::{analyse, GapOptions};
use hal_sim::plant::model::MachineModel;
use support::gap::*;

/// The limit of the acceptance, s.
const LIMIT_S: f64 = 3.0;

/// CPU time of this process, every thread, s (Linux: utime + stime of `/proc/self/stat`,
/// 10 ms ticks); `None` elsewhere.
fn process_cpu_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised name; utime and stime are the 14th and 15th.
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Analyses `log` with `model`; prints and returns (wall s, CPU s, the effects named).
fn timed(label: &str, model: &str, log: &hal_sim::runlog::RunLog) -> (f64, f64, Vec<String>) {
    let t = log.column("t_s").unwrap();
    let span = t.last().unwrap() - t.first().unwrap();
    let cpu0 = process_cpu_s();
    let started = Instant::now();
    let out =
        analyse(model, log, &GapOptions::default()).unwrap_or_else(|f| panic!("{}", f.message));
    let wall = started.elapsed().as_secs_f64();
    let cpu = match (cpu0, process_cpu_s()) {
        (Some(a), Some(b)) => b - a,
        _ => wall,
    };
    let found: Vec<String> = out.json.effects.iter().map(|e| e.name.clone()).collect();
    println!(
        "gap benchmark, {label}: {} rows, {span:.2} s of data analysed in {wall:.3} s wall, \
         {cpu:.2} s CPU (all threads); found {found:?}",
        log.len()
    );
    (wall, cpu, found)
}

/// The benchmark's two cases: a closed-loop run, and open ports with a restricted port.
#[derive(Clone, Copy)]
enum Case {
    ClosedLoop,
    OpenPorts,
}

/// Makes `case`'s 10 kHz log and analyses it: (wall s, CPU s, effects named).
fn run_case(case: Case) -> (f64, f64, Vec<String>) {
    let model = without_section(&reference(), "effects.cogging");
    match case {
        // Closed loop at full speed, cogging missing from the model.
        Case::ClosedLoop => {
            let log = decimate(&closed_loop(&reference(), 4.0, 45, 52), 2);
            timed("closed loop, 10 kHz", &model, &log)
        }
        // Open ports, a restricted port hidden as well.
        Case::OpenPorts => {
            let truth = format!(
                "{}\n[effects.port_restriction]\narea_scale = 0.5\n",
                reference()
            );
            let t = MachineModel::parse(&truth).unwrap();
            let stroke_period_s = std::f64::consts::PI * 0.1 / 2.3 * 2.0;
            let log = decimate(&open_port_run(&t, 3.1, 2.3, 10.0 / stroke_period_s, 51), 2);
            timed("open ports, 10 kHz", &model, &log)
        }
    }
}

#[test]
#[ignore = "benchmark: the limit holds in an optimised build; CI runs it for what gap finds"]
fn gap_analyses_10_s_at_10_khz_within_3_s() {
    // One analysis at a time, each timed by the whole process's CPU over it.
    let (_, closed_cpu, closed_found) = run_case(Case::ClosedLoop);
    let (_, open_cpu, open_found) = run_case(Case::OpenPorts);
    // What each case hides, found.
    assert!(
        closed_found.iter().any(|e| e == "cogging"),
        "closed loop: {closed_found:?}"
    );
    assert!(
        open_found.iter().any(|e| e == "port_restriction"),
        "open ports: {open_found:?}"
    );
    if cfg!(debug_assertions) {
        println!("a test build: the {LIMIT_S} s limit is checked in an optimised build");
        return;
    }
    assert!(
        closed_cpu <= LIMIT_S,
        "closed loop: {closed_cpu:.2} s CPU over {LIMIT_S} s"
    );
    // The open-port case is not the acceptance figure and sits near the limit: printed
    // against it, enforced only when FPC_GAP_STRICT is set.
    let verdict = if open_cpu <= LIMIT_S {
        "within"
    } else {
        "over"
    };
    println!("open ports: {open_cpu:.2} s CPU, {verdict} the {LIMIT_S} s limit");
    if std::env::var_os("FPC_GAP_STRICT").is_some() {
        assert!(
            open_cpu <= LIMIT_S,
            "open ports: {open_cpu:.2} s over {LIMIT_S} s"
        );
    }
}
