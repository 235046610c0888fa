//! Commands to the machine and their validation.
//!
//! Every command is checked against the configured limits before it changes anything; a
//! refused command carries the reason and leaves the state as it was. The binary codec for
//! the RTT down-channel encodes exactly these values.

use crate::control::calibration::Routine;
use crate::motion::synchroniser::Rotation;
use crate::motion::volume_ratio::RatioTarget;

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
    /// Set one tunable parameter (validated against its limits; refused while running).
    SetParameter {
        /// Which one.
        parameter: Parameter,
        /// The new value, in the parameter's unit.
        value: f32,
    },
    /// Stop: a running machine finishes its stroke and holds at that dead point; a moving
    /// one stops on the braking deceleration and holds.
    Stop,
    /// Host keep-alive.
    Heartbeat,
    /// Clear latched faults (refused while a cause persists).
    ClearFaults,
    /// Run a calibration routine (idle or holding machine; the sweeping ones homed) and load
    /// its result; the machine then holds (homed) or goes idle.
    Calibrate {
        /// The routine.
        routine: Routine,
    },
    /// A bench operation of the bring-up (`docs/bring-up.md` §2, §9) for `seconds`; the
    /// bench build's. Ends early on `Stop` or any fault.
    #[cfg(feature = "bench")]
    Bench {
        /// What to drive.
        op: BenchOp,
        /// How long, s (within [`BENCH_MAX_SECONDS`]).
        seconds: f32,
    },
}

/// The longest bench operation, s.
#[cfg(feature = "bench")]
pub const BENCH_MAX_SECONDS: f32 = 60.0;

/// The fixed duties a bench operation accepts (the gate drivers' bootstrap capacitors need
/// a low-side pulse every period; the dead time needs room at both ends).
#[cfg(feature = "bench")]
pub const BENCH_DUTY_RANGE: (f32, f32) = (0.05, 0.95);

/// The largest servo torque a bench operation commands, as a fraction of the DAC's full
/// scale (`servo.torque_full_scale_nm`): a quarter, 5 N·m on the reference drive, above the
/// piston seal's breakaway torque (its static friction at the bore's radius, ≈ 2.7 N·m).
#[cfg(feature = "bench")]
pub const BENCH_SERVO_FRACTION: f32 = 0.25;

/// How far a bench servo torque turns the shaft before it ends, rad (a quarter turn): with
/// no position loop the drive accelerates as long as it pushes.
#[cfg(feature = "bench")]
pub const BENCH_SERVO_TURN_RAD: f32 = core::f32::consts::FRAC_PI_2;

/// What a bench operation drives (the bench build's).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
#[cfg(feature = "bench")]
pub enum BenchOp {
    /// One phase of one section at a fixed duty, the section's other two phases and the
    /// other section's three at 50 % (no line voltage between them): every gate pair
    /// switching, on the low-voltage bench supply only (power-good low).
    FixedDuty {
        /// The section.
        section: crate::units::Section,
        /// The phase (0 = u, 1 = v, 2 = w).
        phase: u8,
        /// Its duty, fraction of the period (within [`BENCH_DUTY_RANGE`]).
        duty: f32,
    },
    /// A torque command to the servo drive, N·m (positive: the machine's positive
    /// direction; within [`BENCH_SERVO_FRACTION`] of full scale), until the shaft has
    /// turned [`BENCH_SERVO_TURN_RAD`]; the motor's outputs off.
    ServoTorque {
        /// The torque, N·m.
        torque_nm: f32,
    },
}

/// The parameters the host may set at run time, with stable numbers (the command codec
/// carries the number) and their limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
#[repr(u8)]
pub enum Parameter {
    /// Position-loop stiffness, N/m.
    PositionKp = 1,
    /// Position-loop damping, N·s/m.
    PositionKd = 2,
    /// Host heartbeat timeout before the piston parks, s.
    HeartbeatTimeout = 3,
    /// Park position, m from head A.
    ParkPosition = 4,
    /// Fraction of a dead-point error corrected per stroke.
    DeadPointGain = 5,
}

impl Parameter {
    /// Every parameter, in number order.
    pub const ALL: [Parameter; 5] = [
        Parameter::PositionKp,
        Parameter::PositionKd,
        Parameter::HeartbeatTimeout,
        Parameter::ParkPosition,
        Parameter::DeadPointGain,
    ];

    /// The parameter with number `code`.
    pub fn from_code(code: u8) -> Option<Parameter> {
        Parameter::ALL.iter().copied().find(|p| *p as u8 == code)
    }

    /// Accepted range (inclusive). Loop gains within a factor of about 3 of the reference
    /// tuning (beyond it the loop's stability margin against the real delays is not shown);
    /// the park position keeps 5 mm from either head of the reference travel.
    pub const fn range(self) -> (f32, f32) {
        match self {
            Parameter::PositionKp => (2.0e5, 2.5e6),
            Parameter::PositionKd => (1.5e3, 1.5e4),
            Parameter::HeartbeatTimeout => (0.05, 10.0),
            Parameter::ParkPosition => (0.005, 0.2),
            Parameter::DeadPointGain => (0.0, 1.0),
        }
    }
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
    /// The phase currents read a current with the outputs off: a current-sense offset.
    CurrentSenseOffset,
    /// No complete calibration is loaded (missing, invalid or incomplete in flash): run the
    /// calibration routines first.
    NotCalibrated,
    /// A calibration chunk is not the next one (a chunk lost or resent out of order), or a
    /// commit came before the whole record was written: write it again from offset 0.
    ChunkOutOfOrder,
    /// The calibration record written is not one (magic, version, CRC or the CRC sent do
    /// not match): nothing changed.
    BadRecord,
    /// The scope is not armed with the host's trigger (`fire` needs `arm --trigger command`).
    NotArmed,
    /// The DC link has not been up since boot (power-good low): nothing can be driven.
    SupplyAbsent,
    /// An encoder's signal is absent since boot: nothing tells where the piston is.
    EncodersAbsent,
    /// A chamber pressure sensor reads absent since boot.
    PressuresAbsent,
    /// A bench routine (the commissioning) asked of a firmware built without them: flash the
    /// `bench` build (`docs/bring-up.md` §10).
    BenchBuildOnly,
    /// A fixed duty asked with the DC link up: it runs on the low-voltage bench supply only,
    /// with power-good low (the bench build's).
    #[cfg(feature = "bench")]
    SupplyUp,
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
            Refusal::CurrentSenseOffset => {
                "phase currents read non-zero with the outputs off: run the current-sense calibration"
            }
            Refusal::NotCalibrated => {
                "not calibrated: run current_sense, alignment, home, misalignment, cogging"
            }
            Refusal::ChunkOutOfOrder => {
                "calibration chunk out of order or missing: write the record again from offset 0"
            }
            Refusal::BadRecord => {
                "not a valid calibration record (magic, version or CRC): nothing changed"
            }
            Refusal::NotArmed => "the scope is not armed with the command trigger: arm it first",
            Refusal::SupplyAbsent => {
                "the DC link is not up (power-good low since boot): switch the bus supply on"
            }
            Refusal::EncodersAbsent => {
                "an encoder reads no signal since boot: connect the encoders and check their supply"
            }
            Refusal::PressuresAbsent => {
                "a chamber pressure sensor reads absent since boot: connect the transducers"
            }
            Refusal::BenchBuildOnly => {
                "a bench routine: this firmware is built without them; flash the bench build"
            }
            #[cfg(feature = "bench")]
            Refusal::SupplyUp => {
                "the DC link is up (power-good high): a fixed duty runs on the low-voltage \
                 bench supply only; switch the bus supply off"
            }
        }
    }
}

/// The answer to one command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reply {
    /// The command answered.
    pub command: Command,
    /// Accepted, or refused with the reason.
    pub result: Result<(), Refusal>,
}
