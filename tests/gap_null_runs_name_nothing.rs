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
