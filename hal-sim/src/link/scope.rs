//! Scope recordings on the host: collected from the reply channel's messages (header, then
//! chunks; [`fpc::link::scope`]), checked whole, and turned into run logs `gap` reads as
//! they are (20 kHz, `# force_delay_s`, `# theta_source`, `# ports` from the declaration at
//! the trigger).
//!
//! A recording is refused, never patched, when a chunk is missing (the capture ended, or
//! the host attached while it was being sent), when its samples are not one control period
//! apart (the control task missed a cycle while recording), or when its angle's code
//! disagrees with the angle the header states.

use crate::logmeta::{LogMeta, PortsDeclared, ThetaSource};
use std::collections::BTreeMap;

use fpc::link::frame::Deframer;
use fpc::link::scope::{
    decode_scope, sample_values, Recording, ScopeMessage, Trigger, CHUNK_SAMPLES, MAX_SCOPE_WIRE,
    SAMPLE_BYTES, THETA_UNIT_RAD,
};
use fpc::link::telemetry::{
    mode_code, Ports, CONTROL_PERIOD_US, FORCE_DELAY_PERIODS, THETA_SOURCE,
};

use crate::runlog::{RunLog, REQUIRED};

/// A whole recording: its header and its samples' bytes, oldest first.
#[derive(Clone, Debug, PartialEq)]
pub struct ScopeRecording {
    /// What its header says.
    pub recording: Recording,
    /// Its samples, encoded.
    pub samples: Vec<[u8; SAMPLE_BYTES]>,
}

/// A recording being collected: its header (once it came) and its chunks by index.
type Partial = (Option<Recording>, BTreeMap<u16, Vec<[u8; SAMPLE_BYTES]>>);

/// Collects recordings from scope messages, in any interleaving with other messages.
#[derive(Clone, Debug, Default)]
pub struct ScopeCollector {
    partial: BTreeMap<u8, Partial>,
    done: Vec<ScopeRecording>,
    /// Chunks that arrived for a recording already complete (a repeat), left out.
    pub repeated: usize,
}

impl ScopeCollector {
    /// A collector with nothing yet.
    pub fn new() -> Self {
        ScopeCollector::default()
    }

    /// Takes one decoded scope message.
    pub fn push(&mut self, message: ScopeMessage) {
        let id = match &message {
            ScopeMessage::Header(r) => r.id,
            ScopeMessage::Chunk { id, .. } => *id,
        };
        let entry = self.partial.entry(id).or_default();
        match message {
            ScopeMessage::Header(r) => {
                if entry.0.is_some_and(|old| old != r) {
                    // The id came round again (256 recordings later): a new recording.
                    entry.1.clear();
                }
                entry.0 = Some(r);
            }
            ScopeMessage::Chunk {
                index,
                samples,
                bytes,
                ..
            } => {
                let list = bytes
                    .chunks_exact(SAMPLE_BYTES)
                    .take(usize::from(samples))
                    .filter_map(|c| c.try_into().ok())
                    .collect();
                if entry.1.insert(index, list).is_some() {
                    self.repeated += 1;
                }
            }
        }
        self.complete(id);
    }

    fn complete(&mut self, id: u8) {
        let Some((Some(r), chunks)) = self.partial.get(&id) else {
            return;
        };
        let need = usize::from(r.samples).div_ceil(CHUNK_SAMPLES);
        if (0..need as u16).all(|i| chunks.contains_key(&i)) {
            let samples: Vec<[u8; SAMPLE_BYTES]> = (0..need as u16)
                .filter_map(|i| chunks.get(&i))
                .flatten()
                .copied()
                .take(usize::from(r.samples))
                .collect();
            if samples.len() == usize::from(r.samples) {
                self.done.push(ScopeRecording {
                    recording: *r,
                    samples,
                });
                self.partial.remove(&id);
            }
        }
    }

    /// Recordings complete so far, in the order they completed.
    pub fn recordings(&self) -> &[ScopeRecording] {
        &self.done
    }

    /// What is incomplete: one line per recording with its missing parts.
    pub fn incomplete(&self) -> Vec<String> {
        self.partial
            .iter()
            .map(|(id, (header, chunks))| match header {
                None => format!(
                    "recording {id}: {} chunks without their header (the capture began while \
                     it was being sent)",
                    chunks.len()
                ),
                Some(r) => {
                    let need = usize::from(r.samples).div_ceil(CHUNK_SAMPLES) as u16;
                    let missing: Vec<u16> = (0..need).filter(|i| !chunks.contains_key(i)).collect();
                    format!(
                        "recording {id}: chunks {} of {need} missing (the capture ended, or \
                         lost them, before the recording was sent whole)",
                        ranges(&missing)
                    )
                }
            })
            .collect()
    }
}

/// `[1, 2, 3, 7]` as `1..=3, 7`.
fn ranges(v: &[u16]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while let Some(&a) = v.get(i) {
        let mut j = i;
        while v
            .get(j + 1)
            .is_some_and(|&n| n == v.get(j).copied().unwrap_or(0) + 1)
        {
            j += 1;
        }
        let b = v.get(j).copied().unwrap_or(a);
        out.push(if a == b {
            a.to_string()
        } else {
            format!("{a}..={b}")
        });
        i = j + 1;
    }
    out.join(", ")
}

/// A trigger as typed after `fpc-sim link scope arm --trigger`.
pub fn trigger_text(t: Trigger) -> String {
    match t {
        Trigger::Command => "command".into(),
        Trigger::Fault => "fault".into(),
        Trigger::ModeChange => "mode-change".into(),
        Trigger::Strokes(n) => format!("strokes:{n}"),
    }
}

impl ScopeRecording {
    /// The recording as a run log (20 kHz, the required columns), or why it is refused.
    pub fn to_log(&self) -> Result<RunLog, String> {
        let r = &self.recording;
        let n = self.samples.len();
        let pre = usize::from(r.pre);
        let after = n.saturating_sub(pre + 1) as u32;
        let span_us = r.t_last.0.wrapping_sub(r.t_trigger.0);
        if span_us != after * CONTROL_PERIOD_US {
            return Err(format!(
                "recording {}: its last sample is {span_us} µs after the trigger, {} µs \
                 expected for {after} samples one control period apart: the control task \
                 missed cycles while recording; refused",
                r.id,
                after * CONTROL_PERIOD_US
            ));
        }
        let decoded: Vec<([f32; 7], bool)> = self.samples.iter().map(sample_values).collect();
        // The angle: the codes unwrapped, placed on the trigger's angle.
        let codes: Vec<i64> = self
            .samples
            .iter()
            .map(|b| i64::from(u16::from_le_bytes([b[6], b[7]])))
            .collect();
        let trigger_code = codes.get(pre).copied().unwrap_or(0);
        // The firmware's own arithmetic, in f32: the trigger sample's code from its angle.
        let expected = (r.theta_trigger_rad * (1.0 / THETA_UNIT_RAD)) as i32 as u16;
        if i64::from(expected) != trigger_code {
            return Err(format!(
                "recording {}: the trigger sample's angle code {trigger_code} is not the one of \
                 the angle its header states ({} rad, code {expected}): another layout, or an \
                 angle beyond the code's range; refused",
                r.id, r.theta_trigger_rad
            ));
        }
        let mut unwrapped = Vec::with_capacity(n);
        let mut acc = 0i64;
        let mut prev: Option<i64> = None;
        for &c in &codes {
            if let Some(p) = prev {
                let d = (c - p).rem_euclid(65_536);
                acc += if d >= 32_768 { d - 65_536 } else { d };
            }
            prev = Some(c);
            unwrapped.push(acc);
        }
        let at_trigger = unwrapped.get(pre).copied().unwrap_or(0);
        let clipped = decoded.iter().filter(|(_, c)| *c).count();

        let mut log = RunLog::with_columns(&REQUIRED);
        let mut meta = LogMeta {
            source: Some("fpc scope".into()),
            sample_rate_hz: Some(1e6 / f64::from(CONTROL_PERIOD_US)),
            force_delay_s: Some(f64::from(FORCE_DELAY_PERIODS * CONTROL_PERIOD_US) / 1e6),
            theta_source: ThetaSource::from_name(THETA_SOURCE),
            ports: match r.ports {
                Ports::Timed => Some(PortsDeclared::Open),
                Ports::Sealed => Some(PortsDeclared::Closed),
                Ports::Bypassed => None,
            },
            ..LogMeta::default()
        };
        meta.other
            .push(("scope_trigger".into(), trigger_text(r.trigger)));
        meta.other
            .push(("scope_pre_samples".into(), r.pre.to_string()));
        meta.other.push((
            "scope_modes".into(),
            format!(
                "{} at the trigger, {} at the end",
                mode_code(r.mode_at_trigger),
                mode_code(r.mode_at_end)
            ),
        ));
        if clipped > 0 {
            meta.other
                .push(("scope_clipped_samples".into(), clipped.to_string()));
        }
        meta.write(&mut log);
        for (k, ((v, _), u)) in decoded.iter().zip(&unwrapped).enumerate() {
            let ticks =
                i64::from(r.t_trigger.0) + (k as i64 - pre as i64) * i64::from(CONTROL_PERIOD_US);
            let theta = f64::from(r.theta_trigger_rad)
                + (u - at_trigger) as f64 * f64::from(THETA_UNIT_RAD);
            log.push_row(&[
                ticks as f64 / 1e6,
                f64::from(v[0]),
                f64::from(v[1]),
                theta,
                f64::from(v[3]),
                f64::from(v[4]),
                f64::from(v[5]),
                f64::from(v[6]),
            ]);
        }
        Ok(log)
    }

    /// Samples whose values sat at a code's limit.
    pub fn clipped(&self) -> usize {
        self.samples.iter().filter(|b| sample_values(b).1).count()
    }
}

/// Every scope recording in a capture of the reply channel (raw bytes of up 2): the whole
/// ones, and a line for each one that is not.
pub fn decode_scope_capture(bytes: &[u8]) -> (Vec<ScopeRecording>, Vec<String>) {
    // The reply channel's frames; the answers among them are not wanted here.
    let mut deframer = Deframer::<{ MAX_SCOPE_WIRE }>::default();
    let mut scope = ScopeCollector::new();
    for &b in bytes {
        if let Some(Ok(payload)) = deframer.push(b) {
            if let Some(Ok(message)) = decode_scope(payload) {
                scope.push(message);
            }
        }
    }
    (scope.recordings().to_vec(), scope.incomplete())
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpc::link::scope::{encode_chunk, encode_header, Scope, MAX_SCOPE_WIRE};
    use fpc::status::{ModeKind, Status};
    use fpc::units::Ticks;

    fn status(i: u32) -> Status {
        let t = i as f32 * 50e-6;
        Status {
            t: Ticks(7_000 + 50 * i),
            mode: ModeKind::Running,
            position_m: 0.1 + 0.05 * (20.0 * t).sin(),
            slave_position_m: 0.1 + 0.05 * (20.0 * t).sin() - 2e-6,
            velocity_mps: (20.0 * t).cos(),
            theta_rad: 400.0 * t + 3.0,
            force_master_n: 900.0 * (20.0 * t).sin(),
            force_slave_n: 880.0 * (20.0 * t).sin(),
            pressure_a_pa: 2.5e5,
            pressure_b_pa: 1.5e5,
            ..Status::INIT
        }
    }

    /// A recording made by the firmware's scope, as the command task would send it.
    fn sent() -> (Vec<u8>, Scope) {
        let mut scope = Scope::new();
        scope.arm(Trigger::Command, 64, &status(0)).unwrap();
        for i in 0..200 {
            scope.record(&status(i), Ports::Timed);
        }
        scope.fire().unwrap();
        let mut i = 200;
        while scope.recording().is_none() {
            scope.record(&status(i), Ports::Timed);
            i += 1;
        }
        let r = scope.recording().unwrap();
        let mut out = Vec::new();
        let mut wire = [0u8; MAX_SCOPE_WIRE];
        let n = encode_header(&r, &mut wire).unwrap();
        out.extend_from_slice(&wire[..n]);
        for c in 0..usize::from(r.samples) / CHUNK_SAMPLES {
            let samples: Vec<_> = (c * CHUNK_SAMPLES..(c + 1) * CHUNK_SAMPLES)
                .map(|k| scope.sample_bytes(k).unwrap())
                .collect();
            let n = encode_chunk(r.id, c as u16, &samples, &mut wire).unwrap();
            out.extend_from_slice(&wire[..n]);
        }
        (out, scope)
    }

    #[test]
    fn a_recording_becomes_a_20_khz_run_log_with_its_angle_unwrapped() {
        let (bytes, _) = sent();
        let (recs, incomplete) = decode_scope_capture(&bytes);
        assert!(incomplete.is_empty(), "{incomplete:?}");
        let log = recs[0].to_log().unwrap();
        assert_eq!(log.len(), 512);
        assert_eq!(log.meta("sample_rate_hz"), Some("20000"));
        assert_eq!(log.meta("ports"), Some("open"));
        let t = log.column("t_s").unwrap();
        let th = log.column("theta_rad").unwrap();
        let x = log.column("x_m").unwrap();
        // Sample 64 is the trigger's cycle (200): 136 cycles before it were recorded first.
        for (k, i) in (136..136 + 512).enumerate() {
            let s = status(i);
            assert!((t[k] - f64::from(s.t.0) / 1e6).abs() < 1e-9);
            assert_eq!(x[k], f64::from(s.position_m));
            assert!(
                (th[k] - f64::from(s.theta_rad)).abs() < 2e-4,
                "{k}: {} {}",
                th[k],
                s.theta_rad
            );
        }
        // The angle runs over several turns: it was unwrapped, not folded.
        assert!(th[511] - th[0] > std::f64::consts::TAU);
    }

    #[test]
    fn a_truncated_or_stretched_recording_is_refused_with_the_reason() {
        let (bytes, _) = sent();
        // Cut the capture 1000 bytes before its end: the last chunks are missing.
        let (recs, incomplete) = decode_scope_capture(&bytes[..bytes.len() - 1000]);
        assert!(recs.is_empty());
        assert!(
            incomplete[0].contains("chunks 28..=31 of 32 missing"),
            "{incomplete:?}"
        );
        // Without its beginning: chunks without a header.
        let (recs, incomplete) = decode_scope_capture(&bytes[40..]);
        assert!(recs.is_empty());
        assert!(
            incomplete[0].contains("without their header"),
            "{incomplete:?}"
        );
        // A missed cycle: the last sample later than the count says.
        let (mut recs, _) = decode_scope_capture(&bytes);
        recs[0].recording.t_last = Ticks(recs[0].recording.t_last.0 + 50);
        let e = recs[0].to_log().unwrap_err();
        assert!(e.contains("missed cycles"), "{e}");
        recs[0].recording.t_last = Ticks(recs[0].recording.t_last.0 - 50);
        recs[0].recording.theta_trigger_rad += 1.0;
        let e = recs[0].to_log().unwrap_err();
        assert!(e.contains("angle code"), "{e}");
    }

    #[test]
    fn missing_chunks_are_listed_as_ranges() {
        assert_eq!(ranges(&[1, 2, 3, 7, 9, 10]), "1..=3, 7, 9..=10");
    }
}
