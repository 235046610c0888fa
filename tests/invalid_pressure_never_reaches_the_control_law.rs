//! Invalid pressure samples never reach the control law (`docs/faults.md` scenario 5): on the
//! simulated machine in mid-move, the control step given any pair of chamber codes with an
//! open or shorted one — the whole u16 range — commands exactly what it commands with no gas
//! force at all; and an open sensor latches `pressure_sensor` within 3 samples.

mod support;

use std::cell::RefCell;
use std::ops::ControlFlow;

use fpc::control::command::Command;
use fpc::control::config::ControlConfig;
use fpc::control::step::{ControlStep, CycleInputs, CycleOutputs};
use fpc::ports::{
    CurrentInput, CycleTrigger, EncoderInput, PressureInput, PwmOutput, QuadratureInput,
    TorqueOutput,
};
use fpc::safety::faults::Fault;
use fpc::status::ModeKind;
use fpc::units::{AdcCode, PerSection, Section};
use hal_sim::board::exec::{simulate_with, SimControlPorts, SimShared};
use hal_sim::plant::model::MachineModel;
use hal_sim::run::{control_config, world};
use support::sensing::Rng;

/// What the probe found.
#[derive(Debug, Default)]
struct Probe {
    /// Code pairs with an invalid code tried in mid-move.
    pairs: usize,
    /// Pairs whose outputs differed from the no-gas-force outputs.
    leaks: Vec<(u16, u16)>,
    /// Samples from the first open-circuit sample to the latched fault.
    latched_after: Option<usize>,
}

fn outputs_without_gas_force(
    step: &ControlStep,
    inputs: &CycleInputs,
    code: AdcCode,
) -> (CycleOutputs, f32) {
    let mut s = step.clone();
    let mut i = *inputs;
    i.pressures.chamber_a = code;
    i.pressures.chamber_b = code;
    let out = s.step(&i);
    (out, s.status().force_command_n)
}

/// The control step in the loop as `tasks::control_run` runs it, with a probe before each
/// step 10 ms into the move and an open chamber-A sensor from 20 ms on.
async fn control_with_probe(
    mut io: SimControlPorts,
    shared: &SimShared,
    config: ControlConfig,
    probe: &RefCell<Probe>,
) {
    let cal = config.pressure;
    let mut step = ControlStep::new(config).expect("reference config");
    let mut rng = Rng::new(17);
    let mut moving_cycles = 0usize;
    loop {
        let t = io.cycle.next_cycle().await;
        while let Some(command) = shared.take_command() {
            let _ = step.command(command);
        }
        let mut inputs = CycleInputs {
            t,
            encoders: EncoderInput::read(&mut io.encoders),
            currents: PerSection {
                master: CurrentInput::read(&mut io.currents, Section::Master),
                slave: CurrentInput::read(&mut io.currents, Section::Slave),
            },
            quadrature: QuadratureInput::count(&mut io.quadrature),
            pressures: PressureInput::read(&mut io.pressures),
        };
        if step.status().mode == ModeKind::Moving {
            moving_cycles += 1;
        }
        if moving_cycles == 200 {
            let mut p = probe.borrow_mut();
            let bar = cal.code_for(1.0e5);
            let (want, want_force) = outputs_without_gas_force(&step, &inputs, bar);
            let special = [0u16, 1, 204, 205, 2000, 3890, 3891, 4095, 4096, u16::MAX];
            let mut pairs: Vec<(u16, u16)> = special
                .iter()
                .flat_map(|&a| special.iter().map(move |&b| (a, b)))
                .collect();
            pairs
                .extend((0..2000).map(|_| (rng.next_u64() as u16, (rng.next_u64() % 4096) as u16)));
            for (a, b) in pairs {
                let (ca, cb) = (cal.convert(AdcCode(a)), cal.convert(AdcCode(b)));
                if ca.valid().is_some() && cb.valid().is_some() {
                    continue;
                }
                for (x, y) in [(a, b), (b, a)] {
                    let mut s = step.clone();
                    let mut i = inputs;
                    i.pressures.chamber_a = AdcCode(x);
                    i.pressures.chamber_b = AdcCode(y);
                    let out = s.step(&i);
                    p.pairs += 1;
                    if out.pwm != want.pwm || s.status().force_command_n != want_force {
                        p.leaks.push((x, y));
                    }
                }
            }
        }
        if moving_cycles >= 400 {
            // Open circuit on chamber A from here on.
            inputs.pressures.chamber_a = AdcCode(0);
        }
        let out = step.step(&inputs);
        let mut p = probe.borrow_mut();
        if moving_cycles >= 400
            && p.latched_after.is_none()
            && step.status().faults.contains(Fault::PressureSensor)
        {
            p.latched_after = Some(moving_cycles - 399);
        }
        drop(p);
        match out.pwm {
            Some(d) => {
                PwmOutput::write(&mut io.pwm, Section::Master, d.master);
                PwmOutput::write(&mut io.pwm, Section::Slave, d.slave);
                io.pwm.enable(out.sections);
            }
            None => io.pwm.disable(),
        }
        TorqueOutput::write(&mut io.servo, out.servo);
        shared.publish(step.status());
    }
}

#[test]
fn invalid_pressure_codes_never_change_the_command() {
    let model = MachineModel::reference();
    let config: ControlConfig = control_config(&model);
    let probe = RefCell::new(Probe::default());
    let shared = SimShared::new();
    let body = |io, shared| control_with_probe(io, shared, config.clone(), &probe);
    simulate_with(world(&model, 5, 0, 0.005), &shared, body, |w, shared| {
        let status = shared.status();
        if w.cycle() == 0 {
            let _ = shared.post_command(Command::Home);
        }
        if status.homed && status.mode == ModeKind::Holding && probe.borrow().pairs == 0 {
            let _ = shared.post_command(Command::MoveTo {
                position_m: 0.15,
                peak_speed_mps: 2.0,
            });
        }
        if probe.borrow().latched_after.is_some() || w.time_s() > 3.0 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    let p = probe.into_inner();
    println!(
        "{} invalid chamber-code pairs tried in mid-move: {} changed the command; open sensor \
         latched after {:?} samples",
        p.pairs,
        p.leaks.len(),
        p.latched_after
    );
    assert!(p.pairs > 2000, "the probe did not run");
    assert!(
        p.leaks.is_empty(),
        "{:?}",
        &p.leaks[..p.leaks.len().min(10)]
    );
    assert!(
        p.latched_after.is_some_and(|k| k <= 3),
        "{:?}",
        p.latched_after
    );
}
