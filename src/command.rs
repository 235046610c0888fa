//! Commands to the machine and their validation.
//!
//! Every command is checked against the configured limits before it changes anything; a
//! refused command carries the reason and leaves the state as it was. The binary codec for
//! the RTT down-channel encodes exactly these values.

use crate::synchroniser::Rotation;
use crate::volume_ratio::RatioTarget;

/// A command from the host.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Command {
    /// Find the zero: creep to head A, detect the stop, set x = 0 there, then park.
    Home,
    /// Move to a position, m, at a peak speed, m/s (homed, idle machine only).
    MoveTo {
        /// Target position, m (within the travel, clearances kept).
        position_m: f32,
        /// Peak speed of the move, m/s.
        peak_speed_mps: f32,
    },
    /// Start compressing: continuous strokes between the dead points at this peak speed,
    /// m/s (homed, holding machine only).
    Start {
        /// Peak speed, m/s.
        peak_speed_mps: f32,
    },
    /// Change the peak speed of the running strokes (from the next stroke on), m/s.
    SetSpeed {
        /// Peak speed, m/s.
        peak_speed_mps: f32,
    },
    /// Compressor or expander, from the next half cycle on (on the fly, at a dead point).
    SetRotation {
        /// The mode.
        rotation: Rotation,
    },
    /// How the built-in volume ratio is chosen: follow the measured pressure ratio, or fixed.
    SetVolumeRatio {
        /// The target.
        target: RatioTarget,
    },
    /// Stop: a running machine finishes its stroke and holds at that dead point; a moving
    /// one stops on the braking deceleration and holds.
    Stop,
    /// Host keep-alive.
    Heartbeat,
    /// Clear latched faults (refused while a cause persists).
    ClearFaults,
}

/// Why a command was refused. Nothing changed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Refusal {
    /// A value is NaN or infinite.
    NotFinite,
    /// A value is outside its configured range.
    OutOfRange,
    /// Motion was requested before homing.
    NotHomed,
    /// A fault is latched: clear it first.
    FaultActive,
    /// The machine is busy with another operation (homing, a move).
    Busy,
    /// The cause of a latched fault is still present.
    CausePersists,
}

impl Refusal {
    /// Operator-facing reason.
    pub const fn reason(self) -> &'static str {
        match self {
            Refusal::NotFinite => "value is NaN or infinite",
            Refusal::OutOfRange => "value outside the configured limits",
            Refusal::NotHomed => "not homed: home the axis first",
            Refusal::FaultActive => "a fault is latched: clear it first",
            Refusal::Busy => "busy: wait for the current operation to finish or stop it",
            Refusal::CausePersists => "the cause of the fault is still present",
        }
    }
}
