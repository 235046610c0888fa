//! The telemetry frame: one control cycle's run-log quantities (the channels the host chose),
//! the mode, the first latched fault, the ports as the operator declared them and a sequence
//! number, in a compact binary form for the RTT up-channel.
//!
//! One codec, used by the firmware (encode, in the telemetry task), the simulator (the same
//! task body) and the host tool (`fpc-sim decode`). Framing is [`crate::link`]'s: COBS with a
//! `0x00` delimiter and a CRC-16, so a host attaching mid-stream or reading garbage loses at
//! most one frame and every bad frame is rejected and counted.
//!
//! # Layout 2: kind `0x05` (little-endian; 14 + 4·n bytes, n channels)
//! | offset | field | type | unit |
//! |---|---|---|---|
//! | 0 | kind = `0x05` | u8 | |
//! | 1 | `seq`: control cycles since telemetry started (wrapping) | u16 | cycles |
//! | 3 | `t`: sampling instant of the cycle | u32 | µs (wrapping) |
//! | 7 | `mode` ([`mode_code`]) | u8 | |
//! | 8 | flags: bit 0 = homed; bits 1–2 = the ports as declared ([`Ports`]) | u8 | |
//! | 9 | `fault`: first latched fault's number, 0 = none | u8 | |
//! | 10 | `dropped`: frames lost so far (saturating) | u16 | frames |
//! | 12 | `channels`: bit i set = channel i follows ([`CHANNELS`]) | u16 | |
//! | 14 | the values of the channels set, in channel order | n × f32 | SI |
//!
//! With all ten channels a frame is 54 bytes, 58 on the wire ([`WIRE_BYTES`]); with the seven
//! a run log needs ([`ChannelSet::GAP`]), 42 and 46. Values are the controller's own `f32`s,
//! bit for bit, so a decoded capture equals the run log the simulator writes from the same
//! status. With decimation `D` the sequence number steps by `D`; any other step is a gap
//! (frames lost between the queue and the host).
//!
//! The kind is the layout's version: what a decoder takes from it — the fields, the
//! channel order, the control period ([`CONTROL_PERIOD_US`]), the forces' alignment to the
//! position ([`FORCE_DELAY_PERIODS`]) and what `theta_rad` measures ([`THETA_SOURCE`]) — is
//! fixed by it, and a firmware that changes any of them sends another kind. Layout 1 (kind
//! `0x01`, ten fixed channels, no ports) is an older firmware's; decoders name it
//! ([`LAYOUT_1_KIND`]) instead of reading it as this one.

use crate::link::frame::{encode_frame, f32_at, BufferTooSmall, Deframer, FrameError, LinkStats};
use crate::link::frame::{max_wire_len, KIND_TELEMETRY};
use crate::safety::absent::Absent;
use crate::status::{ModeKind, Status};
use crate::units::{Ticks, CONTROL_PERIOD_US as PERIOD_US};

/// Control period the frames' sequence numbers count, µs (the firmware's).
pub const CONTROL_PERIOD_US: u32 = PERIOD_US;

/// How many control periods the section forces of a frame lag its position: each section's
/// force is computed from the current measured in the previous cycle (`control/step/
/// sense.rs`), the position from this cycle's encoder. A run log declares it as
/// `# force_delay_s` (`docs/formats.md` §1).
pub const FORCE_DELAY_PERIODS: u32 = 1;

/// What `theta_rad` measures, as a run log declares it (`# theta_source`): the servo's
/// quadrature count times its resolution.
pub const THETA_SOURCE: &str = "servo_encoder";

/// Kind of a layout-1 frame (an older firmware's telemetry), recognised only to name it.
pub const LAYOUT_1_KIND: u8 = KIND_TELEMETRY;

/// Kind of a layout-2 telemetry frame (this firmware's).
pub const KIND_SAMPLE: u8 = 0x05;

/// The frame's layout version.
pub const LAYOUT: u8 = 2;

/// Bytes before the channel values.
const HEADER_BYTES: usize = 14;

/// Number of channels a frame can carry.
pub const CHANNEL_COUNT: usize = 10;

/// The channels, by bit number: their names in a run log (`docs/formats.md` §1).
pub const CHANNELS: [&str; CHANNEL_COUNT] = [
    "x_m",
    "x_slave_m",
    "theta_rad",
    "f_master_n",
    "f_slave_n",
    "p_a_pa",
    "p_b_pa",
    "x_ref_m",
    "theta_ref_rad",
    "v_mps",
];

/// Longest payload of a telemetry frame (all channels), bytes.
pub const PAYLOAD_BYTES: usize = HEADER_BYTES + 4 * CHANNEL_COUNT;
/// Longest telemetry frame on the wire, delimiter included, bytes.
pub const WIRE_BYTES: usize = max_wire_len(PAYLOAD_BYTES);

/// Decimation the firmware starts with: one frame every 10 control cycles, 2 kHz — the
/// slowest rate `fpc-sim gap` analyses — with [`DEFAULT_CHANNELS`]: 92 kB/s, two thirds of
/// the RTT rate published for probe-rs (`docs/telemetry.md` states what each rate needs of a
/// probe).
pub const DEFAULT_DECIMATION: u16 = 10;

/// The channels the firmware starts with: the seven a run log needs ([`ChannelSet::GAP`],
/// 46 bytes a frame). `x_ref_m`, `theta_ref_rad` and `v_mps` are a request away.
pub const DEFAULT_CHANNELS: ChannelSet = ChannelSet::GAP;

/// Slowest decimation accepted: one frame every 20 000 cycles (1 Hz).
pub const MAX_DECIMATION: u16 = 20_000;

/// Which channels a frame carries: bit i = [`CHANNELS`]`[i]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChannelSet(pub u16);

impl ChannelSet {
    /// Every channel.
    pub const ALL: ChannelSet = ChannelSet((1 << CHANNEL_COUNT) - 1);
    /// The seven a run log requires (`docs/formats.md` §1), what `gap` reads.
    pub const GAP: ChannelSet = ChannelSet(0x7F);

    /// Whether the set is one a frame can carry: not empty, no bit beyond the channels.
    pub const fn valid(self) -> bool {
        self.0 != 0 && self.0 & !Self::ALL.0 == 0
    }

    /// Whether channel `i` is in the set.
    pub const fn has(self, i: usize) -> bool {
        i < CHANNEL_COUNT && self.0 & (1 << i) != 0
    }

    /// Number of channels in the set.
    pub const fn len(self) -> usize {
        (self.0 & Self::ALL.0).count_ones() as usize
    }

    /// Whether the set is empty.
    pub const fn is_empty(self) -> bool {
        self.len() == 0
    }

    /// Bytes of a frame carrying this set, on the wire (delimiter included).
    pub const fn wire_bytes(self) -> usize {
        max_wire_len(HEADER_BYTES + 4 * self.len())
    }
}

/// How the chambers are connected, as the operator declared it to the firmware (the board
/// cannot see its ports; a run log's `# ports` comes from this).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Ports {
    /// The ports are timed by the rotation (the machine's normal state; the default).
    Timed,
    /// A start-up unloader connects both chambers to the suction line (homing, moves).
    Bypassed,
    /// Every port is blanked: both chambers sealed (closed-port tests).
    Sealed,
}

impl Ports {
    /// Every declaration, in wire order.
    pub const ALL: [Ports; 3] = [Ports::Timed, Ports::Bypassed, Ports::Sealed];

    /// Wire number.
    pub const fn code(self) -> u8 {
        match self {
            Ports::Timed => 0,
            Ports::Bypassed => 1,
            Ports::Sealed => 2,
        }
    }

    /// The declaration with wire number `code`.
    pub fn from_code(code: u8) -> Option<Ports> {
        Ports::ALL.into_iter().find(|p| p.code() == code)
    }

    /// Its name as typed and logged.
    pub const fn name(self) -> &'static str {
        match self {
            Ports::Timed => "timed",
            Ports::Bypassed => "bypassed",
            Ports::Sealed => "sealed",
        }
    }
}

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
    /// The ports as declared when the frame was queued.
    pub ports: Ports,
    /// Number of the first latched fault, 0 = none (`faults.rs`).
    pub fault: u8,
    /// The parts absent since boot ([`Absent`]).
    pub absent: Absent,
    /// Frames lost so far (queue full or sink full), saturating.
    pub dropped: u16,
    /// The channels the frame carries on the wire (the values of the others are not sent;
    /// decoded, they read NaN).
    pub channels: ChannelSet,
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
        #[cfg(feature = "bench")]
        ModeKind::Bench => 8,
    }
}

/// The mode with wire number `code`.
pub fn mode_from_code(code: u8) -> Option<ModeKind> {
    #[cfg(feature = "bench")]
    if code == mode_code(ModeKind::Bench) {
        return Some(ModeKind::Bench);
    }
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
    /// The frame of a status snapshot: every channel, the ports timed (the queue sets the
    /// declaration, the telemetry task the channels sent).
    pub fn from_status(seq: u16, dropped: u16, s: &Status) -> Frame {
        Frame {
            seq,
            t: s.t,
            mode: s.mode,
            homed: s.homed,
            ports: Ports::Timed,
            fault: s.faults.first().map_or(0, |f| f as u8),
            absent: s.absent,
            dropped,
            channels: ChannelSet::ALL,
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

    /// The ten channels' values, in channel order ([`CHANNELS`]); those not carried are
    /// NaN in a decoded frame.
    pub fn values(&self) -> [f32; CHANNEL_COUNT] {
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

    /// The payload (kind byte first) into `p`; returns its length.
    pub fn payload(&self, p: &mut [u8; PAYLOAD_BYTES]) -> usize {
        let [s0, s1] = self.seq.to_le_bytes();
        let [t0, t1, t2, t3] = self.t.0.to_le_bytes();
        let [d0, d1] = self.dropped.to_le_bytes();
        let channels = ChannelSet(self.channels.0 & ChannelSet::ALL.0);
        let [c0, c1] = channels.0.to_le_bytes();
        let header = [
            KIND_SAMPLE,
            s0,
            s1,
            t0,
            t1,
            t2,
            t3,
            mode_code(self.mode),
            u8::from(self.homed) | (self.ports.code() << 1) | (self.absent.bits() << 3),
            self.fault,
            d0,
            d1,
            c0,
            c1,
        ];
        let values = self
            .values()
            .into_iter()
            .enumerate()
            .filter(|(i, _)| channels.has(*i))
            .flat_map(|(_, v)| v.to_le_bytes());
        let mut n = 0;
        for (dst, src) in p.iter_mut().zip(header.into_iter().chain(values)) {
            *dst = src;
            n += 1;
        }
        n
    }

    /// Encodes the frame for the wire into `out` ([`WIRE_BYTES`] always suffice); returns
    /// the bytes written.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
        let mut p = [0u8; PAYLOAD_BYTES];
        let n = self.payload(&mut p);
        encode_frame(p.get(..n).ok_or(BufferTooSmall)?, out)
    }

    /// Decodes a payload (as returned by the deframer). A layout-1 frame is refused as
    /// [`FrameError::UnknownKind`] ([`TelemetryDecoder`] counts those apart).
    pub fn from_payload(p: &[u8]) -> Result<Frame, FrameError> {
        let header: &[u8; HEADER_BYTES] = match p.first() {
            Some(&KIND_SAMPLE) => p
                .get(..HEADER_BYTES)
                .and_then(|h| h.try_into().ok())
                .ok_or(FrameError::BadLength)?,
            Some(_) => return Err(FrameError::UnknownKind),
            None => return Err(FrameError::TooShort),
        };
        let [_, s0, s1, t0, t1, t2, t3, mode, flags, fault, d0, d1, c0, c1] = *header;
        let channels = ChannelSet(u16::from_le_bytes([c0, c1]));
        if !channels.valid() {
            return Err(FrameError::BadValue);
        }
        if p.len() != HEADER_BYTES + 4 * channels.len() {
            return Err(FrameError::BadLength);
        }
        if flags & !0b11_1111 != 0 {
            return Err(FrameError::BadValue);
        }
        let ports = Ports::from_code(flags >> 1 & 0b11).ok_or(FrameError::BadValue)?;
        let mut values = [f32::NAN; CHANNEL_COUNT];
        let mut at = HEADER_BYTES;
        for (i, v) in values.iter_mut().enumerate() {
            if channels.has(i) {
                *v = f32_at(p, at)?;
                at += 4;
            }
        }
        let [x_m, x_slave_m, theta_rad, f_master_n, f_slave_n, p_a_pa, p_b_pa, x_ref_m, theta_ref_rad, v_mps] =
            values;
        Ok(Frame {
            seq: u16::from_le_bytes([s0, s1]),
            t: Ticks(u32::from_le_bytes([t0, t1, t2, t3])),
            mode: mode_from_code(mode).ok_or(FrameError::BadValue)?,
            homed: flags & 1 != 0,
            ports,
            fault,
            absent: Absent::from_bits(flags >> 3),
            dropped: u16::from_le_bytes([d0, d1]),
            channels,
            x_m,
            x_slave_m,
            theta_rad,
            f_master_n,
            f_slave_n,
            p_a_pa,
            p_b_pa,
            x_ref_m,
            theta_ref_rad,
            v_mps,
        })
    }
}

/// Streaming decoder of a telemetry capture: bytes in, frames out; every frame that fails
/// framing, CRC or the payload checks is rejected and counted, and decoding resumes at the
/// next delimiter. Layout-1 frames (an older firmware's) are rejected and also counted
/// apart ([`TelemetryDecoder::layout_1`]), so a host can say whose capture it was given.
#[derive(Clone, Debug, Default)]
pub struct TelemetryDecoder {
    deframer: Deframer<{ WIRE_BYTES }>,
    layout_1: u32,
}

impl TelemetryDecoder {
    /// A decoder waiting for the first frame.
    pub const fn new() -> Self {
        TelemetryDecoder {
            deframer: Deframer::new(),
            layout_1: 0,
        }
    }

    /// Feeds one byte; at the end of a frame returns it, or why it was rejected.
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame, FrameError>> {
        let mut old = false;
        let got = self.deframer.push_decoded(byte, |p| {
            old = p.first() == Some(&LAYOUT_1_KIND);
            Frame::from_payload(p)
        });
        if old {
            self.layout_1 = self.layout_1.wrapping_add(1);
        }
        got
    }

    /// Frames accepted and rejected so far.
    pub fn stats(&self) -> LinkStats {
        self.deframer.stats
    }

    /// Frames of layout 1 (kind `0x01`, an older firmware's) seen so far, all rejected.
    pub fn layout_1(&self) -> u32 {
        self.layout_1
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
            ports: Ports::ALL[(seed % 3) as usize],
            fault: (seed % 15) as u8,
            absent: Absent::from_bits((seed >> 5) as u8),
            dropped: (seed >> 3) as u16,
            channels: ChannelSet::ALL,
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

    fn payload(f: &Frame) -> Vec<u8> {
        let mut p = [0u8; PAYLOAD_BYTES];
        let n = f.payload(&mut p);
        p[..n].to_vec()
    }

    #[test]
    fn a_frame_is_58_bytes_on_the_wire_with_every_channel_and_46_with_gaps_seven() {
        assert_eq!(WIRE_BYTES, 58);
        assert_eq!(wire(&frame(7)).len(), WIRE_BYTES);
        assert_eq!(ChannelSet::ALL.wire_bytes(), 58);
        assert_eq!(ChannelSet::GAP.wire_bytes(), 46);
        let gap = Frame {
            channels: ChannelSet::GAP,
            ..frame(7)
        };
        assert_eq!(wire(&gap).len(), 46);
        let names: Vec<&str> = (0..CHANNEL_COUNT)
            .filter(|&i| ChannelSet::GAP.has(i))
            .map(|i| CHANNELS[i])
            .collect();
        assert_eq!(
            names,
            [
                "x_m",
                "x_slave_m",
                "theta_rad",
                "f_master_n",
                "f_slave_n",
                "p_a_pa",
                "p_b_pa"
            ]
        );
    }

    #[test]
    fn a_channel_set_decodes_to_its_channels_and_nan_elsewhere() {
        let f = Frame {
            channels: ChannelSet(0b10_0000_0101),
            ..frame(11)
        };
        let mut d = TelemetryDecoder::new();
        let got = decode_all(&mut d, &wire(&f));
        let back = got[0].unwrap();
        assert_eq!(back.channels, f.channels);
        let v = back.values();
        assert_eq!(v[0], f.x_m);
        assert_eq!(v[2].to_bits(), f.theta_rad.to_bits());
        assert_eq!(v[9].to_bits(), f.v_mps.to_bits());
        assert!(v[1].is_nan() && v[3].is_nan() && v[8].is_nan());
        for bad in [ChannelSet(0), ChannelSet(1 << 10)] {
            assert!(!bad.valid());
        }
    }

    #[test]
    fn every_mode_code_round_trips() {
        for c in 0..=255u8 {
            if let Some(m) = mode_from_code(c) {
                assert_eq!(mode_code(m), c);
            }
        }
        // The bench build adds `bench`.
        let modes = if cfg!(feature = "bench") { 9 } else { 8 };
        assert_eq!((0..=255u8).filter_map(mode_from_code).count(), modes);
    }

    proptest! {
        #[test]
        fn every_frame_round_trips_bit_for_bit(
            seq in any::<u16>(), t in any::<u32>(), mode in 0u8..7, homed in any::<bool>(),
            ports in 0usize..3, fault in any::<u8>(), dropped in any::<u16>(),
            set in 1u16..1024, bits in proptest::array::uniform10(any::<u32>()), absent in 0u8..8,
        ) {
            let v = bits.map(f32::from_bits);
            let f = Frame {
                seq, t: Ticks(t), mode: mode_from_code(mode).unwrap(), homed,
                ports: Ports::ALL[ports], fault, absent: Absent::from_bits(absent), dropped,
                channels: ChannelSet(set),
                x_m: v[0], x_slave_m: v[1], theta_rad: v[2], f_master_n: v[3], f_slave_n: v[4],
                p_a_pa: v[5], p_b_pa: v[6], x_ref_m: v[7], theta_ref_rad: v[8], v_mps: v[9],
            };
            let bytes = wire(&f);
            prop_assert_eq!(bytes.len(), ChannelSet(set).wire_bytes());
            let mut d = TelemetryDecoder::new();
            let got = decode_all(&mut d, &bytes);
            prop_assert_eq!(got.len(), 1);
            let back = got[0].unwrap();
            prop_assert_eq!(payload(&back), payload(&f));
            for (i, (b, want)) in back.values().iter().zip(bits).enumerate() {
                if ChannelSet(set).has(i) {
                    prop_assert_eq!(b.to_bits(), want);
                } else {
                    prop_assert!(b.is_nan());
                }
            }
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
    fn an_older_firmwares_layout_1_frame_is_rejected_and_counted_as_such() {
        // Layout 1: kind 0x01 and 51 bytes of fields, ten fixed channels.
        let mut old = [0u8; 52];
        old[0] = LAYOUT_1_KIND;
        let mut out = [0u8; WIRE_BYTES];
        let n = encode_frame(&old, &mut out).unwrap();
        let mut d = TelemetryDecoder::new();
        assert_eq!(
            decode_all(&mut d, &out[..n]),
            vec![Err(FrameError::UnknownKind)]
        );
        assert_eq!((d.layout_1(), d.stats().rejected), (1, 1));
    }

    #[test]
    fn unknown_kinds_lengths_and_values_are_rejected() {
        let mut p = [0u8; PAYLOAD_BYTES];
        let len = frame(1).payload(&mut p);
        assert_eq!(len, PAYLOAD_BYTES);
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
        // Ports code 3 (none), and a channel bit beyond the ten.
        let mut q = [0u8; PAYLOAD_BYTES];
        frame(2).payload(&mut q);
        q[8] = 0b110;
        let n = encode_frame(&q, &mut out).unwrap();
        assert_eq!(
            decode_all(&mut d, &out[..n]),
            vec![Err(FrameError::BadValue)]
        );
        frame(2).payload(&mut q);
        q[13] |= 0x04;
        let n = encode_frame(&q, &mut out).unwrap();
        assert_eq!(
            decode_all(&mut d, &out[..n]),
            vec![Err(FrameError::BadValue)]
        );
        assert_eq!(d.stats().rejected, 5);
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
                    got.last().map(|r| r.map(|g| payload(&g))),
                    Some(Ok(payload(&f)))
                );
            }
        }
        let s = d.stats();
        assert!(s.accepted > 100_000 && s.rejected > 100_000, "{s:?}");
    }
}
