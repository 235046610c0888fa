//! The link to the host over RTT: the framing ([`frame`], which knows no payload), the
//! command and reply codec ([`commands`]) and the telemetry frame ([`telemetry`]).

pub mod commands;
pub mod frame;
pub mod telemetry;
