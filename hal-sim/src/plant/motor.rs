//! The two linear-motor sections: averaged-PWM three-phase model in each section's own dq
//! frame, and the effects that make them differ.
//!
//! Per section: `L·di_d/dt = v_d − R·i_d + ω_e·L·i_q`, `L·di_q/dt = v_q − R·i_q − ω_e·L·i_d −
//! K_e·v`, force `K_f·i_q` (the library's [`MotorParams`] and transforms). The PWM duties
//! are held over a control period, as the averaged inverter applies them.
//!
//! - **Misalignment** (paper Eq. 4): the slave section's magnets sit `D_dif` along x from where
//!   its encoder says, so its dq frame is rotated by `2π·D_dif/λ` from the frame the firmware
//!   commutates in; part of its current then makes no force.
//! - **Slave follows master** (the published rig): the slave section's drive ignores this
//!   board's PWM and imposes `i_q(t) = i_q,master(t − delay)`, `i_d = 0`.
//! - **Actuator lag**: each section's force follows `K_f·i_q` late by a delay (what the drive
//!   reports and what acts differ).

use fpc::physics::motor::{inverse_clarke, inverse_park, park, AlphaBeta, Dq, MotorParams};
use fpc::units::{PerSection, Section};

use crate::plant::fastmath::sin_cos;

/// A transport delay sampled once per plant sub-step, read with linear interpolation.
#[derive(Clone, Debug, PartialEq)]
pub struct DelayLine {
    buf: Vec<f64>,
    head: usize,
    delay_steps: f64,
}

impl DelayLine {
    /// A delay of `delay_s` for samples `dt_s` apart, initially all zero.
    pub fn new(delay_s: f64, dt_s: f64) -> Self {
        let delay_steps = (delay_s / dt_s).max(0.0);
        let len = delay_steps.ceil() as usize + 2;
        DelayLine {
            buf: vec![0.0; len],
            head: 0,
            delay_steps,
        }
    }

    /// Stores this step's input and returns the input of `delay` ago.
    #[inline]
    pub fn push(&mut self, value: f64) -> f64 {
        let len = self.buf.len();
        self.head = (self.head + 1) % len;
        self.buf[self.head] = value;
        let whole = self.delay_steps.floor();
        let frac = self.delay_steps - whole;
        let back = whole as usize % len;
        let i0 = (self.head + len - back) % len;
        let i1 = (i0 + len - 1) % len;
        self.buf[i0] + frac * (self.buf[i1] - self.buf[i0])
    }
}

/// `1/x` for the last `x` asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Reciprocal {
    x: f64,
    inv: f64,
}

impl Default for Reciprocal {
    /// Computed at the first use (NaN equals nothing).
    fn default() -> Self {
        Reciprocal {
            x: f64::NAN,
            inv: f64::NAN,
        }
    }
}

impl Reciprocal {
    #[inline]
    fn of(&mut self, x: f64) -> f64 {
        if self.x != x {
            *self = Reciprocal { x, inv: 1.0 / x };
        }
        self.inv
    }
}

/// Parameters of both sections.
#[derive(Clone, Debug, PartialEq)]
pub struct SectionParams {
    /// Each section's electrical parameters.
    pub motor: PerSection<MotorParams<f64>>,
    /// Misalignment of the slave section's magnets, m (0 = none).
    pub slave_offset_m: f64,
    /// Delay of the slave's q current behind the master's when it follows the master, s.
    pub slave_lag_s: Option<f64>,
    /// Delay of each section's force behind its current, s.
    pub actuator_lag_s: Option<f64>,
}

/// State of both sections.
#[derive(Clone, Debug, PartialEq)]
pub struct Sections {
    /// Parameters.
    pub params: SectionParams,
    /// d/q currents of each section in its own magnet frame, A.
    pub current: PerSection<Dq<f64>>,
    /// Force each section delivers, N.
    pub force_n: PerSection<f64>,
    /// sin/cos of each section's electrical angle at the plant's current position.
    angle: PerSection<(f64, f64)>,
    /// The position `angle` is for, m.
    angle_x_m: f64,
    /// Per section: 1/period (rad/m after ×2π) and 1/L, kept for the parameters in use
    /// (divisions dominate the step's cost).
    inv_period: PerSection<Reciprocal>,
    inv_inductance: PerSection<Reciprocal>,
    /// sin/cos of the slave's misalignment angle.
    offset: (f64, f64),
    follower: Option<DelayLine>,
    force_lag: Option<PerSection<DelayLine>>,
}

impl Sections {
    /// Both sections at rest, for a piston at `x_m`, stepped every `dt_s`.
    pub fn new(params: SectionParams, x_m: f64, dt_s: f64) -> Self {
        let period = params.motor.master.electrical_period_m;
        let delta = -std::f64::consts::TAU * params.slave_offset_m / period;
        let mut s = Sections {
            current: PerSection::default(),
            force_n: PerSection::default(),
            angle: PerSection::default(),
            angle_x_m: f64::NAN,
            inv_period: PerSection::default(),
            inv_inductance: PerSection::default(),
            offset: delta.sin_cos(),
            follower: params.slave_lag_s.map(|d| DelayLine::new(d, dt_s)),
            force_lag: params.actuator_lag_s.map(|d| PerSection {
                master: DelayLine::new(d, dt_s),
                slave: DelayLine::new(d, dt_s),
            }),
            params,
        };
        s.set_position(x_m);
        s
    }

    /// Recomputes the electrical angles for a piston at `x_m` (once per sub-step).
    #[inline]
    pub fn set_position(&mut self, x_m: f64) {
        self.angle_x_m = x_m;
        let period = self.params.motor.master.electrical_period_m;
        let per_m = self.inv_period.master.of(period);
        let (s, c) = sin_cos(std::f64::consts::TAU * per_m * x_m);
        let (so, co) = self.offset;
        self.angle = PerSection {
            master: (s, c),
            slave: (s * co + c * so, c * co - s * so),
        };
    }

    /// (sin, cos) of `section`'s electrical angle at the position last set.
    #[inline]
    pub fn angle(&self, section: Section) -> (f64, f64) {
        *self.angle.get(section)
    }

    /// sin/cos of the master section's electrical angle `2π·x/period`, if the last
    /// [`Sections::set_position`] was for `x_m` (the plant reuses it for the cogging).
    #[inline]
    pub fn master_angle_at(&self, x_m: f64) -> Option<(f64, f64)> {
        (self.angle_x_m == x_m).then_some(self.angle.master)
    }

    /// Phase currents of `section`, A.
    pub fn phase_currents(&self, section: Section) -> [f64; 3] {
        let (s, c) = *self.angle.get(section);
        inverse_clarke(inverse_park(*self.current.get(section), s, c))
    }

    /// One sub-step of the currents with each section's stator-frame voltages (`None`: that
    /// bridge is off) at piston speed `v_mps`. Updates the forces.
    pub fn step(&mut self, voltage: &PerSection<Option<AlphaBeta<f64>>>, v_mps: f64, dt_s: f64) {
        for section in Section::ALL {
            let m = self.params.motor.get(section);
            let i = *self.current.get(section);
            let (s, c) = *self.angle.get(section);
            let next = match (section, &mut self.follower, voltage.get(section)) {
                (Section::Slave, Some(delay), _) => Dq {
                    d: 0.0,
                    q: delay.push(self.current.master.q),
                },
                // Outputs off: the bridge is open, the currents decay through the diodes
                // within a few µs — modelled as zero current.
                (_, _, None) => Dq::default(),
                (_, _, Some(v)) => {
                    let v = park(*v, s, c);
                    let per_m = self.inv_period.get_mut(section).of(m.electrical_period_m);
                    let we = std::f64::consts::TAU * per_m * v_mps;
                    let l = m.inductance_h;
                    let inv_l = self.inv_inductance.get_mut(section).of(l);
                    let did = (v.d - m.resistance_ohm * i.d + we * l * i.q) * inv_l;
                    let diq = (v.q
                        - m.resistance_ohm * i.q
                        - we * l * i.d
                        - m.back_emf_v_per_mps() * v_mps)
                        * inv_l;
                    Dq {
                        d: i.d + did * dt_s,
                        q: i.q + diq * dt_s,
                    }
                }
            };
            *self.current.get_mut(section) = next;
            let f = m.force_constant_n_per_a * next.q;
            *self.force_n.get_mut(section) = match &mut self.force_lag {
                Some(lines) => lines.get_mut(section).push(f),
                None => f,
            };
        }
    }

    /// Electrical period, m.
    pub fn electrical_period_m(&self) -> f64 {
        self.params.motor.master.electrical_period_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delay_line_delays_by_whole_and_fractional_steps() {
        let mut d = DelayLine::new(3.5e-3, 1e-3);
        let out: Vec<f64> = (0..10).map(|i| d.push(i as f64)).collect();
        assert_eq!(out[9], 9.0 - 3.5);
        let mut z = DelayLine::new(0.0, 1e-3);
        assert_eq!(z.push(4.0), 4.0);
    }

    #[test]
    fn the_following_slave_repeats_the_master_current_late() {
        let p = SectionParams {
            motor: PerSection {
                master: MotorParams::reference(),
                slave: MotorParams::reference(),
            },
            slave_offset_m: 0.0,
            slave_lag_s: Some(0.75e-3),
            actuator_lag_s: None,
        };
        let dt = 25e-6;
        let mut s = Sections::new(p, 0.1, dt);
        let v = PerSection {
            master: Some(AlphaBeta {
                alpha: 0.0,
                beta: 0.0,
            }),
            slave: Some(AlphaBeta::default()),
        };
        s.current.master.q = 10.0;
        let mut trace = Vec::new();
        for _ in 0..60 {
            s.step(&v, 0.0, dt);
            trace.push((s.current.master.q, s.current.slave.q));
        }
        // 0.75 ms = 30 sub-steps.
        let (m_then, _) = trace[20];
        let (_, s_now) = trace[50];
        assert!((m_then - s_now).abs() < 1e-9);
    }
}
