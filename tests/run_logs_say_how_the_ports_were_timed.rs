//! `fpc-sim run` logs carry the metadata the pressure replay needs (`docs/formats.md` §1 keys,
//! extended compatibly): `# ports = open` from `# ports_from_s` (when the start-up bypass
//! closed; before it both chambers breathe to the suction line) and `# theta_source =
//! servo_encoder` (the logged angle is the servo's count; the piston follows through the
//! spline's play). The streamed CSV carries the same head as the log `run` returns, although
//! the bypass closes only after homing, seconds into the run.

use hal_sim::run::{run, run_streamed, RunOptions};
use hal_sim::runlog::RunLog;

fn check_head(log: &RunLog, end_s: f64) -> f64 {
    assert_eq!(log.meta("ports"), Some("open"));
    assert_eq!(log.meta("theta_source"), Some("servo_encoder"));
    let from: f64 = log
        .meta("ports_from_s")
        .and_then(|v| v.parse().ok())
        .expect("ports_from_s is a time");
    // The bypass closes once homing is done: after the start, well before the end.
    assert!(
        from > 0.1 && from < end_s - 0.5,
        "ports_from_s {from} of {end_s} s"
    );
    from
}

#[test]
fn the_run_log_says_how_its_ports_were_timed_streamed_or_not() {
    let opts = RunOptions {
        cycles: 2,
        seed: 7,
        ..RunOptions::reference()
    };
    let kept = run(&opts).expect("the run completes");
    let end_s = kept
        .log
        .column("t_s")
        .and_then(|t| t.last().copied())
        .unwrap_or(0.0);
    let from = check_head(&kept.log, end_s);
    // The rotation's reference first moves within a few control periods after the bypass
    // closed (the start command goes out in the cycle it closes).
    let t = kept.log.column("t_s").unwrap_or_default();
    let theta_ref = kept.log.column("theta_ref_rad").unwrap_or_default();
    let first = theta_ref
        .iter()
        .position(|v| *v != 0.0)
        .expect("the rotation starts");
    assert!(
        t[first] > from && t[first] - from < 1e-3,
        "rotation from {} s, ports from {from} s",
        t[first]
    );

    let mut csv = Vec::new();
    run_streamed(&opts, &mut csv).expect("the streamed run completes");
    let text = String::from_utf8(csv).expect("UTF-8");
    let streamed = RunLog::parse(&text).expect("the streamed log reads back");
    assert_eq!(check_head(&streamed, end_s), from);
    assert_eq!(streamed.meta, kept.log.meta, "one head, streamed or kept");
}
