//! The log-analysis subcommands of `fpc-sim` (`lag`, `filters`, `forces`, `energy`, `pv`,
//! `decode`): each runs on a log from `fpc-sim run` and on a run log written by hand
//! (`tests/data/hand_stroke.csv`), writes its plot, and refuses a bad log with exit code 2
//! naming the line and column (`docs/faults.md` #18). On a simulator run, whose model is
//! exact, the figures they report are checked against what the laws give: the backward
//! difference half a sample late and its noise √2·σₓ/Δt (the paper's Eq. 5, 6), the
//! unfiltered m·a's noise m·√6·σₓ/Δt² (Fig. 8's ±10 kN), the filtered m·a against the
//! balance, and the works of a stroke closing (Fig. 9), σₓ measured from the log's third
//! differences.

use std::path::{Path, PathBuf};

use hal_sim::cli::analysis::{LogToolArgs, WindowArgs, ZeroPhaseArgs};
use hal_sim::cli::{
    decode as decode_cmd, energy as energy_cmd, filters as filters_cmd, forces as forces_cmd,
    lag as lag_cmd, pv as pv_cmd,
};
use hal_sim::failure::CmdResult;
use hal_sim::runlog::{RunLog, REQUIRED};

const HAND_LOG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/hand_stroke.csv");

/// A scratch directory of its own (tests run concurrently, from several checkouts), removed
/// when the test ends, pass or fail.
fn scratch(prefix: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc-{prefix}-"))
        .tempdir()
        .expect("scratch directory")
}

fn filter() -> ZeroPhaseArgs {
    ZeroPhaseArgs {
        cutoff_hz: 100.0,
        filter_order: 4,
    }
}

fn window() -> WindowArgs {
    WindowArgs {
        from_s: None,
        to_s: None,
    }
}

/// Runs every plotting analysis on `log` into `out` (`energy` on `stroke`, or by default the
/// last whole one); returns each result with its plot.
fn run_all(
    log: &Path,
    out: &Path,
    stroke: Option<usize>,
) -> Vec<(&'static str, CmdResult, PathBuf)> {
    let sg = fpc::control::config::ControlConfig::reference();
    vec![
        (
            "filters",
            filters_cmd::main(filters_cmd::FiltersArgs {
                io: LogToolArgs::new(log, out),
                column: "x_m".into(),
                filter: filter(),
                sg_window: sg.sg_window,
                sg_order: sg.sg_order,
                sg_lag: sg.sg_lag,
                drive_delay_ms: 8.5,
                window: window(),
            }),
            out.join("filters.svg"),
        ),
        (
            "forces",
            forces_cmd::main(forces_cmd::ForcesArgs {
                io: LogToolArgs::new(log, out),
                filter: filter(),
                window: window(),
            }),
            out.join("forces.svg"),
        ),
        (
            "energy",
            energy_cmd::main(energy_cmd::EnergyArgs {
                io: LogToolArgs::new(log, out),
                stroke,
                filter: filter(),
            }),
            out.join("energy.svg"),
        ),
        (
            "pv",
            pv_cmd::main(pv_cmd::PvArgs {
                io: LogToolArgs::new(log, out),
            }),
            out.join("pv.svg"),
        ),
        (
            "lag",
            lag_cmd::main(lag_cmd::LagArgs {
                measured: log.into(),
                a: "f_master_n".into(),
                b: "f_slave_n".into(),
                max_lag_s: None,
                json: true,
            }),
            // `lag` prints, it does not plot.
            PathBuf::new(),
        ),
    ]
}

fn assert_all_plot(log: &Path, out: &Path, stroke: Option<usize>) {
    for (name, result, plot) in run_all(log, out, stroke) {
        assert_eq!(result, Ok(()), "{name} on {}", log.display());
        if plot != PathBuf::new() {
            let svg = std::fs::read_to_string(&plot).unwrap();
            assert!(
                svg.contains("<svg") && svg.contains("polyline"),
                "{name}: {}",
                plot.display()
            );
        }
    }
}

#[test]
fn every_analysis_runs_on_the_hand_written_log() {
    // One cycle: both its strokes touch the log's ends, so `energy` refuses to pick one by
    // itself (naming `--stroke`) and plots the one it is told.
    let dir = scratch("hand");
    let dir = dir.path();
    let e = energy_cmd::main(energy_cmd::EnergyArgs {
        io: LogToolArgs::new(Path::new(HAND_LOG), dir),
        stroke: None,
        filter: filter(),
    })
    .unwrap_err();
    assert_eq!(e.code, 2);
    assert!(
        e.message.contains("no whole stroke") && e.message.contains("--stroke"),
        "{}",
        e.message
    );
    assert_all_plot(Path::new(HAND_LOG), dir, Some(1));
}

#[test]
fn every_analysis_runs_on_an_fpc_sim_run_log() {
    let outcome = hal_sim::run::run(&hal_sim::run::RunOptions {
        cycles: 2,
        ..hal_sim::run::RunOptions::reference()
    })
    .unwrap();
    let dir = scratch("sim");
    let dir = dir.path();
    let csv = dir.join("run.csv");
    outcome.log.write(&csv).unwrap();
    assert_all_plot(&csv, dir, None);
}

#[test]
fn bad_logs_are_refused_with_line_and_column() {
    let text = std::fs::read_to_string(HAND_LOG).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    // Line 20 of the file is a data row; its second field is x_m.
    let mut bad = lines.clone();
    let row: Vec<&str> = bad[19].split(',').collect();
    let broken = format!("{},abc,{}", row[0], row[2..].join(","));
    bad[19] = &broken;
    let dir = scratch("bad");
    let dir = dir.path();
    let path = dir.join("bad.csv");
    std::fs::write(&path, bad.join("\n")).unwrap();
    for (name, result, _) in run_all(&path, dir, None) {
        let failure = result.expect_err(name);
        assert_eq!(failure.code, 2, "{name}: {failure:?}");
        assert!(
            failure.message.contains("line 20") && failure.message.contains("`x_m`"),
            "{name}: {}",
            failure.message
        );
    }
}

/// A log whose slave force is the master force `delay_s` later: a stroke-like force
/// (fundamental at the stroke rate, harmonics from the dead-point reversals) plus ringing
/// like the paper's 400 Hz control-loop vibration — kept below a 25th of the sample rate,
/// where a parabola through three correlation samples still finds the sub-sample peak.
fn planted_lag_log(sample_rate_hz: f64, delay_s: f64, path: &Path) {
    let ringing_hz = (sample_rate_hz / 25.0).min(400.0);
    let force = |t: f64| {
        let w = 2.0 * std::f64::consts::PI * 2.9;
        1200.0 * (w * t).sin()
            + 400.0 * (3.0 * w * t + 0.4).sin()
            + 150.0 * (7.0 * w * t + 1.0).sin()
            + 60.0 * (2.0 * std::f64::consts::PI * ringing_hz * t).sin()
    };
    let mut log = RunLog::with_columns(&REQUIRED);
    let rows = (1.0 * sample_rate_hz) as usize;
    for i in 0..rows {
        let t = i as f64 / sample_rate_hz;
        log.push_row(&[t, 0.1, 0.1, 0.0, force(t), force(t - delay_s), 1e5, 1e5]);
    }
    log.write(path).unwrap();
}

#[test]
fn lag_finds_the_planted_slave_lag_of_0_75_ms() {
    let dir = scratch("lag");
    let dir = dir.path();
    // At the control rate (15 samples) and at 1 kHz, where 0.75 ms is under one sample.
    for rate in [20_000.0, 1_000.0] {
        let path = dir.join(format!("planted_{rate}.csv"));
        planted_lag_log(rate, 0.75e-3, &path);
        let log = RunLog::read(&path).unwrap();
        let r = lag_cmd::measure(&log, "f_master_n", "f_slave_n", None).unwrap();
        assert!((r.lag_s - 0.75e-3).abs() < 0.05e-3, "{rate} Hz: {r:?}");
        // And the other way round it leads.
        let r = lag_cmd::measure(&log, "f_slave_n", "f_master_n", None).unwrap();
        assert!((r.lag_s + 0.75e-3).abs() < 0.05e-3, "{rate} Hz: {r:?}");
    }
}

#[test]
fn lag_refuses_an_unknown_column_naming_the_flag() {
    let log = RunLog::read(Path::new(HAND_LOG)).unwrap();
    let e = lag_cmd::measure(&log, "f_master_n", "f_slav_n", None).unwrap_err();
    assert_eq!(e.code, 2);
    assert!(e.message.contains("--b f_slav_n"), "{}", e.message);
}

#[test]
fn decode_turns_a_capture_into_a_readable_run_log_and_refuses_garbage() {
    let outcome = hal_sim::run::run(&hal_sim::run::RunOptions {
        cycles: 1,
        telemetry_decimation: 10,
        ..hal_sim::run::RunOptions::reference()
    })
    .unwrap();
    let dir = scratch("decode");
    let dir = dir.path();
    let capture = dir.join("telemetry.bin");
    // A host that attached mid-frame and saw line noise first.
    let mut bytes = vec![0x55, 0x00, 0x13, 0x37];
    bytes.extend(&outcome.telemetry[7..]);
    std::fs::write(&capture, &bytes).unwrap();
    let out = dir.join("decoded.csv");
    decode_cmd::main(decode_cmd::DecodeArgs {
        capture: capture.clone(),
        out: out.clone(),
        force: false,
        accept_loss: false,
        recording: None,
        json: false,
    })
    .unwrap();
    let log = RunLog::read(&out).unwrap();
    assert_eq!(log.meta("telemetry_decimation"), Some("10"));
    assert_eq!(log.len(), outcome.log.len().div_ceil(10) - 1);

    std::fs::write(&capture, [0xAAu8; 300]).unwrap();
    let e = decode_cmd::main(decode_cmd::DecodeArgs {
        capture,
        out,
        force: true,
        accept_loss: false,
        recording: None,
        json: false,
    })
    .unwrap_err();
    assert_eq!(e.code, 2);
    assert!(e.message.contains("no telemetry frame"), "{}", e.message);
}

#[test]
fn pv_reports_the_work_per_cycle_that_run_reports() {
    // `run` integrates the plant's true pressures over its own volumes; `pv` has only the
    // log: the pressure sensors' readings and the volumes from the encoder's position. Both
    // report the work done on the gas, mean of the last five complete cycles.
    let outcome = hal_sim::run::run(&hal_sim::run::RunOptions {
        cycles: 7,
        ..hal_sim::run::RunOptions::reference()
    })
    .unwrap();
    let run_work = outcome.summary.indicated_work_j_per_cycle.unwrap();
    let dir = scratch("pv_work");
    let dir = dir.path();
    let figures = pv_cmd::plot_pv(
        &dir.join("pv.svg"),
        &outcome.log,
        &hal_sim::plant::model::MachineModel::reference(),
    )
    .unwrap();
    let pv_work = figures.indicated_work_j_per_cycle.unwrap();
    assert!(
        run_work > 0.0,
        "a compressor does work on its gas: {run_work} J"
    );
    assert!(
        (pv_work - run_work).abs() < 0.02 * run_work,
        "pv {pv_work:.2} J against run {run_work:.2} J per cycle"
    );
    assert!(figures.cycles >= 5, "{} complete cycles", figures.cycles);
}

/// A figure of `command`'s JSON (`<command>.json` beside its plot) at `path`, e.g.
/// `/estimates/1/delay_s`.
fn figure(dir: &Path, command: &str, path: &str) -> f64 {
    let file = dir.join(format!("{command}.json"));
    let text = std::fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let json: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    json.pointer(path)
        .and_then(serde_json::Value::as_f64)
        .unwrap_or_else(|| panic!("{command}.json has no number at {path}: {text}"))
}

/// The label of estimate `i` in `command`'s JSON.
fn label(dir: &Path, command: &str, i: usize) -> String {
    let text = std::fs::read_to_string(dir.join(format!("{command}.json"))).expect("JSON file");
    let json: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    json.pointer(&format!("/estimates/{i}/label"))
        .and_then(serde_json::Value::as_str)
        .unwrap_or_default()
        .to_string()
}

#[test]
fn on_a_simulator_run_the_analyses_report_what_the_laws_give() {
    let outcome = hal_sim::run::run(&hal_sim::run::RunOptions {
        cycles: 2,
        ..hal_sim::run::RunOptions::reference()
    })
    .unwrap();
    let dir = scratch("figures");
    let dir = dir.path();
    let csv = dir.join("run.csv");
    outcome.log.write(&csv).unwrap();
    for (name, result, _) in run_all(&csv, dir, None) {
        assert_eq!(result, Ok(()), "{name}");
    }
    let x = outcome.log.column("x_m").unwrap();
    let dt = outcome.log.sample_time_s().unwrap();
    let m = hal_sim::plant::model::MachineModel::reference()
        .piston
        .mass_kg;
    // The encoder's noise from the log itself: the third difference of white noise has
    // variance 20·σ², and the strokes' own third difference (jerk·Δt³ ≈ 1e-9 m) is far below it.
    let d3: Vec<f64> = x
        .windows(4)
        .map(|w| w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0])
        .collect();
    let sigma_x = (d3.iter().map(|d| d * d).sum::<f64>() / d3.len() as f64 / 20.0).sqrt();

    // `filters`: estimate 1 is the backward difference (Eq. 5), 2 the firmware's
    // Savitzky–Golay, 3 the drive's reading.
    assert!(label(dir, "filters", 1).contains("backward difference"));
    let backward_delay = figure(dir, "filters", "/estimates/1/delay_s");
    let backward_noise = figure(dir, "filters", "/estimates/1/rms_diff_mps");
    let sg_delay = figure(dir, "filters", "/estimates/2/delay_s");
    let drive_delay = figure(dir, "filters", "/estimates/3/delay_s");
    let eq6 = 2f64.sqrt() * sigma_x / dt;
    println!(
        "σx {:.3} µm; backward difference {:.4} ms late (Δt/2 = {:.4} ms), noise {backward_noise:.4} \
         m/s (Eq. 6: {eq6:.4} m/s); Savitzky–Golay {:.4} ms; drive reading {:.3} ms",
        sigma_x * 1e6,
        backward_delay * 1e3,
        0.5 * dt * 1e3,
        sg_delay * 1e3,
        drive_delay * 1e3
    );
    // Half a sample late, to 5 % of a sample (the cross-correlation's parabola resolves it to
    // 0.02 % here); a filter twice as late is a whole sample.
    assert!(
        (backward_delay - 0.5 * dt).abs() < 0.05 * dt,
        "{backward_delay} s"
    );
    // Eq. 6: the difference of two noisy samples; margin 3 % (0.3 % measured: the signal's
    // own error and the noise's colour).
    assert!(
        (backward_noise / eq6 - 1.0).abs() < 0.03,
        "{backward_noise} vs {eq6}"
    );
    // The firmware's differentiator evaluated at its newest sample's lag 0: on time to a
    // tenth of a sample.
    assert!(sg_delay.abs() < 0.1 * dt, "{sg_delay} s");
    // The drive reading is the reference delayed by --drive-delay-ms (a read-back of the
    // flag, 8.5 ms): the cross-correlation finds it to 1 %.
    assert!((drive_delay - 8.5e-3).abs() < 0.085e-3, "{drive_delay} s");

    // `forces`: estimate 0 is m·a from the unfiltered position, 1 from the zero-phase
    // filtered one.
    assert!(label(dir, "forces", 0).contains("unfiltered"));
    let peak = figure(dir, "forces", "/peak_expected_n");
    let raw_rms = figure(dir, "forces", "/estimates/0/rms_vs_expected_n");
    let filtered_rms = figure(dir, "forces", "/estimates/1/rms_vs_expected_n");
    let filtered_delay = figure(dir, "forces", "/estimates/1/delay_s");
    let second_difference_noise = m * 6f64.sqrt() * sigma_x / (dt * dt);
    println!(
        "forces: peak expected {peak:.0} N; unfiltered m·a {raw_rms:.0} N RMS off (m·√6·σx/Δt² = \
         {second_difference_noise:.0} N); filtered {filtered_rms:.1} N RMS off, {:.3} ms",
        filtered_delay * 1e3
    );
    // A second difference of noisy samples: margin 3 % (0.03 % measured).
    assert!(
        (raw_rms / second_difference_noise - 1.0).abs() < 0.03,
        "{raw_rms} vs {second_difference_noise}"
    );
    // The filtered estimate follows the balance the model gives (the model is the plant's):
    // within 10 % of the peak force (7.6 % measured: the 100 Hz filter rounds the dead
    // points), on time to two samples (zero phase).
    assert!(filtered_rms < 0.1 * peak, "{filtered_rms} N of {peak} N");
    assert!(filtered_delay.abs() <= 2.0 * dt, "{filtered_delay} s");

    // `energy`: the last complete stroke, dead point to dead point.
    let motor = figure(dir, "energy", "/motor_j");
    let gas = figure(dir, "energy", "/gas_j");
    let cogging = figure(dir, "energy", "/cogging_j");
    let friction = figure(dir, "energy", "/friction_j");
    let inertia = figure(dir, "energy", "/inertia_j");
    let balance = figure(dir, "energy", "/balance_j");
    let kinetic = figure(dir, "energy", "/peak_kinetic_j");
    println!(
        "energy: motor {motor:.2} J, gas {gas:.2} J, cogging {cogging:.3} J, friction \
         {friction:.2} J, inertia {inertia:.5} J, balance {balance:.3} J; peak kinetic {kinetic:.2} J"
    );
    // The balance is the sum of the works (the trapezoid rule is linear) …
    assert!(
        (motor + gas + cogging - friction - inertia - balance).abs() < 1e-9 * motor.abs(),
        "the works do not add up"
    );
    // … and it closes: within 0.25 % of the motor's work (0.07 % measured). A gas force or a
    // friction 1 % off leaves 1.6 J or 0.16 J.
    assert!(
        balance.abs() < 2.5e-3 * motor.abs(),
        "{balance} J of {motor} J"
    );
    // From rest to rest the piston's kinetic energy comes back: a thousandth of its peak.
    assert!(inertia.abs() < 1e-3 * kinetic, "{inertia} J");
    // The peak kinetic energy is ½·m·v² of the run's peak speed, to 2 %.
    let v = outcome.log.column("v_mps").unwrap();
    let v_peak = v.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(
        (kinetic / (0.5 * m * v_peak * v_peak) - 1.0).abs() < 0.02,
        "{kinetic} J at {v_peak} m/s"
    );
}
