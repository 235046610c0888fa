//! The analysis tools' flags (issue #18): a value out of range is exit 2 with one line that
//! names the one flag at fault and the range it accepts — no `--sg-*` or
//! `--cutoff-hz/--filter-order` guesswork, no Rust debug dump, and no value silently taken
//! (a drive delay of 10²⁰ ms plotted as if it meant something).
//!
//! `cargo test --release --test gap_and_log_tools_name_bad_flags`

use std::time::{Duration, Instant};

use hal_sim::cli::execute;

/// A scratch directory of its own (tests run concurrently, from several checkouts), removed
/// when the test ends, pass or fail.
fn scratch(prefix: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc-{prefix}-"))
        .tempdir()
        .expect("scratch directory")
}

/// The test log: a hand-written 400-row stroke at 1 kHz.
fn log() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/hand_stroke.csv").to_string()
}

#[test]
fn filters_name_the_one_flag_at_fault_and_its_range() {
    let dir = scratch("filters");
    let dir = dir.path();
    let out = dir.join("out").display().to_string();
    for (flag, value, range) in [
        ("--sg-window", "0", "3..=41"),
        ("--sg-window", "4", "3..=41"),
        ("--sg-order", "9", "1..=4"),
        ("--sg-lag", "99", "less than the window"),
        ("--drive-delay-ms", "1e20", "0..=1000"),
        ("--drive-delay-ms", "-1", "0..=1000"),
        ("--cutoff-hz", "600", "500 Hz"),
        ("--cutoff-hz", "NaN", "500 Hz"),
        ("--filter-order", "3", "2..=12"),
        ("--column", "t_s", "not a position in metres"),
        ("--column", "p_a_pa", "x_m, x_slave_m"),
    ] {
        let start = Instant::now();
        let args = [
            "fpc-sim".to_string(),
            "filters".into(),
            "--measured".into(),
            log(),
            "--out".into(),
            out.clone(),
            format!("{flag}={value}"),
        ];
        let code = execute(args);
        assert_eq!(code, 2, "{flag} {value}");
        assert!(start.elapsed() < Duration::from_secs(10), "{flag} {value}");
        // The message itself is checked through the library the command uses.
        let message = filters_message(flag, value);
        assert!(
            message.starts_with(&format!("{flag} ")) && message.contains(range),
            "{flag} {value}: {message}"
        );
        assert!(
            !message.contains('{') && !message.contains("Settings"),
            "{message}"
        );
        // Numbers are echoed short (1e20, not twenty digits).
        assert!(!message.contains("0000000000"), "{message}");
        assert!(!std::path::Path::new(&out).join("filters.svg").exists());
    }
}

/// The message `filters` gives for `flag value` on the test log (the command's own
/// settings, the one flag changed).
fn filters_message(flag: &str, value: &str) -> String {
    use hal_sim::cli::analysis::{LogToolArgs, WindowArgs, ZeroPhaseArgs};
    use hal_sim::cli::filters::{estimates, FiltersArgs};
    let c = fpc::control::config::ControlConfig::reference();
    let mut args = FiltersArgs {
        io: LogToolArgs {
            measured: log().into(),
            out: Some("unused".into()),
            model: None,
            force: false,
            json: false,
        },
        column: "x_m".into(),
        filter: ZeroPhaseArgs {
            cutoff_hz: 100.0,
            filter_order: 4,
        },
        sg_window: c.sg_window,
        sg_order: c.sg_order,
        sg_lag: c.sg_lag,
        drive_delay_ms: 8.5,
        window: WindowArgs {
            from_s: None,
            to_s: None,
        },
    };
    let int = || value.parse::<usize>().expect("an integer flag");
    let real = || value.parse::<f64>().expect("a number flag");
    match flag {
        "--sg-window" => args.sg_window = int(),
        "--sg-order" => args.sg_order = int(),
        "--sg-lag" => args.sg_lag = int(),
        "--filter-order" => args.filter.filter_order = int(),
        "--cutoff-hz" => args.filter.cutoff_hz = real(),
        "--drive-delay-ms" => args.drive_delay_ms = real(),
        "--column" => args.column = value.into(),
        other => panic!("{other}"),
    }
    let log = hal_sim::runlog::RunLog::read(std::path::Path::new(&log())).expect("test log");
    match estimates(&log, &args) {
        Ok(_) => String::new(),
        Err(f) => f.message,
    }
}
