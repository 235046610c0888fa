//! The sections' force readings as effects of the workflow: a run of the firmware on a plant
//! whose one section reports its force offset or scaled (`[sensors.force]`, the log's
//! `f_master_n` / `f_slave_n`), analysed with the model that reads them as exact, must name
//! `force_offset` or `force_gain` with the hidden section's value within 10 % of its error,
//! and no force effect beside it. A force that really acts on the piston, constant as an
//! offset, leaves both readings alike and must not be named as a reading's offset.
//!
//! Both readings offset alike are a constant force on every channel the log has: that is
//! not told apart, and not tested here (`docs/gap.md`).

mod support;

use support::gap::*;

/// The reference machine with `[sensors.force] key = value`.
fn reading_truth(key: &str, value: &str) -> String {
    with_key(&reference(), "sensors.force", key, value)
}

#[test]
fn the_plant_logs_each_sections_force_through_its_reading() {
    let exact = closed_loop(&reference(), 2.3, 1, 25);
    let truth = with_key(
        &reading_truth("offset_master_n", "40.0"),
        "sensors.force",
        "gain_slave",
        "1.05",
    );
    let read = closed_loop(&truth, 2.3, 1, 25);
    let col = |log: &hal_sim::runlog::RunLog, name: &str| log.column(name).unwrap().to_vec();
    // The machine runs as it did: only the logged readings differ.
    assert_eq!(col(&exact, "x_m"), col(&read, "x_m"));
    let pairs = |name: &str| {
        let (a, b) = (col(&exact, name), col(&read, name));
        assert_eq!(a.len(), b.len());
        a.into_iter().zip(b).collect::<Vec<_>>()
    };
    // Logged to 4 decimals of a float: within a milli-newton per kilonewton.
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-3 + 1e-6 * a.abs().max(b.abs());
    assert!(pairs("f_master_n").iter().all(|(f, r)| close(*r, f + 40.0)));
    assert!(pairs("f_slave_n").iter().all(|(f, r)| close(*r, 1.05 * f)));
    assert!(pairs("f_slave_n").iter().any(|(f, _)| f.abs() > 100.0));
}

#[test]
fn gap_names_the_master_readings_offset_and_no_force() {
    let truth = reading_truth("offset_master_n", "40.0");
    let j = gap(&reference(), &closed_loop(&truth, 2.3, 3, 21));
    show("force_offset master", &j);
    assert_eq!(names(&j), ["force_offset"]);
    let master = param(&j, "force_offset", "offset_master_n");
    let slave = param(&j, "force_offset", "offset_slave_n");
    assert!((master - 40.0).abs() <= 4.0, "master offset {master} N");
    assert!(slave.abs() <= 4.0, "slave offset {slave} N");
    // The stated uncertainty (force and slave-force residuals together) covers the truth.
    assert!(covers(&j, "force_offset", "offset_master_n", 40.0, 4.0));
    assert!(covers(&j, "force_offset", "offset_slave_n", 0.0, 4.0));
    assert!(shrink(&j, "force") >= 0.7);
    assert!(shrink(&j, "slave_force") >= 0.7);
}

#[test]
fn gap_names_the_slave_readings_offset_and_no_force() {
    let truth = reading_truth("offset_slave_n", "-30.0");
    let j = gap(&reference(), &closed_loop(&truth, 2.3, 3, 22));
    show("force_offset slave", &j);
    assert_eq!(names(&j), ["force_offset"]);
    let master = param(&j, "force_offset", "offset_master_n");
    let slave = param(&j, "force_offset", "offset_slave_n");
    assert!((slave + 30.0).abs() <= 3.0, "slave offset {slave} N");
    assert!(master.abs() <= 3.0, "master offset {master} N");
}

#[test]
fn gap_names_the_slave_readings_gain_and_no_mass() {
    let truth = reading_truth("gain_slave", "1.05");
    let j = gap(&reference(), &closed_loop(&truth, 2.3, 3, 23));
    show("force_gain slave", &j);
    assert_eq!(names(&j), ["force_gain"]);
    let slave = param(&j, "force_gain", "gain_slave");
    let master = param(&j, "force_gain", "gain_master");
    assert!((slave - 1.05).abs() <= 0.005, "slave gain {slave}");
    assert!((master - 1.0).abs() <= 0.005, "master gain {master}");
    assert!(covers(&j, "force_gain", "gain_slave", 1.05, 4.0));
    assert!(covers(&j, "force_gain", "gain_master", 1.0, 4.0));
    assert!(shrink(&j, "slave_force") >= 0.7);
}

#[test]
fn a_constant_force_on_the_piston_is_not_named_as_a_readings_offset() {
    // The plant (firmware in the loop) pushes the piston with 60 N toward +x: both
    // sections report what they make, and the force balance lacks 60 N.
    let truth = format!(
        "{}\n[effects.extra_force]\nterms = {{ \"1\" = 60.0 }}\n",
        reference()
    );
    let j = gap(&reference(), &closed_loop(&truth, 2.3, 3, 24));
    show("constant force", &j);
    let named = names(&j);
    assert!(!named.iter().any(|n| n.starts_with("force_")), "{named:?}");
    // The force is there to be found: the workflow describes it as a discovered constant.
    let constant = j
        .discovered
        .iter()
        .find_map(|d| d.terms.get("1"))
        .copied()
        .unwrap_or(0.0);
    assert!(
        (constant - 60.0).abs() <= 6.0,
        "constant force {constant} N"
    );
}
