//! The reference machine is written once, in `hal-sim/src/plant/model/reference.toml` (every
//! value with its origin). The firmware, which has no machine model, reads it from
//! `src/reference.rs`, generated from that file: this test renders the module from the TOML
//! and fails if the checked-in one differs (`FPC_BLESS_REFERENCE=1` rewrites it after a
//! deliberate change of the TOML). The controller's view of a machine is one mapping,
//! `MachineModel::machine` → `ControlConfig::for_machine`, for the reference as for any other
//! model; the built-in configuration is that mapping of the reference.

use std::path::PathBuf;

use fpc::control::config::{ControlConfig, Machine};
use hal_sim::plant::model::{MachineModel, REFERENCE_TOML};

fn generated_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../src/reference.rs")
}

/// A constant's Rust literal and type for a TOML value (numbers as `f64`, whole numbers as
/// `u32`, arrays of numbers as `[f64; N]`).
fn literal(key: &str, value: &toml::Value) -> (String, String) {
    let float = |v: f64| format!("{v:?}");
    match value {
        toml::Value::Float(v) => ("f64".into(), float(*v)),
        toml::Value::Integer(v) => {
            let v = u32::try_from(*v).unwrap_or_else(|_| panic!("{key}: {v} is not a u32"));
            ("u32".into(), format!("{v}"))
        }
        toml::Value::Boolean(b) => ("bool".into(), format!("{b}")),
        toml::Value::Array(items) => {
            let numbers: Vec<String> = items
                .iter()
                .map(|i| match i {
                    toml::Value::Float(v) => float(*v),
                    toml::Value::Integer(v) => float(*v as f64),
                    other => panic!("{key}: an array of {other:?}"),
                })
                .collect();
            (
                format!("[f64; {}]", numbers.len()),
                format!("[{}]", numbers.join(", ")),
            )
        }
        other => panic!("{key}: a {other:?} has no constant"),
    }
}

/// The module body for `table` at `depth` (its keys as constants, its sub-tables as modules),
/// in the file's order of keys (the `toml` crate keeps them sorted: stable either way).
fn render(table: &toml::Table, path: &str, depth: usize, out: &mut String) {
    let pad = "    ".repeat(depth);
    for (key, value) in table {
        let full = if path.is_empty() {
            key.clone()
        } else {
            format!("{path}.{key}")
        };
        if let toml::Value::Table(sub) = value {
            out.push_str(&format!("{pad}/// `[{full}]`.\n{pad}pub mod {key} {{\n"));
            render(sub, &full, depth + 1, out);
            out.push_str(&format!("{pad}}}\n"));
        } else {
            let (ty, lit) = literal(&full, value);
            out.push_str(&format!(
                "{pad}/// `{full}`.\n{pad}pub const {}: {ty} = {lit};\n",
                key.to_uppercase()
            ));
        }
    }
}

fn generated() -> String {
    let table: toml::Table = REFERENCE_TOML.parse().expect("reference.toml parses");
    let mut out = String::from(
        "//! The reference machine of `docs/machine.md`, generated from its one source,\n\
         //! `hal-sim/src/plant/model/reference.toml` (each value's origin is written there): do\n\
         //! not edit. `FPC_BLESS_REFERENCE=1 cargo test -p hal-sim --test\n\
         //! the_reference_machine_is_written_once` regenerates it after the TOML changed. One\n\
         //! module per section, one constant per key, SI units as the keys name them.\n\n",
    );
    render(&table, "", 0, &mut out);
    out
}

#[test]
fn the_firmware_s_reference_machine_is_generated_from_reference_toml() {
    let want = generated();
    let path = generated_path();
    if std::env::var_os("FPC_BLESS_REFERENCE").is_some() {
        std::fs::write(&path, &want).expect("write src/reference.rs");
    }
    let have = std::fs::read_to_string(&path).expect("read src/reference.rs");
    assert!(
        have == want,
        "src/reference.rs is not what reference.toml gives: run \
         `FPC_BLESS_REFERENCE=1 cargo test -p hal-sim --test the_reference_machine_is_written_once`"
    );
}

#[test]
fn the_built_in_configuration_is_the_reference_model_s_but_for_the_calibration() {
    // The flashed firmware has no machine model: it runs `ControlConfig::reference()`, with
    // the calibration record from its flash on top; the simulator derives its controller's
    // configuration from the model. Both are the one mapping of the same machine.
    let model = MachineModel::reference();
    assert_eq!(model.machine(), Machine::reference());
    let flashed = ControlConfig::reference();
    let mut modelled = hal_sim::run::control_config(&model);
    // What the calibration record brings at boot (`CalibrationRecord::apply`): the cogging
    // map the routine measures. The model's true map stands in for it in the simulator.
    modelled.allocation.cogging = flashed.allocation.cogging;
    assert_eq!(flashed, modelled);
}

#[test]
fn another_machine_changes_the_configuration_where_its_values_differ() {
    let mut model = MachineModel::reference();
    model.piston.mass_kg = 15.0;
    model.servo.inertia_kgm2 = 3e-3;
    let c = hal_sim::run::control_config(&model);
    assert_eq!(c.moving_mass_kg, 15.0);
    assert_eq!(c.servo.inertia_kgm2, 3e-3);
    assert_eq!(c.travel_m, ControlConfig::reference().travel_m);
}
