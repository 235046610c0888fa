//! The publish stage: what one cycle leaves for the next ([`Previous`]) and the snapshot the
//! outside reads ([`Status`], assembled from both parts). The stages read `Previous`, never
//! the published status.

use crate::safety::absent::Absent;
use crate::safety::faults::FaultSet;
use crate::safety::supervisor::LimitFlags;
use crate::status::{ModeKind, Status};
use crate::units::{PerSection, Ticks};

/// What the last cycle left for this one: where the piston was and what was commanded.
/// The stages read it as a value; the cycle overwrites it as it goes (the drive its
/// commands, the publish stage the measurements), so a stage after the drive sees this
/// cycle's commands.
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub(super) struct Previous {
    /// Master position from the homed zero, m.
    pub position_m: f32,
    /// Slave position in the homed frame, m.
    pub slave_position_m: f32,
    /// Velocity, m/s (differentiator).
    pub velocity_mps: f32,
    /// Acceleration, m/s² (differentiator).
    pub acceleration_mps2: f32,
    /// Chamber A pressure as converted, Pa (meaningless where the sample was invalid).
    pub pressure_a_pa: f32,
    /// Chamber B pressure, likewise, Pa.
    pub pressure_b_pa: f32,
    /// Total force commanded, N.
    pub force_command_n: f32,
    /// Force commanded to each section, N.
    pub shares: PerSection<f32>,
    /// The position reference the loop tracked, m (none with the outputs off).
    pub reference_m: Option<f32>,
}

impl Previous {
    /// Before the first cycle: at rest at zero, nothing commanded.
    pub(super) const INIT: Previous = Previous {
        position_m: 0.0,
        slave_position_m: 0.0,
        velocity_mps: 0.0,
        acceleration_mps2: 0.0,
        pressure_a_pa: 0.0,
        pressure_b_pa: 0.0,
        force_command_n: 0.0,
        shares: PerSection {
            master: 0.0,
            slave: 0.0,
        },
        reference_m: None,
    };

    /// Nothing commanded (the outputs off).
    pub(super) fn outputs_off(&mut self) {
        self.shares = PerSection::default();
        self.force_command_n = 0.0;
    }
}

/// The publish stage's state: the last cycle's values ([`Previous`]) and the rest of the
/// status snapshot as it was at the end of that cycle.
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub(super) struct Publish {
    pub previous: Previous,
    /// Sampling instant.
    pub t: Ticks,
    /// Mode.
    pub mode: ModeKind,
    /// The zero was known.
    pub homed: bool,
    /// Rotation angle and its reference, rad (unwrapped).
    pub theta_rad: f32,
    pub theta_reference_rad: f32,
    /// Each section's force from its measured q-current, N.
    pub force_master_n: f32,
    pub force_slave_n: f32,
    /// Latched faults.
    pub faults: FaultSet,
    /// Limits active in the cycle.
    pub limits: LimitFlags,
    /// The parts absent since boot, as last watched (written only while the outputs have
    /// never been enabled).
    pub absent: Absent,
}

impl Publish {
    pub(super) const INIT: Publish = Publish {
        previous: Previous::INIT,
        t: Status::INIT.t,
        mode: Status::INIT.mode,
        homed: Status::INIT.homed,
        theta_rad: 0.0,
        theta_reference_rad: 0.0,
        force_master_n: 0.0,
        force_slave_n: 0.0,
        faults: FaultSet::new(),
        limits: Status::INIT.limits,
        absent: Absent::NONE,
    };

    /// The snapshot the outside reads (telemetry, the run log, the shared state). The
    /// position reference is the one tracked, or the position itself with the outputs off.
    #[inline]
    pub(super) fn status(&self) -> Status {
        let p = &self.previous;
        Status {
            t: self.t,
            mode: self.mode,
            homed: self.homed,
            position_m: p.position_m,
            slave_position_m: p.slave_position_m,
            velocity_mps: p.velocity_mps,
            acceleration_mps2: p.acceleration_mps2,
            reference_m: p.reference_m.unwrap_or(p.position_m),
            theta_rad: self.theta_rad,
            theta_reference_rad: self.theta_reference_rad,
            force_master_n: self.force_master_n,
            force_slave_n: self.force_slave_n,
            force_command_n: p.force_command_n,
            pressure_a_pa: p.pressure_a_pa,
            pressure_b_pa: p.pressure_b_pa,
            faults: self.faults,
            limits: self.limits,
            absent: self.absent,
        }
    }
}
