//! The proof of the model-gap workflow, one effect at a time: `hal-sim` synthesises a
//! "measured" run of a truth model with the effect present (the firmware in the loop through
//! `hal_sim::run::run`, or the prescribed closed-/open-port drive of `gap::synth` for the
//! pressure channel), the workflow runs with the model that lacks it, and it must name the
//! effect, fit its parameters near the truth and shrink the residual of its channel by at
//! least 70 %. A force outside the library (`[effects.extra_force]`, simulated by the plant)
//! must be named as no library effect and discovered as its basis terms.
//!
//! Fast cases run by default; the long Stribeck run is `#[ignore]` (CI runs
//! `cargo test --workspace --release -- --ignored`).

mod support;

use hal_sim::gap::synth;
use hal_sim::plant::model::MachineModel;
use support::gap::*;

const SHRINK: f64 = 0.70;

fn near(value: f64, truth: f64, rel: f64) -> bool {
    (value - truth).abs() <= rel * truth.abs()
}

#[test]
fn gap_names_a_wrong_mass_and_fits_it_within_3_percent() {
    let truth = with_key(&reference(), "piston", "mass_kg", "15.0");
    let j = gap(&reference(), &closed_loop(&truth, 2.3, 3, 11));
    show("mass", &j);
    assert_eq!(names(&j), ["mass_error"]);
    assert!(near(param(&j, "mass_error", "mass_kg"), 15.0, 0.03));
    assert!(shrink(&j, "force") >= SHRINK);
}

#[test]
fn gap_names_missing_coulomb_friction() {
    let truth = with_key(
        &with_key(&reference(), "friction", "coulomb_n", "80.0"),
        "friction",
        "static_n",
        "100.0",
    );
    let j = gap(&reference(), &closed_loop(&truth, 2.3, 3, 12));
    show("coulomb", &j);
    assert_eq!(names(&j), ["coulomb_friction"]);
    assert!(near(param(&j, "coulomb_friction", "coulomb_n"), 80.0, 0.05));
    assert!(shrink(&j, "force") >= SHRINK);
}

#[test]
fn gap_names_missing_viscous_friction() {
    let truth = with_key(&reference(), "friction", "viscous_ns_per_m", "100.0");
    let j = gap(&reference(), &closed_loop(&truth, 2.3, 3, 13));
    show("viscous", &j);
    assert_eq!(names(&j), ["viscous_friction"]);
    assert!(near(
        param(&j, "viscous_friction", "viscous_ns_per_m"),
        100.0,
        0.05
    ));
    assert!(shrink(&j, "force") >= SHRINK);
}

#[test]
fn gap_names_cogging_with_its_period_within_2_percent() {
    let truth = cogging_truth();
    let model = without_section(&reference(), "effects.cogging");
    let j = gap(&model, &closed_loop(&truth, 2.3, 3, 14));
    show("cogging", &j);
    assert_eq!(names(&j), ["cogging"]);
    assert!(near(param(&j, "cogging", "period_m"), 0.024, 0.02));
    assert!(near(param(&j, "cogging", "amplitude_n"), 45.0, 0.1));
    assert!((param(&j, "cogging", "phase_rad") - 0.7).abs() < 0.1);
    // The stated uncertainties cover the truth, and are tight enough to be worth stating.
    for (key, truth) in [
        ("period_m", 0.024),
        ("amplitude_n", 45.0),
        ("phase_rad", 0.7),
    ] {
        assert!(covers(&j, "cogging", key, truth, 4.0), "{key}");
        assert!(sigma(&j, "cogging", key) < 0.02 * truth, "{key}");
    }
    assert!(shrink(&j, "force") >= SHRINK);
}

#[test]
#[ignore = "slow: 15 s at 4 m/s and 20 kHz (≈ 300 000 samples)"]
fn gap_names_cogging_on_a_log_longer_than_its_searches_see() {
    // The force candidates' searches see the log's first `SEARCH_MAX_S`; the judgement, the
    // residual and the values reported (the named effect fitted once more on the whole log)
    // see all of it. The search on the first 4 s gave a period of 23.978 mm, an amplitude of
    // 45.29 N and a phase of 0.688 rad; the whole log 23.978 mm, 45.41 N and 0.686 rad, as a
    // search of the whole log finds them.
    let truth = cogging_truth();
    let model = without_section(&reference(), "effects.cogging");
    let log = closed_loop(&truth, 4.0, 70, 19);
    let t = log.column("t_s").expect("t_s logged");
    let seconds = t.last().copied().unwrap_or(0.0) - t.first().copied().unwrap_or(0.0);
    assert!(
        seconds > 1.25 * hal_sim::gap::effects::SEARCH_MAX_S,
        "a log of {seconds:.1} s is searched whole"
    );
    let j = gap(&model, &log);
    show("cogging, 15 s", &j);
    assert_eq!(names(&j), ["cogging"]);
    assert!(near(param(&j, "cogging", "period_m"), 0.024, 0.02));
    assert!(near(param(&j, "cogging", "amplitude_n"), 45.0, 0.1));
    assert!((param(&j, "cogging", "phase_rad") - 0.7).abs() < 0.1);
    assert!(shrink(&j, "force") >= SHRINK);
}

#[test]
fn gap_names_an_actuator_lag_within_0_1_ms() {
    let truth = format!(
        "{}\n[effects.actuator_lag]\ndelay_s = 0.0005\n",
        reference()
    );
    let j = gap(&reference(), &closed_loop(&truth, 4.0, 3, 15));
    show("actuator_lag", &j);
    assert_eq!(names(&j), ["actuator_lag"]);
    assert!((param(&j, "actuator_lag", "delay_s") - 0.5e-3).abs() < 0.1e-3);
    assert!(shrink(&j, "force") >= SHRINK);
}

#[test]
fn gap_names_the_papers_slave_lag_within_0_1_ms() {
    let truth = format!(
        "{}\n[effects.slave_lag]\ndelay_s = 0.00075\n",
        with_key(&reference(), "motor", "slave_follows_master", "true")
    );
    let j = gap(&reference(), &closed_loop(&truth, 2.3, 3, 16));
    show("slave_lag", &j);
    assert_eq!(names(&j), ["slave_lag"]);
    assert!((param(&j, "slave_lag", "delay_s") - 0.75e-3).abs() < 0.1e-3);
    assert!(covers(&j, "slave_lag", "delay_s", 0.75e-3, 4.0));
    assert!(shrink(&j, "slave_force") >= SHRINK);
}

#[test]
fn gap_names_an_encoder_pitch_error_and_no_pressure_effect() {
    let truth = format!(
        "{}\n[effects.encoder_pitch_error]\namplitude_m = 1.0e-4\nperiod_m = 0.024\n\
         phase_rad = 0.5\nscale = 2.0e-4\namplitude2_m = 3.0e-5\nphase2_rad = -1.0\n",
        reference()
    );
    let j = gap(&reference(), &closed_loop(&truth, 2.3, 3, 17));
    show("encoder_pitch_error", &j);
    assert_eq!(names(&j), ["encoder_pitch_error"]);
    let p = |k| param(&j, "encoder_pitch_error", k);
    assert!(near(p("period_m"), 0.024, 0.02));
    assert!(near(p("amplitude_m"), 1.0e-4, 0.1));
    assert!(near(p("scale"), 2.0e-4, 0.1));
    assert!(near(p("amplitude2_m"), 3.0e-5, 0.2));
    assert!(shrink(&j, "encoder") >= SHRINK);
}

/// The paper's closed-port campaign on the reference machine (leakage and heat transfer on).
#[test]
fn a_spring_the_plant_simulates_is_discovered_and_named_as_no_library_effect() {
    // `[effects.extra_force]` in the truth: the plant (firmware in the loop) simulates a
    // spring of 1500 N/m about x = 0.1 m that the workflow's library does not hold.
    let truth = format!(
        "{}\n[effects.extra_force]\nterms = {{ \"x\" = -1500.0, \"1\" = 150.0 }}\n",
        reference()
    );
    let j = gap(&reference(), &closed_loop(&truth, 2.0, 3, 18));
    show("spring", &j);
    assert!(names(&j).is_empty(), "{:?}", names(&j));
    let [d] = j.discovered.as_slice() else {
        panic!("discovered {:?}", j.discovered);
    };
    let term = |k: &str| d.terms.get(k).copied().unwrap_or(f64::NAN);
    assert_eq!(d.terms.len(), 2, "{:?}", d.terms);
    assert!(near(term("x"), -1500.0, 0.03), "{:?}", d.terms);
    assert!(near(term("1"), 150.0, 0.05), "{:?}", d.terms);
    assert!(d.rms_after <= (1.0 - SHRINK) * d.rms_before, "{d:?}");
}

fn closed_port_log(truth: &str, seed: u64) -> hal_sim::runlog::RunLog {
    let m = MachineModel::parse(truth).unwrap();
    let (start, moves) = synth::closed_port_moves(&m, 1);
    synth::closed_port_run(&m, start, &moves, seed)
}

#[test]
fn gap_names_leakage_from_the_pressure_decay() {
    let log = closed_port_log(&reference(), 21);
    let j = gap(&without_section(&reference(), "effects.leakage"), &log);
    show("leakage", &j);
    assert_eq!(names(&j), ["leakage"]);
    assert!(near(param(&j, "leakage", "gap_m"), 25e-6, 0.05));
    assert!(covers(&j, "leakage", "gap_m", 25e-6, 4.0));
    assert!(shrink(&j, "pressure") >= SHRINK);
}

#[test]
fn gap_names_heat_transfer_from_the_relaxation_toward_the_wall() {
    let log = closed_port_log(&reference(), 22);
    let j = gap(
        &without_section(&reference(), "effects.heat_transfer"),
        &log,
    );
    show("heat_transfer", &j);
    assert_eq!(names(&j), ["heat_transfer"]);
    assert!(near(param(&j, "heat_transfer", "ua_w_per_k"), 5.0, 0.05));
    assert!(shrink(&j, "pressure") >= SHRINK);
}

#[test]
fn gap_names_a_port_restriction_while_the_ports_are_open() {
    let truth = format!(
        "{}\n[effects.port_restriction]\narea_scale = 0.4\n",
        reference()
    );
    let t = MachineModel::parse(&truth).unwrap();
    let log = synth::open_port_run(&t, 3.1, 2.3, 2.0, 23);
    let j = gap(&reference(), &log);
    show("port_restriction", &j);
    assert_eq!(names(&j), ["port_restriction"]);
    assert!(near(param(&j, "port_restriction", "area_scale"), 0.4, 0.05));
    assert!(shrink(&j, "pressure") >= SHRINK);
}

#[test]
#[ignore = "slow: 12 s of creeping strokes at 0.1 m/s (≈ 250 000 samples)"]
fn gap_names_stribeck_friction_where_it_lives() {
    let plain = with_key(&reference(), "friction", "static_n", "40.0");
    let truth = format!(
        "{plain}\n[effects.stribeck_friction]\nstatic_n = 100.0\nvelocity_mps = 0.02\nexponent = 1.0\n"
    );
    let j = gap(&plain, &closed_loop(&truth, 0.1, 1, 18));
    show("stribeck", &j);
    assert_eq!(names(&j), ["stribeck_friction"]);
    assert!(near(param(&j, "stribeck_friction", "static_n"), 100.0, 0.1));
    assert!(near(
        param(&j, "stribeck_friction", "velocity_mps"),
        0.02,
        0.25
    ));
    let e = j.effects.first().unwrap();
    let (before, after) = (e.region_rms_before.unwrap(), e.region_rms_after.unwrap());
    assert!(
        1.0 - after / before >= SHRINK,
        "low-speed RMS {before} → {after}"
    );
}

#[test]
#[ignore = "slow: two strokes at 0.3 m/s"]
fn gap_names_a_leak_on_a_slow_high_ratio_run() {
    // Slow strokes at a high ratio hold the chambers shut and far apart in pressure for
    // long: the leak's own ground, named with a wide margin and its gap within 10 %.
    let model = without_section(&reference(), "effects.leakage");
    let j = gap(&model, &compressing(&reference(), 4.5, 0.3, 2, 42));
    show("leakage, PR 4.5, 0.3 m/s", &j);
    assert_eq!(names(&j), ["leakage"]);
    assert!(near(param(&j, "leakage", "gap_m"), 25e-6, 0.1));
    assert!(shrink(&j, "pressure") >= SHRINK);
}
