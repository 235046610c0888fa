//! A telemetry capture and its decoding (from the simulator or from the rig's RTT channel)
//! into a run log.
//!
//! A run with telemetry on has a host drain the board's telemetry channel
//! ([`crate::board::channels`]) every control period into [`TelemetryCapture::bytes`] (the
//! `run` module). The bytes are exactly what the board would send, so `fpc-sim decode` reads
//! both alike.

use crate::logmeta::{LogMeta, PortsDeclared, ThetaSource};
use crate::runlog::RunLog;
use fpc::link::frame::LinkStats;
use fpc::link::telemetry::{
    ChannelSet, Frame, Ports, TelemetryDecoder, CHANNELS, CONTROL_PERIOD_US, FORCE_DELAY_PERIODS,
    LAYOUT, THETA_SOURCE,
};

/// Telemetry of a simulated run: the rate it was asked for and the bytes a host read.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TelemetryCapture {
    /// One frame every this many control cycles at boot; 0 = telemetry off (the default:
    /// a long run at full rate would hold 1.2 MB per simulated second).
    pub decimation: u16,
    /// Everything the host read from the telemetry up-channel.
    pub bytes: Vec<u8>,
}

/// Columns of a decoded capture carrying `channels`: `t_s`, the channels in run-log order
/// (the required ones first), then the first fault and the mode number
/// (`fpc::link::telemetry::mode_code`).
pub fn decoded_columns(channels: ChannelSet) -> Vec<&'static str> {
    std::iter::once("t_s")
        .chain(
            CHANNELS
                .iter()
                .enumerate()
                .filter(|(i, _)| channels.has(*i))
                .map(|(_, n)| *n),
        )
        .chain(["fault", "mode"])
        .collect()
}

/// A decoded capture.
#[derive(Clone, Debug)]
pub struct Decoded {
    /// The run log: the longest run of frames without a gap, of one channel set and one
    /// declaration of the ports (a bypass closing once is kept, as `# ports_from_s`).
    pub log: RunLog,
    /// Frames accepted and rejected by the decoder.
    pub stats: LinkStats,
    /// Breaks in the frames: sequence steps other than the decimation (frames lost after
    /// the queue), a change of the rate, of the channels or of the ports declared.
    pub gaps: usize,
    /// Accepted frames left out of the log because they lie outside its gap-free run.
    pub left_out: usize,
    /// Frames not later than the frame before them (repeats, replayed pieces), left out.
    pub duplicates: usize,
    /// The dropped-frame counter of the last frame (frames the firmware could not send).
    pub dropped: u16,
    /// Control cycles per frame, from the sequence numbers.
    pub decimation: u32,
    /// Frames of telemetry layout 1 (an older firmware's), rejected.
    pub layout_1: u32,
    /// The channels the log's frames carried.
    pub channels: ChannelSet,
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
                // Live gap count: a step that is a multiple of the decimation seen so far
                // (frames lost); any other step is a new decimation (set at run time), not
                // a loss. `finish` counts against the most common step.
                if let Some(p) = self.frames.last() {
                    let step = f.seq.wrapping_sub(p.seq);
                    match self.first_step {
                        Some(d) if d == step => {}
                        Some(d) if d > 0 && step > d && step % d == 0 => self.live_gaps += 1,
                        _ => self.first_step = Some(step),
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

    /// The last frame kept, if any.
    pub fn last(&self) -> Option<&Frame> {
        self.frames.last()
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
            self.decoder.layout_1(),
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

/// Why the frames of a capture cannot make a run log, if they cannot: a layout another
/// firmware sends, or channels a run log needs that were not sent.
fn unusable(frames: &[Frame], layout_1: u32, stats: LinkStats, read: usize) -> Option<String> {
    let Some(first) = frames.first() else {
        return Some(if layout_1 > 0 {
            format!(
                "{layout_1} telemetry frames of layout 1 (kind 0x01: an older fpc firmware's, \
                 ten fixed channels) and none of layout {LAYOUT} in {read} bytes: this \
                 fpc-sim reads layout {LAYOUT}; decode the capture with the fpc-sim of the \
                 firmware that sent it"
            )
        } else {
            format!(
                "no telemetry frame in {read} bytes ({} rejected)",
                stats.rejected
            )
        });
    };
    let missing: Vec<&str> = CHANNELS
        .iter()
        .enumerate()
        .filter(|(i, _)| ChannelSet::GAP.has(*i) && !first.channels.has(*i))
        .map(|(_, n)| *n)
        .collect();
    (!missing.is_empty() && frames.iter().all(|f| f.channels == first.channels)).then(|| {
        format!(
            "the telemetry carried no {}: a run log needs them (set the channels with              `fpc-sim link telemetry --channels gap` or `all`)",
            missing.join(", ")
        )
    })
}

/// The run log of decoded frames (see [`decode_stream`]).
fn decode_frames(
    stats: LinkStats,
    layout_1: u32,
    frames: Vec<Frame>,
    duplicates: usize,
    read: usize,
) -> Result<Decoded, String> {
    if let Some(why) = unusable(&frames, layout_1, stats, read) {
        return Err(why);
    }
    // Only frames that can make a run log (every required channel) count.
    let complete = |f: &Frame| (0..7).all(|i| ChannelSet::GAP.has(i) && f.channels.has(i));
    let incomplete = frames.iter().filter(|f| !complete(f)).count();
    let frames: Vec<Frame> = frames.into_iter().filter(complete).collect();
    if frames.is_empty() {
        return Err(format!(
            "none of the {incomplete} telemetry frames carries every channel a run log needs              ({})",
            CHANNELS[..7].join(", ")
        ));
    }
    let Stretch {
        start,
        end,
        decimation,
        tick_step,
        breaks,
    } = longest_stretch(&frames);
    let kept = frames.get(start..end).unwrap_or_default();
    let channels = kept.first().map_or(ChannelSet::ALL, |f| f.channels);

    let mut log = RunLog::with_columns(&decoded_columns(channels));
    let mut meta = LogMeta {
        source: Some("fpc-sim decode".into()),
        sample_rate_hz: (tick_step > 0).then(|| 1e6 / f64::from(tick_step)),
        telemetry_decimation: Some(u32::from(decimation)),
        telemetry_layout: Some(u32::from(LAYOUT)),
        // The firmware's own conventions, fixed by the layout (fpc::link::telemetry).
        force_delay_s: Some(f64::from(FORCE_DELAY_PERIODS * CONTROL_PERIOD_US) / 1e6),
        theta_source: ThetaSource::from_name(THETA_SOURCE),
        ..LogMeta::default()
    };
    // Unwrap the µs time base (it wraps every 71.6 min) from the first kept frame on.
    let mut t_us = kept.first().map_or(0, |f| u64::from(f.t.0));
    let mut prev = kept.first().map(|f| f.t);
    let mut ports_from: Option<(Ports, f64)> = None;
    for f in kept {
        if let Some(p) = prev {
            t_us += u64::from(f.t.0.wrapping_sub(p.0));
        }
        prev = Some(f.t);
        // Divide (correctly rounded), exactly as the simulator's clock prints its time.
        let t_s = t_us as f64 / 1e6;
        if f.ports != Ports::Bypassed && ports_from.is_none() {
            ports_from = Some((f.ports, t_s));
        }
        let mut row = vec![t_s];
        row.extend(
            f.values()
                .iter()
                .enumerate()
                .filter(|(i, _)| channels.has(*i))
                .map(|(_, v)| f64::from(*v)),
        );
        row.push(f64::from(f.fault));
        row.push(f64::from(fpc::link::telemetry::mode_code(f.mode)));
        log.push_row(&row);
    }
    if let Some((ports, from_s)) = ports_from {
        meta.ports = Some(if ports == Ports::Sealed {
            PortsDeclared::Closed
        } else {
            PortsDeclared::Open
        });
        if kept.first().is_some_and(|f| f.ports == Ports::Bypassed) {
            meta.ports_from_s = Some(from_s);
        }
    }
    meta.write(&mut log);
    Ok(Decoded {
        log,
        stats,
        gaps: breaks,
        left_out: frames.len() - kept.len() + incomplete,
        duplicates,
        dropped: frames.last().map_or(0, |f| f.dropped),
        decimation: u32::from(decimation),
        layout_1,
        channels,
    })
}

/// The longest stretch of frames without a break, `start..end`, with the stream's decimation
/// (its most common sequence step), its most common step of the µs time base and the number
/// of breaks in the whole stream.
struct Stretch {
    start: usize,
    end: usize,
    decimation: u16,
    tick_step: u32,
    breaks: usize,
}

/// How far a frame's time step may stray from the stream's usual step without being a
/// break, µs: the firmware stamps a frame with the µs time base as its sample's interrupt
/// runs, and that interrupt's entry latency moves the stamp across a µs boundary now and
/// then — one either way, two between neighbours.
const STAMP_JITTER_US: u32 = 2;

/// The [`Stretch`] of `frames`: a break is a frame lost (the step), another rate, other
/// channels, or the ports declared otherwise — except a bypass closing (bypassed → timed
/// or sealed), which the log states as `# ports_from_s`.
fn longest_stretch(frames: &[Frame]) -> Stretch {
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
    // A break: a frame lost (the step), another rate (a time step more than
    // [`STAMP_JITTER_US`] off the usual one), other channels, or the ports
    // declared otherwise — except a bypass closing (bypassed → timed or sealed), which the
    // log states as `# ports_from_s`.
    let breaks: Vec<usize> = frames
        .windows(2)
        .zip(steps.iter().zip(&tick_steps))
        .enumerate()
        .filter(|(_, (w, (&s, &t)))| {
            s != decimation
                || t.abs_diff(tick_step) > STAMP_JITTER_US
                || w[1].channels != w[0].channels
                || (w[1].ports != w[0].ports && w[0].ports != Ports::Bypassed)
        })
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
    Stretch {
        start,
        end,
        decimation,
        tick_step,
        breaks: breaks.len(),
    }
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
    use fpc::link::telemetry::Ports;
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
    fn a_stamp_a_microsecond_off_is_no_break_but_another_rate_is() {
        // Stamps jittering by ±1 µs around 500 µs steps, then the rate halves.
        let list: Vec<Frame> = (0..300)
            .map(|i| {
                let mut f = at(i, Ports::Timed, ChannelSet::ALL);
                let jitter = [0, 1, 0, u32::MAX][i as usize % 4];
                let slow = if i >= 200 { (i - 200) * 500 } else { 0 };
                f.t = Ticks(f.t.0.wrapping_add(jitter).wrapping_add(slow));
                f
            })
            .collect();
        let d = decode_capture(&frames(&list), |_| {}).unwrap();
        // Frames 0..=200 are one stretch; each of the 99 steps at the other rate breaks.
        assert_eq!((d.gaps, d.log.len()), (99, 201));
    }

    fn frames(list: &[Frame]) -> Vec<u8> {
        let mut out = Vec::new();
        for f in list {
            let mut buf = [0u8; fpc::link::telemetry::WIRE_BYTES];
            let n = f.encode(&mut buf).unwrap();
            out.extend_from_slice(&buf[..n]);
        }
        out
    }

    fn at(i: u32, ports: Ports, channels: ChannelSet) -> Frame {
        let status = Status {
            t: Ticks(1_000 + i * 500),
            mode: ModeKind::Running,
            position_m: 0.1,
            ..Status::INIT
        };
        Frame {
            ports,
            channels,
            ..Frame::from_status((i * 10) as u16, 0, &status)
        }
    }

    #[test]
    fn a_closing_bypass_is_stated_and_the_firmwares_conventions_written() {
        let list: Vec<Frame> = (0..300)
            .map(|i| {
                at(
                    i,
                    if i < 120 {
                        Ports::Bypassed
                    } else {
                        Ports::Timed
                    },
                    ChannelSet::ALL,
                )
            })
            .collect();
        let d = decode_capture(&frames(&list), |_| {}).unwrap();
        assert_eq!((d.gaps, d.left_out, d.log.len()), (0, 0, 300));
        let meta = |k: &str| d.log.meta(k).map(str::to_string);
        assert_eq!(meta("sample_rate_hz").as_deref(), Some("2000"));
        assert_eq!(meta("ports").as_deref(), Some("open"));
        assert_eq!(meta("ports_from_s").as_deref(), Some("0.061"));
        assert_eq!(meta("force_delay_s").as_deref(), Some("5e-5"));
        assert_eq!(meta("theta_source").as_deref(), Some("servo_encoder"));
        // Sealed from the start: closed, no time.
        let sealed: Vec<Frame> = (0..200)
            .map(|i| at(i, Ports::Sealed, ChannelSet::GAP))
            .collect();
        let d = decode_capture(&frames(&sealed), |_| {}).unwrap();
        assert_eq!(d.log.meta("ports"), Some("closed"));
        assert_eq!(d.log.meta("ports_from_s"), None);
        assert_eq!(
            d.log.names.len(),
            1 + 7 + 2,
            "t_s, gap's seven, fault, mode"
        );
        // Bypassed throughout: the ports are not stated (the pressures are not replayed).
        let open: Vec<Frame> = (0..200)
            .map(|i| at(i, Ports::Bypassed, ChannelSet::ALL))
            .collect();
        let d = decode_capture(&frames(&open), |_| {}).unwrap();
        assert_eq!(d.log.meta("ports"), None);
    }

    #[test]
    fn other_channels_or_ports_declared_otherwise_break_the_log() {
        // Timed, then sealed (a declaration changed, not a bypass closing), then other
        // channels: three stretches, the longest kept.
        let list: Vec<Frame> = (0..400)
            .map(|i| match i {
                0..100 => at(i, Ports::Timed, ChannelSet::ALL),
                100..350 => at(i, Ports::Sealed, ChannelSet::ALL),
                _ => at(i, Ports::Sealed, ChannelSet::GAP),
            })
            .collect();
        let d = decode_capture(&frames(&list), |_| {}).unwrap();
        assert_eq!((d.gaps, d.left_out, d.log.len()), (2, 150, 250));
        assert_eq!(d.log.meta("ports"), Some("closed"));
    }

    #[test]
    fn another_firmwares_layout_and_missing_channels_are_named() {
        // Layout 1 (kind 0x01, 52-byte payload): an older firmware's capture.
        let mut old = Vec::new();
        for i in 0..50u8 {
            let mut p = [0u8; 52];
            p[0] = 0x01;
            p[1] = i;
            let mut buf = [0u8; 64];
            let n = fpc::link::frame::encode_frame(&p, &mut buf).unwrap();
            old.extend_from_slice(&buf[..n]);
        }
        let e = decode_capture(&old, |_| {}).unwrap_err();
        assert!(
            e.contains("50 telemetry frames of layout 1") && e.contains("older fpc firmware"),
            "{e}"
        );
        // Frames without the slave encoder: no run log.
        let few: Vec<Frame> = (0..200)
            .map(|i| at(i, Ports::Timed, ChannelSet(0b111_1101)))
            .collect();
        let e = decode_capture(&frames(&few), |_| {}).unwrap_err();
        assert!(e.contains("carried no x_slave_m"), "{e}");
        // Mixed with layout-2 frames: counted, the rest decoded.
        let mut both = old.clone();
        both.extend(frames(
            &(0..200)
                .map(|i| at(i, Ports::Timed, ChannelSet::ALL))
                .collect::<Vec<_>>(),
        ));
        let d = decode_capture(&both, |_| {}).unwrap();
        assert_eq!((d.layout_1, d.stats.rejected, d.log.len()), (50, 50, 200));
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
