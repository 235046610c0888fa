//! Homing: find the zero of the incremental encoders by creeping to head A.
//!
//! The paper's procedure: move the piston slowly toward the extreme position and detect the
//! current rising when the piston stops. Here the controller creeps with a force limit; the
//! stop is declared when the force (from the measured q-currents) stays above the detection
//! level for the detection time — a short friction spike does not last that long and is
//! ignored. The search fails cleanly after the maximum search distance.

/// Homing parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomingConfig {
    /// Creep speed toward head A, m/s (> 0).
    pub creep_speed_mps: f32,
    /// Force limit while homing (the homing current limit × K_f), N.
    pub force_limit_n: f32,
    /// Force that counts as "pushing on the stop", N (< the limit).
    pub detect_force_n: f32,
    /// How long the force must stay above the detection level, s.
    pub detect_time_s: f32,
    /// Maximum search distance, m (more than the travel).
    pub max_search_m: f32,
}

impl HomingConfig {
    /// Reference: 10 mm/s, 400 N limit, 250 N for 20 ms, 0.25 m search.
    pub const fn reference() -> Self {
        HomingConfig {
            creep_speed_mps: 0.01,
            force_limit_n: 400.0,
            detect_force_n: 250.0,
            detect_time_s: 0.02,
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
    above_s: f32,
}

impl Homing {
    /// Starts homing from the raw position `start_raw_m`.
    pub fn new(config: HomingConfig, start_raw_m: f32) -> Self {
        Homing {
            config,
            start_raw_m,
            reference_m: start_raw_m,
            above_s: 0.0,
        }
    }

    /// One cycle of `dt_s`: measured raw position and the force the motor delivers (N,
    /// from the measured currents; negative = pushing toward head A).
    pub fn step(&mut self, raw_position_m: f32, measured_force_n: f32, dt_s: f32) -> HomingStep {
        let c = &self.config;
        if -measured_force_n >= c.detect_force_n {
            self.above_s += dt_s;
        } else {
            self.above_s = 0.0;
        }
        if self.above_s >= c.detect_time_s {
            return HomingStep::Found {
                stop_raw_m: raw_position_m,
            };
        }
        if self.start_raw_m - raw_position_m > c.max_search_m
            || self.start_raw_m - self.reference_m > c.max_search_m + 0.01
        {
            return HomingStep::Failed;
        }
        // The reference never runs more than a few mm ahead of the piston, so the force
        // on the stop is bounded by the limit, not by a growing position error.
        let lead_limit = raw_position_m - 0.003;
        self.reference_m = (self.reference_m - c.creep_speed_mps * dt_s).max(lead_limit);
        HomingStep::Creep {
            reference_m: self.reference_m,
            force_limit_n: c.force_limit_n,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_short_spike_is_ignored_and_a_sustained_push_is_found() {
        let mut h = Homing::new(HomingConfig::reference(), 0.1);
        let dt = 50e-6;
        // 5 ms spike at 300 N.
        for _ in 0..100 {
            assert!(matches!(h.step(0.09, -300.0, dt), HomingStep::Creep { .. }));
        }
        let mut found = None;
        for i in 0..1000 {
            if let HomingStep::Found { stop_raw_m } =
                h.step(0.02, if i > 10 { -300.0 } else { 0.0 }, dt)
            {
                found = Some((i, stop_raw_m));
                break;
            }
        }
        let (i, at) = found.unwrap();
        assert!((i as f32 * dt - 0.02).abs() < 1e-3 + dt * 12.0);
        assert_eq!(at, 0.02);
    }

    #[test]
    fn fails_beyond_the_search_distance() {
        let mut h = Homing::new(HomingConfig::reference(), 0.3);
        assert_eq!(h.step(0.3 - 0.26, 0.0, 50e-6), HomingStep::Failed);
    }
}
