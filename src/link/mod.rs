//! The link to the host over RTT: the framing ([`frame`], which knows no payload), the
//! down-channel's tags ([`tag`]), the command and reply codec ([`commands`]), the telemetry frame ([`telemetry`]), the
//! triggered full-rate capture ([`scope`]), the command task's link requests ([`settings`]:
//! telemetry rate and channels, the ports declared, the scope), the last calibration routine's
//! report ([`report`]), the RTT channel table ([`channels`]) and the
//! never-blocking up-buffer writer ([`rtt_up`]).

pub mod channels;
pub mod commands;
pub mod frame;
pub mod report;
pub mod rtt_up;
pub mod scope;
pub mod settings;
pub mod tag;
pub mod telemetry;
