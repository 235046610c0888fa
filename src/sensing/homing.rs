//! Homing: find the zero of the incremental encoders by creeping to head A.
//!
//! The paper's procedure: move the piston slowly toward the extreme position and detect the
//! current rising when the piston stops. Here the controller follows a creep reference under
//! a force limit (the homing current limit × K_f); the stop is declared when the force the
//! motor delivers (from the measured q-currents) has stayed at or above the detection level
//! for the detection time *and* the piston has not moved meanwhile. A friction spike mid-travel
//! raises the force for a few milliseconds only and is ignored; a piston that still creeps
//! under a high force is not on the stop. The zero is the position where it was declared.
//!
//! The reference never runs more than [`LEAD_M`] ahead of the piston, so the force on the stop
//! is set by the force limit, not by a growing position error, and a stalled search resumes
//! smoothly. The search fails cleanly (the controller latches `homing_failed`, outputs off)
//! once the piston or the reference is further than the maximum search distance from the
//! start: the current never exceeds the homing limit on the way.

/// How far the creep reference may lead the piston, m.
pub const LEAD_M: f32 = 0.003;

/// Fraction of the homing force limit the force command may use: the current loop overshoots
/// a saturated step by ~1 % (measured on the simulated motor), 5 % keeps it under the limit.
pub const COMMAND_MARGIN: f32 = 0.95;

/// Homing parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomingConfig {
    /// Creep speed toward head A, m/s (> 0).
    pub creep_speed_mps: f32,
    /// Homing current limit × K_f (both sections), N: the current must never exceed it. The
    /// force *command* is held [`COMMAND_MARGIN`] below it, room for the current loop's
    /// overshoot when the piston meets the stop.
    pub force_limit_n: f32,
    /// Force that counts as "pushing on the stop", N (< the limit).
    pub detect_force_n: f32,
    /// How long the force must stay above the detection level, s (4× the longest friction
    /// spike to ignore, 5 ms).
    pub detect_time_s: f32,
    /// Largest movement while the force is above the detection level, m: on the stop the
    /// piston only compresses the contact (µm).
    pub stall_travel_m: f32,
    /// Maximum search distance, m (more than the travel).
    pub max_search_m: f32,
}

impl HomingConfig {
    /// Reference: 10 mm/s, 400 N limit, 250 N for 20 ms within 20 µm, 0.25 m search.
    pub const fn reference() -> Self {
        HomingConfig {
            creep_speed_mps: 0.01,
            force_limit_n: 400.0,
            detect_force_n: 250.0,
            detect_time_s: 0.02,
            stall_travel_m: 20e-6,
            max_search_m: 0.25,
        }
    }
}

/// What homing asks of the controller this cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HomingStep {
    /// Keep creeping: position reference (raw encoder frame, m) and the force limit.
    Creep {
        /// Position reference, raw frame, m.
        reference_m: f32,
        /// Force limit, N.
        force_limit_n: f32,
    },
    /// The stop is found at this raw position, m: it becomes x = 0.
    Found {
        /// Raw encoder position at the stop, m.
        stop_raw_m: f32,
    },
    /// No stop within the search distance.
    Failed,
}

/// Homing state.
#[derive(Clone, Debug)]
pub struct Homing {
    config: HomingConfig,
    start_raw_m: f32,
    reference_m: f32,
    /// Time the force has been above the detection level, s, and where the piston was when
    /// it rose.
    above_s: f32,
    above_from_m: f32,
    /// The first step has set the start from a measured position.
    started: bool,
}

impl Homing {
    /// Starts homing from about the raw position `start_raw_m`. The first [`Homing::step`]
    /// takes the measured position as the true start: the command may arrive before the
    /// encoders' first sample of the cycle, and a reference behind the piston would slam it.
    pub fn new(config: HomingConfig, start_raw_m: f32) -> Self {
        Homing {
            config,
            start_raw_m,
            reference_m: start_raw_m,
            above_s: 0.0,
            above_from_m: start_raw_m,
            started: false,
        }
    }

    /// One cycle of `dt_s`: measured raw position and the force the motor delivers (N,
    /// from the measured currents; negative = pushing toward head A). Non-finite inputs
    /// count as "not on the stop" and never move the reference.
    pub fn step(&mut self, raw_position_m: f32, measured_force_n: f32, dt_s: f32) -> HomingStep {
        if !self.started && raw_position_m.is_finite() {
            self.started = true;
            self.start_raw_m = raw_position_m;
            self.reference_m = raw_position_m;
            self.above_from_m = raw_position_m;
        }
        let c = &self.config;
        // NaN-safe: a NaN force fails the comparison.
        if -measured_force_n >= c.detect_force_n {
            if self.above_s == 0.0 {
                self.above_from_m = raw_position_m;
            }
            self.above_s += dt_s;
        } else {
            self.above_s = 0.0;
        }
        let stalled = (raw_position_m - self.above_from_m).abs() <= c.stall_travel_m;
        if self.above_s >= c.detect_time_s {
            if stalled {
                return HomingStep::Found {
                    stop_raw_m: raw_position_m,
                };
            }
            // Pushing hard but still moving: not the stop. Start the interval again here.
            self.above_s = 0.0;
        }
        // The piston has gone the whole search distance (or the reference a lead beyond
        // it). NaN-safe: a NaN distance is not "within".
        let piston_within = self.start_raw_m - raw_position_m <= c.max_search_m;
        let reference_within = self.start_raw_m - self.reference_m <= c.max_search_m + LEAD_M;
        if !(piston_within && reference_within) {
            return HomingStep::Failed;
        }
        let next = self.reference_m - c.creep_speed_mps * dt_s;
        let lead_limit = raw_position_m - LEAD_M;
        if next.is_finite() {
            self.reference_m = if lead_limit.is_finite() {
                crate::real::max_f32(next, lead_limit)
            } else {
                self.reference_m
            };
        }
        HomingStep::Creep {
            reference_m: self.reference_m,
            force_limit_n: c.force_limit_n * COMMAND_MARGIN,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f32 = 50e-6;

    #[test]
    fn a_short_spike_is_ignored_and_a_sustained_push_is_found() {
        let mut h = Homing::new(HomingConfig::reference(), 0.1);
        // 5 ms spike at 300 N.
        for _ in 0..100 {
            assert!(matches!(h.step(0.09, -300.0, DT), HomingStep::Creep { .. }));
        }
        let mut found = None;
        for i in 0..1000 {
            if let HomingStep::Found { stop_raw_m } =
                h.step(0.02, if i > 10 { -300.0 } else { 0.0 }, DT)
            {
                found = Some((i, stop_raw_m));
                break;
            }
        }
        let (i, at) = found.unwrap();
        assert!((i as f32 * DT - 0.02).abs() < 1e-3 + DT * 12.0);
        assert_eq!(at, 0.02);
    }

    #[test]
    fn a_high_force_while_still_moving_is_not_the_stop() {
        let mut h = Homing::new(HomingConfig::reference(), 0.1);
        // 40 ms at 300 N while creeping 10 mm/s (0.4 mm): never found.
        for i in 0..800 {
            let x = 0.09 - i as f32 * 0.01 * DT;
            assert!(matches!(h.step(x, -300.0, DT), HomingStep::Creep { .. }));
        }
    }

    #[test]
    fn fails_beyond_the_search_distance() {
        let mut h = Homing::new(HomingConfig::reference(), 0.3);
        assert!(matches!(h.step(0.3, 0.0, DT), HomingStep::Creep { .. }));
        assert_eq!(h.step(0.3 - 0.26, 0.0, DT), HomingStep::Failed);
        let mut h = Homing::new(HomingConfig::reference(), 0.3);
        assert!(matches!(h.step(0.3, 0.0, DT), HomingStep::Creep { .. }));
        assert_eq!(h.step(f32::NAN, 0.0, DT), HomingStep::Failed);
    }

    #[test]
    fn the_start_is_the_first_measured_position() {
        // Created with a stale position (0), first stepped at 8 mm: the reference starts
        // at 8 mm, not 8 mm behind the piston.
        let mut h = Homing::new(HomingConfig::reference(), 0.0);
        match h.step(0.008, 0.0, DT) {
            HomingStep::Creep {
                reference_m,
                force_limit_n,
            } => {
                assert!((reference_m - 0.008).abs() < 1e-6);
                assert!(force_limit_n < HomingConfig::reference().force_limit_n);
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn the_reference_never_leads_by_more_than_the_limit() {
        let mut h = Homing::new(HomingConfig::reference(), 0.1);
        // The piston is blocked at 0.1 m for 1 s: the reference stops 3 mm ahead.
        let mut last = 0.1;
        for _ in 0..20_000 {
            if let HomingStep::Creep { reference_m, .. } = h.step(0.1, f32::NAN, DT) {
                last = reference_m;
            }
        }
        assert!((last - (0.1 - LEAD_M)).abs() < 1e-6, "{last}");
    }
}
