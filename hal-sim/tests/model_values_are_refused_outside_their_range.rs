//! Every numeric key of the model file has a physical range (`plant::model::validate::RANGES`)
//! and the model is checked as a whole (`faults.md` row 23): a value outside its range, or
//! values that make no machine together, are refused naming the key — never a panic, an
//! abort (a 1e6 s lag allocated 160 GB) or a hang (a 1e50 m travel ran forever).

use hal_sim::plant::model::validate::{range_of, RANGES};
use hal_sim::plant::model::MachineModel;
use proptest::prelude::*;

const REFERENCE: &str = include_str!("../src/plant/model/reference.toml");

/// (line index, full key) of every `key = number` line of the reference file.
fn numeric_lines() -> Vec<(usize, String)> {
    let mut section = String::new();
    let mut out = Vec::new();
    for (i, line) in REFERENCE.lines().enumerate() {
        let code = line.split('#').next().unwrap_or("").trim();
        if let Some(s) = code.strip_prefix('[') {
            section = s.trim_end_matches(']').to_string();
        } else if let Some((k, v)) = code.split_once('=') {
            if v.trim().parse::<f64>().is_ok() {
                out.push((i, format!("{section}.{}", k.trim())));
            }
        }
    }
    out
}

/// The reference file with line `i`'s value replaced by `value`.
fn with_value(i: usize, value: &str) -> String {
    REFERENCE
        .lines()
        .enumerate()
        .map(|(j, l)| {
            if j == i {
                let key = l.split('=').next().unwrap_or("");
                format!("{key}= {value}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn every_value_outside_its_physical_range_is_refused_naming_the_key() {
    let lines = numeric_lines();
    let mut ranged = 0;
    for (i, key) in &lines {
        let Some((lo, hi, _)) = range_of(key) else {
            continue;
        };
        ranged += 1;
        let span = hi - lo;
        for bad in [
            hi + span.max(1.0),
            lo - span.max(1.0),
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NAN,
        ] {
            let text = with_value(*i, &format!("{bad:?}").replace("NaN", "nan"));
            let short = key.rsplit('.').next().unwrap_or(key);
            match MachineModel::parse(&text) {
                Ok(_) => panic!("{key} = {bad} accepted"),
                Err(e) => assert!(
                    e.0.contains(short),
                    "{key} = {bad}: the message does not name the key: {}",
                    e.0
                ),
            }
        }
    }
    println!("{ranged} keys of the reference file checked outside their ranges");
    assert!(ranged >= 50, "only {ranged} keys have a range");
}

#[test]
fn every_key_of_the_reference_file_has_a_range() {
    for (_, key) in numeric_lines() {
        if key.starts_with("simulation.") || key == "servo.counts_per_rev" {
            continue; // counts, checked as integers
        }
        assert!(range_of(&key).is_some(), "{key} has no physical range");
    }
    assert!(RANGES.iter().all(|(_, lo, hi, _)| lo < hi));
}

#[test]
fn values_that_make_no_machine_together_are_refused() {
    let cases = [
        ("travel_m = 0.205", "travel_m = 0.0008", "travel_m"),
        (
            "dead_length_a_m = 0.0005",
            "dead_length_a_m = 0.3",
            "dead_length_a_m",
        ),
        (
            "target_head_clearance_m = 1.0e-3",
            "target_head_clearance_m = 0.2",
            "target_head_clearance_m",
        ),
        (
            "offset_master_a = [0.0, 0.0, 0.0]",
            "offset_master_a = [0.0, 0.0, 0.0, 0.0]",
            "array of 3",
        ),
        ("mass_kg = ", "mass_kg = 1\nmass_kg = ", "given twice"),
    ];
    for (from, to, want) in cases {
        assert!(REFERENCE.contains(from), "{from}");
        let e = MachineModel::parse(&REFERENCE.replacen(from, to, 1)).unwrap_err();
        assert!(e.0.contains(want), "{to}: {}", e.0);
    }
    let lag = format!("{REFERENCE}\n[effects.slave_lag]\ndelay_s = 1e6\n");
    assert!(MachineModel::parse(&lag).unwrap_err().0.contains("delay_s"));
    let cog = REFERENCE.replacen("amplitude_n = 30.0", "amplitude_n = 1e300", 1);
    assert!(MachineModel::parse(&cog)
        .unwrap_err()
        .0
        .contains("amplitude_n"));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Any value at all, for any key: the model loads or is refused with a message — no
    /// panic in validation.
    #[test]
    fn validation_never_panics(pick in 0usize..1000, bits in any::<u64>(), edge in 0usize..4) {
        let lines = numeric_lines();
        let (i, _) = &lines[pick % lines.len()];
        let v = match edge {
            0 => f64::from_bits(bits),
            1 => (bits as f64) * 1e-15,
            2 => -((bits % 1000) as f64) * 1e-3,
            _ => (bits % 10_000) as f64 * 1e-4,
        };
        let text = with_value(*i, &format!("{v:?}").replace("NaN", "nan"));
        if let Err(e) = MachineModel::parse(&text) {
            prop_assert!(!e.0.is_empty());
        }
    }
}
