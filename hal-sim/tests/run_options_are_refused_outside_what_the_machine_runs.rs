//! `fpc-sim run`'s options (`docs/faults.md` row 23): a pressure ratio, speed, cycle count or fault
//! the machine cannot run is refused before any work (exit 2, naming the flag and the range),
//! and a run that stalls or stops early ends soon and says why.

use std::process::Command;

use hal_sim::faults::inject::parse;
use hal_sim::run::{RunOptions, CYCLES_RANGE, PRESSURE_RATIO_RANGE, SPEED_RANGE_MPS};
use tempfile::TempDir;

fn options(pressure_ratio: f64, speed_mps: Option<f64>, cycles: u32) -> RunOptions {
    RunOptions {
        pressure_ratio,
        speed_mps,
        cycles,
        ..RunOptions::reference()
    }
}

#[test]
fn pressure_ratios_speeds_and_cycles_outside_their_ranges_are_refused_naming_the_flag() {
    let (lo, hi) = PRESSURE_RATIO_RANGE;
    for pr in [1.0, 1.01, 1.1, 1.4, lo - 1e-9, hi + 0.1, f64::NAN, 1e300] {
        let e = options(pr, Some(2.0), 3).validate().unwrap_err();
        assert!(
            e.contains("--pressure-ratio") && e.contains(&format!("[{lo}, {hi}]")),
            "{pr}: {e}"
        );
        assert!(e.len() < 300, "{e}");
    }
    let (lo, hi) = SPEED_RANGE_MPS;
    for v in [0.0, -1.0, lo / 2.0, hi + 0.1, f64::INFINITY, 1e300] {
        let e = options(3.1, Some(v), 3).validate().unwrap_err();
        assert!(e.contains("--speed") && e.len() < 300, "{v}: {e}");
    }
    for c in [0, CYCLES_RANGE.1 + 1, u32::MAX] {
        let e = options(3.1, None, c).validate().unwrap_err();
        assert!(e.contains("--cycles") && e.contains("10000"), "{c}: {e}");
    }
    for ok in [
        options(PRESSURE_RATIO_RANGE.0, Some(SPEED_RANGE_MPS.1), 1),
        options(
            PRESSURE_RATIO_RANGE.1,
            Some(SPEED_RANGE_MPS.0),
            CYCLES_RANGE.1,
        ),
        options(5.1, None, 10),
    ] {
        ok.validate().unwrap();
    }
}

#[test]
fn a_speed_above_the_models_limit_or_a_discharge_beyond_the_sensors_is_refused() {
    let mut o = options(3.1, Some(4.0), 3);
    o.model.limits.max_speed_mps = 3.0;
    let e = o.validate().unwrap_err();
    assert!(
        e.contains("--speed") && e.contains("limits.max_speed_mps"),
        "{e}"
    );
    // Without --speed, the ratio's Fig. 3 speed is checked the same way.
    let mut o = options(5.1, None, 3);
    o.model.limits.max_speed_mps = 3.0;
    let e = o.validate().unwrap_err();
    assert!(
        e.contains("--pressure-ratio") && e.contains("limits.max_speed_mps"),
        "{e}"
    );
    let mut o = options(6.0, None, 3);
    o.model.lines.suction_pa = 2.0e5;
    let e = o.validate().unwrap_err();
    assert!(
        e.contains("lines.suction_pa") && e.contains("full scale"),
        "{e}"
    );
}

#[test]
fn a_fault_later_than_the_run_can_last_and_malformed_counts_are_refused() {
    let mut o = options(3.1, None, 3);
    o.faults = vec![parse("load_step@1e300").unwrap()];
    let e = o.validate().unwrap_err();
    assert!(
        e.contains("load_step@1e300") && e.contains("never be injected"),
        "{e}"
    );
    o.faults = vec![parse("load_step@1").unwrap()];
    o.validate().unwrap();
    for (spec, want) in [
        ("overrun@1:cycles=2.5", "whole number"),
        ("overrun@1:cycles=3,cycles=4", "given twice"),
        ("section_loss@1:section=1.5", "section"),
        ("overrun@1:nope=1", "cycles"),
    ] {
        let e = parse(spec).unwrap_err().0;
        assert!(e.contains(want), "{spec}: {e}");
    }
    let long = format!("{}@1", "x".repeat(10_000));
    let e = parse(&long).unwrap_err().0;
    assert!(
        e.len() < 600,
        "the spec is echoed in full: {} chars",
        e.len()
    );
}

/// A scratch directory removed when the test is done with it (a kept partial run's log is
/// tens of megabytes).
fn dir(name: &str) -> TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc_run_options_{name}_"))
        .tempdir()
        .unwrap()
}

/// Runs `fpc-sim run ARGS --out DIR/out`: (exit code, stderr, stdout).
fn fpc_sim(d: &std::path::Path, args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_fpc-sim"))
        .arg("run")
        .args(args)
        .arg("--out")
        .arg(d.join("out"))
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

#[test]
fn bad_flags_exit_2_with_one_line_and_write_nothing() {
    let scratch = dir("flags");
    let d = scratch.path();
    for args in [
        &["--pressure-ratio", "1"][..],
        &["--pressure-ratio", "1.01"],
        &["--speed", "1e300"],
        &["--cycles", "0"],
        &["--fault", "overrun@1:cycles=2.5"],
        &["--fault", "load_step@99999", "--cycles", "2"],
    ] {
        let (code, err, _) = fpc_sim(d, args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(args[0]), "{args:?}: {err}");
        assert!(!err.contains("00000000000"), "{args:?}: {err}");
        assert!(!d.join("out").exists(), "{args:?} wrote its outputs");
    }
}

#[test]
fn a_stalled_homing_ends_soon_saying_so_and_the_lowest_ratio_runs_at_top_speed() {
    let scratch = dir("stall");
    let d = scratch.path();
    // A 1.2 V bus cannot drive the piston to its stop: homing never ends. With 10 000
    // cycles asked, the whole run's limit is hours of simulated time; homing's own limit
    // ends it. (The supply's thresholds follow the bus down, in the order the model
    // requires.)
    let model = d.join("weak.toml");
    let text = hal_sim::plant::model::REFERENCE_TOML
        .replacen("bus_voltage_v = 560.0", "bus_voltage_v = 1.2", 1)
        .replacen(
            "power_good_voltage_v = 500.0",
            "power_good_voltage_v = 1.1",
            1,
        )
        .replacen(
            "logic_dropout_voltage_v = 150.0",
            "logic_dropout_voltage_v = 1.0",
            1,
        );
    std::fs::write(&model, text).unwrap();
    let started = std::time::Instant::now();
    let (code, err, out) = fpc_sim(
        d,
        &[
            "--model",
            model.to_str().unwrap(),
            "--cycles",
            "10000",
            "--json",
        ],
    );
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("no progress: homing"), "{err}");
    assert!(out.contains("\"cycles_requested\": 10000"), "{out}");
    assert!(started.elapsed().as_secs() < 30, "{:?}", started.elapsed());
    // A failed run leaves nothing, unless asked to keep its files (still exit 1).
    assert!(
        !d.join("out").join("run.csv").exists(),
        "a failed run wrote run.csv"
    );
    let (code, err, _) = fpc_sim(
        d,
        &[
            "--model",
            model.to_str().unwrap(),
            "--cycles",
            "2",
            "--keep-partial",
        ],
    );
    assert_eq!(code, 1, "{err}");
    assert!(d.join("out").join("run.csv").is_file(), "{err}");

    // A fault the run ends before is reported, and the run writes nothing.
    let scratch = dir("late");
    let d = scratch.path();
    let (code, err, out) = fpc_sim(d, &["--cycles", "1", "--fault", "load_step@3", "--json"]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("load_step@3") && err.contains("never injected"),
        "{err}"
    );
    assert!(!d.join("out").join("run.csv").exists(), "{err}");
    assert!(
        out.contains("\"faults_not_injected\": [\n    \"load_step@3\""),
        "{out}"
    );

    let scratch = dir("lowest");
    let d = scratch.path();
    let (code, err, out) = fpc_sim(
        d,
        &[
            "--pressure-ratio",
            &PRESSURE_RATIO_RANGE.0.to_string(),
            "--speed",
            &SPEED_RANGE_MPS.1.to_string(),
            "--cycles",
            "10",
            "--json",
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("\"stopped_early\": null"), "{out}");
}

/// The firmware strokes between this model's dead points (target clearance from each head
/// of its travel), not the reference machine's: a 0.2 m travel latched braking_envelope and
/// a 0.3 m one stopped 95 mm short.
#[test]
fn a_model_with_another_travel_or_clearance_runs_to_its_own_dead_points() {
    for (travel, clearance) in [(0.19, 1e-3), (0.3, 1e-3), (0.205, 2e-3)] {
        let mut o = options(3.1, Some(2.0), 2);
        o.model.piston.travel_m = travel;
        o.model.limits.target_head_clearance_m = clearance;
        let s = hal_sim::run::run(&o).unwrap().summary;
        assert_eq!(s.stopped_early, None, "travel {travel}: {s:?}");
        let err = s.dead_point_error_m.unwrap();
        assert!(err < 0.2e-3, "travel {travel}: dead-point error {err}");
        let min = s.min_head_clearance_m.unwrap();
        assert!(
            (min - clearance).abs() < 0.2e-3,
            "travel {travel}: min clearance {min}"
        );
    }
}

#[test]
fn volume_ratio_modes_and_log_rates_are_refused_naming_the_flag() {
    use fpc::motion::volume_ratio::RatioTarget;
    use hal_sim::run::{parse_volume_ratio, CONTROL_RATE_HZ, FIXED_RATIO_RANGE};
    assert_eq!(
        parse_volume_ratio("adaptive"),
        Ok(RatioTarget::FollowMeasured)
    );
    assert_eq!(
        parse_volume_ratio("fixed:4.3"),
        Ok(RatioTarget::Fixed {
            pressure_ratio: 4.3
        })
    );
    let (lo, hi) = FIXED_RATIO_RANGE;
    for bad in [
        "",
        "fixed",
        "fixed:",
        "fixed:1",
        "fixed:0.5",
        "fixed:nan",
        "fixed:11",
        "adaptiv",
        "fixed:3.1x",
        "FIXED:3",
    ] {
        let e = parse_volume_ratio(bad).unwrap_err();
        assert!(e.starts_with("--volume-ratio"), "{bad}: {e}");
        if bad.starts_with("fixed:") {
            assert!(e.contains(&format!("[{lo}, {hi}]")), "{bad}: {e}");
        }
    }
    for rate in [0, 3000, 7, CONTROL_RATE_HZ + 1, 40_000, u32::MAX] {
        let o = RunOptions {
            log_rate_hz: rate,
            ..RunOptions::reference()
        };
        let e = o.validate().unwrap_err();
        assert!(
            e.contains("--log-rate") && e.contains("20000"),
            "{rate}: {e}"
        );
    }
    for rate in [CONTROL_RATE_HZ, 10_000, 1_000, 1] {
        RunOptions {
            log_rate_hz: rate,
            ..RunOptions::reference()
        }
        .validate()
        .unwrap();
    }
}

#[test]
fn a_log_at_a_lower_rate_holds_every_nth_row_of_the_full_rate_log() {
    use hal_sim::run::run_streamed;
    let full = RunOptions {
        cycles: 2,
        ..RunOptions::reference()
    };
    let half = RunOptions {
        log_rate_hz: 10_000,
        ..full.clone()
    };
    let (mut a, mut b) = (Vec::new(), Vec::new());
    run_streamed(&full, &mut a).unwrap();
    run_streamed(&half, &mut b).unwrap();
    let (a, b) = (String::from_utf8(a).unwrap(), String::from_utf8(b).unwrap());
    let rows = |t: &str| -> Vec<String> {
        t.lines()
            .filter(|l| !l.starts_with('#'))
            .map(str::to_string)
            .collect()
    };
    let (ra, rb) = (rows(&a), rows(&b));
    assert_eq!(ra.first(), rb.first(), "the column names differ");
    // Row k of the 10 kHz log is row 2k+1 of the 20 kHz one (both start at t = 1 period).
    let every_other: Vec<&String> = ra.iter().skip(1).skip(1).step_by(2).collect();
    assert_eq!(rb.len() - 1, every_other.len());
    assert!(rb.iter().skip(1).zip(every_other).all(|(x, y)| x == y));
    assert!(b.contains("# sample_rate_hz = 10000"), "{b:.300}");
    assert!(a.contains("# sample_rate_hz = 20000"), "{a:.300}");
}

#[test]
fn the_published_controller_refuses_what_its_drives_lack_and_bad_closed_port_tests() {
    use hal_sim::plant::model::MachineModel;
    use hal_sim::run::closed::ClosedPort;
    use hal_sim::run::Controller;
    assert!(Controller::parse("ours").is_ok() && Controller::parse("published").is_ok());
    let e = Controller::parse("pid").unwrap_err();
    assert!(e.contains("--controller pid"), "{e}");
    let published = || RunOptions {
        controller: Controller::Published,
        ..options(3.1, None, 2)
    };
    published().validate().unwrap();
    let mut o = published();
    o.faults = vec![parse("load_step@1.0").unwrap()];
    assert!(o.validate().unwrap_err().contains("--fault"));
    let mut o = published();
    o.model.motor.slave_follows_master = true;
    assert!(o
        .validate()
        .unwrap_err()
        .contains("motor.slave_follows_master"));
    // The closed-port test: the published drives only, a stop compressing chamber B.
    let test = |stop_m, hold_s| Some(ClosedPort { stop_m, hold_s });
    let mut o = options(3.1, None, 2);
    o.closed_port = test(0.17, 1.0);
    assert!(o.validate().unwrap_err().contains("--controller published"));
    for (stop, hold, flag) in [
        (0.05, 1.0, "--closed-port"),
        (0.2045, 1.0, "--closed-port"),
        (f64::NAN, 1.0, "--closed-port"),
        (0.17, 0.0, "--hold"),
        (0.17, 100.0, "--hold"),
    ] {
        let mut o = published();
        o.closed_port = test(stop, hold);
        let e = o.validate().unwrap_err();
        assert!(e.contains(flag), "{stop} {hold}: {e}");
    }
    let mut o = published();
    o.closed_port = test(0.17, 2.0);
    o.validate().unwrap();
    // A drive cycle that is not a whole number of the simulator's periods is refused.
    let text = format!(
        "{}\n",
        hal_sim::plant::model::REFERENCE_TOML.replace("cycle_s = 1.0e-4", "cycle_s = 1.2e-4")
    );
    let e = MachineModel::parse(&text).unwrap_err().0;
    assert!(e.contains("published.cycle_s"), "{e}");
}
