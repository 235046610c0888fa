//! The telemetry frame: one control cycle's run-log quantities, the mode, the first latched
//! fault and a sequence number, in a compact binary form for the RTT up-channel.
//!
//! One codec, used by the firmware (encode, in the telemetry task), the simulator (the same
//! task body) and the host tool (`fpc-sim decode`). Framing is [`crate::link`]'s: COBS with a
//! `0x00` delimiter and a CRC-16, so a host attaching mid-stream or reading garbage loses at
//! most one frame and every bad frame is rejected and counted.
//!
//! # Payload (little-endian, 52 bytes; 56 on the wire with CRC, COBS byte and delimiter)
//! | offset | field | type | unit |
//! |---|---|---|---|
//! | 0 | kind = `0x01` | u8 | |
//! | 1 | `seq`: control cycles since telemetry started (wrapping) | u16 | cycles |
//! | 3 | `t`: sampling instant of the cycle | u32 | µs (wrapping) |
//! | 7 | `mode` ([`mode_code`]) | u8 | |
//! | 8 | flags: bit 0 = homed | u8 | |
//! | 9 | `fault`: first latched fault's number, 0 = none | u8 | |
//! | 10 | `dropped`: frames lost so far (saturating) | u16 | frames |
//! | 12 | `x_m`, `x_slave_m`, `theta_rad`, `f_master_n`, `f_slave_n`, `p_a_pa`, `p_b_pa`, `x_ref_m`, `theta_ref_rad`, `v_mps` | 10 × f32 | SI |
//!
//! Values are the controller's own `f32`s, bit for bit, so a decoded capture equals the run
//! log the simulator writes from the same status. With decimation `D` the sequence number
//! steps by `D`; any other step is a gap (frames lost between the queue and the host).

use crate::link::frame::{encode_frame, f32_at, BufferTooSmall, Deframer, FrameError, LinkStats};
use crate::link::frame::{max_wire_len, KIND_TELEMETRY};
use crate::status::{ModeKind, Status};
use crate::units::Ticks;

/// Payload length of a telemetry frame, bytes.
pub const PAYLOAD_BYTES: usize = 52;
/// Length of one telemetry frame on the wire, delimiter included, bytes.
pub const WIRE_BYTES: usize = max_wire_len(PAYLOAD_BYTES);

/// Decimation the firmware starts with: one frame every 20 control cycles (1 kHz,
/// 56 kB/s), well inside what a probe-rs host reads from RTT (README, "Telemetry").
pub const DEFAULT_DECIMATION: u16 = 20;

/// One telemetry frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// Control cycles since telemetry started, wrapping.
    pub seq: u16,
    /// Sampling instant of the cycle.
    pub t: Ticks,
    /// Operating mode.
    pub mode: ModeKind,
    /// The zero is known.
    pub homed: bool,
    /// Number of the first latched fault, 0 = none (`faults.rs`).
    pub fault: u8,
    /// Frames lost so far (queue full or sink full), saturating.
    pub dropped: u16,
    /// Position from the master encoder, m.
    pub x_m: f32,
    /// Position from the slave encoder, m.
    pub x_slave_m: f32,
    /// Rotation angle, rad.
    pub theta_rad: f32,
    /// Master-section force, N.
    pub f_master_n: f32,
    /// Slave-section force, N.
    pub f_slave_n: f32,
    /// Chamber A pressure, Pa.
    pub p_a_pa: f32,
    /// Chamber B pressure, Pa.
    pub p_b_pa: f32,
    /// Position reference, m.
    pub x_ref_m: f32,
    /// Rotation reference, rad.
    pub theta_ref_rad: f32,
    /// Velocity (differentiator), m/s.
    pub v_mps: f32,
}

/// Stable number of a mode on the wire.
pub const fn mode_code(mode: ModeKind) -> u8 {
    match mode {
        ModeKind::Idle => 0,
        ModeKind::Homing => 1,
        ModeKind::Holding => 2,
        ModeKind::Moving => 3,
        ModeKind::Stopping => 4,
        ModeKind::Faulted => 5,
        ModeKind::Running => 6,
        ModeKind::Calibrating => 7,
    }
}

/// The mode with wire number `code`.
pub fn mode_from_code(code: u8) -> Option<ModeKind> {
    [
        ModeKind::Idle,
        ModeKind::Homing,
        ModeKind::Holding,
        ModeKind::Moving,
        ModeKind::Stopping,
        ModeKind::Faulted,
        ModeKind::Running,
        ModeKind::Calibrating,
    ]
    .into_iter()
    .find(|m| mode_code(*m) == code)
}

impl Frame {
    /// The frame of a status snapshot.
    pub fn from_status(seq: u16, dropped: u16, s: &Status) -> Frame {
        Frame {
            seq,
            t: s.t,
            mode: s.mode,
            homed: s.homed,
            fault: s.faults.first().map_or(0, |f| f as u8),
            dropped,
            x_m: s.position_m,
            x_slave_m: s.slave_position_m,
            theta_rad: s.theta_rad,
            f_master_n: s.force_master_n,
            f_slave_n: s.force_slave_n,
            p_a_pa: s.pressure_a_pa,
            p_b_pa: s.pressure_b_pa,
            x_ref_m: s.reference_m,
            theta_ref_rad: s.theta_reference_rad,
            v_mps: s.velocity_mps,
        }
    }

    /// The ten physical values, in payload order.
    pub fn values(&self) -> [f32; 10] {
        [
            self.x_m,
            self.x_slave_m,
            self.theta_rad,
            self.f_master_n,
            self.f_slave_n,
            self.p_a_pa,
            self.p_b_pa,
            self.x_ref_m,
            self.theta_ref_rad,
            self.v_mps,
        ]
    }

    /// The payload (kind byte first).
    pub fn payload(&self) -> [u8; PAYLOAD_BYTES] {
        let [s0, s1] = self.seq.to_le_bytes();
        let [t0, t1, t2, t3] = self.t.0.to_le_bytes();
        let [d0, d1] = self.dropped.to_le_bytes();
        let header = [
            KIND_TELEMETRY,
            s0,
            s1,
            t0,
            t1,
            t2,
            t3,
            mode_code(self.mode),
            u8::from(self.homed),
            self.fault,
            d0,
            d1,
        ];
        let values = self.values().into_iter().flat_map(f32::to_le_bytes);
        let mut p = [0u8; PAYLOAD_BYTES];
        for (dst, src) in p.iter_mut().zip(header.into_iter().chain(values)) {
            *dst = src;
        }
        p
    }

    /// Encodes the frame for the wire into `out` ([`WIRE_BYTES`] always suffice); returns
    /// the bytes written.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
        encode_frame(&self.payload(), out)
    }

    /// Decodes a payload (as returned by the deframer).
    pub fn from_payload(p: &[u8]) -> Result<Frame, FrameError> {
        let header: &[u8; 12] = match p.first() {
            Some(&KIND_TELEMETRY) if p.len() == PAYLOAD_BYTES => p
                .get(..12)
                .and_then(|h| h.try_into().ok())
                .ok_or(FrameError::BadLength)?,
            Some(&KIND_TELEMETRY) => return Err(FrameError::BadLength),
            Some(_) => return Err(FrameError::UnknownKind),
            None => return Err(FrameError::TooShort),
        };
        let [_, s0, s1, t0, t1, t2, t3, mode, flags, fault, d0, d1] = *header;
        if flags & !1 != 0 {
            return Err(FrameError::BadValue);
        }
        let v = |i: usize| f32_at(p, 12 + 4 * i);
        Ok(Frame {
            seq: u16::from_le_bytes([s0, s1]),
            t: Ticks(u32::from_le_bytes([t0, t1, t2, t3])),
            mode: mode_from_code(mode).ok_or(FrameError::BadValue)?,
            homed: flags & 1 != 0,
            fault,
            dropped: u16::from_le_bytes([d0, d1]),
            x_m: v(0)?,
            x_slave_m: v(1)?,
            theta_rad: v(2)?,
            f_master_n: v(3)?,
            f_slave_n: v(4)?,
            p_a_pa: v(5)?,
            p_b_pa: v(6)?,
            x_ref_m: v(7)?,
            theta_ref_rad: v(8)?,
            v_mps: v(9)?,
        })
    }
}

/// Streaming decoder of a telemetry capture: bytes in, frames out; every frame that fails
/// framing, CRC or the payload checks is rejected and counted, and decoding resumes at the
/// next delimiter.
#[derive(Clone, Debug, Default)]
pub struct TelemetryDecoder {
    deframer: Deframer<{ WIRE_BYTES }>,
}

impl TelemetryDecoder {
    /// A decoder waiting for the first frame.
    pub const fn new() -> Self {
        TelemetryDecoder {
            deframer: Deframer::new(),
        }
    }

    /// Feeds one byte; at the end of a frame returns it, or why it was rejected.
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame, FrameError>> {
        self.deframer.push_decoded(byte, Frame::from_payload)
    }

    /// Frames accepted and rejected so far.
    pub fn stats(&self) -> LinkStats {
        self.deframer.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::frame::DELIMITER;
    use proptest::prelude::*;

    fn frame(seed: u32) -> Frame {
        let f = |k: u32| f32::from_bits(seed.wrapping_mul(2_654_435_761).rotate_left(k));
        Frame {
            seq: seed as u16,
            t: Ticks(seed.wrapping_mul(50)),
            mode: mode_from_code((seed % 7) as u8).unwrap(),
            homed: seed.is_multiple_of(2),
            fault: (seed % 15) as u8,
            dropped: (seed >> 3) as u16,
            x_m: 0.1,
            x_slave_m: f(1),
            theta_rad: f(2),
            f_master_n: f(3),
            f_slave_n: f(4),
            p_a_pa: f(5),
            p_b_pa: f(6),
            x_ref_m: f(7),
            theta_ref_rad: f(8),
            v_mps: f(9),
        }
    }

    fn wire(f: &Frame) -> Vec<u8> {
        let mut out = [0u8; WIRE_BYTES];
        let n = f.encode(&mut out).unwrap();
        out[..n].to_vec()
    }

    fn decode_all(d: &mut TelemetryDecoder, bytes: &[u8]) -> Vec<Result<Frame, FrameError>> {
        bytes.iter().filter_map(|&b| d.push(b)).collect()
    }

    #[test]
    fn a_frame_is_56_bytes_on_the_wire() {
        assert_eq!(WIRE_BYTES, 56);
        assert_eq!(wire(&frame(7)).len(), WIRE_BYTES);
    }

    #[test]
    fn every_mode_code_round_trips() {
        for c in 0..=255u8 {
            if let Some(m) = mode_from_code(c) {
                assert_eq!(mode_code(m), c);
            }
        }
        assert_eq!((0..=255u8).filter_map(mode_from_code).count(), 8);
    }

    proptest! {
        #[test]
        fn every_frame_round_trips_bit_for_bit(
            seq in any::<u16>(), t in any::<u32>(), mode in 0u8..7, homed in any::<bool>(),
            fault in any::<u8>(), dropped in any::<u16>(), bits in proptest::array::uniform10(any::<u32>()),
        ) {
            let v = bits.map(f32::from_bits);
            let f = Frame {
                seq, t: Ticks(t), mode: mode_from_code(mode).unwrap(), homed, fault, dropped,
                x_m: v[0], x_slave_m: v[1], theta_rad: v[2], f_master_n: v[3], f_slave_n: v[4],
                p_a_pa: v[5], p_b_pa: v[6], x_ref_m: v[7], theta_ref_rad: v[8], v_mps: v[9],
            };
            let bytes = wire(&f);
            prop_assert_eq!(bytes.len(), WIRE_BYTES);
            let mut d = TelemetryDecoder::new();
            let got = decode_all(&mut d, &bytes);
            prop_assert_eq!(got.len(), 1);
            let back = got[0].unwrap();
            prop_assert_eq!(back.payload(), f.payload());
            prop_assert_eq!(back.values().map(f32::to_bits), bits);
        }
    }

    #[test]
    fn truncated_frames_are_rejected_and_counted() {
        let good = wire(&frame(3));
        let mut d = TelemetryDecoder::new();
        for cut in 1..good.len() - 1 {
            let mut bytes = good[..cut].to_vec();
            bytes.push(DELIMITER);
            let got = decode_all(&mut d, &bytes);
            assert!(matches!(got[..], [Err(_)]), "cut {cut}: {got:?}");
        }
        assert_eq!(
            d.stats(),
            LinkStats {
                accepted: 0,
                rejected: (good.len() - 2) as u32
            }
        );
        // A frame truncated by the capture's end is simply never completed.
        assert!(decode_all(&mut d, &good[..30]).is_empty());
    }

    #[test]
    fn a_host_attaching_mid_stream_loses_one_frame_only() {
        let stream: Vec<u8> = (0..10).flat_map(|i| wire(&frame(i))).collect();
        for start in 0..WIRE_BYTES {
            let mut d = TelemetryDecoder::new();
            let got = decode_all(&mut d, &stream[start..]);
            let ok: Vec<u16> = got.iter().filter_map(|r| r.ok()).map(|f| f.seq).collect();
            let expected: Vec<u16> = if start == 0 {
                (0..10).collect()
            } else {
                (1..10).collect()
            };
            assert_eq!(ok, expected, "start {start}");
            assert!(d.stats().rejected <= 1);
        }
    }

    #[test]
    fn unknown_kinds_lengths_and_values_are_rejected() {
        let mut p = frame(1).payload();
        p[7] = 99; // no such mode
        let mut bad_mode = [0u8; WIRE_BYTES];
        let n = encode_frame(&p, &mut bad_mode).unwrap();
        let mut d = TelemetryDecoder::new();
        assert_eq!(
            decode_all(&mut d, &bad_mode[..n]),
            vec![Err(FrameError::BadValue)]
        );
        let mut out = [0u8; WIRE_BYTES];
        let n = encode_frame(&p[..40], &mut out).unwrap();
        assert_eq!(
            decode_all(&mut d, &out[..n]),
            vec![Err(FrameError::BadLength)]
        );
        let n = encode_frame(&[0x02, 0, 0x10], &mut out).unwrap();
        assert_eq!(
            decode_all(&mut d, &out[..n]),
            vec![Err(FrameError::UnknownKind)]
        );
        assert_eq!(d.stats().rejected, 3);
    }

    /// ≥ 10⁶ seeded random inputs (random bytes and mangled frames): the decoder never
    /// panics, and after any garbage a clean frame decodes exactly.
    #[test]
    fn fuzzed_telemetry_decoder_never_panics_and_resynchronises() {
        let mut rng = crate::link::commands::tests::Rng::new(0xD1B5_4A32_D192_ED03);
        let mut d = TelemetryDecoder::new();
        let mut n = 0u32;
        while n < 1_000_000 {
            n += 1;
            let mut bytes = match rng.below(3) {
                0 => (0..rng.below(80)).map(|_| rng.byte()).collect(),
                _ => wire(&frame(rng.word())),
            };
            match rng.below(4) {
                0 => bytes.truncate(rng.below(bytes.len().max(1))),
                1 if !bytes.is_empty() => {
                    let i = rng.below(bytes.len());
                    bytes[i] ^= 1 << rng.below(8);
                }
                2 => bytes
                    .splice(0..0, (0..rng.below(6)).map(|_| rng.byte()))
                    .for_each(drop),
                _ => {}
            }
            for b in bytes {
                let _ = d.push(b);
            }
            if n.is_multiple_of(1000) {
                let f = frame(n);
                let mut clean = vec![DELIMITER];
                clean.extend(wire(&f));
                let got = decode_all(&mut d, &clean);
                assert_eq!(
                    got.last().map(|r| r.map(|g| g.payload())),
                    Some(Ok(f.payload()))
                );
            }
        }
        let s = d.stats();
        assert!(s.accepted > 100_000 && s.rejected > 100_000, "{s:?}");
    }
}
