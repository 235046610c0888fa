//! The last calibration routine's report on the wire: the host asks with the link request
//! `0x23` ([`crate::link::settings::LinkRequest::RoutineReport`], no fields) and the command
//! task answers on up 2 with one message of kind `0x08`, whatever the machine is doing (the
//! report is kept by the command task, never read in the control interrupt).
//!
//! # Kind `0x08` (little-endian)
//! | offset | field | type | |
//! |---|---|---|---|
//! | 0 | kind = `0x08` | u8 | |
//! | 1 | routine | u8 | [`Routine`] as number; `0xFF` with state 0 |
//! | 2 | state | u8 | 0 none since boot, 1 running, 2 left before it ended (a fault latched, or `Stop`), 3 succeeded, 4 failed |
//! | 3 | error | u8 | state 4 only: [`error_code`] |
//! | 4 | section | u8 | state 4 only: 0 master, 1 slave (the errors that name one) |
//! | 5 | phase | u8 | state 4 only: 0 a, 1 b, 2 c (`CurrentSenseOffset`) |
//! | 3 | reversed | u8 | state 3 of `commission` only: [`wiring`] flags |
//! | 4 | flags | u8 | bit 0 ambiguous, bit 1 master pitch ok, bit 2 slave pitch ok |
//! | 5 | master pitch | f32 | m, per electrical period |
//! | 9 | slave pitch | f32 | m |
//! | 13 | expected pitch | f32 | m: the configured electrical period |
//! | 17 | tolerance | f32 | fraction of the period |
//!
//! States 0–3 of the other routines end after byte 2 (what they loaded is read with the
//! calibration record, `0x1B`).
//!
//! [`wiring`]: crate::control::calibration::commission::wiring

use crate::control::calibration::report::{RoutineReport, RoutineState};
use crate::control::calibration::{CalibrationError, Commissioning, Routine};
use crate::link::frame::{encode_frame, max_wire_len, BufferTooSmall, FrameError};
use crate::units::{PerSection, Section};

/// Kind of the report message.
pub const KIND_ROUTINE_REPORT: u8 = 0x08;

/// Longest report payload, bytes (a commissioning's findings).
pub const MAX_REPORT_PAYLOAD: usize = 21;

/// Longest report frame on the wire, bytes.
pub const MAX_REPORT_WIRE: usize = max_wire_len(MAX_REPORT_PAYLOAD);

/// What the host reads: no routine since boot, or the last one's report.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ReportAnswer {
    /// No routine has been accepted since boot.
    Nothing,
    /// The last routine accepted, and how it stands.
    Report(RoutineReport),
    /// The last routine was accepted and the machine left it before it ended (a fault
    /// latched, or `Stop`): nothing was loaded.
    Left(Routine),
}

impl ReportAnswer {
    /// The command task's answer: `report` as the control task last posted it, read with
    /// whether the machine is `calibrating` now (read before the report: the control task
    /// posts a routine's end before the status that leaves `calibrating`).
    pub fn of(report: Option<RoutineReport>, calibrating: bool) -> Self {
        match report {
            None => ReportAnswer::Nothing,
            Some(r) if r.state == RoutineState::Running && !calibrating => {
                ReportAnswer::Left(r.routine)
            }
            Some(r) => ReportAnswer::Report(r),
        }
    }
}

/// The wire number of a routine's error (stable: never reuse or renumber).
pub const fn error_code(e: &CalibrationError) -> u8 {
    match e {
        CalibrationError::CurrentSenseOffset { .. } => 1,
        CalibrationError::AlignmentSpread { .. } => 2,
        CalibrationError::MisalignmentImplausible => 3,
        CalibrationError::NoRoom => 4,
        CalibrationError::MapIncomplete => 5,
        CalibrationError::NoMotion { .. } => 6,
        CalibrationError::EncoderSigns => 7,
    }
}

fn section_code(s: Section) -> u8 {
    match s {
        Section::Master => 0,
        Section::Slave => 1,
    }
}

fn section_of(code: u8) -> Option<Section> {
    match code {
        0 => Some(Section::Master),
        1 => Some(Section::Slave),
        _ => None,
    }
}

fn error_fields(e: &CalibrationError) -> [u8; 3] {
    let (section, phase) = match *e {
        CalibrationError::CurrentSenseOffset { section, phase } => (section_code(section), phase),
        CalibrationError::AlignmentSpread { section } | CalibrationError::NoMotion { section } => {
            (section_code(section), 0)
        }
        _ => (0, 0),
    };
    [error_code(e), section, phase]
}

fn error_of([code, section, phase]: [u8; 3]) -> Option<CalibrationError> {
    let s = section_of(section);
    Some(match code {
        1 if phase < 3 => CalibrationError::CurrentSenseOffset { section: s?, phase },
        2 => CalibrationError::AlignmentSpread { section: s? },
        3 => CalibrationError::MisalignmentImplausible,
        4 => CalibrationError::NoRoom,
        5 => CalibrationError::MapIncomplete,
        6 => CalibrationError::NoMotion { section: s? },
        7 => CalibrationError::EncoderSigns,
        _ => return None,
    })
}

/// Encodes `answer` as a complete up-channel frame into `out` ([`MAX_REPORT_WIRE`] suffice).
#[inline(never)]
pub fn encode_report(answer: &ReportAnswer, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    let mut p = [0u8; MAX_REPORT_PAYLOAD];
    let mut n = 0;
    let mut put = |bytes: &[u8]| {
        for &b in bytes {
            if let Some(slot) = p.get_mut(n) {
                *slot = b;
                n += 1;
            }
        }
    };
    put(&[KIND_ROUTINE_REPORT]);
    match answer {
        ReportAnswer::Nothing => put(&[0xFF, 0]),
        ReportAnswer::Left(routine) => put(&[*routine as u8, 2]),
        ReportAnswer::Report(r) => match r.state {
            RoutineState::Running => put(&[r.routine as u8, 1]),
            RoutineState::Failed(e) => {
                put(&[r.routine as u8, 4]);
                put(&error_fields(&e));
            }
            RoutineState::Succeeded(None) => put(&[r.routine as u8, 3]),
            RoutineState::Succeeded(Some(c)) => {
                put(&[r.routine as u8, 3, c.reversed]);
                let flags = u8::from(c.ambiguous)
                    | u8::from(c.pitch_ok.master) << 1
                    | u8::from(c.pitch_ok.slave) << 2;
                put(&[flags]);
                for v in [
                    c.pitch_m.master,
                    c.pitch_m.slave,
                    r.expected_pitch_m,
                    r.pitch_tolerance,
                ] {
                    put(&v.to_le_bytes());
                }
            }
        },
    }
    encode_frame(p.get(..n).ok_or(BufferTooSmall)?, out)
}

/// Decodes a report payload (kind `0x08` included); `None` if it is not one.
pub fn decode_report(payload: &[u8]) -> Option<Result<ReportAnswer, FrameError>> {
    let (&kind, rest) = payload.split_first()?;
    if kind != KIND_ROUTINE_REPORT {
        return None;
    }
    let routine = |code: u8| Routine::from_code(code).ok_or(FrameError::BadValue);
    let f32_at = |b: &[u8], i: usize| {
        let mut w = [0u8; 4];
        if let Some(s) = b.get(i..i + 4) {
            w.copy_from_slice(s);
        }
        f32::from_le_bytes(w)
    };
    let report = |code: u8, state| {
        routine(code).map(|routine| {
            ReportAnswer::Report(RoutineReport {
                routine,
                state,
                expected_pitch_m: 0.0,
                pitch_tolerance: 0.0,
            })
        })
    };
    Some(match *rest {
        [0xFF, 0] => Ok(ReportAnswer::Nothing),
        [code, 1] => report(code, RoutineState::Running),
        [code, 2] => routine(code).map(ReportAnswer::Left),
        [code, 3] => report(code, RoutineState::Succeeded(None)),
        [code, 4, e, s, ph] => match error_of([e, s, ph]) {
            Some(e) => report(code, RoutineState::Failed(e)),
            None => Err(FrameError::BadValue),
        },
        [code, 3, reversed, flags, ref values @ ..] if values.len() == 16 => {
            routine(code).map(|routine| {
                let found = Commissioning {
                    reversed,
                    ambiguous: flags & 1 != 0,
                    pitch_m: PerSection {
                        master: f32_at(values, 0),
                        slave: f32_at(values, 4),
                    },
                    pitch_ok: PerSection {
                        master: flags & 2 != 0,
                        slave: flags & 4 != 0,
                    },
                };
                ReportAnswer::Report(RoutineReport {
                    routine,
                    state: RoutineState::Succeeded(Some(found)),
                    expected_pitch_m: f32_at(values, 8),
                    pitch_tolerance: f32_at(values, 12),
                })
            })
        }
        _ => Err(FrameError::BadLength),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::frame::Deframer;

    fn round_trip(answer: ReportAnswer) -> ReportAnswer {
        let mut out = [0u8; MAX_REPORT_WIRE];
        let n = encode_report(&answer, &mut out).unwrap();
        let mut d = Deframer::<MAX_REPORT_WIRE>::new();
        let got: Vec<_> = out[..n]
            .iter()
            .filter_map(|&b| d.push_decoded(b, |p| decode_report(p).unwrap()))
            .collect();
        assert_eq!(got.len(), 1, "{answer:?}");
        got[0].unwrap()
    }

    #[test]
    fn every_answer_round_trips() {
        let found = Commissioning {
            reversed: 2,
            ambiguous: false,
            pitch_m: PerSection {
                master: 0.02398,
                slave: 0.02408,
            },
            pitch_ok: PerSection {
                master: true,
                slave: false,
            },
        };
        let commission = RoutineReport {
            routine: Routine::Commission,
            state: RoutineState::Succeeded(Some(found)),
            expected_pitch_m: 0.024,
            pitch_tolerance: 0.02,
        };
        let bare = |routine, state| RoutineReport {
            routine,
            state,
            expected_pitch_m: 0.0,
            pitch_tolerance: 0.0,
        };
        for answer in [
            ReportAnswer::Nothing,
            ReportAnswer::Left(Routine::Cogging),
            ReportAnswer::Report(commission),
            ReportAnswer::Report(bare(Routine::Alignment, RoutineState::Running)),
            ReportAnswer::Report(bare(Routine::CurrentSense, RoutineState::Succeeded(None))),
            ReportAnswer::Report(bare(
                Routine::Commission,
                RoutineState::Failed(CalibrationError::NoMotion {
                    section: Section::Slave,
                }),
            )),
            ReportAnswer::Report(bare(
                Routine::CurrentSense,
                RoutineState::Failed(CalibrationError::CurrentSenseOffset {
                    section: Section::Master,
                    phase: 2,
                }),
            )),
            ReportAnswer::Report(bare(
                Routine::Commission,
                RoutineState::Failed(CalibrationError::EncoderSigns),
            )),
        ] {
            assert_eq!(round_trip(answer), answer);
        }
    }

    #[test]
    fn a_running_report_reads_as_left_once_the_machine_is_not_calibrating() {
        let running = RoutineReport::started(Routine::Commission, 0.024, 0.02);
        assert_eq!(ReportAnswer::of(None, false), ReportAnswer::Nothing);
        assert_eq!(
            ReportAnswer::of(Some(running), true),
            ReportAnswer::Report(running)
        );
        assert_eq!(
            ReportAnswer::of(Some(running), false),
            ReportAnswer::Left(Routine::Commission)
        );
        let ended = running.ended(&Err(CalibrationError::NoRoom));
        assert_eq!(
            ReportAnswer::of(Some(ended), false),
            ReportAnswer::Report(ended)
        );
    }

    #[test]
    fn malformed_reports_are_refused() {
        let k = KIND_ROUTINE_REPORT;
        assert_eq!(decode_report(&[0x02, 0, 0]), None);
        assert_eq!(decode_report(&[k, 9, 3]), Some(Err(FrameError::BadValue)));
        assert_eq!(
            decode_report(&[k, 5, 4, 8, 0, 0]),
            Some(Err(FrameError::BadValue))
        );
        assert_eq!(
            decode_report(&[k, 5, 3, 0]),
            Some(Err(FrameError::BadLength))
        );
        assert_eq!(decode_report(&[k, 5]), Some(Err(FrameError::BadLength)));
    }
}
