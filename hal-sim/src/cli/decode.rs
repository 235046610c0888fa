//! `fpc-sim decode`: a captured telemetry stream (the raw bytes of the RTT telemetry
//! up-channel, or `fpc-sim run --telemetry FILE`) to a run-log CSV — or, given the reply
//! channel's capture (up2.bin), a scope recording to a 20 kHz run log.
//!
//! Frames that fail framing or CRC are rejected and counted; the log holds the longest run
//! of frames without a gap in their sequence numbers, at one rate, with one channel set and
//! one declaration of the ports (a run log must be uniformly sampled), and what was left
//! out is reported. The log carries the metadata `fpc-sim gap` reads: the rate, `ports`
//! (and `ports_from_s`) from the ports the operator declared, `theta_source` and
//! `force_delay_s` from the firmware's frame layout. A capture of another firmware's layout
//! is refused with a message saying so.

use std::path::{Path, PathBuf};

use clap::Args;

use crate::board::capture::{decode_stream, Decoded};
use crate::cli::analysis::progress;
use crate::failure::{CmdResult, Failure};
use crate::link::scope::{decode_scope_capture, trigger_text};
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
    #[arg(long, default_value = "out/decode/decoded.csv")]
    pub out: PathBuf,
    /// Print what was decoded as one JSON object (instead of the lines).
    #[arg(long)]
    pub json: bool,
    /// Replace an existing output file (never the capture itself).
    #[arg(long)]
    pub force: bool,
    /// Write the longest gap-free stretch even when it holds less than half of the frames
    /// received (by default such a capture is refused as mostly unusable).
    #[arg(long)]
    pub accept_loss: bool,
    /// Of a capture holding several scope recordings, the one to write (by number, as
    /// `link capture` names them); by default the last whole one.
    #[arg(long, value_name = "N")]
    pub recording: Option<u8>,
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
    });
    bar.finish_and_clear();
    let d = match decoded {
        Ok(d) => d,
        // No telemetry: the reply channel's capture may hold scope recordings.
        Err(e) if e.starts_with("no telemetry frame") => return scope(&args, out, &e),
        Err(e) => return Err(Failure::bad_input(format!("{}: {e}", show(&args.capture)))),
    };
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
    if args.json {
        return outln!("{}", decoded_json(&d, &args.out)?);
    }
    outln!("{}", counts(&d))?;
    report_written(&d, &args.out, "fpc-sim decode")
}

/// What `decode --json` prints for a telemetry capture.
fn decoded_json(d: &Decoded, out: &Path) -> Result<String, Failure> {
    let t = d.log.column("t_s").unwrap_or_default();
    let span_s = match (t.first(), t.last()) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    };
    let json = serde_json::json!({
        "frames_accepted": d.stats.accepted,
        "frames_rejected": d.stats.rejected,
        "repeated": d.duplicates,
        "gaps": d.gaps,
        "left_out": d.left_out,
        "dropped_by_the_firmware": d.dropped,
        "decimation": d.decimation,
        "rows": d.log.len(),
        "span_s": span_s,
        "sample_rate_hz": d.log.meta("sample_rate_hz").and_then(|v| v.parse::<f64>().ok()),
        "ports": d.log.meta("ports"),
        "ports_from_s": d.log.meta("ports_from_s").and_then(|v| v.parse::<f64>().ok()),
        "out": out.display().to_string(),
    });
    serde_json::to_string(&json).map_err(|e| Failure::runtime(e.to_string()))
}

/// The scope recording of a reply-channel capture, written as a run log.
fn scope(args: &DecodeArgs, out: OutFile, no_telemetry: &str) -> CmdResult {
    let bytes = std::fs::read(&args.capture)
        .map_err(|e| Failure::bad_input(format!("cannot read {}: {e}", show(&args.capture))))?;
    let (recordings, incomplete) = decode_scope_capture(&bytes);
    for line in &incomplete {
        errln!("fpc-sim decode: {line}")?;
    }
    let chosen = match args.recording {
        Some(id) => recordings.iter().find(|r| r.recording.id == id),
        None => recordings.last(),
    };
    let Some(rec) = chosen else {
        let found: Vec<String> = recordings
            .iter()
            .map(|r| r.recording.id.to_string())
            .collect();
        return Err(Failure::bad_input(format!(
            "{}: {}; and {}",
            show(&args.capture),
            no_telemetry,
            match (args.recording, found.is_empty()) {
                (Some(id), false) =>
                    format!("no scope recording {id} (whole ones: {})", found.join(", ")),
                _ if incomplete.is_empty() => "no scope recording".to_string(),
                _ => "no whole scope recording".to_string(),
            }
        )));
    };
    let log = rec
        .to_log()
        .map_err(|e| Failure::bad_input(format!("{}: {e}", show(&args.capture))))?;
    log.write(&out.path())
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&args.out))))?;
    out.commit()?;
    let r = &rec.recording;
    if args.json {
        let json = serde_json::json!({
            "scope_recording": r.id,
            "whole_recordings": recordings.len(),
            "trigger": trigger_text(r.trigger),
            "samples": r.samples,
            "pre": r.pre,
            "sample_rate_hz": 20000,
            "ports": r.ports.name(),
            "clipped": rec.clipped(),
            "out": args.out.display().to_string(),
        });
        return outln!("{json}");
    }
    outln!(
        "scope recording {} of {} whole: trigger {}, {} samples at 20000 Hz ({} before the \
         trigger), ports {}{}; wrote {}",
        r.id,
        recordings.len(),
        trigger_text(r.trigger),
        r.samples,
        r.pre,
        r.ports.name(),
        match rec.clipped() {
            0 => String::new(),
            n => format!("; {n} samples clipped at a code's limit"),
        },
        args.out.display()
    )
}

/// The counts of a decoded capture, as one line: accepted, rejected, repeated, gaps, left
/// out, dropped by the firmware.
pub fn counts(d: &Decoded) -> String {
    let older = match d.layout_1 {
        0 => String::new(),
        n => format!(" ({n} of another firmware's layout 1)"),
    };
    format!(
        "frames accepted {}, rejected {}{older} (framing or CRC), repeated {}, gaps {}, left out \
         of the log {}, dropped by the firmware {}",
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
    let meta = |k: &str| d.log.meta(k).unwrap_or("-").to_string();
    outln!(
        "metadata: sample_rate_hz {}, ports {}{}, theta_source {}, force_delay_s {}",
        meta("sample_rate_hz"),
        meta("ports"),
        d.log
            .meta("ports_from_s")
            .map_or(String::new(), |t| format!(" from {t} s")),
        meta("theta_source"),
        meta("force_delay_s")
    )?;
    if d.log.len() < MIN_ROWS {
        errln!(
            "{tool}: warning: {} rows; run-log readers need at least {MIN_ROWS}",
            d.log.len()
        )?;
    }
    Ok(())
}
