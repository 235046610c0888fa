//! The model-gap workflow on logs it has never seen: the field logs of `tests/data/field-logs`
//! come from a plant, a controller and a logger written outside this project (another
//! integrator, commanded forces logged on their own time convention, 10 and 20 kHz, vented
//! or sealed chambers), gzipped as delivered. Each comes with the nominal model a user would
//! hold and `truth.json` says what was hidden from it. The workflow must name exactly that,
//! with the slave lag within 0.05 ms and the cogging period within 2 %, and discover nothing
//! more; where what was hidden is outside the library (d05 a spring, d06 quadratic drag) it
//! must name no library effect and describe the force by `truth.json`'s `discovered_terms`.
//! In d07 (sealed) two pressure effects act together: both must be named. d09's hardening
//! spring is described by the basis's cubic terms and no periodic one; d10's chamber-A
//! transducer offset is named as the sensor's error, not as a force; d11 names three effects
//! at once at 20 kHz.

use std::collections::BTreeMap;
use std::path::PathBuf;

use hal_sim::gap::{analyse, GapJson, GapOptions};
use hal_sim::runlog::RunLog;

fn dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/field-logs")
}

/// The hidden effects of `log` in `truth.json`, with their parameters.
fn truth(log: &str) -> BTreeMap<String, BTreeMap<String, f64>> {
    let text = std::fs::read_to_string(dir().join("truth.json")).expect("truth.json");
    let v: serde_json::Value = serde_json::from_str(&text).expect("truth.json parses");
    let hidden = v
        .get(log)
        .and_then(|l| l.get("hidden"))
        .and_then(|h| h.as_object())
        .expect("a `hidden` object");
    hidden
        .iter()
        .map(|(name, params)| {
            let p = params
                .as_object()
                .map(|o| {
                    o.iter()
                        .filter_map(|(k, v)| Some((k.clone(), v.as_f64()?)))
                        .collect()
                })
                .unwrap_or_default();
            (name.clone(), p)
        })
        .collect()
}

/// Runs the workflow on `dNN.csv.gz` with `dNN.toml`, as `fpc-sim gap` does.
fn gap(log: &str) -> GapJson {
    let measured =
        RunLog::read(&dir().join(format!("{log}.csv.gz"))).expect("the gzipped log reads");
    let model = std::fs::read_to_string(dir().join(format!("{log}.toml"))).expect("model");
    let out = analyse(&model, &measured, &GapOptions::default()).expect("analysis runs");
    let j = out.json;
    println!(
        "{log}: named {:?}; forces act {:.4} ms after their row ({})",
        j.effects.iter().map(|e| &e.name).collect::<Vec<_>>(),
        j.force_align_s * 1e3,
        if j.force_align_fitted {
            "fitted"
        } else {
            "declared"
        }
    );
    for e in &j.effects {
        println!("  {} {:?}", e.name, e.params);
    }
    j
}

fn check(log: &str) -> GapJson {
    let j = gap(log);
    let mut named: Vec<&str> = j.effects.iter().map(|e| e.name.as_str()).collect();
    named.sort_unstable();
    let hidden = truth(log);
    let expected: Vec<&str> = hidden.keys().map(String::as_str).collect();
    assert_eq!(named, expected, "{log}: named against hidden");
    // What the library describes leaves nothing for the discovery basis.
    assert!(
        j.discovered.is_empty(),
        "{log}: discovered {:?}",
        j.discovered
    );
    j
}

fn param(j: &GapJson, effect: &str, key: &str) -> f64 {
    j.effects
        .iter()
        .find(|e| e.name == effect)
        .and_then(|e| e.params.get(key))
        .copied()
        .unwrap_or(f64::NAN)
}

/// Nothing structured is left on any channel: what the model misses is at the noise floor.
fn nothing_structured_left(log: &str, j: &GapJson) {
    for c in &j.channels {
        let u = &c.unexplained;
        println!("  {} left: {u:?}", c.name);
        assert!(!u.structured, "{log}: {} left structured: {u:?}", c.name);
        assert!(u.follows.is_empty(), "{log}: {}: {u:?}", c.name);
    }
}

#[test]
fn gap_names_nothing_on_a_vented_null_log_at_10_khz() {
    let j = check("d01");
    nothing_structured_left("d01", &j);
}

#[test]
fn gap_names_the_slave_lag_of_another_plant_within_0_05_ms() {
    let j = check("d02");
    let truth = truth("d02")["slave_lag"]["delay_s"];
    let found = param(&j, "slave_lag", "delay_s");
    assert!(
        (found - truth).abs() <= 0.05e-3,
        "{found} s against {truth} s"
    );
}

#[test]
fn gap_names_nothing_on_a_sealed_null_log() {
    let j = check("d03");
    nothing_structured_left("d03", &j);
}

#[test]
fn gap_names_the_cogging_of_another_plant_at_20_khz_within_2_percent() {
    let j = check("d04");
    let truth = truth("d04")["cogging"]["period_m"];
    let found = param(&j, "cogging", "period_m");
    assert!(
        (found / truth - 1.0).abs() <= 0.02,
        "{found} m against {truth} m"
    );
}

/// `truth.json`'s `discovered_terms` of `log`: the force the model lacks as coefficients of
/// the basis of `docs/formats.md` ("Beyond the library").
fn truth_terms(log: &str) -> BTreeMap<String, f64> {
    let text = std::fs::read_to_string(dir().join("truth.json")).expect("truth.json");
    let v: serde_json::Value = serde_json::from_str(&text).expect("truth.json parses");
    v.get(log)
        .and_then(|l| l.get("discovered_terms"))
        .and_then(|t| t.as_object())
        .expect("a `discovered_terms` object")
        .iter()
        .filter_map(|(k, v)| Some((k.clone(), v.as_f64()?)))
        .collect()
}

/// A force outside the library: no library effect named, and exactly the terms of
/// `truth.json` discovered, each within 15 % (the constant within 15 % or 10 N).
fn check_discovered(log: &str) {
    let j = gap(log);
    let named: Vec<&str> = j.effects.iter().map(|e| e.name.as_str()).collect();
    assert!(
        named.is_empty(),
        "{log}: named {named:?} for a force outside the library"
    );
    let truth = truth_terms(log);
    let [found] = j.discovered.as_slice() else {
        panic!("{log}: discovered {:?}", j.discovered);
    };
    println!("  discovered {:?}: {}", found.terms, found.reading);
    assert_eq!(found.channel, "force");
    let names = |m: &BTreeMap<String, f64>| m.keys().cloned().collect::<Vec<_>>();
    assert_eq!(names(&found.terms), names(&truth), "{log}: terms");
    for (term, want) in &truth {
        let got = found.terms[term];
        let tol = if term == "1" {
            (0.15 * want.abs()).max(10.0)
        } else {
            0.15 * want.abs()
        };
        assert!(
            (got - want).abs() <= tol,
            "{log}: term {term} = {got} against {want}"
        );
    }
    assert!(found.rms_after < 0.25 * found.rms_before, "{found:?}");
}

#[test]
fn gap_describes_a_spring_outside_its_library_as_terms_in_x_and_1() {
    check_discovered("d05");
}

#[test]
fn gap_describes_quadratic_drag_as_v_abs_v_and_does_not_call_it_viscous_friction() {
    check_discovered("d06");
}

#[test]
fn gap_names_both_leakage_and_heat_transfer_in_one_sealed_log() {
    let j = check("d07");
    // The leak is the piston seal's alone (truth: no rod leak): the rod leak to ambient that
    // the first fit took for the heat transfer is given back when both are fitted together.
    assert_eq!(param(&j, "leakage", "rod_gap_m"), 0.0);
    let ua = param(&j, "heat_transfer", "ua_w_per_k");
    let truth = truth("d07")["heat_transfer"]["ua_w_per_k"];
    assert!(
        (ua / truth - 1.0).abs() <= 0.15,
        "{ua} W/K against {truth} W/K"
    );
}

/// Friction that grows along the bore (d08: |x − x₀|·700 N/m against the motion) is outside
/// both the library and the discovery basis. Whatever is named for part of it, the force
/// left must be reported: well above the noise floor, structured (out of sample), following
/// position by direction of motion, and said so in words.
#[test]
fn gap_reports_friction_growing_along_the_bore_as_a_structured_force_left_by_position() {
    let measured = RunLog::read(&dir().join("d08.csv.gz")).expect("the gzipped log reads");
    let model = std::fs::read_to_string(dir().join("d08.toml")).expect("model");
    let out = analyse(&model, &measured, &GapOptions::default()).expect("analysis runs");
    let j = &out.json;
    let force = j
        .channels
        .iter()
        .find(|c| c.name == "force")
        .expect("the force channel");
    let u = &force.unexplained;
    println!("  force left: {u:?}");
    assert!(u.structured, "{u:?}");
    assert!(u.rms > 2.0 * u.noise_floor, "{u:?}");
    assert!(u.structured_share >= 0.5, "{u:?}");
    assert_eq!(
        u.follows.first().map(String::as_str),
        Some("x·sgn v"),
        "position by direction of motion first: {u:?}"
    );
    assert_eq!(u.rms, force.rms_after);
    assert!(
        (u.share_of_gap - (force.rms_after / force.rms_before).powi(2)).abs() < 1e-12,
        "{u:?}"
    );
    // The other channels hold nothing of it.
    for c in j.channels.iter().filter(|c| c.name != "force") {
        assert!(!c.unexplained.structured, "{}: {:?}", c.name, c.unexplained);
    }
    // And the words say where it grows.
    let said = out
        .unexplained
        .iter()
        .find(|u| u.json.structured)
        .map(|u| hal_sim::gap::unexplained::sentence(u, "N"))
        .unwrap_or_default();
    println!("  {said}");
    assert!(
        said.contains("grows with distance from mid-stroke while moving (against the motion)"),
        "{said}"
    );
}

/// A hardening spring (d09: 9·10⁵ N/m³·(x − x₀)³) is outside the library: described by the
/// cubic's four terms within 15 %, and by no periodic term (a sine in x at a period the
/// machine does not have would be a curve fit, not a force).
#[test]
fn gap_describes_a_hardening_spring_by_its_cubic_and_no_periodic_term() {
    check_discovered("d09");
    let j = gap("d09");
    for d in &j.discovered {
        assert!(
            !d.terms.keys().any(|t| t.contains("2πx/p")),
            "d09: a periodic term: {d:?}"
        );
        assert!(d.reading.contains("hardening spring"), "{}", d.reading);
    }
}

/// A sealed log whose chamber-A transducer reads 2.5 kPa low (d10): the sensor's offset is
/// named, within 10 %, and no force effect nor discovered force stands in for it.
#[test]
fn gap_names_a_pressure_transducers_offset_and_no_force_for_it() {
    let j = check("d10");
    let truth = truth("d10")["pressure_offset"]["a_pa"];
    let found = param(&j, "pressure_offset", "offset_a_pa");
    assert!(
        (found / truth - 1.0).abs() <= 0.10,
        "{found} Pa against {truth} Pa"
    );
    // Chamber B's transducer is right: its offset stays within a tenth of A's.
    let b = param(&j, "pressure_offset", "offset_b_pa");
    assert!(b.abs() <= 0.1 * truth.abs(), "chamber B: {b} Pa");
    let force_effects: Vec<&str> = j
        .effects
        .iter()
        .filter(|e| e.channel == "force")
        .map(|e| e.name.as_str())
        .collect();
    assert!(force_effects.is_empty(), "{force_effects:?}");
}

/// Three effects at once at 20 kHz (d11): mass −8 %, Coulomb +30 N, slave lag 0.6 ms, each
/// within the benchmarks' tolerance: mass within 3 %, the slave lag within 0.05 ms (both as
/// `gap_generalises_to_a_foreign_plant` holds them); the benchmarks check no Coulomb level,
/// so it is held to 10 % of the true level.
#[test]
fn gap_names_mass_coulomb_and_slave_lag_together_at_20_khz() {
    let j = check("d11");
    let t = truth("d11");
    let model = std::fs::read_to_string(dir().join("d11.toml")).expect("model");
    let nominal = |key: &str| -> f64 {
        model
            .lines()
            .find_map(|l| {
                let (k, v) = l.split_once('=')?;
                (k.trim() == key).then(|| v.trim().parse::<f64>().ok())?
            })
            .expect("a nominal value")
    };
    let mass = nominal("mass_kg") * t["mass_error"]["factor"];
    let found = param(&j, "mass_error", "mass_kg");
    assert!(
        (found / mass - 1.0).abs() <= 0.03,
        "mass {found} kg against {mass} kg"
    );
    let coulomb = nominal("coulomb_n") + t["coulomb_friction"]["extra_n"];
    let found = param(&j, "coulomb_friction", "coulomb_n");
    assert!(
        (found / coulomb - 1.0).abs() <= 0.10,
        "Coulomb {found} N against {coulomb} N"
    );
    let lag = t["slave_lag"]["delay_s"];
    let found = param(&j, "slave_lag", "delay_s");
    assert!(
        (found - lag).abs() <= 0.05e-3,
        "slave lag {found} s against {lag} s"
    );
}
