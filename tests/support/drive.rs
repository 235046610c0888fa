//! The drive tests' bench: the firmware's control step on the simulated board, stepped one
//! control period at a time, with the step itself in reach (its configuration and its
//! calibration record), as `fpc::tasks::control_run` runs it: read the burst, step, write
//! both sections' duties in the same cycle (or switch the outputs off), write the servo.

use std::cell::{Ref, RefMut};
use std::rc::Rc;

use fpc::control::calibration::{Calibrated, Routine};
use fpc::control::command::{Command, Refusal};
use fpc::control::config::ControlConfig;
use fpc::control::step::{ControlStep, CycleInputs};
use fpc::ports::{
    CurrentInput, EncoderInput, PressureInput, PwmOutput, QuadratureInput, TorqueOutput,
};
use fpc::status::{ModeKind, Status};
use fpc::units::{PerSection, Section};
use hal_sim::board::world::{peripherals, SimPeripherals, World, WorldRef};
use hal_sim::plant::chambers::PortMode;
use hal_sim::plant::model::MachineModel;

/// The firmware's step on a simulated board.
pub struct Bench {
    world: WorldRef,
    io: SimPeripherals,
    /// The control step under test.
    pub step: ControlStep,
    enabled: bool,
}

impl Bench {
    /// The board of `model` (chambers unloaded, as `fpc-sim run` starts) with the piston at
    /// `start_m`, controlled with `config`.
    pub fn new(model: &MachineModel, config: ControlConfig, seed: u64, start_m: f64) -> Self {
        let world = Rc::new(std::cell::RefCell::new(hal_sim::run::world(
            model, seed, 0, start_m,
        )));
        let io = peripherals(&world);
        Bench {
            world,
            io,
            step: ControlStep::new(config).expect("valid configuration"),
            enabled: false,
        }
    }

    /// The simulated board.
    pub fn world(&self) -> Ref<'_, World> {
        self.world.borrow()
    }

    /// The simulated board, to change the plant.
    pub fn world_mut(&self) -> RefMut<'_, World> {
        self.world.borrow_mut()
    }

    /// The status of the last step.
    pub fn status(&self) -> Status {
        self.step.status()
    }

    /// Simulated time, s.
    pub fn time_s(&self) -> f64 {
        self.world.borrow().time_s()
    }

    /// Sends a command (taken before the next step, as from the RTT channel).
    pub fn command(&mut self, command: Command) -> Result<(), Refusal> {
        self.step.command(command)
    }

    /// One control period: sample, step, write, advance the plant.
    pub fn cycle(&mut self) {
        let t = self.world.borrow().ticks();
        let io = &mut self.io;
        let inputs = CycleInputs {
            t,
            encoders: EncoderInput::read(io),
            currents: PerSection {
                master: CurrentInput::read(io, Section::Master),
                slave: CurrentInput::read(io, Section::Slave),
            },
            quadrature: QuadratureInput::count(io),
            pressures: PressureInput::read(io),
        };
        let out = self.step.step(&inputs);
        match out.pwm {
            Some(d) => {
                PwmOutput::write(io, Section::Master, d.master);
                PwmOutput::write(io, Section::Slave, d.slave);
                // Idempotent on the simulated board: the sections in service every cycle.
                PwmOutput::enable(io, out.sections);
                self.enabled = true;
            }
            None => {
                if self.enabled {
                    PwmOutput::disable(io);
                    self.enabled = false;
                }
            }
        }
        TorqueOutput::write(io, out.servo);
        self.world.borrow_mut().advance();
    }

    /// Steps until `done` says so (true) or `limit_s` of simulated time pass (false).
    pub fn run_until(
        &mut self,
        limit_s: f64,
        mut done: impl FnMut(&World, &Status) -> bool,
    ) -> bool {
        let end = self.time_s() + limit_s;
        while self.time_s() < end {
            self.cycle();
            if done(&self.world.borrow(), &self.step.status()) {
                return true;
            }
        }
        false
    }

    /// Steps for `duration_s`, calling `each` after every cycle.
    pub fn run_for(&mut self, duration_s: f64, mut each: impl FnMut(&World, &Status)) {
        let end = self.time_s() + duration_s;
        while self.time_s() < end {
            self.cycle();
            each(&self.world.borrow(), &self.step.status());
        }
    }

    /// Sends `command` and steps until the machine is back in `mode` (or `limit_s`).
    pub fn run_command(&mut self, command: Command, mode: ModeKind, limit_s: f64) {
        self.command(command)
            .unwrap_or_else(|r| panic!("{command:?} refused: {}", r.reason()));
        // The command takes effect at the next step: leave the starting mode first.
        self.cycle();
        let ok = self.run_until(limit_s, |_, s| s.mode == mode || !s.faults.is_empty());
        let s = self.status();
        assert!(
            ok && s.faults.is_empty(),
            "{command:?}: mode {} after {limit_s} s, faults {:?}",
            s.mode.name(),
            s.faults.iter().map(|f| f.name()).collect::<Vec<_>>()
        );
    }

    /// Homes the axis (it then parks and holds).
    pub fn home(&mut self) {
        self.run_command(Command::Home, ModeKind::Holding, 30.0);
        assert!(self.status().homed);
    }

    /// From holding: closes the start-up bypass, sets the line pressure ratio, strokes at
    /// `speed_mps` and calls `each` on every cycle of the `strokes` half cycles after the
    /// first two (the first stroke starts from rest); then stops and holds.
    pub fn strokes(
        &mut self,
        pressure_ratio: f64,
        speed_mps: f32,
        strokes: u32,
        mut each: impl FnMut(&World, &Status),
    ) {
        {
            let mut w = self.world_mut();
            w.plant.port_mode = PortMode::Timed;
            w.plant.lines.set_pressure_ratio(pressure_ratio);
        }
        self.command(Command::Start {
            peak_speed_mps: speed_mps,
        })
        .expect("start accepted");
        let mut dead_points = 0u32;
        let mut last_dead = self.step.last_dead_point();
        let limit = self.time_s() + 2.0 + f64::from(strokes);
        while dead_points < strokes + 2 && self.time_s() < limit {
            self.cycle();
            let dead = self.step.last_dead_point();
            if dead != last_dead {
                dead_points += 1;
                last_dead = dead;
            }
            let s = self.status();
            assert!(
                s.faults.is_empty(),
                "fault while stroking: {:?}",
                s.faults.first()
            );
            if dead_points >= 2 && dead_points < strokes + 2 {
                each(&self.world.borrow(), &s);
            }
        }
        assert_eq!(dead_points, strokes + 2, "strokes did not complete");
        self.command(Command::Stop).expect("stop accepted");
        let held = self.run_until(3.0, |_, s| s.mode == ModeKind::Holding);
        assert!(held, "no hold after the stop");
        self.world_mut().plant.lines.set_pressure_ratio(1.0);
    }
}

/// The controller's configuration for `model` before any calibration: the firmware's
/// reference with the model's machine parameters, but nothing the calibration would find
/// (no cogging map, angle and current-sense offsets at zero).
pub fn uncalibrated_config(model: &MachineModel) -> ControlConfig {
    let mut c = hal_sim::run::control_config(model);
    c.allocation.cogging = fpc::physics::cogging::HarmonicMap::none();
    c
}

/// The pitch harmonic (fundamental at `period_m`) of `samples` (position, value): its
/// amplitude, by least squares on sin, cos and a constant (exact for any spread of samples).
pub fn pitch_harmonic(samples: &[(f64, f64)], period_m: f64) -> f64 {
    // Normal equations of y ≈ a·sin + b·cos + c.
    let mut m = [[0.0f64; 3]; 3];
    let mut r = [0.0f64; 3];
    for &(x, y) in samples {
        let th = std::f64::consts::TAU * x / period_m;
        let basis = [th.sin(), th.cos(), 1.0];
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += basis[i] * basis[j];
            }
            r[i] += basis[i] * y;
        }
    }
    let [a, b, _] = solve3(m, r);
    a.hypot(b)
}

/// Solves a 3×3 linear system by Cramer's rule.
fn solve3(m: [[f64; 3]; 3], r: [f64; 3]) -> [f64; 3] {
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(&m);
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let mut mk = m;
        for i in 0..3 {
            mk[i][k] = r[i];
        }
        *o = det(&mk) / d;
    }
    out
}

/// Misalignment of the slave section's magnets in the plant with unknowns, m (22.5°
/// electrical).
pub const MISALIGNMENT_M: f64 = 1.5e-3;
/// Phase-current sensor offsets of the plant with unknowns, A (master a, b, c; slave a, b, c).
pub const CURRENT_OFFSETS_A: [[f64; 3]; 2] = [[0.8, -0.5, 0.3], [-0.6, 0.0, 0.9]];
/// Cogging of the plant with unknowns: 30 N at the pitch, phase 0.9 rad (the reference
/// machine's amplitude; the phase is what no drawing gives).
pub const COGGING_PHASE_RAD: f64 = 0.9;

/// The reference machine with what the calibration must find set to values the firmware
/// does not know: the slave's magnets 1.5 mm off (its electrical angle offset −22.5°), an
/// offset on five of the six phase-current sensors (with 0.1 A of noise), the cogging's
/// phase.
pub fn machine_with_unknowns() -> MachineModel {
    let mut m = MachineModel::reference();
    m.effects.section_misalignment = Some(hal_sim::plant::model::MisalignmentEffect {
        offset_m: MISALIGNMENT_M,
    });
    m.sensors.current.offset_master_a = CURRENT_OFFSETS_A[0];
    m.sensors.current.offset_slave_a = CURRENT_OFFSETS_A[1];
    m.sensors.current.noise_a = 0.1;
    if let Some(c) = m.effects.cogging.as_mut() {
        c.phase_rad = COGGING_PHASE_RAD;
    }
    m
}

/// Runs a calibration routine to its end and returns what it loaded.
pub fn calibrate(bench: &mut Bench, routine: Routine) -> Calibrated {
    let back = if bench.status().homed {
        ModeKind::Holding
    } else {
        ModeKind::Idle
    };
    let t0 = bench.time_s();
    bench.run_command(Command::Calibrate { routine }, back, 30.0);
    let record = *bench.step.calibrated();
    println!(
        "  {} took {:.2} s of machine time",
        routine.name(),
        bench.time_s() - t0
    );
    assert_eq!(record.last_error, None, "{} failed", routine.name());
    record
}

/// Commissions a machine: current-sense offsets, alignment, homing, misalignment, cogging.
/// Returns the bench (homed, holding) and what the calibration loaded.
pub fn commission(model: &MachineModel, seed: u64) -> (Bench, Calibrated) {
    let mut bench = Bench::new(model, uncalibrated_config(model), seed, 0.05);
    calibrate(&mut bench, Routine::CurrentSense);
    calibrate(&mut bench, Routine::Alignment);
    bench.home();
    calibrate(&mut bench, Routine::Misalignment);
    let record = calibrate(&mut bench, Routine::Cogging);
    (bench, record)
}

/// Electrical angle as a wrapping fraction of a period → degrees in (−180, 180].
pub fn degrees(angle: u32) -> f64 {
    f64::from(angle as i32) / 4_294_967_296.0 * 360.0
}

/// How long the piston has been at rest (|v| < 1 mm/s), s: `at_rest_s` advanced by one
/// control period, or zero while it moves.
pub fn at_rest_for(at_rest_s: &mut f64, v_mps: f64) -> f64 {
    *at_rest_s = if v_mps.abs() < 1e-3 {
        *at_rest_s + 50e-6
    } else {
        0.0
    };
    *at_rest_s
}
