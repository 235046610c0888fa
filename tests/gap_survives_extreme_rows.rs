//! The model-gap workflow on logs with extreme but finite values (issue #18): the library
//! (`hal_sim::gap::analyse`, called in-process, so the log reader's own checks do not
//! shield it) returns Ok or a named bad-input error (exit 2) — never a panic inside a
//! least-squares solve or an FFT, never a hang whose cost follows the log's duration.
//!
//! `cargo test --release --test gap_survives_extreme_rows` (`PROPTEST_CASES` to change the
//! property's case count, 256 by default).

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use hal_sim::gap::data::Measured;
use hal_sim::gap::fit::lstsq;
use hal_sim::gap::replay::replay_pressures;
use hal_sim::gap::{analyse, GapOptions};
use hal_sim::plant::model::{MachineModel, REFERENCE_TOML};
use hal_sim::runlog::RunLog;
use hal_sim::signal::xcorr_lag;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};

/// A simulated run of one cycle at 2.5 kHz with closed ports (the gap workflow wants
/// ≥ 2 kHz), made once.
fn base_log() -> &'static RunLog {
    static LOG: OnceLock<RunLog> = OnceLock::new();
    LOG.get_or_init(|| {
        let opts = hal_sim::run::RunOptions {
            cycles: 1,
            ..hal_sim::run::RunOptions::reference()
        };
        let mut log = hal_sim::run::run(&opts).expect("reference run").log;
        for c in &mut log.columns {
            *c = c.iter().step_by(8).copied().collect();
        }
        log.meta
            .retain(|(k, _)| k != "sample_rate_hz" && k != "ports");
        log.meta.push(("ports".into(), "closed".into()));
        log
    })
}

fn col_index(log: &RunLog, name: &str) -> usize {
    log.names
        .iter()
        .position(|n| n == name)
        .unwrap_or_else(|| panic!("column {name}"))
}

/// `log` with `column` set to `value` at data row `row` (0-based).
fn with_value(log: &RunLog, column: &str, row: usize, value: f64) -> RunLog {
    let mut out = log.clone();
    let c = col_index(&out, column);
    out.columns[c][row] = value;
    out
}

/// The workflow on `log`: the exit code it maps to (0 for Ok) and the message.
fn gap_code(log: &RunLog) -> (u8, String) {
    match analyse(REFERENCE_TOML, log, &GapOptions::default()) {
        Ok(_) => (0, String::new()),
        Err(f) => (f.code, f.message),
    }
}

#[test]
fn one_huge_finite_value_is_refused_naming_its_column_and_row() {
    let base = base_log();
    let row = base.len() / 2;
    for (column, value) in [
        ("theta_rad", 1e300),
        ("theta_rad", -1e20),
        ("x_m", 1e20),
        ("t_s", 1e20),
        ("p_suction_pa", 1e300),
        ("f_master_n", f64::NAN),
        ("p_a_pa", f64::INFINITY),
    ] {
        if !base.names.iter().any(|n| n == column) {
            continue;
        }
        let start = Instant::now();
        let (code, message) = gap_code(&with_value(base, column, row, value));
        assert_eq!(code, 2, "{column} = {value}: {message}");
        assert!(
            message.contains(column) && message.contains(&format!("row {}", row + 1)),
            "{column} = {value}: {message}"
        );
        assert!(start.elapsed() < Duration::from_secs(10), "{column}");
    }
}

#[test]
fn an_uneven_time_column_is_refused_naming_the_row() {
    let base = base_log();
    let row = 100;
    let t = base.column("t_s").expect("t_s")[row];
    let (code, message) = gap_code(&with_value(base, "t_s", row, t + 0.7 * 4e-4));
    assert_eq!(code, 2, "{message}");
    assert!(
        message.contains("t_s") && message.contains("row"),
        "{message}"
    );
}

#[test]
fn the_chamber_replay_costs_rows_not_duration() {
    // A 400-row sealed log whose sample time is then made 10⁶ s: before, the replay took
    // ⌈dt / 50 µs⌉ sub-steps per row (2·10¹⁰ here: a hang).
    let mut log = base_log().clone();
    for c in &mut log.columns {
        c.truncate(400);
    }
    let model = MachineModel::parse(REFERENCE_TOML).expect("reference model");
    let mut measured = Measured::from_log(&log, model.encoder.period_m).expect("valid log");
    for dt in [1.0, 1e6] {
        measured.dt_s = dt;
        let start = Instant::now();
        let _ = replay_pressures(&measured, &model);
        assert!(
            start.elapsed() < Duration::from_secs(5),
            "dt {dt} s: {:?}",
            start.elapsed()
        );
    }
}

#[test]
fn the_solvers_refuse_values_whose_squares_overflow() {
    let n = 50u32;
    let ones = vec![1.0; n as usize];
    let mut big: Vec<f64> = (0..n).map(f64::from).collect();
    big[7] = 1e200;
    assert!(lstsq(&[ones.clone(), big.clone()], &ones).is_none());
    let mut nan = ones.clone();
    nan[3] = f64::NAN;
    assert!(lstsq(std::slice::from_ref(&ones), &nan).is_none());
    let x: Vec<f64> = (0..200).map(|i| (f64::from(i) * 0.1).sin()).collect();
    let mut y = x.clone();
    y[50] = f64::INFINITY;
    let e = xcorr_lag(&x, &y, 1e-3, None).expect_err("non-finite input");
    assert!(e.contains("sample 51"), "{e}");
    y[50] = 1e300;
    assert!(xcorr_lag(&x, &y, 1e-3, None).is_err());
}

/// Values a row is given by the property.
fn extreme() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(1e20),
        Just(-1e20),
        Just(1e300),
        Just(-1e300),
        Just(1e-300),
        Just(f64::MAX),
        Just(f64::MIN_POSITIVE),
        Just(0.0),
        -1e3f64..1e3,
    ]
}

#[test]
fn extreme_rows_never_panic_the_workflow() {
    let base = base_log();
    let names = base.names.clone();
    let rows = base.len();
    let cases = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(256);
    let mut runner = TestRunner::new_with_rng(
        Config {
            cases,
            failure_persistence: None,
            ..Config::default()
        },
        TestRng::from_seed(RngAlgorithm::ChaCha, &[18; 32]),
    );
    let strategy = (
        proptest::collection::vec((0..names.len(), 0..rows, extreme()), 1..4),
        prop_oneof![Just(1.0), Just(1e-9), Just(1e3), Just(1e6)],
    );
    runner
        .run(&strategy, |(edits, time_scale)| {
            let mut log = base.clone();
            for (c, r, v) in &edits {
                log.columns[*c][*r] = *v;
            }
            if time_scale != 1.0 {
                let t = col_index(&log, "t_s");
                log.columns[t].iter_mut().for_each(|v| *v *= time_scale);
            }
            let start = Instant::now();
            let outcome = std::panic::catch_unwind(|| gap_code(&log));
            let (code, message) = match outcome {
                Ok(r) => r,
                Err(_) => return Err(TestCaseError::fail(format!("panic on {edits:?}"))),
            };
            prop_assert!(code == 0 || code == 2, "exit {code}: {message}");
            if code == 2 {
                prop_assert!(
                    message.contains("column") || message.contains("row"),
                    "unnamed cause: {message}"
                );
            }
            prop_assert!(
                start.elapsed() < Duration::from_secs(20),
                "{:?} on {edits:?}",
                start.elapsed()
            );
            Ok(())
        })
        .unwrap_or_else(|e| panic!("{e}"));
}
