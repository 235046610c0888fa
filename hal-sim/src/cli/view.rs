//! `fpc-sim view`: the bench console in the browser ([`crate::view`]).

use std::path::PathBuf;

use clap::Args;

use crate::failure::{num, CmdResult, Failure};
use crate::outln;
use crate::view::feed::Source;
use crate::view::{serve, ViewOptions};

const VIEW_HELP: &str = "\
Open the address it prints in a browser on this machine (it listens on 127.0.0.1 only):

    fpc-sim view                                  the simulated board, reference machine
    fpc-sim view --model my-machine.toml          another machine
    fpc-sim view --replay rig-run                 a recorded session (a capture directory)
    fpc-sim view --probe                          the board (fpc-sim built with `probe`)

The page shows, live: position and its reference, both sections' forces, both chamber
pressures, the rotation angle, the mode, faults (in red), the scope's window when it fires,
the frame rate and how far the display lags the stream. Its controls send the link's
commands: home, calibrate, start (pressure ratio, speed, compressor or expander), stop,
clear faults, telemetry rate and channels, scope arm and fire. Record writes the stream to
--out as DIR/rec-N/ (up0.bin, up1.bin, up2.bin, run.csv): `fpc-sim decode`, `gap` and
`view --replay` read it. A replay answers the controls from its recording, as
`fpc-sim link send --replay` does. Ctrl-C ends the console (a recording in progress is
written).";

/// The bench console: live plots and controls in the browser.
#[derive(Args, Debug)]
#[command(after_help = VIEW_HELP)]
pub struct ViewArgs {
    /// Machine model of the simulated board (default: the reference machine).
    #[arg(long, conflicts_with_all = ["replay", "probe"])]
    pub model: Option<PathBuf>,
    /// Noise seed of the simulated board.
    #[arg(long, default_value_t = 1, conflicts_with_all = ["replay", "probe"])]
    pub seed: u64,
    /// Play a recorded session (a capture directory: up0.bin, up1.bin, up2.bin) at the pace
    /// it was recorded, again from its start when it ends.
    #[arg(long, value_name = "DIR", conflicts_with = "probe")]
    pub replay: Option<PathBuf>,
    /// The board through the debug probe (the link's transport; needs fpc-sim built with the
    /// `probe` feature). VID:PID[:SN] chooses among several probes.
    #[arg(long, value_name = "VID:PID[:SN]", num_args = 0..=1, default_missing_value = "")]
    pub probe: Option<String>,
    /// With --probe: the firmware ELF that runs on the board (finds the RTT block).
    #[arg(long, value_name = "FILE", requires = "probe")]
    pub elf: Option<PathBuf>,
    /// With --probe: the chip (probe-rs name).
    #[arg(long, default_value = crate::link::CHIP)]
    pub chip: String,
    /// Port on 127.0.0.1 (0: any free port; the address is printed).
    #[arg(long, default_value_t = 8046)]
    pub port: u16,
    /// Where recordings go: DIR/rec-1/, DIR/rec-2/, …
    #[arg(long, value_name = "DIR", default_value = "out/view")]
    pub out: PathBuf,
    /// End after this many seconds (default: at Ctrl-C).
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
}

/// Runs `fpc-sim view`.
pub fn main(args: ViewArgs) -> CmdResult {
    if let Some(s) = args.seconds.filter(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(Failure::bad_input(format!(
            "--seconds {}: give a duration above 0 s",
            num(s)
        )));
    }
    let source = match (&args.replay, &args.probe) {
        (Some(dir), _) => {
            // Refused before the server starts: a directory without a recording.
            crate::link::Replay::from_dir(dir).map_err(Failure::bad_input)?;
            Source::Replay { dir: dir.clone() }
        }
        (None, Some(selector)) => probe_source(&args, selector)?,
        (None, None) => {
            let (model, model_name) = match &args.model {
                Some(path) => (
                    crate::plant::model::MachineModel::read(path)
                        .map_err(|e| Failure::bad_input(e.0))?,
                    path.display().to_string(),
                ),
                None => (
                    crate::plant::model::MachineModel::reference(),
                    "reference".to_string(),
                ),
            };
            Source::Sim {
                model: Box::new(model),
                model_name,
                seed: args.seed,
            }
        }
    };
    // Ctrl-C ends the console, which then writes a recording in progress.
    crate::interrupt::catch();
    serve(
        ViewOptions {
            source,
            port: args.port,
            out: args.out.clone(),
            seconds: args.seconds,
            version: super::VERSION,
        },
        |addr, what| outln!("fpc-sim view: http://{addr}/ — {what} (Ctrl-C ends)"),
    )
}

#[cfg(feature = "probe")]
fn probe_source(args: &ViewArgs, selector: &str) -> Result<Source, Failure> {
    let probe = if selector.is_empty() {
        None
    } else {
        Some(
            super::link::probe_selector(selector)
                .map_err(|e| Failure::bad_input(format!("--probe {e}")))?,
        )
    };
    let options = crate::link::probe::ProbeOptions {
        chip: args.chip.clone(),
        probe,
        speed_khz: None,
        connect_under_reset: false,
    };
    // Attached before the server starts: no probe, no board or no firmware is one error
    // naming what is missing, with nothing started and nothing written.
    let channels = crate::link::probe::attach(&options, args.elf.as_deref())
        .map_err(|e| Failure::runtime(format!("--probe: {e}")))?;
    Ok(Source::Probe(crate::view::feed::LiveLink {
        what: format!("board {} through the probe", options.chip),
        open: Box::new(move || Ok(Box::new(channels) as Box<dyn crate::link::Channels>)),
    }))
}

#[cfg(not(feature = "probe"))]
fn probe_source(_args: &ViewArgs, _selector: &str) -> Result<Source, Failure> {
    Err(Failure::bad_input(
        "--probe: this fpc-sim was built without the `probe` feature, so it cannot attach to a \
         board (rebuild: cargo install --path hal-sim --features probe); --replay DIR plays a \
         recorded session",
    ))
}

#[cfg(test)]
mod tests {
    /// `--probe` on an fpc-sim that cannot reach a probe: one error naming what is missing
    /// (here the `probe` feature; with it, the probe, board or firmware `attach` did not
    /// find), exit 2, before the server starts — no folder made, nothing written.
    #[cfg(not(feature = "probe"))]
    #[test]
    fn probe_without_a_way_to_the_board_is_one_error_and_changes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("console");
        let out_text = out.to_str().unwrap();
        let (code, text) = crate::console::captured(|| {
            crate::cli::execute([
                "fpc-sim", "view", "--probe", "--out", out_text, "--port", "0",
            ])
        });
        assert_eq!(code, 2, "{text}");
        assert!(!out.exists(), "{text}");
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 1, "{text}");
        assert!(
            lines[0].contains("--probe") && lines[0].contains("`probe` feature"),
            "{text}"
        );
    }
}
