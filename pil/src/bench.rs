//! The first day on the bench (`docs/bring-up.md`), on the release ELF: the board boots with
//! nothing connected — the DC link off (PB5 low), both linear encoders unplugged (flat
//! inputs), the four pressure sensors unplugged (0 V) — and must wait without switching a
//! gate on, report what is absent and answer the operator with the reason. Then the link
//! comes up and the sensors are plugged in, in the same run.
//!
//! The gates are judged from TIM1/TIM8's output-stage registers every PWM period
//! ([`crate::chip::gates`]), not from MOE alone: zero duties with MOE set (all six low sides
//! on: the short-circuit brake) or an idle level of 1 with MOE clear are gates on as much as
//! a switching bridge.

use fpc::control::calibration::Routine;
use fpc::control::command::Command;
use fpc::link::commands::Answer;
use fpc::safety::readiness::Absent;
use fpc::units::DacCode;
use hal_sim::link::session::answer_text;

use crate::chip::gates::Gate;
use crate::session::Session;

/// What the bare bench showed.
#[derive(Clone, Debug, Default)]
pub struct BareBenchReport {
    /// How long the board waited with nothing connected, emulated s.
    pub seconds: f64,
    /// PWM periods judged.
    pub periods: u64,
    /// Periods in which any of the twelve gate inputs was high for part or all of the period.
    pub gate_on_periods: u64,
    /// The first such: (emulated s, section 1 or 2, phase 0–2, side "high"/"low", the gate).
    pub first_gate_on: Option<(f64, usize, usize, &'static str, Gate)>,
    /// Periods in which the servo command (DAC1 OUT1 as the plant receives it) was not
    /// zero torque (mid-scale).
    pub servo_torque_periods: u64,
    /// Faults seen over the wait (telemetry frames and the defmt log).
    pub faults: Vec<String>,
    /// The parts the last telemetry frame of the wait reported absent.
    pub absent: Vec<&'static str>,
    /// The defmt lines of the wait that name a part the machine waits for.
    pub waiting_lines: Vec<String>,
    /// Each command sent during the wait and the firmware's answer, as `fpc-sim link send`
    /// prints it.
    pub answers: Vec<String>,
    /// The answer to `Calibrate current_sense` once every part was there.
    pub calibrate_after: Option<String>,
    /// What `fpc-sim link status` prints for the last telemetry frame of the wait.
    pub status_line: String,
}

/// The commands the operator tries while nothing is connected.
const TRIED: [Command; 3] = [
    Command::ClearFaults,
    Command::Calibrate {
        routine: Routine::CurrentSense,
    },
    Command::Home,
];

/// Prepares the board before power-on: the DC link off, every linear sensor unplugged.
pub fn unplug(world: &mut hal_sim::board::world::World) {
    world.plant.supply.off();
    world.corruption.encoders_unplugged = true;
    world.corruption.pressures_unplugged = true;
}

/// Runs the bare wait for `seconds` from power-on, trying the operator's commands half-way
/// through, then brings the link up, plugs the sensors in and runs `Calibrate
/// current_sense` to its end: the board is then as the main scenario starts it.
pub fn bare_bench(session: &mut Session, seconds: f64) -> Result<BareBenchReport, String> {
    let mut r = BareBenchReport {
        seconds,
        ..BareBenchReport::default()
    };
    let mut tried = false;
    while session.chip.time_s() < seconds {
        session.step()?;
        judge(session, &mut r);
        if !tried && session.chip.time_s() >= seconds / 2.0 {
            tried = true;
            for c in TRIED {
                if !session.send(c) {
                    return Err("the firmware's RTT channels never came up".into());
                }
            }
        }
    }
    r.faults = session
        .faults
        .iter()
        .map(|f| f.name().to_string())
        .collect();
    r.status_line = hal_sim::link::session::status_text(&fpc::link::telemetry::Frame::from_status(
        0,
        0,
        &session.status,
    ));
    r.absent = session.status.absent.names().collect();
    r.waiting_lines = session
        .log
        .lines
        .iter()
        .filter(|(_, l)| l.contains("waiting:"))
        .map(|(_, l)| l.clone())
        .collect();
    r.answers = session
        .answers_log
        .iter()
        .filter_map(|(_, a)| match a {
            Answer::Reply(_) => Some(answer_text(a)),
            _ => None,
        })
        .collect();
    // PB5 rises; the encoders and the pressure sensors are plugged in.
    {
        let w = &mut session.chip.soc().board.world;
        w.plant.supply.restore();
        w.corruption.encoders_unplugged = false;
        w.corruption.pressures_unplugged = false;
    }
    let seen = session.answers_log.len();
    let deadline = session.chip.time_s() + 0.5;
    while session.status.absent != Absent::NONE || session.chip.time_s() < seconds + 0.05 {
        session.step()?;
        if session.chip.time_s() > deadline {
            return Err(format!(
                "the firmware still waits for {:?} 0.5 s after everything was connected",
                session.status.absent.names().collect::<Vec<_>>()
            ));
        }
    }
    session.send(Command::Calibrate {
        routine: Routine::CurrentSense,
    });
    let deadline = session.chip.time_s() + 3.0;
    loop {
        session.step()?;
        let answer = session.answers_log[seen..]
            .iter()
            .find_map(|(_, a)| match a {
                Answer::Reply(reply) if matches!(reply.command, Command::Calibrate { .. }) => {
                    Some(answer_text(a))
                }
                _ => None,
            });
        if let Some(text) = &answer {
            r.calibrate_after = Some(text.clone());
        }
        let done = answer.is_some()
            && session.status.mode == fpc::status::ModeKind::Idle
            && session
                .log
                .lines
                .iter()
                .any(|(_, l)| l.contains("calibration saved"));
        if done || (answer.is_some() && !answer.as_deref().unwrap_or("").starts_with("accepted")) {
            break;
        }
        if session.chip.time_s() > deadline {
            return Err("Calibrate current_sense did not end within 3 s".into());
        }
    }
    Ok(r)
}

/// Judges one period of the wait: the gates from the output stage, the servo command.
fn judge(session: &mut Session, r: &mut BareBenchReport) {
    let t = session.chip.time_s();
    let soc = session.chip.soc_ref();
    let gates = soc.gates();
    r.periods += 1;
    let mut on = None;
    for (i, pair) in gates.iter().enumerate() {
        for (side, g) in ["high", "low"].into_iter().zip(pair) {
            if *g != Gate::Never && on.is_none() {
                on = Some((t, i / 3 + 1, i % 3, side, *g));
            }
        }
    }
    if let Some(first) = on {
        r.gate_on_periods += 1;
        r.first_gate_on.get_or_insert(first);
    }
    if soc.board.world.servo_code != DacCode::MID {
        r.servo_torque_periods += 1;
    }
}
