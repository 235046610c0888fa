//! Reference trajectories of the linear axis.
//!
//! A [`Setpoint`] is position, velocity and acceleration at one instant; the controller
//! feeds the acceleration forward through the mass. [`PointToPoint`] is a minimum-jerk move
//! (quintic: zero velocity and acceleration at both ends), sized by a peak speed:
//! `x(s) = x₀ + D·(10s³ − 15s⁴ + 6s⁵)`, `s = t/T`, peak speed `1.875·D/T`, peak acceleration
//! `5.774·D/T²`.

/// Position, velocity and acceleration reference at one instant.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Setpoint {
    /// Position, m.
    pub position_m: f32,
    /// Velocity, m/s.
    pub velocity_mps: f32,
    /// Acceleration, m/s².
    pub acceleration_mps2: f32,
}

impl Setpoint {
    /// At rest at `position_m`.
    pub const fn at_rest(position_m: f32) -> Self {
        Setpoint {
            position_m,
            velocity_mps: 0.0,
            acceleration_mps2: 0.0,
        }
    }
}

/// A minimum-jerk move between two positions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointToPoint {
    from_m: f32,
    distance_m: f32,
    duration_s: f32,
    /// 1/T (0 for a zero-length move), and the velocity's and acceleration's scales
    /// `30·D/T`, m/s, and `60·D/T²`, m/s², precomputed: [`PointToPoint::sample`] runs per
    /// cycle.
    inv_duration: f32,
    velocity_scale_mps: f32,
    acceleration_scale_mps2: f32,
}

impl PointToPoint {
    /// A move from `from_m` to `to_m` whose peak speed is `peak_speed_mps` (> 0; a
    /// non-positive or NaN speed is treated as 1 mm/s). A zero-length move lasts 0 s.
    pub fn new(from_m: f32, to_m: f32, peak_speed_mps: f32) -> Self {
        let distance_m = to_m - from_m;
        let speed = if peak_speed_mps > 1e-3 {
            peak_speed_mps
        } else {
            1e-3
        };
        let duration_s = 1.875 * distance_m.abs() / speed;
        let inv_duration = if duration_s > 0.0 {
            1.0 / duration_s
        } else {
            0.0
        };
        PointToPoint {
            from_m,
            distance_m,
            duration_s,
            inv_duration,
            velocity_scale_mps: 30.0 * distance_m * inv_duration,
            acceleration_scale_mps2: 60.0 * distance_m * inv_duration * inv_duration,
        }
    }

    /// Duration of the move, s.
    pub fn duration_s(&self) -> f32 {
        self.duration_s
    }

    /// Target position, m.
    pub fn target_m(&self) -> f32 {
        self.from_m + self.distance_m
    }

    /// Peak acceleration magnitude of the move, m/s².
    pub fn peak_acceleration_mps2(&self) -> f32 {
        if self.duration_s <= 0.0 {
            0.0
        } else {
            5.773_503 * self.distance_m.abs() / (self.duration_s * self.duration_s)
        }
    }

    /// The setpoint `t_s` after the start (held at the ends outside [0, T]).
    pub fn sample(&self, t_s: f32) -> Setpoint {
        if self.duration_s <= 0.0 || t_s >= self.duration_s {
            return Setpoint::at_rest(self.target_m());
        }
        if t_s <= 0.0 {
            return Setpoint::at_rest(self.from_m);
        }
        let s = t_s * self.inv_duration;
        let s2 = s * s;
        let s3 = s2 * s;
        let pos = s3 * (10.0 - 15.0 * s + 6.0 * s2);
        let vel = s2 * (1.0 - 2.0 * s + s2);
        let acc = s * (1.0 - 3.0 * s + 2.0 * s2);
        Setpoint {
            position_m: self.from_m + self.distance_m * pos,
            velocity_mps: self.velocity_scale_mps * vel,
            acceleration_mps2: self.acceleration_scale_mps2 * acc,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reaches_peak_speed_and_target() {
        let m = PointToPoint::new(0.01, 0.19, 4.0);
        let mid = m.sample(m.duration_s() / 2.0);
        assert!((mid.velocity_mps - 4.0).abs() < 1e-3);
        assert_eq!(m.sample(m.duration_s() + 1.0), Setpoint::at_rest(0.19));
        // Velocity is the derivative of position.
        let t = 0.3 * m.duration_s();
        let h = 1e-5;
        let num = (m.sample(t + h).position_m - m.sample(t - h).position_m) / (2.0 * h);
        assert!((num - m.sample(t).velocity_mps).abs() < 0.05);
    }

    #[test]
    fn degenerate_moves_are_safe() {
        let m = PointToPoint::new(0.1, 0.1, 1.0);
        assert_eq!(m.sample(0.0), Setpoint::at_rest(0.1));
        let m = PointToPoint::new(0.1, 0.2, f32::NAN);
        assert!(m.duration_s().is_finite());
    }
}
