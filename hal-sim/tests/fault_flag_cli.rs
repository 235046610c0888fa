//! `fpc-sim run --fault NAME@T[:k=v,…]`: a fault specification with an unknown name or a
//! malformed part exits 2 with one line naming it, and writes nothing; a valid one runs, and
//! the run log's `fault` column records the code of the first latched fault. A refused model
//! file writes nothing either (`docs/faults.md` #17).

use std::path::PathBuf;
use std::process::Command;

/// A scratch directory of its own (tests run concurrently, from several checkouts), removed
/// when the test ends, pass or fail.
fn dir(prefix: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc-{prefix}-"))
        .tempdir()
        .expect("scratch directory")
}

/// Runs `fpc-sim run` with `args` into a fresh directory; returns (exit code, stderr, out
/// dir, the scratch directory holding it).
fn fpc_sim_run(name: &str, args: &[&str]) -> (i32, String, PathBuf, tempfile::TempDir) {
    let scratch = dir(name);
    let out = scratch.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_fpc-sim"))
        .arg("run")
        .args(args)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
        out,
        scratch,
    )
}

#[test]
fn a_bad_fault_spec_exits_2_naming_it_and_writes_nothing() {
    let cases = [
        ("encoder_amplitud@1.0", "unknown fault `encoder_amplitud`"),
        ("encoder_amplitude", "missing `@`"),
        ("encoder_amplitude@soon", "time `soon`"),
        ("encoder_amplitude@-1", "non-negative"),
        ("encoder_amplitude@1:gian=2", "no parameter `gian`"),
        ("encoder_amplitude@1:gain", "is not k=v"),
        ("encoder_amplitude@1:gain=NaN", "outside"),
        ("section_loss@1:section=left", "master|slave"),
        ("task_hang@1:task=telemetry", "control|supervision"),
    ];
    for (i, (spec, says)) in cases.iter().enumerate() {
        let (code, err, out, _scratch) =
            fpc_sim_run(&format!("bad{i}"), &["--cycles", "1", "--fault", spec]);
        println!("--fault {spec}: exit {code}: {}", err.trim());
        assert_eq!(code, 2, "{spec}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
        assert!(err.contains(spec), "{spec} not named in {err}");
        assert!(err.contains(says), "{spec}: `{says}` not in {err}");
        assert!(!out.exists(), "{spec}: something was written");
    }
}

#[test]
fn a_valid_fault_runs_and_the_log_records_its_code() {
    // Master encoder amplitude ×0.2 once compressing (≈ 0.93 s): `encoder_signal`, code 1.
    let (code, err, out, _scratch) = fpc_sim_run(
        "valid",
        &[
            "--cycles",
            "3",
            "--fault",
            "encoder_amplitude@1.1:gain=0.2",
            "--fault",
            "gas_loss@1.5:chamber=b",
        ],
    );
    println!("{}", err.trim());
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("injected fault from 1.1000 s: encoder_signal"),
        "{err}"
    );
    let log = hal_sim::runlog::RunLog::read(&out.join("run.csv")).unwrap();
    let t = log.column("t_s").unwrap();
    let fault = log.column("fault").unwrap();
    let first = t
        .iter()
        .zip(fault)
        .find(|(_, f)| **f != 0.0)
        .map(|(t, f)| (*t, *f))
        .expect("a fault in the log");
    println!("first fault code {} at {} s", first.1, first.0);
    assert_eq!(
        first.1,
        f64::from(fpc::safety::faults::Fault::EncoderSignal as u8)
    );
    assert!((1.1..1.101).contains(&first.0), "{first:?}");
}

#[test]
fn a_refused_model_file_writes_nothing() {
    let d = dir("model");
    let d = d.path();
    let model = d.join("model.toml");
    std::fs::write(
        &model,
        hal_sim::plant::model::REFERENCE_TOML.replace("mass_kg = 12.0", "mass_kg = -12.0"),
    )
    .unwrap();
    let (code, err, out, _scratch) =
        fpc_sim_run("model_run", &["--model", model.to_str().unwrap()]);
    println!("negative mass: exit {code}: {}", err.trim());
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("mass_kg"), "{err}");
    assert!(!out.exists(), "something was written");
}
