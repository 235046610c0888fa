//! Faults of the drive (`docs/faults.md`), on the simulated machine:
//! - a **current-sense offset** is seen with the outputs off (the phase currents' mean is not
//!   zero once the calibrated offsets are taken off); the outputs are not switched on
//!   (homing and the routines that drive are refused with the reason) until the current-sense
//!   calibration has loaded new offsets — and a sensor whose zero is beyond the plausible
//!   range is refused by that calibration, so the refusal stays;
//! - an **overcurrent** in one section latches the fault at once, takes that section out of
//!   the allocation and switches its bridge off (six gates low; the other keeps switching),
//!   and the other section alone stops the piston on the braking envelope (SS1), clearance
//!   kept;
//! - a **section loss** (its bridge open: no current, no force) shows as the force it
//!   delivers falling short of its share; the allocation drops it, the other section carries
//!   the whole force and stops the piston (SS1), clearance kept.

mod support;

use fpc::control::calibration::{CalibrationError, Routine};
use fpc::control::command::{Command, Refusal};
use fpc::physics::motor::Dq;
use fpc::safety::faults::Fault;
use fpc::status::ModeKind;
use fpc::units::Section;
use hal_sim::plant::model::MachineModel;
use support::drive::*;

#[test]
fn a_current_sense_offset_is_seen_with_the_outputs_off_and_calibrated_away() {
    let model = machine_with_unknowns();
    let mut bench = Bench::new(&model, uncalibrated_config(&model), 4, 0.05);
    bench.run_for(0.1, |_, _| {});
    let residual = bench.step.current_sense_residual_a().expect("checked");
    println!("outputs off at start-up: {residual:.2} A mean phase current");
    assert!(residual > 0.5);
    assert_eq!(
        bench.command(Command::Home),
        Err(Refusal::CurrentSenseOffset)
    );
    assert_eq!(
        bench.command(Command::Calibrate {
            routine: Routine::Alignment
        }),
        Err(Refusal::CurrentSenseOffset)
    );
    println!("  refused: {}", Refusal::CurrentSenseOffset.reason());
    assert_eq!(bench.status().mode, ModeKind::Idle);
    assert!(!bench.world().enabled);

    calibrate(&mut bench, Routine::CurrentSense);
    bench.run_for(0.1, |_, _| {});
    let residual = bench.step.current_sense_residual_a().expect("checked");
    println!("after the current-sense calibration: {residual:.3} A");
    assert!(residual < 0.1);
    bench.home();
}

#[test]
fn a_broken_current_sensor_is_refused_by_the_calibration() {
    // 9 A on the slave's phase b: 184 codes, beyond the 100 codes a sound sensor can show.
    let mut model = MachineModel::reference();
    model.sensors.current.offset_slave_a = [0.0, 9.0, 0.0];
    let mut bench = Bench::new(&model, uncalibrated_config(&model), 4, 0.05);
    bench.run_command(
        Command::Calibrate {
            routine: Routine::CurrentSense,
        },
        ModeKind::Idle,
        1.0,
    );
    let record = bench.step.calibrated();
    println!("broken sensor: {:?}", record.last_error);
    assert_eq!(
        record.last_error,
        Some((
            Routine::CurrentSense,
            CalibrationError::CurrentSenseOffset {
                section: Section::Slave,
                phase: 1
            }
        ))
    );
    assert_eq!(record.current_sense, None);
    assert_eq!(
        bench.step.config().current_sense.slave.offset_codes,
        [0.0; 3]
    );
    bench.run_for(0.1, |_, _| {});
    assert_eq!(
        bench.command(Command::Home),
        Err(Refusal::CurrentSenseOffset)
    );
}

#[test]
fn an_overcurrent_switches_its_section_off_and_the_other_stops_the_piston() {
    // Strokes at 4.1 m/s against PR 5.1; late on the way to head B (its chamber near the
    // discharge pressure, 55 mm to go), a 90 A surge on the master section's d axis (a
    // gate-drive glitch or a transient short).
    let model = MachineModel::reference();
    let mut bench = Bench::new(&model, uncalibrated_config(&model), 8, 0.05);
    stroking_until(&mut bench, |w| w.plant.v_mps > 1.0 && w.plant.x_m > 0.15);
    let q = bench.world().plant.motors.current.master.q;
    bench.world_mut().plant.motors.current.master = Dq { d: 90.0, q };
    let t0 = bench.time_s();
    let (mut detected_s, mut min_clearance, mut max_master_after) = (None, f64::MAX, 0.0f64);
    let (mut slave_force, mut at_rest_s, mut x0) = (0.0f64, 0.0, None);
    // Cycles, from the detection on, with the master bridge still switching / the slave's.
    let (mut master_switching, mut slave_switching) = (0u32, 0u32);
    let ended = bench.run_until(2.0, |w, s| {
        x0.get_or_insert(w.plant.x_m);
        let t = w.time_s() - t0;
        if detected_s.is_none() && s.faults.contains(Fault::Overcurrent) {
            detected_s = Some(t);
        }
        min_clearance = min_clearance.min(w.plant.head_clearance_m());
        if t > 5e-3 {
            let i = w.plant.current.master;
            max_master_after = max_master_after.max(i.d.hypot(i.q));
        }
        if detected_s.is_some() {
            slave_force = slave_force.max(w.plant.force_n.slave.abs());
            let drive = w.drive();
            master_switching += u32::from(drive.duties.master.is_some());
            slave_switching += u32::from(drive.duties.slave.is_some());
        }
        // Stopped: at rest for 20 ms (SS1 then switches the outputs off once holding needs
        // no force; with the chambers still under pressure it holds).
        s.mode == ModeKind::Faulted || at_rest_for(&mut at_rest_s, w.plant.v_mps) >= 0.02
    });
    let s = bench.status();
    println!(
        "overcurrent at {:.1} mm: detected after {:.2} ms, {:?}; master section's current \
         after 5 ms ≤ {:.2} A; slave alone carries up to {:.0} N; min clearance {:.3} mm; \
         final mode {}, outputs {}; after the detection the master bridge switched in {} \
         cycles, the slave's in {}",
        x0.unwrap_or(f64::NAN) * 1e3,
        detected_s.unwrap_or(f64::NAN) * 1e3,
        s.faults.iter().map(|f| f.name()).collect::<Vec<_>>(),
        max_master_after,
        slave_force,
        min_clearance * 1e3,
        s.mode.name(),
        if bench.world().enabled { "on" } else { "off" },
        master_switching,
        slave_switching
    );
    assert!(ended, "no stop");
    assert_eq!(s.faults.first(), Some(Fault::Overcurrent));
    assert!(detected_s.is_some_and(|t| t <= 3.0 * 50e-6 + 1e-9));
    assert!(
        max_master_after < 2.0,
        "the master section still carries current"
    );
    // The cycle that sees the surge drops the section: its bridge is off from the next on,
    // while the slave's keeps switching to stop the piston.
    assert!(master_switching <= 1, "the master bridge kept switching");
    assert!(slave_switching > 100, "the slave drives the stop");
    // Against the compressed chamber B the stop needs the motor to push on: the slave alone.
    assert!(slave_force > 1000.0, "the slave carries the force");
    assert!(min_clearance >= 0.3e-3);
    assert!(matches!(s.mode, ModeKind::Stopping | ModeKind::Faulted));
    assert!(!s.faults.is_empty(), "restart inhibited");
}

/// Strokes the reference machine at 4.1 m/s against PR 5.1 until `at` says the moment has
/// come (a few strokes in).
fn stroking_until(bench: &mut Bench, at: impl Fn(&hal_sim::board::world::World) -> bool) {
    bench.home();
    {
        let mut w = bench.world_mut();
        w.plant.port_mode = hal_sim::plant::chambers::PortMode::Timed;
        w.plant.lines.set_pressure_ratio(5.1);
    }
    bench
        .command(Command::Start {
            peak_speed_mps: 4.1,
        })
        .expect("start");
    let start = bench.time_s();
    let reached = bench.run_until(5.0, |w, _| w.time_s() > start + 0.4 && at(w));
    assert!(reached);
}

#[test]
fn a_lost_section_is_dropped_and_the_other_stops_the_piston() {
    // At full speed mid-stroke, the slave section's bridge opens: from then on its phases
    // carry no current (modelled as an inductance no voltage can drive a current through).
    let model = MachineModel::reference();
    let mut bench = Bench::new(&model, uncalibrated_config(&model), 12, 0.05);
    stroking_until(&mut bench, |w| w.plant.v_mps > 3.9);
    {
        let mut w = bench.world_mut();
        w.plant.motors.params.motor.slave.inductance_h = 1e3;
        w.plant.motors.current.slave = Dq::default();
    }
    let (t0, x0) = (bench.time_s(), bench.world().plant.x_m);
    let (mut detected_s, mut min_clearance) = (None, f64::MAX);
    let (mut master_force, mut slave_force, mut at_rest_s) = (0.0f64, 0.0f64, 0.0);
    let ended = bench.run_until(2.0, |w, s| {
        if detected_s.is_none() && !s.faults.is_empty() {
            detected_s = Some(w.time_s() - t0);
        }
        min_clearance = min_clearance.min(w.plant.head_clearance_m());
        if detected_s.is_some() {
            master_force = master_force.max(w.plant.force_n.master.abs());
        }
        slave_force = slave_force.max(w.plant.force_n.slave.abs());
        s.mode == ModeKind::Faulted || at_rest_for(&mut at_rest_s, w.plant.v_mps) >= 0.02
    });
    let s = bench.status();
    println!(
        "slave section lost at {:.1} mm, 3.9+ m/s: {:?} after {:.2} ms; the master alone \
         carries up to {:.0} N (the slave {:.1} N); stopped at {:.1} mm, min clearance {:.3} mm, \
         mode {}",
        x0 * 1e3,
        s.faults.iter().map(|f| f.name()).collect::<Vec<_>>(),
        detected_s.unwrap_or(f64::NAN) * 1e3,
        master_force,
        slave_force,
        bench.world().plant.x_m * 1e3,
        min_clearance * 1e3,
        s.mode.name()
    );
    assert!(ended, "no stop");
    assert!(matches!(
        s.faults.first(),
        Some(Fault::SectionFault | Fault::FollowingError)
    ));
    assert!(detected_s.is_some_and(|t| t <= 10e-3));
    assert!(slave_force < 1.0);
    assert!(master_force > 1000.0);
    assert!(min_clearance >= 0.3e-3);
    assert!(matches!(s.mode, ModeKind::Stopping | ModeKind::Faulted));
}
