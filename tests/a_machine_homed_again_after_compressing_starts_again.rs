//! A machine that has compressed, stopped and been homed again compresses again. The strokes
//! end at head B (an even number of half cycles from head A), and the stop freezes the
//! rotation there, at head B's dead-point phase (π); homing then creeps to head A and parks
//! the piston by it without turning the rotation. The first stroke from the park starts from
//! head A's phase (0): the start first turns the rotation there, the piston held, and the
//! strokes that follow time the ports as on a machine fresh from power-up. (Started from the
//! other dead point's phase, the rotation had no half turn to make over the first stroke: it
//! stood still, chamber B was compressed sealed past the pressure sensors' range and
//! `pressure_sensor` latched — or, a rounding the other way, it had a whole turn to make and
//! `rotation_sync` latched.)

mod support;

use std::f64::consts::{PI, TAU};

use hal_sim::plant::chambers::PortMode;
use hal_sim::plant::model::MachineModel;
use support::drive::*;

const PAPER_RIG: &str = include_str!("../docs/studies/paper-rig.toml");

/// Pressure ratio of the lines while compressing.
const PRESSURE_RATIO: f64 = 3.1;

/// The highest chamber pressure over strokes at `speed_mps` (six half cycles after the
/// first two), Pa.
fn peak_pressure_pa(bench: &mut Bench, speed_mps: f32) -> f64 {
    let mut peak: f64 = 0.0;
    bench.strokes(PRESSURE_RATIO, speed_mps, 6, |w, _| {
        let c = &w.plant.chambers;
        peak = peak.max(c.a.pressure_pa).max(c.b.pressure_pa);
    });
    peak
}

/// The rotation's phase from head A's dead point, rad in [0, 2π).
fn phase_rad(bench: &Bench) -> f64 {
    f64::from(bench.status().theta_rad).rem_euclid(TAU)
}

fn compresses_again_after_homing(machine: &str, model: &MachineModel, seed: u64) {
    let mut bench = Bench::new(model, hal_sim::run::control_config(model), seed, 0.05);
    bench.home();
    let first = peak_pressure_pa(&mut bench, 1.0);
    let s = bench.status();
    assert!(
        s.position_m > 0.2,
        "{machine}: stopped at {} m",
        s.position_m
    );
    // The premise: homed again with the start-up bypass open, as after a shutdown, the piston
    // parks by head A with the rotation still at head B's phase.
    bench.world_mut().plant.port_mode = PortMode::Unloaded;
    bench.home();
    let phase = phase_rad(&bench);
    println!("{machine}: parked at the rotation phase {phase:.3} rad");
    assert!(
        (phase - PI).abs() < 0.1,
        "{machine}: homing left the rotation at {phase} rad"
    );
    let second = peak_pressure_pa(&mut bench, 1.0);
    println!(
        "{machine}: chamber peak {:.0} kPa before homing, {:.0} kPa after",
        first * 1e-3,
        second * 1e-3
    );
    // The ports timed as before: the discharge opens at the same pressure (the line's, at
    // PR 3.1 ≈ 310 kPa, plus the flow's overshoot), not a sealed chamber's 1 MPa.
    assert!(
        (second - first).abs() < 0.1 * first,
        "{machine}: peak {second} Pa after homing against {first} Pa before"
    );
}

#[test]
fn the_paper_rig_compresses_again_after_a_stop_at_head_b_and_homing() {
    let model = MachineModel::parse(PAPER_RIG).expect("the paper rig's model");
    compresses_again_after_homing("paper rig", &model, 11);
}

#[test]
fn the_reference_machine_compresses_again_after_a_stop_at_head_b_and_homing() {
    compresses_again_after_homing("reference machine", &MachineModel::reference(), 3);
}
