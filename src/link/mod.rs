//! The link to the host over RTT: the framing ([`frame`], which knows no payload), the
//! command and reply codec ([`commands`]), the telemetry frame ([`telemetry`]) and the
//! never-blocking up-buffer writer the defmt logger uses ([`rtt_up`]).

pub mod commands;
pub mod frame;
pub mod rtt_up;
pub mod telemetry;
