//! A run of the very machine the model describes must name nothing: the workflow's
//! significance test and floors (`gap::judge`) hold on closed-loop runs at every speed and
//! on the closed- and open-port pressure runs, over many noise seeds.
//!
//! A few seeds run by default; the 20-seed sweeps are `#[ignore]`: in full,
//! `cargo test --profile slow-tests --test gap_null_runs_name_nothing -- --ignored`; CI runs
//! a slice of them (`FPC_NULL_STRIDE=ci`, see [`stride`]).

mod support;

use hal_sim::gap::{synth, GapJson};
use hal_sim::plant::model::MachineModel;
use support::gap::*;

/// Whether any channel of a null run is left structured (`unexplained.structured`), printed.
fn left_structured(what: &str, j: &GapJson) -> bool {
    let structured: Vec<String> = j
        .channels
        .iter()
        .filter(|c| c.unexplained.structured)
        .map(|c| format!("{} {:?}", c.name, c.unexplained))
        .collect();
    if !structured.is_empty() {
        println!("{what}: left structured: {structured:?}");
    }
    !structured.is_empty()
}

/// At most 5 % of null runs may be left structured (of 20 or fewer: none).
fn at_most_5_percent_structured(flags: &[bool]) {
    let n = flags.iter().filter(|f| **f).count();
    assert!(
        20 * n <= flags.len(),
        "{n} of {} null runs left structured",
        flags.len()
    );
}

fn closed_loop_null(seed: u64, speed_mps: f64) -> bool {
    let log = closed_loop(&reference(), speed_mps, 2, seed);
    let j = gap(&reference(), &log);
    assert!(
        j.effects.is_empty(),
        "seed {seed} at {speed_mps} m/s named {:?}",
        names(&j)
    );
    for c in &j.channels {
        assert_eq!(
            c.rms_before, c.rms_after,
            "{}: the model must not change",
            c.name
        );
    }
    left_structured(&format!("seed {seed} at {speed_mps} m/s"), &j)
}

fn closed_port_null(seed: u64) -> bool {
    let m = MachineModel::reference();
    let (start, moves) = synth::closed_port_moves(&m, 1);
    let j = gap(
        &reference(),
        &synth::closed_port_run(&m, start, &moves, seed),
    );
    assert!(j.effects.is_empty(), "seed {seed} named {:?}", names(&j));
    left_structured(&format!("closed ports, seed {seed}"), &j)
}

fn open_port_null(seed: u64) -> bool {
    let m = MachineModel::reference();
    let j = gap(&reference(), &synth::open_port_run(&m, 3.1, 2.3, 1.5, seed));
    assert!(j.effects.is_empty(), "seed {seed} named {:?}", names(&j));
    left_structured(&format!("open ports, seed {seed}"), &j)
}

#[test]
fn gap_names_nothing_on_runs_of_the_modelled_machine() {
    at_most_5_percent_structured(&[
        closed_loop_null(101, 2.3),
        closed_loop_null(102, 4.0),
        closed_port_null(103),
        open_port_null(104),
    ]);
}

/// Every `FPC_NULL_STRIDE`-th case of the slow sweeps below (1, all of them, by default).
/// CI runs a stride of 3 and 7: a further seed of an operating point already covered only
/// draws the noise again, so the slice keeps every speed, pressure ratio and log rate and
/// drops repeats (the strides are coprime with the sweeps' periods of 4 and 12).
fn stride(ci: usize) -> usize {
    match std::env::var("FPC_NULL_STRIDE") {
        Ok(v) if v.trim() == "ci" => ci,
        Ok(v) => v.trim().parse().unwrap_or(1).max(1),
        Err(_) => 1,
    }
}

#[test]
#[ignore = "slow: 20 closed-loop seeds at four speeds"]
fn gap_names_nothing_on_20_closed_loop_seeds() {
    let speeds = [1.0, 2.3, 3.5, 4.0];
    let flags: Vec<bool> = (0..20u64)
        .step_by(stride(3))
        .map(|seed| closed_loop_null(200 + seed, speeds[(seed % 4) as usize]))
        .collect();
    at_most_5_percent_structured(&flags);
}

#[test]
#[ignore = "slow: 20 closed-port and 20 open-port seeds"]
fn gap_names_nothing_on_20_pressure_seeds() {
    let mut flags = Vec::new();
    for seed in (0..20u64).step_by(stride(3)) {
        flags.push(closed_port_null(300 + seed));
        flags.push(open_port_null(400 + seed));
    }
    at_most_5_percent_structured(&flags);
}

/// The simulator's own run (`fpc-sim run --seed SEED --speed V`, 10 cycles), its log as
/// `run` writes it: `# ports = open` from the moment the start-up bypass closes
/// (`ports_from_s`) and `# theta_source = servo_encoder` (the logged angle is the servo's
/// count; the piston follows through the spline's play). Issue #18: with `ports = open`
/// alone gap named leakage, port restriction and heat transfer (28 kPa).
/// Effects of the pressure channel (what the ports metadata is for).
const PRESSURE_EFFECTS: [&str; 5] = [
    "leakage",
    "heat_transfer",
    "port_restriction",
    "pressure_offset",
    "pressure_gain",
];

/// `only_pressure`: only the pressure channel's effects count (the sweep below; see its note).
fn own_run_null(
    seed: u64,
    speed_mps: f64,
    pressure_ratio: f64,
    decimation: usize,
    only_pressure: bool,
) -> bool {
    let opts = hal_sim::run::RunOptions {
        seed,
        speed_mps: Some(speed_mps),
        pressure_ratio,
        ..hal_sim::run::RunOptions::reference()
    };
    let mut log = hal_sim::run::run(&opts).expect("run").log;
    if decimation > 1 {
        // A copy at a lower rate, as a logger that keeps every n-th sample writes it.
        for c in &mut log.columns {
            *c = c.iter().step_by(decimation).copied().collect();
        }
        for (k, v) in &mut log.meta {
            if k == "sample_rate_hz" {
                *v = format!("{}", 20_000 / decimation);
            }
        }
    }
    assert_eq!(log.meta("ports"), Some("open"));
    assert_eq!(log.meta("theta_source"), Some("servo_encoder"));
    let j = gap(&reference(), &log);
    let pressure = j
        .channels
        .iter()
        .find(|c| c.name == "pressure")
        .expect("the pressure channel is compared");
    println!(
        "seed {seed} at {speed_mps} m/s, PR {pressure_ratio}, 1/{decimation} of the rows: pressure residual {:.0} Pa, named {:?}",
        pressure.rms_before,
        names(&j)
    );
    let named: Vec<String> = names(&j)
        .into_iter()
        .filter(|n| !only_pressure || PRESSURE_EFFECTS.contains(&n.as_str()))
        .collect();
    // Seed 537 (PR 4.5, 0.6 m/s, full rate) named `port_restriction` at `area_scale` 0.996
    // until the sparse significance test counted a sample only when the change reaches one
    // sensor code (`gap::channel::sample_resolution`): its change was below one code on every
    // sample.
    assert!(
        named.is_empty(),
        "seed {seed} at {speed_mps} m/s, PR {pressure_ratio}, 1/{decimation} of the rows named {:?} (pressure {:.0} Pa)",
        names(&j),
        pressure.rms_before
    );
    // Below one code of the 10 bar sensor (305 Pa; its rounding alone is 88 Pa RMS): the
    // 28 kPa of issue #18 and the 0.2–1 kPa of an untimed or unplayed rotation are gone.
    assert!(
        pressure.rms_before < 250.0,
        "seed {seed} at {speed_mps} m/s, PR {pressure_ratio}, 1/{decimation} of the rows: pressure residual {:.0} Pa",
        pressure.rms_before
    );
    let what = format!("seed {seed} at {speed_mps} m/s, PR {pressure_ratio}, 1/{decimation}");
    if only_pressure {
        pressure.unexplained.structured
    } else {
        left_structured(&what, &j)
    }
}

#[test]
fn gap_names_nothing_on_the_simulators_own_runs() {
    let mut flags: Vec<bool> = [1, 2, 3, 7]
        .into_iter()
        .map(|seed| own_run_null(seed, 2.3, 3.1, 1, false))
        .collect();
    flags.push(own_run_null(11, 1.0, 3.1, 1, false));
    flags.push(own_run_null(12, 4.1, 3.1, 1, false));
    // A 10 kHz copy (the paper's logging rate).
    flags.push(own_run_null(13, 4.1, 3.1, 2, false));
    at_most_5_percent_structured(&flags);
}

/// Slow strokes at a high ratio (0.3 m/s, PR 4.5: 27 s runs). The rotation nearly stops at
/// each dead point and then turns one servo count every 3–20 ms, and the servo, whose loop
/// closes on that count, turns unevenly within each count: the ports' angle there is known
/// only within the count, and a chamber blowing down through its opening port follows it.
/// Judged there, the replay missed the plant by about 1 kPa at every dead point and
/// `leakage` was named on seeds 62 and 63 (rod seals' gap fitted to 0, 69 % and 50 % of the
/// residual); those samples are no longer judged (`gap::replay::ports_resolved`). Seed
/// 62 first, so that CI's stride keeps it.
#[test]
#[ignore = "slow: three runs of 27 s at 0.3 m/s"]
fn gap_names_nothing_on_slow_high_ratio_runs() {
    let flags: Vec<bool> = [62, 63, 61]
        .into_iter()
        .step_by(stride(3))
        .map(|seed| own_run_null(seed, 0.3, 4.5, 1, false))
        .collect();
    at_most_5_percent_structured(&flags);
}

/// The point of the sweep below where the logged position's homing offset (7–10 µm into
/// head A) showed once the angle-unresolved samples were left out: `port_restriction` was
/// named (area 1.006) until the replay fitted that offset as a nuisance
/// (`gap::offset::fit_position_offset`).
#[test]
#[ignore = "slow: a run at 2.3 m/s, PR 6"]
fn gap_names_nothing_where_the_homing_offset_showed() {
    at_most_5_percent_structured(&[own_run_null(554, 2.3, 6.0, 2, true)]);
}

#[test]
#[ignore = "slow: the simulator's own runs over speeds and pressure ratios"]
/// The pressure channel names nothing anywhere in the envelope. Open finding: the force
/// channel names `viscous_friction` at PR 1.5 and 4.1 m/s (printed above the assertion).
fn gap_names_no_pressure_effect_on_the_simulators_own_runs_at_every_operating_point() {
    let mut points = Vec::new();
    for pressure_ratio in [1.5, 2.2, 3.1, 4.5, 6.0] {
        for speed in [0.6, 1.0, 2.3, 3.5, 4.1, 4.5] {
            for decimation in [1, 2] {
                points.push((501 + points.len() as u64, speed, pressure_ratio, decimation));
            }
        }
    }
    let flags: Vec<bool> = points
        .into_iter()
        .step_by(stride(7))
        .map(|(seed, speed, pressure_ratio, decimation)| {
            own_run_null(seed, speed, pressure_ratio, decimation, true)
        })
        .collect();
    at_most_5_percent_structured(&flags);
}
