//! Port timing: which port of which chamber is open at a given rotation phase of the piston.
//!
//! The piston rotates monotonically, one revolution per compression cycle (A → B → A); its
//! slots sweep past the cylinder's ports, so each port is open over a fixed window of the
//! rotation phase `φ = θ mod 2π`. Phase 0 is dead point A (x at its smallest, chamber A at its
//! dead volume); the stroke A → B takes φ from 0 to π, the stroke B → A from π to 2π:
//!
//! | port | window (reference) | role |
//! |---|---|---|
//! | intake A | 0 … π | open through A's whole suction stroke |
//! | discharge A | 288° … 360° | opens when A has reached the discharge pressure |
//! | intake B | π … 2π | B's suction stroke |
//! | discharge B | 108° … 180° | as A, shifted by π |
//!
//! The window *edges are fixed geometry*. The volume ratio is set by *when* the rotation
//! crosses an edge: the rotary synchroniser shapes θ(t) so that the discharge edge is crossed
//! at the planned piston position. Reversing the rotation traverses the windows in reverse
//! order, so the discharge window admits high-pressure gas at the start of the stroke and the
//! intake window exhausts it: the machine runs as an expander.
//!
//! Each window opens and closes over a ramp of `ramp_rad` (a slot edge sweeping across the
//! port), shaped as a smoothstep so the open fraction is continuous with its slope; the
//! window's edge angle is where the port *starts* to open (or has just closed). The open
//! fraction scales the port's effective flow area `C_d·A`.
//!
//! One geometry for the simulator's plant (`f64`) and the firmware's synchroniser (`f32`).

use crate::angle::wrap_rad;
use crate::real::Real;

/// The four ports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Port {
    /// Intake (suction) port of chamber A.
    IntakeA,
    /// Discharge port of chamber A.
    DischargeA,
    /// Intake port of chamber B.
    IntakeB,
    /// Discharge port of chamber B.
    DischargeB,
}

impl Port {
    /// All four, in the order of [`PortOpenings`].
    pub const ALL: [Port; 4] = [
        Port::IntakeA,
        Port::DischargeA,
        Port::IntakeB,
        Port::DischargeB,
    ];
}

/// One port's window in rotation phase: open from `open_rad` going forward to `close_rad`
/// (the window may contain phase 0, e.g. 300° … 20°). Both in [0, 2π].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PortWindow<T> {
    /// Leading edge (where the port starts to open with forward rotation), rad.
    pub open_rad: T,
    /// Trailing edge (where it has just closed), rad.
    pub close_rad: T,
}

impl<T: Real> PortWindow<T> {
    /// A window from `open_deg` to `close_deg`, in degrees.
    pub fn from_degrees(open_deg: T, close_deg: T) -> Self {
        let k = T::PI / T::of(180.0);
        PortWindow {
            open_rad: open_deg * k,
            close_rad: close_deg * k,
        }
    }

    /// Angular length of the window, rad, in (0, 2π] (equal edges: a full turn).
    #[inline]
    pub fn span_rad(&self) -> T {
        let s = wrap_rad(self.close_rad - self.open_rad);
        if s > T::ZERO {
            s
        } else {
            T::of(2.0) * T::PI
        }
    }

    /// Open fraction 0..1 at `phase_rad` in [0, 2π) with ramps of `ramp_rad` at both edges.
    #[inline]
    pub fn fraction(&self, phase_rad: T, ramp_rad: T) -> T {
        let into = wrap_rad(phase_rad - self.open_rad);
        let span = self.span_rad();
        if into >= span {
            return T::ZERO;
        }
        let edge = into.min(span - into);
        if ramp_rad > T::ZERO {
            smoothstep(edge / ramp_rad)
        } else if edge > T::ZERO {
            T::ONE
        } else {
            T::ZERO
        }
    }
}

impl<T: Real> PortWindow<T> {
    /// Whether `phase_rad` lies in the window, the opening edge included, the closing edge not.
    #[inline]
    pub fn contains(&self, phase_rad: T) -> bool {
        wrap_rad(phase_rad - self.open_rad) < self.span_rad()
    }

    /// How long a turn of the rotation by `turn_rad` (signed: positive forward) from
    /// `phase_rad` spends in the window, s, driven toward its end at `accel_rad_s2` (> 0)
    /// from its speed `speed_rad_s` (signed). Against its speed the rotation first coasts to
    /// a stop, deeper into a window it is in, and comes back: that time counts too. 0 for no
    /// turn.
    pub fn time_in_turn(&self, phase_rad: T, turn_rad: T, speed_rad_s: T, accel_rad_s2: T) -> T {
        if turn_rad == T::ZERO {
            return T::ZERO;
        }
        let forward_turn = turn_rad > T::ZERO;
        let length = turn_rad.abs();
        // Speed along the turn, and the time to have come `s` along it (the later root:
        // against the speed the rotation passes its start again on the way).
        let v0 = if forward_turn {
            speed_rad_s
        } else {
            -speed_rad_s
        };
        let reach = |s: T| ((v0 * v0 + T::of(2.0) * accel_rad_s2 * s).sqrt() - v0) / accel_rad_s2;
        // The window in the turn's own coordinate: where it begins ahead on the path, and
        // how far into it the path begins.
        let (edge_ahead, edge_behind) = if forward_turn {
            (self.open_rad, self.close_rad)
        } else {
            (self.close_rad, self.open_rad)
        };
        let width = self.span_rad();
        let along = |a: T, b: T| {
            if forward_turn {
                wrap_rad(b - a)
            } else {
                wrap_rad(a - b)
            }
        };
        let ahead = along(phase_rad, edge_ahead);
        let mut time = T::ZERO;
        if ahead < length && ahead > T::ZERO {
            time = time + (reach((ahead + width).min(length)) - reach(ahead));
        }
        // Inside the window at the start: until the path leaves it.
        let left = along(phase_rad, edge_behind);
        if along(edge_ahead, phase_rad) < width && left > T::ZERO {
            time = time + reach(left.min(length));
        }
        time
    }
}

/// An arc of rotation phase: from `start_rad` forward over `span_rad`, rad.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseArc<T> {
    /// Where the arc begins, rad (not wrapped: an edge plus a ramp).
    pub start_rad: T,
    /// Its length going forward, rad, in [0, 2π).
    pub span_rad: T,
}

impl<T: Real> PhaseArc<T> {
    /// How far past the arc's start `phase_rad` lies going forward, rad in [0, 2π): within
    /// the arc while at most [`PhaseArc::span_rad`].
    #[inline]
    pub fn past_start(&self, phase_rad: T) -> T {
        wrap_rad(phase_rad - self.start_rad)
    }
}

/// `3t² − 2t³` on t clamped to [0, 1].
#[inline]
fn smoothstep<T: Real>(t: T) -> T {
    let t = t.max(T::ZERO).min(T::ONE);
    t * t * (T::of(3.0) - T::of(2.0) * t)
}

/// Open fraction (0 = closed, 1 = fully open) of each port.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PortOpenings<T> {
    /// Intake of chamber A.
    pub intake_a: T,
    /// Discharge of chamber A.
    pub discharge_a: T,
    /// Intake of chamber B.
    pub intake_b: T,
    /// Discharge of chamber B.
    pub discharge_b: T,
}

impl<T: Copy> PortOpenings<T> {
    /// The value for `port`.
    #[inline]
    pub fn get(&self, port: Port) -> T {
        match port {
            Port::IntakeA => self.intake_a,
            Port::DischargeA => self.discharge_a,
            Port::IntakeB => self.intake_b,
            Port::DischargeB => self.discharge_b,
        }
    }
}

/// The port geometry of the machine: windows, ramp and flow areas.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PortGeometry<T> {
    /// Intake window of chamber A.
    pub intake_a: PortWindow<T>,
    /// Discharge window of chamber A.
    pub discharge_a: PortWindow<T>,
    /// Intake window of chamber B.
    pub intake_b: PortWindow<T>,
    /// Discharge window of chamber B.
    pub discharge_b: PortWindow<T>,
    /// Angular width of the opening (and closing) ramp, rad (≥ 0).
    pub ramp_rad: T,
    /// Geometric area of an intake port fully open, m².
    pub intake_area_m2: T,
    /// Geometric area of a discharge port fully open, m².
    pub discharge_area_m2: T,
    /// Discharge coefficient C_d of the ports (effective area = C_d·A·open fraction).
    pub discharge_coefficient: T,
}

impl<T: Real> PortGeometry<T> {
    /// The reference machine (**A**, the paper gives no port geometry): windows of the table
    /// above, 6° ramps, 5 cm² ports (about 2 % pressure drop at 4 m/s), C_d 0.8. The discharge
    /// edge at 288° is where a sinusoidal stroke with uniform rotation reaches the
    /// discharge-opening volume of PR ≈ 4 (V/V₀ ≈ 0.37); the synchroniser moves the crossing
    /// to the position each pressure ratio needs.
    pub fn reference() -> Self {
        use crate::reference::ports;
        let w = |[open, close]: [f64; 2]| {
            PortWindow::from_degrees(T::of(open as f32), T::of(close as f32))
        };
        PortGeometry {
            intake_a: w(ports::INTAKE_A_DEG),
            discharge_a: w(ports::DISCHARGE_A_DEG),
            intake_b: w(ports::INTAKE_B_DEG),
            discharge_b: w(ports::DISCHARGE_B_DEG),
            ramp_rad: T::of(ports::RAMP_DEG as f32) * T::PI / T::of(180.0),
            intake_area_m2: T::of(ports::INTAKE_AREA_M2 as f32),
            discharge_area_m2: T::of(ports::DISCHARGE_AREA_M2 as f32),
            discharge_coefficient: T::of(ports::DISCHARGE_COEFFICIENT as f32),
        }
    }

    /// The window of `port`.
    #[inline]
    pub fn window(&self, port: Port) -> &PortWindow<T> {
        match port {
            Port::IntakeA => &self.intake_a,
            Port::DischargeA => &self.discharge_a,
            Port::IntakeB => &self.intake_b,
            Port::DischargeB => &self.discharge_b,
        }
    }

    /// Phase at which `port` starts to open with forward rotation, rad.
    #[inline]
    pub fn opening_edge_rad(&self, port: Port) -> T {
        self.window(port).open_rad
    }

    /// Phase at which `port` has just closed with forward rotation, rad.
    #[inline]
    pub fn closing_edge_rad(&self, port: Port) -> T {
        self.window(port).close_rad
    }

    /// Phase at which `port` is half open on its opening ramp, rad (wrapped to [0, 2π)) —
    /// the effective opening instant for timing the discharge.
    #[inline]
    pub fn half_open_rad(&self, port: Port) -> T {
        let w = self.window(port);
        let half_ramp = (T::of(0.5) * self.ramp_rad).min(T::of(0.5) * w.span_rad());
        wrap_rad(w.open_rad + half_ramp)
    }

    /// Open fraction of every port at rotation phase `phase_rad` ∈ [0, 2π).
    #[inline]
    pub fn openings(&self, phase_rad: T) -> PortOpenings<T> {
        let r = self.ramp_rad;
        PortOpenings {
            intake_a: self.intake_a.fraction(phase_rad, r),
            discharge_a: self.discharge_a.fraction(phase_rad, r),
            intake_b: self.intake_b.fraction(phase_rad, r),
            discharge_b: self.discharge_b.fraction(phase_rad, r),
        }
    }

    /// How well both chambers breathe at `phase_rad`: the smaller of the two chambers'
    /// most-open port (0: one chamber is sealed, 1: each has a port fully open).
    #[inline]
    pub fn venting(&self, phase_rad: T) -> T {
        let o = self.openings(phase_rad);
        o.intake_a
            .max(o.discharge_a)
            .min(o.intake_b.max(o.discharge_b))
    }

    /// The phases where both chambers breathe: the middle of each discharge window, where
    /// the other chamber's intake is open too (a chamber discharges while the other one
    /// takes in), kept when [`PortGeometry::venting`] is at least half open there. Parking
    /// moves the piston with the rotation at one of them, so neither chamber can be
    /// compressed sealed. Two evaluations: cheap enough for the control step's cold path.
    pub fn venting_phases_rad(&self) -> [Option<T>; 2] {
        let middle = |w: &PortWindow<T>| wrap_rad(w.open_rad + T::of(0.5) * w.span_rad());
        let keep = |phase: T| (self.venting(phase) >= T::of(0.5)).then_some(phase);
        [
            keep(middle(&self.discharge_b)),
            keep(middle(&self.discharge_a)),
        ]
    }

    /// The two arcs where both ports of a chamber (its `intake` and `discharge` windows) are
    /// closed, each inset by a ramp at both ends so the ports are fully shut on it: from the
    /// intake's closing to the discharge's opening, and from the discharge's closing to the
    /// intake's opening. `None` for an arc no longer than two ramps.
    pub fn sealed_arcs(
        &self,
        intake: &PortWindow<T>,
        discharge: &PortWindow<T>,
    ) -> [Option<PhaseArc<T>>; 2] {
        let ramp = self.ramp_rad;
        let arc = |from: T, to: T| {
            if wrap_rad(to - from) <= T::of(2.0) * ramp {
                return None;
            }
            let start_rad = from + ramp;
            Some(PhaseArc {
                start_rad,
                span_rad: wrap_rad(to - ramp - start_rad),
            })
        };
        [
            arc(intake.close_rad, discharge.open_rad),
            arc(discharge.close_rad, intake.open_rad),
        ]
    }

    /// Effective flow area C_d·A of `port` at open fraction `fraction`, m².
    #[inline]
    pub fn effective_area_m2(&self, port: Port, fraction: T) -> T {
        let area = match port {
            Port::IntakeA | Port::IntakeB => self.intake_area_m2,
            Port::DischargeA | Port::DischargeB => self.discharge_area_m2,
        };
        self.discharge_coefficient * area * fraction
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn deg(d: f64) -> f64 {
        d.to_radians()
    }

    #[test]
    fn reference_windows_open_in_the_right_strokes() {
        let g = PortGeometry::<f64>::reference();
        // Mid A→B stroke: A sucks, B compresses (closed).
        let o = g.openings(deg(60.0));
        assert_eq!(
            (o.intake_a, o.discharge_a, o.intake_b, o.discharge_b),
            (1.0, 0.0, 0.0, 0.0)
        );
        // Late A→B stroke: B discharges.
        let o = g.openings(deg(150.0));
        assert_eq!((o.intake_a, o.discharge_b), (1.0, 1.0));
        // Mid B→A stroke: B sucks, A compresses.
        let o = g.openings(deg(250.0));
        assert_eq!(
            (o.intake_a, o.discharge_a, o.intake_b, o.discharge_b),
            (0.0, 0.0, 1.0, 0.0)
        );
        let o = g.openings(deg(320.0));
        assert_eq!((o.discharge_a, o.intake_b), (1.0, 1.0));
        // At the dead points every window is at an edge: all closed, no short circuit.
        for p in [0.0, deg(180.0)] {
            let o = g.openings(p);
            assert_eq!(o.intake_a + o.discharge_a + o.intake_b + o.discharge_b, 0.0);
        }
    }

    #[test]
    fn ramps_are_continuous_and_monotonic() {
        let g = PortGeometry::<f64>::reference();
        let edge = g.opening_edge_rad(Port::DischargeA);
        let mut last = 0.0;
        for i in 0..=200 {
            let f = g.openings(edge + g.ramp_rad * i as f64 / 200.0).discharge_a;
            assert!(f >= last && f - last < 0.02);
            last = f;
        }
        assert!((last - 1.0).abs() < 1e-12);
        let half = g.openings(g.half_open_rad(Port::DischargeA)).discharge_a;
        assert!((half - 0.5).abs() < 1e-9);
        assert!((g.closing_edge_rad(Port::DischargeA) - 2.0 * core::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn the_reference_vents_both_chambers_in_each_half_turn() {
        let g = PortGeometry::<f64>::reference();
        let [first, second] = g.venting_phases_rad();
        let (first, second) = (first.unwrap(), second.unwrap());
        // A's intake with B's discharge (108°…180°), A's discharge with B's intake (288°…360°).
        assert!(
            (deg(114.0)..deg(174.0)).contains(&first),
            "{}",
            first.to_degrees()
        );
        assert!(
            (deg(294.0)..deg(354.0)).contains(&second),
            "{}",
            second.to_degrees()
        );
        assert_eq!(g.venting(first), 1.0);
        assert_eq!(g.venting(second), 1.0);
        // A sealed chamber gives nothing: A's compression (B's intake only, A closed).
        assert_eq!(g.venting(deg(230.0)), 0.0);
        let mut sealed = g;
        sealed.discharge_b = PortWindow::from_degrees(10.0, 20.0);
        sealed.discharge_a = PortWindow::from_degrees(190.0, 200.0);
        sealed.intake_a = PortWindow::from_degrees(30.0, 170.0);
        sealed.intake_b = PortWindow::from_degrees(210.0, 350.0);
        assert_eq!(sealed.venting_phases_rad(), [None, None]);
    }

    #[test]
    fn a_window_across_phase_zero_works() {
        let w = PortWindow::<f64>::from_degrees(300.0, 20.0);
        assert!((w.span_rad() - deg(80.0)).abs() < 1e-12);
        assert_eq!(w.fraction(deg(350.0), deg(5.0)), 1.0);
        assert_eq!(w.fraction(deg(10.0), deg(5.0)), 1.0);
        assert_eq!(w.fraction(deg(30.0), deg(5.0)), 0.0);
        assert_eq!(w.fraction(deg(200.0), deg(5.0)), 0.0);
    }

    #[test]
    fn a_window_contains_its_opening_edge_not_its_closing_one() {
        let w = PortWindow::<f64>::from_degrees(300.0, 20.0);
        assert!(w.contains(deg(300.0)) && w.contains(deg(10.0)) && w.contains(deg(359.0)));
        assert!(!w.contains(deg(20.0)) && !w.contains(deg(150.0)));
    }

    #[test]
    fn the_reference_seals_each_chamber_on_one_arc_between_its_ports() {
        let g = PortGeometry::<f64>::reference();
        // A: intake closes at 180°, discharge opens at 288° (an arc of 108°, 96° inset by
        // the 6° ramps); discharge closes at 360° where the intake opens: no arc.
        let [a, none] = g.sealed_arcs(&g.intake_a, &g.discharge_a);
        let a = a.unwrap();
        assert!(
            (a.start_rad - deg(186.0)).abs() < 1e-12,
            "{}",
            a.start_rad.to_degrees()
        );
        assert!(
            (a.span_rad - deg(96.0)).abs() < 1e-12,
            "{}",
            a.span_rad.to_degrees()
        );
        assert_eq!(none, None);
        assert!((a.past_start(deg(200.0)) - deg(14.0)).abs() < 1e-12);
        assert!(a.past_start(deg(100.0)) > a.span_rad);
        // B: 360°…108°, inset to 366° (6°)…102°; its other arc closes up at 180°.
        let [b, none] = g.sealed_arcs(&g.intake_b, &g.discharge_b);
        let b = b.unwrap();
        assert!((wrap_rad(b.start_rad) - deg(6.0)).abs() < 1e-12);
        assert!((b.span_rad - deg(96.0)).abs() < 1e-12);
        assert_eq!(none, None);
    }

    #[test]
    fn zero_ramp_opens_as_a_step() {
        let w = PortWindow::<f64>::from_degrees(10.0, 20.0);
        assert_eq!(w.fraction(deg(15.0), 0.0), 1.0);
        assert_eq!(w.fraction(deg(25.0), 0.0), 0.0);
        assert_eq!(w.fraction(deg(10.0), 0.0), 0.0);
    }

    #[test]
    fn f32_geometry_matches_f64() {
        let g64 = PortGeometry::<f64>::reference();
        let g32 = PortGeometry::<f32>::reference();
        for i in 0..720 {
            let p = deg(i as f64 * 0.5);
            let a = g64.openings(p);
            let b = g32.openings(p as f32);
            for port in Port::ALL {
                assert!(
                    (a.get(port) - f64::from(b.get(port))).abs() < 1e-3,
                    "{port:?} at {i}"
                );
            }
        }
    }

    /// The same time found by stepping the motion through time: the angle at full
    /// acceleration toward the turn from the speed now, and whether it is in the window,
    /// tested directly at each step of 1 µs until the turn is done.
    fn stepped(phase: f32, turn: f32, w: &PortWindow<f32>, speed: f32, accel: f32) -> f32 {
        let (phase, turn, speed, accel) = (
            f64::from(phase),
            f64::from(turn),
            f64::from(speed),
            f64::from(accel),
        );
        let (open, close) = (f64::from(w.open_rad), f64::from(w.close_rad));
        let tau = std::f64::consts::TAU;
        let dir = turn.signum();
        let dt = 1e-6;
        let (mut angle, mut v, mut inside_s) = (0.0f64, speed * dir, 0.0);
        while angle < turn.abs() {
            let at = (phase + dir * angle).rem_euclid(tau);
            if (at - open).rem_euclid(tau) < (close - open).rem_euclid(tau) {
                inside_s += dt;
            }
            v += accel * dt;
            angle += v * dt;
        }
        inside_s as f32
    }

    #[test]
    fn the_time_in_a_window_is_the_stepped_motions() {
        let g = PortGeometry::<f32>::reference();
        let accel = 2500.0;
        // Each way, with and against the speed, from inside the window, before it and past
        // it; the coast before turning round stays well inside the region it starts in.
        let deg = |d: f32| d.to_radians();
        let cases = [
            (deg(327.7), deg(38.3), -34.0),
            (deg(327.7), deg(-225.7), -34.0),
            (deg(250.0), deg(116.0), -34.0),
            (deg(250.0), deg(-148.0), -34.0),
            (deg(250.0), deg(116.0), 34.0),
            (deg(100.0), deg(250.0), 20.0),
            (deg(20.0), deg(-120.0), 0.0),
            (deg(20.0), 0.0, 34.0),
        ];
        for (phase, turn, speed) in cases {
            let w = &g.discharge_a;
            let formula = w.time_in_turn(phase, turn, speed, accel);
            let reference = stepped(phase, turn, w, speed, accel);
            println!("φ {phase:.3} turn {turn:+.3} ω {speed:+.0}: {formula:.6} s (stepped {reference:.6} s)");
            assert!(
                (formula - reference).abs() < 2e-5,
                "φ {phase} turn {turn} ω {speed}: {formula} s, stepped {reference} s"
            );
        }
    }
}
