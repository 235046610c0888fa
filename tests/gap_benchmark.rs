//! The model-gap workflow's speed: 10 s of data at 10 kHz analysed in ≤ 3 s. Run in release
//! (`cargo test --workspace --release -- --ignored gap_analyses`, as CI does with
//! `--ignored`); it prints the wall and CPU time. Two cases: a closed-loop run with the
//! firmware in the loop (force, slave-force and encoder channels: the acceptance figure) and
//! an open-port compressor run (every channel; each pressure candidate replays the chambers
//! some twenty times). The limit is checked on the analysing thread's CPU time, because the
//! build machine is shared and its wall time is not this program's alone; the open-port
//! case only with `FPC_GAP_STRICT` set (it runs close to the limit, and CPU time on a shared
//! machine still varies by ±10 %). The cases go through the studies' own runner
//! (`hal_sim::sweep::run_each`), side by side over the cores; each analysis is timed on the
//! thread that ran it.

mod support;

use std::time::Instant;

use hal_sim::gap::synth::{decimate, open_port_run};
use hal_sim::gap::{analyse, GapOptions};
use hal_sim::plant::model::MachineModel;
use support::gap::*;

/// The limit of the acceptance, s.
const LIMIT_S: f64 = 3.0;

/// CPU time of this thread, s (Linux: utime + stime of `/proc/thread-self/stat`, 10 ms
/// ticks); `None` elsewhere.
fn thread_cpu_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
    // Fields after the parenthesised name; utime and stime are the 14th and 15th.
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Analyses `log` with `model`; prints and returns (wall, CPU) seconds.
fn timed(label: &str, model: &str, log: &hal_sim::runlog::RunLog) -> (f64, f64) {
    let t = log.column("t_s").unwrap();
    let span = t.last().unwrap() - t.first().unwrap();
    let cpu0 = thread_cpu_s();
    let started = Instant::now();
    let out =
        analyse(model, log, &GapOptions::default()).unwrap_or_else(|f| panic!("{}", f.message));
    let wall = started.elapsed().as_secs_f64();
    let cpu = match (cpu0, thread_cpu_s()) {
        (Some(a), Some(b)) => b - a,
        _ => wall,
    };
    let found: Vec<&str> = out.json.effects.iter().map(|e| e.name.as_str()).collect();
    println!(
        "gap benchmark, {label}: {} rows, {span:.2} s of data analysed in {wall:.3} s wall, \
         {cpu:.2} s CPU; found {found:?}",
        log.len()
    );
    (wall, cpu)
}

/// The benchmark's two cases: a closed-loop run, and open ports with a restricted port.
#[derive(Clone, Copy)]
enum Case {
    ClosedLoop,
    OpenPorts,
}

/// Makes `case`'s 10 kHz log and analyses it: (wall, CPU) seconds of the analysis.
fn run_case(case: Case) -> (f64, f64) {
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
#[ignore = "benchmark: run in release"]
fn gap_analyses_10_s_at_10_khz_within_3_s() {
    // Through the studies' own runner (`hal_sim::sweep::run_each`, as `fpc-sim sweep` and
    // the fault sweep): the cases run side by side over the cores, and each analysis is
    // timed on the CPU time of the thread that ran it.
    let times = hal_sim::sweep::run_each(
        &[Case::ClosedLoop, Case::OpenPorts],
        |&c| run_case(c),
        &|_| {},
    );
    let [(_, closed_cpu), (_, open_cpu)] = times[..] else {
        panic!("two cases, two results: {times:?}");
    };

    assert!(
        closed_cpu <= LIMIT_S,
        "closed loop: {closed_cpu:.2} s over {LIMIT_S} s"
    );
    // The open-port case is not the acceptance figure and sits near the limit (2.6–3.1 s
    // CPU seen on the shared build machine): printed against it, enforced only when
    // FPC_GAP_STRICT is set, so machine noise cannot fail CI.
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
