//! The periodic stroke of the compressor: back-to-back strokes between the two dead points,
//! with a next-stroke correction that makes the reached dead points converge to the targets.
//!
//! Each half cycle is a minimum-jerk stroke (zero velocity *and* acceleration at the dead
//! points): the motor accelerates the piston, the inertia stored in mid-stroke is given back
//! while the gas force rises toward the dead point (the paper's Fig. 9), and the jerk stays
//! bounded (peak `60·D/T³`). With the braking deceleration of one section ≥ 150 m/s², the
//! profile stays inside the braking envelope up to 4.5 m/s (peak required deceleration
//! 149.5 m/s² at 4.5 m/s, 124 m/s² at 4.1 m/s, for a 0.203 m stroke and 1 mm clearance).
//!
//! Dead-point control: within a stroke the position loop tracks the profile; after each
//! stroke the reached extreme (measured) is compared with its target and the *commanded*
//! end point of the next stroke toward that head moves by −gain × error, so a steady offset
//! (leakage, friction, a gas-force model error) is removed in a few cycles.

use crate::motion::trajectory::{PointToPoint, Setpoint};
use crate::real::{clamp_f32, max_f32, min_f32};

/// Which way the piston is going.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Direction {
    /// From head A toward head B (x increasing): chamber B compresses.
    TowardB,
    /// From head B toward head A (x decreasing): chamber A compresses.
    TowardA,
}

/// Stroke parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StrokeConfig {
    /// Target dead point at the A end, m.
    pub dead_a_m: f32,
    /// Target dead point at the B end, m.
    pub dead_b_m: f32,
    /// Peak speed, m/s.
    pub peak_speed_mps: f32,
    /// Fraction of the dead-point error corrected per stroke (0..1).
    pub correction_gain: f32,
    /// Largest correction of a commanded end point, m (it can never move the command past
    /// the target by more than this, toward the head).
    pub max_correction_m: f32,
}

impl StrokeConfig {
    /// Dead points 1 mm from each head of a 0.205 m travel, at `peak_speed_mps`.
    pub fn reference(peak_speed_mps: f32) -> Self {
        StrokeConfig {
            dead_a_m: 1.0e-3,
            dead_b_m: 0.204,
            peak_speed_mps,
            correction_gain: 0.6,
            max_correction_m: 0.3e-3,
        }
    }
}

/// A dead point reached: reported once per half cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeadPoint {
    /// Which end (the direction of the stroke that just ended).
    pub end: Direction,
    /// Its target, m.
    pub target_m: f32,
    /// The extreme position measured during the stroke, m.
    pub reached_m: f32,
}

/// The stroke generator.
#[derive(Clone, Debug)]
pub struct StrokeGenerator {
    config: StrokeConfig,
    direction: Direction,
    path: PointToPoint,
    elapsed_s: f32,
    /// Commanded end points (targets + corrections), m.
    command_a_m: f32,
    command_b_m: f32,
    /// Measured extreme in the current stroke, m (NaN until the stroke's first sample: the
    /// comparisons of [`max_f32`] and [`min_f32`] then take the sample).
    extreme_m: f32,
    half_cycles: u32,
    stop_requested: bool,
}

impl StrokeGenerator {
    /// Starts stroking from rest at `from_m` toward the farther dead point.
    pub fn new(config: StrokeConfig, from_m: f32) -> Self {
        let direction = if from_m - config.dead_a_m < config.dead_b_m - from_m {
            Direction::TowardB
        } else {
            Direction::TowardA
        };
        let target = match direction {
            Direction::TowardB => config.dead_b_m,
            Direction::TowardA => config.dead_a_m,
        };
        StrokeGenerator {
            path: PointToPoint::new(from_m, target, config.peak_speed_mps),
            config,
            direction,
            elapsed_s: 0.0,
            command_a_m: config.dead_a_m,
            command_b_m: config.dead_b_m,
            extreme_m: f32::NAN,
            half_cycles: 0,
            stop_requested: false,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &StrokeConfig {
        &self.config
    }

    /// Direction of the current stroke.
    pub fn direction(&self) -> Direction {
        self.direction
    }

    /// Where the current stroke's reference starts and ends, m.
    pub fn path_ends_m(&self) -> (f32, f32) {
        (self.path.sample(0.0).position_m, self.path.target_m())
    }

    /// Completed half cycles.
    pub fn half_cycles(&self) -> u32 {
        self.half_cycles
    }

    /// Fraction of the current stroke done by the reference, 0..1.
    pub fn progress(&self) -> f32 {
        let d = self.path.duration_s();
        if d <= 0.0 {
            1.0
        } else {
            clamp_f32(self.elapsed_s / d, 0.0, 1.0)
        }
    }

    /// Changes the peak speed from the next stroke on.
    pub fn set_peak_speed(&mut self, peak_speed_mps: f32) {
        self.config.peak_speed_mps = peak_speed_mps;
    }

    /// Holds the reference at rest where it starts for `wait_s` (s, ≥ 0) before the first
    /// stroke; only before that stroke has begun.
    pub fn wait(&mut self, wait_s: f32) {
        if self.half_cycles == 0 && self.elapsed_s <= 0.0 {
            self.elapsed_s = -max_f32(wait_s, 0.0);
        }
    }

    /// Whether the reference still rests before the first stroke ([`Self::wait`]).
    pub fn waiting(&self) -> bool {
        self.elapsed_s < 0.0
    }

    /// Finishes the current stroke, then stops at its dead point.
    pub fn request_stop(&mut self) {
        self.stop_requested = true;
    }

    /// True once a requested stop is complete (the reference rests at a dead point).
    pub fn stopped(&self) -> bool {
        self.stop_requested && self.elapsed_s >= self.path.duration_s()
    }

    /// Advances by `dt_s` with the measured position; returns the setpoint and, at the end
    /// of a stroke, the dead point just reached.
    pub fn step(&mut self, dt_s: f32, measured_m: f32) -> (Setpoint, Option<DeadPoint>) {
        self.extreme_m = match self.direction {
            Direction::TowardB => max_f32(self.extreme_m, measured_m),
            Direction::TowardA => min_f32(self.extreme_m, measured_m),
        };
        self.elapsed_s += dt_s;
        let mut reached = None;
        if self.elapsed_s >= self.path.duration_s() && !self.stop_requested {
            reached = Some(self.turn());
        }
        (self.path.sample(self.elapsed_s), reached)
    }

    /// Ends the stroke at its dead point: corrects that end's command and starts back.
    fn turn(&mut self) -> DeadPoint {
        let (target, command) = match self.direction {
            Direction::TowardB => (self.config.dead_b_m, &mut self.command_b_m),
            Direction::TowardA => (self.config.dead_a_m, &mut self.command_a_m),
        };
        // No sample measured (or none a number): the command stands as reached.
        let reached = if self.extreme_m.is_nan() {
            *command
        } else {
            self.extreme_m
        };
        let error = reached - target;
        let max = self.config.max_correction_m;
        // Integral correction of the commanded end point, bounded around the target.
        *command = clamp_f32(
            *command - self.config.correction_gain * error,
            target - max,
            target + max,
        );
        let dead = DeadPoint {
            end: self.direction,
            target_m: target,
            reached_m: reached,
        };
        let here = self.path.target_m();
        // Carry the time past the end into the next stroke, so the cycle period is exact.
        let carry_s = max_f32(self.elapsed_s - self.path.duration_s(), 0.0);
        self.direction = match self.direction {
            Direction::TowardB => Direction::TowardA,
            Direction::TowardA => Direction::TowardB,
        };
        let next = match self.direction {
            Direction::TowardB => self.command_b_m,
            Direction::TowardA => self.command_a_m,
        };
        self.path = PointToPoint::new(here, next, self.config.peak_speed_mps);
        self.elapsed_s = carry_s;
        self.extreme_m = f32::NAN;
        self.half_cycles = self.half_cycles.saturating_add(1);
        dead
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wait_holds_the_reference_at_rest_before_the_first_stroke() {
        let mut g = StrokeGenerator::new(StrokeConfig::reference(2.0), 0.01);
        g.wait(0.1);
        let mut rest_cycles = 0;
        while g.waiting() {
            let (sp, dead) = g.step(50e-6, 0.01);
            assert_eq!(dead, None);
            if g.waiting() {
                assert_eq!((sp.position_m, sp.velocity_mps), (0.01, 0.0));
            }
            rest_cycles += 1;
        }
        // 0.1 s of 50 µs cycles (± one for the f32 clock).
        assert!((1999..=2001).contains(&rest_cycles), "{rest_cycles}");
        let mut sp = Setpoint::at_rest(0.01);
        for _ in 0..200 {
            sp = g.step(50e-6, 0.01).0;
        }
        assert!(sp.position_m > 0.0101 && sp.velocity_mps > 0.0, "{sp:?}");
        // Once stroking, a wait changes nothing.
        g.wait(0.1);
        assert!(!g.waiting());
    }

    #[test]
    fn strokes_alternate_and_report_dead_points() {
        let mut g = StrokeGenerator::new(StrokeConfig::reference(2.0), 0.01);
        assert_eq!(g.direction(), Direction::TowardB);
        let mut ends = Vec::new();
        for _ in 0..40_000 {
            let (sp, dead) = g.step(50e-6, g.path.sample(g.elapsed_s).position_m);
            assert!((0.0..=0.205).contains(&sp.position_m));
            if let Some(d) = dead {
                ends.push(d.end);
            }
        }
        assert!(ends.len() >= 8);
        assert!(ends.windows(2).all(|w| w[0] != w[1]));
    }

    #[test]
    fn a_steady_overshoot_is_corrected_within_a_few_strokes() {
        let mut g = StrokeGenerator::new(StrokeConfig::reference(3.0), 0.01);
        let mut errors_b = Vec::new();
        for _ in 0..200_000 {
            let sp = g.path.sample(g.elapsed_s);
            // The plant overshoots toward B by 0.2 mm (e.g. a gas-force model error).
            let measured = if g.direction() == Direction::TowardB {
                sp.position_m + 0.2e-3 * g.progress()
            } else {
                sp.position_m
            };
            if let (_, Some(d)) = g.step(50e-6, measured) {
                if d.end == Direction::TowardB {
                    errors_b.push((d.reached_m - d.target_m).abs());
                }
            }
        }
        assert!(errors_b.first().is_some_and(|e| *e > 0.15e-3));
        assert!(
            errors_b.last().is_some_and(|e| *e < 0.01e-3),
            "{errors_b:?}"
        );
    }
}
