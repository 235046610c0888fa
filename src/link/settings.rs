//! The command task's own requests about the link: the telemetry's rate and channels, the
//! ports as the operator declares them, and the scope ([`crate::link::scope`]). Like the
//! calibration transfer they never reach the controller: the command task applies them to
//! the shared state and answers each with a verdict (a `0x04` message, as the transfer's).
//!
//! # Requests (down-channel payload = tag ‖ fields, little-endian)
//! | tag | request | fields | verdict's `arg` |
//! |---|---|---|---|
//! | `0x1E` | [`LinkRequest::SetTelemetry`] | `decimation: u16` (0 = off), `channels: u16` ([`ChannelSet`]) | `decimation ‖ channels << 16` |
//! | `0x1F` | [`LinkRequest::DeclarePorts`] | `ports: u8` ([`Ports`] as number) | the number |
//! | `0x20` | [`LinkRequest::ScopeArm`] | `trigger: u8`, `arg: u16` ([`Trigger`] as number), `pre: u16` samples | `trigger ‖ arg << 8` |
//! | `0x21` | [`LinkRequest::ScopeFire`] | — | 0 |
//! | `0x22` | [`LinkRequest::ScopeDisarm`] | — | 0 |
//! | `0x23` | [`LinkRequest::RoutineReport`] | — | the bench build only (the release firmware rejects the tag): answered with a report, kind `0x08` ([`crate::link::report`]), not a verdict |
//!
//! The codec checks the form; the values are checked where they are applied
//! (`Shared::apply`): a decimation above [`MAX_DECIMATION`] or an empty
//! channel set is refused ([`Refusal::OutOfRange`]) and changes nothing.

use crate::control::command::Refusal;
use crate::link::frame::{encode_frame, BufferTooSmall, FrameError};
use crate::link::scope::Trigger;
use crate::link::tag::{self, TransferId};
use crate::link::telemetry::{ChannelSet, Ports, MAX_DECIMATION};

/// A request about the link.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkRequest {
    /// One frame every `decimation` control cycles (0: telemetry off), carrying `channels`.
    SetTelemetry {
        /// Control cycles per frame, 0 = off.
        decimation: u16,
        /// The channels each frame carries.
        channels: ChannelSet,
    },
    /// How the chambers are connected (the board cannot see it): stamped in every frame.
    DeclarePorts(Ports),
    /// Arm the scope.
    ScopeArm {
        /// What ends the recording.
        trigger: Trigger,
        /// Samples before the trigger's to keep.
        pre: u16,
    },
    /// The host's trigger.
    ScopeFire,
    /// Disarm the scope, dropping a recording in progress or unsent.
    ScopeDisarm,
    /// Read the last calibration routine's report.
    RoutineReport,
}

impl LinkRequest {
    /// What the verdict on this request names.
    pub fn id(&self) -> TransferId {
        let (t, arg) = match *self {
            LinkRequest::SetTelemetry {
                decimation,
                channels,
            } => (
                tag::SET_TELEMETRY,
                u32::from(decimation) | u32::from(channels.0) << 16,
            ),
            LinkRequest::DeclarePorts(p) => (tag::DECLARE_PORTS, u32::from(p.code())),
            LinkRequest::ScopeArm { trigger, .. } => {
                let (code, arg) = trigger.code();
                (tag::SCOPE_ARM, u32::from(code) | u32::from(arg) << 8)
            }
            LinkRequest::ScopeFire => (tag::SCOPE_FIRE, 0),
            LinkRequest::ScopeDisarm => (tag::SCOPE_DISARM, 0),
            LinkRequest::RoutineReport => (tag::ROUTINE_REPORT, 0),
        };
        TransferId { tag: t, arg }
    }

    /// The values checked: the request as the firmware would apply it, or why it refuses.
    pub fn check(&self) -> Result<(), Refusal> {
        match *self {
            LinkRequest::SetTelemetry {
                decimation,
                channels,
            } if decimation > MAX_DECIMATION || !channels.valid() => Err(Refusal::OutOfRange),
            _ => Ok(()),
        }
    }
}

/// Whether `t` is the tag of a link request (the routine report's in the bench build only:
/// the release firmware rejects it as an unknown tag).
pub const fn is_link_tag(t: u8) -> bool {
    matches!(
        t,
        tag::SET_TELEMETRY
            | tag::DECLARE_PORTS
            | tag::SCOPE_ARM
            | tag::SCOPE_FIRE
            | tag::SCOPE_DISARM
    ) || (cfg!(feature = "bench") && t == tag::ROUTINE_REPORT)
}

/// Longest link-request payload, bytes.
const MAX_PAYLOAD: usize = 6;

/// Encodes a link request as a complete down-channel frame into `out`
/// ([`crate::link::commands::MAX_COMMAND_WIRE`] suffice).
pub fn encode_link_request(request: &LinkRequest, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    let mut p = [0u8; MAX_PAYLOAD];
    let n = match *request {
        LinkRequest::SetTelemetry {
            decimation,
            channels,
        } => {
            let [d0, d1] = decimation.to_le_bytes();
            let [c0, c1] = channels.0.to_le_bytes();
            fill(&mut p, &[tag::SET_TELEMETRY, d0, d1, c0, c1])
        }
        LinkRequest::DeclarePorts(ports) => fill(&mut p, &[tag::DECLARE_PORTS, ports.code()]),
        LinkRequest::ScopeArm { trigger, pre } => {
            let (code, arg) = trigger.code();
            let [a0, a1] = arg.to_le_bytes();
            let [p0, p1] = pre.to_le_bytes();
            fill(&mut p, &[tag::SCOPE_ARM, code, a0, a1, p0, p1])
        }
        LinkRequest::ScopeFire => fill(&mut p, &[tag::SCOPE_FIRE]),
        LinkRequest::ScopeDisarm => fill(&mut p, &[tag::SCOPE_DISARM]),
        LinkRequest::RoutineReport => fill(&mut p, &[tag::ROUTINE_REPORT]),
    };
    encode_frame(p.get(..n).ok_or(BufferTooSmall)?, out)
}

fn fill(p: &mut [u8; MAX_PAYLOAD], bytes: &[u8]) -> usize {
    for (d, s) in p.iter_mut().zip(bytes) {
        *d = *s;
    }
    bytes.len().min(MAX_PAYLOAD)
}

/// Decodes a link-request payload (tag ‖ fields); `None` if the tag is not one.
pub(crate) fn decode_link_request(payload: &[u8]) -> Option<Result<LinkRequest, FrameError>> {
    let (&t, f) = payload.split_first()?;
    if !is_link_tag(t) {
        return None;
    }
    Some(match (t, f) {
        (tag::SET_TELEMETRY, &[d0, d1, c0, c1]) => Ok(LinkRequest::SetTelemetry {
            decimation: u16::from_le_bytes([d0, d1]),
            channels: ChannelSet(u16::from_le_bytes([c0, c1])),
        }),
        (tag::DECLARE_PORTS, &[code]) => Ports::from_code(code)
            .map(LinkRequest::DeclarePorts)
            .ok_or(FrameError::BadValue),
        (tag::SCOPE_ARM, &[code, a0, a1, p0, p1]) => {
            Trigger::from_code(code, u16::from_le_bytes([a0, a1]))
                .map(|trigger| LinkRequest::ScopeArm {
                    trigger,
                    pre: u16::from_le_bytes([p0, p1]),
                })
                .ok_or(FrameError::BadValue)
        }
        (tag::SCOPE_FIRE, []) => Ok(LinkRequest::ScopeFire),
        (tag::SCOPE_DISARM, []) => Ok(LinkRequest::ScopeDisarm),
        (tag::ROUTINE_REPORT, []) => Ok(LinkRequest::RoutineReport),
        _ => Err(FrameError::BadLength),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::commands::{decode_request, Request, MAX_COMMAND_WIRE};
    use crate::link::frame::Deframer;

    fn all() -> [LinkRequest; 7] {
        [
            LinkRequest::SetTelemetry {
                decimation: 10,
                channels: ChannelSet::GAP,
            },
            LinkRequest::SetTelemetry {
                decimation: 0,
                channels: ChannelSet::ALL,
            },
            LinkRequest::DeclarePorts(Ports::Sealed),
            LinkRequest::ScopeArm {
                trigger: Trigger::Strokes(3),
                pre: 128,
            },
            LinkRequest::ScopeFire,
            LinkRequest::ScopeDisarm,
            LinkRequest::RoutineReport,
        ]
    }

    #[test]
    fn every_request_round_trips_through_the_command_reader() {
        for r in all() {
            let mut out = [0u8; MAX_COMMAND_WIRE];
            let n = encode_link_request(&r, &mut out).unwrap();
            let mut d = Deframer::<MAX_COMMAND_WIRE>::new();
            let got: Vec<_> = out[..n]
                .iter()
                .filter_map(|&b| d.push_decoded(b, decode_request))
                .collect();
            assert_eq!(got, vec![Ok(Request::Link(r))], "{r:?}");
        }
    }

    #[test]
    fn malformed_requests_are_rejected_and_bad_values_refused() {
        assert_eq!(
            decode_link_request(&[tag::DECLARE_PORTS, 3]),
            Some(Err(FrameError::BadValue))
        );
        assert_eq!(
            decode_link_request(&[tag::SCOPE_ARM, 3, 0, 0, 0, 0]),
            Some(Err(FrameError::BadValue)),
            "a stroke count of 0"
        );
        assert_eq!(
            decode_link_request(&[tag::SCOPE_FIRE, 1]),
            Some(Err(FrameError::BadLength))
        );
        assert_eq!(decode_link_request(&[tag::HOME]), None);
        let too_slow = LinkRequest::SetTelemetry {
            decimation: MAX_DECIMATION + 1,
            channels: ChannelSet::ALL,
        };
        assert_eq!(too_slow.check(), Err(Refusal::OutOfRange));
        let nothing = LinkRequest::SetTelemetry {
            decimation: 1,
            channels: ChannelSet(0),
        };
        assert_eq!(nothing.check(), Err(Refusal::OutOfRange));
        assert!(all().iter().all(|r| r.check().is_ok()));
    }
}
