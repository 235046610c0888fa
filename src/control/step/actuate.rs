//! The drive stage: the position loop with model feed-forward, the force split over the
//! sections in service, both sections' current loops in the same cycle — or, with no
//! setpoint, the outputs off (the current loops reset, the phase currents watched for an
//! offset).

use super::estimate::LoadObserver;
use super::sense::Sensed;
use crate::control::calibration::SenseMonitor;
use crate::control::config::ControlConfig;
use crate::drive::allocation::{allocate_split, Split};
use crate::drive::foc::CurrentController;
use crate::motion::trajectory::Setpoint;
use crate::physics::balance::PistonForces;
use crate::physics::motor::Dq;
use crate::ports::PhaseCurrentCodes;
use crate::real::clamp_or_zero_f32;
use crate::safety::supervisor::LimitFlags;
use crate::sensing::differentiator::Derivatives;
use crate::units::{PerSection, PhaseDuties, Section};

/// The drive's state: the running strokes' load observer, the position loop's gains, both
/// sections' current loops and the current-sense monitor.
#[derive(Clone, Debug)]
#[repr(C)]
pub(super) struct Drive {
    pub load: LoadObserver,
    /// Position-loop stiffness, N/m, and damping, N·s/m (the configuration's until a host
    /// sets others).
    pub kp_n_per_m: f32,
    pub kd_ns_per_m: f32,
    /// q-current per newton of a section's share, 1/K_f, A/N (the motor's force constant
    /// is fixed: taken at construction, not divided out every cycle).
    amps_per_newton: f32,
    pub currents: PerSection<CurrentController>,
    /// The phase currents while the outputs are off (current-sense offset detection).
    pub sense_monitor: SenseMonitor,
}

/// What the drive did in one cycle with the outputs on.
#[derive(Clone, Copy, Debug)]
pub(super) struct Actuation {
    /// Both sections' duties (always `Some`: the form the step's outputs carry them in, built
    /// where they are made).
    pub duties: Option<PerSection<PhaseDuties>>,
    /// The total force commanded, N.
    pub force_n: f32,
    /// The force commanded to each section, N.
    pub shares: PerSection<f32>,
    /// The limits the force and the current loops hit.
    pub limits: LimitFlags,
}

/// The forces the model knows besides the motors' and inertia: friction at the reference
/// velocity and the measured gas force (their load, [`PistonForces::load_n`], is what the
/// motor must supply beyond `m·a`).
#[inline(always)]
pub(super) fn model_forces(
    c: &ControlConfig,
    sp: &Setpoint,
    gas_force_n: f32,
) -> PistonForces<f32> {
    PistonForces::known(0.0, gas_force_n, c.friction.force_n(sp.velocity_mps))
}

impl Drive {
    pub(super) fn new(config: &ControlConfig) -> Self {
        let current =
            || CurrentController::new(&config.motor, config.current_gains, config.sample_time_s);
        Drive {
            load: LoadObserver::new(config),
            kp_n_per_m: config.position_kp_n_per_m,
            kd_ns_per_m: config.position_kd_ns_per_m,
            amps_per_newton: 1.0 / config.motor.force_constant_n_per_a,
            currents: PerSection {
                master: current(),
                slave: current(),
            },
            sense_monitor: SenseMonitor::new(),
        }
    }

    /// Each section's largest phase-current magnitude of the last cycle, A.
    #[inline(always)]
    pub(super) fn peak_phase_a(&self) -> PerSection<f32> {
        PerSection {
            master: self.currents.master.state().peak_phase_a,
            slave: self.currents.slave.state().peak_phase_a,
        }
    }

    /// The drive stage with the outputs on: the position loop's force toward `sp` (within
    /// `limit`, N) with the load observer's estimate cancelled while `running` strokes,
    /// split over the sections in service by `split`, and both current loops run
    /// on the phase currents `codes`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn actuate(
        &mut self,
        c: &ControlConfig,
        codes: &PerSection<PhaseCurrentCodes>,
        s: &Sensed,
        sp: &Setpoint,
        limit: f32,
        split: &Split,
        running: bool,
    ) -> Actuation {
        let model = model_forces(c, sp, s.gas_force_n);
        // Observed and cancelled while running strokes only: homing pushes on its end stop
        // on purpose, a controlled stop has its own observer, and holding and moves keep the
        // behaviour they were tuned with. Outside them the observer waits reset, and starts
        // again with the first running cycle (the wait before the first stroke).
        let cancel_n = if running {
            self.load.observe(s, &model, limit)
        } else {
            self.load.reset();
            0.0
        };
        let force_n =
            self.position_loop(c, sp, s.position_m, &s.derivatives, &model, cancel_n, limit);
        let force_limited = force_n.abs() >= limit;
        let shares = allocate_split(&c.allocation.cogging, split, force_n, s.position_m);
        let inv_kf = self.amps_per_newton;
        let frame = |section: Section, angle: u32| {
            let reference = Dq {
                d: 0.0,
                q: *shares.get(section) * inv_kf,
            };
            (angle.wrapping_add(*c.angle_offset.get(section)), reference)
        };
        let frames = PerSection {
            master: frame(Section::Master, s.master.angle),
            slave: frame(Section::Slave, s.slave.angle),
        };
        let duties = self.drive_sections(c, codes, frames, s.derivatives.velocity_mps);
        Actuation {
            duties,
            force_n,
            shares,
            limits: LimitFlags {
                force: force_limited,
                voltage: self.voltage_limited(),
                envelope: false,
            },
        }
    }

    /// Whether a current loop hit its voltage limit in the last step.
    #[inline(always)]
    pub(super) fn voltage_limited(&self) -> bool {
        self.currents.master.state().voltage_limited || self.currents.slave.state().voltage_limited
    }

    /// Position loop with model feed-forward (the motor force the force balance needs for the
    /// setpoint's acceleration against `model`, the forces of [`model_forces`]) and
    /// `cancel_n`, an estimated external force (toward +x) to push against: total motor
    /// force, N, saturated at `limit`. Always inlined: the calibration calls it too, and a
    /// second call site must not take it out of the step.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn position_loop(
        &self,
        c: &ControlConfig,
        sp: &Setpoint,
        position_m: f32,
        d: &Derivatives,
        model: &PistonForces<f32>,
        cancel_n: f32,
        limit: f32,
    ) -> f32 {
        let feed_forward = if c.feed_forward {
            model.motor_needed_n(c.moving_mass_kg, sp.acceleration_mps2)
        } else {
            0.0
        };
        let feedback = self.kp_n_per_m * (sp.position_m - position_m)
            + self.kd_ns_per_m * (sp.velocity_mps - d.velocity_mps);
        let f = feed_forward + feedback - cancel_n;
        clamp_or_zero_f32(f, -limit, limit)
    }

    /// Both sections' current loops in this cycle: each in its `frames` (the electrical
    /// angle it commutates on and its d/q current reference, A) on its phase currents
    /// `codes`, at the piston's `velocity_mps` (back-EMF feed-forward). The duties come as the
    /// step's outputs carry them (`Some`), written once where the caller keeps them.
    ///
    /// Out of line, with both current loops inlined in it: the loops then have the
    /// registers to themselves (inlined in the step, they would spill its values; called
    /// out of line each, they pay a call apiece).
    #[inline(never)]
    pub(super) fn drive_sections(
        &mut self,
        c: &ControlConfig,
        codes: &PerSection<PhaseCurrentCodes>,
        frames: PerSection<(u32, Dq<f32>)>,
        velocity_mps: f32,
    ) -> Option<PerSection<PhaseDuties>> {
        // Written out per section, not looped: a loop over the sections keeps the current
        // loop's body once and indexes every field by section.
        let (currents, sense) = (&mut self.currents, &c.current_sense);
        let ((angle_m, reference_m), (angle_s, reference_s)) = (frames.master, frames.slave);
        let master = currents.master.step(
            sense.master.amps(&codes.master),
            angle_m,
            reference_m,
            velocity_mps,
        );
        let slave = currents.slave.step(
            sense.slave.amps(&codes.slave),
            angle_s,
            reference_s,
            velocity_mps,
        );
        Some(PerSection { master, slave })
    }

    /// The outputs with no setpoint (not calibrating): off — the current loops and the load
    /// observer reset, the phase currents `codes` watched for an offset — except while the
    /// blind brake short-circuits the windings (`shorted`: equal duties, zero voltage on
    /// every phase).
    #[cold]
    #[inline(never)]
    pub(super) fn outputs_off(
        &mut self,
        codes: &PerSection<PhaseCurrentCodes>,
        shorted: bool,
    ) -> Option<PerSection<PhaseDuties>> {
        self.reset();
        if shorted {
            return Some(PerSection::default());
        }
        self.sense_monitor.observe(codes);
        None
    }

    /// The current loops and the load observer reset (the outputs go off).
    pub(super) fn reset(&mut self) {
        self.currents.master.reset();
        self.currents.slave.reset();
        self.load.reset();
    }
}
