//! What the operator sees in the log: the supervision task (1 kHz, never the 20 kHz path)
//! reports mode changes (info), limits (warn) and latched faults (error). On the board these
//! are defmt lines; the simulator records them with their time.

use std::ops::ControlFlow;

use fpc::control::command::Command;
use fpc::safety::faults::Fault;
use fpc::status::ModeKind;
use hal_sim::board::exec::simulate;
use hal_sim::board::world::Event;
use hal_sim::plant::model::MachineModel;
use hal_sim::run::{control_config, world};

#[test]
fn mode_changes_and_a_latched_fault_are_reported_once_each() {
    let model = MachineModel::reference();
    let mut config = control_config(&model);
    // A following-error limit no real move can meet: the park move after homing latches it.
    config.supervisor.following_error_m = 1e-6;
    let mut moved = false;
    let mut fault_at = None;
    let mut faulted_at: Option<f64> = None;
    let end = simulate(world(&model, 5, 0, 0.005), config, |w, shared| {
        let status = shared.status();
        if w.cycle() == 0 {
            let _ = shared.post_command(Command::Home);
        }
        if !moved && status.homed && status.mode == ModeKind::Holding {
            moved = true;
            let _ = shared.post_command(Command::MoveTo {
                position_m: 0.1,
                peak_speed_mps: 1.0,
            });
        }
        if !status.faults.is_empty() && fault_at.is_none() {
            fault_at = Some(w.time_s());
        }
        // Until SS1 has ended (the stop, the turn to the rest phase, then 50 ms of holding
        // with no force before the outputs go off) and the 1 kHz task has seen it: 20 ms
        // after the outputs went off, or 1 s after the fault at most.
        let ended = status.mode == ModeKind::Faulted;
        if ended && faulted_at.is_none() {
            faulted_at = Some(w.time_s());
        }
        if faulted_at.is_some_and(|t| w.time_s() > t + 0.02)
            || fault_at.is_some_and(|t| w.time_s() > t + 1.0)
            || w.time_s() > 3.0
        {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    let modes: Vec<ModeKind> = end
        .events
        .iter()
        .filter_map(|e| match e {
            Event::ModeChanged(_, m) => Some(*m),
            _ => None,
        })
        .collect();
    let faults: Vec<Fault> = end
        .events
        .iter()
        .filter_map(|e| match e {
            Event::FaultLatched(_, f) => Some(*f),
            _ => None,
        })
        .collect();
    println!("events: {:?}", end.events);
    assert_eq!(modes.first(), Some(&ModeKind::Homing));
    assert!(modes.contains(&ModeKind::Moving));
    assert_eq!(
        modes.last(),
        Some(&ModeKind::Faulted),
        "SS1 ends with the outputs off"
    );
    assert!(
        modes.windows(2).all(|w| w[0] != w[1]),
        "a mode change is reported once"
    );
    assert_eq!(faults, vec![Fault::FollowingError]);
}
