//! The laws of the machine's sensors, before any converter: what the pressure transducers
//! and the slave encoder's scale make of the true state. Written once for the simulated
//! board's sensors (`board::sensors`, `board::world`), the synthetic runs and the model-gap
//! workflow, which inverts them (`gap::residuals`).
//!
//! - **Pressure transducers** (`[sensors.pressure]`): a first-order lag `τ·ṙ = p − r`, a
//!   gain, an offset and noise, `reading = gain·r + offset + n` (noise from
//!   [`crate::plant::noise`]; the gain is the chambers' transducers', 1 for the lines'). Over
//!   a step `h` with `p` held the lag is exact, `r ← r + (1 − e^{−h/τ})·(p − r)`
//!   ([`FirstOrderLag`]); its inverse from a reading and its rate is
//!   `p = (reading − offset + τ·ṙ)/gain` ([`PressureSensor::true_pressure_pa`]).
//! - **Force readings** (`[sensors.force]`): each section reports `gain·F + offset` of the
//!   force its drive makes from its currents ([`ForceSensor::reading_n`]); inverted,
//!   `F = (reading − offset)/gain` ([`ForceSensor::force_n`]).
//! - **Pitch error of the slave scale** (`[effects.encoder_pitch_error]`): what it reads at a
//!   true position ([`PitchErrorEffect::reading_m`]), the pattern the section documents.

use fpc::units::Section;

use crate::plant::fastmath::sin_cos;
use crate::plant::model::{ForceSensor, PitchErrorEffect, PressureSensor};
use crate::plant::noise::Noise;

/// A first-order lag stepped exactly over a fixed step with its input held.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FirstOrderLag {
    /// The share of the gap closed per step, `1 − e^{−h/τ}` (1: no lag).
    pub alpha: f64,
}

impl FirstOrderLag {
    /// The lag of time constant `time_constant_s` (0 or less: none) stepped every `step_s`.
    pub fn new(time_constant_s: f64, step_s: f64) -> Self {
        FirstOrderLag {
            alpha: if time_constant_s > 0.0 {
                1.0 - (-step_s / time_constant_s).exp()
            } else {
                1.0
            },
        }
    }

    /// `lagged` one step on, following `input`.
    #[inline]
    pub fn step(&self, lagged: &mut f64, input: f64) {
        *lagged += self.alpha * (input - *lagged);
    }
}

/// The pressure channels of [`PressureSensor::transducers`], in order.
pub const PRESSURE_CHANNELS: usize = 4;

/// One pressure transducer's static error: `reading = gain·p + offset_pa`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transducer {
    /// Offset, Pa.
    pub offset_pa: f64,
    /// Gain (1: exact).
    pub gain: f64,
}

impl PressureSensor {
    /// The transducers' lag stepped every `step_s`.
    pub fn lag(&self, step_s: f64) -> FirstOrderLag {
        FirstOrderLag::new(self.time_constant_s, step_s)
    }

    /// Chamber A's transducer.
    pub fn chamber_a(&self) -> Transducer {
        Transducer {
            offset_pa: self.offset_a_pa,
            gain: self.gain_a,
        }
    }

    /// Chamber B's transducer.
    pub fn chamber_b(&self) -> Transducer {
        Transducer {
            offset_pa: self.offset_b_pa,
            gain: self.gain_b,
        }
    }

    /// The four channels' transducers: chamber A, chamber B, suction, discharge (the lines'
    /// with their offsets, at gain 1).
    pub fn transducers(&self) -> [Transducer; PRESSURE_CHANNELS] {
        let line = |offset_pa| Transducer {
            offset_pa,
            gain: 1.0,
        };
        [
            self.chamber_a(),
            self.chamber_b(),
            line(self.offset_suction_pa),
            line(self.offset_discharge_pa),
        ]
    }

    /// What transducer `t` reads with its lag at `lagged_pa` (noise aside), Pa.
    #[inline]
    pub fn reading_pa(&self, lagged_pa: f64, t: Transducer) -> f64 {
        t.gain * lagged_pa + t.offset_pa
    }

    /// What transducer `t` reads with its lag at `lagged_pa`, its noise (`noise_pa` RMS)
    /// drawn from `noise`, Pa.
    #[inline]
    pub fn noisy_reading_pa(&self, lagged_pa: f64, t: Transducer, noise: &mut Noise) -> f64 {
        self.reading_pa(lagged_pa, t) + noise.scaled(self.noise_pa)
    }

    /// The true pressure behind a reading of transducer `t`, the lag undone:
    /// `(reading − offset + τ·ṙ)/gain`, Pa (`rate_pa_per_s` the reading's rate).
    #[inline]
    pub fn true_pressure_pa(&self, reading_pa: f64, rate_pa_per_s: f64, t: Transducer) -> f64 {
        (reading_pa - t.offset_pa + self.time_constant_s * rate_pa_per_s) / t.gain
    }
}

impl ForceSensor {
    /// `(offset, gain)` of `section`'s reading, N and N/N.
    fn of(&self, section: Section) -> (f64, f64) {
        match section {
            Section::Master => (self.offset_master_n, self.gain_master),
            Section::Slave => (self.offset_slave_n, self.gain_slave),
        }
    }

    /// Whether both readings are exact (offset 0, gain 1): then a reading is the force itself,
    /// bit for bit.
    pub fn exact(&self) -> bool {
        *self == ForceSensor::default()
    }

    /// What `section` reports of the force `force_n` its drive makes, N: `gain·F + offset`.
    #[inline]
    pub fn reading_n(&self, section: Section, force_n: f64) -> f64 {
        let (offset, gain) = self.of(section);
        gain * force_n + offset
    }

    /// The force behind `section`'s reading `reading_n`, N: `(reading − offset)/gain`.
    #[inline]
    pub fn force_n(&self, section: Section, reading_n: f64) -> f64 {
        let (offset, gain) = self.of(section);
        (reading_n - offset) / gain
    }

    /// [`ForceSensor::force_n`] of every reading of `readings_n` (exact readings as they are).
    pub fn forces_n(&self, section: Section, readings_n: Vec<f64>) -> Vec<f64> {
        if self.exact() {
            return readings_n;
        }
        readings_n
            .into_iter()
            .map(|r| self.force_n(section, r))
            .collect()
    }

    /// [`ForceSensor::reading_n`] of every force of `forces_n` (exact readings as they are).
    pub fn readings_n(&self, section: Section, forces_n: Vec<f64>) -> Vec<f64> {
        if self.exact() {
            return forces_n;
        }
        forces_n
            .into_iter()
            .map(|f| self.reading_n(section, f))
            .collect()
    }
}

/// Speed below which the direction-dependent reading blends through zero, m/s.
pub const DIRECTION_BLEND_MPS: f64 = 1e-3;

impl PitchErrorEffect {
    /// The position the slave scale reads at true position `x_m` moving at `v_mps`, m:
    /// `x·(1 + scale) + A·sin(2π·x/p + φ) + A₂·sin(4π·x/p + φ₂) + S·(frac(x/p + φ/2π) − ½)
    /// + ½·D·v/(|v| + v_blend)`.
    #[inline]
    pub fn reading_m(&self, x_m: f64, v_mps: f64) -> f64 {
        let th = std::f64::consts::TAU * x_m / self.period_m;
        let mut x = x_m * (1.0 + self.scale) + self.amplitude_m * sin_cos(th + self.phase_rad).0;
        if self.amplitude2_m != 0.0 {
            x += self.amplitude2_m * sin_cos(2.0 * th + self.phase2_rad).0;
        }
        if self.step_m != 0.0 {
            let u = x_m / self.period_m + self.phase_rad / std::f64::consts::TAU;
            x += self.step_m * (u - u.floor() - 0.5);
        }
        if self.direction_m != 0.0 {
            x += 0.5 * self.direction_m * v_mps / (v_mps.abs() + DIRECTION_BLEND_MPS);
        }
        x
    }

    /// The same at rest.
    #[inline]
    pub fn reading_at_rest_m(&self, x_m: f64) -> f64 {
        self.reading_m(x_m, 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lag_steps_exactly_and_its_inverse_recovers_the_pressure() {
        // A ramp through a 1 ms lag stepped at 50 µs, read 5 % high and 250 Pa up: after the
        // transient the reading trails by τ·slope, and p = (r − offset + τ·ṙ)/gain recovers
        // the ramp.
        let sensor = PressureSensor {
            time_constant_s: 1e-3,
            offset_a_pa: 250.0,
            gain_a: 1.05,
            ..PressureSensor::default()
        };
        let (h, slope) = (50e-6, 2e6);
        let lag = sensor.lag(h);
        assert!((lag.alpha - (1.0 - (-0.05f64).exp())).abs() < 1e-15);
        let mut r = 1e5;
        let mut readings = Vec::new();
        for k in 0..400 {
            lag.step(&mut r, 1e5 + slope * k as f64 * h);
            readings.push(sensor.reading_pa(r, sensor.chamber_a()));
        }
        let k = 399;
        let rate = (readings[k] - readings[k - 1]) / h;
        let p = sensor.true_pressure_pa(readings[k], rate, sensor.chamber_a());
        // The discrete lag trails by τ − h/2 (zero-order hold): within h/2·slope = 50 Pa.
        assert!((p - (1e5 + slope * k as f64 * h)).abs() < 60.0, "{p}");
        assert_eq!(FirstOrderLag::new(0.0, h).alpha, 1.0);
    }

    #[test]
    fn pitch_error_reads_the_stated_pattern() {
        let e = PitchErrorEffect {
            amplitude_m: 1e-4,
            period_m: 0.024,
            phase_rad: 0.0,
            scale: 1e-3,
            amplitude2_m: 0.0,
            phase2_rad: 0.0,
            step_m: 0.0,
            direction_m: 0.0,
        };
        assert!((e.reading_at_rest_m(0.006) - (0.006 * 1.001 + 1e-4)).abs() < 1e-12);
        // A saw of 0.1 mm stepping once a pitch, 0.05 mm more moving toward +x.
        let saw = PitchErrorEffect {
            amplitude_m: 0.0,
            scale: 0.0,
            step_m: 1e-4,
            direction_m: 5e-5,
            ..e
        };
        let err = |x: f64, v: f64| saw.reading_m(x, v) - x;
        assert!((err(0.0241, 0.0) - (-0.5e-4 + 1e-4 * 0.1 / 24.0)).abs() < 1e-9);
        assert!((err(0.0239, 0.0) - (0.5e-4 - 1e-4 * 0.1 / 24.0)).abs() < 1e-9);
        assert!((err(0.03, 2.0) - err(0.03, -2.0) - 5e-5).abs() < 1e-7);
    }
}
