//! The head clearance holds whatever fault strikes, whenever it strikes: a seeded sweep of
//! randomised fault scenarios (`docs/faults.md`), instants across the whole stroke cycle (so every
//! phase: accelerating, at full speed, braking into a dead point, at rest there), pressure
//! ratios 3.1–5.1 (2.3–4.1 m/s) and a plant mass ±10 % off the controller's model. Every run
//! goes through `fpc-sim run`'s own runner with a `--fault` specification, and must keep
//! ≥ 0.3 mm between the piston and either head from the fault to the end of its outcome.
//!
//! Left out, and why: the homing faults and the counter wrap (no instant to randomise); a
//! power cut, which no controller can brake (nothing is powered: at full speed the piston
//! reaches the head, `faults_are_caught…::s21`); a cut during a calibration save, which
//! happens at rest and is tested at every step of a save in
//! `calibration_survives_a_power_cut.rs`.
//!
//! Every case runs in both modes: as a compressor (rotation forward) and as an expander
//! (rotation reversed from the first stroke, `docs/faults.md` #25). Each mode has its own
//! tests, named after it. The full sweep (10,000 runs per mode) is `#[ignore]`: CI runs it
//! with the slow suites (`cargo test --profile slow-tests --test
//! random_faults_keep_the_head_clearance -- --ignored --nocapture`, 4–7 min per mode on two
//! cores; `FPC_FAULT_RUNS=N` for another count). A 24-run slice of each runs by default.
//! Each prints the distribution of the minimum clearance (overall and per fault kind: min,
//! 1 %, median), the five worst runs with what reproduces them, and writes its histogram
//! (`clearance.svg`). The runs go through the studies' own runner
//! (`hal_sim::sweep::run_each`, as `fpc-sim sweep`). `FPC_FAULT_SEEDS=361,951` runs only
//! the named cases of the full sweep (the seeds its reports print), to reproduce a run.
//!
//! The full sweep then runs its task hangs again with the board's boot at half and one and a
//! half times `BOOT_US` (the after-reset cases: their clearance must not rest on the boot
//! time's exact figure).
//!
//! Status: 0 of 10,000 below 0.3 mm in each mode — as a compressor ≥ 0.417 mm, as an
//! expander ≥ 0.487 mm (task hangs ≥ 0.603 mm; with the boot ×0.5 / ×1.5 ≥ 0.809 / 0.821 mm
//! as a compressor, ≥ 0.769 / 0.433 mm as an expander). CI runs the whole 10,000 of each
//! (`.ci/run`), the default suite a 24-run slice of each. Figures and causes:
//! `docs/firmware.md`, "The fault sweep".

use std::sync::OnceLock;

use fpc::control::command::Command;
use fpc::motion::synchroniser::Rotation;
use hal_sim::board::exec::BOOT_US;
use hal_sim::faults::inject::{parse, FaultSpec};
use hal_sim::plant::model::MachineModel;
use hal_sim::run::{run, HostAction, RunOptions};
use rand::seq::IndexedRandom;
use rand::{Rng as _, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The sweep's random stream: each case draws from its own seeded generator.
type Rng = ChaCha8Rng;

/// One of `items`, uniformly.
fn pick<T: Copy>(rng: &mut Rng, items: &[T]) -> T {
    *items.choose(rng).expect("a non-empty choice")
}

/// Where the piston rests at power-up: close to head A, so homing is short.
const START_M: f64 = 0.002;

/// When compression starts in a fault-free run from [`START_M`] (homing, then the park move),
/// s: the first instant above 0.5 m/s.
fn running_start_s() -> f64 {
    static START: OnceLock<f64> = OnceLock::new();
    *START.get_or_init(|| {
        let mut o = RunOptions::reference();
        o.cycles = 1;
        o.start_position_m = START_M;
        let out = run(&o).expect("fault-free run");
        let t = out.log.column("t_s").expect("t_s");
        let v = out.log.column("v_mps").expect("v_mps");
        t.iter()
            .zip(v)
            .find(|(_, v)| v.abs() > 0.5)
            .map(|(t, _)| *t)
            .expect("the piston strokes")
    })
}

/// One randomised case: its specification text, pressure ratio, plant mass factor, and the
/// board's boot time after a reset.
#[derive(Clone, Debug)]
struct Case {
    spec: String,
    pressure_ratio: f64,
    mass_factor: f64,
    seed: u64,
    boot_us: u64,
}

fn case(index: u64) -> Case {
    let mut rng = Rng::seed_from_u64(0xFA17_5EED ^ index);
    // Two stroke cycles at the slowest speed (0.38 s each) after compression starts.
    let at = running_start_s() + 0.01 + 0.75 * rng.random::<f64>();
    let kinds: [&dyn Fn(&mut Rng) -> String; 15] = [
        &|r| {
            format!(
                "encoder_amplitude@{{t}}:gain={},encoder={}",
                pick(r, &[0.2, 1.5]),
                pick(r, &["master", "slave"])
            )
        },
        &|r| format!("encoder_stuck@{{t}}:channel={}", pick(r, &["sin", "cos"])),
        &|r| {
            format!(
                "encoder_glitch@{{t}}:jump_rad={:.3}",
                6.0 * r.random::<f64>() - 3.0
            )
        },
        &|_| "encoder_noise_burst@{t}".to_string(),
        &|_| "both_encoders@{t}".to_string(),
        &|r| format!("pressure_open@{{t}}:chamber={}", pick(r, &["a", "b"])),
        &|r| format!("pressure_short@{{t}}:chamber={}", pick(r, &["a", "b"])),
        &|r| format!("pressure_stuck@{{t}}:chamber={}", pick(r, &["a", "b"])),
        &|r| {
            format!(
                "section_loss@{{t}}:section={}",
                pick(r, &["master", "slave"])
            )
        },
        &|_| "servo_stall@{t}".to_string(),
        &|r| format!("gas_loss@{{t}}:chamber={}", pick(r, &["a", "b"])),
        &|r| format!("load_step@{{t}}:force_n={}", pick(r, &[-3000.0, 3000.0])),
        &|r| format!("overrun@{{t}}:cycles={}", pick(r, &[2, 3, 5])),
        &|_| "command_loss@{t}".to_string(),
        &|r| {
            format!(
                "task_hang@{{t}}:task={}",
                pick(r, &["control", "supervision"])
            )
        },
    ];
    let spec = r_pick_kind(&mut rng, &kinds).replace("{t}", &format!("{at:.5}"));
    Case {
        spec,
        pressure_ratio: pick(&mut rng, &[3.1, 3.7, 4.3, 5.1]),
        mass_factor: 0.9 + 0.2 * rng.random::<f64>(),
        seed: index,
        boot_us: BOOT_US,
    }
}

fn r_pick_kind(rng: &mut Rng, kinds: &[&dyn Fn(&mut Rng) -> String]) -> String {
    let kind = pick(rng, kinds);
    kind(rng)
}

/// What one case showed.
#[derive(Clone, Debug)]
struct Outcome {
    case: Case,
    /// Smallest head clearance from the fault on, m.
    min_clearance_m: f64,
    /// The first fault latched after the onset, if any.
    fault: Option<String>,
}

fn run_case(c: &Case, rotation: Rotation) -> Outcome {
    let spec: FaultSpec = parse(&c.spec).expect("valid spec");
    let mut o = RunOptions::reference();
    o.pressure_ratio = c.pressure_ratio;
    o.cycles = 20;
    o.seed = c.seed;
    o.start_position_m = START_M;
    o.faults = vec![spec];
    o.boot_us = c.boot_us;
    if rotation == Rotation::Expander {
        o.schedule = vec![(
            0,
            HostAction::Command(Command::SetRotation {
                rotation: Rotation::Expander,
            }),
        )];
    }
    // The plant is heavier or lighter than the controller believes (its model stays the
    // reference machine's 12 kg).
    o.model = MachineModel::reference();
    o.model.piston.mass_kg *= c.mass_factor;
    o.configure = Some(|config| config.moving_mass_kg = 12.0);
    let out = run(&o).expect("run");
    let r = &out.injection;
    Outcome {
        case: c.clone(),
        min_clearance_m: r.min_clearance_m.expect("the fault started"),
        fault: r
            .first_fault_after_onset()
            .map(|(_, f)| f.name().to_string()),
    }
}

/// Runs cases `0..n` over the cores with the studies' own runner (`fpc-sim sweep`'s): the
/// result does not depend on the split.
fn sweep(n: u64, rotation: Rotation) -> Vec<Outcome> {
    sweep_of((0..n).collect(), rotation)
}

/// The cases of these indices, over the cores (as [`sweep`]).
fn sweep_of(indices: Vec<u64>, rotation: Rotation) -> Vec<Outcome> {
    let _ = running_start_s();
    let cases: Vec<Case> = indices.into_iter().map(case).collect();
    let run_one = |c: &Case| run_case(c, rotation);
    hal_sim::sweep::run_each(&cases, run_one, &|_| {})
}

/// The distribution of the minimum clearance, the five worst runs with what reproduces them,
/// and the histogram (`clearance.svg` beside the test's scratch files).
fn distribution(outcomes: &[Outcome], name: &str) {
    let mut c: Vec<f64> = outcomes.iter().map(|o| o.min_clearance_m * 1e3).collect();
    c.sort_by(f64::total_cmp);
    let q = |p: f64| c[((c.len() - 1) as f64 * p).round() as usize];
    println!(
        "{} runs: min head clearance, mm: min {:.3}, 0.1 % {:.3}, 1 % {:.3}, 10 % {:.3}, median \
         {:.3}, max {:.3}",
        c.len(),
        q(0.0),
        q(0.001),
        q(0.01),
        q(0.1),
        q(0.5),
        q(1.0)
    );
    let mut worst: Vec<&Outcome> = outcomes.iter().collect();
    worst.sort_by(|a, b| a.min_clearance_m.total_cmp(&b.min_clearance_m));
    println!("the five worst (seed: the case's index):");
    for o in worst.iter().take(5) {
        println!(
            "  {:.3} mm: --fault {} at PR {}, mass ×{:.3}, seed {} (latched {})",
            o.min_clearance_m * 1e3,
            o.case.spec,
            o.case.pressure_ratio,
            o.case.mass_factor,
            o.case.seed,
            o.fault.as_deref().unwrap_or("nothing")
        );
    }
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    let svg = dir.join("clearance.svg");
    hal_sim::sweep::report::histogram(
        &svg,
        &format!(
            "Minimum head clearance after a random fault, {} runs",
            c.len()
        ),
        "clearance, mm",
        &c,
    )
    .expect("histogram written");
    println!("histogram: {}", svg.display());
}

fn report_and_check(outcomes: &[Outcome], rotation: Rotation) {
    let mut by_kind: std::collections::BTreeMap<&str, (Vec<f64>, usize)> = Default::default();
    for o in outcomes {
        let kind = o.case.spec.split('@').next().unwrap_or("?");
        let e = by_kind.entry(kind).or_default();
        e.0.push(o.min_clearance_m * 1e3);
        e.1 += usize::from(o.fault.is_some());
    }
    println!("as {rotation:?}, min head clearance per fault kind, mm:");
    for (kind, (c, detected)) in &mut by_kind {
        c.sort_by(f64::total_cmp);
        let q = |p: f64| c[((c.len() - 1) as f64 * p).round() as usize];
        println!(
            "{kind:>20}: {:5} runs, min {:.3}, 1 % {:.3}, median {:.3}; a fault latched in {detected}",
            c.len(),
            q(0.0),
            q(0.01),
            q(0.5)
        );
    }
    let worst = outcomes
        .iter()
        .min_by(|a, b| a.min_clearance_m.total_cmp(&b.min_clearance_m))
        .expect("runs");
    println!(
        "{} runs as {rotation:?}: min head clearance {:.3} mm ({} at PR {}, mass ×{:.3}, seed {})",
        outcomes.len(),
        worst.min_clearance_m * 1e3,
        worst.case.spec,
        worst.case.pressure_ratio,
        worst.case.mass_factor,
        worst.case.seed
    );
    let below: Vec<_> = outcomes
        .iter()
        .filter(|o| o.min_clearance_m < 0.3e-3)
        .map(|o| {
            format!(
                "{} (PR {}, mass ×{:.3}, seed {}): {:.3} mm",
                o.case.spec,
                o.case.pressure_ratio,
                o.case.mass_factor,
                o.case.seed,
                o.min_clearance_m * 1e3
            )
        })
        .collect();
    assert!(below.is_empty(), "clearance below 0.3 mm: {below:#?}");
    // A lost host parks the piston: nothing latches (the park vents both chambers first,
    // so no pressure sensor is driven past its range).
    let host_loss_faults: Vec<String> = outcomes
        .iter()
        .filter(|o| o.case.spec.starts_with("command_loss"))
        .filter_map(|o| o.fault.as_ref().map(|f| format!("{}: {f}", o.case.spec)))
        .collect();
    assert!(
        host_loss_faults.is_empty(),
        "host loss latched a fault: {host_loss_faults:#?}"
    );
}

/// The default slice in `rotation`'s mode.
fn slice(rotation: Rotation, name: &str) {
    let outcomes = sweep(24, rotation);
    distribution(&outcomes, name);
    report_and_check(&outcomes, rotation);
}

#[test]
fn a_slice_of_random_faults_keeps_the_head_clearance_as_a_compressor() {
    slice(Rotation::Compressor, "slice-compressor");
}

#[test]
fn a_slice_of_random_faults_keeps_the_head_clearance_as_an_expander() {
    slice(Rotation::Expander, "slice-expander");
}

/// Runs of the full sweep, per mode: `FPC_FAULT_RUNS` or 10,000.
fn full_runs() -> u64 {
    std::env::var("FPC_FAULT_RUNS")
        .ok()
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(10_000)
}

/// The cases named by `FPC_FAULT_SEEDS` (indices, comma-separated, as the reports print
/// them), to reproduce a run of the full sweep without the rest; `None` if unset.
fn named_seeds() -> Option<Vec<u64>> {
    let v = std::env::var("FPC_FAULT_SEEDS").ok()?;
    let seeds: Vec<u64> = v
        .split(',')
        .map(|s| {
            s.trim()
                .parse()
                .unwrap_or_else(|_| panic!("FPC_FAULT_SEEDS: {s:?} is not a case index"))
        })
        .collect();
    Some(seeds)
}

/// The full sweep in `rotation`'s mode (or the cases `FPC_FAULT_SEEDS` names).
fn full(rotation: Rotation, name: &str) {
    if let Some(seeds) = named_seeds() {
        let outcomes = sweep_of(seeds, rotation);
        distribution(&outcomes, name);
        report_and_check(&outcomes, rotation);
        return;
    }
    let n = full_runs();
    let outcomes = sweep(n, rotation);
    assert_eq!(outcomes.len() as u64, n);
    distribution(&outcomes, name);
    report_and_check(&outcomes, rotation);
    boot_bracket(&outcomes, rotation);
}

/// The sweep's after-reset cases (the task hangs: the watchdog resets the board, which brakes
/// once booted) again with the boot half and one and a half times the board's `BOOT_US`:
/// the clearance must not rest on the boot time's exact figure.
fn boot_bracket(outcomes: &[Outcome], rotation: Rotation) {
    for boot_us in [BOOT_US / 2, BOOT_US * 3 / 2] {
        let cases: Vec<Case> = outcomes
            .iter()
            .filter(|o| o.case.spec.starts_with("task_hang"))
            .map(|o| Case {
                boot_us,
                ..o.case.clone()
            })
            .collect();
        let run_one = |c: &Case| run_case(c, rotation);
        let bracket = hal_sim::sweep::run_each(&cases, run_one, &|_| {});
        println!(
            "the task hangs again with a boot of {:.2} ms:",
            boot_us as f64 * 1e-3
        );
        report_and_check(&bracket, rotation);
    }
}

#[test]
#[ignore = "slow: 10,000 closed-loop runs (4–7 min in release on two cores; FPC_FAULT_RUNS=N for another count)"]
fn ten_thousand_random_faults_keep_the_head_clearance_as_a_compressor() {
    full(Rotation::Compressor, "full-compressor");
}

#[test]
#[ignore = "slow: 10,000 closed-loop runs (4–7 min in release on two cores; FPC_FAULT_RUNS=N for another count)"]
fn ten_thousand_random_faults_keep_the_head_clearance_as_an_expander() {
    full(Rotation::Expander, "full-expander");
}
