//! A calibration routine on the board, as `fpc-sim link send calibrate ROUTINE` runs it: the
//! command, then the routine's report (link request `0x23`, answered with kind `0x08`:
//! `fpc::link::report`) asked for every [`POLL`] until the routine is no longer running,
//! and what it found in the lines `fpc-sim calibrate --check-wiring` prints (one formatter,
//! [`findings_lines`]). Only the firmware's bench build answers `0x23`;
//! the release firmware rejects it as an unknown tag, and the routine's acceptance is then
//! all there is to print ([`NO_REPORT`]).

use std::time::Duration;

use fpc::control::calibration::commission::wiring;
use fpc::control::calibration::report::{RoutineReport, RoutineState};
use fpc::control::calibration::{Commissioning, Routine};
use fpc::control::command::Command;
use fpc::link::commands::{Answer, MAX_COMMAND_WIRE};
use fpc::link::frame::FrameError;
use fpc::link::report::ReportAnswer;
use fpc::link::settings::{encode_link_request, LinkRequest};
use fpc::units::Section;

use super::session::{
    frame_error_text, outcome_text, report_text, section_name, send_command, Exchange, Outcome,
};
use super::Channels;

/// How often the host asks for the report while a routine runs.
pub const POLL: Duration = Duration::from_millis(100);

/// Longest a routine is awaited, in polls (60 s: the longest routine, cogging, takes ≈ 20 s
/// on the reference machine).
pub const MAX_POLLS: u32 = 600;

/// What follows the acceptance when the firmware reports no routine's end (the release
/// build rejects link request `0x23`).
pub const NO_REPORT: &str = "this firmware reports no routine's end (the bench build does): \
                             its results are in the calibration record (fpc-sim link \
                             calibration read)";

/// Asks for the last routine's report and waits up to `timeout` for it on up 2. Answers to
/// earlier requests go to `other`, as text. `None`: the firmware does not know the request
/// (the release build). An error is one line.
pub fn read_report<C: Channels + ?Sized>(
    channels: &mut C,
    timeout: Duration,
    other: impl FnMut(String),
) -> Result<Option<ReportAnswer>, String> {
    let mut wire = [0u8; MAX_COMMAND_WIRE];
    let n = encode_link_request(&LinkRequest::RoutineReport, &mut wire)
        .map_err(|_| "the request does not fit a frame".to_string())?;
    let mut exchange = Exchange::new(channels, timeout, other);
    let got = exchange.ask(
        wire.get(..n).unwrap_or_default(),
        "routine report",
        |a| match a {
            Answer::Report(r) => Some(*r),
            _ => None,
        },
    )?;
    match got {
        Ok(answer) => Ok(Some(answer)),
        Err(FrameError::UnknownKind) => Ok(None),
        Err(reason) => Err(format!(
            "rejected by the firmware: the `routine report` frame {}",
            frame_error_text(reason)
        )),
    }
}

/// Sends `Calibrate { routine }`, and once it is accepted, waits for the routine to end
/// (its report asked for every [`POLL`], at most [`MAX_POLLS`] times); each answer waited for
/// up to `timeout`. The lines to print: the acceptance, then what the routine found (the
/// commissioning's findings; `ROUTINE done` for the others, whose results the calibration
/// record carries). A refusal, a failure or a routine left before it ended is the error,
/// after the lines printed so far (`Err((lines, error))`).
pub fn calibrate<C: Channels + ?Sized>(
    channels: &mut C,
    routine: Routine,
    timeout: Duration,
    mut other: impl FnMut(String),
) -> Result<Vec<String>, (Vec<String>, String)> {
    let command = Command::Calibrate { routine };
    let outcome =
        send_command(channels, &command, timeout, &mut other).map_err(|e| (Vec::new(), e))?;
    match outcome {
        Outcome::Reply(r) if r.result.is_ok() => {}
        _ => return Err((Vec::new(), outcome_text(&outcome))),
    }
    let mut lines = vec![outcome_text(&outcome)];
    for _ in 0..MAX_POLLS {
        let answer = match read_report(channels, timeout, &mut other) {
            Ok(Some(a)) => a,
            Ok(None) => {
                lines.push(format!("{} accepted; {NO_REPORT}", routine.name()));
                return Ok(lines);
            }
            Err(e) => return Err((lines, e)),
        };
        match answer {
            ReportAnswer::Report(RoutineReport {
                state: RoutineState::Running,
                routine: running,
                ..
            }) if running == routine => channels.pause(POLL),
            answer => return ended(lines, routine, &answer),
        }
    }
    let waited = POLL.as_secs_f64() * f64::from(MAX_POLLS);
    Err((
        lines,
        format!("{} did not end within {waited:.0} s", routine.name()),
    ))
}

/// The lines of a routine that is no longer running, or the error after `lines`.
fn ended(
    mut lines: Vec<String>,
    routine: Routine,
    answer: &ReportAnswer,
) -> Result<Vec<String>, (Vec<String>, String)> {
    let name = routine.name();
    let report = match answer {
        ReportAnswer::Report(r) if r.routine == routine => r,
        ReportAnswer::Left(r) if *r == routine => {
            return Err((
                lines,
                format!(
                "{name} was left before it ended (a fault latched, or stop): nothing was loaded"
            ),
            ))
        }
        other => {
            return Err((
                lines,
                format!(
                    "{name} was accepted, but the board reports {}",
                    report_text(other)
                ),
            ))
        }
    };
    match report.state {
        RoutineState::Succeeded(Some(found)) => lines.extend(findings_lines(
            &found,
            report.expected_pitch_m,
            report.pitch_tolerance,
        )),
        RoutineState::Succeeded(None) => lines.push(format!("{name} done")),
        RoutineState::Failed(e) => return Err((lines, format!("{name} failed: {e}"))),
        RoutineState::Running => return Err((lines, format!("{name} is still running"))),
    }
    Ok(lines)
}

/// What the commissioning found, a line each, as the host prints it: each section's phase
/// order and each encoder's direction (or the two explanations that cannot be told apart),
/// then each section's pitch against an electrical period (`expected_pitch_m`, m) and a pitch
/// tolerance (fraction of it) as given: the board's report read over the link, or the
/// simulator's configuration (`fpc-sim calibrate --check-wiring`).
pub fn findings_lines(
    found: &Commissioning,
    expected_pitch_m: f32,
    pitch_tolerance: f32,
) -> Vec<String> {
    let phases = |s: Section| match s {
        Section::Master => wiring::MASTER_PHASES,
        Section::Slave => wiring::SLAVE_PHASES,
    };
    let encoder = |s: Section| match s {
        Section::Master => wiring::MASTER_ENCODER,
        Section::Slave => wiring::SLAVE_ENCODER,
    };
    let faults = |set: u8| {
        let mut parts = Vec::new();
        for s in Section::ALL {
            if set & phases(s) != 0 {
                parts.push(format!("phases swapped in section {}", section_name(s)));
            }
        }
        for s in Section::ALL {
            if set & encoder(s) != 0 {
                parts.push(format!("{} encoder reversed", section_name(s)));
            }
        }
        parts.join(" and ")
    };
    let mut lines = Vec::new();
    if found.ambiguous {
        lines.push(format!(
            "ambiguous: {}, or {}: the signs cannot tell these apart; correct one of them \
             and commission again",
            faults(found.reversed),
            faults(wiring::ALL ^ found.reversed)
        ));
    } else {
        for s in Section::ALL {
            lines.push(if found.reversed & phases(s) != 0 {
                format!("phases swapped in section {}", section_name(s))
            } else {
                format!("phases in order in section {}", section_name(s))
            });
        }
        for s in Section::ALL {
            lines.push(if found.reversed & encoder(s) != 0 {
                format!("{} encoder reversed", section_name(s))
            } else {
                format!("{} encoder counts with the motion", section_name(s))
            });
        }
    }
    let expected_mm = expected_pitch_m * 1e3;
    let tolerance = pitch_tolerance * 100.0;
    for s in Section::ALL {
        let verdict = if *found.pitch_ok.get(s) {
            "ok".to_string()
        } else {
            format!(
                "off by more than {tolerance:.0} %: check the motor's and the encoder's \
                 periods in the configuration"
            )
        };
        lines.push(format!(
            "N-N pitch in section {} {:.2} mm, expected {expected_mm:.2} mm: {verdict}",
            section_name(s),
            found.pitch_m.get(s) * 1e3
        ));
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpc::control::calibration::{CalibrationError, Commissioning};
    use fpc::control::command::{Refusal, Reply};
    use fpc::link::commands::{encode_reply, MAX_REPLY_WIRE};
    use fpc::link::report::{encode_report, MAX_REPORT_WIRE};
    use fpc::units::{PerSection, Section};
    use std::collections::VecDeque;

    /// A board that answers each frame written to down 0 with the next scripted answer.
    struct Scripted {
        answers: VecDeque<Vec<u8>>,
        up: Vec<u8>,
    }

    impl Channels for Scripted {
        fn read_up(&mut self, _: usize, buf: &mut [u8]) -> std::io::Result<usize> {
            let n = buf.len().min(self.up.len());
            buf[..n].copy_from_slice(&self.up[..n]);
            self.up.drain(..n);
            Ok(n)
        }

        fn write_down(&mut self, _: usize, bytes: &[u8]) -> std::io::Result<usize> {
            if let Some(a) = self.answers.pop_front() {
                self.up.extend(a);
            }
            Ok(bytes.len())
        }

        fn pause(&mut self, _: Duration) {}
    }

    fn reply(result: Result<(), Refusal>) -> Vec<u8> {
        let command = Command::Calibrate {
            routine: Routine::Commission,
        };
        let mut out = [0u8; MAX_REPLY_WIRE];
        let n = encode_reply(&Reply { command, result }, &mut out).unwrap();
        out[..n].to_vec()
    }

    fn report(answer: ReportAnswer) -> Vec<u8> {
        let mut out = [0u8; MAX_REPORT_WIRE];
        let n = encode_report(&answer, &mut out).unwrap();
        out[..n].to_vec()
    }

    fn commission(state: RoutineState) -> Vec<u8> {
        report(ReportAnswer::Report(RoutineReport {
            state,
            ..RoutineReport::started(Routine::Commission, 0.024, 0.02)
        }))
    }

    fn run(answers: Vec<Vec<u8>>) -> Result<Vec<String>, (Vec<String>, String)> {
        let mut board = Scripted {
            answers: answers.into(),
            up: Vec::new(),
        };
        let other = |l: String| panic!("unexpected answer {l}");
        calibrate(
            &mut board,
            Routine::Commission,
            Duration::from_secs(1),
            other,
        )
    }

    #[test]
    fn the_findings_are_printed_once_the_routine_has_ended() {
        let found = Commissioning {
            reversed: 4,
            ambiguous: false,
            pitch_m: PerSection {
                master: 0.02409,
                slave: 0.02408,
            },
            pitch_ok: PerSection {
                master: true,
                slave: true,
            },
        };
        let lines = run(vec![
            reply(Ok(())),
            commission(RoutineState::Running),
            commission(RoutineState::Running),
            commission(RoutineState::Succeeded(Some(found))),
        ])
        .unwrap();
        assert_eq!(lines[0], "accepted: calibrate commission");
        assert_eq!(lines[3], "master encoder reversed");
        assert_eq!(
            lines[5],
            "N-N pitch in section master 24.09 mm, expected 24.00 mm: ok"
        );
        assert_eq!(lines.len(), 7);
    }

    #[test]
    fn a_refusal_a_failure_and_a_routine_left_are_errors_after_what_was_printed() {
        let refused = run(vec![reply(Err(Refusal::FaultActive))]).unwrap_err();
        assert!(refused.0.is_empty());
        assert!(
            refused.1.starts_with("refused: calibrate commission: "),
            "{}",
            refused.1
        );
        let no_motion = CalibrationError::NoMotion {
            section: Section::Master,
        };
        let failed = run(vec![
            reply(Ok(())),
            commission(RoutineState::Failed(no_motion)),
        ])
        .unwrap_err();
        assert_eq!(failed.0, ["accepted: calibrate commission"]);
        assert!(
            failed
                .1
                .starts_with("commission failed: the piston did not follow the master section's"),
            "{}",
            failed.1
        );
        let left = run(vec![
            reply(Ok(())),
            commission(RoutineState::Running),
            report(ReportAnswer::Left(Routine::Commission)),
        ])
        .unwrap_err();
        assert!(left.1.contains("left before it ended"), "{}", left.1);
    }

    #[test]
    fn a_firmware_without_the_report_gets_the_acceptance_and_where_the_results_are() {
        use fpc::link::commands::encode_rejection;
        let mut rejected = [0u8; MAX_REPLY_WIRE];
        let n = encode_rejection(FrameError::UnknownKind, &mut rejected).unwrap();
        let lines = run(vec![reply(Ok(())), rejected[..n].to_vec()]).unwrap();
        assert_eq!(
            lines,
            [
                "accepted: calibrate commission".to_string(),
                format!("commission accepted; {NO_REPORT}")
            ]
        );
        // Any other rejection of the request is an error.
        let n = encode_rejection(FrameError::Crc, &mut rejected).unwrap();
        let crc = run(vec![reply(Ok(())), rejected[..n].to_vec()]).unwrap_err();
        assert!(crc.1.contains("failed its CRC"), "{}", crc.1);
    }
}
