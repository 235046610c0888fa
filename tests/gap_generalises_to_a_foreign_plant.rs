//! The model-gap workflow on a plant it has never seen: the generalisation benchmark.
//!
//! The logs come from `foreign_plant`, a plant, controller and logger written apart from
//! `hal-sim` (see its module header for what it does differently and the detection floor
//! of each hidden effect). Every case runs through the workflow exactly as `fpc-sim gap`
//! does (`RunLog::parse` then `gap::analyse` with the default options) and is scored
//! against the truth by the benchmarks' one scorer (`support::gap::score`, shared with the
//! independent plant's benchmark):
//!
//! - recall per effect: the hidden effect is named;
//! - false alarms: anything named on a null log;
//! - wrong extra effects: something named that is not hidden, on any log;
//! - parameter errors where a hidden effect is named: cogging period (relative), slave and
//!   actuator lag (absolute, ms), mass (relative).
//!
//! Acceptance (issue #13): recall ≥ 95 % for every effect, false alarms on ≤ 1 % of null
//! logs, wrong extras on ≤ 2 % of logs, cogging period within 2 %, lags within 0.05 ms, mass
//! within 3 % — every case that names it, as the other plant's benchmark is held to.
//! Cases outside are printed.
//! The slave lag is scored from the lags the log can carry: this logger moves the
//! slave's force by whole samples, so the lag is known to one sample from the columns
//! ([`distance_to_logged_lags`]).
//!
//! The field logs' forms (friction growing along the bore, a hardening spring, a pressure
//! transducer's or a force reading's offset or gain, three library effects at once) are
//! judged as `tests/gap_names_effects_in_foreign_field_logs.rs` holds d08–d11
//! (`support::forms::Want`): right in ≥ 95 % of each form's cases, a library effect named
//! falsely in ≤ 2 % (asserted but for the forms measured short of it on this plant,
//! [`SHORT_OF_ACCEPTANCE`], whose figures are printed); one case per form by default, 20 per
//! form in the ignored full run.
//!
//! A slice of 24 cases runs by default; the full benchmark (520 cases: 160 null, 20 of each
//! effect alone, 10 of each of 15 pairs) is one command:
//! `cargo test --profile slow-tests --test gap_generalises_to_a_foreign_plant -- --ignored --nocapture`.
//! A failed case prints its index; `FOREIGN_CASE=<index> cargo test --test
//! gap_generalises_to_a_foreign_plant replay -- --ignored --nocapture` writes its log,
//! model and truth to a temporary directory for `fpc-sim gap`.

mod foreign_plant;
mod support;

use foreign_plant::{
    draw_case, draw_field_case, draw_form_case, generate, CaseKind, Chambers, Effect, Form, Hidden,
    Machine, Profile, Segment, SensorError, Shape, Trajectory, Truth, AMBIENT_PA, DEAD_LENGTH_M,
    FORMS, GAMMA, TRAVEL_M,
};
use hal_sim::runlog::RunLog;
use std::collections::BTreeMap;
use std::time::Instant;
use support::forms::{
    field_form_cases, judge, run_field_forms, write_case_if_asked, Check, FieldCase, Want,
};
use support::gap::{
    bench_cases, classify_form, form_cases, form_seed_runs, name_effects, par_map, score,
    score_forms, Acceptance, BenchCase, FormCase, FormOutcome, ParamError, ParamRule,
};

// ---------------------------------------------------------------------------------------
// The plant itself: checks against physics laws and the log contract, not the workflow.
// ---------------------------------------------------------------------------------------

/// A generated log's columns, parsed independently of `hal-sim`.
struct Columns {
    t: Vec<f64>,
    x: Vec<f64>,
    x_slave: Vec<f64>,
    f_master: Vec<f64>,
    f_slave: Vec<f64>,
    p_a: Vec<f64>,
    p_b: Vec<f64>,
    meta: Vec<String>,
}

fn columns(csv: &str) -> Columns {
    let mut c = Columns {
        t: vec![],
        x: vec![],
        x_slave: vec![],
        f_master: vec![],
        f_slave: vec![],
        p_a: vec![],
        p_b: vec![],
        meta: vec![],
    };
    let mut lines = csv.lines();
    for line in lines.by_ref() {
        if let Some(m) = line.strip_prefix('#') {
            c.meta.push(m.trim().to_string());
        } else {
            assert_eq!(
                line,
                "t_s,x_m,x_slave_m,theta_rad,f_master_n,f_slave_n,p_a_pa,p_b_pa"
            );
            break;
        }
    }
    for line in lines {
        let v: Vec<f64> = line.split(',').map(|s| s.parse().unwrap()).collect();
        assert_eq!(v.len(), 8, "row {line}");
        assert_eq!(v[3], 0.0, "the piston does not turn");
        c.t.push(v[0]);
        c.x.push(v[1]);
        c.x_slave.push(v[2]);
        c.f_master.push(v[4]);
        c.f_slave.push(v[5]);
        c.p_a.push(v[6]);
        c.p_b.push(v[7]);
    }
    c
}

fn plain_case(seed: u64, rate_hz: f64, chambers: Chambers, segments: Vec<Segment>) -> Case {
    let start_m = match chambers {
        Chambers::Sealed { .. } => 0.5 * TRAVEL_M,
        Chambers::Vented { .. } => 0.04,
    };
    Case {
        seed,
        kind: CaseKind::Null,
        rate_hz,
        trajectory: Trajectory {
            shape: Shape::HoldsAndMoves,
            start_m,
            segments,
        },
        chambers,
        nominal: Machine {
            mass_kg: 11.0,
            bore_m: 0.09,
            rod_m: 0.02,
            coulomb_n: 40.0,
            viscous_ns_per_m: 25.0,
        },
        hidden: vec![],
        form: None,
        sensor: None,
        loop_hz: 30.0,
        loop_damping: 0.7,
        velocity_filter_hz: 300.0,
    }
}

use foreign_plant::Case;

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn cosine(to_m: f64, peak_speed_mps: f64) -> Segment {
    Segment::Move {
        to_m,
        peak_speed_mps,
        profile: Profile::Cosine,
    }
}

fn hold(duration_s: f64) -> Segment {
    Segment::Hold { duration_s }
}

#[test]
fn sealed_chamber_follows_the_adiabatic_law_and_returns_to_its_start_pressure() {
    let case = plain_case(
        1,
        10_000.0,
        Chambers::Sealed {
            start_pa: AMBIENT_PA,
        },
        vec![
            hold(0.2),
            cosine(0.05, 1.5),
            hold(0.3),
            cosine(0.5 * TRAVEL_M, 1.0),
            hold(0.3),
        ],
    );
    let g = generate(&case);
    let c = columns(&g.csv);
    assert!(c.meta.iter().any(|m| m == "ports = closed"));
    let n = c.t.len();
    let (first, last) = (0..1500, n - 1500..n);
    let p_start = mean(&c.p_a[first.clone()]);
    let p_end = mean(&c.p_a[last.clone()]);
    assert!(
        (p_end - p_start).abs() < 300.0,
        "round trip: {p_start:.0} → {p_end:.0} Pa"
    );
    assert!((p_start - AMBIENT_PA).abs() < 100.0);
    // In the compressed hold: p·V^γ as at the start, from the logged position.
    let hold_rows: Vec<usize> = (0..n)
        .filter(|&i| c.t[i] > 0.2 + 0.1 && c.t[i] < 0.2 + 0.15 + 0.25)
        .filter(|&i| (c.x[i] - 0.05).abs() < 2e-4)
        .collect();
    assert!(
        hold_rows.len() > 1000,
        "{} rows in the hold",
        hold_rows.len()
    );
    let la = |x: f64| x + DEAD_LENGTH_M;
    let lb = |x: f64| TRAVEL_M - x + DEAD_LENGTH_M;
    let x0 = 0.5 * TRAVEL_M;
    for (p, l) in [(&c.p_a, &la as &dyn Fn(f64) -> f64), (&c.p_b, &lb)] {
        let x_hold = mean(&hold_rows.iter().map(|&i| c.x[i]).collect::<Vec<_>>());
        let p_hold = mean(&hold_rows.iter().map(|&i| p[i]).collect::<Vec<_>>());
        let expected = AMBIENT_PA * (l(x0) / l(x_hold)).powf(GAMMA);
        assert!(
            (p_hold / expected - 1.0).abs() < 2e-3,
            "hold at {x_hold:.4} m: {p_hold:.0} Pa, adiabatic law {expected:.0} Pa"
        );
    }
}

#[test]
fn vented_pressures_stay_near_ambient_and_differ_by_a_loss_growing_with_speed() {
    let case = plain_case(
        2,
        5_000.0,
        Chambers::Vented {
            loss_pa_s2_per_m2: 1500.0,
        },
        vec![hold(0.2), cosine(0.17, 0.5), cosine(0.04, 2.5), hold(0.2)],
    );
    let c = columns(&generate(&case).csv);
    assert!(!c.meta.iter().any(|m| m.starts_with("ports")));
    let dt = c.t[1] - c.t[0];
    let mut slow = vec![];
    let mut fast = vec![];
    for i in 5..c.t.len() - 5 {
        assert!((c.p_a[i] - AMBIENT_PA).abs() < 12_000.0);
        assert!((c.p_b[i] - AMBIENT_PA).abs() < 12_000.0);
        let v = (c.x[i + 5] - c.x[i - 5]) / (10.0 * dt);
        let dp = c.p_b[i] - c.p_a[i];
        if v.abs() > 0.45 && v.abs() < 0.5 {
            slow.push(dp / (v * v.abs()));
        }
        if v.abs() > 2.3 {
            fast.push(dp / (v * v.abs()));
        }
    }
    // Both speeds see the same loss coefficient, 2k = 3000 Pa·s²/m².
    for (what, k) in [("0.5 m/s", mean(&slow)), ("2.5 m/s", mean(&fast))] {
        assert!((k / 3000.0 - 1.0).abs() < 0.1, "{what}: {k:.0}");
    }
}

#[test]
fn the_logged_slave_force_is_the_masters_shifted_by_the_lag_on_the_loggers_grid() {
    for (rate_hz, delay_s, whole) in [
        (10_000.0, 0.73e-3, 8usize),
        (10_000.0, 1.0e-3, 10),
        (5_000.0, 0.41e-3, 3),
    ] {
        let mut case = plain_case(
            3,
            rate_hz,
            Chambers::Vented {
                loss_pa_s2_per_m2: 1500.0,
            },
            vec![hold(0.1), cosine(0.17, 2.0), cosine(0.04, 1.0), hold(0.1)],
        );
        case.hidden = vec![Hidden::SlaveLag { delay_s }];
        let c = columns(&generate(&case).csv);
        let rms_at = |shift: usize| {
            let d: Vec<f64> = (shift..c.t.len())
                .map(|i| (c.f_slave[i] - c.f_master[i - shift]).powi(2))
                .collect();
            mean(&d).sqrt()
        };
        // At the shift only the two drives' noise differs: √2 · 3 N.
        let best = rms_at(whole);
        assert!(
            best < 4.6,
            "{delay_s} s at {rate_hz} Hz: rms {best:.2} N at {whole}"
        );
        assert!(rms_at(whole - 1) > best + 1.0 && rms_at(whole + 1) > best + 1.0);
        assert!(rms_at(0) > 3.0 * best);
    }
}

/// RMS over 10 ms windows of the force-balance residual, impulse form: `m·Δv` against the
/// logged forces (each acting over its sample period), the logged gas force and friction.
fn balance_rms(c: &Columns, mass_kg: f64, area_m2: f64, coulomb_n: f64, viscous: f64) -> f64 {
    let dt = c.t[1] - c.t[0];
    let w = (0.01 / dt).round() as usize;
    let h = w / 10;
    let vel = |i: usize| (c.x[i + h] - c.x[i - h]) / (2 * h) as f64 / dt;
    let mut sq = vec![];
    let mut i = h + 1;
    while i + w + h + 1 < c.t.len() {
        let mut impulse = 0.0;
        for k in i..i + w {
            let v = (c.x[k + 1] - c.x[k]) / dt;
            let v_s = vel(k.max(h).min(c.t.len() - h - 1));
            let fr = coulomb_n * (v_s / 1e-2).tanh() + viscous * v;
            impulse += (c.f_master[k] + c.f_slave[k] + (c.p_a[k] - c.p_b[k]) * area_m2 - fr) * dt;
        }
        let dv = vel(i + w) - vel(i);
        sq.push(((mass_kg * dv - impulse) / (w as f64 * dt)).powi(2));
        i += w;
    }
    mean(&sq).sqrt()
}

#[test]
fn the_force_balance_closes_with_the_true_mass_and_not_with_the_nominal_one() {
    let segments = vec![
        hold(0.2),
        cosine(0.17, 2.0),
        cosine(0.04, 2.5),
        cosine(0.17, 1.0),
        hold(0.2),
    ];
    let vented = Chambers::Vented {
        loss_pa_s2_per_m2: 1500.0,
    };
    let mut case = plain_case(4, 10_000.0, vented, segments);
    let area = case.nominal.area_m2();
    let null = columns(&generate(&case).csv);
    let closes = balance_rms(&null, 11.0, area, 40.0, 25.0);
    case.hidden = vec![Hidden::MassError { mass_kg: 13.2 }];
    let heavy = columns(&generate(&case).csv);
    let nominal = balance_rms(&heavy, 11.0, area, 40.0, 25.0);
    let true_mass = balance_rms(&heavy, 13.2, area, 40.0, 25.0);
    println!("force balance rms: null {closes:.1} N; +20 % mass: nominal {nominal:.1} N, true {true_mass:.1} N");
    assert!(closes < 8.0, "null log: {closes:.1} N");
    assert!(true_mass < 8.0, "true mass: {true_mass:.1} N");
    assert!(
        nominal > 3.0 * true_mass,
        "nominal {nominal:.1} vs true {true_mass:.1}"
    );
}

#[test]
fn drawn_cases_respect_the_ranges_and_are_reproducible() {
    let mut speeds_seen = 0usize;
    for seed in 0..120u64 {
        let kind = match seed % 4 {
            0 => CaseKind::Null,
            1 => CaseKind::One(Effect::ALL[(seed as usize / 4) % 10]),
            2 => CaseKind::Two(Effect::Cogging, Effect::Leakage),
            _ => CaseKind::Two(Effect::StribeckFriction, Effect::SlaveLag),
        };
        let case = draw_case(seed, kind);
        assert!([5e3, 1e4, 2e4].contains(&case.rate_hz));
        let m = &case.nominal;
        assert!((8.0..=14.0).contains(&m.mass_kg) && (0.085..=0.092).contains(&m.bore_m));
        assert!((0.018..=0.024).contains(&m.rod_m) && (30.0..=50.0).contains(&m.coulomb_n));
        let d = case.trajectory.duration_s();
        assert!((3.0..7.5).contains(&d), "seed {seed}: {d} s");
        let fastest = case
            .trajectory
            .segments
            .iter()
            .filter_map(|s| match s {
                Segment::Move { peak_speed_mps, .. } => Some(*peak_speed_mps),
                Segment::Hold { .. } => None,
            })
            .fold(0.0, f64::max);
        assert!(fastest >= 1.5, "seed {seed}: fastest stroke {fastest} m/s");
        speeds_seen += 1;
        let names: Vec<_> = case.hidden.iter().map(|h| h.effect()).collect();
        assert_eq!(names, kind.effects());
        if kind.effects().iter().any(|e| e.sealed_only()) {
            assert!(matches!(case.chambers, Chambers::Sealed { .. }));
        }
        if kind.effects().iter().any(|e| e.needs_holds()) {
            assert_eq!(case.trajectory.shape, Shape::HoldsAndMoves);
        }
        for h in &case.hidden {
            match *h {
                Hidden::MassError { mass_kg } => {
                    let r = (mass_kg / m.mass_kg - 1.0).abs();
                    assert!((0.08..=0.25).contains(&r));
                }
                Hidden::CoulombFriction { coulomb_n } => {
                    assert!((15.0..=40.0).contains(&(coulomb_n - m.coulomb_n).abs()));
                    assert!(coulomb_n >= 5.0);
                }
                Hidden::ViscousFriction { viscous_ns_per_m } => {
                    let d = (viscous_ns_per_m - m.viscous_ns_per_m).abs();
                    assert!((20.0..=80.0).contains(&d) && viscous_ns_per_m >= 0.0);
                }
                Hidden::Cogging { amplitude_n, .. } => assert!(amplitude_n >= 15.0),
                Hidden::SlaveLag { delay_s } => assert!((0.4e-3..=1.5e-3).contains(&delay_s)),
                Hidden::ActuatorLag { delay_s } => assert!((0.3e-3..=1.5e-3).contains(&delay_s)),
                Hidden::EncoderPitchError { amplitude_m, .. } => assert!(amplitude_m >= 10e-6),
                _ => {}
            }
        }
    }
    assert_eq!(speeds_seen, 120);
    let a = generate(&draw_case(7, CaseKind::One(Effect::Cogging)));
    let b = generate(&draw_case(7, CaseKind::One(Effect::Cogging)));
    assert_eq!(a.csv, b.csv);
    assert_eq!(a.model_toml, b.model_toml);
}

#[test]
fn generating_a_log_is_fast() {
    // The longest kind: 20 kHz, sealed chambers with both gas effects.
    let mut seed = 0u64;
    let case = loop {
        let c = draw_case(seed, CaseKind::Two(Effect::Leakage, Effect::HeatTransfer));
        if c.rate_hz == 20_000.0 {
            break c;
        }
        seed += 1;
    };
    let start = Instant::now();
    let g = generate(&case);
    let took = start.elapsed();
    println!(
        "generate: {} rows ({:.2} s at {} Hz, sealed) in {:.0} ms",
        g.rows,
        g.rows as f64 / case.rate_hz,
        case.rate_hz,
        took.as_secs_f64() * 1e3
    );
    // The rows are deterministic: the duration the trajectory asks for at the log rate.
    assert_eq!(
        g.rows,
        (case.trajectory.duration_s() * case.rate_hz).floor() as usize
    );
    assert!(
        RunLog::parse(&g.csv).is_ok(),
        "the project's reader takes it"
    );
}

// ---------------------------------------------------------------------------------------
// The benchmark.
// ---------------------------------------------------------------------------------------

/// Pairs of effects hidden together (10 cases each in the full run).
const PAIRS: [(Effect, Effect); 15] = [
    (Effect::Cogging, Effect::SlaveLag),
    (Effect::MassError, Effect::Leakage),
    (Effect::MassError, Effect::Cogging),
    (Effect::CoulombFriction, Effect::Cogging),
    (Effect::ViscousFriction, Effect::EncoderPitchError),
    (Effect::StribeckFriction, Effect::SlaveLag),
    (Effect::ActuatorLag, Effect::Cogging),
    (Effect::SlaveLag, Effect::EncoderPitchError),
    (Effect::Leakage, Effect::HeatTransfer),
    (Effect::HeatTransfer, Effect::MassError),
    (Effect::MassError, Effect::ViscousFriction),
    (Effect::CoulombFriction, Effect::ActuatorLag),
    (Effect::StribeckFriction, Effect::HeatTransfer),
    (Effect::Cogging, Effect::EncoderPitchError),
    (Effect::MassError, Effect::SlaveLag),
];

/// The full benchmark: (seed, kind), index = position in this list.
fn all_cases() -> Vec<(u64, CaseKind)> {
    let mut kinds = vec![CaseKind::Null; 160];
    for e in Effect::ALL {
        kinds.extend(std::iter::repeat_n(CaseKind::One(e), 20));
    }
    for (a, b) in PAIRS {
        kinds.extend(std::iter::repeat_n(CaseKind::Two(a, b), 10));
    }
    kinds
        .into_iter()
        .enumerate()
        .map(|(i, k)| (13_000 + i as u64, k))
        .collect()
}

/// The CI slice: 6 null logs, each effect alone once, 8 pairs (24 cases of the full list).
fn slice() -> Vec<usize> {
    let mut idx: Vec<usize> = (0..6).collect();
    idx.extend((0..10).map(|e| 160 + 20 * e));
    idx.extend((0..8).map(|p| 360 + 10 * p));
    idx
}

/// The acceptance of issue #13, as the other plant's benchmark holds it: every named
/// parameter within its tolerance (not a share of them).
const ACCEPTANCE: Acceptance = Acceptance {
    min_recall_percent: 95.0,
    max_false_alarm_percent: 1.0,
    max_wrong_extra_percent: 2.0,
    params: ParamRule::Every,
};

/// Case `index` of [`all_cases`], generated, analysed and scored against its truth.
fn run_case(index: usize) -> BenchCase {
    let (seed, kind) = all_cases()[index];
    let case = draw_case(seed, kind);
    let t0 = Instant::now();
    let g = generate(&case);
    let named = name_effects(&g.csv, &g.model_toml);
    let sealed = matches!(case.chambers, Chambers::Sealed { .. });
    let params = match &named {
        Ok(n) => param_errors(&g.truth.hidden, n, case.rate_hz),
        Err(_) => vec![],
    };
    BenchCase {
        label: format!(
            "#{index} seed {seed} {kind:?}: {} kHz {} {:?}",
            case.rate_hz / 1e3,
            if sealed { "sealed" } else { "vented" },
            case.trajectory.shape
        ),
        group: format!(
            "{:>2} kHz {}",
            case.rate_hz / 1e3,
            if sealed { "sealed" } else { "vented" }
        ),
        hidden: g.truth.names().into_iter().map(String::from).collect(),
        named,
        params,
        seconds: t0.elapsed().as_secs_f64(),
    }
}

/// The parameter errors where a hidden effect was named: cogging period (relative), slave
/// and actuator lag (absolute, ms; the slave lag from the lags the log can carry), mass
/// (relative).
fn param_errors(
    truth: &[Hidden],
    named: &BTreeMap<String, BTreeMap<String, f64>>,
    rate_hz: f64,
) -> Vec<ParamError> {
    let checks: [(Effect, &str, &'static str, f64, bool); 4] = [
        (Effect::Cogging, "period_m", "cogging period, %", 2.0, true),
        (Effect::SlaveLag, "delay_s", "slave lag, ms", 0.05, false),
        (
            Effect::ActuatorLag,
            "delay_s",
            "actuator lag, ms",
            0.05,
            false,
        ),
        (Effect::MassError, "mass_kg", "mass, %", 3.0, true),
    ];
    let mut out = vec![];
    for (effect, key, what, tolerance, relative) in checks {
        let Some(truth) = true_param(truth, effect, key) else {
            continue;
        };
        let Some(&found) = named.get(effect.name()).and_then(|p| p.get(key)) else {
            continue;
        };
        let error = if relative {
            100.0 * (found / truth - 1.0).abs()
        } else if effect == Effect::SlaveLag {
            1e3 * distance_to_logged_lags(found, truth, rate_hz)
        } else {
            1e3 * (found - truth).abs()
        };
        out.push(ParamError {
            what,
            error,
            tolerance,
            detail: format!("truth {truth:.6}, found {found:.6}"),
        });
    }
    out
}

/// How far `found` lies from the slave lags a log at `rate_hz` cannot tell from `truth`.
///
/// The plant's logger samples the slave's setpoint on its own grid, so the logged slave
/// force is the master's moved by `K = ⌈truth·rate⌉` whole samples: every lag in
/// `((K−1)/rate, K/rate]` writes the same columns. The rest of the lag moves only the
/// instant the slave's force switches inside a sample, which the position sees as a
/// common shift of both forces, i.e. as the forces' alignment (a fitted nuisance), to
/// first order. So the log carries the lag to within one sample, and the tolerance is
/// applied from that interval.
fn distance_to_logged_lags(found: f64, truth: f64, rate_hz: f64) -> f64 {
    let k = (truth * rate_hz - 1e-9).ceil();
    let (lo, hi) = ((k - 1.0) / rate_hz, k / rate_hz);
    (lo - found).max(found - hi).max(0.0)
}

fn true_param(truth: &[Hidden], effect: Effect, key: &str) -> Option<f64> {
    let truth = Truth {
        hidden: truth.to_vec(),
    };
    truth
        .get(effect)
        .and_then(|h| h.params().into_iter().find(|(k, _)| *k == key))
        .map(|(_, v)| v)
}

#[test]
fn gap_generalises_to_a_foreign_plant_slice() {
    let indices = slice();
    let cases = par_map(indices.len(), |i| run_case(indices[i]));
    println!("(replay one: FOREIGN_CASE=<index> cargo test --test gap_generalises_to_a_foreign_plant replay -- --ignored --nocapture)");
    let misses = score("foreign plant", &cases, &ACCEPTANCE);
    assert!(misses.is_empty(), "acceptance missed: {misses:#?}");
}

#[test]
#[ignore = "full generalisation benchmark (520 cases); run with --profile slow-tests"]
fn gap_generalises_to_a_foreign_plant_full() {
    let n = all_cases().len();
    assert!(n >= 500);
    let which = bench_cases(n);
    let cases = par_map(which.len(), |i| run_case(which[i]));
    println!("(replay one: FOREIGN_CASE=<index> cargo test --test gap_generalises_to_a_foreign_plant replay -- --ignored --nocapture)");
    let misses = score("foreign plant", &cases, &ACCEPTANCE);
    assert!(misses.is_empty(), "acceptance missed: {misses:#?}");
}

// ---------------------------------------------------------------------------------------
// Forces outside the library (issue #30): described in the discovery basis, never named.
// ---------------------------------------------------------------------------------------

/// The case of `seed` hiding the out-of-library `form`, analysed and classified.
fn run_form_case(seed: u64, form: &str) -> FormCase {
    let Some(case) = draw_form_case(seed, form) else {
        return FormCase {
            form: form.into(),
            outcome: FormOutcome::Missed,
            detail: format!("{form}: not a form of this plant"),
        };
    };
    let want = case.form.map(|f| f.discovered_terms()).unwrap_or_default();
    let g = generate(&case);
    let label = format!(
        "seed {seed} {form} ({} kHz, {}, {:?}) truth {want:?}",
        case.rate_hz / 1e3,
        if matches!(case.chambers, Chambers::Sealed { .. }) {
            "sealed"
        } else {
            "vented"
        },
        case.trajectory.shape
    );
    classify_form(form, &g.csv, &g.model_toml, &want, &label)
}

/// Runs `per_form` cases of each form and returns what misses the acceptance.
fn score_forms_here(per_form: u64) -> Vec<String> {
    let plan: Vec<(u64, &str)> = FORMS
        .iter()
        .enumerate()
        .flat_map(|(i, f)| (0..per_form).map(move |k| (17_000 + 100 * i as u64 + k, *f)))
        .filter(|(seed, _)| form_seed_runs(*seed))
        .collect();
    let results = par_map(plan.len(), |i| run_form_case(plan[i].0, plan[i].1));
    score_forms("foreign plant", &FORMS, &results)
}

#[test]
fn a_spring_a_bias_drag_a_motor_constant_and_drifting_friction_reach_the_log() {
    // Each form changes the force balance as its law says (a check of the plant, not of the
    // workflow): the same case with and without it differs in the logged motor forces.
    for form in FORMS {
        let case = draw_form_case(3, form).expect("a form");
        assert_eq!(case.form.map(|f| f.name()), Some(form));
        assert!(case.hidden.is_empty() && case.kind == CaseKind::Null);
        let with = generate(&case);
        let without = generate(&foreign_plant::Case {
            form: None,
            ..case.clone()
        });
        let (a, b) = (columns(&with.csv), columns(&without.csv));
        let diff = a
            .f_master
            .iter()
            .zip(&b.f_master)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(diff > 2.0, "{form}: the forces differ by {diff} N at most");
    }
    assert!(draw_form_case(3, "gravity_wave").is_none());
}

#[test]
fn gap_describes_forces_outside_its_library_on_the_foreign_plant_slice() {
    let problems = score_forms_here(1);
    assert!(problems.is_empty(), "{problems:#?}");
}

#[test]
#[ignore = "slow: 100 cases of forces outside the library (FPC_FORM_CASES per form, 20)"]
fn gap_describes_forces_outside_its_library_on_the_foreign_plant_in_100_cases() {
    let problems = score_forms_here(form_cases());
    assert!(problems.is_empty(), "{problems:#?}");
}

/// Writes one case of the benchmark for `fpc-sim gap`: `FOREIGN_CASE=<index>`, to a
/// directory of its own that is kept (without it, the first case, checked and removed).
#[test]
#[ignore = "a tool: writes one case to a temporary directory"]
fn replay() {
    let index = std::env::var("FOREIGN_CASE").unwrap_or_else(|_| "0".into());
    let index: usize = index.trim().parse().expect("FOREIGN_CASE: an index");
    let (seed, kind) = all_cases()[index];
    let case = draw_case(seed, kind);
    let g = generate(&case);
    // A directory of its own, kept for the user who named a case (removed after CI's run).
    let tmp = tempfile::Builder::new()
        .prefix(&format!("fpc-foreign-case-{index}-"))
        .tempdir()
        .expect("case directory");
    let dir = tmp.path().to_path_buf();
    std::fs::write(dir.join("run.csv"), &g.csv).unwrap();
    std::fs::write(dir.join("model.toml"), &g.model_toml).unwrap();
    // What was written is the case the benchmark scores, through the readers `fpc-sim gap`
    // uses, and gap takes it.
    let log = RunLog::read(&dir.join("run.csv")).expect("run.csv reads");
    assert_eq!(Ok(&log), RunLog::parse(&g.csv).as_ref());
    assert_eq!(log.len(), g.rows, "rows written");
    let model = hal_sim::plant::model::MachineModel::read(&dir.join("model.toml"))
        .expect("model.toml reads");
    assert_eq!(
        Ok(model),
        hal_sim::plant::model::MachineModel::parse(&g.model_toml)
    );
    hal_sim::gap::analyse(&g.model_toml, &log, &hal_sim::gap::GapOptions::default())
        .unwrap_or_else(|f| panic!("gap refuses the case: {}", f.message));
    let truth: Vec<String> = g
        .truth
        .hidden
        .iter()
        .map(|h| format!("{} {:?}", h.effect().name(), h.params()))
        .collect();
    std::fs::write(dir.join("truth.txt"), truth.join("\n") + "\n").unwrap();
    if std::env::var_os("FOREIGN_CASE").is_none() {
        return;
    }
    let _ = tmp.keep();
    println!("case #{index} (seed {seed}, {kind:?}): {}", dir.display());
    println!(
        "run: cargo run --release -p hal-sim -- gap --model {0}/model.toml --measured {0}/run.csv --json",
        dir.display()
    );
    println!("truth: {truth:?}");
}

// ---------------------------------------------------------------------------------------
// The field logs' forms: friction along the bore, a hardening spring, sensors, triples.
// ---------------------------------------------------------------------------------------

/// A sensor's two keys in `name`: the one in error within 10 % of its error `v − exact`,
/// the other within 10 % of that error of `exact`.
fn sensor_pair(
    name: &'static str,
    keys: [&'static str; 2],
    second: bool,
    exact: f64,
    v: f64,
) -> Want {
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
}

/// The checks of a triple's parameters: mass within 3 %, Coulomb level within 10 %, cogging
/// period within 2 %, lags within 0.05 ms (the slave lag of the interval the log carries,
/// [`distance_to_logged_lags`]); the other effects by name.
fn triple_checks(hidden: &[Hidden], rate_hz: f64) -> Vec<Check> {
    let mut out = Vec::new();
    for h in hidden {
        match *h {
            Hidden::MassError { mass_kg } => {
                out.push(Check::within(
                    "mass_error",
                    "mass_kg",
                    mass_kg,
                    0.03 * mass_kg,
                ));
            }
            Hidden::CoulombFriction { coulomb_n } => out.push(Check::within(
                "coulomb_friction",
                "coulomb_n",
                coulomb_n,
                0.1 * coulomb_n,
            )),
            Hidden::Cogging { period_m, .. } => {
                out.push(Check::within(
                    "cogging",
                    "period_m",
                    period_m,
                    0.02 * period_m,
                ));
            }
            Hidden::ActuatorLag { delay_s } => {
                out.push(Check::within("actuator_lag", "delay_s", delay_s, 0.05e-3));
            }
            Hidden::SlaveLag { delay_s } => {
                let k = (delay_s * rate_hz - 1e-9).ceil();
                out.push(Check {
                    effect: "slave_lag",
                    key: "delay_s",
                    truth: delay_s,
                    lo: (k - 1.0) / rate_hz - 0.05e-3,
                    hi: k / rate_hz + 0.05e-3,
                });
            }
            _ => {}
        }
    }
    out
}

/// What a right answer is for `case`.
fn want_of(case: &Case) -> Want {
    if let Some(s) = case.sensor {
        return match s {
            SensorError::PressureOffset {
                chamber_b,
                offset_pa,
            } => sensor_pair(
                "pressure_offset",
                ["offset_a_pa", "offset_b_pa"],
                chamber_b,
                0.0,
                offset_pa,
            ),
            SensorError::PressureGain { chamber_b, gain } => {
                sensor_pair("pressure_gain", ["gain_a", "gain_b"], chamber_b, 1.0, gain)
            }
            SensorError::ForceOffset { slave, offset_n } => sensor_pair(
                "force_offset",
                ["offset_master_n", "offset_slave_n"],
                slave,
                0.0,
                offset_n,
            ),
            SensorError::ForceGain { slave, gain } => sensor_pair(
                "force_gain",
                ["gain_master", "gain_slave"],
                slave,
                1.0,
                gain,
            ),
        };
    }
    match case.form {
        Some(Form::PositionFriction { .. }) => Want::LeftByPosition,
        Some(f) => Want::Terms(f.discovered_terms()),
        None => Want::Named {
            effects: case.hidden.iter().map(|h| h.effect().name()).collect(),
            checks: triple_checks(&case.hidden, case.rate_hz),
        },
    }
}

/// Case `k` of the field-log form `form` (seed `seed`), generated, analysed and judged.
fn run_field_case(seed: u64, form: &str, k: u64) -> FieldCase {
    let Some(case) = draw_field_case(seed, form, k as usize) else {
        return FieldCase {
            form: form.into(),
            right: false,
            false_name: false,
            detail: format!("{form}: not a form of this plant"),
        };
    };
    let want = want_of(&case);
    let g = generate(&case);
    let label = format!(
        "seed {seed} {form} ({} kHz, {}, {:?}) truth {:?}{:?}{:?}",
        case.rate_hz / 1e3,
        if matches!(case.chambers, Chambers::Sealed { .. }) {
            "sealed"
        } else {
            "vented"
        },
        case.trajectory.shape,
        case.form,
        case.sensor,
        case.hidden
    );
    write_case_if_asked(seed, &g.csv, &g.model_toml);
    judge(form, &g.csv, &g.model_toml, &want, &label)
}

/// The field-log forms measured short of the acceptance on this plant (`docs/gap.md`).
const SHORT_OF_ACCEPTANCE: [&str; 1] = ["triple"];

/// Runs `per_form` cases of each field-log form and returns what misses the acceptance.
fn score_field_forms_here(per_form: u64) -> Vec<String> {
    run_field_forms(
        "foreign plant",
        37_000,
        per_form,
        &SHORT_OF_ACCEPTANCE,
        run_field_case,
    )
}

#[test]
fn gap_meets_the_field_logs_forms_on_the_foreign_plant_slice() {
    let problems = score_field_forms_here(1);
    assert!(problems.is_empty(), "{problems:#?}");
}

#[test]
#[ignore = "slow: 140 cases of the field logs' forms (FPC_FIELD_FORM_CASES per form, 20)"]
fn gap_meets_the_field_logs_forms_on_the_foreign_plant_in_140_cases() {
    let problems = score_field_forms_here(field_form_cases());
    assert!(problems.is_empty(), "{problems:#?}");
}
