//! A run of the very machine the model describes must name nothing: the workflow's
//! significance test and floors (`gap::select`) hold on closed-loop runs at every speed and
//! on the closed- and open-port pressure runs, over many noise seeds.
//!
//! A few seeds run by default; the 20-seed sweeps are `#[ignore]` (CI runs
//! `cargo test --workspace --release -- --ignored`).

mod support;

use hal_sim::gap::synth;
use hal_sim::plant::model::MachineModel;
use support::gap::*;

fn closed_loop_null(seed: u64, speed_mps: f64) {
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
}

fn closed_port_null(seed: u64) {
    let m = MachineModel::reference();
    let (start, moves) = synth::closed_port_moves(&m, 1);
    let j = gap(
        &reference(),
        &synth::closed_port_run(&m, start, &moves, seed),
    );
    assert!(j.effects.is_empty(), "seed {seed} named {:?}", names(&j));
}

fn open_port_null(seed: u64) {
    let m = MachineModel::reference();
    let j = gap(&reference(), &synth::open_port_run(&m, 3.1, 2.3, 1.5, seed));
    assert!(j.effects.is_empty(), "seed {seed} named {:?}", names(&j));
}

#[test]
fn gap_names_nothing_on_runs_of_the_modelled_machine() {
    closed_loop_null(101, 2.3);
    closed_loop_null(102, 4.0);
    closed_port_null(103);
    open_port_null(104);
}

#[test]
#[ignore = "slow: 20 closed-loop seeds at four speeds"]
fn gap_names_nothing_on_20_closed_loop_seeds() {
    let speeds = [1.0, 2.3, 3.5, 4.0];
    for seed in 0..20u64 {
        closed_loop_null(200 + seed, speeds[(seed % 4) as usize]);
    }
}

#[test]
#[ignore = "slow: 20 closed-port and 20 open-port seeds"]
fn gap_names_nothing_on_20_pressure_seeds() {
    for seed in 0..20u64 {
        closed_port_null(300 + seed);
        open_port_null(400 + seed);
    }
}

/// The simulator's own run (`fpc-sim run --seed SEED`, the default 10 cycles at 2.3 m/s)
/// with the ports metadata of what its machine does: `open` (timed by the rotation) from the
/// moment the start-up bypass closes, which is the row before the rotation's reference first
/// moves (the run posts the start command in the cycle it closes the bypass), and the ports
/// one control period behind the logged servo angle. Run logs do not carry these keys yet
/// (issue #18: at other speeds the replay still names leakage, see the README); without
/// `ports_from_s` the replay vents nothing through homing and the residual is 28 kPa.
fn run_log_with_ports_null(seed: u64) {
    let opts = hal_sim::run::RunOptions {
        seed,
        ..hal_sim::run::RunOptions::reference()
    };
    let mut log = hal_sim::run::run(&opts).expect("run").log;
    let t = log.column("t_s").expect("t_s").to_vec();
    let theta_ref = log.column("theta_ref_rad").expect("theta_ref_rad");
    let first = theta_ref
        .iter()
        .position(|v| *v != 0.0)
        .expect("the rotation starts");
    let from = t[first.saturating_sub(1)];
    log.meta.retain(|(k, _)| !k.starts_with("ports"));
    log.meta.push(("ports".into(), "open".into()));
    log.meta.push(("ports_from_s".into(), format!("{from}")));
    log.meta.push(("ports_delay_s".into(), "5e-5".into()));
    let j = gap(&reference(), &log);
    let pressure = j
        .channels
        .iter()
        .find(|c| c.name == "pressure")
        .expect("the pressure channel is compared");
    assert!(
        j.effects.is_empty(),
        "seed {seed} named {:?} (pressure {:.0} Pa)",
        names(&j),
        pressure.rms_before
    );
    assert!(
        pressure.rms_before < 200.0,
        "seed {seed}: pressure residual {:.0} Pa",
        pressure.rms_before
    );
}

#[test]
fn gap_names_nothing_on_the_simulators_own_runs_with_their_ports() {
    for seed in [1, 2, 3, 7] {
        run_log_with_ports_null(seed);
    }
}
