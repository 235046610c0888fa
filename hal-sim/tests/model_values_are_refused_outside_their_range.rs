//! Every numeric key of the model file has a physical range (`plant::model::validate::RANGES`)
//! and the model is checked as a whole (`docs/faults.md` row 23): a value outside its range, or
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
            1e-300,
            -1e-300,
            0.0,
            -1.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ] {
            if (lo..=hi).contains(&bad) {
                continue; // 0 or 1e-300 where the range starts at 0
            }
            let text = with_value(*i, &format!("{bad:?}").replace("NaN", "nan"));
            match MachineModel::parse(&text) {
                Ok(_) => panic!("{key} = {bad} accepted"),
                Err(e) => assert_names(&e.0, key, &format!("{bad}")),
            }
        }
    }
    println!("{ranged} keys of the reference file checked outside their ranges");
    assert!(ranged >= 60, "only {ranged} keys have a range");
}

/// One short line naming `key` (its last part at least), with the range or the rule, and no
/// Rust debug dump or 300-digit echo.
fn assert_names(message: &str, key: &str, value: &str) {
    let short = key.rsplit('.').next().unwrap_or(key);
    assert!(
        message.contains(short),
        "{key} = {value}: the message does not name the key: {message}"
    );
    assert!(
        !message.contains('\n') && message.chars().count() <= 400,
        "{key} = {value}: not one short line: {message}"
    );
    assert!(
        !message.contains(" { ") && !message.contains("0000000000000"),
        "{key} = {value}: a debug dump or a long echo: {message}"
    );
}

#[test]
fn every_range_is_stated_with_its_bounds_and_the_reference_lies_inside() {
    MachineModel::parse(REFERENCE).expect("the reference model loads");
    for (i, key) in numeric_lines() {
        let Some((lo, hi, _)) = range_of(&key) else {
            continue;
        };
        let value: f64 = REFERENCE
            .lines()
            .nth(i)
            .unwrap()
            .split('=')
            .nth(1)
            .unwrap()
            .split('#')
            .next()
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        assert!(
            (lo..=hi).contains(&value),
            "{key} = {value} outside {lo} ..= {hi}"
        );
        // Just outside: refused, and the message states the range.
        let e = MachineModel::parse(&with_value(i, &format!("{:?}", hi + (hi - lo).max(1.0))))
            .unwrap_err()
            .0;
        assert!(e.contains("range") || e.contains("must"), "{key}: {e}");
    }
}

/// Every TOML file of the repository under `dir` (relative to the repository's root),
/// skipping build output and version control.
fn toml_files(root: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        for entry in entries {
            let path = entry.expect("a directory entry").path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if path.is_dir() {
                if !matches!(name, "target" | ".git" | "node_modules") {
                    stack.push(path);
                }
            } else if name.ends_with(".toml") {
                found.push(
                    path.strip_prefix(root)
                        .expect("under the root")
                        .to_path_buf(),
                );
            }
        }
    }
    found.sort();
    found
}

/// Tool configuration, not the project's data: Cargo manifests, the pinned toolchain,
/// cargo's, clippy's, rustfmt's and cargo-deny's settings.
fn is_tool_configuration(path: &std::path::Path) -> bool {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    matches!(
        name,
        "Cargo.toml" | "rust-toolchain.toml" | "clippy.toml" | "rustfmt.toml" | "deny.toml"
    ) || path.parent().and_then(|p| p.file_name()) == Some(std::ffi::OsStr::new(".cargo"))
}

/// Every TOML file of the repository is found (not listed by hand) and read by the reader
/// of its kind: machine models (`[piston]`) by the model reader, sweep plans (`[axes]`) by
/// the plan reader (their `model = "…"` relative to the plan), calibration files
/// (`format_version`) by the calibration reader. A file of no known kind fails the test, as
/// does a field log without its model.
#[test]
fn every_model_plan_and_calibration_file_of_the_repository_loads() {
    let root = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let (mut models, mut plans, mut calibrations) = (Vec::new(), Vec::new(), Vec::new());
    for rel in toml_files(root) {
        if is_tool_configuration(&rel) {
            continue;
        }
        let path = root.join(&rel);
        let text =
            std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", rel.display()));
        let has = |line: &str| text.lines().any(|l| l.trim_start().starts_with(line));
        if has("[piston]") {
            MachineModel::read(&path).unwrap_or_else(|e| panic!("{}: {e}", rel.display()));
            models.push(rel);
        } else if has("[axes]") {
            let dir = path.parent().expect("a directory").to_path_buf();
            hal_sim::sweep::plan::Plan::parse(&text, |m| {
                let p = dir.join(m);
                std::fs::read_to_string(&p)
                    .map(|t| (t, m.to_string()))
                    .map_err(|e| format!("{}: {e}", p.display()))
            })
            .unwrap_or_else(|e| panic!("{}: {e}", rel.display()));
            plans.push(rel);
        } else if has("format_version") {
            hal_sim::calibration::read(&path).unwrap_or_else(|e| panic!("{}: {e}", rel.display()));
            calibrations.push(rel);
        } else {
            panic!(
                "{}: a TOML file of no kind this test knows (a model has `[piston]`, a plan \
                 `[axes]`, a calibration `format_version`): add its reader here",
                rel.display()
            );
        }
    }
    println!(
        "{} model files, {} sweep plans, {} calibration files loaded:\n{models:#?}\n{plans:#?}\n{calibrations:#?}",
        models.len(),
        plans.len(),
        calibrations.len()
    );
    // Each field log comes with the nominal model it is analysed with.
    let logs = root.join("tests/data/field-logs");
    let mut field_logs = 0;
    for entry in std::fs::read_dir(&logs).expect("the field logs") {
        let name = entry
            .expect("an entry")
            .file_name()
            .to_string_lossy()
            .into_owned();
        if let Some(stem) = name.strip_suffix(".csv.gz") {
            let model = std::path::Path::new("tests/data/field-logs").join(format!("{stem}.toml"));
            assert!(
                models.contains(&model),
                "{name} has no model {} that loads",
                model.display()
            );
            field_logs += 1;
        }
    }
    // The kinds are all there: the embedded reference, the minimal model, the docs' examples
    // and studies, the field logs' models.
    assert!(field_logs >= 7, "{field_logs} field logs");
    for must in [
        "hal-sim/src/plant/model/reference.toml",
        "hal-sim/tests/data/minimal_model.toml",
        "docs/examples/model.toml",
        "docs/studies/paper-rig.toml",
    ] {
        assert!(
            models.contains(&std::path::PathBuf::from(must)),
            "{must} not found as a model"
        );
    }
    assert!(!plans.is_empty() && !calibrations.is_empty());
}

/// Through the command: every numeric key at 1e300 (and NaN for a few) exits 2 with one line
/// naming the key, before any output is written.
#[test]
fn fpc_sim_run_exits_2_naming_the_key_and_writes_nothing() {
    let scratch = tempfile::tempdir().expect("scratch directory");
    let d = scratch.path();
    let model = d.join("model.toml");
    let out = d.join("out");
    for (n, (i, key)) in numeric_lines().into_iter().enumerate() {
        let value = if n % 7 == 0 { "nan" } else { "1e300" };
        std::fs::write(&model, with_value(i, value)).unwrap();
        let run = std::process::Command::new(env!("CARGO_BIN_EXE_fpc-sim"))
            .args(["run", "--cycles", "1", "--model"])
            .arg(&model)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{key} = {value}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{key} = {value}: {err}");
        assert_names(err.trim(), &key, value);
        assert!(!out.exists(), "{key} = {value}: outputs written");
    }
}

#[test]
fn every_key_of_the_reference_file_has_a_range() {
    for (_, key) in numeric_lines() {
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
        (
            "mass_kg = ",
            "mass_kg = 1\nmass_kg = ",
            "piston.mass_kg` is given twice",
        ),
        (
            "[gas]",
            "[piston]\nmass_kg = 1.0\n[gas]",
            "section `[piston]` is given twice",
        ),
        (
            "discharge_a_deg = [288.0, 360.0]",
            "discharge_a_deg = [100.0, 200.0]",
            "overlap",
        ),
        (
            "discharge_a_deg = [288.0, 360.0]",
            "discharge_a_deg = [360.0, 288.0]",
            "overlap",
        ),
        (
            "discharge_b_deg = [108.0, 180.0]",
            "discharge_b_deg = [150.0, 150.0]",
            "no length",
        ),
        (
            "intake_a_deg = [0.0, 180.0]",
            "intake_a_deg = [0.0, 180.0, 200.0]",
            "ports.intake_a_deg",
        ),
        ("static_n = 60.0", "static_n = 6000.0", "friction.static_n"),
        ("force_limit_n = 10000.0", "force_limit_n = 1e6", "ok"),
        ("sin_offset_codes = 0.0", "sin_offset_codes = 600.0", "ADC"),
        ("suction_pa = 1.0e5", "suction_pa = 5.0e5", "full scale"),
        ("mass_kg = 12.0", "mass_kg = \"heavy\"", "piston.mass_kg"),
        ("mass_kg = 12.0", "mass_kg = [1.0, 2.0]", "piston.mass_kg"),
        (
            "counts_per_rev = 4096",
            "counts_per_rev = 1e300",
            "servo.counts_per_rev",
        ),
        (
            "counts_per_rev = 4096",
            "counts_per_rev = 1",
            "servo.counts_per_rev",
        ),
        (
            "substeps_per_period = 1",
            "substeps_per_period = -1",
            "substeps_per_period",
        ),
        // The link's thresholds out of order: power good above the nominal voltage, the
        // chopper below it.
        (
            "power_good_voltage_v = 500.0",
            "power_good_voltage_v = 600.0",
            "supply.power_good_voltage_v",
        ),
        (
            "chopper_voltage_v = 750.0",
            "chopper_voltage_v = 550.0",
            "supply.chopper_voltage_v",
        ),
    ];
    for (from, to, want) in cases {
        assert!(REFERENCE.contains(from), "{from}");
        let text = REFERENCE.replacen(from, to, 1);
        if want == "ok" {
            MachineModel::parse(&text).unwrap_or_else(|e| panic!("{to}: {e}"));
            continue;
        }
        let e = MachineModel::parse(&text).unwrap_err();
        assert!(e.0.contains(want), "{to}: {}", e.0);
        assert_names(&e.0, want, to);
    }
    // Cogging beyond half the motor's peak force, even under a large force limit.
    let cog = REFERENCE
        .replacen("force_limit_n = 10000.0", "force_limit_n = 1e6", 1)
        .replacen("amplitude_n = 30.0", "amplitude_n = 9000.0", 1);
    assert!(MachineModel::parse(&cog)
        .unwrap_err()
        .0
        .contains("amplitude_n"));
    // A missing section is named as a section; a long unknown key is cut short.
    let no_encoder = REFERENCE.replacen("[encoder]\nperiod_m = 0.024", "", 1);
    let e = MachineModel::parse(&no_encoder).unwrap_err().0;
    assert!(e.contains("missing section [encoder]"), "{e}");
    let long = REFERENCE.replacen(
        "mass_kg = 12.0",
        &format!("mass_kg = 12.0\n{} = 1.0", "k".repeat(5000)),
        1,
    );
    let e = MachineModel::parse(&long).unwrap_err().0;
    assert!(e.contains("unknown field") && e.len() < 400, "{e}");
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

    /// Several keys at once at the ends of their ranges or anywhere between (log-uniform):
    /// the model loads or is refused naming a rule — no panic, and a refusal is one line.
    #[test]
    fn in_range_extremes_load_or_are_refused_by_name(
        picks in proptest::collection::vec((0usize..1000, 0u8..4, 0.0f64..1.0), 1..8)
    ) {
        let lines = numeric_lines();
        let mut text: Vec<String> = REFERENCE.lines().map(str::to_string).collect();
        for (pick, how, u) in picks {
            let (i, key) = &lines[pick % lines.len()];
            let Some((lo, hi, _)) = range_of(key) else { continue };
            let v = match how {
                0 => lo,
                1 => hi,
                2 if lo > 0.0 => lo * (hi / lo).powf(u),
                _ => lo + (hi - lo) * u,
            };
            let v = if key.ends_with("counts_per_rev") || key.starts_with("simulation.") {
                format!("{}", v.round() as i64)
            } else {
                format!("{v:?}")
            };
            let k = text[*i].split('=').next().unwrap_or("").to_string();
            text[*i] = format!("{k}= {v}");
        }
        if let Err(e) = MachineModel::parse(&text.join("\n")) {
            prop_assert!(!e.0.is_empty() && !e.0.contains('\n') && e.0.len() < 400, "{}", e.0);
            prop_assert!(e.0.contains('`'), "names no key: {}", e.0);
        }
    }

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

#[test]
fn an_endless_or_huge_model_file_is_refused_without_reading_it_all() {
    let zero = std::path::Path::new("/dev/zero");
    if zero.exists() {
        let e = MachineModel::read(zero).unwrap_err().0;
        assert!(e.contains("larger than"), "{e}");
    }
    let scratch = tempfile::tempdir().expect("scratch directory");
    let d = scratch.path();
    let huge = d.join("huge.toml");
    let padding = "# padding\n".repeat(200_000);
    std::fs::write(&huge, format!("{REFERENCE}\n{padding}")).unwrap();
    let e = MachineModel::read(&huge).unwrap_err().0;
    assert!(e.contains("larger than"), "{e}");
    std::fs::write(&huge, [0xff, 0xfe, 0x00, 0x41]).unwrap();
    let e = MachineModel::read(&huge).unwrap_err().0;
    assert!(e.contains("not UTF-8"), "{e}");
}
