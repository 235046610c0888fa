//! The down-channel's tags: the first payload byte of every frame the host sends, shared by
//! the command codec ([`crate::link::commands`]) and the link requests
//! ([`crate::link::settings`]), and [`TransferId`], the tag and argument a verdict (a `0x04`
//! message) names. Tags are part of the wire contract: never reuse or renumber.

/// [`crate::control::command::Command::Home`].
pub const HOME: u8 = 0x10;
/// [`crate::control::command::Command::MoveTo`].
pub const MOVE_TO: u8 = 0x11;
/// [`crate::control::command::Command::Stop`].
pub const STOP: u8 = 0x12;
/// [`crate::control::command::Command::Heartbeat`].
pub const HEARTBEAT: u8 = 0x13;
/// [`crate::control::command::Command::ClearFaults`].
pub const CLEAR_FAULTS: u8 = 0x14;
/// [`crate::control::command::Command::Start`].
pub const START: u8 = 0x15;
/// [`crate::control::command::Command::SetSpeed`].
pub const SET_SPEED: u8 = 0x16;
/// [`crate::control::command::Command::SetRotation`].
pub const SET_ROTATION: u8 = 0x17;
/// [`crate::control::command::Command::SetVolumeRatio`].
pub const SET_VOLUME_RATIO: u8 = 0x18;
/// [`crate::control::command::Command::Calibrate`].
pub const CALIBRATE: u8 = 0x19;
/// [`crate::control::command::Command::SetParameter`].
pub const SET_PARAMETER: u8 = 0x1A;
/// [`crate::link::commands::Transfer::Read`].
pub const CALIBRATION_READ: u8 = 0x1B;
/// [`crate::link::commands::Transfer::Write`].
pub const CALIBRATION_WRITE: u8 = 0x1C;
/// [`crate::link::commands::Transfer::Commit`].
pub const CALIBRATION_COMMIT: u8 = 0x1D;
/// [`crate::link::settings::LinkRequest::SetTelemetry`].
pub const SET_TELEMETRY: u8 = 0x1E;
/// [`crate::link::settings::LinkRequest::DeclarePorts`].
pub const DECLARE_PORTS: u8 = 0x1F;
/// [`crate::link::settings::LinkRequest::ScopeArm`].
pub const SCOPE_ARM: u8 = 0x20;
/// [`crate::link::settings::LinkRequest::ScopeFire`].
pub const SCOPE_FIRE: u8 = 0x21;
/// [`crate::link::settings::LinkRequest::ScopeDisarm`].
pub const SCOPE_DISARM: u8 = 0x22;
/// [`crate::link::settings::LinkRequest::RoutineReport`].
pub const ROUTINE_REPORT: u8 = 0x23;
/// `Command::Bench` (the bench build's; the release firmware rejects it as an unknown tag).
pub const BENCH: u8 = 0x24;

/// Which request a verdict answers: its tag and its offset (read, write) or CRC (commit).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TransferId {
    /// The request's tag ([`CALIBRATION_READ`] .. [`CALIBRATION_COMMIT`], or a link request's).
    pub tag: u8,
    /// Its offset, or the CRC of a commit.
    pub arg: u32,
}
