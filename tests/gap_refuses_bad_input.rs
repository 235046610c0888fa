//! `fpc-sim gap` refuses what it cannot use (`docs/faults.md` #17–18): exit 2, one line naming
//! the key or the line and column, and nothing written.

use std::path::Path;

use hal_sim::cli::gap::{main, GapArgs};
use hal_sim::plant::model::REFERENCE_TOML;
use hal_sim::runlog::{RunLog, REQUIRED};

/// A scratch directory of its own (tests run concurrently, from several checkouts), removed
/// when the test ends, pass or fail.
fn scratch(prefix: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc-{prefix}-"))
        .tempdir()
        .expect("scratch directory")
}

/// A plausible little log: a slow sine stroke.
fn log_text(ports: Option<&str>) -> String {
    let mut log = RunLog::with_columns(&REQUIRED);
    if let Some(p) = ports {
        log.meta.push(("ports".into(), p.into()));
    }
    for i in 0..2000 {
        let t = i as f64 * 1e-4;
        let x = 0.1 + 0.05 * (6.0 * t).sin();
        log.push_row(&[t, x, x, 0.0, 10.0, 10.0, 1e5, 1e5]);
    }
    log.to_csv()
}

fn gap(dir: &Path, model: &str, log: &str) -> (u8, String, bool) {
    gap_band(dir, model, log, 300.0)
}

fn gap_band(dir: &Path, model: &str, log: &str, band_hz: f64) -> (u8, String, bool) {
    let (m, l, out) = (dir.join("model.toml"), dir.join("run.csv"), dir.join("out"));
    std::fs::write(&m, model).unwrap();
    std::fs::write(&l, log).unwrap();
    let r = main(GapArgs {
        model: Some(m),
        measured: l,
        out: out.clone(),
        json: false,
        band_hz,
        force: false,
    });
    match r {
        Ok(()) => (0, String::new(), out.exists()),
        Err(f) => (f.code, f.message, out.exists()),
    }
}

#[test]
fn gap_refuses_bad_model_files_naming_the_key() {
    let dir = scratch("model");
    let dir = dir.path();
    let log = log_text(None);
    for (bad, key) in [
        (
            REFERENCE_TOML.replace("mass_kg = 12.0", "mass_kg = -1.0"),
            "piston.mass_kg",
        ),
        (
            REFERENCE_TOML.replace("coulomb_n = 40.0", "colomb_n = 40.0"),
            "colomb_n",
        ),
        (
            REFERENCE_TOML.replace("period_m = 0.024 ", "period_m = 0.0 "),
            "period_m",
        ),
        (REFERENCE_TOML.replace("mass_kg = 12.0", ""), "mass_kg"),
    ] {
        let (code, msg, wrote) = gap(dir, &bad, &log);
        assert_eq!(code, 2, "{msg}");
        assert!(msg.contains(key), "`{msg}` should name {key}");
        assert!(!msg.contains('\n'));
        assert!(!wrote, "nothing may be written on bad input");
    }
}

#[test]
fn gap_refuses_bad_logs_naming_line_and_column() {
    let dir = scratch("log");
    let dir = dir.path();
    let good = log_text(None);
    let lines: Vec<&str> = good.lines().collect();
    let mut text = lines.clone();
    text[10] = "0.0009,abc,0.1,0,10,10,1e5,1e5";
    let mut nan = lines.clone();
    nan[20] = "0.0019,0.1,NaN,0,10,10,1e5,1e5";
    let mut back = lines.clone();
    back[30] = "0.0001,0.1,0.1,0,10,10,1e5,1e5";
    let mut short = lines.clone();
    short[40] = "0.0039,0.1";
    for (bad, want) in [
        (text.join("\n"), "line 11, column `x_m`"),
        (nan.join("\n"), "column `x_slave_m`"),
        (back.join("\n"), "column `t_s`"),
        (short.join("\n"), "line 41"),
        (log_text(Some("ajar")), "ports"),
    ] {
        let (code, msg, wrote) = gap(dir, REFERENCE_TOML, &bad);
        assert_eq!(code, 2, "{msg}");
        assert!(msg.contains(want), "`{msg}` should contain {want}");
        assert!(!wrote, "nothing may be written on bad input");
    }
}

/// The little log with every time stamp scaled by `k` (its step 1e-4·k s).
fn rescaled_time(k: f64) -> String {
    let mut log = RunLog::parse(&log_text(Some("closed"))).unwrap();
    if let Some(t) = log.columns.first_mut() {
        t.iter_mut().for_each(|v| *v *= k);
    }
    log.to_csv()
}

#[test]
fn gap_refuses_values_and_rates_no_machine_logs_without_hanging() {
    let dir = scratch("implausible");
    let dir = dir.path();
    let good = log_text(None);
    let mut far = good.lines().map(str::to_string).collect::<Vec<_>>();
    // One large finite position (it used to reach the least-squares SVD as NaN).
    far[500] = "0.0499,1e20,0.1,0,10,10,1e5,1e5".into();
    let mut force = good.lines().map(str::to_string).collect::<Vec<_>>();
    force[700] = "0.0699,0.1,0.1,0,1e12,10,1e5,1e5".into();
    let started = std::time::Instant::now();
    for (bad, band, want) in [
        (far.join("\n"), 300.0, "line 501, column `x_m`"),
        (force.join("\n"), 300.0, "column `f_master_n`"),
        // 1 s steps (the chamber replay's cost grew with the duration, not the rows) …
        (rescaled_time(1e4), 300.0, "time step 1e0 s is outside"),
        // … and 1e-12 s steps (everything was "nothing missing", every RMS 0).
        (rescaled_time(1e-8), 300.0, "time step 1e-12 s is outside"),
        // A band above the log's Nyquist frequency (5 kHz at 10 kHz).
        (good.clone(), 6000.0, "Nyquist"),
    ] {
        let (code, msg, wrote) = gap_band(dir, REFERENCE_TOML, &bad, band);
        assert_eq!(code, 2, "{msg}");
        assert!(msg.contains(want), "`{msg}` should contain {want}");
        assert!(!wrote, "nothing may be written on bad input");
    }
    assert!(started.elapsed().as_secs() < 20, "{:?}", started.elapsed());
}

#[test]
fn gap_writes_the_augmented_model_and_the_report() {
    let dir = scratch("ok");
    let dir = dir.path();
    let (code, msg, wrote) = gap(dir, REFERENCE_TOML, &log_text(Some("closed")));
    assert_eq!(code, 0, "{msg}");
    assert!(wrote);
    let out = dir.join("out");
    for f in [
        "model.toml",
        "report.md",
        "report.html",
        "gap.json",
        "overlay_force.svg",
        "pv_replay.svg",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    // The augmented model loads as `fpc-sim run --model` would load it.
    hal_sim::plant::model::MachineModel::read(&out.join("model.toml")).unwrap();
    // Both reports embed every plot the run wrote, and the HTML one is self-contained.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    let mut svgs = 0;
    for e in std::fs::read_dir(&out).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        if name.ends_with(".svg") {
            svgs += 1;
            assert!(md.contains(&format!("]({name})")), "report.md lacks {name}");
            assert!(
                html.contains(&format!("<img src=\"{name}\"")),
                "report.html lacks {name}"
            );
        }
    }
    // Six maps and an overlay per channel (four), the p–V replay, and the residual left on
    // each channel judged structured drawn against what it follows.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("gap.json")).unwrap()).unwrap();
    let structured = json["channels"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["unexplained"]["structured"] == serde_json::Value::Bool(true))
        .count();
    let plots = 4 * (6 + 1) + 1 + structured;
    assert_eq!(svgs, plots, "{svgs} plots");
    assert!(
        !html.contains("<script") && !html.contains("http"),
        "{html}"
    );
}
