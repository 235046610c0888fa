//! The model-gap workflow on a plant it has never seen: seeded cases from
//! `independent_plant` (its own integrator, controller, chambers and logger, sharing no code
//! with `hal-sim`), null or hiding one effect or a pair at random magnitudes above their
//! detection floors, at 5, 10 and 20 kHz, sine, trapezoid and hold-and-move strokes, vented or
//! sealed chambers. Each log goes through the workflow exactly as `fpc-sim gap` takes it.
//!
//! Printed: per-effect recall, the false-alarm rate on null logs, the rate of logs with a
//! wrong extra effect, and the parameter errors (cogging period, lags, mass), then every
//! case that went wrong with its seed. Asserted: the acceptance of issue #13 — recall ≥ 95 %
//! for every effect, false alarms on ≤ 1 % of null logs, wrong extras on ≤ 2 % of logs,
//! cogging period ± 2 %, lags ± 0.05 ms, mass ± 3 %.
//!
//! A slice of 26 cases runs by default; the full benchmark (≥ 500 cases) is
//! `cargo test --profile slow-tests --test gap_generalises_to_another_plant -- --ignored --nocapture`.

mod independent_plant;

use std::collections::BTreeMap;
use std::time::Instant;

use hal_sim::gap::{analyse, GapOptions};
use hal_sim::runlog::RunLog;
use independent_plant::{draw_case, generate, Case, Hidden, EFFECTS};

/// What the workflow said of one case.
struct Outcome {
    case: Case,
    named: Vec<String>,
    params: BTreeMap<String, BTreeMap<String, f64>>,
    seconds: f64,
}

fn run_case(seed: u64, effects: &[&str]) -> Outcome {
    let case = draw_case(seed, effects);
    let started = Instant::now();
    let g = generate(&case);
    let log = RunLog::parse(&g.csv).expect("the independent plant's log parses");
    let out = analyse(&g.model_toml, &log, &GapOptions::default());
    let (named, params) = match out {
        Ok(o) => (
            o.json.effects.iter().map(|e| e.name.clone()).collect(),
            o.json
                .effects
                .iter()
                .map(|e| (e.name.clone(), e.params.clone()))
                .collect(),
        ),
        Err(e) => (vec![format!("error: {}", e.message)], BTreeMap::new()),
    };
    Outcome {
        case,
        named,
        params,
        seconds: started.elapsed().as_secs_f64(),
    }
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

/// Runs `plan` over the machine's cores.
fn run_all(plan: &[(u64, Vec<&'static str>)]) -> Vec<Outcome> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some((seed, effects)) = plan.get(i) else {
                    break;
                };
                let o = run_case(*seed, effects);
                if let Ok(mut r) = results.lock() {
                    r.push((i, o));
                }
            });
        }
    });
    let mut r = results.into_inner().unwrap_or_default();
    r.sort_by_key(|(i, _)| *i);
    r.into_iter().map(|(_, o)| o).collect()
}

fn hidden_names(c: &Case) -> Vec<&'static str> {
    c.hidden.iter().map(Hidden::name).collect()
}

/// The scores, printed and checked.
fn score(outcomes: &[Outcome]) -> Vec<String> {
    let mut failures = Vec::new();
    let mut recall: BTreeMap<&str, (usize, usize)> = BTreeMap::new();
    let (mut nulls, mut false_alarms, mut extras) = (0usize, 0usize, 0usize);
    let mut errors: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
    for o in outcomes {
        let hidden = hidden_names(&o.case);
        let wrong: Vec<&String> = o
            .named
            .iter()
            .filter(|n| !hidden.contains(&n.as_str()))
            .collect();
        if hidden.is_empty() {
            nulls += 1;
            false_alarms += usize::from(!o.named.is_empty());
        }
        extras += usize::from(!wrong.is_empty());
        let mut missed = Vec::new();
        for h in &hidden {
            let e = recall.entry(h).or_default();
            e.1 += 1;
            if o.named.iter().any(|n| n == h) {
                e.0 += 1;
            } else {
                missed.push(*h);
            }
        }
        let p = |effect: &str, key: &str| o.params.get(effect).and_then(|m| m.get(key)).copied();
        let mut bad_params = Vec::new();
        for h in &o.case.hidden {
            match *h {
                Hidden::Cogging { period_m, .. } => {
                    if let Some(f) = p("cogging", "period_m") {
                        let e = (f / period_m - 1.0).abs();
                        errors
                            .entry("cogging period, %")
                            .or_default()
                            .push(100.0 * e);
                        if e > 0.02 {
                            bad_params.push(format!("cogging period {f:.5} m vs {period_m:.5}"));
                        }
                    }
                }
                Hidden::SlaveLag { delay_s } | Hidden::ActuatorLag { delay_s } => {
                    if let Some(f) = p(h.name(), "delay_s") {
                        let e = (f - delay_s).abs();
                        errors.entry("lags, ms").or_default().push(1e3 * e);
                        if e > 0.05e-3 {
                            bad_params.push(format!(
                                "{} {:.4} ms vs {:.4} ms",
                                h.name(),
                                f * 1e3,
                                delay_s * 1e3
                            ));
                        }
                    }
                }
                Hidden::Mass { factor } => {
                    if let Some(f) = p("mass_error", "mass_kg") {
                        let truth = o.case.nominal.mass_kg * factor;
                        let e = (f / truth - 1.0).abs();
                        errors.entry("mass, %").or_default().push(100.0 * e);
                        if e > 0.03 {
                            bad_params.push(format!("mass {f:.3} kg vs {truth:.3}"));
                        }
                    }
                }
                _ => {}
            }
        }
        if !missed.is_empty() || !wrong.is_empty() || !bad_params.is_empty() {
            failures.push(format!(
                "seed {} ({} Hz, {:?}, {:?}): hidden {:?}, named {:?}{}",
                o.case.seed,
                o.case.rate_hz,
                o.case.trajectory,
                o.case.chambers,
                o.case.hidden,
                o.named,
                if bad_params.is_empty() {
                    String::new()
                } else {
                    format!("; {}", bad_params.join("; "))
                }
            ));
        }
    }
    let n = outcomes.len();
    println!("\n{n} cases from the independent plant ({nulls} null)");
    println!("| effect | hidden | named | recall |\n|---|---|---|---|");
    let mut problems = Vec::new();
    for (e, (hit, of)) in &recall {
        let r = *hit as f64 / (*of).max(1) as f64;
        println!("| {e} | {of} | {hit} | {:.1} % |", 100.0 * r);
        if r < 0.95 {
            problems.push(format!("recall of {e} {:.1} % < 95 %", 100.0 * r));
        }
    }
    let fa = false_alarms as f64 / nulls.max(1) as f64;
    let ex = extras as f64 / n.max(1) as f64;
    println!(
        "false alarms on null logs: {false_alarms} of {nulls} ({:.1} %)",
        100.0 * fa
    );
    println!(
        "logs with a wrong extra effect: {extras} of {n} ({:.1} %)",
        100.0 * ex
    );
    for (what, v) in &errors {
        let worst = v.iter().copied().fold(0.0, f64::max);
        let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
        println!("{what}: mean {mean:.4}, worst {worst:.4} over {}", v.len());
    }
    let secs: f64 = outcomes.iter().map(|o| o.seconds).sum();
    println!(
        "{:.2} s per case (generate + analyse)",
        secs / n.max(1) as f64
    );
    if fa > 0.01 {
        problems.push(format!("false alarms {:.1} % > 1 %", 100.0 * fa));
    }
    if ex > 0.02 {
        problems.push(format!("wrong extras {:.1} % > 2 %", 100.0 * ex));
    }
    for f in &failures {
        println!("  {f}");
    }
    let bad_params = failures.iter().filter(|f| f.contains(" vs ")).count();
    if bad_params > 0 {
        problems.push(format!(
            "{bad_params} cases with a parameter outside its tolerance"
        ));
    }
    problems
}

#[test]
fn gap_generalises_to_a_slice_of_cases_from_another_plant() {
    let outcomes = run_all(&plan(6, 1, 10));
    let problems = score(&outcomes);
    assert!(problems.is_empty(), "{problems:#?}");
}

#[test]
#[ignore = "slow: 510 cases, about ten minutes on two cores"]
fn gap_generalises_to_510_cases_from_another_plant() {
    let outcomes = run_all(&plan(160, 25, 100));
    let problems = score(&outcomes);
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
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("case-{seed}"));
    std::fs::create_dir_all(&dir).expect("case directory");
    std::fs::write(dir.join("run.csv"), &g.csv).expect("run.csv");
    std::fs::write(dir.join("model.toml"), &g.model_toml).expect("model.toml");
    println!("{case:?}\nwrote {}", dir.display());
}
