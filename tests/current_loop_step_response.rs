//! The firmware's current loop, on the simulated motor: a locked mover (as on a test bench),
//! a q-current step, and the figures the drive issue asks for — rise time, overshoot, no
//! limit cycle, and steady-state force tracking across the linear range.

use std::cell::RefCell;
use std::ops::ControlFlow;

use fpc::control::config::ControlConfig;
use fpc::drive::foc::CurrentController;
use fpc::physics::motor::Dq;
use fpc::ports::{CurrentInput, CycleTrigger, EncoderInput, PwmOutput};
use fpc::sensing::encoder::SinCosDecoder;
use fpc::units::{Duty, PerSection, Section};
use hal_sim::board::exec::{simulate_with, SimControlPorts, SimShared};
use hal_sim::plant::model::MachineModel;
use hal_sim::run::world;

const STEP_AT_S: f64 = 1e-3;

/// Runs a q-current step of `amps` on the master section with the mover locked at 0.1 m;
/// returns the true q current of every cycle.
fn step_response(amps: f32, duration_s: f64) -> Vec<(f64, f64)> {
    let model = MachineModel::reference();
    let config = ControlConfig::reference();
    let trace = RefCell::new(Vec::new());
    let shared = SimShared::new();
    let body = |mut io: SimControlPorts, _: &SimShared| {
        let config = config.clone();
        async move {
            let mut cc =
                CurrentController::new(&config.motor, config.current_gains, config.sample_time_s);
            let mut enc = SinCosDecoder::new(config.encoder_master);
            let mut t_s = 0.0f64;
            loop {
                io.cycle.next_cycle().await;
                let angle = enc
                    .update(EncoderInput::read(&mut io.encoders).master)
                    .angle;
                let current = config
                    .current_sense
                    .master
                    .amps(&CurrentInput::read(&mut io.currents, Section::Master));
                let q = if t_s >= STEP_AT_S { amps } else { 0.0 };
                let duties = cc.step(current, angle, Dq { d: 0.0, q }, 0.0);
                io.pwm.write(Section::Master, duties);
                io.pwm.write(Section::Slave, [Duty::HALF; 3]);
                io.pwm.enable(PerSection {
                    master: true,
                    slave: true,
                });
                t_s += f64::from(config.sample_time_s);
            }
        }
    };
    simulate_with(world(&model, 3, 0, 0.1), &shared, body, |w, _| {
        // Locked mover: the bench clamps the slider.
        w.plant.x_m = 0.1;
        w.plant.v_mps = 0.0;
        trace
            .borrow_mut()
            .push((w.time_s(), w.plant.current.master.q));
        if w.time_s() >= duration_s {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    trace.into_inner()
}

#[test]
fn current_step_rises_fast_without_overshoot_or_limit_cycle() {
    let target = 10.0;
    let trace = step_response(target as f32, 6e-3);
    let after: Vec<(f64, f64)> = trace
        .iter()
        .copied()
        .filter(|(t, _)| *t >= STEP_AT_S)
        .collect();
    let cross = |level: f64| {
        after
            .iter()
            .find(|(_, i)| *i >= level * target)
            .map(|(t, _)| *t)
    };
    let rise_s = cross(0.9).zip(cross(0.1)).map(|(a, b)| a - b);
    let peak = after.iter().map(|(_, i)| *i).fold(f64::MIN, f64::max);
    let overshoot = (peak - target) / target;
    let tail: Vec<f64> = after
        .iter()
        .filter(|(t, _)| *t > 4e-3)
        .map(|(_, i)| *i)
        .collect();
    let ripple = tail.iter().copied().fold(f64::MIN, f64::max)
        - tail.iter().copied().fold(f64::MAX, f64::min);
    let final_error = (tail.last().copied().unwrap_or(0.0) - target).abs() / target;
    println!(
        "current step {target} A: rise 10–90 % {:.3} ms, overshoot {:.1} %, ripple in the last 2 ms {:.4} A, final error {:.2} %",
        rise_s.unwrap_or(f64::NAN) * 1e3,
        overshoot * 100.0,
        ripple,
        final_error * 100.0
    );
    assert!(rise_s.is_some_and(|r| r <= 0.3e-3), "rise time {rise_s:?}");
    assert!(overshoot <= 0.10, "overshoot {overshoot}");
    assert!(ripple < 0.01 * target, "limit cycle: ripple {ripple} A");
    assert!(final_error < 0.01);
}

#[test]
fn force_tracks_the_command_across_the_linear_range() {
    let kf = f64::from(ControlConfig::reference().motor.force_constant_n_per_a);
    for amps in [2.0f32, 10.0, 30.0, 60.0] {
        let trace = step_response(amps, 10e-3);
        let iq = trace.last().map_or(0.0, |(_, i)| *i);
        let err = (iq - f64::from(amps)).abs() / f64::from(amps);
        println!(
            "force command {:.0} N → delivered {:.1} N ({:.2} %)",
            kf * f64::from(amps),
            kf * iq,
            err * 100.0
        );
        assert!(err <= 0.02, "at {amps} A: {iq} A");
    }
}
