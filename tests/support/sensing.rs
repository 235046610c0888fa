//! Helpers shared by the sensing tests: seeded noise and encoder signals built from the
//! library's own types (the simulator's sensor models belong to the plant; these tests need
//! distortions the reference world does not have).

use fpc::ports::SinCosCodes;
use fpc::sensing::encoder::SinCosCalibration;
use fpc::units::AdcCode;
use rand::{Rng as _, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Seeded noise for the sensing tests: ChaCha8 (`rand_chacha`), the same stream on every
/// machine, with the two draws the tests need.
pub struct Rng(ChaCha8Rng);

impl Rng {
    /// A generator from `seed`.
    pub fn new(seed: u64) -> Self {
        Rng(ChaCha8Rng::seed_from_u64(seed))
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0.random()
    }

    /// Standard normal.
    pub fn normal(&mut self) -> f64 {
        self.0.sample(StandardNormal)
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
