//! `fpc-sim decode`: a captured telemetry stream (the raw bytes of the RTT telemetry
//! up-channel, or `fpc-sim run --telemetry FILE`) to a run-log CSV.
//!
//! Frames that fail framing or CRC are rejected and counted; the log holds the longest run
//! of frames without a gap in their sequence numbers (a run log must be uniformly sampled),
//! and what was left out is reported.

use std::path::{Path, PathBuf};

use clap::Args;

use crate::board::capture::{decode_stream, Decoded};
use crate::cli::analysis::progress;
use crate::failure::{CmdResult, Failure};
use crate::output::{show, OutFile};
use crate::runlog::MIN_ROWS;
use crate::{errln, outln};

/// Decode a telemetry capture into a run log.
#[derive(Args, Debug)]
pub struct DecodeArgs {
    /// The capture: raw bytes of the telemetry up-channel.
    #[arg(long)]
    pub capture: PathBuf,
    /// The run-log CSV to write.
    #[arg(long, default_value = "decoded.csv")]
    pub out: PathBuf,
    /// Replace an existing output file (never the capture itself).
    #[arg(long)]
    pub force: bool,
    /// Write the longest gap-free stretch even when it holds less than half of the frames
    /// received (by default such a capture is refused as mostly unusable).
    #[arg(long)]
    pub accept_loss: bool,
}

/// Runs `fpc-sim decode`.
pub fn main(args: DecodeArgs) -> CmdResult {
    let out = OutFile::prepare(&args.out, args.force, &[args.capture.as_path()])?;
    let file = std::fs::File::open(&args.capture)
        .map_err(|e| Failure::bad_input(format!("cannot read {}: {e}", show(&args.capture))))?;
    let len = file.metadata().map_or(0, |m| m.len());
    let bar = progress(len, "decoding");
    let decoded = decode_stream(std::io::BufReader::new(file), |done| {
        bar.set_position(done as u64)
    })
    .map_err(|e| Failure::bad_input(format!("{}: {e}", show(&args.capture))));
    bar.finish_and_clear();
    let d = decoded?;
    if let Some(why) = mostly_unusable(&d) {
        if !args.accept_loss {
            return Err(Failure::bad_input(format!(
                "{}: {why}; nothing written (--accept-loss writes that stretch anyway)",
                show(&args.capture)
            )));
        }
    }
    d.log
        .write(&out.path())
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&args.out))))?;
    out.commit()?;
    outln!("{}", counts(&d))?;
    report_written(&d, &args.out, "fpc-sim decode")
}

/// The counts of a decoded capture, as one line: accepted, rejected, repeated, gaps, left
/// out, dropped by the firmware.
pub fn counts(d: &Decoded) -> String {
    format!(
        "frames accepted {}, rejected {} (framing or CRC), repeated {}, gaps {}, left out of the \
         log {}, dropped by the firmware {}",
        d.stats.accepted, d.stats.rejected, d.duplicates, d.gaps, d.left_out, d.dropped
    )
}

/// Why a decoded capture is mostly unusable (its longest gap-free stretch holds less than
/// half of the frames received), if it is.
pub fn mostly_unusable(d: &Decoded) -> Option<String> {
    let received = d.log.len() + d.left_out;
    (2 * d.log.len() < received).then(|| {
        format!(
            "mostly unusable: the longest gap-free stretch holds {} of {received} frames \
             ({:.1} %); {}",
            d.log.len(),
            100.0 * d.log.len() as f64 / received.max(1) as f64,
            counts(d)
        )
    })
}

/// Prints what was written: decimation, rows, span and where; warns (as `tool`) when the
/// log is shorter than run-log readers accept.
pub fn report_written(d: &Decoded, out: &Path, tool: &str) -> CmdResult {
    let received = d.log.len() + d.left_out;
    let span_s = match (
        d.log.column("t_s").and_then(|t| t.first()),
        d.log.column("t_s").and_then(|t| t.last()),
    ) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    };
    outln!(
        "decimation {} control cycles per frame; wrote {} rows ({:.1} % of the frames) over \
         {span_s:.4} s to {}",
        d.decimation,
        d.log.len(),
        100.0 * d.log.len() as f64 / received.max(1) as f64,
        out.display()
    )?;
    if d.log.len() < MIN_ROWS {
        errln!(
            "{tool}: warning: {} rows; run-log readers need at least {MIN_ROWS}",
            d.log.len()
        )?;
    }
    Ok(())
}
