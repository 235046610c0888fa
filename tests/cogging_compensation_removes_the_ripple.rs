//! Cogging compensation from the calibrated map removes ≥ 80 % of the force ripple at the
//! magnetic pitch.
//!
//! The ripple measure: at constant velocity (0.1 m/s, both directions, over 4 whole
//! periods each way — the cogging routine's own sweeps), the amplitude of the 24 mm
//! harmonic of
//! - the position error, true piston position minus reference (what the ripple does to the
//!   machine: the position loop lets `F/k_p` through at this low frequency), and
//! - the net disturbance on the piston, the plant's cogging force minus the compensation
//!   the firmware adds (the map at the measured position).
//!
//! Fitted by least squares over the samples (a constant and the pitch's sine and cosine), on
//! the machine with unknowns, commissioned; "before" is the same machine with the map
//! emptied.

mod support;

use fpc::control::calibration::{Calibrated, Routine};
use fpc::physics::cogging::HarmonicMap;
use fpc::status::ModeKind;
use support::drive::*;

/// Pitch-harmonic amplitudes (position error, m; net disturbance, N) over the cruises of a
/// cogging routine's sweeps, with `map` compensating.
fn ripple(
    model: &hal_sim::plant::model::MachineModel,
    found: &Calibrated,
    map: HarmonicMap,
) -> (f64, f64) {
    let mut config = uncalibrated_config(model);
    found.apply(&mut config);
    config.allocation.cogging = map;
    let mut bench = Bench::new(model, config, 17, 0.05);
    bench.home();
    // The homed frame sits where homing found the head; the plant's is the head itself.
    let shift = bench.world().plant.x_m - f64::from(bench.status().position_m);
    bench
        .command(fpc::control::command::Command::Calibrate {
            routine: Routine::Cogging,
        })
        .expect("cogging sweeps accepted");
    let speed = f64::from(bench.step.config().calibration.sweep_speed_mps);
    let period = f64::from(bench.step.config().motor.electrical_period_m);
    let (mut error, mut disturbance) = (Vec::new(), Vec::new());
    let mut last_ref = None;
    let done = bench.run_until(10.0, |w, s| {
        let r = f64::from(s.reference_m);
        let v_ref = last_ref.map_or(0.0, |l: f64| (r - l) / 50e-6);
        last_ref = Some(r);
        if s.mode == ModeKind::Calibrating && (v_ref.abs() - speed).abs() < 1e-3 {
            let x = w.plant.x_m;
            error.push((x, x - shift - r));
            let compensation = f64::from(map.force_n(s.position_m));
            disturbance.push((x, w.plant.cogging_force_n - compensation));
        }
        s.mode == ModeKind::Holding
    });
    assert!(done && bench.status().faults.is_empty());
    assert!(error.len() > 30_000, "{} cruise samples", error.len());
    (
        pitch_harmonic(&error, period),
        pitch_harmonic(&disturbance, period),
    )
}

#[test]
fn the_calibrated_map_removes_at_least_80_percent_of_the_pitch_ripple() {
    let model = machine_with_unknowns();
    println!("commissioning:");
    let (_, found) = commission(&model, 3);
    let map = found.cogging.expect("cogging map");
    let (e0, d0) = ripple(&model, &found, HarmonicMap::none());
    let (e1, d1) = ripple(&model, &found, map);
    println!(
        "pitch ripple at 0.1 m/s: position error {:.2} µm → {:.2} µm ({:.1} % removed); \
         net disturbance {:.2} N → {:.2} N ({:.1} % removed)",
        e0 * 1e6,
        e1 * 1e6,
        (1.0 - e1 / e0) * 100.0,
        d0,
        d1,
        (1.0 - d1 / d0) * 100.0
    );
    assert!(d0 > 25.0, "the plant's 30 N of cogging must show");
    assert!(e1 <= 0.2 * e0);
    assert!(d1 <= 0.2 * d0);
}
