//! `fpc-sim run --model FILE`: the minimal model file of `docs/formats.md` §2 runs; an unknown
//! key, a missing required key or a non-physical value is refused with exit code 2 and one
//! line on stderr naming the key.

use std::process::Command;

/// The minimal file of `docs/formats.md` §2.
const MINIMAL: &str = include_str!("data/minimal_model.toml");

/// A scratch directory, removed with the run's files when the guard drops.
fn dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc_model_cli_{name}_"))
        .tempdir()
        .unwrap()
}

/// Runs `fpc-sim run --model <text> --cycles 1`; returns (exit code, stderr).
fn run_with(name: &str, text: &str) -> (i32, String) {
    let scratch = dir(name);
    let d = scratch.path();
    let model = d.join("model.toml");
    std::fs::write(&model, text).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_fpc-sim"))
        .args(["run", "--cycles", "1", "--model"])
        .arg(&model)
        .arg("--out")
        .arg(d.join("out"))
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_minimal_model_file_runs() {
    let (code, err) = run_with("minimal", MINIMAL);
    println!("minimal model: exit {code}: {}", err.trim());
    assert_eq!(code, 0, "{err}");
}

#[test]
fn bad_model_files_exit_2_naming_the_key() {
    let cases = [
        (
            "unknown",
            MINIMAL.replace("coulomb_n = 40.0", "coulomb_n = 40.0\ncolumb_n = 40.0"),
            "columb_n",
        ),
        ("missing", MINIMAL.replace("bore_m = 0.090\n", ""), "bore_m"),
        (
            "negative_mass",
            MINIMAL.replace("mass_kg = 12.0", "mass_kg = -12.0"),
            "piston.mass_kg",
        ),
        (
            "zero_period",
            format!("{MINIMAL}\n[effects.cogging]\namplitude_n = 30.0\nperiod_m = 0.0\n"),
            "effects.cogging.period_m",
        ),
        (
            "unknown_effect",
            format!("{MINIMAL}\n[effects.coging]\namplitude_n = 30.0\n"),
            "coging",
        ),
    ];
    for (name, text, key) in cases {
        let (code, err) = run_with(name, &text);
        println!("{name}: exit {code}: {}", err.trim());
        assert_eq!(code, 2, "{name}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
        assert!(err.contains(key), "{name}: `{key}` not named in {err}");
    }
}
