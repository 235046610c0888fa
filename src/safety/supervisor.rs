//! Supervision in the 20 kHz step: the checks that decide when the machine must stop.
//!
//! Each check is a small filter over one measured quantity; a check that trips names a
//! [`Fault`]. The controller latches it and carries out its reaction
//! ([`Fault::reaction`]): a controlled stop on the braking envelope (SS1) while the
//! position can be trusted, outputs off at once (STO) when it cannot. SS1 ends in a hold
//! that releases the outputs only once holding needs no force (a compressed chamber would
//! otherwise throw the piston). Limits that are merely active (force saturated, envelope
//! clamp) are [`LimitFlags`], not faults. The rotation check only applies while compressing:
//! then the ports need the rotation; in a stop it only holds.
//!
//! The braking envelope (`docs/faults.md`): at every instant
//! `|v| ≤ √(2·a_brake·(d − d_min))`, with `d` the distance to the head the piston moves
//! toward, `d_min` = 0.3 mm and `a_brake` what one section alone can do against the worst gas
//! force, so that either section can still stop the piston.

use crate::real::{max_f32, sqrt_f32};

use crate::safety::faults::{Fault, Trip};
use crate::units::{PerSection, Section};

/// The reference machine's `a_brake`, m/s² ([`SupervisorConfig::reference`]).
const BRAKE_DECELERATION_MPS2: f32 = 150.0;

/// Limits of the supervisor, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SupervisorConfig {
    /// Head-to-head travel, m.
    pub travel_m: f32,
    /// Clearance never to be crossed, m (0.3 mm).
    pub min_clearance_m: f32,
    /// Deceleration one section alone guarantees, m/s² (the envelope's `a_brake`; fixed at
    /// construction with the envelope's constant below).
    brake_deceleration_mps2: f32,
    /// The envelope's squared speed per metre of margin with its 5 % on the speed,
    /// `1.05²·2·a_brake`, m/s² (the root-free check's factor, taken where `a_brake` is set).
    envelope_mps2: f32,
    /// Speed above which `Overspeed` trips, m/s (1.2 × the largest commanded speed).
    pub overspeed_mps: f32,
    /// Phase-current magnitude that trips `Overcurrent`, A.
    pub overcurrent_a: f32,
    /// Master/slave position disagreement that trips `EncoderMismatch`, m.
    pub encoder_mismatch_m: f32,
    /// Position error of the following-error check, m.
    pub following_error_m: f32,
    /// Time the position error must persist, s.
    pub following_error_time_s: f32,
    /// Force shortfall of one section (commanded − measured) that counts as a lost section, N.
    pub section_shortfall_n: f32,
    /// Time a section's shortfall must persist, s.
    pub section_time_s: f32,
    /// Rotation error that trips `RotationSync`, rad.
    pub rotation_error_rad: f32,
    /// Rotation error that trips `RotationSync` when the rotation has (all but) stopped
    /// while its reference moves on — a blocked rotation — rad.
    pub rotation_stall_error_rad: f32,
    /// Time the rotation error must persist, s.
    pub rotation_time_s: f32,
}

impl SupervisorConfig {
    /// Reference limits: 150 m/s² braking (one 5 kN section against 2.5 kN of gas force on
    /// 13.2 kg, i.e. the mass +10 %, with margin), overspeed at 1.2 × 4.5 m/s, 70 A,
    /// 2 mm encoder mismatch (the paper saw up to 1 mm at the magnetic pitch); rotation
    /// sync for 1 ms at 0.35 rad (the servo tracks within 0.07 rad on the reference machine,
    /// 0.21 rad at 4.5 m/s with a 0.5 ms actuator lag), or at 0.1 rad while the rotation
    /// turns at less than a quarter of its reference's speed: a blocked rotation trips within
    /// 5 ms once its reference moves at ≥ 25 rad/s (mid-stroke: 40–65 rad/s).
    pub const fn reference() -> Self {
        SupervisorConfig {
            travel_m: crate::reference::piston::TRAVEL_M as f32,
            min_clearance_m: crate::reference::limits::MIN_HEAD_CLEARANCE_M as f32,
            brake_deceleration_mps2: BRAKE_DECELERATION_MPS2,
            envelope_mps2: 1.05 * 1.05 * 2.0 * BRAKE_DECELERATION_MPS2,
            overspeed_mps: 5.4,
            overcurrent_a: 70.0,
            encoder_mismatch_m: 2.0e-3,
            following_error_m: 2.0e-3,
            following_error_time_s: 5e-3,
            section_shortfall_n: 400.0,
            section_time_s: 5e-3,
            rotation_error_rad: 0.35,
            rotation_stall_error_rad: 0.1,
            rotation_time_s: 1e-3,
        }
    }

    /// Deceleration one section alone guarantees, m/s² (the envelope's `a_brake`).
    #[inline(always)]
    pub fn brake_deceleration_mps2(&self) -> f32 {
        self.brake_deceleration_mps2
    }

    /// The largest speed the envelope allows at `position_m` moving with sign of `velocity`
    /// (m/s, ≥ 0; zero at or inside the minimum clearance).
    #[inline]
    pub fn envelope_speed_mps(&self, position_m: f32, velocity_mps: f32) -> f32 {
        let distance = if velocity_mps >= 0.0 {
            self.travel_m - position_m
        } else {
            position_m
        };
        let margin = distance - self.min_clearance_m;
        if margin <= 0.0 {
            0.0
        } else {
            sqrt_f32(2.0 * self.brake_deceleration_mps2 * margin)
        }
    }
}

impl SupervisorConfig {
    /// Whether `velocity_mps` at `position_m` breaks the braking envelope, with 5 % and
    /// 2 cm/s of margin so that velocity noise alone never trips it:
    /// `|v| > 1.05·√(2·a_brake·(d − d_min)) + 0.02`, compared squared (no root in the 20 kHz
    /// step). NaN never trips (the differentiator's output is finite by construction).
    #[inline]
    pub fn envelope_violated(&self, position_m: f32, velocity_mps: f32) -> bool {
        let distance = if velocity_mps >= 0.0 {
            self.travel_m - position_m
        } else {
            position_m
        };
        let margin = max_f32(distance - self.min_clearance_m, 0.0);
        let excess = velocity_mps.abs() - 0.02;
        excess > 0.0 && excess * excess > self.envelope_mps2 * margin
    }
}

/// Limits active this cycle (information, not faults).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct LimitFlags {
    /// The total force command was saturated.
    pub force: bool,
    /// A current loop hit its voltage limit.
    pub voltage: bool,
    /// The setpoint was clamped to the braking envelope.
    pub envelope: bool,
}

/// What the supervisor sees in one cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Observation {
    /// Cycle time, s.
    pub dt_s: f32,
    /// The zero is known (position-based checks are meaningless before homing).
    pub homed: bool,
    /// The motor outputs are on.
    pub driving: bool,
    /// Position (master encoder), m.
    pub position_m: f32,
    /// Position from the slave encoder, m.
    pub slave_position_m: f32,
    /// Velocity, m/s.
    pub velocity_mps: f32,
    /// Position reference, m (when driving).
    pub reference_m: f32,
    /// Largest phase-current magnitude of each section, A.
    pub peak_phase_a: PerSection<f32>,
    /// Force commanded to each section, N.
    pub commanded_n: PerSection<f32>,
    /// Force each section delivers (measured q-current × K_f), N.
    pub delivered_n: PerSection<f32>,
    /// Rotation reference minus measured angle, rad (0 when the servo is not controlled).
    pub rotation_error_rad: f32,
    /// The rotation has (all but) stopped while its reference moves on: it turns at less
    /// than a quarter of the reference's speed.
    pub rotation_stalled: bool,
}

/// Supervision state (the persistence timers).
#[derive(Clone, Debug, Default)]
pub struct Supervisor {
    following_s: f32,
    section_s: PerSection<f32>,
    rotation_s: f32,
}

impl Supervisor {
    /// A supervisor with all timers at zero.
    pub const fn new() -> Self {
        Supervisor {
            following_s: 0.0,
            section_s: PerSection {
                master: 0.0,
                slave: 0.0,
            },
            rotation_s: 0.0,
        }
    }

    /// Forgets persistence (after a stop or a mode change that resets references).
    pub fn reset(&mut self) {
        *self = Supervisor::new();
    }

    /// Runs every check once: the first fault found this cycle, if any (others follow on
    /// later cycles if they persist; the cause is the first), as a [`Trip`] with the
    /// reaction its kind asks for and the sections to drop — a section found lost (whatever
    /// fault came first), the one with the larger phase current on an overcurrent.
    pub fn check(&mut self, c: &SupervisorConfig, o: &Observation) -> Option<Trip> {
        // The persistence timers first: they advance whatever fault this cycle finds.
        let following = o.driving && o.homed;
        self.following_s = persist(
            self.following_s,
            following && (o.reference_m - o.position_m).abs() > c.following_error_m,
            o.dt_s,
        );
        let mut lost = None;
        if o.driving {
            // A section that delivers far less than asked, in the asked direction. The
            // delivered force along the command, `got·sgn(cmd)`, by a sign flip on the
            // command's sign bit (the same for every non-NaN `cmd`; a NaN one is never
            // short: its margin compares false). The margin `|cmd| − shortfall` is positive
            // exactly when `|cmd|` exceeds the shortfall (a float difference of two finite
            // values is positive iff the first is larger).
            let short = |cmd: f32, got: f32| {
                let margin = cmd.abs() - c.section_shortfall_n;
                let along = if cmd.is_sign_negative() { -got } else { got };
                margin > 0.0 && along < margin
            };
            // Written out per section (a loop indexes every field by section).
            let (cmd, got, timers) = (&o.commanded_n, &o.delivered_n, &mut self.section_s);
            timers.master = persist(timers.master, short(cmd.master, got.master), o.dt_s);
            timers.slave = persist(timers.slave, short(cmd.slave, got.slave), o.dt_s);
            // One section found lost a cycle, the master first.
            lost = if timers.master >= c.section_time_s {
                Some(Section::Master)
            } else if timers.slave >= c.section_time_s {
                Some(Section::Slave)
            } else {
                None
            };
            let error = o.rotation_error_rad.abs();
            // A blocked rotation: the reference moves on, the rotation does not — caught at a
            // smaller error than a rotation that merely lags.
            let stalled = o.rotation_stalled && error > c.rotation_stall_error_rad;
            self.rotation_s = persist(
                self.rotation_s,
                error > c.rotation_error_rad || stalled,
                o.dt_s,
            );
        } else {
            self.section_s = PerSection::default();
            self.rotation_s = 0.0;
        }
        // Then the checks in the order of their precedence, the first that fails named. A
        // timer is 0 while its check does not apply, and every persistence time is positive
        // (`ControlConfig::check`): a timer at its time needs no test of the mode.
        // NaN-safe in one compare: a NaN current is not within the limit, and trips.
        let within = max_f32(o.peak_phase_a.master, o.peak_phase_a.slave) <= c.overcurrent_a;
        let fault = if !within {
            Fault::Overcurrent
        } else if o.homed && (o.position_m - o.slave_position_m).abs() > c.encoder_mismatch_m {
            Fault::EncoderMismatch
        } else if o.homed && o.velocity_mps.abs() > c.overspeed_mps {
            Fault::Overspeed
        } else if o.homed && c.envelope_violated(o.position_m, o.velocity_mps) {
            Fault::BrakingEnvelope
        } else if self.following_s >= c.following_error_time_s {
            Fault::FollowingError
        } else if lost.is_some() {
            Fault::SectionFault
        } else if self.rotation_s >= c.rotation_time_s {
            Fault::RotationSync
        } else {
            return None;
        };
        Some(trip(fault, lost, o.peak_phase_a))
    }
}

/// The supervisor's trip for `fault`: the section found `lost` dropped whatever the fault,
/// and on an overcurrent the section with the larger phase current (`peak_phase_a`, A; the
/// master on a tie) as well. Out of line: a healthy cycle never builds one.
#[cold]
#[inline(never)]
fn trip(fault: Fault, lost: Option<Section>, peak_phase_a: PerSection<f32>) -> Trip {
    let mut trip = Trip::of(fault);
    if fault == Fault::Overcurrent {
        let hotter = if peak_phase_a.master >= peak_phase_a.slave {
            Section::Master
        } else {
            Section::Slave
        };
        trip = trip.dropping(hotter);
    }
    match lost {
        Some(section) => trip.dropping(section),
        None => trip,
    }
}

/// A persistence timer: grows by `dt` while `active`, else resets.
#[inline]
fn persist(timer_s: f32, active: bool, dt_s: f32) -> f32 {
    if active {
        timer_s + dt_s
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs() -> Observation {
        Observation {
            dt_s: 50e-6,
            homed: true,
            driving: true,
            position_m: 0.1,
            slave_position_m: 0.1,
            reference_m: 0.1,
            ..Observation::default()
        }
    }

    #[test]
    fn envelope_speed_shrinks_to_zero_at_the_minimum_clearance() {
        let c = SupervisorConfig::reference();
        assert_eq!(c.envelope_speed_mps(0.2048, 1.0), 0.0);
        assert!((c.envelope_speed_mps(0.1, -1.0) - (300.0f32 * 0.0997).sqrt()).abs() < 1e-3);
        // Moving away from the near head, the far head counts.
        assert!(c.envelope_speed_mps(0.001, 1.0) > 5.0);
    }

    #[test]
    fn a_fast_approach_to_a_head_trips_the_envelope() {
        let c = SupervisorConfig::reference();
        let mut s = Supervisor::new();
        let mut o = obs();
        o.position_m = 0.005;
        o.slave_position_m = 0.005;
        o.reference_m = 0.005;
        o.velocity_mps = -2.0;
        assert_eq!(
            s.check(&c, &o).map(|t| t.fault),
            Some(Fault::BrakingEnvelope)
        );
        o.velocity_mps = -1.0;
        assert_eq!(s.check(&c, &o).map(|t| t.fault), None);
    }

    #[test]
    fn following_error_needs_persistence() {
        let c = SupervisorConfig::reference();
        let mut s = Supervisor::new();
        let mut o = obs();
        o.reference_m = 0.105;
        let mut tripped = None;
        for i in 0..200 {
            if s.check(&c, &o).map(|t| t.fault) == Some(Fault::FollowingError) {
                tripped = Some(i);
                break;
            }
        }
        // 5 ms at 50 µs = 100 cycles (±1 for the f32 sum of the steps).
        assert!(matches!(tripped, Some(98..=100)), "{tripped:?}");
    }

    #[test]
    fn a_section_that_delivers_nothing_is_named() {
        let c = SupervisorConfig::reference();
        let mut s = Supervisor::new();
        let mut o = obs();
        o.commanded_n = PerSection {
            master: 1500.0,
            slave: 1500.0,
        };
        o.delivered_n = PerSection {
            master: 1500.0,
            slave: 0.0,
        };
        let mut v = None;
        for _ in 0..110 {
            if v.is_none() {
                v = s.check(&c, &o);
            }
        }
        let v = v.unwrap();
        assert_eq!(v.fault, Fault::SectionFault);
        assert_eq!((v.drop.master, v.drop.slave), (false, true));
    }

    #[test]
    fn the_root_free_envelope_check_is_the_envelope_with_its_margin() {
        let c = SupervisorConfig::reference();
        for i in 0..=400 {
            let x = c.travel_m * i as f32 / 400.0;
            for j in -60..=60 {
                let v = j as f32 * 0.1;
                let by_root = v.abs() > c.envelope_speed_mps(x, v) * 1.05 + 0.02;
                // Within rounding of the boundary the two may differ; elsewhere never.
                let near = (v.abs() - (c.envelope_speed_mps(x, v) * 1.05 + 0.02)).abs() < 1e-3;
                assert!(near || by_root == c.envelope_violated(x, v), "x {x} v {v}");
            }
        }
        assert!(!c.envelope_violated(0.1, f32::NAN));
    }

    #[test]
    fn a_blocked_rotation_trips_at_a_smaller_error_than_a_lagging_one() {
        let c = SupervisorConfig::reference();
        let mut s = Supervisor::new();
        let mut o = obs();
        // Lagging 0.2 rad behind a moving reference: within the limit.
        o.rotation_error_rad = 0.2;
        for _ in 0..200 {
            assert_eq!(s.check(&c, &o).map(|t| t.fault), None);
        }
        // The same error with the rotation stopped: 1 ms later (20 cycles, ±1 for the f32
        // sum of the steps), RotationSync.
        o.rotation_stalled = true;
        let n =
            (0..100).position(|_| s.check(&c, &o).map(|t| t.fault) == Some(Fault::RotationSync));
        assert!(matches!(n, Some(18..=20)), "{n:?}");
    }

    #[test]
    fn overcurrent_and_nan_trip_at_once() {
        let c = SupervisorConfig::reference();
        let mut s = Supervisor::new();
        let mut o = obs();
        o.peak_phase_a.slave = 80.0;
        let t = s.check(&c, &o).unwrap();
        assert_eq!(t.fault, Fault::Overcurrent);
        // The hotter section is the one taken out.
        assert_eq!((t.drop.master, t.drop.slave), (false, true));
        o.peak_phase_a.master = f32::NAN;
        assert_eq!(s.check(&c, &o).map(|t| t.fault), Some(Fault::Overcurrent));
    }
}
