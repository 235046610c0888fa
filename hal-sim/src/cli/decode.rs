//! `fpc-sim decode`: a captured telemetry stream (the raw bytes of the RTT telemetry
//! up-channel, or `fpc-sim run --telemetry FILE`) to a run-log CSV.
//!
//! Frames that fail framing or CRC are rejected and counted; the log holds the longest run
//! of frames without a gap in their sequence numbers (a run log must be uniformly sampled),
//! and what was left out is reported.

use std::path::PathBuf;

use clap::Args;

use crate::board::capture::decode_capture;
use crate::cli::analysis::progress;
use crate::failure::{CmdResult, Failure};
use crate::runlog::MIN_ROWS;

/// Decode a telemetry capture into a run log.
#[derive(Args, Debug)]
pub struct DecodeArgs {
    /// The capture: raw bytes of the telemetry up-channel.
    #[arg(long)]
    pub capture: PathBuf,
    /// The run-log CSV to write.
    #[arg(long, default_value = "decoded.csv")]
    pub out: PathBuf,
}

/// Runs `fpc-sim decode`.
pub fn main(args: DecodeArgs) -> CmdResult {
    let bytes = std::fs::read(&args.capture)
        .map_err(|e| Failure::bad_input(format!("cannot read {}: {e}", args.capture.display())))?;
    let bar = progress(bytes.len() as u64, "decoding");
    let decoded = decode_capture(&bytes, |done| bar.set_position(done as u64))
        .map_err(|e| Failure::bad_input(format!("{}: {e}", args.capture.display())));
    bar.finish_and_clear();
    let d = decoded?;
    d.log
        .write(&args.out)
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", args.out.display())))?;
    let span_s = match (
        d.log.column("t_s").and_then(|t| t.first()),
        d.log.column("t_s").and_then(|t| t.last()),
    ) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    };
    println!(
        "frames accepted {}, rejected {}, gaps {}, left out {}, dropped by the firmware {}",
        d.stats.accepted, d.stats.rejected, d.gaps, d.left_out, d.dropped
    );
    println!(
        "decimation {} control cycles per frame; wrote {} rows over {span_s:.4} s to {}",
        d.decimation,
        d.log.len(),
        args.out.display()
    );
    if d.log.len() < MIN_ROWS {
        eprintln!(
            "fpc-sim decode: warning: {} rows; run-log readers need at least {MIN_ROWS}",
            d.log.len()
        );
    }
    Ok(())
}
