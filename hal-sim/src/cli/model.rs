//! `fpc-sim model`: the built-in reference machine as a model file, with the comment on every
//! value saying where it comes from — the file to start a machine of your own from
//! (`fpc-sim model > my-machine.toml`). Every key and its range: `docs/formats.md` §2.

use clap::Args;

use crate::failure::{CmdResult, Failure};
use crate::outln;
use crate::plant::model::REFERENCE_TOML;

/// Print the built-in reference machine model, with its comments.
#[derive(Args, Debug)]
pub struct ModelArgs {
    /// The reference machine (the default and, for now, the only model built in).
    #[arg(long)]
    pub reference: bool,
    /// Print the model as one JSON object (the same keys and values, without the comments).
    #[arg(long)]
    pub json: bool,
}

/// Runs `fpc-sim model`.
pub fn main(args: ModelArgs) -> CmdResult {
    if args.json {
        let value: toml::Value = REFERENCE_TOML
            .parse()
            .map_err(|e: toml::de::Error| Failure::runtime(e.to_string()))?;
        let text =
            serde_json::to_string_pretty(&value).map_err(|e| Failure::runtime(e.to_string()))?;
        return outln!("{text}");
    }
    outln!("{}", REFERENCE_TOML.trim_end())
}
