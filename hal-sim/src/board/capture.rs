//! Telemetry in the simulator: the sink the firmware's telemetry task writes to, and the
//! decoding of a capture (from the simulator or from the rig's RTT channel) into a run log.
//!
//! The simulated board's sink is the RTT up-channel with a host that always keeps up: it
//! takes every byte into [`TelemetryCapture::bytes`]. The bytes are exactly what the
//! board would send, so `fpc-sim decode` reads both alike.

use fpc::link::frame::LinkStats;
use fpc::link::telemetry::{Frame, TelemetryDecoder};
use fpc::ports::FrameSink;

use crate::board::world::WorldRef;
use crate::runlog::{RunLog, REQUIRED};

/// Telemetry of a simulated run: the rate it was asked for and the bytes sent.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TelemetryCapture {
    /// One frame every this many control cycles; 0 = telemetry off (the default: a long
    /// run at full rate would hold 1.1 MB per simulated second).
    pub decimation: u16,
    /// Everything the telemetry task wrote to the up-channel.
    pub bytes: Vec<u8>,
}

/// The simulated RTT telemetry up-channel.
pub struct SimTelemetrySink {
    world: WorldRef,
}

impl FrameSink for SimTelemetrySink {
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.world
            .borrow_mut()
            .telemetry
            .bytes
            .extend_from_slice(bytes);
        bytes.len()
    }
}

/// The telemetry sink of `world`.
pub fn telemetry_sink(world: &WorldRef) -> SimTelemetrySink {
    SimTelemetrySink {
        world: world.clone(),
    }
}

/// Columns of a decoded capture: what a frame carries, named as in the simulator's run
/// log, then the mode number (`fpc::link::telemetry::mode_code`).
pub fn decoded_columns() -> Vec<&'static str> {
    REQUIRED
        .iter()
        .copied()
        .chain(["x_ref_m", "theta_ref_rad", "v_mps", "fault", "mode"])
        .collect()
}

/// A decoded capture.
#[derive(Clone, Debug)]
pub struct Decoded {
    /// The run log: the longest run of frames without a gap.
    pub log: RunLog,
    /// Frames accepted and rejected by the decoder.
    pub stats: LinkStats,
    /// Sequence steps other than the decimation (frames lost after the queue).
    pub gaps: usize,
    /// Accepted frames left out of the log because they lie outside its gap-free run.
    pub left_out: usize,
    /// Frames not later than the frame before them (repeats, replayed pieces), left out.
    pub duplicates: usize,
    /// The dropped-frame counter of the last frame (frames the firmware could not send).
    pub dropped: u16,
    /// Control cycles per frame, from the sequence numbers.
    pub decimation: u32,
}

/// Decodes a telemetry capture. `progress` is told how many bytes have been read.
pub fn decode_capture(bytes: &[u8], progress: impl FnMut(usize)) -> Result<Decoded, String> {
    decode_stream(bytes, progress)
}

/// Incremental decoding of a telemetry stream: bytes in as they arrive, frames kept, and
/// the counters a live display shows; [`FrameCollector::finish`] turns what was collected
/// into the run log. [`decode_stream`] (`fpc-sim decode`) and the host link
/// (`fpc-sim link capture`) both use it, so a live capture and a decoded file give the same
/// log.
#[derive(Clone, Debug, Default)]
pub struct FrameCollector {
    decoder: TelemetryDecoder,
    frames: Vec<Frame>,
    duplicates: usize,
    read: usize,
    live_gaps: usize,
    first_step: Option<u16>,
}

impl FrameCollector {
    /// A collector waiting for the first frame.
    pub fn new() -> Self {
        FrameCollector::default()
    }

    /// Feeds bytes (any split: a frame may straddle two calls).
    ///
    /// A frame that is not later than the one before it (a repeat, or a piece of the
    /// capture replayed) is counted in [`Decoded::duplicates`] and left out.
    pub fn push(&mut self, bytes: &[u8]) {
        for &b in bytes {
            if let Some(Ok(f)) = self.decoder.push(b) {
                // Not after the last frame (the µs time base wraps every 71.6 min): a
                // repeat or a replayed piece of the capture.
                let last = self.frames.last();
                if last.is_some_and(|p| (f.t.0.wrapping_sub(p.t.0) as i32) <= 0) {
                    self.duplicates += 1;
                    continue;
                }
                // Live gap count: a sequence step other than the first one seen (the
                // decimation, as far as the live view can tell; `finish` counts against
                // the most common step).
                if let Some(p) = self.frames.last() {
                    let step = f.seq.wrapping_sub(p.seq);
                    if *self.first_step.get_or_insert(step) != step {
                        self.live_gaps += 1;
                    }
                }
                self.frames.push(f);
            }
        }
        self.read += bytes.len();
    }

    /// Bytes fed so far.
    pub fn bytes_read(&self) -> usize {
        self.read
    }

    /// Frames accepted and rejected so far.
    pub fn stats(&self) -> LinkStats {
        self.decoder.stats()
    }

    /// Frames kept so far (accepted, not repeats).
    pub fn frames(&self) -> usize {
        self.frames.len()
    }

    /// Repeated frames so far.
    pub fn duplicates(&self) -> usize {
        self.duplicates
    }

    /// Sequence steps that differed from the first step seen, so far.
    pub fn live_gaps(&self) -> usize {
        self.live_gaps
    }

    /// The firmware's dropped-frame counter in the last frame (0 before any).
    pub fn dropped(&self) -> u16 {
        self.frames.last().map_or(0, |f| f.dropped)
    }

    /// The run log of everything fed: the longest gap-free run of frames.
    pub fn finish(self) -> Result<Decoded, String> {
        decode_frames(
            self.decoder.stats(),
            self.frames,
            self.duplicates,
            self.read,
        )
    }
}

/// Decodes a telemetry capture read from `source` in 64 KiB pieces (memory grows with the
/// frames, not with the bytes). `progress` is told how many bytes have been read.
///
/// A frame that is not later than the one before it (a repeat, or a piece of the capture
/// replayed) is counted in [`Decoded::duplicates`] and left out.
pub fn decode_stream(
    mut source: impl std::io::Read,
    mut progress: impl FnMut(usize),
) -> Result<Decoded, String> {
    let mut collector = FrameCollector::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = match source.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => {
                return Err(format!(
                    "cannot read on after {} bytes ({e})",
                    collector.bytes_read()
                ))
            }
        };
        collector.push(buf.get(..n).unwrap_or_default());
        progress(collector.bytes_read());
    }
    collector.finish()
}

/// The run log of decoded frames (see [`decode_stream`]).
fn decode_frames(
    stats: LinkStats,
    frames: Vec<Frame>,
    duplicates: usize,
    read: usize,
) -> Result<Decoded, String> {
    if frames.is_empty() {
        return Err(format!(
            "no telemetry frame in {read} bytes ({} rejected)",
            stats.rejected
        ));
    }
    // The decimation is the most common sequence step; any other step is a gap.
    let steps: Vec<u16> = frames
        .windows(2)
        .map(|w| w[1].seq.wrapping_sub(w[0].seq))
        .collect();
    // A step of 0 is no step (a repeated sequence number is a gap, never the decimation).
    let nonzero: Vec<u16> = steps.iter().copied().filter(|&s| s > 0).collect();
    let decimation = mode_of(&nonzero).unwrap_or(1);
    let tick_steps: Vec<u32> = frames
        .windows(2)
        .map(|w| w[1].t.0.wrapping_sub(w[0].t.0))
        .collect();
    let positive: Vec<u32> = tick_steps.iter().copied().filter(|&t| t > 0).collect();
    let tick_step = mode_of(&positive).unwrap_or(0);
    let breaks: Vec<usize> = steps
        .iter()
        .zip(&tick_steps)
        .enumerate()
        .filter(|(_, (&s, &t))| s != decimation || t != tick_step)
        .map(|(i, _)| i + 1)
        .collect();
    // Longest run of frames between breaks.
    let bounds: Vec<usize> = std::iter::once(0)
        .chain(breaks.iter().copied())
        .chain(std::iter::once(frames.len()))
        .collect();
    let (start, end) = bounds
        .windows(2)
        .map(|w| (w[0], w[1]))
        .max_by_key(|(a, b)| (b - a, usize::MAX - a))
        .unwrap_or((0, frames.len()));
    let kept = frames.get(start..end).unwrap_or_default();

    let mut log = RunLog::with_columns(&decoded_columns());
    log.meta.push(("source".into(), "fpc-sim decode".into()));
    if tick_step > 0 {
        let rate = 1e6 / f64::from(tick_step);
        log.meta.push(("sample_rate_hz".into(), format!("{rate}")));
    }
    log.meta
        .push(("telemetry_decimation".into(), decimation.to_string()));
    // Unwrap the µs time base (it wraps every 71.6 min) from the first kept frame on.
    let mut t_us = kept.first().map_or(0, |f| u64::from(f.t.0));
    let mut prev = kept.first().map(|f| f.t);
    for f in kept {
        if let Some(p) = prev {
            t_us += u64::from(f.t.0.wrapping_sub(p.0));
        }
        prev = Some(f.t);
        let v = f.values().map(f64::from);
        // Divide (correctly rounded), exactly as the simulator's clock prints its time.
        let mut row = vec![t_us as f64 / 1e6];
        row.extend(v);
        row.push(f64::from(f.fault));
        row.push(f64::from(fpc::link::telemetry::mode_code(f.mode)));
        log.push_row(&row);
    }
    Ok(Decoded {
        log,
        stats,
        gaps: breaks.len(),
        left_out: frames.len() - kept.len(),
        duplicates,
        dropped: frames.last().map_or(0, |f| f.dropped),
        decimation: u32::from(decimation),
    })
}

/// The most frequent value (the smallest among ties), if any.
fn mode_of<T: Ord + Copy>(values: &[T]) -> Option<T> {
    let mut sorted = values.to_vec();
    sorted.sort_unstable();
    sorted
        .chunk_by(|a, b| a == b)
        .max_by_key(|run| (run.len(), std::cmp::Reverse(run.first().copied())))
        .and_then(|run| run.first().copied())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpc::status::{ModeKind, Status};
    use fpc::units::Ticks;

    fn capture(seqs: impl Iterator<Item = u32>, decimation: u32) -> Vec<u8> {
        let mut out = Vec::new();
        for i in seqs {
            let status = Status {
                t: Ticks((u32::MAX - 500).wrapping_add(i * 50)),
                mode: ModeKind::Moving,
                position_m: i as f32 * 1e-3,
                ..Status::INIT
            };
            let f = Frame::from_status((i * decimation) as u16, 0, &status);
            let mut buf = [0u8; fpc::link::telemetry::WIRE_BYTES];
            let n = f.encode(&mut buf).unwrap();
            out.extend_from_slice(&buf[..n]);
        }
        out
    }

    #[test]
    fn decoding_unwraps_time_and_keeps_the_longest_gap_free_run() {
        // 0..40, a lost frame, 41..200: the second run is kept; time runs across the wrap.
        let bytes = capture((0..40).chain(41..200), 1);
        let d = decode_capture(&bytes, |_| {}).unwrap();
        assert_eq!((d.gaps, d.left_out, d.decimation), (1, 40, 1));
        assert_eq!(d.log.len(), 159);
        let t = d.log.column("t_s").unwrap();
        assert!(t.windows(2).all(|w| ((w[1] - w[0]) - 50e-6).abs() < 1e-9));
        assert_eq!(d.log.column("x_m").unwrap()[0], f64::from(41f32 * 1e-3));
        assert_eq!(d.log.column("mode").unwrap()[0], 3.0);
    }

    #[test]
    fn garbage_only_is_refused() {
        let e = decode_capture(&[1, 2, 3, 0, 9, 9], |_| {}).unwrap_err();
        assert!(e.contains("no telemetry frame"), "{e}");
    }

    #[test]
    fn repeated_and_replayed_frames_are_counted_and_left_out() {
        // Every frame twice, then a replay of frames 50..80: the decimation stays 4 and the
        // log is the 200 frames once each.
        let frames: Vec<u32> = (0..200).flat_map(|i| [i, i]).chain(50..80).collect();
        let d = decode_capture(&capture(frames.into_iter(), 4), |_| {}).unwrap();
        assert_eq!((d.decimation, d.duplicates, d.gaps), (4, 230, 0));
        assert_eq!(d.log.len(), 200);
    }
}
