//! `fpc-sim derive` — the firmware's fixed-point differentiator — against scipy's
//! Savitzky–Golay, on reference vectors made once by `tests/data/sg_reference/generate.py`:
//! every row within 1e-4 of the signal's RMS, centred (`savgol_filter`, `mode='interp'`
//! edges included), causal end point (`savgol_coeffs(..., pos=N−1)`) and in between. Bad
//! input exits 2 naming the file, line and column.

use std::path::{Path, PathBuf};

use hal_sim::cli::derive::{derive, main, DeriveArgs, Settings};
use hal_sim::runlog::RunLog;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/sg_reference")
        .join(name)
}

/// The expected columns, by name (`v_N_K_L`, `a_N_K_L`).
fn expected() -> Vec<(String, Vec<f64>)> {
    let text = std::fs::read_to_string(data("expected.csv")).expect("expected.csv");
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let names: Vec<String> = lines
        .next()
        .expect("header")
        .split(',')
        .map(str::to_string)
        .collect();
    let mut cols = vec![Vec::new(); names.len()];
    for line in lines {
        for (col, field) in cols.iter_mut().zip(line.split(',')) {
            col.push(field.trim().parse::<f64>().expect("number"));
        }
    }
    names.into_iter().zip(cols).collect()
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

#[test]
fn derive_matches_scipy_on_every_row() {
    let log = RunLog::read(&data("run.csv")).expect("reference log");
    let x = log.column("x_m").expect("x_m");
    let dt = log.sample_time_s().expect("dt");
    let mut checked = 0;
    for (name, want) in expected() {
        let mut parts = name.split('_');
        let kind = parts.next().unwrap_or_default().to_string();
        let nums: Vec<usize> = parts.map(|p| p.parse().expect("N_K_L")).collect();
        let [window, order, lag] = nums[..] else {
            panic!("bad column {name}");
        };
        let got = derive(x, dt, Settings { window, order, lag }).expect("derive");
        let got = if kind == "v" { &got.v_mps } else { &got.a_mps2 };
        assert_eq!(got.len(), want.len());
        let scale = rms(&want);
        let worst = got
            .iter()
            .zip(&want)
            .map(|(g, w)| (g - w).abs())
            .fold(0.0f64, f64::max);
        println!(
            "{name}: worst |derive − scipy| = {:.2e} of the RMS ({scale:.4e})",
            worst / scale
        );
        assert!(worst <= 1e-4 * scale, "{name}: {worst:e} vs RMS {scale:e}");
        checked += 1;
    }
    assert_eq!(checked, 14);
}

#[test]
fn bad_input_is_refused_with_exit_2_naming_where() {
    let scratch = tempfile::tempdir().expect("scratch directory");
    let dir = scratch.path();
    let good = std::fs::read_to_string(data("run.csv")).expect("run.csv");
    // Text in a number on the 10th data row (file line 13: two metadata lines, the header).
    let mut lines: Vec<&str> = good.lines().collect();
    let broken = lines[12].replacen(',', ",abc", 1);
    lines[12] = &broken;
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, lines.join("\n")).expect("write");
    let args = |measured: PathBuf, window: Option<usize>| DeriveArgs {
        measured,
        window,
        order: None,
        lag: None,
        out: None,
        json: false,
        force: false,
    };
    let e = main(args(bad.clone(), None)).unwrap_err();
    assert_eq!(e.code, 2);
    assert!(
        e.message.contains("bad.csv") && e.message.contains("line 13") && e.message.contains("x_m"),
        "{}",
        e.message
    );
    let e = main(args(dir.join("missing.csv"), None)).unwrap_err();
    assert_eq!(e.code, 2);
    assert!(e.message.contains("missing.csv"), "{}", e.message);
    let e = main(args(data("run.csv"), Some(8))).unwrap_err();
    assert_eq!(e.code, 2);
    assert!(e.message.contains("--window 8"), "{}", e.message);
    assert!(main(args(data("run.csv"), Some(21))).is_ok());
}
