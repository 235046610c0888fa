//! Helpers shared by the sensing tests: seeded noise and encoder signals built from the
//! library's own types (the simulator's sensor models belong to the plant; these tests need
//! distortions the reference world does not have).
#![allow(dead_code)] // each test file uses its own subset

use fpc::ports::SinCosCodes;
use fpc::sensing::encoder::SinCosCalibration;
use fpc::units::AdcCode;

/// SplitMix64: tiny, seeded, deterministic.
pub struct Rng(u64);

impl Rng {
    /// A generator from `seed`.
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// A 12-bit code from an analog value in codes: rounded and clamped like the ADC.
pub fn adc(v: f64) -> AdcCode {
    AdcCode(v.round().clamp(0.0, 4095.0) as u16)
}

/// Encoder codes at position `x_m` for an encoder of period `period_m` whose channels are
/// distorted as `cal` describes, with `noise_codes` RMS of white noise on each channel.
pub fn encoder_codes(
    x_m: f64,
    period_m: f64,
    cal: &SinCosCalibration,
    noise_codes: f64,
    rng: &mut Rng,
) -> SinCosCodes {
    let th = std::f64::consts::TAU * x_m / period_m;
    let s = 2048.0 + f64::from(cal.sin_offset) + f64::from(cal.sin_amplitude) * th.sin();
    let c = 2048.0
        + f64::from(cal.cos_offset)
        + f64::from(cal.cos_amplitude) * (th + f64::from(cal.phase_rad)).cos();
    SinCosCodes {
        sin: adc(s + noise_codes * rng.normal()),
        cos: adc(c + noise_codes * rng.normal()),
    }
}

/// The distortion of the acceptance test: 5 % gain mismatch between the channels, offsets of
/// 2 % of the amplitude, 3° quadrature error.
pub fn distorted_encoder() -> SinCosCalibration {
    let a = fpc::sensing::encoder::NOMINAL_AMPLITUDE_CODES;
    SinCosCalibration {
        sin_offset: 0.02 * a,
        cos_offset: -0.02 * a,
        sin_amplitude: 1.025 * a,
        cos_amplitude: 0.975 * a,
        phase_rad: 3f32.to_radians(),
    }
}
