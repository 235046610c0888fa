//! A calibration routine on the board, as `fpc-sim link send calibrate ROUTINE` runs it: the
//! command, then the routine's report (link request `0x23`, answered with kind `0x08`:
//! `fpc::link::report`) asked for every [`POLL`] until the routine is no longer running,
//! and what it found in the lines `fpc-sim calibrate --check-wiring` prints (one formatter,
//! [`crate::calibration::findings_lines`]).

use std::time::Duration;

use fpc::control::calibration::report::{RoutineReport, RoutineState};
use fpc::control::calibration::Routine;
use fpc::control::command::Command;
use fpc::link::commands::{Answer, MAX_COMMAND_WIRE};
use fpc::link::report::ReportAnswer;
use fpc::link::settings::{encode_link_request, LinkRequest};

use super::session::{
    frame_error_text, outcome_text, report_text, send_command, Exchange, Outcome,
};
use super::Channels;

/// How often the host asks for the report while a routine runs.
pub const POLL: Duration = Duration::from_millis(100);

/// Longest a routine is awaited, in polls (60 s: the longest routine, cogging, takes ≈ 20 s
/// on the reference machine).
pub const MAX_POLLS: u32 = 600;

/// Asks for the last routine's report and waits up to `timeout` for it on up 2. Answers to
/// earlier requests go to `other`, as text. An error is one line.
pub fn read_report<C: Channels + ?Sized>(
    channels: &mut C,
    timeout: Duration,
    other: impl FnMut(String),
) -> Result<ReportAnswer, String> {
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
    got.map_err(|reason| {
        format!(
            "rejected by the firmware: the `routine report` frame {}",
            frame_error_text(reason)
        )
    })
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
    let lines = vec![outcome_text(&outcome)];
    for _ in 0..MAX_POLLS {
        let answer = match read_report(channels, timeout, &mut other) {
            Ok(a) => a,
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
        RoutineState::Succeeded(Some(found)) => lines.extend(crate::calibration::findings_lines(
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
