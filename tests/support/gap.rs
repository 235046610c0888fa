//! What the model-gap proofs share: truth and model files made from the reference machine,
//! the synthetic runs, and running the workflow on them.

use hal_sim::gap::{analyse, GapJson, GapOptions};
use hal_sim::plant::model::{MachineModel, REFERENCE_TOML};
use hal_sim::run::{run, RunOptions};
use hal_sim::runlog::RunLog;

/// The reference model file with `key` of `[section]` set to `value` (the line replaced).
pub fn with_key(text: &str, section: &str, key: &str, value: &str) -> String {
    let mut out = Vec::new();
    let mut current = String::new();
    let mut done = false;
    for line in text.lines() {
        let t = line.trim();
        if t.starts_with('[') {
            current = t
                .trim_start_matches('[')
                .split(']')
                .next()
                .unwrap_or("")
                .to_string();
        }
        let is_key = t.split('=').next().map(str::trim) == Some(key);
        if !done && current == section && is_key {
            out.push(format!("{key} = {value}"));
            done = true;
        } else {
            out.push(line.to_string());
        }
    }
    assert!(done, "[{section}] {key} not found");
    out.join("\n") + "\n"
}

/// `text` without the section `[section]` (up to the next section header).
pub fn without_section(text: &str, section: &str) -> String {
    let mut out = Vec::new();
    let mut skip = false;
    for line in text.lines() {
        let t = line.trim();
        if t.starts_with('[') {
            skip = t.trim_start_matches('[').split(']').next() == Some(section);
        }
        if !skip {
            out.push(line);
        }
    }
    out.join("\n") + "\n"
}

/// The reference machine's model file.
pub fn reference() -> String {
    REFERENCE_TOML.to_string()
}

/// The truth of the cogging cases: the reference machine with 45 N of cogging at a phase of
/// 0.7 rad.
pub fn cogging_truth() -> String {
    with_key(
        &with_key(&reference(), "effects.cogging", "amplitude_n", "45.0"),
        "effects.cogging",
        "phase_rad",
        "0.7",
    )
}

/// A closed-loop run of the firmware on the plant of `truth`.
pub fn closed_loop(truth: &str, speed_mps: f64, cycles: u32, seed: u64) -> RunLog {
    let model = MachineModel::parse(truth).expect("truth model loads");
    let opts = RunOptions {
        model,
        model_name: "truth".into(),
        speed_mps: Some(speed_mps),
        cycles,
        seed,
        ..RunOptions::reference()
    };
    let out = run(&opts).expect("run");
    assert!(
        out.summary.faults.is_empty(),
        "faults: {:?}",
        out.summary.faults
    );
    out.log
}

/// The workflow on `log` with the model `model` (text); panics on failure.
pub fn gap(model: &str, log: &RunLog) -> GapJson {
    analyse(model, log, &GapOptions::default())
        .unwrap_or_else(|f| panic!("gap failed: {}", f.message))
        .json
}

/// Names of the effects found.
pub fn names(j: &GapJson) -> Vec<String> {
    j.effects.iter().map(|e| e.name.clone()).collect()
}

/// A fitted parameter of the effect `name`.
pub fn param(j: &GapJson, name: &str, key: &str) -> f64 {
    let e = j
        .effects
        .iter()
        .find(|e| e.name == name)
        .unwrap_or_else(|| panic!("{name} not named: {:?}", names(j)));
    *e.params
        .get(key)
        .unwrap_or_else(|| panic!("{name} has no {key}"))
}

/// Relative RMS reduction of channel `ch`, 0..1.
pub fn shrink(j: &GapJson, ch: &str) -> f64 {
    let c = j
        .channels
        .iter()
        .find(|c| c.name == ch)
        .unwrap_or_else(|| panic!("no channel {ch}"));
    1.0 - c.rms_after / c.rms_before
}

/// Prints the outcome (visible with `--nocapture`).
pub fn show(label: &str, j: &GapJson) {
    let ch: Vec<String> = j
        .channels
        .iter()
        .map(|c| format!("{} {:.4e}→{:.4e}", c.name, c.rms_before, c.rms_after))
        .collect();
    let ef: Vec<String> = j
        .effects
        .iter()
        .map(|e| {
            format!(
                "{} {:?} {:.4e}→{:.4e}",
                e.name, e.params, e.rms_before, e.rms_after
            )
        })
        .collect();
    eprintln!(
        "{label}: [{}] effects [{}] {:?}",
        ch.join(", "),
        ef.join("; "),
        j.warnings
    );
}
