//! `fpc-sim gap` (`docs/formats.md` §3): compares a model with a measured run, names the missing
//! effect(s), fits them, writes the augmented model and a report, and with `--json` prints
//! the summary. Everything is checked before anything is written: a bad model file or log is
//! exit 2 with one line naming the key, or the line and column (`docs/faults.md` #17–18).

use std::path::PathBuf;

use clap::Args;

use crate::cli::analysis::read_log;
use crate::failure::{CmdResult, Failure};
use crate::gap::{analyse_log, report, GapOptions, DEFAULT_BAND_HZ};
use crate::output::OutDir;
use crate::plant::model::MachineModel;
use crate::{errln, outln};

/// What the measured log must be, and how one comes from the board.
const GAP_HELP: &str = "\
The measured run: a run log (docs/formats.md §1) sampled uniformly at 2000 Hz to 1 MHz (gap's
differentiator spans 2 ms and needs 5 samples in it), at least 4 differentiator windows long.
Its metadata are read as they are: `ports` (open, closed; absent: the pressures are not
compared) and `ports_from_s`, `theta_source`, `force_delay_s` (absent: the forces'
alignment is fitted).

From the board, with no edits: the firmware streams 2000 Hz by default (or
`fpc-sim link telemetry --rate 5000`); `fpc-sim link ports timed|sealed` when the ports change;
`fpc-sim link capture --out rig-run`, then `fpc-sim gap --model M --measured rig-run/run.csv`.
From the simulator: `fpc-sim run --telemetry up1.bin` (2000 Hz by default), then
`fpc-sim decode --capture up1.bin --out dec.csv`. Walkthrough: docs/rig-to-model.md.";

/// Find, name and add the effect missing from a model.
#[derive(Args, Debug)]
#[command(after_help = GAP_HELP)]
pub struct GapArgs {
    /// The model to check (machine-model TOML; default: the built-in reference machine,
    /// `fpc-sim model` prints it).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// The measured run (run-log CSV, sampled at 2000 Hz or faster).
    #[arg(long)]
    pub measured: PathBuf,
    /// Output directory: model.toml, report.md, plots, gap.json.
    #[arg(long, default_value = "out/gap")]
    pub out: PathBuf,
    /// Print the JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
    /// Upper edge of the analysis band, Hz.
    #[arg(long, default_value_t = DEFAULT_BAND_HZ)]
    pub band_hz: f64,
    /// Replace the files of an earlier analysis in the output directory (never an input,
    /// such as the model read).
    #[arg(long)]
    pub force: bool,
}

/// Refuses a log sampled slower than the workflow analyses, saying what would work.
fn refuse_slow_log(log: &crate::runlog::RunLog, path: &std::path::Path) -> Result<(), Failure> {
    use crate::gap::data::MIN_SAMPLE_RATE_HZ;
    let Some(dt) = log.sample_time_s().filter(|dt| *dt > 0.0) else {
        return Ok(());
    };
    let rate = 1.0 / dt;
    // The reader's own tolerance on the rate (1 %), so a log at the limit passes.
    if rate >= 0.99 * MIN_SAMPLE_RATE_HZ {
        return Ok(());
    }
    Err(Failure::bad_input(format!(
        "{}: sampled at {}, below the {} gap analyses (its differentiator spans 2 ms and \
         needs 5 samples in it); log at {} or faster: `fpc-sim run --log-rate 2000` (or \
         10000, 20000), `fpc-sim link telemetry --rate 2000` on the board, or a rig logger \
         set to 2 kHz or more. `fpc-sim lag`, `filters` and `pv` read this log as it is",
        crate::output::show(path),
        crate::console::eng(rate, "Hz"),
        crate::console::eng(MIN_SAMPLE_RATE_HZ, "Hz"),
        crate::console::eng(MIN_SAMPLE_RATE_HZ, "Hz")
    )))
}

/// Runs `fpc-sim gap`.
pub fn main(args: GapArgs) -> CmdResult {
    let mut inputs = vec![args.measured.as_path()];
    inputs.extend(args.model.as_deref());
    let out = OutDir::prepare(
        &args.out,
        &["model.toml", "report.md", "report.html", "gap.json"],
        args.force,
        &inputs,
    )?;
    // The model is validated by the model reader (naming the key), then kept as text so the
    // augmented file keeps every key the input had.
    let text = match &args.model {
        Some(path) => {
            MachineModel::read(path).map_err(|e| Failure::bad_input(e.0))?;
            std::fs::read_to_string(path)
                .map_err(|e| Failure::bad_input(format!("cannot read {}: {e}", path.display())))?
        }
        None => crate::plant::model::REFERENCE_TOML.to_string(),
    };
    let log = read_log(&args.measured)?;
    refuse_slow_log(&log, &args.measured)?;
    let opts = GapOptions {
        band_hz: args.band_hz,
    };
    let mut outcome = analyse_log(&text, log, &opts).map_err(|f| Failure {
        code: f.code,
        message: format!("{}: {}", args.measured.display(), f.message),
    })?;
    let model_out = out.final_path("model.toml");
    std::fs::write(out.path("model.toml"), &outcome.model_text)
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", model_out.display())))?;
    outcome.json.model_out = model_out.display().to_string();
    report::write(out.staging_dir(), &outcome).map_err(Failure::runtime)?;
    let json =
        serde_json::to_string_pretty(&outcome.json).map_err(|e| Failure::runtime(e.to_string()))?;
    std::fs::write(out.path("gap.json"), &json)
        .map_err(|e| Failure::runtime(format!("cannot write gap.json: {e}")))?;
    let report_out = out.final_path("report.md");
    out.commit()?;
    // Each warning once (a pair of effects is one warning, whichever order found it).
    let mut said: Vec<&String> = Vec::new();
    for w in &outcome.json.warnings {
        if !said.contains(&w) {
            errln!("fpc-sim gap: warning: {w}")?;
            said.push(w);
        }
    }
    let mut names: Vec<String> = outcome
        .json
        .effects
        .iter()
        .map(|e| e.name.clone())
        .collect();
    for d in &outcome.json.discovered {
        names.push(format!("discovered terms ({})", d.reading));
    }
    let shrink: Vec<String> = outcome
        .json
        .channels
        .iter()
        .map(|c| {
            format!(
                "{} {} → {}",
                c.name,
                crate::console::eng(c.rms_before, &c.unit),
                crate::console::eng(c.rms_after, &c.unit)
            )
        })
        .collect();
    errln!(
        "fpc-sim gap: {}; residual RMS {}; wrote {} and {}",
        if names.is_empty() {
            "nothing significant is missing".to_string()
        } else {
            format!("added {}", names.join(", "))
        },
        shrink.join(", "),
        model_out.display(),
        report_out.display()
    )?;
    let left: Vec<String> = outcome
        .unexplained
        .iter()
        .map(|u| crate::gap::unexplained::sentence(u, u.channel.unit()))
        .collect();
    if !left.is_empty() {
        errln!("fpc-sim gap: {}", left.join("; "))?;
    }
    if args.json {
        outln!("{json}")?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::GAP_HELP;
    use crate::gap::data::MIN_SAMPLE_RATE_HZ;
    use fpc::link::telemetry::{CONTROL_PERIOD_US, DEFAULT_DECIMATION};

    #[test]
    fn the_help_states_the_slowest_rate_the_reader_takes_and_the_firmware_offers_it() {
        assert!(GAP_HELP.contains(&format!("sampled uniformly at {MIN_SAMPLE_RATE_HZ} Hz")));
        let firmware_hz = 1e6 / f64::from(CONTROL_PERIOD_US * u32::from(DEFAULT_DECIMATION));
        assert_eq!(firmware_hz, MIN_SAMPLE_RATE_HZ);
    }
}
