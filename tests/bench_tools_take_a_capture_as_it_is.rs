//! The bench's command line on what a bench session on the simulated board recorded (the
//! raw channels, as `fpc-sim link capture` writes them): `link capture --replay` makes the run
//! log and the scope's, `decode` makes them again from the raw files, and `gap` takes the run
//! log as it is. Bad input — another firmware's layout, a rate the firmware cannot run, a
//! request the recording holds no answer to — is a clear refusal, with nothing written.

mod support;

use std::path::Path;

use hal_sim::cli::execute;
use hal_sim::runlog::RunLog;
use support::gap::*;
use support::rig::{bench, Campaign};

fn fpc_sim(args: &[&str]) -> u8 {
    execute(std::iter::once("fpc-sim").chain(args.iter().copied()))
}

/// A scratch directory of its own (tests run concurrently, from several checkouts), removed
/// when the test ends, pass or fail.
fn tmp(prefix: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc-{prefix}-"))
        .tempdir()
        .expect("scratch directory")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn a_recorded_session_goes_through_capture_decode_and_gap_with_no_edits() {
    let c = bench(
        &cogging_truth(),
        14,
        fpc::link::telemetry::DEFAULT_DECIMATION,
        Campaign::Running {
            speed_mps: 2.3,
            seconds: 1.0,
        },
    );
    let dir = tmp("session");
    let dir = dir.path();
    let rec = dir.join("rec");
    std::fs::create_dir_all(&rec).unwrap();
    for (i, bytes) in c.raw.iter().enumerate() {
        std::fs::write(rec.join(format!("up{i}.bin")), bytes).unwrap();
    }
    // The capture, played back: the run log and the scope recording.
    let out = dir.join("rig-run");
    assert_eq!(
        fpc_sim(&["link", "capture", "--replay", s(&rec), "--out", s(&out)]),
        0
    );
    let log = RunLog::read(&out.join("run.csv")).unwrap();
    assert_eq!(log.meta("sample_rate_hz"), Some("2000"));
    assert_eq!(log.meta("ports"), Some("open"));
    let scope = RunLog::read(&out.join("scope-1.csv")).unwrap();
    assert_eq!(scope.len(), 512);
    // The same from the raw files.
    let dec = dir.join("dec.csv");
    let up1 = rec.join("up1.bin");
    assert_eq!(
        fpc_sim(&["decode", "--capture", s(&up1), "--out", s(&dec)]),
        0
    );
    assert_eq!(RunLog::read(&dec).unwrap(), log);
    let sc = dir.join("scope.csv");
    let up2 = rec.join("up2.bin");
    assert_eq!(
        fpc_sim(&["decode", "--capture", s(&up2), "--out", s(&sc)]),
        0
    );
    assert_eq!(RunLog::read(&sc).unwrap(), scope);
    assert_eq!(
        fpc_sim(&[
            "decode",
            "--capture",
            s(&up2),
            "--out",
            s(&dir.join("none.csv")),
            "--recording",
            "7"
        ]),
        2,
        "no recording 7"
    );
    // gap takes the run log as it is.
    let model = dir.join("nominal.toml");
    std::fs::write(&model, without_section(&reference(), "effects.cogging")).unwrap();
    let g = dir.join("gap");
    assert_eq!(
        fpc_sim(&[
            "gap",
            "--model",
            s(&model),
            "--measured",
            s(&out.join("run.csv")),
            "--out",
            s(&g)
        ]),
        0
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(g.join("gap.json")).unwrap()).unwrap();
    assert_eq!(json["effects"][0]["name"], "cogging");
    // Requests answered in the recording: the telemetry set at 2000 Hz, every channel.
    assert_eq!(
        fpc_sim(&["link", "telemetry", "--rate", "2000", "--replay", s(&rec)]),
        0
    );
    // A request the recording has no answer to (the ports were never declared sealed).
    assert_eq!(
        fpc_sim(&["link", "ports", "sealed", "--replay", s(&rec)]),
        1
    );
}

#[test]
fn bad_requests_and_another_firmwares_capture_are_refused_naming_what_is_wrong() {
    let dir = tmp("bad");
    let dir = dir.path();
    let rec = dir.join("rec");
    std::fs::create_dir_all(&rec).unwrap();
    std::fs::write(rec.join("up2.bin"), [0u8; 4]).unwrap();
    for args in [
        vec!["link", "telemetry", "--rate", "3000"],
        vec!["link", "telemetry", "--rate", "0.5"],
        vec!["link", "telemetry", "--decimation", "30000"],
        vec![
            "link",
            "telemetry",
            "--rate",
            "2000",
            "--channels",
            "x_m,pressure",
        ],
        vec!["link", "telemetry"],
        vec!["link", "scope", "arm", "--trigger", "strokes:0"],
        vec!["link", "scope", "arm", "--trigger", "soon"],
        vec!["link", "scope", "arm", "--trigger", "fault", "--pre", "512"],
        vec!["link", "capture", "--probe", "04x3:374b"],
    ] {
        let mut a = args.clone();
        a.extend(["--replay", s(&rec)]);
        assert_eq!(fpc_sim(&a), 2, "{args:?}");
    }
    // A capture of layout 1 (kind 0x01: an older firmware's telemetry).
    let mut old = Vec::new();
    for i in 0..300u16 {
        let mut p = [0u8; 52];
        p[0] = 0x01;
        p[1..3].copy_from_slice(&i.to_le_bytes());
        let mut w = [0u8; 64];
        let n = fpc::link::frame::encode_frame(&p, &mut w).unwrap();
        old.extend_from_slice(&w[..n]);
    }
    let cap = dir.join("old.bin");
    std::fs::write(&cap, old).unwrap();
    let out = dir.join("old.csv");
    assert_eq!(
        fpc_sim(&["decode", "--capture", s(&cap), "--out", s(&out)]),
        2
    );
    assert!(!out.exists());
}

/// Records a bench session on the simulated board (a 0.75 ms slave lag hidden in the plant)
/// as up0.bin, up1.bin and up2.bin — what `docs/rig-to-model.md` plays back with `--replay` —
/// into the directory `FPC_BENCH_DIR` names (or a scratch one), and checks that its telemetry
/// decodes to a run log. Slow (a second of machine time through the link), so marked.
#[test]
#[ignore = "slow: records a bench session (to FPC_BENCH_DIR, if set)"]
fn write_a_bench_session() {
    let keep = std::env::var_os("FPC_BENCH_DIR");
    let scratch = tmp("session");
    let dir = match &keep {
        Some(d) => Path::new(d).to_path_buf(),
        None => scratch.path().to_path_buf(),
    };
    let truth = format!("{}\n[effects.slave_lag]\ndelay_s = 0.00075\n", reference());
    let c = bench(
        &truth,
        16,
        fpc::link::telemetry::DEFAULT_DECIMATION,
        Campaign::Running {
            speed_mps: 2.3,
            seconds: 1.0,
        },
    );
    std::fs::create_dir_all(&dir).unwrap();
    // up0 (defmt) may be empty: the simulated board logs no defmt text.
    for (i, bytes) in c.raw.iter().enumerate() {
        std::fs::write(dir.join(format!("up{i}.bin")), bytes).unwrap();
    }
    let csv = dir.join("up1.csv");
    assert_eq!(
        fpc_sim(&[
            "decode",
            "--capture",
            s(&dir.join("up1.bin")),
            "--out",
            s(&csv),
            "--force"
        ]),
        0
    );
    let log = RunLog::read(&csv).unwrap();
    assert!(
        log.len() > 1000,
        "{} rows from a second at 2 kHz",
        log.len()
    );
    if keep.is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    } else {
        let _ = std::fs::remove_file(&csv);
    }
}
