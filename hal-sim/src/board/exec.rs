//! Runs the firmware's task bodies against the simulated board, in lock-step with
//! simulated time.
//!
//! The futures are exactly `fpc::tasks::control_run`, `fpc::tasks::supervision_run` and
//! `fpc::tasks::telemetry_run` (at `World::telemetry`'s decimation, 0 = off), polled
//! on this thread with a no-op waker: poll every task until each waits on the
//! hardware (the next cycle, or a deadline), let the caller observe and command, advance the
//! world by one control period, repeat. No threads, no wall clock, no sleeps.
//!
//! [`simulate_board`] adds what the board does beyond running the tasks, for the fault
//! scenarios of `docs/faults.md`: a control step that overruns (the task is not polled for some
//! periods, the outputs hold), a task that hangs, and the independent watchdog, which resets
//! the MCU when the supervision task stops feeding it: outputs off, the boot's
//! [`BOOT_US`] with nothing running, then the shared RAM and every task started afresh with
//! [`ResetCause::Watchdog`], while the plant keeps moving.

use std::cell::RefCell;
use std::convert::Infallible;
use std::future::Future;
use std::ops::ControlFlow;
use std::pin::{pin, Pin};
use std::rc::Rc;
use std::task::{Context, Waker};

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use fpc::control::calibration::record::CalibrationRecord;
use fpc::control::calibration::store::LoadError;
use fpc::control::config::ControlConfig;
use fpc::link::channels::UP_REPLIES;
use fpc::ports::ControlPorts;
use fpc::safety::faults::ResetCause;
use fpc::shared::Shared;
use fpc::tasks::{command_run, control_run, supervision_run, telemetry_run};

use crate::board::flash::SimFlash;

use crate::board::channels::{command_channel, telemetry_sink, up_channel};
use crate::board::world::{
    clock, cycle, event_log, peripherals, watchdog, SimCycle, SimPeripherals, World, WorldRef,
};

/// Timeout of the board's independent watchdog once running, µs
/// ([`fpc::tasks::WATCHDOG_TIMEOUT_US`]).
pub const WATCHDOG_TIMEOUT_US: u64 = fpc::tasks::WATCHDOG_TIMEOUT_US as u64;

/// Timeout of the board's watchdog from a boot to its first feed, µs
/// ([`fpc::tasks::BOOT_WATCHDOG_TIMEOUT_US`]).
pub const BOOT_WATCHDOG_TIMEOUT_US: u64 = fpc::tasks::BOOT_WATCHDOG_TIMEOUT_US as u64;

/// Time from a reset of the MCU to the firmware's first control cycle, µs: the runtime's
/// start at the 16 MHz reset clock (`.bss` zeroed 32 bytes per store, `.data` copied), the
/// clock tree, the board's bring-up and the calibration read, the control task's start and
/// its step built, up to its first cycle. Measured on the release ELF in the emulated
/// STM32G474 on its counted timeline (`fpc-pil fault hung-control` prints the boot's
/// milestones: 1.82 ms from power-on, 1.81 ms after a watchdog reset, to `ControlCycle`; the
/// first cycle waits for the next ADC burst, so the figure moves by up to a 50 µs period with
/// the boot's other times), rounded up; `fpc-pil`'s tests check the ELF boots within it, and the fault tests' after-reset
/// cases hold with half and one and a half times it, so no result rests on its exact figure.
/// No task runs and the outputs are off meanwhile, while the plant goes on: a simulator that
/// booted at once would brake a moving piston that much earlier than the board can. A run's
/// own start (t = 0) is the firmware's first cycle; only a reset within a run (the watchdog,
/// a power cut) costs it.
pub const BOOT_US: u64 = 1_850;

/// The board's execution beyond polling the tasks: overruns, hangs and the watchdog.
/// [`simulate_board`] hands it to the caller every period, so a fault scenario can change
/// it at any instant.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Execution {
    /// Timeout of the independent watchdog once it has been fed, µs; `None`: not running
    /// (the default, so a test body that never checks in is not reset). From a boot to the
    /// first feed the board's longer [`BOOT_WATCHDOG_TIMEOUT_US`] applies, as on the MCU.
    pub watchdog_timeout_us: Option<u64>,
    /// Periods the control task is still busy with its current step: it is not polled, it
    /// misses those cycle triggers and the outputs hold (an overrunning step).
    pub control_busy_periods: u32,
    /// The control task is never polled again (hung) until the next reset.
    pub control_hung: bool,
    /// The supervision task is never polled again (hung) until the next reset.
    pub supervision_hung: bool,
    /// Simulated time of every watchdog reset so far, µs.
    pub resets_us: Vec<u64>,
    /// The board's calibration flash, read by the firmware's store at every boot; `None`:
    /// the board has no store and the configuration is the calibration.
    pub flash: Option<SimFlash>,
    /// The supply is off until this time, µs: no task runs, the outputs are low; then the
    /// board boots from power-on.
    pub power_off_until_us: Option<u64>,
    /// The mains is off until this time, µs: the board runs on the DC link
    /// ([`crate::plant::supply`]) until its logic supply drops out, and is then off (as
    /// [`Execution::power_off_until_us`]) until the mains is back, which recharges the link.
    pub mains_off_until_us: Option<u64>,
    /// Simulated time of every boot after a power cut, µs.
    pub power_ups_us: Vec<u64>,
    /// The MCU is booting after a reset until this time, µs ([`BOOT_US`]): no task runs.
    pub booting_until_us: Option<u64>,
    /// Time from a reset to the first control cycle, µs; `None`: the board's [`BOOT_US`]
    /// (a run may bracket it, as the fault sweep's after-reset cases do).
    pub boot_us: Option<u64>,
    /// The firmware's command task runs too, on the RTT command channel in the board's RAM
    /// (answers and scope recordings on the reply channel). Off by default: a caller that
    /// posts commands to the shared state itself also takes the replies from it.
    pub command_task: bool,
    /// What the host asks of the link at each boot, before the tasks start (how the ports
    /// are, which channels the telemetry carries), as `fpc-sim link` would at once.
    pub at_boot: Vec<fpc::link::settings::LinkRequest>,
}

/// The shared state as the simulator instantiates it (single thread: no-op mutex).
pub type SimShared = Shared<NoopRawMutex>;

/// Every control-task port of `world`'s simulated board (one place, for each boot).
fn control_ports(world: &WorldRef) -> SimControlPorts {
    ControlPorts {
        cycle: cycle(world),
        encoders: peripherals(world),
        currents: peripherals(world),
        pwm: peripherals(world),
        quadrature: peripherals(world),
        servo: peripherals(world),
        pressures: peripherals(world),
    }
}

/// The firmware's boot read of its calibration store on `flash`, with its NMI handler for a
/// double ECC error ([`super::flash::boot_read`]); the flash comes back (a load may repair a
/// torn save, the NMI erase the store).
fn boot_load(flash: SimFlash) -> (Result<CalibrationRecord, LoadError>, SimFlash) {
    let (loaded, flash, _nmi_resets) = super::flash::boot_read(flash);
    (loaded, flash)
}

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
        |io, shared| control_run(io, shared, config, ResetCause::PowerOn, None),
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
    // The firmware sets up its RTT control block first thing at boot.
    world.borrow_mut().ram.boot_rtt();
    let io = control_ports(&world);
    {
        let mut control = pin!(control(io, shared));
        let mut supervision = pin!(supervision_run(
            clock(&world),
            clock(&world),
            watchdog(&world),
            event_log(&world),
            peripherals(&world),
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

impl Execution {
    /// Whether the MCU runs its tasks at `now_us`: supplied and not booting (a boot that has
    /// ended is forgotten).
    fn runs_at(&mut self, now_us: u64) -> bool {
        let powered = self.power_off_until_us.is_none();
        let booting = self.booting_until_us.is_some_and(|until| now_us < until);
        if !booting {
            self.booting_until_us = None;
        }
        powered && !booting
    }

    /// A mains outage: the supply restored when it ends, the board off for the rest of it
    /// once the DC link can no longer hold the logic supply.
    fn follow_mains(&mut self, w: &mut World) {
        if let Some(back) = self.mains_off_until_us {
            if w.time_us() >= back {
                self.mains_off_until_us = None;
                w.plant.supply.restore();
            } else if !w.plant.supply.logic_powered() && self.power_off_until_us.is_none() {
                // The link ran down: the board is off for the rest of the outage.
                self.power_off_until_us = Some(back);
            }
        }
    }

    /// A boot begins at `t_us` (µs): the MCU runs again after the boot time
    /// ([`Execution::boot_us`]), every task from its entry (no hang, no overrun carried over).
    fn boot_from(&mut self, t_us: u64) {
        self.booting_until_us = Some(t_us + self.boot_us.unwrap_or(BOOT_US));
        self.control_hung = false;
        self.supervision_hung = false;
        self.control_busy_periods = 0;
    }

    /// Whether the running watchdog was not fed within its window (the longer boot window
    /// until the first feed since a boot).
    fn starved(&self, w: &World) -> bool {
        self.watchdog_timeout_us.is_some_and(|timeout| {
            let window = if w.watchdog_fed_since_boot {
                timeout
            } else {
                timeout.max(BOOT_WATCHDOG_TIMEOUT_US)
            };
            w.time_us().saturating_sub(w.watchdog_fed_us) >= window
        })
    }
}

/// Runs the firmware's control, supervision and telemetry tasks on `world` as
/// [`simulate`] does, with the board's [`Execution`]: `each_cycle` may make the control
/// step overrun or a task hang, and when the watchdog is running and not fed for its timeout
/// the board resets.
///
/// A reset, as the MCU does it: the motor outputs go off and the servo command to zero at
/// once (the pins float, the gate drivers' pull-downs hold them low), the shared state is
/// lost, and every task starts again from its entry with [`ResetCause::Watchdog`] once the
/// MCU has booted ([`BOOT_US`]). The plant is not reset: the piston keeps whatever speed it
/// had. Returns the world and the execution at the end.
pub fn simulate_board<F>(
    world: World,
    config: ControlConfig,
    execution: Execution,
    mut each_cycle: F,
) -> (World, Execution)
where
    F: FnMut(&mut World, &SimShared, &mut Execution) -> ControlFlow<()>,
{
    let world: WorldRef = Rc::new(RefCell::new(world));
    let mut execution = execution;
    let mut cause = ResetCause::PowerOn;
    let mut cx = Context::from_waker(Waker::noop());
    'boot: loop {
        // RAM starts afresh at every boot: the shared state, and the RTT control block the
        // firmware sets up first thing (bytes in flight are lost).
        let shared = SimShared::new();
        world.borrow_mut().ram.boot_rtt();
        for request in &execution.at_boot {
            // A request the firmware refuses changes nothing, as over the link.
            let _ = shared.apply(*request);
        }
        let io = control_ports(&world);
        let stored = execution.flash.take().map(|flash| {
            let (loaded, flash) = boot_load(flash);
            execution.flash = Some(flash);
            loaded
        });
        let mut control = pin!(control_run(io, &shared, config.clone(), cause, stored));
        let mut supervision = pin!(supervision_run(
            clock(&world),
            clock(&world),
            watchdog(&world),
            event_log(&world),
            peripherals(&world),
            &shared
        ));
        let decimation = world.borrow().telemetry.decimation;
        let mut telemetry = pin!(telemetry_run(telemetry_sink(&world), &shared, decimation));
        let mut commands = pin!(command_run(
            command_channel(&world),
            up_channel(&world, UP_REPLIES),
            clock(&world),
            clock(&world),
            &shared
        ));
        loop {
            let now_us = world.borrow().time_us();
            let powered = execution.runs_at(now_us);
            if powered && !execution.control_hung {
                if execution.control_busy_periods == 0 {
                    let _ = control.as_mut().poll(&mut cx);
                } else {
                    execution.control_busy_periods -= 1;
                }
            }
            if powered {
                let _ = telemetry.as_mut().poll(&mut cx);
                if execution.command_task {
                    let _ = commands.as_mut().poll(&mut cx);
                }
            }
            if powered && !execution.supervision_hung {
                let _ = supervision.as_mut().poll(&mut cx);
            }
            let mut w = world.borrow_mut();
            if !powered {
                // No supply: the gate drivers' pull-downs hold every output low.
                w.outputs_reset();
            }
            if each_cycle(&mut w, &shared, &mut execution).is_break() {
                break 'boot;
            }
            execution.follow_mains(&mut w);
            if let Some(until) = execution.power_off_until_us {
                if w.time_us() >= until {
                    // Power is back: a cold boot (RAM lost, watchdog in its boot window,
                    // the flash as the cut left it).
                    execution.power_off_until_us = None;
                    execution.power_ups_us.push(w.time_us());
                    execution.boot_from(w.time_us());
                    if let Some(f) = execution.flash.as_mut() {
                        *f = f.reboot();
                    }
                    w.watchdog_fed_us = w.time_us();
                    w.watchdog_fed_since_boot = false;
                    cause = ResetCause::PowerOn;
                    w.advance();
                    continue 'boot;
                }
                // The watchdog is off with the MCU.
                w.watchdog_fed_us = w.time_us();
                w.advance();
                continue;
            }
            if execution.starved(&w) {
                w.outputs_reset();
                // Started again by the boot, in its boot window, as the firmware's init does.
                w.watchdog_fed_us = w.time_us();
                w.watchdog_fed_since_boot = false;
                execution.resets_us.push(w.time_us());
                execution.boot_from(w.time_us());
                cause = ResetCause::Watchdog;
                w.advance();
                continue 'boot;
            }
            w.advance();
        }
    }
    // The task futures, the only other holders, were dropped above, so this never clones.
    let world = Rc::try_unwrap(world).map_or_else(|rc| rc.borrow().clone(), RefCell::into_inner);
    (world, execution)
}

/// A task body as [`LinkedBoard`] holds it.
type Task<'s> = Pin<Box<dyn Future<Output = Infallible> + 's>>;

/// The simulated board run one control period at a time, with all four of the firmware's
/// tasks — control, supervision, telemetry and commands — for a host that reaches it only
/// the way a probe reaches the real board: through the RTT channels in its RAM
/// (`link::rtt`). No watchdog resets or power cuts here ([`simulate_board`] has
/// them); the caller may change the plant between periods (what the rig's operator does:
/// close a bypass, blank the ports).
pub struct LinkedBoard<'s> {
    world: WorldRef,
    tasks: [Task<'s>; 4],
}

impl<'s> LinkedBoard<'s> {
    /// Boots the firmware on `world` from power-on: its RTT control block set up, then the
    /// tasks started with `config` and telemetry at `decimation`, sharing `shared`.
    pub fn boot(
        world: World,
        config: ControlConfig,
        shared: &'s SimShared,
        decimation: u16,
    ) -> LinkedBoard<'s> {
        let world: WorldRef = Rc::new(RefCell::new(world));
        world.borrow_mut().ram.boot_rtt();
        let io = control_ports(&world);
        let tasks: [Task<'s>; 4] = [
            Box::pin(control_run(io, shared, config, ResetCause::PowerOn, None)),
            Box::pin(supervision_run(
                clock(&world),
                clock(&world),
                watchdog(&world),
                event_log(&world),
                peripherals(&world),
                shared,
            )),
            Box::pin(telemetry_run(telemetry_sink(&world), shared, decimation)),
            Box::pin(command_run(
                command_channel(&world),
                up_channel(&world, UP_REPLIES),
                clock(&world),
                clock(&world),
                shared,
            )),
        ];
        LinkedBoard { world, tasks }
    }

    /// One control period: every task runs until it waits on the hardware, then the plant
    /// advances.
    pub fn step(&mut self) {
        let mut cx = Context::from_waker(Waker::noop());
        for task in &mut self.tasks {
            let _ = task.as_mut().poll(&mut cx);
        }
        self.world.borrow_mut().advance();
    }

    /// The board and its plant, between periods.
    pub fn world(&self) -> std::cell::RefMut<'_, World> {
        self.world.borrow_mut()
    }
}
