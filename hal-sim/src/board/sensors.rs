//! Sensor models of the simulated board: the two sin/cos encoders (offsets, gain and phase
//! errors, noise, 12-bit quantisation, the slave's pitch error), the phase-current sensing
//! (offsets, noise), the four pressure sensors (first-order lag, offset, noise) and the
//! servo's quadrature counter — and the seeded noise they draw from.
//!
//! Noise is cheap and deterministic: a ChaCha8 stream seeded per run, cut into 12-bit
//! indices into a 4096-entry table of the standard normal's quantiles (tails clipped at
//! ±3.5 σ). Five samples per 64-bit draw, no transcendental function per sample.

use std::sync::OnceLock;

use fpc::drive::foc::CurrentSense;
use fpc::sensing::pressure::PressureCalibration;
use fpc::units::{AdcCode, PerSection};
use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::plant::fastmath::sin_cos;
use crate::plant::model::{EncoderSensor, MachineModel, PitchErrorEffect};

/// Entries of the normal-quantile table (12 bits).
const TABLE_BITS: u32 = 12;
const TABLE_LEN: usize = 1 << TABLE_BITS;

fn normal_table() -> &'static [f64; TABLE_LEN] {
    static TABLE: OnceLock<[f64; TABLE_LEN]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = [0.0; TABLE_LEN];
        for (i, v) in t.iter_mut().enumerate() {
            *v = inverse_normal_cdf((i as f64 + 0.5) / TABLE_LEN as f64);
        }
        // Remove the tiny residual mean and scale to unit variance exactly.
        let n = TABLE_LEN as f64;
        let mean = t.iter().sum::<f64>() / n;
        let var = t.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        let k = 1.0 / var.sqrt();
        for v in &mut t {
            *v = (*v - mean) * k;
        }
        t
    })
}

/// Φ⁻¹(p) for p in (0, 1) (Acklam's rational approximation, relative error < 1.2e-9).
pub fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let p = p.clamp(1e-300, 1.0 - 1e-16);
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// Seeded standard-normal noise (see the module header).
#[derive(Clone, Debug)]
pub struct Noise {
    rng: ChaCha8Rng,
    bits: u64,
    left: u32,
    table: &'static [f64; TABLE_LEN],
}

impl Noise {
    /// A noise stream for `seed`.
    pub fn new(seed: u64) -> Self {
        Noise {
            rng: ChaCha8Rng::seed_from_u64(seed),
            bits: 0,
            left: 0,
            table: normal_table(),
        }
    }

    /// The next standard-normal sample.
    #[inline]
    pub fn normal(&mut self) -> f64 {
        if self.left == 0 {
            self.bits = self.rng.next_u64();
            self.left = 64 / TABLE_BITS;
        }
        let i = (self.bits as usize) & (TABLE_LEN - 1);
        self.bits >>= TABLE_BITS;
        self.left -= 1;
        self.table[i]
    }

    /// `sigma` times the next sample (no draw when `sigma` is zero, so a noiseless sensor
    /// leaves the stream of the others unchanged).
    #[inline]
    pub fn scaled(&mut self, sigma: f64) -> f64 {
        if sigma == 0.0 {
            0.0
        } else {
            sigma * self.normal()
        }
    }
}

/// A 12-bit ADC conversion of a value in codes (rounded, clamped to the range; NaN reads 0).
#[inline]
pub fn adc(code: f64) -> AdcCode {
    // `as` saturates (below 0 and NaN → 0), so only the top needs a bound.
    AdcCode(((code + 0.5) as u16).min(4095))
}

/// One sin/cos encoder at the ADC.
#[derive(Clone, Debug, PartialEq)]
pub struct EncoderModel {
    /// Signal period λ, m.
    pub period_m: f64,
    /// Sine amplitude, codes.
    pub amplitude_codes: f64,
    /// Sine offset from mid-scale, codes.
    pub sin_offset_codes: f64,
    /// Cosine offset from mid-scale, codes.
    pub cos_offset_codes: f64,
    /// Cosine amplitude / sine amplitude − 1.
    pub gain_mismatch: f64,
    /// Phase error of the cosine channel, rad.
    pub quadrature_error_rad: f64,
    /// Noise per channel, codes RMS.
    pub noise_codes: f64,
}

impl EncoderModel {
    /// From the model's `[sensors.encoder_*]` section.
    pub fn new(period_m: f64, s: &EncoderSensor) -> Self {
        EncoderModel {
            period_m,
            amplitude_codes: s.amplitude_codes,
            sin_offset_codes: s.sin_offset_codes,
            cos_offset_codes: s.cos_offset_codes,
            gain_mismatch: s.gain_mismatch,
            quadrature_error_rad: s.quadrature_error_rad,
            noise_codes: s.noise_codes,
        }
    }

    /// An ideal encoder of nominal amplitude.
    pub fn ideal(period_m: f64) -> Self {
        Self::new(period_m, &EncoderSensor::default())
    }

    /// The two channel values (codes, before noise and quantisation) at the position the
    /// encoder reads, `x_read_m`.
    #[inline]
    pub fn signals(&self, x_read_m: f64) -> (f64, f64) {
        let th = self.angle_rad(x_read_m);
        self.signals_at(th, sin_cos(th))
    }

    /// The signal angle `2π·x/λ` at the position the encoder reads, rad, evaluated as
    /// `(2π·(1/λ))·x`, as the motors evaluate their electrical angle (so that a scale of the
    /// motor's period can read the motors' sine and cosine, bit for bit).
    #[inline]
    pub fn angle_rad(&self, x_read_m: f64) -> f64 {
        std::f64::consts::TAU * (1.0 / self.period_m) * x_read_m
    }

    /// [`EncoderModel::signals`] at the signal angle `th` with its `(sin, cos)` given (both
    /// encoders read the same angle when they have the same period and no pitch error).
    #[inline]
    pub fn signals_at(&self, th: f64, (s, c): (f64, f64)) -> (f64, f64) {
        let a = self.amplitude_codes;
        let c = if self.quadrature_error_rad == 0.0 {
            c
        } else {
            sin_cos(th + self.quadrature_error_rad).1
        };
        let sin = 2048.0 + self.sin_offset_codes + a * s;
        let cos = 2048.0 + self.cos_offset_codes + a * (1.0 + self.gain_mismatch) * c;
        (sin, cos)
    }
}

/// Pitch error of the slave encoder's scale: what it reads at true position x.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PitchError {
    /// Amplitude at the period, m.
    pub amplitude_m: f64,
    /// Period, m.
    pub period_m: f64,
    /// Phase, rad.
    pub phase_rad: f64,
    /// Scale error.
    pub scale: f64,
    /// Amplitude at half the period, m.
    pub amplitude2_m: f64,
    /// Phase of the half-period term, rad.
    pub phase2_rad: f64,
    /// Step once per period, m.
    pub step_m: f64,
    /// Difference between the readings moving toward +x and toward −x, m.
    pub direction_m: f64,
}

/// Speed below which the direction-dependent reading blends through zero, m/s.
pub const DIRECTION_BLEND_MPS: f64 = 1e-3;

impl PitchError {
    /// From `[effects.encoder_pitch_error]`.
    pub fn new(e: &PitchErrorEffect) -> Self {
        PitchError {
            amplitude_m: e.amplitude_m,
            period_m: e.period_m,
            phase_rad: e.phase_rad,
            scale: e.scale,
            amplitude2_m: e.amplitude2_m,
            phase2_rad: e.phase2_rad,
            step_m: e.step_m,
            direction_m: e.direction_m,
        }
    }

    /// The position the encoder reads at true position `x_m`, at rest, m.
    #[inline]
    pub fn read_m(&self, x_m: f64) -> f64 {
        self.read_moving_m(x_m, 0.0)
    }

    /// The position the encoder reads at true position `x_m` moving at `v_mps`, m.
    #[inline]
    pub fn read_moving_m(&self, x_m: f64, v_mps: f64) -> f64 {
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
}

/// The pressure channels, in [`PressureSensors`] order.
pub const PRESSURE_CHANNELS: usize = 4;

/// The four pressure sensors: chamber A, chamber B, suction, discharge.
#[derive(Clone, Debug, PartialEq)]
pub struct PressureSensors {
    /// Calibration (the firmware's: the same codes mean the same pressures).
    pub calibration: PressureCalibration,
    /// Noise, Pa RMS.
    pub noise_pa: f64,
    /// First-order lag, s.
    pub time_constant_s: f64,
    /// Offsets, Pa (A, B, suction, discharge).
    pub offset_pa: [f64; PRESSURE_CHANNELS],
}

/// Everything the simulated board senses with, and how.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensors {
    /// Encoder on the master section.
    pub encoder_master: EncoderModel,
    /// Encoder on the slave section.
    pub encoder_slave: EncoderModel,
    /// Pitch error of the slave encoder's scale, if any.
    pub slave_pitch_error: Option<PitchError>,
    /// Current-sense calibration (the firmware's reference).
    pub current: CurrentSense,
    /// Current noise per phase, A RMS.
    pub current_noise_a: f64,
    /// Current offsets per phase, A.
    pub current_offset_a: PerSection<[f64; 3]>,
    /// Pressure sensors.
    pub pressure: PressureSensors,
    /// Servo encoder counts per revolution.
    pub counts_per_rev: u32,
}

impl Sensors {
    /// Ideal sensors of the reference geometry (quantisation only).
    pub fn reference() -> Self {
        Sensors {
            encoder_master: EncoderModel::ideal(0.024),
            encoder_slave: EncoderModel::ideal(0.024),
            slave_pitch_error: None,
            current: CurrentSense::reference(),
            current_noise_a: 0.0,
            current_offset_a: PerSection::default(),
            pressure: PressureSensors {
                calibration: PressureCalibration::reference(),
                noise_pa: 0.0,
                time_constant_s: 0.0,
                offset_pa: [0.0; PRESSURE_CHANNELS],
            },
            counts_per_rev: 4096,
        }
    }

    /// The sensors a model describes.
    pub fn from_model(model: &MachineModel) -> Self {
        let s = &model.sensors;
        let p = &s.pressure;
        Sensors {
            encoder_master: EncoderModel::new(model.encoder.period_m, &s.encoder_master),
            encoder_slave: EncoderModel::new(model.encoder.period_m, &s.encoder_slave),
            slave_pitch_error: model
                .effects
                .encoder_pitch_error
                .as_ref()
                .map(PitchError::new),
            current: CurrentSense::reference(),
            current_noise_a: s.current.noise_a,
            current_offset_a: PerSection {
                master: s.current.offset_master_a,
                slave: s.current.offset_slave_a,
            },
            pressure: PressureSensors {
                calibration: PressureCalibration::reference(),
                noise_pa: p.noise_pa,
                time_constant_s: p.time_constant_s,
                offset_pa: [
                    p.offset_a_pa,
                    p.offset_b_pa,
                    p.offset_suction_pa,
                    p.offset_discharge_pa,
                ],
            },
            counts_per_rev: model.servo.counts_per_rev,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_standard_normal_and_seeded() {
        let mut n = Noise::new(7);
        let xs: Vec<f64> = (0..200_000).map(|_| n.normal()).collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        assert!(
            mean.abs() < 0.01 && (var - 1.0).abs() < 0.01,
            "{mean} {var}"
        );
        let within_1 = xs.iter().filter(|x| x.abs() < 1.0).count() as f64 / xs.len() as f64;
        assert!((within_1 - 0.6827).abs() < 0.005);
        let mut again = Noise::new(7);
        assert!(xs.iter().take(100).all(|&x| x == again.normal()));
        assert!((inverse_normal_cdf(0.975) - 1.959_964).abs() < 1e-6);
    }

    #[test]
    fn the_adc_rounds_and_clamps() {
        for x in [
            -1e9, -0.6, -0.5, -0.4, 0.0, 0.49, 0.5, 2047.5, 4094.6, 4095.4, 4095.6, 7e4, 1e30,
        ] {
            assert_eq!(adc(x).0, (x + 0.5).clamp(0.0, 4095.0) as u16, "{x}");
        }
        assert_eq!(adc(f64::NAN).0, 0);
    }

    #[test]
    fn pitch_error_reads_the_stated_pattern() {
        let e = PitchError {
            amplitude_m: 1e-4,
            period_m: 0.024,
            phase_rad: 0.0,
            scale: 1e-3,
            amplitude2_m: 0.0,
            phase2_rad: 0.0,
            step_m: 0.0,
            direction_m: 0.0,
        };
        assert!((e.read_m(0.006) - (0.006 * 1.001 + 1e-4)).abs() < 1e-12);
        // A saw of 0.1 mm stepping once a pitch, 0.05 mm more moving toward +x.
        let saw = PitchError {
            amplitude_m: 0.0,
            scale: 0.0,
            step_m: 1e-4,
            direction_m: 5e-5,
            ..e
        };
        let err = |x: f64, v: f64| saw.read_moving_m(x, v) - x;
        assert!((err(0.0241, 0.0) - (-0.5e-4 + 1e-4 * 0.1 / 24.0)).abs() < 1e-9);
        assert!((err(0.0239, 0.0) - (0.5e-4 - 1e-4 * 0.1 / 24.0)).abs() < 1e-9);
        assert!((err(0.03, 2.0) - err(0.03, -2.0) - 5e-5).abs() < 1e-7);
    }
}
