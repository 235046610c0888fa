//! Sin/cos interpolation of the 1 Vpp magnetic encoders of the linear axis.
//!
//! Each encoder gives two analog channels, `sin θ` and `cos θ`, with θ = 2π·x/λ (λ = 24 mm,
//! one electrical period of the motor). Decoding is: correct offset, gain and quadrature
//! error (parameters from a slow calibration traverse), take the angle as a *wrapping* fixed
//! point number (2³² = one period, so `i32::MIN`..`i32::MAX` is −π..π and wrap-around is
//! free), and count periods by accumulating the wrapping angle difference sample to sample —
//! no jump at any wrap, over the whole stroke.
//!
//! Position is carried as [`PositionCounts`]: LSB = λ/2²⁰ ≈ 22.9 nm, range ±2048 periods
//! (±49 m), far beyond the 0.205 m travel.
//!
//! The amplitude `√(sin²+cos²)` is monitored against the window [0.7, 1.3] of nominal with an
//! error-rate filter (`faults.md`); a sample outside the window, or one whose angle step is
//! physically impossible, is rejected and the previous motion extrapolated (single-sample
//! glitch rejection).

use crate::ports::SinCosCodes;
use micromath::F32Ext;

/// Fractional bits of position per encoder period: LSB = λ/2²⁰.
pub const POSITION_FRAC_BITS: u32 = 20;

/// Position along the axis in encoder counts of λ/2²⁰ (≈ 22.9 nm at λ = 24 mm).
pub type PositionCounts = i32;

/// Calibration of one sin/cos encoder, in ADC codes (from a slow traverse).
///
/// Model of the raw signals: `sin_code = sin_offset + sin_amplitude·sin θ`,
/// `cos_code = cos_offset + cos_amplitude·cos(θ + phase_rad)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SinCosCalibration {
    /// Sine channel offset from mid-scale, codes.
    pub sin_offset: f32,
    /// Cosine channel offset from mid-scale, codes.
    pub cos_offset: f32,
    /// Sine amplitude, codes (> 0).
    pub sin_amplitude: f32,
    /// Cosine amplitude, codes (> 0).
    pub cos_amplitude: f32,
    /// Quadrature error of the cosine channel, rad (|φ| < 0.5).
    pub phase_rad: f32,
}

impl SinCosCalibration {
    /// An ideal encoder of the given amplitude (codes) centred at mid-scale.
    pub const fn ideal(amplitude: f32) -> Self {
        SinCosCalibration {
            sin_offset: 0.0,
            cos_offset: 0.0,
            sin_amplitude: amplitude,
            cos_amplitude: amplitude,
            phase_rad: 0.0,
        }
    }
}

/// Nominal amplitude of the encoder signals at the ADC, codes: 1 Vpp scaled to ≈ 80 % of
/// the 3.3 V range by the analog front end.
pub const NOMINAL_AMPLITUDE_CODES: f32 = 1600.0;

/// Configuration of the decoder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncoderConfig {
    /// Signal period λ, m.
    pub period_m: f32,
    /// Calibration of the two channels.
    pub calibration: SinCosCalibration,
    /// Largest plausible angle step per sample, fraction of a period (speed limit × period /
    /// λ with margin; 6 m/s × 50 µs / 24 mm = 0.0125).
    pub max_step_periods: f32,
    /// Error-rate filter: added per bad sample.
    pub error_increment: u16,
    /// Error-rate filter: fault when the counter exceeds this.
    pub error_limit: u16,
}

impl EncoderConfig {
    /// Reference encoder (λ = 24 mm, ideal calibration at nominal amplitude).
    pub const fn reference() -> Self {
        EncoderConfig {
            period_m: 0.024,
            calibration: SinCosCalibration::ideal(NOMINAL_AMPLITUDE_CODES),
            max_step_periods: 0.0125,
            error_increment: 4,
            error_limit: 12,
        }
    }

    /// Metres per position count.
    #[inline]
    pub fn m_per_count(&self) -> f32 {
        self.period_m / (1u32 << POSITION_FRAC_BITS) as f32
    }
}

/// One decoded sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EncoderReading {
    /// Position since the decoder started, counts (see [`PositionCounts`]).
    pub position: PositionCounts,
    /// Electrical angle within the period as a wrapping fraction (2³² = one period).
    pub angle: u32,
    /// Normalised signal amplitude (1.0 nominal).
    pub amplitude: f32,
    /// This sample was rejected (out of window or impossible step) and extrapolated.
    pub rejected: bool,
    /// The error-rate filter has tripped: the position is not trustworthy.
    pub signal_fault: bool,
}

/// Decoder state of one sin/cos encoder.
#[derive(Clone, Debug)]
pub struct SinCosDecoder {
    config: EncoderConfig,
    /// sin φ and 1/cos φ of the quadrature error, precomputed.
    sin_phi: f32,
    inv_cos_phi: f32,
    /// Unwrapped position in 2⁻³² periods (i64: ±2³¹ periods).
    fine: i64,
    last_angle: u32,
    last_step: i32,
    max_step: i32,
    error_count: u16,
    started: bool,
    fault: bool,
}

impl SinCosDecoder {
    /// A decoder with the given configuration; the first sample sets the angle within the
    /// period (position = that fraction of a period).
    pub fn new(config: EncoderConfig) -> Self {
        let max_step = (config.max_step_periods.clamp(0.0, 0.49) * 4_294_967_296.0) as i32;
        let (sin_phi, cos_phi) = F32Ext::sin_cos(config.calibration.phase_rad.clamp(-0.5, 0.5));
        SinCosDecoder {
            config,
            sin_phi,
            inv_cos_phi: 1.0 / cos_phi,
            fine: 0,
            last_angle: 0,
            last_step: 0,
            max_step,
            error_count: 0,
            started: false,
            fault: false,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &EncoderConfig {
        &self.config
    }

    /// Whether the signal is bad right now (error-rate filter above half its limit), as
    /// opposed to a fault latched earlier.
    pub fn cause_present(&self) -> bool {
        self.error_count > self.config.error_limit / 2
    }

    /// Clears a latched signal fault (after the cause is gone; position must be re-homed).
    pub fn clear_fault(&mut self) {
        self.fault = false;
        self.error_count = 0;
    }

    /// Decodes one sample.
    pub fn update(&mut self, codes: SinCosCodes) -> EncoderReading {
        let cal = &self.config.calibration;
        let s = (f32::from(codes.sin.centered()) - cal.sin_offset) / cal.sin_amplitude;
        let c_raw = (f32::from(codes.cos.centered()) - cal.cos_offset) / cal.cos_amplitude;
        // cos(θ+φ) = cosθ·cosφ − sinθ·sinφ  ⇒  cosθ = (c_raw + s·sinφ)/cosφ.
        let c = (c_raw + s * self.sin_phi) * self.inv_cos_phi;
        let amplitude = F32Ext::sqrt(s * s + c * c);
        let angle = angle_from(s, c);

        let in_window = (0.7..=1.3).contains(&amplitude);
        let step = angle.wrapping_sub(self.last_angle) as i32;
        let plausible = !self.started || step.unsigned_abs() <= self.max_step.unsigned_abs();
        let good = in_window && plausible;

        let step = if !self.started {
            self.started = true;
            // Position starts at the fraction of the period the first sample shows.
            self.fine = i64::from(angle);
            self.last_angle = angle;
            0
        } else if good {
            self.last_angle = angle;
            step
        } else {
            // Reject: extrapolate the previous step (constant velocity over one sample).
            self.last_angle = self.last_angle.wrapping_add(self.last_step as u32);
            self.last_step
        };
        self.last_step = step;
        self.fine = self.fine.saturating_add(i64::from(step));

        if good {
            self.error_count = self.error_count.saturating_sub(1);
        } else {
            self.error_count = self.error_count.saturating_add(self.config.error_increment);
            if self.error_count > self.config.error_limit {
                self.fault = true;
            }
        }

        EncoderReading {
            position: (self.fine >> (32 - POSITION_FRAC_BITS))
                .clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32,
            angle: self.last_angle,
            amplitude,
            rejected: !good,
            signal_fault: self.fault,
        }
    }
}

/// Angle of (s, c) as a wrapping fraction of a turn (2³² = 2π); 0 for the origin.
///
/// Octant reduction plus the minimax polynomial of Abramowitz & Stegun 4.4.49 for atan on
/// [0, 1] (|error| ≤ 2e-8 rad in exact arithmetic, ≈ 1e-7 rad in f32: 0.4 nm at λ = 24 mm).
#[inline]
pub fn angle_from(s: f32, c: f32) -> u32 {
    let (ax, ay) = (c.abs(), s.abs());
    let (num, den, swapped) = if ay > ax {
        (ax, ay, true)
    } else {
        (ay, ax, false)
    };
    if den == 0.0 || den.is_nan() {
        return 0;
    }
    let z = num / den; // 0..=1
    let z2 = z * z;
    // a16 … a2 of A&S 4.4.49, Horner in z².
    let p = 0.002_866_225_7_f32;
    let p = p * z2 - 0.016_165_737;
    let p = p * z2 + 0.042_909_614;
    let p = p * z2 - 0.075_289_64;
    let p = p * z2 + 0.106_562_64;
    let p = p * z2 - 0.142_089;
    let p = p * z2 + 0.199_935_51;
    let p = p * z2 - 0.333_331_45;
    let atan = z + z * z2 * p; // atan(z) in 0..=π/4, rad
                               // Work in turns: the octant corrections are exact fractions of a turn.
    let mut turns = atan * (1.0 / core::f32::consts::TAU);
    if swapped {
        turns = 0.25 - turns;
    }
    if c < 0.0 {
        turns = 0.5 - turns;
    }
    if s < 0.0 {
        turns = -turns;
    }
    // −0.5..=0.5 turns → i32 (the cast saturates at +0.5), i32 → u32 is the wrap.
    (turns * 4_294_967_296.0) as i64 as i32 as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::units::AdcCode;

    fn codes(theta: f32, amp: f32) -> SinCosCodes {
        SinCosCodes {
            sin: AdcCode((2048.0 + amp * theta.sin()).round() as u16),
            cos: AdcCode((2048.0 + amp * theta.cos()).round() as u16),
        }
    }

    #[test]
    fn counts_periods_without_jumps() {
        let cfg = EncoderConfig::reference();
        let mut dec = SinCosDecoder::new(cfg);
        let lambda = cfg.period_m;
        let mut worst = 0.0f32;
        for i in 0..20_000 {
            let x = 0.001 + i as f32 * 1e-5; // 0.2 m at 10 µm per sample
            let r = dec.update(codes(core::f32::consts::TAU * x / lambda, 1600.0));
            let est = r.position as f32 * cfg.m_per_count();
            worst = worst.max((est - x).abs());
            assert!(!r.signal_fault);
        }
        assert!(worst < 5e-6, "worst error {worst}");
    }

    #[test]
    fn single_glitch_is_rejected_and_extrapolated() {
        let cfg = EncoderConfig::reference();
        let mut dec = SinCosDecoder::new(cfg);
        let mut last = 0;
        for i in 0..200 {
            let theta = i as f32 * 0.01;
            let theta = if i == 100 { theta + 2.0 } else { theta };
            let r = dec.update(codes(theta, 1600.0));
            if i == 100 {
                assert!(r.rejected);
            }
            last = r.position;
        }
        let expect = 1.99 / core::f32::consts::TAU * (1u32 << 20) as f32;
        assert!((last as f32 - expect).abs() < 200.0, "{last} vs {expect}");
    }

    #[test]
    fn weak_signal_trips_the_error_filter() {
        let mut dec = SinCosDecoder::new(EncoderConfig::reference());
        let mut tripped_at = None;
        for i in 0..10 {
            let r = dec.update(codes(0.1 * i as f32, 300.0));
            if r.signal_fault && tripped_at.is_none() {
                tripped_at = Some(i);
            }
        }
        assert!(matches!(tripped_at, Some(i) if i <= 3));
    }
}
