//! The model-gap workflow on a plant it has never seen: seeded cases from
//! `independent_plant` (its own integrator, controller, chambers and logger, sharing no code
//! with `hal-sim`), null or hiding one effect or a pair at random magnitudes above their
//! detection floors, at 5, 10 and 20 kHz, sine, trapezoid and hold-and-move strokes, vented or
//! sealed chambers. Each log goes through the workflow exactly as `fpc-sim gap` takes it.
//!
//! Scored by the benchmarks' one scorer (`support::gap::score`, shared with the foreign
//! plant's benchmark). Printed: per-effect recall, the false-alarm rate on null logs, the
//! rate of logs with a wrong extra effect, and the parameter errors (cogging period, lags,
//! mass), then every case that went wrong with its seed. Asserted: the acceptance of issue #13 — recall ≥ 95 %
//! for every effect, false alarms on ≤ 1 % of null logs, wrong extras on ≤ 2 % of logs,
//! cogging period ± 2 %, lags ± 0.05 ms, mass ± 3 %.
//!
//! **Forces outside the library** (issue #30): the plant also hides a spring, a bias, quadratic
//! drag, a force-constant error or a drifting friction, which no library effect describes.
//! Scored per form: *described* (no library effect named, and exactly the form's terms of the
//! discovery basis found, each coefficient within 15 %, a constant within 15 % or 10 N),
//! *named as a library effect* (a wrong name for it), or *missed*. Asserted: described in
//! ≥ 90 % of each form's cases, named as a library effect in ≤ 2 %. A slice of 10 runs by
//! default, the full run (100) with the other ignored benchmark.
//!
//! **The field logs' forms** (d08–d11 of `gap_names_effects_in_foreign_field_logs.rs`, drawn
//! here at random): friction growing along the bore, a hardening spring, a pressure
//! transducer's or a force reading's offset or gain, and three library effects at once.
//! Each is right as its field log is (`support::forms::Want`); asserted: right in ≥ 95 % of
//! each form's cases, a library effect named falsely in ≤ 2 %, except for the forms measured
//! short of it on this plant ([`SHORT_OF_ACCEPTANCE`]), whose figures are printed. A slice of
//! one case per form by default, the full run (20 per form, `FPC_FIELD_FORM_CASES`) with the
//! other ignored benchmarks.
//!
//! A slice of 26 cases runs by default; the full benchmark (≥ 500 cases) is
//! `cargo test --profile slow-tests --test gap_generalises_to_another_plant -- --ignored --nocapture`.

mod independent_plant;
mod support;

use std::collections::BTreeMap;
use std::time::Instant;

use independent_plant::{draw_case, generate, Case, Hidden, EFFECTS, FORMS, TRIPLES};
use support::forms::{
    field_form_cases, judge, run_field_forms, write_case_if_asked, Check, FieldCase, Want,
};
use support::gap::{
    bench_cases, classify_form, form_cases, form_seed_runs, name_effects, par_map, score,
    score_forms, Acceptance, BenchCase, FormCase, FormOutcome, ParamError, ParamRule,
};

/// The acceptance of issue #13: recall ≥ 95 %, false alarms on ≤ 1 % of null logs, wrong
/// extras on ≤ 2 % of logs, and every named parameter within its tolerance.
const ACCEPTANCE: Acceptance = Acceptance {
    min_recall_percent: 95.0,
    max_false_alarm_percent: 1.0,
    max_wrong_extra_percent: 2.0,
    params: ParamRule::Every,
};

/// The case of `seed` hiding `effects`, generated, analysed and scored against its truth.
fn run_case(seed: u64, effects: &[&str]) -> BenchCase {
    let case = draw_case(seed, effects);
    let started = Instant::now();
    let g = generate(&case);
    let named = name_effects(&g.csv, &g.model_toml);
    let params = match &named {
        Ok(n) => param_errors(&case, n),
        Err(_) => vec![],
    };
    BenchCase {
        label: format!(
            "seed {} ({} Hz, {:?}, {:?})",
            case.seed, case.rate_hz, case.trajectory, case.chambers
        ),
        group: format!("{:>2} kHz {:?}", case.rate_hz / 1e3, case.chambers),
        hidden: case.hidden.iter().map(|h| h.name().to_string()).collect(),
        named,
        params,
        seconds: started.elapsed().as_secs_f64(),
    }
}

/// The parameter errors where a hidden effect was named: cogging period ± 2 %, lags
/// ± 0.05 ms, mass ± 3 %.
fn param_errors(case: &Case, named: &BTreeMap<String, BTreeMap<String, f64>>) -> Vec<ParamError> {
    let p = |effect: &str, key: &str| named.get(effect).and_then(|m| m.get(key)).copied();
    let mut out = Vec::new();
    for h in &case.hidden {
        match *h {
            Hidden::Cogging { period_m, .. } => {
                if let Some(f) = p("cogging", "period_m") {
                    out.push(ParamError {
                        what: "cogging period, %",
                        error: 100.0 * (f / period_m - 1.0).abs(),
                        tolerance: 2.0,
                        detail: format!("{f:.5} m vs {period_m:.5}"),
                    });
                }
            }
            Hidden::SlaveLag { delay_s } | Hidden::ActuatorLag { delay_s } => {
                if let Some(f) = p(h.name(), "delay_s") {
                    out.push(ParamError {
                        what: "lags, ms",
                        error: 1e3 * (f - delay_s).abs(),
                        tolerance: 0.05,
                        detail: format!(
                            "{} {:.4} ms vs {:.4} ms",
                            h.name(),
                            f * 1e3,
                            delay_s * 1e3
                        ),
                    });
                }
            }
            Hidden::Mass { factor } => {
                if let Some(f) = p("mass_error", "mass_kg") {
                    let truth = case.nominal.mass_kg * factor;
                    out.push(ParamError {
                        what: "mass, %",
                        error: 100.0 * (f / truth - 1.0).abs(),
                        tolerance: 3.0,
                        detail: format!("{f:.3} kg vs {truth:.3}"),
                    });
                }
            }
            _ => {}
        }
    }
    out
}

/// The case list: `nulls` null cases, `singles` per effect, and `pairs` pairs drawn from
/// the effects that can share a log.
fn plan(nulls: u64, singles: u64, pairs: u64) -> Vec<(u64, Vec<&'static str>)> {
    let mut out = Vec::new();
    let mut seed = 1000;
    for _ in 0..nulls {
        out.push((seed, vec![]));
        seed += 1;
    }
    for e in EFFECTS {
        for _ in 0..singles {
            out.push((seed, vec![e]));
            seed += 1;
        }
    }
    // Pairs of effects in different channels or of different signatures, compatible in
    // their chamber and trajectory needs.
    const PAIRS: [(&str, &str); 10] = [
        ("cogging", "slave_lag"),
        ("mass_error", "slave_lag"),
        ("cogging", "encoder_pitch_error"),
        ("viscous_friction", "slave_lag"),
        ("actuator_lag", "encoder_pitch_error"),
        ("mass_error", "cogging"),
        ("leakage", "slave_lag"),
        ("heat_transfer", "cogging"),
        ("coulomb_friction", "encoder_pitch_error"),
        ("actuator_lag", "slave_lag"),
    ];
    for i in 0..pairs {
        let (a, b) = PAIRS[(i as usize) % PAIRS.len()];
        out.push((seed, vec![a, b]));
        seed += 1;
    }
    out
}

#[test]
fn gap_generalises_to_a_slice_of_cases_from_another_plant() {
    let plan = plan(6, 1, 10);
    let cases = par_map(plan.len(), |i| run_case(plan[i].0, &plan[i].1));
    let problems = score("the independent plant", &cases, &ACCEPTANCE);
    assert!(problems.is_empty(), "{problems:#?}");
}

#[test]
#[ignore = "slow: 510 cases, about ten minutes on two cores"]
fn gap_generalises_to_510_cases_from_another_plant() {
    let plan = plan(160, 25, 100);
    let which = bench_cases(plan.len());
    let cases = par_map(which.len(), |i| {
        run_case(plan[which[i]].0, &plan[which[i]].1)
    });
    let problems = score("the independent plant", &cases, &ACCEPTANCE);
    assert!(problems.is_empty(), "{problems:#?}");
}

/// The plant itself: what the logs must show whatever the workflow does with them.
#[test]
fn the_independent_plant_logs_what_it_should() {
    let col = |csv: &str, name: &str| -> Vec<f64> {
        let mut lines = csv.lines().filter(|l| !l.starts_with('#'));
        let header: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
        let j = header.iter().position(|h| *h == name).expect("column");
        lines
            .map(|l| {
                l.split(',')
                    .nth(j)
                    .and_then(|v| v.parse().ok())
                    .expect("number")
            })
            .collect()
    };
    // Vented: pressures within a few kPa of ambient, the piston follows its strokes.
    let mut vented = draw_case(7, &["cogging"]);
    vented.chambers = independent_plant::Chambers::Vented;
    let g = generate(&vented);
    assert!(!g.csv.contains("# ports"));
    let pa = col(&g.csv, "p_a_pa");
    assert!(pa.iter().all(|p| (p - 101_325.0).abs() < 5_000.0));
    let x = col(&g.csv, "x_m");
    let span =
        x.iter().copied().fold(f64::MIN, f64::max) - x.iter().copied().fold(f64::MAX, f64::min);
    assert!(span > 0.05, "the piston moves: span {span}");
    assert!(x.iter().all(|x| *x > 0.0 && *x < 0.205));
    // Slave lag: the logged slave force is the master's, late by the lag.
    let lagged = draw_case(11, &["slave_lag"]);
    let Hidden::SlaveLag { delay_s } = lagged.hidden[0] else {
        panic!("a slave lag")
    };
    let g = generate(&lagged);
    let (m, s) = (col(&g.csv, "f_master_n"), col(&g.csv, "f_slave_n"));
    let dt = 1.0 / lagged.rate_hz;
    let k = (delay_s / dt).round() as usize;
    let rms = |shift: usize| -> f64 {
        let n = m.len() - shift;
        ((0..n).map(|i| (s[i + shift] - m[i]).powi(2)).sum::<f64>() / n as f64).sqrt()
    };
    assert!(
        rms(k) < 0.5 * rms(0),
        "aligned {} against {}",
        rms(k),
        rms(0)
    );
    // Sealed, no effects: adiabatic, so p·V^γ of each chamber stays put.
    let mut sealed = draw_case(5, &["leakage"]);
    sealed.hidden.clear();
    let g = generate(&sealed);
    assert!(g.csv.contains("# ports = closed"));
    let (x, pa) = (col(&g.csv, "x_m"), col(&g.csv, "p_a_pa"));
    let n = &sealed.nominal;
    let pv = |i: usize| pa[i] * (n.area_m2() * (x[i] + n.dead_m)).powf(1.4);
    // Mean over 100 rows at each end (the start is a rest, the end a hold): 0.4 kPa of noise
    // on a reading is 0.4 %.
    let mean = |r: std::ops::Range<usize>| r.clone().map(pv).sum::<f64>() / r.len() as f64;
    let (first, last) = (mean(0..100), mean(x.len() - 100..x.len()));
    assert!((last / first - 1.0).abs() < 0.003, "{first} → {last}");
    assert!(
        pa.iter().copied().fold(0.0, f64::max) > 1.5e5,
        "the sealed chamber compresses"
    );
}

/// Writes one case's log and nominal model for `fpc-sim gap`, to look at a failure:
/// `FPC_CASE=1012:slave_lag cargo test --test gap_generalises_to_another_plant
/// write_one_case -- --ignored --nocapture` (effects comma-separated, none for a null case).
#[test]
#[ignore = "a tool: writes the case named by FPC_CASE"]
fn write_one_case() {
    let spec = std::env::var("FPC_CASE").unwrap_or_else(|_| "1000:".into());
    let (seed, effects) = spec.split_once(':').unwrap_or((&spec, ""));
    let seed: u64 = seed.parse().expect("FPC_CASE=SEED:effect,effect");
    let effects: Vec<&str> = effects.split(',').filter(|e| !e.is_empty()).collect();
    let case = draw_case(seed, &effects);
    let g = generate(&case);
    // A directory of its own, kept for the user who named a case (removed after CI's run).
    let tmp = tempfile::Builder::new()
        .prefix(&format!("fpc-case-{seed}-"))
        .tempdir()
        .expect("case directory");
    let dir = tmp.path().to_path_buf();
    std::fs::write(dir.join("run.csv"), &g.csv).expect("run.csv");
    std::fs::write(dir.join("model.toml"), &g.model_toml).expect("model.toml");
    // What was written is the case the benchmark scores, through the readers `fpc-sim gap`
    // uses, and gap takes it.
    let log = hal_sim::runlog::RunLog::read(&dir.join("run.csv")).expect("run.csv reads");
    assert_eq!(Ok(&log), hal_sim::runlog::RunLog::parse(&g.csv).as_ref());
    let model = hal_sim::plant::model::MachineModel::read(&dir.join("model.toml"))
        .expect("model.toml reads");
    assert_eq!(
        Ok(model),
        hal_sim::plant::model::MachineModel::parse(&g.model_toml)
    );
    hal_sim::gap::analyse(&g.model_toml, &log, &hal_sim::gap::GapOptions::default())
        .unwrap_or_else(|f| panic!("gap refuses the case: {}", f.message));
    if std::env::var_os("FPC_CASE").is_some() {
        let _ = tmp.keep();
        println!("{case:?}\nwrote {}", dir.display());
    }
}

/// The case of `seed` hiding the out-of-library `form`, analysed and classified.
fn run_form_case(seed: u64, form: &str) -> FormCase {
    let case = draw_case(seed, &[form]);
    let Some(want) = case.hidden.first().and_then(Hidden::discovered_terms) else {
        return FormCase {
            form: form.into(),
            outcome: FormOutcome::Missed,
            detail: "not a form".into(),
        };
    };
    let g = generate(&case);
    let label = format!(
        "seed {seed} {form} ({} Hz, {:?}, {:?}) truth {want:?}",
        case.rate_hz, case.trajectory, case.chambers
    );
    classify_form(form, &g.csv, &g.model_toml, &want, &label)
}

/// Runs `per_form` cases of each form and returns what misses the acceptance.
fn score_forms_here(per_form: u64) -> Vec<String> {
    let plan: Vec<(u64, &str)> = FORMS
        .iter()
        .enumerate()
        .flat_map(|(i, f)| (0..per_form).map(move |k| (7000 + 100 * i as u64 + k, *f)))
        .filter(|(seed, _)| form_seed_runs(*seed))
        .collect();
    let results = par_map(plan.len(), |i| run_form_case(plan[i].0, plan[i].1));
    score_forms("independent plant", &FORMS, &results)
}

#[test]
fn gap_describes_forces_outside_its_library_in_a_slice_of_cases() {
    let problems = score_forms_here(2);
    assert!(problems.is_empty(), "{problems:#?}");
}

#[test]
#[ignore = "slow: 100 cases of forces outside the library (FPC_FORM_CASES per form, 20)"]
fn gap_describes_forces_outside_its_library_in_100_cases() {
    let problems = score_forms_here(form_cases());
    assert!(problems.is_empty(), "{problems:#?}");
}

/// What a right answer is for `case`, which hides the field-log form `form`.
fn want_of(case: &Case, form: &str) -> Want {
    if form == "triple" {
        let effects: Vec<&'static str> = case.hidden.iter().map(Hidden::name).collect();
        let mut checks = Vec::new();
        for h in &case.hidden {
            match *h {
                Hidden::Mass { factor } => {
                    let m = case.nominal.mass_kg * factor;
                    checks.push(Check::within("mass_error", "mass_kg", m, 0.03 * m));
                }
                Hidden::Coulomb { delta_n } => {
                    let c = case.nominal.coulomb_n + delta_n;
                    checks.push(Check::within("coulomb_friction", "coulomb_n", c, 0.1 * c));
                }
                Hidden::Cogging { period_m, .. } => {
                    checks.push(Check::within(
                        "cogging",
                        "period_m",
                        period_m,
                        0.02 * period_m,
                    ));
                }
                Hidden::SlaveLag { delay_s } | Hidden::ActuatorLag { delay_s } => {
                    checks.push(Check::within(h.name(), "delay_s", delay_s, 0.05e-3));
                }
                _ => {}
            }
        }
        return Want::Named { effects, checks };
    }
    let Some(&h) = case.hidden.first() else {
        return Want::Named {
            effects: vec![],
            checks: vec![],
        };
    };
    // A sensor's two keys: the one in error within 10 % of its error, the other within 10 %
    // of that error of its exact value.
    let pair = |name: &'static str, keys: [&'static str; 2], second: bool, exact: f64, v: f64| {
        let tol = 0.1 * (v - exact).abs();
        let (bad, good) = if second {
            (keys[1], keys[0])
        } else {
            (keys[0], keys[1])
        };
        Want::Named {
            effects: vec![name],
            checks: vec![
                Check::within(name, bad, v, tol),
                Check::within(name, good, exact, tol),
            ],
        }
    };
    match h {
        Hidden::PositionFriction { .. } => Want::LeftByPosition,
        Hidden::PressureOffset {
            chamber_b,
            offset_pa,
        } => pair(
            "pressure_offset",
            ["offset_a_pa", "offset_b_pa"],
            chamber_b,
            0.0,
            offset_pa,
        ),
        Hidden::PressureGain { chamber_b, gain } => {
            pair("pressure_gain", ["gain_a", "gain_b"], chamber_b, 1.0, gain)
        }
        Hidden::ForceOffset { slave, offset_n } => pair(
            "force_offset",
            ["offset_master_n", "offset_slave_n"],
            slave,
            0.0,
            offset_n,
        ),
        Hidden::ForceGain { slave, gain } => pair(
            "force_gain",
            ["gain_master", "gain_slave"],
            slave,
            1.0,
            gain,
        ),
        h => Want::Terms(h.discovered_terms().unwrap_or_default()),
    }
}

/// Case `k` of the field-log form `form` (seed `seed`), generated, analysed and judged.
fn run_field_case(seed: u64, form: &str, k: u64) -> FieldCase {
    let effects: Vec<&str> = if form == "triple" {
        TRIPLES[(k as usize) % TRIPLES.len()].to_vec()
    } else {
        vec![form]
    };
    let case = draw_case(seed, &effects);
    let want = want_of(&case, form);
    let g = generate(&case);
    let label = format!(
        "seed {seed} {form} ({} Hz, {:?}, {:?}) truth {:?}",
        case.rate_hz, case.trajectory, case.chambers, case.hidden
    );
    write_case_if_asked(seed, &g.csv, &g.model_toml);
    judge(form, &g.csv, &g.model_toml, &want, &label)
}

/// The field-log forms measured short of the acceptance on this plant (`docs/gap.md`).
const SHORT_OF_ACCEPTANCE: [&str; 2] = ["position_friction", "triple"];

/// Runs `per_form` cases of each field-log form and returns what misses the acceptance.
fn score_field_forms_here(per_form: u64) -> Vec<String> {
    run_field_forms(
        "independent plant",
        27_000,
        per_form,
        &SHORT_OF_ACCEPTANCE,
        run_field_case,
    )
}

#[test]
fn gap_meets_the_field_logs_forms_in_a_slice_of_cases() {
    let problems = score_field_forms_here(1);
    assert!(problems.is_empty(), "{problems:#?}");
}

#[test]
#[ignore = "slow: 140 cases of the field logs' forms (FPC_FIELD_FORM_CASES per form, 20)"]
fn gap_meets_the_field_logs_forms_in_140_cases() {
    let problems = score_field_forms_here(field_form_cases());
    assert!(problems.is_empty(), "{problems:#?}");
}
