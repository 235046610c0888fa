//! The page's controls as the link's commands and requests: what the console knows of the
//! machine, and each control checked and turned into frames (or refused with the reason).

use fpc::control::calibration::Routine;
use fpc::control::command::Command;
use fpc::link::commands::{encode_command, Answer, TransferReply, MAX_COMMAND_WIRE};
use fpc::link::settings::{encode_link_request, LinkRequest};
use fpc::link::telemetry::Ports;
use fpc::motion::synchroniser::Rotation;

use super::CYCLES_PER_S;
use crate::link::session::{describe, parse_channels, transfer_text};
use crate::plant::model::MachineModel;
use crate::view::protocol::Control;

/// What the simulated board's operator does besides sending commands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum PlantAction {
    /// Set the discharge line to this pressure ratio and close the start-up bypass.
    Load(f64),
}

/// The page's control as the link's frames (and the plant's change on the simulated
/// board), or the console's answer when it cannot be sent.
pub(super) struct Sends {
    /// Commands and requests, in order.
    pub(super) items: Vec<Outgoing>,
    /// A change of the simulated plant before them.
    pub(super) plant: Option<PlantAction>,
}

/// One command or link request.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Outgoing {
    Command(Command),
    Request(LinkRequest),
}

impl Outgoing {
    pub(super) fn wire(&self) -> Vec<u8> {
        let mut wire = [0u8; MAX_COMMAND_WIRE];
        let n = match self {
            Outgoing::Command(c) => encode_command(c, &mut wire).unwrap_or(0),
            Outgoing::Request(r) => encode_link_request(r, &mut wire).unwrap_or(0),
        };
        wire.get(..n).unwrap_or_default().to_vec()
    }

    pub(super) fn text(&self) -> String {
        match self {
            Outgoing::Command(c) => describe(c),
            Outgoing::Request(r) => transfer_text(r.id()),
        }
    }

    /// Whether `answer` answers it.
    pub(super) fn answered_by(&self, answer: &Answer) -> bool {
        match (self, answer) {
            (Outgoing::Command(c), Answer::Reply(r)) => r.command == *c,
            (
                Outgoing::Request(q),
                Answer::Calibration(TransferReply::Verdict { transfer, .. }),
            ) => *transfer == q.id(),
            _ => false,
        }
    }
}

/// What the console knows of the machine it controls, to turn a control into frames.
#[derive(Clone, Copy, Debug)]
pub(super) struct Known {
    /// The rotation last set (the firmware boots as a compressor).
    pub(super) rotation: Rotation,
    /// The ports declared timed (the simulated board's bypass closed).
    pub(super) ports_timed: bool,
}

/// Turns a page control into what is sent, or the reason it is not.
pub(super) fn translate(
    control: &Control,
    mode: &str,
    model: Option<&MachineModel>,
    known: &mut Known,
) -> Result<Sends, String> {
    let one = |s: Outgoing| {
        Ok(Sends {
            items: vec![s],
            plant: None,
        })
    };
    match control {
        Control::Home => one(Outgoing::Command(Command::Home)),
        Control::Stop => one(Outgoing::Command(Command::Stop)),
        Control::ClearFaults => one(Outgoing::Command(Command::ClearFaults)),
        Control::Calibrate { routine } => {
            let routine = match routine.as_str() {
                "current-sense" => Routine::CurrentSense,
                "alignment" => Routine::Alignment,
                "misalignment" => Routine::Misalignment,
                "cogging" => Routine::Cogging,
                other => {
                    return Err(format!(
                        "calibrate {}: give current-sense, alignment, misalignment or cogging",
                        crate::output::clip(other, 40)
                    ))
                }
            };
            one(Outgoing::Command(Command::Calibrate { routine }))
        }
        Control::Start {
            pressure_ratio,
            speed_mps,
            rotation,
        } => {
            let rotation = match rotation.as_str() {
                "compressor" => Rotation::Compressor,
                "expander" => Rotation::Expander,
                other => {
                    return Err(format!(
                        "rotation {}: give compressor or expander",
                        crate::output::clip(other, 40)
                    ))
                }
            };
            // The ratio and speed are checked as `fpc-sim run` checks its flags.
            let opts = crate::run::RunOptions {
                model: model.cloned().unwrap_or_else(MachineModel::reference),
                pressure_ratio: *pressure_ratio,
                speed_mps: *speed_mps,
                ..crate::run::RunOptions::reference()
            };
            opts.validate()?;
            let mut items = Vec::new();
            let mut plant = None;
            if mode != "probe" && !known.ports_timed {
                // The operator closes the start-up bypass and says so.
                items.push(Outgoing::Request(LinkRequest::DeclarePorts(Ports::Timed)));
                known.ports_timed = true;
            }
            if mode == "sim" {
                plant = Some(PlantAction::Load(*pressure_ratio));
            }
            if rotation != known.rotation {
                items.push(Outgoing::Command(Command::SetRotation { rotation }));
                known.rotation = rotation;
            }
            items.push(Outgoing::Command(Command::Start {
                peak_speed_mps: opts.peak_speed_mps() as f32,
            }));
            Ok(Sends { items, plant })
        }
        Control::Telemetry { rate_hz, channels } => {
            let per_s = CYCLES_PER_S as f64;
            let decimation = per_s / rate_hz;
            if !(rate_hz.is_finite()
                && *rate_hz >= 1.0
                && decimation.fract() == 0.0
                && decimation <= f64::from(fpc::link::telemetry::MAX_DECIMATION))
            {
                return Err(format!(
                    "telemetry rate {rate_hz} Hz: give {per_s} Hz divided by a whole number \
                     (20000, 10000, 5000, 4000, 2000, 1000, …)"
                ));
            }
            let channels = parse_channels(channels)?;
            one(Outgoing::Request(LinkRequest::SetTelemetry {
                decimation: decimation as u16,
                channels,
            }))
        }
        Control::ScopeArm { trigger, pre } => {
            let trigger = parse_trigger(trigger)?;
            one(Outgoing::Request(LinkRequest::ScopeArm {
                trigger,
                pre: *pre,
            }))
        }
        Control::ScopeFire => one(Outgoing::Request(LinkRequest::ScopeFire)),
        Control::Record { .. } => Ok(Sends {
            items: Vec::new(),
            plant: None,
        }),
    }
}

/// A scope trigger as typed: `command`, `fault`, `mode-change` or `strokes:N`.
pub(super) fn parse_trigger(text: &str) -> Result<fpc::link::scope::Trigger, String> {
    use fpc::link::scope::Trigger;
    match text.trim() {
        "command" => Ok(Trigger::Command),
        "fault" => Ok(Trigger::Fault),
        "mode-change" => Ok(Trigger::ModeChange),
        t => match t.strip_prefix("strokes:").map(str::parse::<u16>) {
            Some(Ok(n)) if n >= 1 => Ok(Trigger::Strokes(n)),
            _ => Err(format!(
                "trigger {}: give command, fault, mode-change or strokes:N (N from 1)",
                crate::output::clip(t, 40)
            )),
        },
    }
}
