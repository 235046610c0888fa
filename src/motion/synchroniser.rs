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
    theta_end_rad: f32,
    /// Stroke progress of the timed edge: the knot between the cam's two segments.
    u_edge: f32,
    /// The cam's two segments as rotation angle against stroke progress, set once per half
    /// cycle so that a cycle evaluates three short polynomials.
    segments: [CamSegment; 2],
    edge: TimedEdge,
    /// The edge was crossed by the measured rotation in this half.
    edge_crossed: bool,
}

/// One segment of the cam, `θ(u) = a₀ + a₁·w + a₂·w² + a₃·w³` with `w = u − u₀` (rad, `u`
/// the stroke progress), with the coefficients of its first two derivatives.
#[derive(Clone, Copy, Debug)]
struct CamSegment {
    /// Progress at the segment's start.
    u0: f32,
    /// `a₀..a₃`, rad.
    a: [f32; 4],
    /// `2·a₂`, `3·a₃`, `6·a₃`: dθ/du = a₁ + w·(2a₂ + 3a₃·w), d²θ/du² = 2a₂ + 6a₃·w.
    derivative: [f32; 3],
}

impl CamSegment {
    /// The segment from `(u0, y0)` to `(u0 + h, y1)` with slopes `t0`, `t1` (fractions of the
    /// half revolution per unit progress), scaled by `span` rad and offset by `theta0` rad.
    fn hermite(
        u0: f32,
        h: f32,
        [y0, y1]: [f32; 2],
        [t0, t1]: [f32; 2],
        span: f32,
        theta0: f32,
    ) -> Self {
        let inv_h = 1.0 / h;
        let secant = (y1 - y0) * inv_h;
        // Power basis of the cubic Hermite segment in w = u − u0.
        let c2 = (3.0 * secant - 2.0 * t0 - t1) * inv_h;
        let c3 = (t0 + t1 - 2.0 * secant) * inv_h * inv_h;
        let a = [theta0 + span * y0, span * t0, span * c2, span * c3];
        CamSegment {
            u0,
            a,
            derivative: [2.0 * a[2], 3.0 * a[3], 6.0 * a[3]],
        }
    }

    /// A segment that holds `theta` rad whatever the progress.
    fn held(theta: f32) -> Self {
        CamSegment {
            u0: 0.0,
            a: [theta, 0.0, 0.0, 0.0],
            derivative: [0.0; 3],
        }
    }

    fn rebase(&mut self, d: f32) {
        self.a[0] -= d;
    }
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
            theta_end_rad: theta_rad,
            u_edge: 0.5,
            segments: [
                CamSegment::hermite(0.0, 0.5, [0.0, 0.5], [1.0, 1.0], 0.0, theta_rad),
                CamSegment::hermite(0.5, 0.5, [0.5, 1.0], [1.0, 1.0], 0.0, theta_rad),
            ],
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
        let theta_start = theta_now_rad;
        self.theta_end_rad = theta_nominal + sign * PI;
        let theta_edge = theta_nominal + sign * to_edge;
        let span = self.theta_end_rad - theta_start;
        let f_edge = if span.abs() > 1e-6 {
            clamp_f32((theta_edge - theta_start) / span, 0.02, 0.98)
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
        self.segments = if self.inv_stroke == 0.0 {
            // A degenerate stroke: the rotation holds at the half's end (every position reads
            // as progress 0, on a segment that does not move).
            [CamSegment::held(self.theta_end_rad); 2]
        } else {
            // Fritsch–Carlson: secant slopes, harmonic mean at the inner knot, secants at the
            // ends (within [0, 3·secant], so the cubic stays monotone).
            let d0 = f_edge / u_edge;
            let d1 = (1.0 - f_edge) / (1.0 - u_edge);
            let me = 2.0 * d0 * d1 / (d0 + d1);
            [
                CamSegment::hermite(0.0, u_edge, [0.0, f_edge], [d0, me], span, theta_start),
                CamSegment::hermite(
                    u_edge,
                    1.0 - u_edge,
                    [f_edge, 1.0],
                    [me, d1],
                    span,
                    theta_start,
                ),
            ]
        };
        self.edge = TimedEdge {
            chamber,
            rotation,
            angle_rad: theta_start + span * f_edge,
        };
        self.edge_crossed = false;
    }

    /// Moves the angle base by whole turns (the servo's count base moves with it).
    pub fn rebase(&mut self, turns: i32) {
        let d = turns as f32 * TAU;
        self.theta_end_rad -= d;
        self.edge.angle_rad -= d;
        for segment in &mut self.segments {
            segment.rebase(d);
        }
    }

    /// The rotation setpoint for the measured position `x_m`, with feed-forward from the
    /// linear reference velocity and acceleration.
    pub fn setpoint(&self, x_m: f32, velocity_mps: f32, acceleration_mps2: f32) -> RotarySetpoint {
        // A degenerate stroke (`inv_stroke` 0) reads every position as progress 0 on a held
        // segment: its end angle, at rest.
        let u = clamp_f32((x_m - self.x_start_m) * self.inv_stroke, 0.0, 1.0);
        let segment = if u <= self.u_edge {
            &self.segments[0]
        } else {
            &self.segments[1]
        };
        let w = u - segment.u0;
        let [a0, a1, a2, a3] = segment.a;
        let [b2, b3, c3] = segment.derivative;
        let slope = a1 + w * (b2 + w * b3);
        let curvature = b2 + w * c3;
        let du = velocity_mps * self.inv_stroke;
        let ddu = acceleration_mps2 * self.inv_stroke;
        RotarySetpoint {
            angle_rad: a0 + w * (a1 + w * (a2 + w * a3)),
            velocity_rad_s: slope * du,
            acceleration_rad_s2: curvature * du * du + slope * ddu,
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
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sync() -> Synchroniser {
        Synchroniser::new(PortGeometry::reference(), 0.0)
    }

    #[test]
    fn a_stroke_of_no_length_holds_the_rotation_at_the_halfs_end() {
        let mut s = sync();
        s.begin_half(Direction::TowardB, Rotation::Compressor, 0.1, 0.1, 0.1, 0.0);
        for x in [-1.0, 0.0, 0.1, 0.3, f32::NAN, f32::INFINITY] {
            let sp = s.setpoint(x, 2.0, -30.0);
            assert_eq!(sp.angle_rad, PI, "x {x}");
            assert_eq!(
                (sp.velocity_rad_s, sp.acceleration_rad_s2),
                (0.0, 0.0),
                "x {x}"
            );
        }
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

    /// The cubic Hermite segment through (u0, y0), (u0 + h, y1) with slopes t0, t1, and its
    /// first two derivatives, in f64 (the textbook form, evaluated directly).
    fn hermite(u: f64, u0: f64, h: f64, y: [f64; 2], t: [f64; 2]) -> [f64; 3] {
        let s = (u - u0) / h;
        let (s2, s3) = (s * s, s * s * s);
        let f = (2.0 * s3 - 3.0 * s2 + 1.0) * y[0]
            + (s3 - 2.0 * s2 + s) * h * t[0]
            + (-2.0 * s3 + 3.0 * s2) * y[1]
            + (s3 - s2) * h * t[1];
        let df = ((6.0 * s2 - 6.0 * s) * y[0]
            + (3.0 * s2 - 4.0 * s + 1.0) * h * t[0]
            + (-6.0 * s2 + 6.0 * s) * y[1]
            + (3.0 * s2 - 2.0 * s) * h * t[1])
            / h;
        let ddf = ((12.0 * s - 6.0) * y[0]
            + (6.0 * s - 4.0) * h * t[0]
            + (-12.0 * s + 6.0) * y[1]
            + (6.0 * s - 2.0) * h * t[1])
            / (h * h);
        [f, df, ddf]
    }

    #[test]
    fn the_cam_is_the_fritsch_carlson_cubic_through_the_edge() {
        // Progress u_edge = (0.15 − 0.001)/0.203, the rotation to B's discharge edge f_edge;
        // tangents: secants at the ends, their harmonic mean at the edge.
        let mut s = sync();
        let (x0, x1, xe) = (0.001f32, 0.204f32, 0.15f32);
        s.begin_half(Direction::TowardB, Rotation::Compressor, x0, x1, xe, 0.0);
        let geometry = PortGeometry::<f32>::reference();
        let ue = f64::from((xe - x0) / (x1 - x0));
        let fe = f64::from(geometry.half_open_rad(Port::DischargeB)) / core::f64::consts::PI;
        let (d0, d1) = (fe / ue, (1.0 - fe) / (1.0 - ue));
        let me = 2.0 * d0 * d1 / (d0 + d1);
        let (v, a) = (1.5f32, -40.0f32);
        let stroke = f64::from(x1 - x0);
        let (du, ddu) = (f64::from(v) / stroke, f64::from(a) / stroke);
        for i in 0..=1000 {
            let u = f64::from(i) / 1000.0;
            let [f, df, ddf] = if u <= ue {
                hermite(u, 0.0, ue, [0.0, fe], [d0, me])
            } else {
                hermite(u, ue, 1.0 - ue, [fe, 1.0], [me, d1])
            };
            let x = x0 + (u * stroke) as f32;
            let sp = s.setpoint(x, v, a);
            let pi = core::f64::consts::PI;
            let want = [pi * f, pi * df * du, pi * (ddf * du * du + df * ddu)];
            let got = [sp.angle_rad, sp.velocity_rad_s, sp.acceleration_rad_s2].map(f64::from);
            assert!(
                (got[0] - want[0]).abs() < 2e-5,
                "u {u}: angle {got:?} vs {want:?}"
            );
            assert!(
                (got[1] - want[1]).abs() < 1e-4 * want[1].abs().max(1.0),
                "u {u}: {got:?} vs {want:?}"
            );
            assert!(
                (got[2] - want[2]).abs() < 1e-3 * want[2].abs().max(10.0),
                "u {u}: {got:?} vs {want:?}"
            );
        }
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
