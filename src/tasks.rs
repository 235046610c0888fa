//! The task bodies, generic over the ports: the firmware wraps each in a concrete embassy
//! task, and `hal-sim` runs the very same futures against the simulated plant.

use core::convert::Infallible;

use embassy_sync::blocking_mutex::raw::RawMutex;

use crate::controller::{ControlConfig, ControlStep, CycleInputs};
use crate::ports::{
    Clock, ControlPorts, CurrentInput, CycleTrigger, EncoderInput, PressureInput, PwmOutput,
    QuadratureInput, Sleep, TorqueOutput, Watchdog,
};
use crate::shared::{task_bits, Reply, Shared};
use crate::units::{DacCode, PerSection, Section};

/// Period of the supervision task, µs.
pub const SUPERVISION_PERIOD_US: u32 = 1000;

/// The 20 kHz control task: wait for the sampling burst, read every port, run one
/// [`ControlStep`], write both sections' PWM and the servo command, publish the status.
///
/// An invalid configuration keeps the outputs off for good (and keeps checking in, so the
/// watchdog does not reset the board into the same configuration).
pub async fn control_run<M, T, E, C, P, Q, S, R>(
    mut ports: ControlPorts<T, E, C, P, Q, S, R>,
    shared: &Shared<M>,
    config: ControlConfig,
) -> Infallible
where
    M: RawMutex,
    T: CycleTrigger,
    E: EncoderInput,
    C: CurrentInput,
    P: PwmOutput,
    Q: QuadratureInput,
    S: TorqueOutput,
    R: PressureInput,
{
    ports.pwm.disable();
    ports.servo.write(DacCode::MID);
    let mut step = match ControlStep::new(config) {
        Ok(step) => step,
        Err(_) => loop {
            ports.cycle.next_cycle().await;
            shared.check_in(task_bits::CONTROL);
        },
    };
    let mut enabled = false;
    loop {
        let t = ports.cycle.next_cycle().await;
        while let Some(command) = shared.take_command() {
            let result = step.command(command);
            shared.post_reply(Reply { command, result });
        }
        let inputs = CycleInputs {
            t,
            encoders: ports.encoders.read(),
            currents: PerSection {
                master: ports.currents.read(Section::Master),
                slave: ports.currents.read(Section::Slave),
            },
            quadrature: ports.quadrature.count(),
            pressures: ports.pressures.read(),
        };
        let out = step.step(&inputs);
        match out.pwm {
            Some(duties) => {
                // Both sections in the same cycle, from the same force command.
                ports.pwm.write(Section::Master, duties.master);
                ports.pwm.write(Section::Slave, duties.slave);
                if !enabled {
                    ports.pwm.enable();
                    enabled = true;
                }
            }
            None => {
                if enabled {
                    ports.pwm.disable();
                    enabled = false;
                }
            }
        }
        ports.servo.write(out.servo);
        shared.publish(*step.status());
        shared.check_in(task_bits::CONTROL);
    }
}

/// The supervision task (thread mode, 1 kHz): feeds the independent watchdog only when
/// every task has checked in since the last feed, so a hung task resets the board.
pub async fn supervision_run<M, L, K, W>(
    mut sleep: L,
    clock: K,
    mut watchdog: W,
    shared: &Shared<M>,
) -> Infallible
where
    M: RawMutex,
    L: Sleep,
    K: Clock,
    W: Watchdog,
{
    let mut next = clock.now();
    loop {
        next = next.add_us(SUPERVISION_PERIOD_US);
        sleep.until(next).await;
        if shared.take_checkins(task_bits::ALL) {
            watchdog.feed();
        }
    }
}
