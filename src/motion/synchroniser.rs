//! The rotary synchroniser: the rotation slaved to the *measured* linear position (an
//! electronic cam, not a clock), so every port edge is crossed at the planned piston position.
//!
//! Each half cycle turns the piston by half a revolution. Over one stroke the cam maps the
//! stroke progress `u = (x − x_start)/(x_end − x_start)` (measured x, clamped to 0..1) to the
//! fraction of that half revolution done, through a monotone C¹ cubic (Fritsch–Carlson) that
//! passes through the planned edge: at `x = x_edge` the rotation is exactly at the port's
//! half-open angle ([`PortGeometry::half_open_rad`]). The rotation is monotonic and, because
//! the piston is at rest at each dead point, it comes to rest there too, so reversing it to
//! switch between compressor and expander at a dead point needs no jump.
//!
//! | mode | rotation | stroke A → B | stroke B → A |
//! |---|---|---|---|
//! | compressor | forward, φ 0 → π → 2π | B's discharge opens at x_edge | A's discharge opens |
//! | expander | reverse, φ 2π → π → 0 | A's admission cuts off at x_edge | B's admission cuts off |
//!
//! The output is a [`RotarySetpoint`] with velocity and acceleration feed-forward from the
//! linear reference (`θ̇ = Δθ·f′(u)·u̇`, `θ̈ = Δθ·(f″·u̇² + f′·ü)`), relative to a base that
//! the controller moves by whole turns ([`Synchroniser::rebase`]) so `f32` never runs out of
//! precision however long the machine runs.

use crate::angle::{wrap_rad, wrap_signed_rad};
use crate::real::clamp_f32;
use core::f32::consts::{PI, TAU};

use crate::drive::servo::RotarySetpoint;
use crate::motion::stroke::Direction;
use crate::motion::volume_ratio::Chamber;
use crate::physics::port_timing::{Port, PortGeometry};

/// Compressor or expander.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Rotation {
    /// Forward rotation: gas is compressed and discharged.
    Compressor,
    /// Reverse rotation: high-pressure gas is admitted, expands and is exhausted.
    Expander,
}

/// The port edge a half cycle times, and the chamber it belongs to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimedEdge {
    /// The chamber whose port it is.
    pub chamber: Chamber,
    /// Discharge opening (compressor) or admission cut-off (expander).
    pub rotation: Rotation,
    /// Rotation angle of the edge, rad (same base as the setpoints).
    pub angle_rad: f32,
}

/// The synchroniser's state for the current half cycle.
#[derive(Clone, Debug)]
pub struct Synchroniser {
    geometry: PortGeometry<f32>,
    rotation: Rotation,
    x_start_m: f32,
    x_end_m: f32,
    /// 1/(x_end − x_start), 0 for a degenerate stroke (precomputed: no division per cycle).
    inv_stroke: f32,
    theta_start_rad: f32,
    theta_end_rad: f32,
    /// Cam knots: edge at (u_edge, f_edge); tangents at 0, edge, 1.
    u_edge: f32,
    f_edge: f32,
    tangents: [f32; 3],
    /// 1/h of the two cam segments.
    inv_h: [f32; 2],
    edge: TimedEdge,
    /// The edge was crossed by the measured rotation in this half.
    edge_crossed: bool,
}

impl Synchroniser {
    /// At rest at rotation angle `theta_rad`, which is taken as phase 0 (dead point A).
    pub fn new(geometry: PortGeometry<f32>, theta_rad: f32) -> Self {
        Synchroniser {
            geometry,
            rotation: Rotation::Compressor,
            x_start_m: 0.0,
            x_end_m: 1.0,
            inv_stroke: 1.0,
            theta_start_rad: theta_rad,
            theta_end_rad: theta_rad,
            u_edge: 0.5,
            f_edge: 0.5,
            tangents: [1.0; 3],
            inv_h: [2.0; 2],
            edge: TimedEdge {
                chamber: Chamber::B,
                rotation: Rotation::Compressor,
                angle_rad: theta_rad,
            },
            edge_crossed: true,
        }
    }

    /// The mode of the current half cycle.
    pub fn rotation(&self) -> Rotation {
        self.rotation
    }

    /// The edge this half cycle times.
    pub fn edge(&self) -> TimedEdge {
        self.edge
    }

    /// The chamber whose edge a stroke in `direction` times in `rotation` mode.
    pub fn timed_chamber(direction: Direction, rotation: Rotation) -> Chamber {
        match (direction, rotation) {
            // Compressing chamber: B on the way to B, A on the way to A.
            (Direction::TowardB, Rotation::Compressor) => Chamber::B,
            (Direction::TowardA, Rotation::Compressor) => Chamber::A,
            // Expanding chamber: A on the way to B, B on the way to A.
            (Direction::TowardB, Rotation::Expander) => Chamber::A,
            (Direction::TowardA, Rotation::Expander) => Chamber::B,
        }
    }

    /// Starts a half cycle: the piston goes from `x_start_m` to `x_end_m` in `direction`,
    /// the timed edge must be crossed at `x_edge_m`, the rotation continues from
    /// `theta_now_rad` (the current reference, for continuity) in `rotation` mode.
    pub fn begin_half(
        &mut self,
        direction: Direction,
        rotation: Rotation,
        x_start_m: f32,
        x_end_m: f32,
        x_edge_m: f32,
        theta_now_rad: f32,
    ) {
        let chamber = Self::timed_chamber(direction, rotation);
        let port = match chamber {
            Chamber::A => Port::DischargeA,
            Chamber::B => Port::DischargeB,
        };
        // Nominal phase at the start of this half: 0 at dead point A, π at dead point B.
        let start_phase = match direction {
            Direction::TowardB => 0.0,
            Direction::TowardA => PI,
        };
        let edge_phase = self.geometry.half_open_rad(port);
        let sign = match rotation {
            Rotation::Compressor => 1.0,
            Rotation::Expander => -1.0,
        };
        // Rotation from the start of the half to the edge, in the direction of rotation.
        let to_edge = wrap_rad(sign * (edge_phase - start_phase));
        // The nominal start is the dead-point phase nearest to where the rotation is now.
        let theta_nominal = theta_now_rad - wrap_signed_rad(theta_now_rad - start_phase);
        self.theta_start_rad = theta_now_rad;
        self.theta_end_rad = theta_nominal + sign * PI;
        let theta_edge = theta_nominal + sign * to_edge;
        let span = self.theta_end_rad - self.theta_start_rad;
        let f_edge = if span.abs() > 1e-6 {
            clamp_f32((theta_edge - self.theta_start_rad) / span, 0.02, 0.98)
        } else {
            0.5
        };
        let stroke = x_end_m - x_start_m;
        let u_edge = if stroke.abs() > 1e-6 {
            clamp_f32((x_edge_m - x_start_m) / stroke, 0.02, 0.98)
        } else {
            0.5
        };
        self.rotation = rotation;
        self.x_start_m = x_start_m;
        self.x_end_m = x_end_m;
        self.inv_stroke = if stroke.abs() > 1e-6 {
            1.0 / stroke
        } else {
            0.0
        };
        self.u_edge = u_edge;
        self.f_edge = f_edge;
        // Fritsch–Carlson: secant slopes, harmonic mean at the inner knot, secants at the ends
        // (within [0, 3·secant], so the cubic stays monotone).
        let d0 = f_edge / u_edge;
        let d1 = (1.0 - f_edge) / (1.0 - u_edge);
        self.tangents = [d0, 2.0 * d0 * d1 / (d0 + d1), d1];
        self.inv_h = [1.0 / u_edge, 1.0 / (1.0 - u_edge)];
        self.edge = TimedEdge {
            chamber,
            rotation,
            angle_rad: self.theta_start_rad + span * f_edge,
        };
        self.edge_crossed = false;
    }

    /// Moves the angle base by whole turns (the servo's count base moves with it).
    pub fn rebase(&mut self, turns: i32) {
        let d = turns as f32 * TAU;
        self.theta_start_rad -= d;
        self.theta_end_rad -= d;
        self.edge.angle_rad -= d;
    }

    /// The rotation setpoint for the measured position `x_m`, with feed-forward from the
    /// linear reference velocity and acceleration.
    pub fn setpoint(&self, x_m: f32, velocity_mps: f32, acceleration_mps2: f32) -> RotarySetpoint {
        let span = self.theta_end_rad - self.theta_start_rad;
        if self.inv_stroke == 0.0 {
            return RotarySetpoint {
                angle_rad: self.theta_end_rad,
                ..RotarySetpoint::default()
            };
        }
        let u = clamp_f32((x_m - self.x_start_m) * self.inv_stroke, 0.0, 1.0);
        let (f, df, ddf) = self.cam(u);
        let du = velocity_mps * self.inv_stroke;
        let ddu = acceleration_mps2 * self.inv_stroke;
        RotarySetpoint {
            angle_rad: self.theta_start_rad + span * f,
            velocity_rad_s: span * df * du,
            acceleration_rad_s2: span * (ddf * du * du + df * ddu),
        }
    }

    /// Reports the measured rotation; returns the timed edge once, when it is crossed.
    pub fn crossed(&mut self, measured_rad: f32) -> Option<TimedEdge> {
        if self.edge_crossed {
            return None;
        }
        let past = match self.rotation {
            Rotation::Compressor => measured_rad >= self.edge.angle_rad,
            Rotation::Expander => measured_rad <= self.edge.angle_rad,
        };
        if past {
            self.edge_crossed = true;
            Some(self.edge)
        } else {
            None
        }
    }

    /// The cam: fraction of the half revolution and its first two derivatives at `u`.
    fn cam(&self, u: f32) -> (f32, f32, f32) {
        let [m0, me, m1] = self.tangents;
        let [inv_h0, inv_h1] = self.inv_h;
        let (u0, y0, t0, h, inv_h, y1, t1) = if u <= self.u_edge {
            (0.0, 0.0, m0, self.u_edge, inv_h0, self.f_edge, me)
        } else {
            (
                self.u_edge,
                self.f_edge,
                me,
                1.0 - self.u_edge,
                inv_h1,
                1.0,
                m1,
            )
        };
        let t = (u - u0) * inv_h;
        let t2 = t * t;
        let t3 = t2 * t;
        // Cubic Hermite basis and its derivatives in t.
        let f = (2.0 * t3 - 3.0 * t2 + 1.0) * y0
            + (t3 - 2.0 * t2 + t) * h * t0
            + (-2.0 * t3 + 3.0 * t2) * y1
            + (t3 - t2) * h * t1;
        let df = ((6.0 * t2 - 6.0 * t) * y0
            + (3.0 * t2 - 4.0 * t + 1.0) * h * t0
            + (-6.0 * t2 + 6.0 * t) * y1
            + (3.0 * t2 - 2.0 * t) * h * t1)
            * inv_h;
        let ddf = ((12.0 * t - 6.0) * y0
            + (6.0 * t - 4.0) * h * t0
            + (-12.0 * t + 6.0) * y1
            + (6.0 * t - 2.0) * h * t1)
            * (inv_h * inv_h);
        (f, df, ddf)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sync() -> Synchroniser {
        Synchroniser::new(PortGeometry::reference(), 0.0)
    }

    #[test]
    fn the_edge_is_crossed_at_the_planned_position_and_rotation_is_monotonic() {
        let mut s = sync();
        s.begin_half(
            Direction::TowardB,
            Rotation::Compressor,
            0.001,
            0.204,
            0.15,
            0.0,
        );
        let at_edge = s.setpoint(0.15, 0.0, 0.0).angle_rad;
        let geometry = PortGeometry::<f32>::reference();
        assert!((at_edge - geometry.half_open_rad(Port::DischargeB)).abs() < 1e-4);
        let mut last = -1.0;
        for i in 0..=2030 {
            let a = s.setpoint(0.001 + i as f32 * 1e-4, 1.0, 0.0).angle_rad;
            assert!(a >= last - 1e-6);
            last = a;
        }
        assert!((last - PI).abs() < 1e-4);
        // Next half continues from π toward 2π, A's discharge at its edge.
        s.begin_half(
            Direction::TowardA,
            Rotation::Compressor,
            0.204,
            0.001,
            0.06,
            last,
        );
        assert!(
            (s.setpoint(0.06, 0.0, 0.0).angle_rad - geometry.half_open_rad(Port::DischargeA)).abs()
                < 1e-3
        );
        assert!((s.setpoint(0.001, 0.0, 0.0).angle_rad - TAU).abs() < 1e-4);
    }

    #[test]
    fn the_cam_slope_is_continuous_at_the_edge() {
        let mut s = sync();
        s.begin_half(
            Direction::TowardB,
            Rotation::Compressor,
            0.001,
            0.204,
            0.15,
            0.0,
        );
        let below = s.setpoint(0.15 - 1e-5, 1.0, 0.0).velocity_rad_s;
        let above = s.setpoint(0.15 + 1e-5, 1.0, 0.0).velocity_rad_s;
        assert!(
            (below - above).abs() < 0.01 * below.abs(),
            "{below} vs {above}"
        );
    }

    #[test]
    fn expander_turns_backward_and_times_the_cut_off() {
        let mut s = sync();
        s.begin_half(
            Direction::TowardB,
            Rotation::Expander,
            0.001,
            0.204,
            0.05,
            0.0,
        );
        assert_eq!(s.edge().chamber, Chamber::A);
        assert!((s.setpoint(0.204, 0.0, 0.0).angle_rad + PI).abs() < 1e-4);
        let edge = s.setpoint(0.05, 0.0, 0.0).angle_rad;
        let geometry = PortGeometry::<f32>::reference();
        assert!(
            (crate::angle::wrap_rad(edge) - geometry.half_open_rad(Port::DischargeA)).abs() < 1e-3
        );
        assert_eq!(s.crossed(-0.1), None);
        assert!(s.crossed(edge - 0.01).is_some());
        assert_eq!(s.crossed(edge - 0.02), None, "reported once");
    }
}
