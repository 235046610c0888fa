//! The rotation servo loop: position/velocity control from the quadrature count, torque
//! command out through the DAC, with feed-forward of the rotary trajectory.
//!
//! The rotation sets the port timing, so it is a position loop on the piston angle. The
//! servo drive runs in torque mode; its analog input is ±full-scale torque around DAC
//! mid-scale.

use crate::real::{clamp_or_zero_f32, i64_to_f32};
use crate::units::DacCode;

/// Servo configuration (reference values **A**: J 2e-3 kg·m², ≈ 30 Hz bandwidth).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ServoConfig {
    /// Encoder counts per revolution (after quadrature).
    pub counts_per_rev: u32,
    /// Rotating inertia, kg·m² (feed-forward).
    pub inertia_kgm2: f32,
    /// Proportional gain, N·m/rad.
    pub kp_nm_per_rad: f32,
    /// Derivative gain, N·m·s/rad.
    pub kd_nms_per_rad: f32,
    /// Torque at DAC full scale (and the command limit), N·m.
    pub torque_full_scale_nm: f32,
    /// Time constant of the velocity estimate, s.
    pub velocity_filter_s: f32,
    /// Sample time, s.
    pub sample_time_s: f32,
}

impl ServoConfig {
    /// Reference servo tuned for ≈ 30 Hz (ω = 190 rad/s, damping 0.8).
    pub const fn reference() -> Self {
        ServoConfig {
            counts_per_rev: crate::reference::servo::COUNTS_PER_REV,
            inertia_kgm2: crate::reference::servo::INERTIA_KGM2 as f32,
            kp_nm_per_rad: 72.0,
            kd_nms_per_rad: 0.6,
            // The reference machine's drive (20 N·m, enough for the piston's sliding
            // friction at 4 m/s).
            torque_full_scale_nm: crate::reference::servo::TORQUE_FULL_SCALE_NM as f32,
            velocity_filter_s: 5e-4,
            sample_time_s: 50e-6,
        }
    }

    /// Radians per count.
    #[inline]
    pub fn rad_per_count(&self) -> f32 {
        core::f32::consts::TAU / self.counts_per_rev.max(1) as f32
    }
}

/// Angle reference of the rotation.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RotarySetpoint {
    /// Angle, rad (unwrapped).
    pub angle_rad: f32,
    /// Angular velocity, rad/s.
    pub velocity_rad_s: f32,
    /// Angular acceleration, rad/s².
    pub acceleration_rad_s2: f32,
}

/// Servo loop state.
#[derive(Clone, Debug)]
pub struct ServoController {
    config: ServoConfig,
    /// The configuration's [`ServoConfig::rad_per_count`], rad.
    rad_per_count: f32,
    /// The same per sample time: a count step's velocity, rad/s.
    rad_s_per_count: f32,
    /// DAC codes per N·m of torque: 2047 / full scale.
    codes_per_nm: f32,
    /// The velocity filter's gain per sample, Ts / (τ + Ts), in (0, 1].
    velocity_alpha: f32,
    last_count: Option<i64>,
    /// Count at angle zero of the current base.
    count_base: i64,
    velocity_rad_s: f32,
    angle_rad: f32,
    torque_nm: f32,
}

impl ServoController {
    /// A servo loop with `config`.
    pub fn new(config: ServoConfig) -> Self {
        ServoController {
            config,
            rad_per_count: config.rad_per_count(),
            rad_s_per_count: config.rad_per_count() / config.sample_time_s,
            codes_per_nm: 2047.0 / config.torque_full_scale_nm,
            velocity_alpha: config.sample_time_s
                / (config.velocity_filter_s + config.sample_time_s),
            last_count: None,
            count_base: 0,
            velocity_rad_s: 0.0,
            angle_rad: 0.0,
            torque_nm: 0.0,
        }
    }

    /// Moves the angle base forward by whole `turns` (angles drop by 2π per turn).
    pub fn rebase(&mut self, turns: i32) {
        let counts = i64::from(turns) * i64::from(self.config.counts_per_rev);
        self.count_base = self.count_base.saturating_add(counts);
        self.angle_rad -= turns as f32 * core::f32::consts::TAU;
    }

    /// Measured angle, rad (from the last step).
    pub fn angle_rad(&self) -> f32 {
        self.angle_rad
    }

    /// Estimated angular velocity, rad/s.
    pub fn velocity_rad_s(&self) -> f32 {
        self.velocity_rad_s
    }

    /// Last torque command, N·m.
    pub fn torque_nm(&self) -> f32 {
        self.torque_nm
    }

    /// Updates the measurement from the wide count without commanding (outputs off).
    pub fn observe(&mut self, count: i64) {
        // The step as a wrapping difference of the low 32 bits: exact for every step below
        // 2³¹ counts (a quadrature counter moves by at most 2¹⁵ a cycle), one instruction
        // and an i32 → f32 conversion where an i64 difference converts by halves.
        let step = self
            .last_count
            .map_or(0, |l| (count as i32).wrapping_sub(l as i32));
        self.last_count = Some(count);
        // Relative to the base, the count stays within a few turns (the controller re-bases by
        // whole turns), so the f32 angle keeps its full resolution however long it runs.
        // i64 → f32 by halves: `as f32` is a library call of ~35 instructions on the M4
        // (exact either way for the few turns the angle spans). The base's wrapping
        // difference stays within ±2⁶³ for centuries of turning at any speed.
        // The configuration's constants are taken once, at construction.
        self.angle_rad = i64_to_f32(count.wrapping_sub(self.count_base)) * self.rad_per_count;
        let raw_velocity = step as f32 * self.rad_s_per_count;
        self.velocity_rad_s += self.velocity_alpha * (raw_velocity - self.velocity_rad_s);
    }

    /// One loop step: measure, then compute the torque command for `reference`.
    pub fn step(&mut self, count: i64, reference: &RotarySetpoint) -> DacCode {
        self.observe(count);
        self.control(reference)
    }

    /// The torque command for `reference` from the last observation.
    pub fn control(&mut self, reference: &RotarySetpoint) -> DacCode {
        let c = &self.config;
        let torque = c.inertia_kgm2 * reference.acceleration_rad_s2
            + c.kp_nm_per_rad * (reference.angle_rad - self.angle_rad)
            + c.kd_nms_per_rad * (reference.velocity_rad_s - self.velocity_rad_s);
        self.command(torque)
    }

    /// Converts a torque to the DAC code, saturating at full scale (NaN → zero torque).
    pub fn command(&mut self, torque_nm: f32) -> DacCode {
        let fs = self.config.torque_full_scale_nm;
        let t = clamp_or_zero_f32(torque_nm, -fs, fs);
        self.torque_nm = t;
        // The float→int cast saturates; t is within ±fs, so the code is within 1..=4095.
        // Through u32 (one VCVT) and an integer cap: the same code as `as u16`, which
        // compares the float against both ends instead.
        let code = (2048.0 + t * self.codes_per_nm + 0.5) as u32;
        DacCode(code.min(u32::from(u16::MAX)) as u16)
    }
}

/// Torque a DAC code stands for (inverse of [`ServoController::command`]), for the
/// simulator's servo drive model.
pub fn torque_of_code(code: DacCode, torque_full_scale_nm: f32) -> f32 {
    (f32::from(code.0.min(4095)) - 2048.0) / 2047.0 * torque_full_scale_nm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dac_code_round_trips_and_saturates() {
        let config = ServoConfig::reference();
        let fs = config.torque_full_scale_nm;
        let mut s = ServoController::new(config);
        for t in [-fs, -1.0, 0.0, 2.5, fs] {
            let c = s.command(t);
            assert!((torque_of_code(c, fs) - t).abs() < fs / 2047.0);
        }
        assert_eq!(s.command(100.0), DacCode(4095));
        assert_eq!(s.command(f32::NAN), DacCode(2048));
    }

    /// The velocity of a step is the same wherever the count is: across the low word's wrap,
    /// at the i64 range's ends, and for the largest steps a quadrature counter makes.
    #[test]
    fn a_count_step_gives_the_same_velocity_wherever_the_count_is() {
        let config = ServoConfig::reference();
        let per_count = config.rad_per_count() / config.sample_time_s;
        for start in [
            0i64,
            (1 << 32) - 3,
            -(1 << 32) + 2,
            i64::MAX - 40_000,
            i64::MIN + 5,
        ] {
            for step in [0i64, 1, -1, 32_767, -32_768] {
                let mut s = ServoController::new(config);
                s.velocity_alpha = 1.0;
                s.observe(start);
                s.observe(start.wrapping_add(step));
                let want = step as f32 * per_count;
                let got = s.velocity_rad_s();
                assert!(
                    (got - want).abs() <= want.abs() * 1e-6,
                    "{start} + {step}: {got} vs {want}"
                );
            }
        }
    }
}
