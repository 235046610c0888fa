//! `fpc-sim calibrate`: commissions the simulated machine as on a new one — the firmware's
//! control step runs its Calibrate routines (current sense, alignment, homing, misalignment,
//! cogging) on the model's plant, knowing only its machine parameters — and writes the
//! record the firmware would save to flash, as a calibration file (TOML, readable and
//! diffable) that `fpc-sim run --calibration` loads. `--check-wiring` runs the
//! commissioning alone (current sense, then phase order, encoder direction and pitch of
//! each section) on a machine wired as `--swap-phases` and `--reverse-encoder` say, and
//! prints what it found.

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use fpc::units::Section;
use serde::Serialize;

use crate::board::wiring::Wiring;
use crate::calibration::{check_wiring, commission, commission_lines, to_toml, Stage};
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
    #[arg(long, value_name = "FILE", required_unless_present = "check_wiring")]
    pub out: Option<PathBuf>,
    /// Check the wiring only: current sense, then the `commission` routine (phase order,
    /// encoder direction, pitch of each section) with the piston at mid-travel; prints what
    /// it found and writes no file.
    #[arg(long, conflicts_with_all = ["out", "json", "force"])]
    pub check_wiring: bool,
    /// Wire this section's motor leads b and c swapped (with --check-wiring; repeatable).
    #[arg(long, value_enum, value_name = "SECTION", requires = "check_wiring")]
    pub swap_phases: Vec<SectionArg>,
    /// Wire this section's encoder with sin and cos swapped, so it reads backwards (with
    /// --check-wiring; repeatable).
    #[arg(long, value_enum, value_name = "SECTION", requires = "check_wiring")]
    pub reverse_encoder: Vec<SectionArg>,
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

/// A motor section, as typed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SectionArg {
    /// The master section (and its encoder).
    Master,
    /// The slave section (and its encoder).
    Slave,
}

impl SectionArg {
    fn section(self) -> Section {
        match self {
            SectionArg::Master => Section::Master,
            SectionArg::Slave => Section::Slave,
        }
    }
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
    if args.check_wiring {
        return wiring(&args, &model);
    }
    let Some(out_path) = &args.out else {
        return Err(Failure::bad_input("give --out FILE (or --check-wiring)"));
    };
    let inputs: Vec<&std::path::Path> = args.model.iter().map(PathBuf::as_path).collect();
    let out = OutFile::prepare(out_path, args.force, &inputs)?;
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

/// `--check-wiring`: the commissioning on the machine wired as the flags say; its findings
/// on stdout, a line each.
fn wiring(args: &CalibrateArgs, model: &MachineModel) -> CmdResult {
    let mut wiring = Wiring::default();
    for s in &args.swap_phases {
        *wiring.swapped_phases.get_mut(s.section()) = true;
    }
    for s in &args.reverse_encoder {
        *wiring.reversed_encoder.get_mut(s.section()) = true;
    }
    let start_m = 0.5 * model.piston.travel_m;
    let (found, stages) =
        check_wiring(model, &wiring, args.seed, start_m).map_err(Failure::runtime)?;
    let config = crate::run::control_config(model);
    for line in commission_lines(&found, &config) {
        outln!("{line}")?;
    }
    let each = stages
        .iter()
        .map(|s| format!("{} {:.2} s", s.name, s.duration_s))
        .collect::<Vec<_>>()
        .join(", ");
    errln!("fpc-sim calibrate: {each} (simulated)")?;
    Ok(())
}
