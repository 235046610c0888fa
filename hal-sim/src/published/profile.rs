//! The published rig's motion program: the paper's accelerate-then-stop velocity profile
//! (§4: "the piston was accelerated until a certain speed and then stopped"), stroke after
//! stroke between two dead points, and the rotation synchronised with it in time (§4: "both
//! the translation of the piston and its rotation were synchronized").
//!
//! A stroke of length `S` at peak speed `v` accelerates at `a = v²/S` over its first half and
//! brakes at `a` over its second, so it lasts `2S/v` (a triangle in velocity). A ramp fraction
//! `f < ½` (`[published] profile_ramp_fraction`) accelerates over the first `f·S` at
//! `a = v²/(2fS)`, cruises at `v`, and brakes over the last `f·S`: it lasts `(1 + 2f)·S/v`,
//! the same peak speed with a force `1/(2f)` times the triangle's. The rotation
//! is programmed on the *reference* stroke, not on the measured one: within a stroke the
//! port phase is piecewise linear in the reference position, half open at the isentropic
//! opening position for the programmed pressure ratio.

use std::f64::consts::{PI, TAU};

use fpc::physics::port_timing::Port;

use crate::plant::model::MachineModel;

/// One point of the programme: position, velocity and acceleration references.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Setpoint {
    /// Position, m.
    pub x_m: f64,
    /// Velocity, m/s.
    pub v_mps: f64,
    /// Acceleration, m/s².
    pub a_mps2: f64,
}

/// One accelerate-then-stop move from `from_m` to `to_m`, started at `t0_s`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stroke {
    /// Start time, s.
    pub t0_s: f64,
    /// Start position, m.
    pub from_m: f64,
    /// End position, m.
    pub to_m: f64,
    /// Peak speed (reached at mid-stroke), m/s.
    pub peak_mps: f64,
    /// Share of the stroke spent accelerating, and again braking (0.5: the triangle).
    pub ramp_fraction: f64,
}

impl Stroke {
    /// Duration, s.
    pub fn duration_s(&self) -> f64 {
        (1.0 + 2.0 * self.ramp()) * (self.to_m - self.from_m).abs() / self.peak_mps.max(1e-9)
    }

    /// The ramp fraction within (0, ½].
    fn ramp(&self) -> f64 {
        self.ramp_fraction.clamp(1e-3, 0.5)
    }

    /// End time, s.
    pub fn end_s(&self) -> f64 {
        self.t0_s + self.duration_s()
    }

    /// The references at `t_s` (held at the ends outside the move).
    pub fn at(&self, t_s: f64) -> Setpoint {
        let s = (self.to_m - self.from_m).abs();
        let dir = (self.to_m - self.from_m).signum();
        let d = self.duration_s();
        if s == 0.0 || t_s >= self.t0_s + d {
            return Setpoint {
                x_m: self.to_m,
                ..Setpoint::default()
            };
        }
        let tau = (t_s - self.t0_s).max(0.0);
        let v = self.peak_mps;
        let ramp_s = 2.0 * self.ramp() * s / v.max(1e-9);
        let a = v / ramp_s.max(1e-12);
        if tau < ramp_s {
            Setpoint {
                x_m: self.from_m + dir * 0.5 * a * tau * tau,
                v_mps: dir * a * tau,
                a_mps2: dir * a,
            }
        } else if tau < d - ramp_s {
            Setpoint {
                x_m: self.from_m + dir * (0.5 * v * ramp_s + v * (tau - ramp_s)),
                v_mps: dir * v,
                a_mps2: 0.0,
            }
        } else {
            let r = d - tau;
            Setpoint {
                x_m: self.to_m - dir * 0.5 * a * r * r,
                v_mps: dir * a * r,
                a_mps2: -dir * a,
            }
        }
    }
}

/// The port phase programmed along the reference stroke (see the module header).
#[derive(Clone, Debug, PartialEq)]
pub struct RotationProgramme {
    dead_a_m: f64,
    dead_b_m: f64,
    /// Reference position at which B's discharge is half open (stroke A → B), m.
    open_b_m: f64,
    /// Reference position at which A's discharge is half open (stroke B → A), m.
    open_a_m: f64,
    edge_b_rad: f64,
    edge_a_rad: f64,
}

impl RotationProgramme {
    /// Dead points `dead_a_m`, `dead_b_m`; discharges opening at the isentropic volume of
    /// the pressure ratio `pr`.
    pub fn new(model: &MachineModel, dead_a_m: f64, dead_b_m: f64, pr: f64) -> Self {
        let cyl = model.cylinder();
        let gas = model.gas_properties();
        // Where an isentropic compression from the chamber's largest volume reaches `pr`.
        let open = |v_max_m3: f64| gas.isentropic_volume_m3(1.0, v_max_m3, pr.max(1.0));
        let ports = model.port_geometry();
        RotationProgramme {
            dead_a_m,
            dead_b_m,
            open_b_m: cyl.position_for_volume_b_m(open(cyl.volume_b_m3(dead_a_m))),
            open_a_m: cyl.position_for_volume_a_m(open(cyl.volume_a_m3(dead_b_m))),
            edge_b_rad: ports.half_open_rad(Port::DischargeB),
            edge_a_rad: ports.half_open_rad(Port::DischargeA),
        }
    }

    /// Port phase (rad, within the turn of stroke pair `turn`) and its rate (rad/s) for the
    /// reference `sp` on a stroke toward B (`toward_b`) or toward A.
    pub fn phase(&self, sp: &Setpoint, toward_b: bool) -> (f64, f64) {
        // (position, phase) breakpoints along the stroke, in the direction of travel.
        let pts = if toward_b {
            [
                (self.dead_a_m, 0.0),
                (self.open_b_m, self.edge_b_rad),
                (self.dead_b_m, PI),
            ]
        } else {
            [
                (self.dead_b_m, PI),
                (self.open_a_m, self.edge_a_rad),
                (self.dead_a_m, TAU),
            ]
        };
        let x = sp.x_m;
        let seg = |(x0, p0): (f64, f64), (x1, p1): (f64, f64)| {
            let slope = (p1 - p0) / (x1 - x0);
            (p0 + slope * (x - x0), slope * sp.v_mps)
        };
        let first = if toward_b {
            x <= pts[1].0
        } else {
            x >= pts[1].0
        };
        let (phase, rate) = if first {
            seg(pts[0], pts[1])
        } else {
            seg(pts[1], pts[2])
        };
        let (lo, hi) = if toward_b { (0.0, PI) } else { (PI, TAU) };
        (phase.clamp(lo, hi), rate)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stroke_accelerates_then_stops_at_its_end() {
        let s = Stroke {
            t0_s: 1.0,
            from_m: 0.001,
            to_m: 0.204,
            peak_mps: 4.1,
            ramp_fraction: 0.5,
        };
        let d = s.duration_s();
        assert!((d - 2.0 * 0.203 / 4.1).abs() < 1e-12);
        let mid = s.at(1.0 + 0.5 * d);
        assert!((mid.v_mps - 4.1).abs() < 1e-9 && (mid.x_m - 0.1025).abs() < 1e-9);
        let end = s.at(1.0 + d);
        assert_eq!((end.x_m, end.v_mps), (0.204, 0.0));
        // Velocity is the derivative of position.
        let (t, h) = (1.0 + 0.3 * d, 1e-7);
        let dx = (s.at(t + h).x_m - s.at(t - h).x_m) / (2.0 * h);
        assert!((dx - s.at(t).v_mps).abs() < 1e-5);
    }

    #[test]
    fn a_shorter_ramp_cruises_at_the_peak_speed_and_pushes_harder() {
        let tri = Stroke {
            t0_s: 0.0,
            from_m: 0.204,
            to_m: 0.001,
            peak_mps: 4.1,
            ramp_fraction: 0.5,
        };
        let steep = Stroke {
            ramp_fraction: 0.125,
            ..tri
        };
        let d = steep.duration_s();
        assert!((d - 1.25 * 0.203 / 4.1).abs() < 1e-12);
        // Four times the triangle's acceleration, the same peak speed, cruising mid-stroke.
        assert!((steep.at(1e-4).a_mps2 - 4.0 * tri.at(1e-4).a_mps2).abs() < 1e-9);
        let mid = steep.at(0.5 * d);
        assert!((mid.v_mps + 4.1).abs() < 1e-9 && mid.a_mps2 == 0.0);
        assert!((mid.x_m - 0.1025).abs() < 1e-9);
        // Continuous in position and velocity everywhere; it ends at rest on its target.
        let mut last = steep.at(0.0);
        for k in 1..=2000 {
            let now = steep.at(d * k as f64 / 2000.0);
            let h = d / 2000.0;
            assert!((now.x_m - last.x_m - 0.5 * h * (now.v_mps + last.v_mps)).abs() < 1e-6);
            last = now;
        }
        assert_eq!((last.x_m, last.v_mps), (0.001, 0.0));
    }

    #[test]
    fn the_rotation_opens_the_discharge_at_the_isentropic_position() {
        let m = MachineModel::reference();
        let r = RotationProgramme::new(&m, 0.001, 0.204, 5.1);
        let at = |x| Setpoint {
            x_m: x,
            v_mps: 1.0,
            a_mps2: 0.0,
        };
        let (p, _) = r.phase(&at(r.open_b_m), true);
        assert!((p - r.edge_b_rad).abs() < 1e-12);
        assert_eq!(r.phase(&at(0.001), true).0, 0.0);
        assert!((r.phase(&at(0.204), true).0 - PI).abs() < 1e-12);
        assert!((r.phase(&at(0.001), false).0 - TAU).abs() < 1e-12);
        // V_B at the opening is V_B(dead A)·PR^(−1/γ).
        let c = m.cylinder();
        let ratio = c.volume_b_m3(0.001) / c.volume_b_m3(r.open_b_m);
        assert!((ratio - 5.1f64.powf(1.0 / 1.4)).abs() < 1e-9);
    }
}
