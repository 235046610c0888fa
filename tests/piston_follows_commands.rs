//! Closed loop: the firmware's own task bodies, against the simulated plant, in simulated
//! time. The piston homes, then follows a commanded move; without the control task in the
//! loop the same checks fail.

use std::ops::ControlFlow;

use fpc::control::command::Command;
use fpc::ports::CycleTrigger;
use fpc::status::ModeKind;
use hal_sim::board::exec::{simulate, simulate_with, SimShared};
use hal_sim::plant::model::MachineModel;
use hal_sim::run::{control_config, world};

const TARGET_M: f64 = 0.15;
const SPEED_MPS: f32 = 1.0;

/// Largest |x − x_ref| while moving, and |x − target| 50 ms after the move, both true plant
/// positions in metres; `None` where the piston never got there.
#[derive(Debug, Default)]
struct Tracking {
    homed_at_s: Option<f64>,
    max_error_m: f64,
    final_error_m: Option<f64>,
}

fn observe(
    w: &hal_sim::board::world::World,
    shared: &SimShared,
    state: &mut (Tracking, Option<f64>),
) -> ControlFlow<()> {
    let (track, move_started) = state;
    let status = shared.status();
    if w.cycle() == 0 {
        let _ = shared.post_command(Command::Home);
    }
    if track.homed_at_s.is_none() && status.homed && status.mode == ModeKind::Holding {
        track.homed_at_s = Some(w.time_s());
        *move_started = Some(w.time_s());
        let _ = shared.post_command(Command::MoveTo {
            position_m: TARGET_M as f32,
            peak_speed_mps: SPEED_MPS,
        });
    }
    if status.mode == ModeKind::Moving && move_started.is_some() {
        let err = (w.plant.x_m - f64::from(status.reference_m)).abs();
        track.max_error_m = track.max_error_m.max(err);
    }
    if let Some(t0) = *move_started {
        // Move of ~0.14 m at 1 m/s peak lasts ~0.27 s; judge 50 ms after that.
        if w.time_s() > t0 + 0.33 {
            track.final_error_m = Some((w.plant.x_m - TARGET_M).abs());
            return ControlFlow::Break(());
        }
    }
    if w.time_s() > 3.0 {
        return ControlFlow::Break(());
    }
    ControlFlow::Continue(())
}

#[test]
fn piston_homes_then_follows_a_commanded_move() {
    let model = MachineModel::reference();
    let mut state = (Tracking::default(), None);
    let end = simulate(
        world(&model, 7, 0, 0.005),
        control_config(&model),
        |w, s| observe(w, s, &mut state),
    );
    let (track, _) = state;
    println!(
        "homed at {:?} s; max tracking error {:.1} µm; final error {:?} m",
        track.homed_at_s,
        track.max_error_m * 1e6,
        track.final_error_m
    );
    // Homing from 5 mm at 10 mm/s, then the park move to 10 mm: about 0.9 s.
    assert!(
        track.homed_at_s.is_some_and(|t| t < 1.5),
        "homing did not finish"
    );
    assert!(
        track.max_error_m < 0.3e-3,
        "tracking error {} m",
        track.max_error_m
    );
    assert!(
        track.final_error_m.is_some_and(|e| e < 20e-6),
        "final error {:?}",
        track.final_error_m
    );
    // The zero is head A: the piston never went through it.
    assert!(end.plant.x_m > 0.1);
}

#[test]
fn without_the_control_task_the_piston_does_not_follow() {
    let model = MachineModel::reference();
    let mut state = (Tracking::default(), None);
    let shared = SimShared::new();
    // A body that keeps the cycle but never reads, decides or drives anything.
    let idle = |mut io: hal_sim::board::exec::SimControlPorts, _: &SimShared| async move {
        loop {
            io.cycle.next_cycle().await;
        }
    };
    simulate_with(world(&model, 7, 0, 0.005), &shared, idle, |w, s| {
        observe(w, s, &mut state)
    });
    let (track, _) = state;
    assert!(track.homed_at_s.is_none());
    assert!(track.final_error_m.is_none_or(|e| e > 20e-6));
}
