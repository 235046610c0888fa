//! Runs the firmware's task bodies against the simulated board, in lock-step with
//! simulated time.
//!
//! The futures are exactly `fpc::tasks::control_run`, `fpc::tasks::supervision_run` and
//! `fpc::tasks::telemetry_run` (at `World::telemetry`'s decimation, 0 = off), polled
//! on this thread with a no-op waker: poll every task until each waits on the
//! hardware (the next cycle, or a deadline), let the caller observe and command, advance the
//! world by one control period, repeat. No threads, no wall clock, no sleeps.

use std::cell::RefCell;
use std::future::Future;
use std::ops::ControlFlow;
use std::pin::pin;
use std::rc::Rc;
use std::task::{Context, Waker};

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use fpc::controller::ControlConfig;
use fpc::faults::ResetCause;
use fpc::ports::ControlPorts;
use fpc::shared::Shared;
use fpc::tasks::{control_run, supervision_run, telemetry_run};

use crate::capture::telemetry_sink;
use crate::world::{
    clock, cycle, event_log, peripherals, watchdog, SimCycle, SimPeripherals, World, WorldRef,
};

/// The shared state as the simulator instantiates it (single thread: no-op mutex).
pub type SimShared = Shared<NoopRawMutex>;

/// The control-task ports of the simulated board.
pub type SimControlPorts = ControlPorts<
    SimCycle,
    SimPeripherals,
    SimPeripherals,
    SimPeripherals,
    SimPeripherals,
    SimPeripherals,
    SimPeripherals,
>;

/// Runs the firmware's control and supervision tasks on `world` until `each_cycle` breaks.
///
/// `each_cycle` is called once per control period, after the tasks have run for that
/// period and before the plant advances; it may inspect the world and the shared state
/// and post commands (they are taken at the next cycle, as from the RTT channel).
pub fn simulate<F>(world: World, config: ControlConfig, each_cycle: F) -> World
where
    F: FnMut(&mut World, &SimShared) -> ControlFlow<()>,
{
    let shared = SimShared::new();
    simulate_with(
        world,
        &shared,
        |io, shared| control_run(io, shared, config, ResetCause::PowerOn),
        each_cycle,
    )
}

/// As [`simulate`], with the control task body given by `control` (a test can put a
/// different body in the loop, e.g. one that never drives, to show what the real one does).
pub fn simulate_with<'s, F, C, Fut>(
    world: World,
    shared: &'s SimShared,
    control: C,
    mut each_cycle: F,
) -> World
where
    F: FnMut(&mut World, &SimShared) -> ControlFlow<()>,
    C: FnOnce(SimControlPorts, &'s SimShared) -> Fut,
    Fut: Future,
{
    let world: WorldRef = Rc::new(RefCell::new(world));
    let io = ControlPorts {
        cycle: cycle(&world),
        encoders: peripherals(&world),
        currents: peripherals(&world),
        pwm: peripherals(&world),
        quadrature: peripherals(&world),
        servo: peripherals(&world),
        pressures: peripherals(&world),
    };
    {
        let mut control = pin!(control(io, shared));
        let mut supervision = pin!(supervision_run(
            clock(&world),
            clock(&world),
            watchdog(&world),
            event_log(&world),
            shared
        ));
        let decimation = world.borrow().telemetry.decimation;
        let mut telemetry = pin!(telemetry_run(telemetry_sink(&world), shared, decimation));
        let mut cx = Context::from_waker(Waker::noop());
        loop {
            // The task bodies loop forever; a body that returns simply stops acting.
            let _ = control.as_mut().poll(&mut cx);
            let _ = telemetry.as_mut().poll(&mut cx);
            let _ = supervision.as_mut().poll(&mut cx);
            let mut w = world.borrow_mut();
            if each_cycle(&mut w, shared).is_break() {
                break;
            }
            w.advance();
        }
    }
    // The task futures, the only other holders, were dropped above, so this never clones.
    Rc::try_unwrap(world).map_or_else(|rc| rc.borrow().clone(), RefCell::into_inner)
}
