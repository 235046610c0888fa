//! The triggered capture ("scope"): every control cycle, at the full 20 kHz, the seven
//! channels a run log needs go into a fixed ring in RAM while the scope is armed; a trigger
//! (the host's command, a fault latched, a mode change, the n-th stroke reversal) ends the
//! recording [`SCOPE_SAMPLES`] samples later, the part before the trigger kept as asked.
//! The command task then sends the recording to the host on the reply channel, in chunks
//! ([`encode_header`], [`encode_chunk`]), and the scope can be armed again.
//!
//! The control task calls [`Scope::record`] after it has written the outputs, so the
//! recording never delays them; while disarmed it costs one flag test
//! (`Shared::record_scope`). No allocation: the ring is a fixed array.
//!
//! # A sample (16 bytes; scales below)
//! | field | type | unit | range |
//! |---|---|---|---|
//! | `x_m` | f32 | m | the controller's own value, bit for bit |
//! | `x_slave_m − x_m` | i16 | [`SLAVE_UNIT_M`] (0.1 µm) | ±3.28 mm |
//! | `theta_rad` mod 2π | u16 | [`THETA_UNIT_RAD`] (2π/65536, 96 µrad) | one turn; unwrapped from the trigger sample's `theta_rad` |
//! | `f_master_n`, `f_slave_n` | i16 | [`FORCE_UNIT_N`] (0.5 N) | ±16.4 kN |
//! | `p_a_pa`, `p_b_pa` | u16 | [`PRESSURE_UNIT_PA`] (20 Pa) | 0–1.31 MPa |
//!
//! Codes are truncated toward zero (one `vcvt`): a decoded value is within one unit of the
//! controller's. A value beyond its range is held at the code's limit; a decoder counts the
//! samples at a limit and says so. The servo's count (4096 per turn, 1.5 mrad) is far coarser than the
//! angle's code, the pressure sensors' noise (0.5 kPa) than the pressure's.
//!
//! # Up-channel messages (reply channel, up 2)
//! | kind | message | rest |
//! |---|---|---|
//! | `0x06` | recording header | `id: u8` ‖ `trigger: u8` ‖ `arg: u16` ‖ `samples: u16` ‖ `pre: u16` ‖ `t_trigger: u32` µs ‖ `t_last: u32` µs ‖ `theta_trigger_rad: f32` ‖ `mode at trigger: u8` ‖ `mode at end: u8` ‖ `ports: u8` ‖ `fault: u8` |
//! | `0x07` | chunk | `id: u8` ‖ `index: u16` ‖ [`CHUNK_SAMPLES`] samples (the last chunk may hold fewer) |
//!
//! Samples are in time order, oldest first; sample `pre` is the trigger's cycle; they are one
//! control period apart (a decoder checks `t_last − t_trigger` against it: a recording with
//! a missed cycle is refused, never stretched).

use crate::control::command::Refusal;
use crate::link::frame::{encode_frame, max_wire_len, BufferTooSmall, FrameError};
use crate::link::telemetry::{mode_code, mode_from_code, Ports};
use crate::safety::faults::FaultSet;
use crate::status::{ModeKind, Status};
use crate::units::Ticks;

/// Samples in a recording: 512 × 16 bytes = 8 KiB of RAM, 25.6 ms at 20 kHz (a power of
/// two: the ring's index is masked).
pub const SCOPE_SAMPLES: usize = 512;
const _: () = assert!(SCOPE_SAMPLES.is_power_of_two() && SCOPE_SAMPLES <= 1 << 15);
/// Bytes of one sample.
pub const SAMPLE_BYTES: usize = 16;
/// Samples per chunk message.
pub const CHUNK_SAMPLES: usize = 16;
/// Chunks in a full recording.
pub const CHUNKS: usize = SCOPE_SAMPLES.div_ceil(CHUNK_SAMPLES);

/// Unit of the slave encoder's offset from the master's, m.
pub const SLAVE_UNIT_M: f32 = 1e-7;
/// Unit of the rotation angle, rad.
pub const THETA_UNIT_RAD: f32 = core::f32::consts::TAU / 65_536.0;
/// Unit of a section force, N.
pub const FORCE_UNIT_N: f32 = 0.5;
/// Unit of a chamber pressure, Pa.
pub const PRESSURE_UNIT_PA: f32 = 20.0;

/// Message kind of a recording header.
pub const KIND_SCOPE_HEADER: u8 = 0x06;
/// Message kind of a chunk of samples.
pub const KIND_SCOPE_CHUNK: u8 = 0x07;
/// Payload of a header message, bytes.
pub const HEADER_PAYLOAD: usize = 25;
/// Longest chunk payload, bytes.
pub const CHUNK_PAYLOAD: usize = 4 + CHUNK_SAMPLES * SAMPLE_BYTES;
/// Longest scope message on the wire, delimiter included.
pub const MAX_SCOPE_WIRE: usize = max_wire_len(CHUNK_PAYLOAD);

/// Speed a stroke reversal must pass in the new direction to count, m/s: well above the
/// differentiator's noise at a dead point, well below any stroke's speed.
pub const REVERSAL_SPEED_MPS: f32 = 0.05;

/// What ends the recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Trigger {
    /// The host's "fire" request.
    Command,
    /// A fault latched that was not latched at arming.
    Fault,
    /// The mode changed from the one at arming.
    ModeChange,
    /// The n-th stroke reversal (dead point) after arming, n ≥ 1.
    Strokes(u16),
}

impl Trigger {
    /// Wire form: code and argument.
    pub const fn code(self) -> (u8, u16) {
        match self {
            Trigger::Command => (0, 0),
            Trigger::Fault => (1, 0),
            Trigger::ModeChange => (2, 0),
            Trigger::Strokes(n) => (3, n),
        }
    }

    /// The trigger of a wire code and argument (a stroke count of 0 is none).
    pub fn from_code(code: u8, arg: u16) -> Option<Trigger> {
        match (code, arg) {
            (0, 0) => Some(Trigger::Command),
            (1, 0) => Some(Trigger::Fault),
            (2, 0) => Some(Trigger::ModeChange),
            (3, n) if n > 0 => Some(Trigger::Strokes(n)),
            _ => None,
        }
    }
}

/// A finished recording's description (what its header message carries).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Recording {
    /// Its number (counts the recordings since boot, wrapping).
    pub id: u8,
    /// What ended it.
    pub trigger: Trigger,
    /// Samples held.
    pub samples: u16,
    /// Samples before the trigger's.
    pub pre: u16,
    /// Sampling instant of the trigger's cycle.
    pub t_trigger: Ticks,
    /// Sampling instant of the last sample.
    pub t_last: Ticks,
    /// The controller's (unwrapped) rotation angle at the trigger, rad.
    pub theta_trigger_rad: f32,
    /// Mode at the trigger.
    pub mode_at_trigger: ModeKind,
    /// Mode at the last sample.
    pub mode_at_end: ModeKind,
    /// The ports as declared at the trigger.
    pub ports: Ports,
    /// First latched fault at the last sample, 0 = none.
    pub fault: u8,
}

#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Sample {
    x_m: f32,
    slave: i16,
    theta: u16,
    f_master: i16,
    f_slave: i16,
    p_a: u16,
    p_b: u16,
}

impl Sample {
    const ZERO: Sample = Sample {
        x_m: 0.0,
        slave: 0,
        theta: 0,
        f_master: 0,
        f_slave: 0,
        p_a: 0,
        p_b: 0,
    };

    #[inline(always)]
    fn of(s: &Status) -> Sample {
        // f32 → i32 is one saturating `vcvt` (NaN to 0); the clamp to 16 bits one `ssat` or
        // `usat`: a value beyond its code holds at the limit.
        let i16_of = |v: f32| (v as i32).clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16;
        let u16_of = |v: f32| (v as i32).clamp(0, i32::from(u16::MAX)) as u16;
        Sample {
            x_m: s.position_m,
            slave: i16_of((s.slave_position_m - s.position_m) * (1.0 / SLAVE_UNIT_M)),
            // The angle mod one turn: the low 16 bits of the angle in units.
            theta: (s.theta_rad * (1.0 / THETA_UNIT_RAD)) as i32 as u16,
            f_master: i16_of(s.force_master_n * (1.0 / FORCE_UNIT_N)),
            f_slave: i16_of(s.force_slave_n * (1.0 / FORCE_UNIT_N)),
            p_a: u16_of(s.pressure_a_pa * (1.0 / PRESSURE_UNIT_PA)),
            p_b: u16_of(s.pressure_b_pa * (1.0 / PRESSURE_UNIT_PA)),
        }
    }

    fn bytes(&self) -> [u8; SAMPLE_BYTES] {
        let mut out = [0u8; SAMPLE_BYTES];
        let fields = self
            .x_m
            .to_le_bytes()
            .into_iter()
            .chain(self.slave.to_le_bytes())
            .chain(self.theta.to_le_bytes())
            .chain(self.f_master.to_le_bytes())
            .chain(self.f_slave.to_le_bytes())
            .chain(self.p_a.to_le_bytes())
            .chain(self.p_b.to_le_bytes());
        for (d, s) in out.iter_mut().zip(fields) {
            *d = s;
        }
        out
    }
}

/// `repr(u8)`: the tag comes first and `Idle` is 0, so a disarmed scope is all zeros and a
/// `static` holding it needs no flash image (a niche-placed tag made it 8 KiB of `.data`).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(u8)]
enum State {
    Idle,
    Armed {
        trigger: Trigger,
        pre: u16,
        mode: ModeKind,
        faults: FaultSet,
        forward: Option<bool>,
        reversals: u16,
        fired: bool,
    },
    Recording {
        left: u16,
        pre: u16,
        t_trigger: Ticks,
        theta_trigger_rad: f32,
        mode: ModeKind,
        ports: Ports,
        trigger: Trigger,
    },
    Done(Recording),
}

/// The scope: its ring of samples and where it stands.
#[derive(Clone, Debug)]
pub struct Scope {
    ring: [Sample; SCOPE_SAMPLES],
    /// Next slot to write.
    next: u16,
    /// Samples written since arming (saturating at the ring's size).
    filled: u16,
    state: State,
    id: u8,
}

impl Default for Scope {
    fn default() -> Self {
        Self::new()
    }
}

impl Scope {
    /// A disarmed scope (all zeros: it costs no flash in a `static`).
    pub const fn new() -> Self {
        Scope {
            ring: [Sample::ZERO; SCOPE_SAMPLES],
            next: 0,
            filled: 0,
            state: State::Idle,
            id: 0,
        }
    }

    /// Arms the scope: from the next cycle every sample is kept, and `trigger` ends the
    /// recording, `pre` samples before the trigger's included (at most as many as were
    /// recorded since arming). `now` is the latest status (the trigger's reference: its
    /// mode, its faults). Refused while a recording is in progress or unsent
    /// ([`Refusal::Busy`]: wait, or disarm), or with `pre` not below [`SCOPE_SAMPLES`] or a
    /// stroke count of 0 ([`Refusal::OutOfRange`]).
    pub fn arm(&mut self, trigger: Trigger, pre: u16, now: &Status) -> Result<(), Refusal> {
        if matches!(self.state, State::Recording { .. } | State::Done(_)) {
            return Err(Refusal::Busy);
        }
        let (code, arg) = trigger.code();
        if usize::from(pre) >= SCOPE_SAMPLES || Trigger::from_code(code, arg) != Some(trigger) {
            return Err(Refusal::OutOfRange);
        }
        self.next = 0;
        self.filled = 0;
        self.state = State::Armed {
            trigger,
            pre,
            mode: now.mode,
            faults: now.faults,
            forward: None,
            reversals: 0,
            fired: false,
        };
        Ok(())
    }

    /// The host's trigger: refused unless armed with [`Trigger::Command`].
    pub fn fire(&mut self) -> Result<(), Refusal> {
        match &mut self.state {
            State::Armed {
                trigger: Trigger::Command,
                fired,
                ..
            } => {
                *fired = true;
                Ok(())
            }
            _ => Err(Refusal::NotArmed),
        }
    }

    /// Disarms, dropping any recording in progress or unsent.
    pub fn disarm(&mut self) {
        self.state = State::Idle;
    }

    /// Whether the scope is armed or recording (the control task records only then).
    pub fn active(&self) -> bool {
        matches!(self.state, State::Armed { .. } | State::Recording { .. })
    }

    /// One control cycle: keeps the sample of `s` while armed or recording, checks the
    /// trigger, ends the recording when full. `ports` is the declaration in force. Returns
    /// whether the scope is still armed or recording.
    #[inline]
    pub fn record(&mut self, s: &Status, ports: Ports) -> bool {
        match &mut self.state {
            State::Idle | State::Done(_) => return false,
            State::Armed {
                trigger,
                pre,
                mode,
                faults,
                forward,
                reversals,
                fired,
            } => {
                let triggered = match *trigger {
                    Trigger::Command => *fired,
                    Trigger::Fault => s.faults != *faults && !s.faults.is_empty(),
                    Trigger::ModeChange => s.mode != *mode,
                    Trigger::Strokes(n) => {
                        let v = s.velocity_mps;
                        let now = if v > REVERSAL_SPEED_MPS {
                            Some(true)
                        } else if v < -REVERSAL_SPEED_MPS {
                            Some(false)
                        } else {
                            *forward
                        };
                        if now != *forward && forward.is_some() {
                            *reversals = reversals.saturating_add(1);
                        }
                        *forward = now;
                        *reversals >= n
                    }
                };
                if triggered {
                    let (trigger, pre) = (*trigger, (*pre).min(self.filled));
                    self.start_recording(s, ports, trigger, pre);
                }
            }
            State::Recording { .. } => {}
        }
        // The ring's size is a power of two: the slot is the index masked.
        if let Some(slot) = self
            .ring
            .get_mut(usize::from(self.next) & (SCOPE_SAMPLES - 1))
        {
            *slot = Sample::of(s);
        }
        self.next = (self.next + 1) & (SCOPE_SAMPLES as u16 - 1);
        if usize::from(self.filled) < SCOPE_SAMPLES {
            self.filled += 1;
        }
        if let State::Recording { left, .. } = &mut self.state {
            if *left > 1 {
                *left -= 1;
            } else {
                self.finish(s);
                return false;
            }
        }
        true
    }

    /// The trigger fired: from this sample on, the rest of the ring.
    #[cold]
    #[inline(never)]
    fn start_recording(&mut self, s: &Status, ports: Ports, trigger: Trigger, pre: u16) {
        self.state = State::Recording {
            left: SCOPE_SAMPLES as u16 - pre,
            pre,
            t_trigger: s.t,
            theta_trigger_rad: s.theta_rad,
            mode: s.mode,
            ports,
            trigger,
        };
    }

    /// The ring is full: the recording is done, waiting to be sent.
    #[cold]
    #[inline(never)]
    fn finish(&mut self, s: &Status) {
        if let State::Recording {
            pre,
            t_trigger,
            theta_trigger_rad,
            mode,
            ports,
            trigger,
            ..
        } = self.state
        {
            self.id = self.id.wrapping_add(1);
            self.state = State::Done(Recording {
                id: self.id,
                trigger,
                samples: SCOPE_SAMPLES as u16,
                pre,
                t_trigger,
                t_last: s.t,
                theta_trigger_rad,
                mode_at_trigger: mode,
                mode_at_end: s.mode,
                ports,
                fault: s.faults.first().map_or(0, |f| f as u8),
            });
        }
    }

    /// The finished recording, if one waits to be sent.
    pub fn recording(&self) -> Option<Recording> {
        match self.state {
            State::Done(r) => Some(r),
            _ => None,
        }
    }

    /// Sample `i` (0 = oldest) of the finished recording, encoded.
    pub fn sample_bytes(&self, i: usize) -> Option<[u8; SAMPLE_BYTES]> {
        let r = self.recording()?;
        if i >= usize::from(r.samples) {
            return None;
        }
        // The ring is full and `next` is the oldest slot (a recording fills the ring).
        let slot = (usize::from(self.next) + i) % SCOPE_SAMPLES;
        self.ring.get(slot).map(Sample::bytes)
    }

    /// The recording has been sent: the scope is disarmed, ready to be armed again.
    pub fn release(&mut self) {
        if matches!(self.state, State::Done(_)) {
            self.state = State::Idle;
        }
    }
}

/// Encodes a recording's header message into `out` ([`MAX_SCOPE_WIRE`] suffice).
pub fn encode_header(r: &Recording, out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    let (code, arg) = r.trigger.code();
    let mut p = [0u8; HEADER_PAYLOAD];
    let bytes = [KIND_SCOPE_HEADER, r.id, code]
        .into_iter()
        .chain(arg.to_le_bytes())
        .chain(r.samples.to_le_bytes())
        .chain(r.pre.to_le_bytes())
        .chain(r.t_trigger.0.to_le_bytes())
        .chain(r.t_last.0.to_le_bytes())
        .chain(r.theta_trigger_rad.to_le_bytes())
        .chain([
            mode_code(r.mode_at_trigger),
            mode_code(r.mode_at_end),
            r.ports.code(),
            r.fault,
        ]);
    for (d, s) in p.iter_mut().zip(bytes) {
        *d = s;
    }
    encode_frame(&p, out)
}

/// Encodes chunk `index` of recording `id` from its samples' bytes into `out`.
pub fn encode_chunk(
    id: u8,
    index: u16,
    samples: &[[u8; SAMPLE_BYTES]],
    out: &mut [u8],
) -> Result<usize, BufferTooSmall> {
    if samples.is_empty() || samples.len() > CHUNK_SAMPLES {
        return Err(BufferTooSmall);
    }
    let mut p = [0u8; CHUNK_PAYLOAD];
    let [i0, i1] = index.to_le_bytes();
    let head = [KIND_SCOPE_CHUNK, id, i0, i1];
    let n = head.len() + samples.len() * SAMPLE_BYTES;
    for (d, s) in p
        .iter_mut()
        .zip(head.into_iter().chain(samples.iter().flatten().copied()))
    {
        *d = s;
    }
    encode_frame(p.get(..n).ok_or(BufferTooSmall)?, out)
}

/// A scope message as decoded on the host.
#[derive(Clone, Debug, PartialEq)]
#[allow(clippy::large_enum_variant)] // host-side, one at a time: a chunk is the common case
pub enum ScopeMessage {
    /// A recording's header.
    Header(Recording),
    /// A chunk: recording id, chunk index, its samples' bytes.
    Chunk {
        /// Recording id.
        id: u8,
        /// Chunk index (samples `index·CHUNK_SAMPLES..`).
        index: u16,
        /// Number of samples in it.
        samples: u8,
        /// Their bytes.
        bytes: [u8; CHUNK_SAMPLES * SAMPLE_BYTES],
    },
}

/// Decodes a scope message payload (kind byte first); `None` if it is not one.
pub fn decode_scope(p: &[u8]) -> Option<Result<ScopeMessage, FrameError>> {
    let (&kind, rest) = p.split_first()?;
    Some(match kind {
        KIND_SCOPE_HEADER => decode_header(rest),
        KIND_SCOPE_CHUNK => match rest {
            [id, i0, i1, data @ ..]
                if !data.is_empty()
                    && data.len() % SAMPLE_BYTES == 0
                    && data.len() <= CHUNK_SAMPLES * SAMPLE_BYTES =>
            {
                let mut bytes = [0u8; CHUNK_SAMPLES * SAMPLE_BYTES];
                if let Some(d) = bytes.get_mut(..data.len()) {
                    d.copy_from_slice(data);
                }
                Ok(ScopeMessage::Chunk {
                    id: *id,
                    index: u16::from_le_bytes([*i0, *i1]),
                    samples: (data.len() / SAMPLE_BYTES) as u8,
                    bytes,
                })
            }
            _ => Err(FrameError::BadLength),
        },
        _ => return None,
    })
}

fn decode_header(rest: &[u8]) -> Result<ScopeMessage, FrameError> {
    let &[id, code, a0, a1, s0, s1, p0, p1, t0, t1, t2, t3, l0, l1, l2, l3, h0, h1, h2, h3, mt, me, ports, fault] =
        rest
    else {
        return Err(FrameError::BadLength);
    };
    let trigger =
        Trigger::from_code(code, u16::from_le_bytes([a0, a1])).ok_or(FrameError::BadValue)?;
    let samples = u16::from_le_bytes([s0, s1]);
    let pre = u16::from_le_bytes([p0, p1]);
    if samples == 0 || usize::from(samples) > SCOPE_SAMPLES || pre >= samples {
        return Err(FrameError::BadValue);
    }
    Ok(ScopeMessage::Header(Recording {
        id,
        trigger,
        samples,
        pre,
        t_trigger: Ticks(u32::from_le_bytes([t0, t1, t2, t3])),
        t_last: Ticks(u32::from_le_bytes([l0, l1, l2, l3])),
        theta_trigger_rad: f32::from_le_bytes([h0, h1, h2, h3]),
        mode_at_trigger: mode_from_code(mt).ok_or(FrameError::BadValue)?,
        mode_at_end: mode_from_code(me).ok_or(FrameError::BadValue)?,
        ports: Ports::from_code(ports).ok_or(FrameError::BadValue)?,
        fault,
    }))
}

/// A sample's values as a run log has them: `x_m`, `x_slave_m`, `theta_rad` within one
/// turn ([0, 2π), to be unwrapped), `f_master_n`, `f_slave_n`, `p_a_pa`, `p_b_pa`; and
/// whether any field sat at its code's limit (clipped).
pub fn sample_values(b: &[u8; SAMPLE_BYTES]) -> ([f32; 7], bool) {
    let [x0, x1, x2, x3, s0, s1, h0, h1, m0, m1, f0, f1, a0, a1, b0, b1] = *b;
    let x = f32::from_le_bytes([x0, x1, x2, x3]);
    let slave = i16::from_le_bytes([s0, s1]);
    let theta = u16::from_le_bytes([h0, h1]);
    let (fm, fs) = (i16::from_le_bytes([m0, m1]), i16::from_le_bytes([f0, f1]));
    let (pa, pb) = (u16::from_le_bytes([a0, a1]), u16::from_le_bytes([b0, b1]));
    let clipped = [slave, fm, fs]
        .iter()
        .any(|v| *v == i16::MAX || *v == i16::MIN)
        || [pa, pb].contains(&u16::MAX);
    (
        [
            x,
            x + f32::from(slave) * SLAVE_UNIT_M,
            f32::from(theta) * THETA_UNIT_RAD,
            f32::from(fm) * FORCE_UNIT_N,
            f32::from(fs) * FORCE_UNIT_N,
            f32::from(pa) * PRESSURE_UNIT_PA,
            f32::from(pb) * PRESSURE_UNIT_PA,
        ],
        clipped,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::frame::Deframer;
    use crate::safety::faults::Fault;

    fn status(i: u32) -> Status {
        let t = i as f32 * 50e-6;
        Status {
            t: Ticks(1000 + 50 * i),
            mode: ModeKind::Running,
            position_m: 0.1 + 0.05 * (20.0 * t).sin(),
            slave_position_m: 0.1 + 0.05 * (20.0 * t).sin() + 3e-6,
            velocity_mps: (20.0 * t).cos(),
            theta_rad: 6.0 * t + 100.0,
            force_master_n: 800.0 * (20.0 * t).sin(),
            force_slave_n: 790.0 * (20.0 * t).sin(),
            pressure_a_pa: 2.0e5 + 1e5 * (20.0 * t).sin(),
            pressure_b_pa: 3.1e5,
            ..Status::INIT
        }
    }

    fn run(scope: &mut Scope, from: u32, to: u32) {
        for i in from..to {
            scope.record(&status(i), Ports::Timed);
        }
    }

    fn decoded(scope: &Scope) -> Vec<[f32; 7]> {
        let r = scope.recording().unwrap();
        (0..usize::from(r.samples))
            .map(|i| sample_values(&scope.sample_bytes(i).unwrap()).0)
            .collect()
    }

    #[test]
    fn a_command_trigger_keeps_the_pre_trigger_part_asked_for() {
        let mut scope = Scope::new();
        assert!(!scope.active());
        run(&mut scope, 0, 10);
        assert_eq!(scope.recording(), None, "disarmed: nothing kept");
        scope.arm(Trigger::Command, 100, &status(9)).unwrap();
        run(&mut scope, 10, 1000);
        assert!(scope.recording().is_none(), "armed, not fired");
        scope.fire().unwrap();
        run(&mut scope, 1000, 1000 + 411);
        assert!(scope.active(), "one sample to go");
        run(&mut scope, 1411, 1412);
        let r = scope.recording().unwrap();
        assert_eq!((r.samples, r.pre), (512, 100));
        assert_eq!(r.t_trigger, status(1000).t);
        assert_eq!(r.t_last.0 - r.t_trigger.0, 411 * 50);
        let v = decoded(&scope);
        for (k, row) in v.iter().enumerate() {
            let s = status(900 + k as u32);
            assert_eq!(row[0], s.position_m);
            assert!((row[1] - s.slave_position_m).abs() <= 0.51e-7 + 1e-7);
            let turn = s.theta_rad.rem_euclid(core::f32::consts::TAU);
            let d = (row[2] - turn).abs();
            assert!(d <= THETA_UNIT_RAD + 1e-4 || (d - core::f32::consts::TAU).abs() < 1e-3);
            assert!((row[3] - s.force_master_n).abs() <= FORCE_UNIT_N);
            assert!((row[5] - s.pressure_a_pa).abs() <= PRESSURE_UNIT_PA);
        }
        // Busy until released; then it arms again.
        assert_eq!(scope.arm(Trigger::Fault, 0, &status(0)), Err(Refusal::Busy));
        scope.release();
        assert!(scope.arm(Trigger::Fault, 0, &status(0)).is_ok());
    }

    #[test]
    fn a_trigger_before_the_pre_part_filled_keeps_what_there_is() {
        let mut scope = Scope::new();
        scope.arm(Trigger::Command, 300, &status(0)).unwrap();
        run(&mut scope, 0, 20);
        scope.fire().unwrap();
        run(&mut scope, 20, 20 + 492);
        let r = scope.recording().unwrap();
        assert_eq!((r.samples, r.pre), (512, 20));
        assert_eq!(decoded(&scope)[0][0], status(0).position_m);
    }

    #[test]
    fn fault_mode_and_stroke_triggers_fire_on_their_event() {
        let mut scope = Scope::new();
        let mut s = status(0);
        scope.arm(Trigger::Fault, 10, &s).unwrap();
        for _ in 0..50 {
            scope.record(&s, Ports::Sealed);
        }
        assert!(scope.recording().is_none());
        s.faults.latch(Fault::Overcurrent);
        for _ in 0..(SCOPE_SAMPLES - 10) {
            scope.record(&s, Ports::Sealed);
        }
        let r = scope.recording().unwrap();
        assert_eq!(
            (r.trigger, r.pre, r.ports),
            (Trigger::Fault, 10, Ports::Sealed)
        );
        assert_ne!(r.fault, 0);
        scope.release();

        let mut s = status(0);
        scope.arm(Trigger::ModeChange, 0, &s).unwrap();
        scope.record(&s, Ports::Timed);
        s.mode = ModeKind::Stopping;
        scope.record(&s, Ports::Timed);
        assert!(matches!(
            scope.state,
            State::Recording {
                mode: ModeKind::Stopping,
                ..
            }
        ));
        scope.disarm();

        // v = cos(20 t): reversals at t = π/40 s (cycle 1571) and 3π/40 s (cycle 4712).
        scope.arm(Trigger::Strokes(2), 0, &status(0)).unwrap();
        run(&mut scope, 0, 4700);
        assert!(scope.recording().is_none(), "one reversal only");
        run(&mut scope, 4700, 4800);
        assert!(matches!(scope.state, State::Recording { .. }));
        let State::Recording { t_trigger, .. } = scope.state else {
            unreachable!()
        };
        // Counted where the speed passes −0.05 m/s after the dead point (≈ 2.5 ms later).
        let at = (t_trigger.0 - 1000) / 50;
        assert!((4712..4712 + 60).contains(&at), "{at}");
    }

    #[test]
    fn refusals_and_the_wire_round_trip() {
        let mut scope = Scope::new();
        assert_eq!(scope.fire(), Err(Refusal::NotArmed));
        assert_eq!(
            scope.arm(Trigger::Command, SCOPE_SAMPLES as u16, &status(0)),
            Err(Refusal::OutOfRange)
        );
        assert_eq!(
            scope.arm(Trigger::Strokes(0), 0, &status(0)),
            Err(Refusal::OutOfRange)
        );
        scope.arm(Trigger::Strokes(1), 5, &status(0)).unwrap();
        assert_eq!(
            scope.fire(),
            Err(Refusal::NotArmed),
            "not a command trigger"
        );
        run(&mut scope, 0, 3000);
        let r = scope.recording().unwrap();
        let mut out = [0u8; MAX_SCOPE_WIRE];
        let mut d = Deframer::<MAX_SCOPE_WIRE>::new();
        let n = encode_header(&r, &mut out).unwrap();
        let got: Vec<_> = out[..n]
            .iter()
            .filter_map(|&b| d.push(b).map(|p| p.map(decode_scope)))
            .collect();
        assert_eq!(got, vec![Ok(Some(Ok(ScopeMessage::Header(r))))]);
        let samples: Vec<[u8; SAMPLE_BYTES]> = (0..CHUNK_SAMPLES)
            .map(|i| scope.sample_bytes(i).unwrap())
            .collect();
        let n = encode_chunk(r.id, 0, &samples, &mut out).unwrap();
        assert!(n <= MAX_SCOPE_WIRE);
        let mut got = None;
        for &b in &out[..n] {
            if let Some(p) = d.push(b) {
                got = decode_scope(p.unwrap());
            }
        }
        let Some(Ok(ScopeMessage::Chunk {
            id,
            index,
            samples: k,
            bytes,
        })) = got
        else {
            panic!("{got:?}")
        };
        assert_eq!((id, index, usize::from(k)), (r.id, 0, CHUNK_SAMPLES));
        assert_eq!(&bytes[..SAMPLE_BYTES], &samples[0]);
        assert_eq!(
            decode_scope(&[KIND_SCOPE_CHUNK, 1, 0, 0, 9]),
            Some(Err(FrameError::BadLength))
        );
        assert_eq!(decode_scope(&[0x02, 0]), None);
    }

    #[test]
    fn out_of_range_values_hold_at_the_code_limits_and_read_as_clipped() {
        let s = Status {
            slave_position_m: 0.01,
            force_master_n: -40_000.0,
            pressure_a_pa: 2.0e6,
            pressure_b_pa: f32::NAN,
            ..status(0)
        };
        let (v, clipped) = sample_values(&Sample::of(&s).bytes());
        assert!(clipped);
        assert_eq!(v[3], f32::from(i16::MIN) * FORCE_UNIT_N);
        assert_eq!(
            v[6], 0.0,
            "NaN reads as 0 (and the supervisor has faulted on it)"
        );
        let (_, clean) = sample_values(&Sample::of(&status(3)).bytes());
        assert!(!clean);
    }
}
