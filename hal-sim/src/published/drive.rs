//! One industrial servo drive of the published rig, as the paper describes it and as such
//! drives are built — written apart from this project's firmware (none of `fpc::control`,
//! `fpc::drive`, `fpc::motion` or `fpc::sensing` is used):
//!
//! - its own sin/cos encoder, read by `atan2` and counted period by period;
//! - its own velocity estimate, the backward difference of the position over one drive cycle
//!   (the paper's Eq. 5), optionally smoothed and delayed before the loop uses it, and the
//!   *reported* velocity (what the paper logged as "readings from drive", Fig. 7): a moving
//!   average whose delay is the paper's 8.5 ms;
//! - a cascade run every drive cycle: position P with velocity feed-forward, then a velocity
//!   PI whose output is the force setpoint (the paper's "PI-controller");
//! - a current loop per section every 50 µs: PI in the section's dq frame on the drive's own
//!   encoder angle, back-EMF feed-forward, the voltage vector held within the bus.

use std::collections::VecDeque;
use std::f64::consts::TAU;

use fpc::physics::motor::{clarke, inverse_clarke, inverse_park, park, AlphaBeta, Dq};
use fpc::ports::SinCosCodes;
use fpc::units::{Duty, PhaseDuties};

/// Position from a sin/cos encoder: the angle of the two channels about mid-scale, counted
/// across periods from a known start.
#[derive(Clone, Debug, PartialEq)]
pub struct EncoderReader {
    period_m: f64,
    /// Whole periods counted.
    periods: i64,
    /// Angle of the last reading, rad in (−π, π].
    last_rad: f64,
}

impl EncoderReader {
    /// A reader zeroed so that `codes` read `x_m` (the rig's homing, done before).
    pub fn zeroed(period_m: f64, codes: SinCosCodes, x_m: f64) -> Self {
        let a = angle(codes);
        let frac = a / TAU * period_m;
        EncoderReader {
            period_m,
            periods: ((x_m - frac) / period_m).round() as i64,
            last_rad: a,
        }
    }

    /// The position `codes` read, m (a step of more than half a period between two readings
    /// is taken as the shorter way round).
    pub fn read(&mut self, codes: SinCosCodes) -> f64 {
        let a = angle(codes);
        let d = a - self.last_rad;
        if d > std::f64::consts::PI {
            self.periods -= 1;
        } else if d < -std::f64::consts::PI {
            self.periods += 1;
        }
        self.last_rad = a;
        (self.periods as f64 + a / TAU) * self.period_m
    }
}

fn angle(c: SinCosCodes) -> f64 {
    let s = f64::from(c.sin.0) - 2048.0;
    let k = f64::from(c.cos.0) - 2048.0;
    s.atan2(k)
}

/// A transport delay of whole samples.
#[derive(Clone, Debug, PartialEq)]
pub struct Delay {
    buf: VecDeque<f64>,
}

impl Delay {
    /// A delay of `n` samples, initially zero.
    pub fn new(n: usize) -> Self {
        Delay {
            buf: std::iter::repeat_n(0.0, n).collect(),
        }
    }

    /// Stores `v`, returns the value of `n` samples ago.
    pub fn push(&mut self, v: f64) -> f64 {
        self.buf.push_back(v);
        self.buf.pop_front().unwrap_or(v)
    }
}

/// Gains and timing of the drive's cascade.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopGains {
    /// Drive cycle, s.
    pub cycle_s: f64,
    /// Position gain K_v, 1/s.
    pub position_gain_per_s: f64,
    /// Velocity PI proportional gain, N·s/m.
    pub velocity_gain_ns_per_m: f64,
    /// Velocity PI integral time, s (0: no integral).
    pub velocity_integral_time_s: f64,
    /// Velocity feed-forward, fraction of the reference velocity.
    pub velocity_feedforward: f64,
    /// First-order smoothing of the velocity the loop closes on, s.
    pub velocity_filter_s: f64,
    /// Extra delay of the velocity the loop closes on, drive cycles.
    pub loop_velocity_delay_cycles: usize,
    /// Moving-average length of the reported velocity, drive cycles.
    pub reported_velocity_cycles: usize,
    /// Largest force setpoint, N (both sections).
    pub force_limit_n: f64,
}

/// The cascade of the master drive (position P, velocity PI), run once per drive cycle.
#[derive(Clone, Debug, PartialEq)]
pub struct Cascade {
    g: LoopGains,
    x_prev_m: Option<f64>,
    v_filtered: f64,
    v_delay: Delay,
    reported: VecDeque<f64>,
    reported_sum: f64,
    integral_n: f64,
    /// The velocity the loop used last, m/s.
    pub loop_velocity_mps: f64,
    /// The drive's velocity reading, m/s.
    pub reported_velocity_mps: f64,
    /// The backward-difference velocity of the last cycle, m/s.
    pub raw_velocity_mps: f64,
}

impl Cascade {
    /// A cascade at rest.
    pub fn new(g: LoopGains) -> Self {
        Cascade {
            g,
            x_prev_m: None,
            v_filtered: 0.0,
            v_delay: Delay::new(g.loop_velocity_delay_cycles),
            reported: VecDeque::with_capacity(g.reported_velocity_cycles.max(1)),
            reported_sum: 0.0,
            integral_n: 0.0,
            loop_velocity_mps: 0.0,
            reported_velocity_mps: 0.0,
            raw_velocity_mps: 0.0,
        }
    }

    /// One drive cycle: the measured position `x_m` and the references `x_ref_m`, `v_ref_mps`
    /// give the force setpoint, N (both sections together).
    pub fn step(&mut self, x_m: f64, x_ref_m: f64, v_ref_mps: f64) -> f64 {
        let g = &self.g;
        let t = g.cycle_s;
        let raw = self.x_prev_m.map_or(0.0, |p| (x_m - p) / t);
        self.x_prev_m = Some(x_m);
        self.raw_velocity_mps = raw;
        let alpha = if g.velocity_filter_s > 0.0 {
            t / (g.velocity_filter_s + t)
        } else {
            1.0
        };
        self.v_filtered += alpha * (raw - self.v_filtered);
        let v = self.v_delay.push(self.v_filtered);
        self.loop_velocity_mps = v;
        // The reading: a moving average of the raw velocity.
        let n = g.reported_velocity_cycles.max(1);
        self.reported.push_back(raw);
        self.reported_sum += raw;
        if self.reported.len() > n {
            self.reported_sum -= self.reported.pop_front().unwrap_or(0.0);
        }
        self.reported_velocity_mps = self.reported_sum / self.reported.len() as f64;

        let v_cmd = g.velocity_feedforward * v_ref_mps + g.position_gain_per_s * (x_ref_m - x_m);
        let e = v_cmd - v;
        let p = g.velocity_gain_ns_per_m * e;
        let lim = g.force_limit_n;
        if g.velocity_integral_time_s > 0.0 {
            let di = g.velocity_gain_ns_per_m * e * t / g.velocity_integral_time_s;
            // Conditional integration: no wind-up while the output is at its limit.
            let next = self.integral_n + di;
            if (p + next).abs() < lim || (p + next).abs() < (p + self.integral_n).abs() {
                self.integral_n = next;
            }
        }
        (p + self.integral_n).clamp(-lim, lim)
    }
}

/// The current loop of one section: PI on the q and d currents in the section's frame as
/// the drive's encoder gives it.
#[derive(Clone, Debug, PartialEq)]
pub struct CurrentLoop {
    kp_v_per_a: f64,
    ki_v_per_as: f64,
    integral: Dq<f64>,
    bus_v: f64,
    back_emf_v_per_mps: f64,
    period_s: f64,
}

impl CurrentLoop {
    /// Bandwidth `bandwidth_hz` by pole-zero cancellation on `R`, `L`, run every `period_s`.
    pub fn new(
        resistance_ohm: f64,
        inductance_h: f64,
        bandwidth_hz: f64,
        bus_v: f64,
        back_emf_v_per_mps: f64,
        period_s: f64,
    ) -> Self {
        let w = TAU * bandwidth_hz;
        CurrentLoop {
            kp_v_per_a: inductance_h * w,
            ki_v_per_as: resistance_ohm * w,
            integral: Dq::default(),
            bus_v,
            back_emf_v_per_mps,
            period_s,
        }
    }

    /// Duties that drive `iq_ref_a` (d current 0) given the measured phase currents, the
    /// electrical angle (sin, cos) from the drive's encoder and its velocity estimate.
    pub fn step(
        &mut self,
        iq_ref_a: f64,
        phase_currents_a: [f64; 3],
        (sin, cos): (f64, f64),
        v_mps: f64,
    ) -> PhaseDuties {
        let i = park(clarke(phase_currents_a), sin, cos);
        let e = Dq {
            d: -i.d,
            q: iq_ref_a - i.q,
        };
        let ff = self.back_emf_v_per_mps * v_mps;
        let mut v = Dq {
            d: self.kp_v_per_a * e.d + self.integral.d,
            q: self.kp_v_per_a * e.q + self.integral.q + ff,
        };
        // Linear range of centred (min-max) modulation: |v| ≤ V_bus/√3.
        let vmax = self.bus_v / 3f64.sqrt();
        let mag = (v.d * v.d + v.q * v.q).sqrt();
        let saturated = mag > vmax;
        if saturated {
            v.d *= vmax / mag;
            v.q *= vmax / mag;
        } else {
            self.integral.d += self.ki_v_per_as * e.d * self.period_s;
            self.integral.q += self.ki_v_per_as * e.q * self.period_s;
        }
        duties(inverse_park(v, sin, cos), self.bus_v)
    }
}

/// Centred sine-triangle modulation of a stator-frame voltage vector.
fn duties(v: AlphaBeta<f64>, bus_v: f64) -> PhaseDuties {
    let p = inverse_clarke(v);
    let hi = p.iter().copied().fold(f64::MIN, f64::max);
    let lo = p.iter().copied().fold(f64::MAX, f64::min);
    let common = -0.5 * (hi + lo);
    p.map(|u| Duty::from_fraction((0.5 + (u + common) / bus_v) as f32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpc::units::AdcCode;

    fn codes(x: f64, period: f64) -> SinCosCodes {
        let th = TAU * x / period;
        SinCosCodes {
            sin: AdcCode((2048.0 + 1600.0 * th.sin()).round() as u16),
            cos: AdcCode((2048.0 + 1600.0 * th.cos()).round() as u16),
        }
    }

    #[test]
    fn the_encoder_counts_periods_both_ways() {
        let p = 0.024;
        let mut r = EncoderReader::zeroed(p, codes(0.0511, p), 0.0511);
        for i in 0..4000 {
            let x = 0.0511 + 0.1 * (i as f64 * 0.003).sin();
            let got = r.read(codes(x, p));
            assert!((got - x).abs() < 20e-6, "{x} read {got}");
        }
    }

    #[test]
    fn the_reported_velocity_is_late_by_half_its_window() {
        let g = LoopGains {
            cycle_s: 1e-4,
            position_gain_per_s: 0.0,
            velocity_gain_ns_per_m: 0.0,
            velocity_integral_time_s: 0.0,
            velocity_feedforward: 0.0,
            velocity_filter_s: 0.0,
            loop_velocity_delay_cycles: 0,
            reported_velocity_cycles: 170,
            force_limit_n: 1.0,
        };
        let mut c = Cascade::new(g);
        // A ramp in velocity: v = t. The moving average of the backward difference is late by
        // (170 − 1)/2 + 1/2 cycles = 8.5 ms.
        for k in 0..1000 {
            let t = k as f64 * 1e-4;
            c.step(0.5 * t * t, 0.0, 0.0);
        }
        let t = 999.0 * 1e-4;
        assert!((t - c.reported_velocity_mps - 8.5e-3).abs() < 1e-6);
    }

    #[test]
    fn the_modulation_makes_the_voltage_vector() {
        let v = AlphaBeta {
            alpha: 250.0,
            beta: -120.0,
        };
        let d = duties(v, 560.0);
        let back: [f64; 3] = fpc::drive::foc::phase_voltages(&d, 560.0);
        let ab = clarke(back);
        assert!((ab.alpha - v.alpha).abs() < 0.1 && (ab.beta - v.beta).abs() < 0.1);
    }
}
