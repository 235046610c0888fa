//! The rotation: servo drive (torque lag and limit), drive-train inertia and friction, the
//! spline's backlash, and the load torque of the piston's sliding friction.
//!
//! The drive train is one inertia (servo, gearbox and piston, referred to the piston). The
//! spline has a total play `b`: the piston angle stays where it is until the servo side
//! reaches one flank of the play, then it is carried along (a play operator; the piston's own
//! rotary inertia is negligible against its friction). The piston's friction torque loads the
//! servo only while a flank is engaged. The drive train's own friction is the library's
//! friction law in angular units (the paper: "this set of equations is also used for the
//! rotation"). Friction enters through its secant coefficient `F(ω)/ω`, applied implicitly,
//! so a sliding surface that stiffens near zero speed cannot make the step unstable.

use fpc::physics::friction::FrictionParams;

/// Parameters of the rotation.
#[derive(Clone, Debug, PartialEq)]
pub struct ServoParams {
    /// Inertia at the piston, kg·m².
    pub inertia_kgm2: f64,
    /// Drive-train friction (Coulomb in N·m, viscous in N·m·s/rad, velocities in rad/s).
    pub friction: FrictionParams<f64>,
    /// Torque at the command's full scale, N·m.
    pub torque_full_scale_nm: f64,
    /// Torque limit of the drive, N·m.
    pub torque_limit_nm: f64,
    /// Lag of the torque behind the command, s (0 = none).
    pub torque_time_constant_s: f64,
    /// Total play of the spline, rad.
    pub backlash_rad: f64,
}

impl ServoParams {
    /// From the model's `[servo]` section.
    pub fn from_model(s: &crate::plant::model::Servo) -> Self {
        ServoParams {
            inertia_kgm2: s.inertia_kgm2,
            friction: FrictionParams {
                coulomb_n: s.coulomb_nm,
                static_n: s.coulomb_nm,
                // No Stribeck dip (static = Coulomb), so its velocity changes nothing; a tiny
                // one lets the law skip its exponential (it does past 16 of them).
                stribeck_velocity_mps: 1e-12,
                stribeck_exponent: 1.0,
                viscous_ns_per_m: s.viscous_nms_per_rad,
                sign_velocity_mps: 1e-2,
            },
            torque_full_scale_nm: s.torque_full_scale_nm,
            torque_limit_nm: s.torque_limit_nm,
            torque_time_constant_s: s.torque_time_constant_s,
            backlash_rad: s.backlash_rad,
        }
    }
}

/// State of the rotation.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rotation {
    /// Servo-side angle (what the quadrature encoder reads), rad, unwrapped.
    pub servo_angle_rad: f64,
    /// Servo-side speed, rad/s.
    pub servo_speed_rad_s: f64,
    /// Piston angle (what times the ports), rad, unwrapped.
    pub piston_angle_rad: f64,
    /// Piston speed, rad/s.
    pub piston_speed_rad_s: f64,
    /// Torque the drive applies, N·m.
    pub torque_nm: f64,
    /// Friction torque of the piston's sliding surface on the drive train in the last step,
    /// N·m (opposing the rotation).
    pub load_torque_nm: f64,
    /// Factors of the step that depend only on the step and the parameters.
    factors: StepFactors,
}

/// `dt/(τ + dt)`, `dt/J` and `1/dt` for the `(dt, τ, J)` they were computed for: the step is
/// the same every period, and divisions dominate its cost.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct StepFactors {
    key: (f64, f64, f64),
    lag: f64,
    dt_over_inertia: f64,
    inv_dt: f64,
}

impl StepFactors {
    #[inline]
    fn for_step(&mut self, p: &ServoParams, dt_s: f64) -> StepFactors {
        let key = (dt_s, p.torque_time_constant_s, p.inertia_kgm2);
        if self.key != key {
            *self = StepFactors {
                key,
                lag: dt_s / (p.torque_time_constant_s + dt_s),
                dt_over_inertia: dt_s / p.inertia_kgm2,
                inv_dt: 1.0 / dt_s,
            };
        }
        *self
    }
}

impl Rotation {
    /// Advances by `dt_s` with the drive commanded `command_nm` and the piston's sliding
    /// friction acting as `load_nms_per_rad`·ω (its secant coefficient, ≥ 0).
    pub fn step(&mut self, p: &ServoParams, command_nm: f64, load_nms_per_rad: f64, dt_s: f64) {
        let k = self.factors.for_step(p, dt_s);
        let cmd = command_nm.clamp(-p.torque_limit_nm, p.torque_limit_nm);
        self.torque_nm = if p.torque_time_constant_s > 0.0 {
            self.torque_nm + (cmd - self.torque_nm) * k.lag
        } else {
            cmd
        };
        let half = 0.5 * p.backlash_rad;
        let gap = self.servo_angle_rad - self.piston_angle_rad;
        let w = self.servo_speed_rad_s;
        // Engaged: on a flank and moving into it (or no play at all).
        let engaged = half <= 1e-12 || (gap.abs() >= half - 1e-9 && gap * w >= 0.0);
        let secant = |f: &FrictionParams<f64>, w: f64| {
            let s = w.abs().max(1e-9);
            f.force_n(s) / s
        };
        let mut c = secant(&p.friction, w);
        if engaged {
            c += load_nms_per_rad;
        }
        let w_new = (w + k.dt_over_inertia * self.torque_nm) / (1.0 + k.dt_over_inertia * c);
        self.load_torque_nm = if engaged {
            load_nms_per_rad * w_new
        } else {
            0.0
        };
        self.servo_speed_rad_s = w_new;
        self.servo_angle_rad += w_new * dt_s;
        let before = self.piston_angle_rad;
        self.piston_angle_rad = through_play(self.piston_angle_rad, self.servo_angle_rad, half);
        self.piston_speed_rad_s = (self.piston_angle_rad - before) * k.inv_dt;
    }
}

/// The spline's play operator: where the carried side (the piston) stands once the driving
/// side (the servo) is at `driver`, with `half_play` either way — it stays where it is
/// until a flank of the play reaches it, then it is carried along. Rad.
#[inline]
pub fn through_play(carried: f64, driver: f64, half_play: f64) -> f64 {
    let (lo, hi) = (driver - half_play, driver + half_play);
    if carried < lo {
        lo
    } else if carried > hi {
        hi
    } else {
        carried
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> ServoParams {
        ServoParams::from_model(&crate::plant::model::Servo::default())
    }

    #[test]
    fn the_backlash_is_crossed_before_the_piston_turns() {
        let p = params();
        let mut r = Rotation::default();
        let mut first_piston_motion = None;
        for i in 0..400 {
            r.step(&p, 1.0, 0.5, 25e-6);
            if first_piston_motion.is_none() && r.piston_angle_rad != 0.0 {
                first_piston_motion = Some((i, r.servo_angle_rad));
            }
        }
        let (_, servo_at_pickup) = first_piston_motion.unwrap();
        assert!((servo_at_pickup - 0.5 * p.backlash_rad).abs() < 1e-4);
        assert!((r.servo_angle_rad - r.piston_angle_rad - 0.5 * p.backlash_rad).abs() < 1e-9);
    }

    #[test]
    fn torque_is_limited_and_friction_brakes_to_rest_stably() {
        let p = params();
        let mut r = Rotation::default();
        for _ in 0..4000 {
            r.step(&p, 100.0, 0.0, 25e-6);
        }
        assert!((r.torque_nm - p.torque_limit_nm).abs() < 1e-9);
        // A stiff load (secant 1e4 N·m·s/rad: 200× the inertia per step) must not ring.
        for _ in 0..100 {
            r.step(&p, 0.0, 1e4, 25e-6);
            assert!(r.servo_speed_rad_s >= 0.0);
        }
        assert!(r.servo_speed_rad_s < 1e-3);
    }
}
