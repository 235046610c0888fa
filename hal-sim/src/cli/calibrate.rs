//! `fpc-sim calibrate`: commissions the simulated machine as on a new one — the firmware's
//! control step runs its Calibrate routines (current sense, alignment, homing, misalignment,
//! cogging) on the model's plant, knowing only its machine parameters — and writes the
//! record the firmware would save to flash, as a calibration file (TOML, readable and
//! diffable) that `fpc-sim run --calibration` loads.

use std::path::PathBuf;

use clap::Args;
use serde::Serialize;

use crate::calibration::{commission, to_toml, Stage};
use crate::failure::{CmdResult, Failure};
use crate::output::{show, OutFile};
use crate::plant::model::MachineModel;
use crate::{errln, outln};

/// Commission the simulated machine and write its calibration file.
#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// Machine-model TOML (default: the embedded reference machine).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// The calibration file to write.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Noise seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Replace an existing file.
    #[arg(long)]
    pub force: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct Summary<'a> {
    out: String,
    stages: &'a [Stage],
    sim_time_s: f64,
}

/// Runs `fpc-sim calibrate`.
pub fn main(args: CalibrateArgs) -> CmdResult {
    let (model, name) = match &args.model {
        Some(path) => (
            MachineModel::read(path).map_err(|e| Failure::bad_input(e.0))?,
            path.display().to_string(),
        ),
        None => (MachineModel::reference(), "reference".to_string()),
    };
    let inputs: Vec<&std::path::Path> = args.model.iter().map(PathBuf::as_path).collect();
    let out = OutFile::prepare(&args.out, args.force, &inputs)?;
    let (record, stages) = commission(&model, args.seed).map_err(Failure::runtime)?;
    let text = to_toml(
        &record,
        &format!(
            "simulated commissioning of model {name}, seed {}",
            args.seed
        ),
    )
    .map_err(Failure::runtime)?;
    std::fs::write(out.path(), text)
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&out.final_path()))))?;
    let final_path = out.final_path();
    out.commit()?;
    let sim_time_s: f64 = stages.iter().map(|s| s.duration_s).sum();
    let each = stages
        .iter()
        .map(|s| format!("{} {:.2} s", s.name, s.duration_s))
        .collect::<Vec<_>>()
        .join(", ");
    errln!(
        "fpc-sim calibrate: {each} ({sim_time_s:.2} s simulated); wrote {}",
        show(&final_path)
    )?;
    if args.json {
        let summary = Summary {
            out: final_path.display().to_string(),
            stages: &stages,
            sim_time_s,
        };
        let text =
            serde_json::to_string_pretty(&summary).map_err(|e| Failure::runtime(e.to_string()))?;
        outln!("{text}")?;
    }
    Ok(())
}
