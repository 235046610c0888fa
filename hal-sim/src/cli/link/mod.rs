//! `fpc-sim link`: the host link to the running board over RTT through a debug probe —
//! `capture` records telemetry into a capture and a run log and shows the defmt log and the
//! drop counters; `send` sends one command and prints the firmware's answer; `calibration
//! read|write` moves the calibration record between the board and a calibration file.
//! `--replay DIR` runs any of them on recorded channel contents instead of the board.
//!
//! `telemetry`, `ports`, `scope` set the link up, `flash` writes the firmware ([`settings`]).
//!
//! The session logic is [`crate::link`]'s; this module is the command line and the files.

mod settings;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::{Args, Subcommand, ValueEnum};
use fpc::control::calibration::Routine;
use fpc::control::command::{BenchOp, Command, Parameter};
use fpc::motion::synchroniser::Rotation;
use fpc::motion::volume_ratio::RatioTarget;
use fpc::units::Section;

use crate::calibration::to_toml;
use crate::cli::decode::{counts, mostly_unusable, report_written};
use crate::failure::{num, CmdResult, Failure};
use crate::link::defmt::DefmtLog;
use crate::link::replay::up_file;
use crate::link::scope::trigger_text;
use crate::link::session::{
    outcome_text, read_calibration, send_command, write_calibration, CaptureSession, Outcome,
};
use crate::link::{Channels, Replay, CHIP};
use crate::outln;
use crate::output::{show, OutDir, OutFile};
use fpc::control::calibration::record::{CalibrationRecord, RECORD_BYTES};
use settings::{
    flash, ports, scope, telemetry, FlashArgs, PortsArgs, ScopeArgs, TelemetryArgs, SCOPE_HELP,
    TELEMETRY_HELP,
};

const LINK_HELP: &str = "\
RTT channels of the fpc firmware: up 0 defmt log, up 1 telemetry, up 2 command replies and
scope recordings, down 0 commands. The tool attaches to the running board (no reset, no
halt) through the debug probe (--probe VID:PID[:SN] when several are connected), finds the
RTT control block in its RAM (or at the ELF's _SEGGER_RTT) and reads and writes the channels
there. Talking to a board needs fpc-sim built with the `probe` feature (about 9 minutes once):
    cargo install --path hal-sim --features probe
The walkthrough from the bench to the augmented model: docs/rig-to-model.md.

Typical session on the rig (firmware flashed and running), with the answers:
    $ fpc-sim link send home
    accepted: home
    $ fpc-sim link send start --speed 2.3        (once homing has finished)
    accepted: start --speed 2.3
    $ fpc-sim link capture --elf target/thumbv7em-none-eabihf/release/fpc --out rig-run --seconds 30
    1 s: telemetry 92000 bytes: frames accepted 2000, rejected 0, ... dropped by the firmware 0; ...
    ...
    decimation 10 control cycles per frame; wrote 60000 rows (100.0 % of the frames) ... to rig-run/run.csv
    $ fpc-sim link send stop
    accepted: stop
    $ fpc-sim link send start --speed 9
    fpc-sim: refused: start --speed 9: value outside the configured limits

`capture` writes rig-run/up1.bin (the raw telemetry, what `fpc-sim decode --capture` reads),
rig-run/run.csv (the run log, with the metadata `fpc-sim gap` reads), rig-run/scope-N.csv
for each scope recording received, rig-run/up0.bin and up2.bin (raw defmt, replies and
recordings). A capture directory is also a recording: `--replay rig-run` plays it back.";

/// Talk to the running board: telemetry capture, commands, defmt log.
#[derive(Args, Debug)]
#[command(after_help = LINK_HELP)]
pub struct LinkArgs {
    #[command(subcommand)]
    action: Action,
}

#[derive(Subcommand, Debug)]
enum Action {
    /// Record telemetry (up 1) into DIR/up1.bin and the run log DIR/run.csv, show the defmt
    /// log (up 0) and command replies (up 2), and the drop counters once a second.
    #[command(after_help = CAPTURE_HELP)]
    Capture(CaptureArgs),
    /// Send one command on down 0 and print the firmware's answer from up 2: accepted (exit
    /// 0), or refused or rejected with the reason (exit 1).
    #[command(after_help = SEND_HELP)]
    Send(SendArgs),
    /// Read the calibration record the controller runs on into a calibration file, or
    /// write a calibration file to the board (checked and loaded by the firmware, then kept
    /// in flash).
    #[command(after_help = CALIBRATION_HELP)]
    Calibration(CalibrationArgs),
    /// Set the telemetry's rate and channels (the firmware starts at 2000 Hz with the seven
    /// channels a run log needs).
    #[command(after_help = TELEMETRY_HELP)]
    Telemetry(TelemetryArgs),
    /// Declare how the chambers are connected (the board cannot see it): stamped in every
    /// telemetry frame, it becomes `# ports` (and `# ports_from_s`) of the decoded log.
    Ports(PortsArgs),
    /// The triggered capture: every channel `gap` needs at the full 20 kHz, 25.6 ms around a
    /// trigger, sent on up 2 and written by `capture` as scope-N.csv.
    #[command(after_help = SCOPE_HELP)]
    Scope(ScopeArgs),
    /// Write a firmware ELF to the board's flash, reset the core and detach, leaving the
    /// firmware running (needs the `probe` feature).
    Flash(FlashArgs),
}

const CALIBRATION_HELP: &str = "\
Examples:
    fpc-sim link calibration read --out rig.toml
    fpc-sim link calibration write rig.toml
    fpc-sim link calibration read --replay rig-run --out rig.toml    (from a recording)

The record goes in 16-byte chunks, each answered; a write ends with a commit carrying the
record's CRC-32. The firmware loads it only when the whole record arrived in order and its
magic, version and CRC hold, and only while idle (after boot, before homing): then the
machine must home again. Otherwise it refuses with the reason (exit 1) and changes nothing.
The file is the one `fpc-sim calibrate --out` writes and `fpc-sim run --calibration` loads.";

/// `fpc-sim link calibration`.
#[derive(Args, Debug)]
struct CalibrationArgs {
    #[command(subcommand)]
    action: CalibrationAction,
}

#[derive(Subcommand, Debug)]
enum CalibrationAction {
    /// Read the record the controller runs on and write it as a calibration file.
    Read {
        #[command(flatten)]
        target: Target,
        /// The calibration file to write.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Replace an existing file.
        #[arg(long)]
        force: bool,
        /// How long to wait for each answer, ms.
        #[arg(long, value_name = "MS", default_value_t = 1000)]
        timeout_ms: u64,
    },
    /// Send a calibration file to the board, which checks it, loads it and keeps it.
    Write {
        #[command(flatten)]
        target: Target,
        /// The calibration file (as `fpc-sim calibrate --out` writes it).
        #[arg(value_name = "FILE")]
        file: PathBuf,
        /// How long to wait for each answer, ms.
        #[arg(long, value_name = "MS", default_value_t = 1000)]
        timeout_ms: u64,
    },
}

const CAPTURE_HELP: &str = "\
Example (30 s on the rig, defmt decoded with the firmware ELF):
    fpc-sim link capture --elf target/thumbv7em-none-eabihf/release/fpc --out rig-run --seconds 30

The counters: frames accepted/rejected (framing or CRC: noise, a host attaching mid-frame),
repeated, sequence gaps (frames lost between the firmware and the host: the host read too slowly;
raise the decimation), dropped by the firmware (frames it could not queue or send). run.csv holds
the longest gap-free stretch, exactly as `fpc-sim decode --capture DIR/up1.bin` gives it.
Ctrl-C ends a capture early and still writes the files (a second Ctrl-C abandons it).";

const SEND_HELP: &str = "\
Examples:
    fpc-sim link send home
    fpc-sim link send start --speed 2.3
    fpc-sim link send set-volume-ratio --ratio 3.5
    fpc-sim link send stop
    fpc-sim link send --replay rig-run heartbeat      (answer from a recording)

Prints `accepted: start --speed 2.3`, or `refused: start --speed 2.3: not homed: home the
axis first` (exit 1). The controller checks every value against its limits.";

/// Where the channels come from. All but `--speed` (which `send start` has as its own) are
/// global: they may follow a subcommand (`fpc-sim link send home --replay rig-run`) as well as
/// precede it.
#[derive(Args, Debug)]
struct Target {
    /// Play recorded channels (DIR/up0.bin, DIR/up1.bin, DIR/up2.bin, e.g. an earlier
    /// capture) instead of attaching to the board.
    #[arg(long, value_name = "DIR", global = true)]
    replay: Option<PathBuf>,
    /// The chip to attach to (probe-rs name).
    #[arg(long, default_value = CHIP, global = true)]
    chip: String,
    /// The firmware ELF that runs on the board: locates the RTT block and decodes defmt.
    #[arg(long, value_name = "FILE", global = true)]
    elf: Option<PathBuf>,
    /// Which probe: VID:PID or VID:PID:SERIAL (hex ids, as `probe-rs list` prints them);
    /// by default the only one connected.
    #[arg(long, value_name = "VID:PID[:SN]", value_parser = probe_selector, global = true)]
    probe: Option<String>,
    /// SWD clock, kHz (by default the probe's).
    #[arg(long, value_name = "KHZ", value_parser = clap::value_parser!(u32).range(1..=100_000))]
    speed: Option<u32>,
    /// Hold the chip in reset while connecting (when it does not answer otherwise); this
    /// restarts the firmware.
    #[arg(long, global = true)]
    connect_under_reset: bool,
}

/// `--probe`: `VID:PID` or `VID:PID:SERIAL`, the ids in hex (what probe-rs takes).
pub(crate) fn probe_selector(text: &str) -> Result<String, String> {
    let mut parts = text.splitn(3, ':');
    let hex =
        |p: Option<&str>| p.is_some_and(|h| !h.is_empty() && u16::from_str_radix(h, 16).is_ok());
    let (vid, pid) = (parts.next(), parts.next());
    let serial_ok = parts.next().is_none_or(|sn| !sn.is_empty());
    if hex(vid) && hex(pid) && serial_ok {
        Ok(text.to_string())
    } else {
        Err(format!(
            "`{text}`: give VID:PID or VID:PID:SERIAL with hex ids, e.g. 0483:374b or \
             0483:374b:0670FF505055877267164520"
        ))
    }
}

/// `fpc-sim link capture`.
#[derive(Args, Debug)]
struct CaptureArgs {
    #[command(flatten)]
    target: Target,
    /// Output directory: up0.bin, up1.bin, up2.bin (raw channels) and run.csv.
    #[arg(long, value_name = "DIR", default_value = "out/capture")]
    out: PathBuf,
    /// How long to record from the board, s (Ctrl-C ends it earlier; a replay plays to
    /// its end).
    #[arg(long, value_name = "S", default_value_t = 10.0)]
    seconds: f64,
    /// Replace existing output files of the same names.
    #[arg(long)]
    force: bool,
    /// Write run.csv even when its gap-free stretch holds less than half of the frames.
    #[arg(long)]
    accept_loss: bool,
}

/// `fpc-sim link send`.
#[derive(Args, Debug)]
struct SendArgs {
    #[command(flatten)]
    target: Target,
    /// How long to wait for the answer, ms.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    timeout_ms: u64,
    #[command(subcommand)]
    command: CommandArg,
}

/// The commands, as typed.
#[derive(Subcommand, Debug)]
enum CommandArg {
    /// Find the zero: creep to head A, set x = 0 there, then park (needed before motion).
    Home,
    /// Move to a position and hold there (homed, idle machine).
    MoveTo {
        /// Target position, m from head A.
        #[arg(long, value_name = "M", allow_negative_numbers = true)]
        position: f32,
        /// Peak speed of the move, m/s.
        #[arg(long, value_name = "M/S", allow_negative_numbers = true)]
        speed: f32,
    },
    /// Start compressing: continuous strokes at this peak speed (homed, holding machine).
    Start {
        /// Peak speed, m/s.
        #[arg(long, value_name = "M/S", allow_negative_numbers = true)]
        speed: f32,
    },
    /// Change the peak speed of the running strokes (from the next stroke on).
    SetSpeed {
        /// Peak speed, m/s.
        #[arg(long, value_name = "M/S", allow_negative_numbers = true)]
        speed: f32,
    },
    /// Stop: finish the stroke (or brake a move) and hold.
    Stop,
    /// Host keep-alive. The first one arms the firmware's host watchdog: from then on the
    /// piston parks when they stop coming (this tool sends one per call, none by itself).
    Heartbeat,
    /// Clear latched faults (refused while a cause persists).
    ClearFaults,
    /// Compressor or expander, from the next half cycle on.
    SetRotation {
        /// The rotation.
        #[arg(value_enum)]
        rotation: RotationArg,
    },
    /// Built-in volume ratio: follow the measured pressure ratio, or fixed for a design
    /// pressure ratio.
    SetVolumeRatio {
        /// Follow the measured pressure ratio.
        #[arg(long, conflicts_with = "ratio", required_unless_present = "ratio")]
        follow: bool,
        /// Fixed, designed for this pressure ratio (> 1).
        #[arg(long, value_name = "RATIO", allow_negative_numbers = true)]
        ratio: Option<f32>,
    },
    /// Run a calibration routine and wait for it to end: prints its acceptance, then what it
    /// found (the commissioning's findings, as `fpc-sim calibrate --check-wiring` prints
    /// them; `ROUTINE done` for the others) or why it failed (exit 1).
    Calibrate {
        /// The routine.
        #[arg(value_enum)]
        routine: RoutineArg,
    },
    /// Set one tuning parameter (validated against its limits; refused while running).
    SetParameter {
        /// Which one.
        #[arg(value_enum)]
        name: ParameterArg,
        /// The new value, in the parameter's unit (N/m, N·s/m, s, m, fraction).
        #[arg(allow_negative_numbers = true)]
        value: f32,
    },
    /// A bench operation of the bring-up (the bench build only: `cargo fw-bench`): prints
    /// what the board drives and what to measure (docs/bring-up.md §2, §9.3).
    Bench {
        #[command(subcommand)]
        op: BenchArg,
    },
}

/// The bench operations, as typed.
#[derive(Subcommand, Debug)]
enum BenchArg {
    /// One phase of one section at a fixed duty, every other phase at 50 %: the gate
    /// pairs switching on the low-voltage bench supply (power-good low; refused with the DC
    /// link up).
    FixedDuty {
        /// The section (master: TIM1, slave: TIM8).
        #[arg(long, value_enum)]
        section: SectionArg,
        /// The phase.
        #[arg(long, value_enum)]
        phase: PhaseArg,
        /// Its duty, fraction of the period (0.05 to 0.95).
        #[arg(long, value_name = "FRACTION", allow_negative_numbers = true)]
        duty: f32,
        /// How long, s (at most 60; `stop` ends it sooner).
        #[arg(
            long,
            value_name = "S",
            default_value_t = 10.0,
            allow_negative_numbers = true
        )]
        seconds: f32,
    },
    /// A torque command to the servo drive until the shaft has turned a quarter turn, the
    /// motor's outputs off.
    ServoTorque {
        /// The torque, N·m (positive: the machine's positive direction; at most a quarter of
        /// the drive's full scale, above the piston seal's breakaway torque).
        #[arg(long, value_name = "NM", allow_negative_numbers = true)]
        torque: f32,
        /// How long, s (at most 60; `stop` ends it sooner).
        #[arg(
            long,
            value_name = "S",
            default_value_t = 5.0,
            allow_negative_numbers = true
        )]
        seconds: f32,
    },
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum SectionArg {
    Master,
    Slave,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum PhaseArg {
    U,
    V,
    W,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum RotationArg {
    Compressor,
    Expander,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum RoutineArg {
    CurrentSense,
    Alignment,
    Misalignment,
    Cogging,
    EncoderMap,
    Commission,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum ParameterArg {
    /// Position-loop stiffness, N/m.
    PositionKp,
    /// Position-loop damping, N·s/m.
    PositionKd,
    /// Host heartbeat timeout before the piston parks, s.
    HeartbeatTimeout,
    /// Park position, m from head A.
    ParkPosition,
    /// Fraction of a dead-point error corrected per stroke.
    DeadPointGain,
}

impl CommandArg {
    fn command(&self) -> Command {
        match *self {
            CommandArg::Home => Command::Home,
            CommandArg::MoveTo { position, speed } => Command::MoveTo {
                position_m: position,
                peak_speed_mps: speed,
            },
            CommandArg::Start { speed } => Command::Start {
                peak_speed_mps: speed,
            },
            CommandArg::SetSpeed { speed } => Command::SetSpeed {
                peak_speed_mps: speed,
            },
            CommandArg::Stop => Command::Stop,
            CommandArg::Heartbeat => Command::Heartbeat,
            CommandArg::ClearFaults => Command::ClearFaults,
            CommandArg::SetRotation { rotation } => Command::SetRotation {
                rotation: match rotation {
                    RotationArg::Compressor => Rotation::Compressor,
                    RotationArg::Expander => Rotation::Expander,
                },
            },
            CommandArg::SetVolumeRatio { ratio, .. } => Command::SetVolumeRatio {
                target: match ratio {
                    Some(pressure_ratio) => RatioTarget::Fixed { pressure_ratio },
                    None => RatioTarget::FollowMeasured,
                },
            },
            CommandArg::Calibrate { routine } => Command::Calibrate {
                routine: match routine {
                    RoutineArg::CurrentSense => Routine::CurrentSense,
                    RoutineArg::Alignment => Routine::Alignment,
                    RoutineArg::Misalignment => Routine::Misalignment,
                    RoutineArg::Cogging => Routine::Cogging,
                    RoutineArg::EncoderMap => Routine::EncoderMap,
                    RoutineArg::Commission => Routine::Commission,
                },
            },
            CommandArg::SetParameter { name, value } => Command::SetParameter {
                parameter: match name {
                    ParameterArg::PositionKp => Parameter::PositionKp,
                    ParameterArg::PositionKd => Parameter::PositionKd,
                    ParameterArg::HeartbeatTimeout => Parameter::HeartbeatTimeout,
                    ParameterArg::ParkPosition => Parameter::ParkPosition,
                    ParameterArg::DeadPointGain => Parameter::DeadPointGain,
                },
                value,
            },
            CommandArg::Bench { ref op } => match *op {
                BenchArg::FixedDuty {
                    section,
                    phase,
                    duty,
                    seconds,
                } => Command::Bench {
                    op: BenchOp::FixedDuty {
                        section: match section {
                            SectionArg::Master => Section::Master,
                            SectionArg::Slave => Section::Slave,
                        },
                        phase: phase as u8,
                        duty,
                    },
                    seconds,
                },
                BenchArg::ServoTorque { torque, seconds } => Command::Bench {
                    op: BenchOp::ServoTorque { torque_nm: torque },
                    seconds,
                },
            },
        }
    }
}

/// Runs `fpc-sim link`.
pub fn main(args: LinkArgs) -> CmdResult {
    match args.action {
        Action::Capture(a) => capture(a),
        Action::Send(a) => send(a),
        Action::Calibration(a) => calibration(a.action),
        Action::Telemetry(a) => telemetry(a),
        Action::Ports(a) => ports(a),
        Action::Scope(a) => scope(a),
        Action::Flash(a) => flash(&a.target, &a.image, a.force),
    }
}

/// The channels named by `target`: a recording, or the board through a probe.
fn open(target: &Target) -> Result<Box<dyn Channels>, Failure> {
    if let Some(dir) = &target.replay {
        return Ok(Box::new(Replay::from_dir(dir).map_err(Failure::bad_input)?));
    }
    open_probe(target)
}

/// The probe's options from the command line.
#[cfg(feature = "probe")]
fn probe_options(target: &Target) -> crate::link::probe::ProbeOptions {
    crate::link::probe::ProbeOptions {
        chip: target.chip.clone(),
        probe: target.probe.clone(),
        speed_khz: target.speed,
        connect_under_reset: target.connect_under_reset,
    }
}

#[cfg(feature = "probe")]
fn open_probe(target: &Target) -> Result<Box<dyn Channels>, Failure> {
    if target.connect_under_reset {
        // A board that answers without the reset line needs none: never reset a moving one.
        check_idle("--connect-under-reset", target)?;
    }
    crate::link::probe::attach(&probe_options(target), target.elf.as_deref())
        .map(|p| Box::new(p) as Box<dyn Channels>)
        .map_err(Failure::runtime)
}

/// Refuses `what` (which halts or resets the core) unless the board, reached without
/// halting or resetting it, reports the machine idle or does not answer
/// ([`crate::link::session::halting_allowed`]).
#[cfg(feature = "probe")]
fn check_idle(what: &str, target: &Target) -> CmdResult {
    let opts = crate::link::probe::ProbeOptions {
        connect_under_reset: false,
        ..probe_options(target)
    };
    let Ok(mut channels) = crate::link::probe::attach(&opts, target.elf.as_deref()) else {
        // No fpc firmware answers: nothing here is known to run.
        return Ok(());
    };
    let mode = crate::link::session::machine_mode(&mut channels, crate::link::session::MODE_WAIT)
        .unwrap_or(None);
    crate::link::session::halting_allowed(what, mode, false).map_err(Failure::runtime)
}

#[cfg(not(feature = "probe"))]
fn open_probe(_target: &Target) -> Result<Box<dyn Channels>, Failure> {
    Err(Failure::bad_input(
        "this fpc-sim was built without the `probe` feature, so it cannot attach to a board \
         (rebuild: cargo install --path hal-sim --features probe); --replay DIR plays \
         recorded channels",
    ))
}

/// The defmt view: decoded with the ELF when possible, hex otherwise.
fn defmt_log(elf: Option<&Path>) -> Result<DefmtLog, Failure> {
    let Some(elf) = elf else {
        return Ok(DefmtLog::hex());
    };
    let bytes = std::fs::read(elf)
        .map_err(|e| Failure::bad_input(format!("cannot read {}: {e}", show(elf))))?;
    decoded_defmt(&bytes, elf)
}

#[cfg(feature = "probe")]
fn decoded_defmt(bytes: &[u8], elf: &Path) -> Result<DefmtLog, Failure> {
    DefmtLog::from_elf(bytes).map_err(|e| Failure::bad_input(format!("{}: {e}", show(elf))))
}

#[cfg(not(feature = "probe"))]
fn decoded_defmt(_bytes: &[u8], _elf: &Path) -> Result<DefmtLog, Failure> {
    Ok(DefmtLog::hex())
}

/// Name of the run log in a capture directory.
const RUN_LOG: &str = "run.csv";

fn capture(args: CaptureArgs) -> CmdResult {
    if !(args.seconds.is_finite() && args.seconds > 0.0 && args.seconds <= 86_400.0) {
        return Err(Failure::bad_input(format!(
            "--seconds {}: give a duration above 0 and at most 86400 s",
            num(args.seconds)
        )));
    }
    let names: Vec<String> = (0..3).map(up_file).collect();
    let name_refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let inputs: Vec<PathBuf> = args
        .target
        .replay
        .iter()
        .flat_map(|d| names.iter().map(move |n| d.join(n)))
        .chain(args.target.elf.clone())
        .collect();
    let input_refs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    let log_path = args.out.join(RUN_LOG);
    crate::output::check_replaceable(&log_path, args.force)?;
    let out = OutDir::prepare(&args.out, &name_refs, args.force, &input_refs)?;
    let mut channels = open(&args.target)?;
    let defmt = defmt_log(args.target.elf.as_deref())?;
    if args.target.elf.is_some() && !defmt.decodes() {
        outln!("defmt is shown as hex: decoding it needs fpc-sim built with the `probe` feature")?;
    }
    let create = |name: &str| {
        std::fs::File::create(out.path(name))
            .map(std::io::BufWriter::new)
            .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&out.path(name)))))
    };
    let (mut up0, mut up1, mut up2) = (create(&names[0])?, create(&names[1])?, create(&names[2])?);
    let mut session = CaptureSession::new(defmt);
    let live = args.target.replay.is_none();
    if live {
        // Ctrl-C ends a live capture, which still writes its files (a second one abandons
        // it: nothing lands, the staging goes).
        crate::interrupt::catch();
    }
    let started = Instant::now();
    let mut shown = started;
    {
        let mut raw: [&mut dyn Write; 3] = [&mut up0, &mut up1, &mut up2];
        loop {
            let (n, lines) = session
                .poll(&mut channels, &mut raw)
                .map_err(|e| Failure::runtime(format!("link failed: {e}")))?;
            for line in lines {
                outln!("{line}")?;
            }
            let stopped = crate::interrupt::interrupted();
            if session.ended()
                || (live && (stopped || started.elapsed().as_secs_f64() >= args.seconds))
            {
                break;
            }
            if live && shown.elapsed() >= Duration::from_secs(1) {
                shown = Instant::now();
                outln!(
                    "{:.0} s: {}",
                    started.elapsed().as_secs_f64(),
                    session.counters()
                )?;
            }
            if n == 0 {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
    }
    for (w, name) in [
        (&mut up0, &names[0]),
        (&mut up1, &names[1]),
        (&mut up2, &names[2]),
    ] {
        w.flush().map_err(|e| {
            Failure::runtime(format!("cannot write {}: {e}", show(&out.path(name))))
        })?;
    }
    drop((up0, up1, up2));
    let counters = session.counters();
    outln!("{counters}")?;
    write_scopes(session.scope(), &out)?;
    let decoded = session.into_telemetry().finish();
    let why = match &decoded {
        Ok(d) if mostly_unusable(d).is_none() || args.accept_loss => None,
        Ok(d) => mostly_unusable(d).map(|w| format!("{w} (--accept-loss writes it anyway)")),
        Err(e) => Some(e.clone()),
    };
    if let (Ok(d), None) = (&decoded, &why) {
        d.log
            .write(&out.path(RUN_LOG))
            .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&log_path))))?;
    }
    out.commit()?;
    match (decoded, why) {
        (Ok(d), None) => {
            outln!("{}", counts(&d))?;
            report_written(&d, &log_path, "fpc-sim link capture")
        }
        (_, why) => Err(Failure::runtime(format!(
            "telemetry: {}; the files are written to {} without {RUN_LOG}",
            why.unwrap_or_default(),
            show(&args.out)
        ))),
    }
}

/// The scope recordings a capture received, each written into `out` as `scope-N.csv`
/// (and named), the incomplete ones named.
fn write_scopes(scope: &crate::link::scope::ScopeCollector, out: &OutDir) -> CmdResult {
    for line in scope.incomplete() {
        outln!("scope: {line}")?;
    }
    for rec in scope.recordings() {
        let name = format!("scope-{}.csv", rec.recording.id);
        match rec.to_log() {
            Ok(log) => {
                log.write(&out.path(&name)).map_err(|e| {
                    Failure::runtime(format!("cannot write {}: {e}", show(&out.path(&name))))
                })?;
                outln!(
                    "scope recording {} (trigger {}, {} samples, {} before it) written to {}",
                    rec.recording.id,
                    trigger_text(rec.recording.trigger),
                    rec.recording.samples,
                    rec.recording.pre,
                    show(&out.final_path(&name))
                )?;
            }
            Err(e) => outln!("scope: {e}")?,
        }
    }
    Ok(())
}

/// The answer timeout, checked.
fn timeout(ms: u64) -> Result<Duration, Failure> {
    if !(1..=60_000).contains(&ms) {
        return Err(Failure::bad_input(format!(
            "--timeout-ms {ms}: give 1 to 60000 ms"
        )));
    }
    Ok(Duration::from_millis(ms))
}

fn calibration(action: CalibrationAction) -> CmdResult {
    let mut earlier = Vec::new();
    match &action {
        CalibrationAction::Read {
            target,
            out,
            force,
            timeout_ms,
        } => {
            let timeout = timeout(*timeout_ms)?;
            let inputs: Vec<&Path> = target.replay.iter().map(PathBuf::as_path).collect();
            let file = OutFile::prepare(out, *force, &inputs)?;
            let mut channels = open(target)?;
            let bytes = read_calibration(&mut channels, timeout, |l| earlier.push(l));
            for line in earlier.drain(..) {
                outln!("{line}")?;
            }
            let bytes = bytes.map_err(Failure::runtime)?;
            let record = CalibrationRecord::decode(&bytes).map_err(|e| {
                Failure::runtime(format!(
                    "the board sent a record that does not decode: {e:?}"
                ))
            })?;
            let text = to_toml(&record, "read from the board over the link")
                .map_err(|e| Failure::runtime(format!("the board's calibration: {e}")))?;
            std::fs::write(file.path(), text).map_err(|e| {
                Failure::runtime(format!("cannot write {}: {e}", show(&file.final_path())))
            })?;
            let written = file.final_path();
            file.commit()?;
            outln!(
                "read the calibration record ({RECORD_BYTES} bytes); wrote {}",
                show(&written)
            )
        }
        CalibrationAction::Write {
            target,
            file,
            timeout_ms,
        } => {
            let timeout = timeout(*timeout_ms)?;
            let record = crate::calibration::read(file).map_err(Failure::bad_input)?;
            let mut channels = open(target)?;
            let done = write_calibration(&mut channels, &record.encode(), timeout, |l| {
                earlier.push(l)
            });
            for line in earlier.drain(..) {
                outln!("{line}")?;
            }
            done.map_err(Failure::runtime)?;
            outln!(
                "accepted: calibration write of {}: loaded, the machine must home again",
                show(file)
            )
        }
    }
}

fn send(args: SendArgs) -> CmdResult {
    timeout(args.timeout_ms)?;
    let command = args.command.command();
    let mut channels = open(&args.target)?;
    let mut earlier = Vec::new();
    if let Command::Bench { op, seconds } = command {
        let done = crate::link::bench::run(
            &mut channels,
            op,
            seconds,
            Duration::from_millis(args.timeout_ms),
            |line| earlier.push(line),
        );
        for line in earlier {
            outln!("{line}")?;
        }
        for line in done.map_err(Failure::runtime)? {
            outln!("{line}")?;
        }
        return Ok(());
    }
    if let Command::Calibrate { routine } = command {
        let done = crate::link::report::calibrate(
            &mut channels,
            routine,
            Duration::from_millis(args.timeout_ms),
            |line| earlier.push(line),
        );
        for line in earlier {
            outln!("{line}")?;
        }
        let (lines, error) = match done {
            Ok(lines) => (lines, None),
            Err((lines, e)) => (lines, Some(e)),
        };
        for line in lines {
            outln!("{line}")?;
        }
        return match error {
            None => Ok(()),
            Some(e) => Err(Failure::runtime(e)),
        };
    }
    let outcome = send_command(
        &mut channels,
        &command,
        Duration::from_millis(args.timeout_ms),
        |line| earlier.push(line),
    );
    for line in earlier {
        outln!("{line}")?;
    }
    let outcome = outcome.map_err(Failure::runtime)?;
    match outcome {
        Outcome::Reply(r) if r.result.is_ok() => outln!("{}", outcome_text(&outcome)),
        _ => Err(Failure::runtime(outcome_text(&outcome))),
    }
}
