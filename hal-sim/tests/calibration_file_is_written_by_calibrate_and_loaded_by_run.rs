//! `fpc-sim calibrate --out FILE` commissions the simulated machine with the firmware's
//! Calibrate routines and writes the record as TOML; `fpc-sim run --calibration FILE` puts it
//! in the simulated board's flash, where the firmware loads it at boot instead of being
//! handed the model's true values. A bad file exits 2 naming the key, before any work.

use std::path::Path;
use std::process::Command;

/// A scratch directory of its own (tests run concurrently, from several checkouts), removed
/// when the test ends, pass or fail.
fn dir(prefix: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc-{prefix}-"))
        .tempdir()
        .expect("scratch directory")
}

/// Runs `fpc-sim ARGS`; returns (exit code, stderr).
fn fpc_sim(args: &[&str], paths: &[&Path]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_fpc-sim"))
        .args(args)
        .args(paths)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn run_with(calibration: &Path, out: &Path) -> (i32, String) {
    let (code, err) = fpc_sim(
        &["run", "--cycles", "2", "--out"],
        &[out, Path::new("--calibration"), calibration],
    );
    println!(
        "  run --calibration {}: exit {code}: {}",
        calibration.display(),
        err.trim()
    );
    (code, err)
}

#[test]
fn calibrate_writes_a_file_that_run_loads_and_bad_files_are_refused_by_key() {
    let d = dir("all");
    let d = d.path();
    let cal = d.join("cal.toml");
    let (code, err) = fpc_sim(&["calibrate", "--out"], &[&cal]);
    println!("calibrate: exit {code}: {}", err.trim());
    assert_eq!(code, 0, "{err}");
    let text = std::fs::read_to_string(&cal).unwrap();
    let record = hal_sim::calibration::parse(&text).expect("the written file parses");
    assert!(record.is_complete());
    // The commissioning found the reference machine's 30 N cogging at the pitch.
    let map = record.calibrated.cogging.unwrap();
    let amplitude = map.sin_n[0].hypot(map.cos_n[0]);
    println!("  cogging found: {amplitude:.2} N at the pitch (model: 30 N)");
    assert!((amplitude - 30.0).abs() < 1.5);
    // An existing output is not replaced without --force.
    let (code, _) = fpc_sim(&["calibrate", "--out"], &[&cal]);
    assert_eq!(code, 2);

    let (code, err) = run_with(&cal, &d.join("good"));
    assert_eq!(code, 0, "{err}");

    // The firmware runs on the file, not on the model's truth: alignment offsets 120°
    // electrical off make the motors push the wrong way and the run fails.
    let wrong = d.join("wrong.toml");
    std::fs::write(&wrong, {
        let mut t = String::new();
        for line in text.lines() {
            let l = if line.starts_with("master_angle_offset_deg")
                || line.starts_with("slave_angle_offset_deg")
            {
                format!("{} = 120.0", line.split('=').next().unwrap().trim())
            } else {
                line.to_string()
            };
            t.push_str(&l);
            t.push('\n');
        }
        t
    })
    .unwrap();
    let (code, _) = run_with(&wrong, &d.join("wrong"));
    assert_eq!(code, 1, "a calibration 120° off must not run clean");

    for (name, from, to, named) in [
        (
            "unknown",
            "misalignment_m =",
            "misalignment_mm =",
            "misalignment_mm",
        ),
        (
            "negative",
            "period_m = 0.024",
            "period_m = -0.024",
            "cogging.period_m",
        ),
        (
            "version",
            "format_version = 1",
            "format_version = 2",
            "format_version",
        ),
        (
            "nan",
            "[encoder.slave]\nsin_offset_codes = 0.0",
            "[encoder.slave]\nsin_offset_codes = nan",
            "encoder.slave.sin_offset_codes",
        ),
        ("missing", "[cogging]", "[cogging_removed]", "cogging"),
    ] {
        assert!(text.contains(from), "{name}: {from}");
        let bad = d.join(format!("{name}.toml"));
        std::fs::write(&bad, text.replacen(from, to, 1)).unwrap();
        let out = d.join(format!("out_{name}"));
        let (code, err) = run_with(&bad, &out);
        assert_eq!(code, 2, "{name}: {err}");
        assert!(err.contains(named), "{name}: {err}");
        assert!(!out.exists(), "{name}: nothing may be written");
    }
}
