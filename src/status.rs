//! The machine's state as the outside sees it: the operating mode and the per-step status
//! snapshot. Below the control logic, so the port traits, the shared state and telemetry
//! can name them without depending on the controller.

use crate::safety::absent::Absent;
use crate::safety::faults::FaultSet;
use crate::safety::supervisor::LimitFlags;
use crate::units::Ticks;

/// Operating mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ModeKind {
    /// Outputs off, waiting for a command.
    Idle,
    /// Searching the zero.
    Homing,
    /// Holding a position.
    Holding,
    /// Executing a move.
    Moving,
    /// Compressing: continuous strokes.
    Running,
    /// Controlled stop in progress.
    Stopping,
    /// A fault is latched; outputs off.
    Faulted,
    /// Running a calibration routine.
    Calibrating,
    /// A bench operation of the bring-up (the bench build's).
    #[cfg(feature = "bench")]
    Bench,
}

impl ModeKind {
    /// Stable lower-case name.
    pub const fn name(self) -> &'static str {
        match self {
            ModeKind::Idle => "idle",
            ModeKind::Homing => "homing",
            ModeKind::Holding => "holding",
            ModeKind::Moving => "moving",
            ModeKind::Running => "running",
            ModeKind::Stopping => "stopping",
            ModeKind::Faulted => "faulted",
            ModeKind::Calibrating => "calibrating",
            #[cfg(feature = "bench")]
            ModeKind::Bench => "bench",
        }
    }
}

/// A snapshot of the machine after a step: what the run log and telemetry record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Status {
    /// Sampling instant.
    pub t: Ticks,
    /// Mode.
    pub mode: ModeKind,
    /// The zero is known.
    pub homed: bool,
    /// Position from the master encoder, m.
    pub position_m: f32,
    /// Position from the slave encoder, m.
    pub slave_position_m: f32,
    /// Velocity, m/s (differentiator).
    pub velocity_mps: f32,
    /// Acceleration, m/s² (differentiator).
    pub acceleration_mps2: f32,
    /// Position reference, m.
    pub reference_m: f32,
    /// Rotation angle, rad.
    pub theta_rad: f32,
    /// Rotation reference, rad.
    pub theta_reference_rad: f32,
    /// Force of the master section from its measured q-current, N.
    pub force_master_n: f32,
    /// Force of the slave section from its measured q-current, N.
    pub force_slave_n: f32,
    /// Total force commanded, N.
    pub force_command_n: f32,
    /// Chamber A pressure as converted, Pa (its validity is supervised separately).
    pub pressure_a_pa: f32,
    /// Chamber B pressure as converted, Pa.
    pub pressure_b_pa: f32,
    /// Latched faults.
    pub faults: FaultSet,
    /// Limits active this cycle.
    pub limits: LimitFlags,
    /// The parts absent since boot (empty once the outputs have been enabled).
    pub absent: Absent,
}

impl Status {
    /// The state before the first step.
    pub const INIT: Status = Status {
        t: Ticks(0),
        mode: ModeKind::Idle,
        homed: false,
        position_m: 0.0,
        slave_position_m: 0.0,
        velocity_mps: 0.0,
        acceleration_mps2: 0.0,
        reference_m: 0.0,
        theta_rad: 0.0,
        theta_reference_rad: 0.0,
        force_master_n: 0.0,
        force_slave_n: 0.0,
        force_command_n: 0.0,
        pressure_a_pa: 0.0,
        pressure_b_pa: 0.0,
        faults: FaultSet::new(),
        limits: LimitFlags {
            force: false,
            voltage: false,
            envelope: false,
        },
        absent: Absent::NONE,
    };
}
