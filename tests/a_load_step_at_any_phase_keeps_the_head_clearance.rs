//! A sudden external load of ±3 kN (`docs/faults.md` #10, `--fault load_step`) leaves at least
//! 0.6 mm between the piston and either head, whatever the phase of the stroke cycle it
//! strikes at (issue #15, "margin under load").
//!
//! The step strikes at 24 phases evenly over one compression cycle (dead point A to dead
//! point A: accelerating, at full speed, braking into a dead point, at the dead point) and
//! stays on to the end of the run, so every dead point after it is reached under the load.
//! Full speed, 4.1 m/s, at the reference pressure ratio 3.1 and at 5.1 (the ratio of 4.1 m/s
//! in the paper's Fig. 3). Both signs: +3 kN pushes toward head B, −3 kN toward head A.
//!
//! Without the running strokes' disturbance observer (`disturbance_bandwidth_rad_s` 0) the
//! position loop alone yields 4 mm to 3 kN (7.5e5 N/m): the following error or the braking
//! envelope trips in every run, and a step landing at a dead point struck the head (−0.05 mm;
//! 8 of the 96 runs below 0.6 mm). With it, no fault, ≥ 0.76 mm at every phase. The test prints the
//! figures; the ignored negative control asserts the margin lost and a fault in every run
//! with the observer off.

use std::sync::OnceLock;

use fpc::control::command::Command;
use fpc::motion::synchroniser::Rotation;
use hal_sim::faults::inject::parse;
use hal_sim::run::{run, HostAction, RunOptions};

/// Phases over one compression cycle.
const PHASES: usize = 24;
/// The load, N.
const LOAD_N: f64 = 3000.0;
/// Peak speed, m/s.
const SPEED_MPS: f64 = 4.1;
/// The reference pressure ratio, and the one of 4.1 m/s in Fig. 3.
const PRESSURE_RATIOS: [f64; 2] = [3.1, 5.1];
/// The clearance every run must keep, m.
const MIN_CLEARANCE_M: f64 = 0.6e-3;
/// Compression cycles per run: the step strikes in the second, three more follow under load.
const CYCLES: u32 = 5;

/// The run at `pressure_ratio`, the machine in `rotation`'s mode from the first stroke.
fn options(pressure_ratio: f64, rotation: Rotation) -> RunOptions {
    let mut o = RunOptions::reference();
    o.pressure_ratio = pressure_ratio;
    o.speed_mps = Some(SPEED_MPS);
    o.cycles = CYCLES;
    if rotation == Rotation::Expander {
        o.schedule = vec![(0, HostAction::Command(Command::SetRotation { rotation }))];
    }
    o
}

/// Dead point A of the second compression cycle and the cycle's period, s, from a
/// fault-free run (the first cycle starts from the park position).
fn cycle(pressure_ratio: f64, rotation: Rotation) -> (f64, f64) {
    let out = run(&options(pressure_ratio, rotation)).expect("fault-free run");
    if rotation == Rotation::Expander {
        assert!(
            out.cycle_work_j.iter().skip(1).all(|w| *w < 0.0),
            "as an expander the gas does the work: {:?}",
            out.cycle_work_j
        );
    }
    let t = out.log.column("t_s").expect("t_s");
    let v = out.log.column("v_mps").expect("v_mps");
    // Dead points A: the velocity turns from toward A (−) to toward B (+) at speed.
    let mut dead_a = Vec::new();
    let mut last_fast: Option<f64> = None;
    for (&t, &v) in t.iter().zip(v) {
        if v.abs() > 1.0 {
            if last_fast.is_some_and(|l| l < 0.0) && v > 0.0 {
                dead_a.push(t);
            }
            last_fast = Some(v);
        }
    }
    assert!(
        dead_a.len() >= 3,
        "strokes in the fault-free run: {dead_a:?}"
    );
    // Crossing 1 m/s lags the dead point by the same time in every cycle: the period holds.
    let period = dead_a[2] - dead_a[1];
    // Back from the 1 m/s crossing to the dead point itself: the reference's minimum.
    let x_ref = out.log.column("x_ref_m").expect("x_ref_m");
    let from = t
        .iter()
        .position(|&s| s >= dead_a[1] - 0.25 * period)
        .unwrap_or(0);
    let to = t.iter().position(|&s| s >= dead_a[1]).unwrap_or(t.len());
    let k = (from..to)
        .min_by(|&a, &b| x_ref[a].total_cmp(&x_ref[b]))
        .expect("samples before the crossing");
    (t[k], period)
}

/// [`cycle`] at each of [`PRESSURE_RATIOS`] in `rotation`'s mode.
fn cycles(rotation: Rotation) -> &'static [(f64, f64); 2] {
    static COMPRESSOR: OnceLock<[(f64, f64); 2]> = OnceLock::new();
    static EXPANDER: OnceLock<[(f64, f64); 2]> = OnceLock::new();
    let c = match rotation {
        Rotation::Compressor => &COMPRESSOR,
        Rotation::Expander => &EXPANDER,
    };
    c.get_or_init(|| PRESSURE_RATIOS.map(|pr| cycle(pr, rotation)))
}

/// One run: the step's pressure ratio, phase (of [`PHASES`]) and force.
#[derive(Clone, Copy, Debug)]
struct Case {
    rotation: Rotation,
    ratio: usize,
    phase: usize,
    force_n: f64,
}

/// What one run showed.
#[derive(Clone, Debug)]
struct Outcome {
    case: Case,
    /// Smallest head clearance from the step to the end of the run, m.
    clearance_m: f64,
    /// The first fault latched after the step.
    fault: Option<String>,
}

fn run_case(c: &Case, observer: bool) -> Outcome {
    let (dead_a_s, period_s) = cycles(c.rotation)[c.ratio];
    let at = dead_a_s + period_s * c.phase as f64 / PHASES as f64;
    let spec = format!("load_step@{at:.6}:force_n={}", c.force_n);
    let mut o = options(PRESSURE_RATIOS[c.ratio], c.rotation);
    o.faults = vec![parse(&spec).expect("valid spec")];
    if !observer {
        o.configure = Some(|config| config.disturbance_bandwidth_rad_s = 0.0);
    }
    let out = run(&o).expect("run");
    let r = &out.injection;
    Outcome {
        case: *c,
        clearance_m: r.min_clearance_m.expect("the step struck"),
        fault: r
            .first_fault_after_onset()
            .map(|(_, f)| f.name().to_string()),
    }
}

fn sweep(observer: bool, rotation: Rotation) -> Vec<Outcome> {
    let _ = cycles(rotation);
    let mut cases = Vec::new();
    for ratio in 0..PRESSURE_RATIOS.len() {
        for phase in 0..PHASES {
            for force_n in [LOAD_N, -LOAD_N] {
                cases.push(Case {
                    rotation,
                    ratio,
                    phase,
                    force_n,
                });
            }
        }
    }
    hal_sim::sweep::run_each(&cases, |c| run_case(c, observer), &|_| {})
}

/// Prints the minimum per sign and ratio, with its phase, and the worst run overall;
/// returns the runs below [`MIN_CLEARANCE_M`].
fn report(outcomes: &[Outcome], what: &str) -> Vec<String> {
    println!("{what}:");
    for (ratio, pr) in PRESSURE_RATIOS.iter().enumerate() {
        for sign in [1.0, -1.0] {
            let runs: Vec<&Outcome> = outcomes
                .iter()
                .filter(|o| o.case.ratio == ratio && o.case.force_n * sign > 0.0)
                .collect();
            let worst = runs
                .iter()
                .min_by(|a, b| a.clearance_m.total_cmp(&b.clearance_m))
                .expect("runs");
            let faults = runs.iter().filter(|o| o.fault.is_some()).count();
            println!(
                "  PR {pr}, {:+} N: min clearance {:.3} mm at phase {}/{PHASES} ({}°); a fault \
                 latched in {faults} of {} runs",
                sign * LOAD_N,
                worst.clearance_m * 1e3,
                worst.case.phase,
                worst.case.phase * 360 / PHASES,
                runs.len()
            );
        }
    }
    let worst = outcomes
        .iter()
        .min_by(|a, b| a.clearance_m.total_cmp(&b.clearance_m))
        .expect("runs");
    println!(
        "  worst: {:.3} mm, PR {}, {:+} N at phase {}/{PHASES} (latched {})",
        worst.clearance_m * 1e3,
        PRESSURE_RATIOS[worst.case.ratio],
        worst.case.force_n,
        worst.case.phase,
        worst.fault.as_deref().unwrap_or("nothing")
    );
    outcomes
        .iter()
        .filter(|o| o.clearance_m < MIN_CLEARANCE_M)
        .map(|o| {
            format!(
                "PR {}, {:+} N at phase {}/{PHASES}: {:.3} mm (latched {})",
                PRESSURE_RATIOS[o.case.ratio],
                o.case.force_n,
                o.case.phase,
                o.clearance_m * 1e3,
                o.fault.as_deref().unwrap_or("nothing")
            )
        })
        .collect()
}

/// The sweep in `rotation`'s mode with the observer on: no run below [`MIN_CLEARANCE_M`].
fn every_phase_keeps_the_clearance(rotation: Rotation) {
    for (pr, (dead_a_s, period_s)) in PRESSURE_RATIOS.iter().zip(cycles(rotation)) {
        println!("{rotation:?}, PR {pr}: dead point A at {dead_a_s:.5} s, cycle {period_s:.5} s");
    }
    let below = report(
        &sweep(true, rotation),
        &format!("{rotation:?}, disturbance observer on (the configuration)"),
    );
    assert!(
        below.is_empty(),
        "clearance below {} mm: {below:#?}",
        MIN_CLEARANCE_M * 1e3
    );
}

#[test]
fn a_3_kn_load_step_at_any_of_24_phases_leaves_0_6_mm() {
    every_phase_keeps_the_clearance(Rotation::Compressor);
}

/// The same as an expander (the rotation reversed from the first stroke, the gas driving
/// the piston): the load strikes against or with the admitted gas.
#[test]
fn a_3_kn_load_step_at_any_of_24_phases_leaves_0_6_mm_as_an_expander() {
    every_phase_keeps_the_clearance(Rotation::Expander);
}

/// The negative control: the same sweep with the observer off. The position loop alone
/// must lose the margin somewhere (a step near a dead point) and trip a fault in every run;
/// if it did not, the 24 phases would not be reaching the dead points, and the test above
/// would pass for any controller.
#[test]
#[ignore = "the negative control: the position loop alone (96 runs; CI runs it in the slow suite)"]
fn without_the_observer_a_load_step_near_a_dead_point_costs_the_margin() {
    let outcomes = sweep(false, Rotation::Compressor);
    let below = report(&outcomes, "disturbance observer off");
    let faulted = outcomes.iter().filter(|o| o.fault.is_some()).count();
    println!(
        "  {} of {} runs below 0.6 mm; a fault latched in {faulted}",
        below.len(),
        outcomes.len()
    );
    assert!(
        !below.is_empty(),
        "without the observer no run lost the 0.6 mm margin: the phases miss the dead points"
    );
    assert_eq!(
        faulted,
        outcomes.len(),
        "without the observer the following error or the envelope trips in every run"
    );
}
