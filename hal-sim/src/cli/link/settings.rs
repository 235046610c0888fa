//! `fpc-sim link telemetry`, `ports`, `scope` and `flash`: the link requests the firmware's
//! command task answers itself (the telemetry's rate and channels, the ports declared, the
//! scope), and writing a firmware image to the board.

use std::path::{Path, PathBuf};

use clap::{Args, Subcommand, ValueEnum};
use fpc::link::scope::{Trigger, SCOPE_SAMPLES};
use fpc::link::settings::LinkRequest;
use fpc::link::telemetry::{Ports, MAX_DECIMATION};

use super::{open, timeout, Target};
use crate::failure::{num, CmdResult, Failure};
use crate::link::session::{parse_channels, send_link_request, transfer_text};
use crate::outln;

pub(super) const TELEMETRY_HELP: &str = "\
Examples:
    fpc-sim link telemetry --rate 2000                  (the default: gap's slowest rate, gap's seven channels)
    fpc-sim link telemetry --rate 5000 --channels all   (x_ref_m, theta_ref_rad, v_mps too)
    fpc-sim link telemetry --off

The rate is 20000 Hz divided by a whole number (the decimation). Bytes per second on the
probe: frame bytes x rate; gap's seven channels: 46 B (92 kB/s at 2 kHz, 920 kB/s at 20 kHz);
every channel: 58 B (116 kB/s at 2 kHz). What probes carry: docs/telemetry.md. A host that reads
slower than that loses frames: counted by the firmware (`dropped`) and by the host (sequence
gaps); the decoded log keeps the longest stretch without a gap.";

pub(super) const SCOPE_HELP: &str = "\
Examples:
    fpc-sim link scope arm --trigger strokes:4 --pre 256   (the 4th stroke reversal from now)
    fpc-sim link scope arm --trigger fault                 (a fault latched)
    fpc-sim link scope arm --trigger mode-change
    fpc-sim link scope arm --trigger command --pre 500; fpc-sim link scope fire

512 samples (25.6 ms) at 20 kHz of x_m, x_slave_m, theta_rad, f_master_n, f_slave_n,
p_a_pa, p_b_pa, --pre of them before the trigger. The firmware sends a finished recording on
up 2; `fpc-sim link capture` writes it as scope-N.csv (a run log at 20 kHz), and
`fpc-sim decode --capture DIR/up2.bin` decodes it again. Resolution: x as the controller's
f32, x_slave 0.1 um, theta 96 urad, forces 0.5 N, pressures 20 Pa.";

/// `fpc-sim link telemetry`.
#[derive(Args, Debug)]
pub(super) struct TelemetryArgs {
    #[command(flatten)]
    target: Target,
    /// Frames per second: 20000 divided by a whole number, at most 20000.
    #[arg(long, value_name = "HZ", conflicts_with_all = ["decimation", "off"])]
    rate: Option<f64>,
    /// Control cycles per frame, 1 (20 kHz) to 20000 (1 Hz).
    #[arg(long, value_name = "N", conflicts_with = "off")]
    decimation: Option<u16>,
    /// No telemetry.
    #[arg(long)]
    off: bool,
    /// The channels: `gap` (the seven a run log needs: the firmware's default), `all`, or
    /// names joined by commas (x_m, x_slave_m, theta_rad, f_master_n, f_slave_n, p_a_pa,
    /// p_b_pa, x_ref_m, theta_ref_rad, v_mps).
    #[arg(long, value_name = "SET", default_value = "gap")]
    channels: String,
    /// How long to wait for the answer, ms.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    timeout_ms: u64,
}

/// `fpc-sim link ports`.
#[derive(Args, Debug)]
pub(super) struct PortsArgs {
    #[command(flatten)]
    target: Target,
    /// timed (the rotation times the ports: the machine's normal state), bypassed (a
    /// start-up unloader opens both chambers to suction) or sealed (every port blanked).
    #[arg(value_enum)]
    ports: PortsArg,
    /// How long to wait for the answer, ms.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    timeout_ms: u64,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub(super) enum PortsArg {
    Timed,
    Bypassed,
    Sealed,
}

/// `fpc-sim link scope`.
#[derive(Args, Debug)]
pub(super) struct ScopeArgs {
    #[command(subcommand)]
    action: ScopeAction,
}

#[derive(Subcommand, Debug)]
pub(super) enum ScopeAction {
    /// Arm: record from now, stop 25.6 ms after the trigger (less the pre-trigger part).
    Arm {
        #[command(flatten)]
        target: Target,
        /// command (then `scope fire`), fault, mode-change, or strokes:N (the N-th stroke
        /// reversal from now).
        #[arg(long, value_name = "TRIGGER")]
        trigger: String,
        /// Samples (50 us each) to keep before the trigger, 0 to 511.
        #[arg(long, value_name = "SAMPLES", default_value_t = 128)]
        pre: u16,
        /// How long to wait for the answer, ms.
        #[arg(long, value_name = "MS", default_value_t = 1000)]
        timeout_ms: u64,
    },
    /// The host's trigger (the scope armed with --trigger command).
    Fire {
        #[command(flatten)]
        target: Target,
        /// How long to wait for the answer, ms.
        #[arg(long, value_name = "MS", default_value_t = 1000)]
        timeout_ms: u64,
    },
    /// Disarm, dropping a recording in progress or unsent.
    Disarm {
        #[command(flatten)]
        target: Target,
        /// How long to wait for the answer, ms.
        #[arg(long, value_name = "MS", default_value_t = 1000)]
        timeout_ms: u64,
    },
}

/// `fpc-sim link flash`.
#[derive(Args, Debug)]
pub(super) struct FlashArgs {
    #[command(flatten)]
    pub(super) target: Target,
    /// The firmware ELF (`cargo fw` builds target/thumbv7em-none-eabihf/release/fpc).
    #[arg(value_name = "ELF")]
    pub(super) image: PathBuf,
    /// Flash even though the machine is not idle (flashing halts and resets the core: the
    /// outputs drop and a moving piston coasts).
    #[arg(long)]
    pub(super) force: bool,
}

/// `fpc-sim link ports`.
pub(super) fn ports(a: PortsArgs) -> CmdResult {
    let ports = match a.ports {
        PortsArg::Timed => Ports::Timed,
        PortsArg::Bypassed => Ports::Bypassed,
        PortsArg::Sealed => Ports::Sealed,
    };
    request(&a.target, LinkRequest::DeclarePorts(ports), a.timeout_ms)
}

/// `fpc-sim link scope`.
pub(super) fn scope(a: ScopeArgs) -> CmdResult {
    match a.action {
        ScopeAction::Arm {
            target,
            trigger,
            pre,
            timeout_ms,
        } => {
            let trigger = parse_trigger(&trigger)?;
            if usize::from(pre) >= SCOPE_SAMPLES {
                return Err(Failure::bad_input(format!(
                    "--pre {pre}: give 0 to {} samples",
                    SCOPE_SAMPLES - 1
                )));
            }
            request(&target, LinkRequest::ScopeArm { trigger, pre }, timeout_ms)
        }
        ScopeAction::Fire { target, timeout_ms } => {
            request(&target, LinkRequest::ScopeFire, timeout_ms)
        }
        ScopeAction::Disarm { target, timeout_ms } => {
            request(&target, LinkRequest::ScopeDisarm, timeout_ms)
        }
    }
}

/// `--trigger`: command, fault, mode-change or strokes:N.
pub(super) fn parse_trigger(text: &str) -> Result<Trigger, Failure> {
    let bad = || {
        Failure::bad_input(format!(
            "--trigger {text}: give command, fault, mode-change or strokes:N (N from 1 to 65535)"
        ))
    };
    match text {
        "command" => Ok(Trigger::Command),
        "fault" => Ok(Trigger::Fault),
        "mode-change" => Ok(Trigger::ModeChange),
        _ => match text.strip_prefix("strokes:").map(str::parse::<u16>) {
            Some(Ok(n)) if n > 0 => Ok(Trigger::Strokes(n)),
            _ => Err(bad()),
        },
    }
}

pub(super) fn telemetry(args: TelemetryArgs) -> CmdResult {
    let channels = parse_channels(&args.channels)
        .map_err(|e| Failure::bad_input(format!("--channels: {e}")))?;
    let control_hz = 1e6 / f64::from(fpc::link::telemetry::CONTROL_PERIOD_US);
    let decimation = match (args.rate, args.decimation, args.off) {
        (_, _, true) => 0,
        (Some(rate), _, _) => {
            let d = control_hz / rate;
            if !(rate.is_finite() && rate > 0.0 && d >= 1.0 && (d - d.round()).abs() < 1e-9)
                || d.round() > f64::from(MAX_DECIMATION)
            {
                let (lo, hi) = (
                    d.floor().clamp(1.0, f64::from(MAX_DECIMATION)),
                    d.ceil().clamp(1.0, f64::from(MAX_DECIMATION)),
                );
                let hz = |d: f64| {
                    format!("{:.3}", control_hz / d)
                        .trim_end_matches('0')
                        .trim_end_matches('.')
                        .to_string()
                };
                let nearest = if lo == hi {
                    format!("the nearest is {} Hz", hz(lo))
                } else {
                    format!("the nearest are {} and {} Hz", hz(lo), hz(hi))
                };
                return Err(Failure::bad_input(format!(
                    "--rate {}: give {control_hz} Hz divided by a whole number from 1 to \
                     {MAX_DECIMATION}; {nearest}",
                    num(rate)
                )));
            }
            d.round() as u16
        }
        (None, Some(d), _) if (1..=MAX_DECIMATION).contains(&d) => d,
        (None, Some(d), _) => {
            return Err(Failure::bad_input(format!(
                "--decimation {d}: give 1 to {MAX_DECIMATION}"
            )))
        }
        (None, None, false) => {
            return Err(Failure::bad_input(
                "give --rate HZ, --decimation N or --off",
            ))
        }
    };
    request(
        &args.target,
        LinkRequest::SetTelemetry {
            decimation,
            channels,
        },
        args.timeout_ms,
    )?;
    if decimation > 0 {
        let rate = control_hz / f64::from(decimation);
        let bytes = channels.wire_bytes();
        outln!(
            "{} Hz; frames of {bytes} bytes: {:.1} kB/s on the probe",
            num(rate),
            bytes as f64 * rate / 1e3
        )?;
    }
    Ok(())
}

/// Sends one link request and prints the verdict: accepted (exit 0), or refused or rejected
/// with the reason (exit 1).
pub(super) fn request(target: &Target, request: LinkRequest, timeout_ms: u64) -> CmdResult {
    let timeout = timeout(timeout_ms)?;
    let mut channels = open(target)?;
    let mut earlier = Vec::new();
    let verdict = send_link_request(&mut channels, &request, timeout, |l| earlier.push(l));
    for line in earlier {
        outln!("{line}")?;
    }
    let what = transfer_text(request.id());
    match verdict.map_err(Failure::runtime)? {
        Ok(()) => outln!("accepted: {what}"),
        Err(r) => Err(Failure::runtime(format!("refused: {what}: {}", r.reason()))),
    }
}

#[cfg(feature = "probe")]
pub(super) fn flash(target: &Target, image: &Path, force: bool) -> CmdResult {
    if target.replay.is_some() {
        return Err(Failure::bad_input(
            "--replay: a recording cannot be flashed",
        ));
    }
    if !force {
        super::check_idle("flashing", target)?;
    }
    let line = crate::link::probe::flash(&super::probe_options(target), image)
        .map_err(Failure::runtime)?;
    outln!("{line}")
}

#[cfg(not(feature = "probe"))]
pub(super) fn flash(_target: &Target, _image: &Path, _force: bool) -> CmdResult {
    Err(Failure::bad_input(
        "this fpc-sim was built without the `probe` feature, so it cannot flash a board \
         (rebuild: cargo install --path hal-sim --features probe); or with probe-rs: \
         probe-rs download --chip STM32G474RETx ELF, then probe-rs reset --chip STM32G474RETx",
    ))
}
