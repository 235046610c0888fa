//! A log as a rig's logger writes it gives `fpc-sim gap` the same effects as the clean log:
//! sample instants that jitter by ±2 µs, 0.1 % of the rows dropped, and the same log with
//! `;` between the fields and decimal commas. The reader puts the rows back on their grid
//! (and says so); the workflow sees a uniform log.

mod support;

use std::path::{Path, PathBuf};

use hal_sim::gap::synth::decimate;
use hal_sim::runlog::RunLog;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use support::gap::*;

/// `fine` (20 kHz) as a 10 kHz logger records it: each row's instant off its grid point by
/// up to `jitter_s` (a measured signal's value at that instant, interpolated from the fine
/// log; a count's — the servo angle's, an ADC code's — the last one before it), and
/// `drop_share` of the rows lost, never the first or last.
fn as_a_logger_writes_it(fine: &RunLog, jitter_s: f64, drop_share: f64, seed: u64) -> RunLog {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let t = fine.column("t_s").unwrap();
    let step = 2.0 * (t[1] - t[0]);
    let rows = (t.len() - 2) / 2;
    let mut out = RunLog::with_columns(&fine.names.iter().map(String::as_str).collect::<Vec<_>>());
    out.meta = decimate(fine, 2).meta;
    let counted: Vec<usize> = (0..fine.names.len())
        .filter(|&c| hal_sim::runlog::grid::lattice(&fine.columns[c]))
        .collect();
    let mut dropped = 0;
    for k in 0..rows {
        if k > 0 && k + 1 < rows && rng.random_bool(drop_share) {
            dropped += 1;
            continue;
        }
        let at = t[0] + k as f64 * step + rng.random_range(-jitter_s..=jitter_s);
        let i = (((at - t[0]) / (step / 2.0)).floor() as usize).min(t.len() - 2);
        let w = (at - t[i]) / (t[i + 1] - t[i]);
        let row: Vec<f64> = fine
            .columns
            .iter()
            .enumerate()
            .map(|(c, col)| {
                if fine.names[c] == "t_s" {
                    at
                } else if counted.contains(&c) {
                    // A count (the servo's angle, an ADC code, a fault code) is what it was
                    // at the logger's instant: the fine log's last value before it.
                    col[i]
                } else {
                    col[i] + w * (col[i + 1] - col[i])
                }
            })
            .collect();
        out.push_row(&row);
    }
    eprintln!("logger: {} rows written, {dropped} dropped", out.len());
    out
}

/// A scratch folder of this test, emptied first.
fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("gap_reads_logs_as_rigs_write_them")
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `fpc-sim gap` on the log file `log` with the model file `model`, as a user runs it: the
/// effects it names, and what it printed on stderr.
fn gap_cli(model: &Path, log: &Path, out: &Path) -> (Vec<String>, String) {
    let args = [
        "fpc-sim",
        "gap",
        "--model",
        model.to_str().unwrap(),
        "--measured",
        log.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--json",
    ];
    let (code, text) = hal_sim::console::captured(|| hal_sim::cli::execute(args));
    assert_eq!(code, 0, "{text}");
    let start = text.find('{').expect("the JSON summary");
    let json: serde_json::Value = serde_json::from_str(&text[start..]).expect("JSON");
    let names = json["effects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["name"].as_str().unwrap().to_string())
        .collect();
    (names, text)
}

#[test]
fn jitter_dropped_rows_and_semicolons_give_gap_the_same_effects() {
    let dir = scratch("cogging");
    let truth = cogging_truth();
    let model = dir.join("model.toml");
    std::fs::write(&model, without_section(&reference(), "effects.cogging")).unwrap();
    let fine = closed_loop(&truth, 2.3, 2, 42);

    let clean = dir.join("clean.csv");
    decimate(&fine, 2).write(&clean).unwrap();
    let rig = as_a_logger_writes_it(&fine, 2e-6, 1e-3, 7);
    let jittered = dir.join("jittered.csv");
    rig.write(&jittered).unwrap();
    // The same rows with `;` between the fields and decimal commas, as a spreadsheet set to
    // a European locale writes them.
    let semicolons = dir.join("semicolons.csv");
    let text: String = rig
        .to_csv()
        .lines()
        .map(|l| {
            if l.starts_with('#') {
                format!("{l}\n")
            } else {
                format!("{}\n", l.replace(',', ";").replace('.', ","))
            }
        })
        .collect();
    std::fs::write(&semicolons, text).unwrap();

    let (want, _) = gap_cli(&model, &clean, &dir.join("g-clean"));
    assert_eq!(want, ["cogging"], "the clean log names the hidden cogging");
    for (what, path) in [("jittered", &jittered), ("`;`-separated", &semicolons)] {
        let (got, printed) = gap_cli(&model, path, &dir.join(format!("g-{what}")));
        eprintln!("{what}: {got:?}\n{printed}");
        assert_eq!(got, want, "{what}: {printed}");
        // The reader said what it did: the rows it filled and how far they were off.
        assert!(
            printed.contains("resampled onto its nominal step of 100 µs")
                && printed.contains("filled where the logger dropped them"),
            "{what}: {printed}"
        );
    }
}
