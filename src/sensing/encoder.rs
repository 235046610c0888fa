//! Sin/cos interpolation of the 1 Vpp magnetic encoders of the linear axis.
//!
//! Each encoder gives two analog channels, `sin θ` and `cos θ`, with θ = 2π·x/λ (λ = 24 mm,
//! one electrical period of the motor). Decoding, every control cycle and for both encoders:
//!
//! 1. **Correct** offset, gain and quadrature error ([`SinCosCalibration`], fitted from a slow
//!    traverse by [`SinCosCalibrator`]: an algebraic ellipse fit, so the traverse need not be
//!    uniform nor cover whole periods).
//! 2. **Angle** as a *wrapping* fixed-point number, [`angle_from`]: 2³² = one period, so
//!    wrap-around is free. Octant reduction and an odd minimax polynomial for atan on [0, 1]
//!    (6 terms, |error| ≤ 1.7e-6 rad = 6.6 nm at λ = 24 mm, below the 22.9 nm LSB), in f32:
//!    on the M4F a multiply-add is one instruction, so it costs 46 instructions per call
//!    against 380 for a 24-step integer CORDIC of the same accuracy (QEMU, the `bench/cm4`
//!    method). The whole decode costs 132 instructions per encoder (budget 150).
//! 3. **Count periods** from the wrapping angle step: the carry of the 32-bit angle moves a
//!    period counter, so there is no jump at any period boundary, ever.
//! 4. **Monitor** the amplitude √(sin²+cos²) against [0.7, 1.3] of nominal (compared squared,
//!    no root in the loop) and the *plausibility* of the step: a first step beyond the speed
//!    limit, or any step that departs from constant velocity by more than the glitch gate
//!    (50 µm), is rejected and the position extrapolated at the last velocity (single-sample
//!    glitch rejection); a sub-gate glitch that got through is undone by a re-lock on the
//!    next consistent pair of samples.
//!    A sample with a channel at either ADC rail is out of window too (a clipped ×1.5 signal
//!    can look in-window near the axes). Rejected samples feed an error-rate filter
//!    (`docs/faults.md`, VESC style): +64 per bad sample, −1 per good one, fault above 80. So two
//!    bad samples in a row latch the fault (scenario 1: amplitude ×0.2 or ×1.5, ≤ 2 cycles),
//!    two within 48 samples (2.4 ms) too (scenario 4, a burst of 10 % corrupt samples: at its
//!    second corrupt sample, typically), one isolated glitch never does (scenario 3).
//!
//! Position is carried as [`PositionCounts`]: Q12.20 periods in an i32, LSB = λ/2²⁰ ≈ 22.9 nm.
//! It *wraps* after ±2048 periods (±49 m, 240 strokes one way): differences taken with
//! `wrapping_sub`, as the differentiator does, are exact across that wrap too.
//!
//! Noise scale (the ADC front end maps 1 Vpp to 2 × [`NOMINAL_AMPLITUDE_CODES`] codes
//! peak to peak): [`CODES_PER_MV`] = 3.2 codes per mV, and a signal noise of σ codes RMS on
//! each channel gives σ/A·λ/2π of position noise per sample — 7.6 µm RMS per mV RMS at
//! λ = 24 mm, A = 1600 codes. The stated encoder noise of ≈ 1 µm RMS is 0.13 mV (0.42 codes).

use crate::ports::SinCosCodes;
use crate::real::clamp_f32;
use crate::real::sqrt_f32;
use crate::units::{AdcCode, ADC_FULL_SCALE};

/// Fractional bits of position per encoder period: LSB = λ/2²⁰.
pub const POSITION_FRAC_BITS: u32 = 20;
const _: () = assert!(PositionCounts::FRAC_NBITS == POSITION_FRAC_BITS);

/// Position along the axis in encoder periods, Q12.20 (`fixed`'s `I12F20`: 12 integer bits of
/// periods, 20 fractional; LSB λ/2²⁰ ≈ 22.9 nm at λ = 24 mm), wrapping. The raw count is
/// [`fixed::FixedI32::to_bits`]; [`EncoderConfig::metres`] converts to metres.
pub type PositionCounts = fixed::types::I12F20;

/// Nominal amplitude of the encoder signals at the ADC, codes: 1 Vpp (0.5 V amplitude)
/// scaled to ≈ 80 % of the 3.3 V range by the analog front end.
pub const NOMINAL_AMPLITUDE_CODES: f32 = 1600.0;

/// ADC codes per millivolt of encoder signal: 1 Vpp = 2 × 1600 codes peak to peak.
pub const CODES_PER_MV: f32 = 2.0 * NOMINAL_AMPLITUDE_CODES / 1000.0;

/// Amplitude window of the signal monitor, fraction of nominal (`docs/faults.md`, VESC).
pub const AMPLITUDE_WINDOW: (f32, f32) = (0.7, 1.3);

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

    /// Fits the calibration to the samples of a slow traverse (see [`SinCosCalibrator`]).
    pub fn from_traverse<I>(samples: I) -> Result<Self, CalibrationError>
    where
        I: IntoIterator<Item = SinCosCodes>,
    {
        let mut fit = SinCosCalibrator::new();
        for s in samples {
            fit.add(s);
        }
        fit.finish()
    }

    /// The ideal codes this calibration predicts at electrical angle `theta_rad` (what a
    /// perfect ADC would read; for tests and the simulator).
    pub fn codes_at(&self, theta_rad: f32) -> (f32, f32) {
        let (s, _) = sin_cos(theta_rad);
        let (_, c) = sin_cos(theta_rad + self.phase_rad);
        (
            2048.0 + self.sin_offset + self.sin_amplitude * s,
            2048.0 + self.cos_offset + self.cos_amplitude * c,
        )
    }
}

/// sin and cos of `x` rad through the shared table (±7.6e-5; libm's sinf/cosf would add
/// 7 KiB of flash for init-time and model use only).
fn sin_cos(x: f32) -> (f32, f32) {
    crate::angle::sin_cos_turns(crate::angle::turns(x * (1.0 / core::f32::consts::TAU)))
}

/// Why a calibration traverse was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CalibrationError {
    /// Fewer than [`SinCosCalibrator::MIN_SAMPLES`] samples.
    TooFewSamples,
    /// The traverse did not visit every sixteenth of a period: move at least one period.
    IncompleteCoverage,
    /// The samples do not lie on an ellipse (a channel dead or stuck, or pure noise).
    NotAnEllipse,
    /// The fit is outside the plausible range: amplitude not within 0.3–2 × nominal, offset
    /// beyond ±25 % of nominal, or quadrature error beyond ±0.5 rad.
    Implausible,
}

/// Streaming fit of a [`SinCosCalibration`] from the samples of a slow traverse.
///
/// The samples of both channels lie on an ellipse; its general conic
/// `A·x² + B·xy + C·y² + D·x + E·y = 1` (x, y the centred codes scaled by 1/1600) is fitted
/// by linear least squares, then the centre gives the offsets and the axes and tilt give the
/// amplitudes and the quadrature error: in the calibration's model the centred signals obey
/// `X²/a_s² + 2·sin φ·XY/(a_s·a_c) + Y²/a_c² = cos² φ`. Needs no uniform speed and no whole
/// number of periods; only that every sixteenth of a period is visited. Accumulates 20 sums
/// in f64, no sample buffer; intended for the commissioning traverse, not the 20 kHz loop.
#[derive(Clone, Debug, Default)]
pub struct SinCosCalibrator {
    /// Upper triangle of Σφφᵀ (φ = [x², xy, y², x, y]), row-major.
    normal: [f64; 15],
    /// Σφ.
    rhs: [f64; 5],
    /// Sixteenths of a period visited, one bit each.
    sectors: u16,
    count: u32,
}

impl SinCosCalibrator {
    /// Fewest samples accepted.
    pub const MIN_SAMPLES: u32 = 64;

    /// An empty fit.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one sample.
    pub fn add(&mut self, codes: SinCosCodes) {
        let x = f64::from(codes.sin.centered()) / f64::from(NOMINAL_AMPLITUDE_CODES);
        let y = f64::from(codes.cos.centered()) / f64::from(NOMINAL_AMPLITUDE_CODES);
        let phi = [x * x, x * y, y * y, x, y];
        let mut k = 0;
        for (r, &pr) in phi.iter().enumerate() {
            for &pc in phi.iter().skip(r) {
                if let Some(n) = self.normal.get_mut(k) {
                    *n += pr * pc;
                }
                k += 1;
            }
            if let Some(b) = self.rhs.get_mut(r) {
                *b += pr;
            }
        }
        let sector = angle_from(x as f32, y as f32) >> 28;
        self.sectors |= 1 << sector;
        self.count = self.count.saturating_add(1);
    }

    /// The fitted calibration.
    pub fn finish(&self) -> Result<SinCosCalibration, CalibrationError> {
        if self.count < Self::MIN_SAMPLES {
            return Err(CalibrationError::TooFewSamples);
        }
        if self.sectors != u16::MAX {
            return Err(CalibrationError::IncompleteCoverage);
        }
        let mut m = [[0.0f64; 5]; 5];
        let mut k = 0;
        for r in 0..5 {
            for c in r..5 {
                let v = self.normal.get(k).copied().unwrap_or(0.0);
                set(&mut m, r, c, v);
                set(&mut m, c, r, v);
                k += 1;
            }
        }
        let [a, b, c, d, e] = solve5(m, self.rhs).ok_or(CalibrationError::NotAnEllipse)?;
        let det = 4.0 * a * c - b * b;
        if det.is_nan() || det <= 0.0 {
            return Err(CalibrationError::NotAnEllipse);
        }
        let x0 = (b * e - 2.0 * c * d) / det;
        let y0 = (b * d - 2.0 * a * e) / det;
        let scale = 1.0 + a * x0 * x0 + b * x0 * y0 + c * y0 * y0;
        if scale.is_nan() || scale <= 0.0 {
            return Err(CalibrationError::NotAnEllipse);
        }
        let (a, b, c) = (a / scale, b / scale, c / scale);
        let sin_phi = b / (2.0 * libm::sqrt(a * c));
        let cos_phi = libm::sqrt(1.0 - sin_phi * sin_phi);
        let nominal = f64::from(NOMINAL_AMPLITUDE_CODES);
        let cal = SinCosCalibration {
            sin_offset: (x0 * nominal) as f32,
            cos_offset: (y0 * nominal) as f32,
            sin_amplitude: (nominal / (cos_phi * libm::sqrt(a))) as f32,
            cos_amplitude: (nominal / (cos_phi * libm::sqrt(c))) as f32,
            phase_rad: libm::asin(sin_phi) as f32,
        };
        let amp_ok =
            |v: f32| (0.3 * NOMINAL_AMPLITUDE_CODES..=2.0 * NOMINAL_AMPLITUDE_CODES).contains(&v);
        let off_ok = |v: f32| v.abs() <= 0.25 * NOMINAL_AMPLITUDE_CODES;
        if amp_ok(cal.sin_amplitude)
            && amp_ok(cal.cos_amplitude)
            && off_ok(cal.sin_offset)
            && off_ok(cal.cos_offset)
            && cal.phase_rad.abs() <= 0.5
        {
            Ok(cal)
        } else {
            Err(CalibrationError::Implausible)
        }
    }
}

fn set(m: &mut [[f64; 5]; 5], r: usize, c: usize, v: f64) {
    if let Some(cell) = m.get_mut(r).and_then(|row| row.get_mut(c)) {
        *cell = v;
    }
}

/// Solves the 5×5 system by Gaussian elimination with partial pivoting; `None` if singular
/// or not finite.
fn solve5(mut m: [[f64; 5]; 5], mut b: [f64; 5]) -> Option<[f64; 5]> {
    for col in 0..5 {
        let pivot = (col..5).max_by(|&i, &j| {
            let a = m.get(i).and_then(|r| r.get(col)).map_or(0.0, |v| v.abs());
            let c = m.get(j).and_then(|r| r.get(col)).map_or(0.0, |v| v.abs());
            a.total_cmp(&c)
        })?;
        m.swap(col, pivot);
        b.swap(col, pivot);
        let (upper, lower) = m.split_at_mut(col + 1);
        let prow = upper.last()?;
        let d = *prow.get(col)?;
        if !d.is_finite() || d.abs() <= 1e-300 {
            return None;
        }
        let (bu, bl) = b.split_at_mut(col + 1);
        let pb = *bu.last()?;
        for (row, rb) in lower.iter_mut().zip(bl.iter_mut()) {
            let f = row.get(col).copied().unwrap_or(0.0) / d;
            for (x, p) in row.iter_mut().zip(prow.iter()).skip(col) {
                *x -= f * p;
            }
            *rb -= f * pb;
        }
    }
    let mut x = [0.0f64; 5];
    for r in (0..5).rev() {
        let row = m.get(r)?;
        let mut s = *b.get(r)?;
        for (c, xc) in x.iter().enumerate().skip(r + 1) {
            s -= row.get(c).copied().unwrap_or(0.0) * xc;
        }
        let v = s / row.get(r)?;
        if !v.is_finite() {
            return None;
        }
        *x.get_mut(r)? = v;
    }
    Some(x)
}

/// Configuration of the decoder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncoderConfig {
    /// Signal period λ, m.
    pub period_m: f32,
    /// Calibration of the two channels.
    pub calibration: SinCosCalibration,
    /// Largest plausible angle step per sample, fraction of a period (speed limit × sample
    /// time / λ with margin; 6 m/s × 50 µs / 24 mm = 0.0125). Bounds the first step after
    /// start (later the glitch gate bounds each change of step) and the steps a decoder with
    /// a latched fault re-locks on.
    pub max_step_periods: f32,
    /// Glitch gate: largest plausible departure of a step from the previous one, fraction
    /// of a period. 50 µm / 24 mm: 25× the largest real change (830 m/s² × (50 µs)² = 2 µm)
    /// and 20σ of the step noise at the encoder's 1 µm; a phase glitch larger than this is
    /// rejected (scenario 3: error < 0.05 mm). For noisier signals keep it ≥ 8 × √6 × the
    /// position noise (each sample's noise enters a change of step three times).
    pub glitch_gate_periods: f32,
    /// Error-rate filter: added per rejected sample (one is subtracted per good sample).
    pub error_increment: u16,
    /// Error-rate filter: fault when the counter exceeds this.
    pub error_limit: u16,
}

impl EncoderConfig {
    /// Reference encoder (λ = 24 mm, ideal calibration at nominal amplitude).
    pub const fn reference() -> Self {
        EncoderConfig {
            period_m: crate::reference::encoder::PERIOD_M as f32,
            calibration: SinCosCalibration::ideal(NOMINAL_AMPLITUDE_CODES),
            max_step_periods: 0.0125,
            glitch_gate_periods: 50e-6 / (crate::reference::encoder::PERIOD_M as f32),
            error_increment: 64,
            error_limit: 80,
        }
    }

    /// Metres per position count.
    #[inline]
    pub fn m_per_count(&self) -> f32 {
        self.period_m / (1u32 << POSITION_FRAC_BITS) as f32
    }

    /// A position in metres from the decoder's start (the count times [`Self::m_per_count`]).
    #[inline]
    pub fn metres(&self, position: PositionCounts) -> f32 {
        position.to_bits() as f32 * self.m_per_count()
    }
}

/// One decoded sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EncoderReading {
    /// Position since the decoder started, counts (see [`PositionCounts`]; wrapping).
    pub position: PositionCounts,
    /// Electrical angle within the period as a wrapping fraction (2³² = one period).
    pub angle: u32,
    /// Square of the corrected signal amplitude (1.0 nominal; the window is [0.49, 1.69]).
    pub amplitude_squared: f32,
    /// This sample was rejected (out of window or implausible step) and extrapolated.
    pub rejected: bool,
    /// The error-rate filter has tripped: the position is not trustworthy.
    pub signal_fault: bool,
}

impl EncoderReading {
    /// The normalised signal amplitude √(sin²+cos²) (1.0 nominal).
    pub fn amplitude(&self) -> f32 {
        sqrt_f32(self.amplitude_squared)
    }
}

/// `slave − master` in counts: the disagreement of the two encoders of the axis (wrapping, so
/// exact whatever the counters read).
#[inline]
pub fn difference_counts(master: PositionCounts, slave: PositionCounts) -> i32 {
    slave.wrapping_sub(master).to_bits()
}

/// Decoder state of one sin/cos encoder.
#[derive(Clone, Debug)]
pub struct SinCosDecoder {
    config: EncoderConfig,
    /// Correction precomputed from the calibration: s = (sin − os)·ks,
    /// c = (cos − oc)·kc + s·tan φ, with the raw codes and the offsets from code 0.
    sin_offset: f32,
    cos_offset: f32,
    sin_gain: f32,
    cos_gain: f32,
    tan_phi: f32,
    /// Limits in 2⁻³² periods; `gate_now` is the speed limit until the second sample has
    /// given a velocity, then the glitch gate.
    max_step: u32,
    gate: u32,
    gate_now: u32,
    /// Angle of the position (accepted or extrapolated), its step, and the period count.
    angle: u32,
    step: i32,
    periods: i32,
    /// The raw angle of the last sample, and whether that sample was rejected (re-lock).
    raw_angle: u32,
    last_rejected: bool,
    /// A sample has been accepted: the angle and period count are running.
    started: bool,
    error_count: u16,
    fault: bool,
}

impl SinCosDecoder {
    /// A decoder with the given configuration; the first sample in the amplitude window sets
    /// the angle within the period (position = that fraction of a period).
    pub fn new(config: EncoderConfig) -> Self {
        let cal = &config.calibration;
        let phi = if cal.phase_rad.is_finite() {
            clamp_f32(cal.phase_rad, -0.5, 0.5)
        } else {
            0.0
        };
        let (sin_phi, cos_phi) = sin_cos(phi);
        let gain = |amplitude: f32| {
            if amplitude.is_finite() && amplitude > 1.0 {
                1.0 / amplitude
            } else {
                1.0 / NOMINAL_AMPLITUDE_CODES
            }
        };
        let offset = |o: f32| if o.is_finite() { o } else { 0.0 };
        let periods = |p: f32| (clamp_f32(p, 0.0, 0.49) * 4_294_967_296.0) as u32;
        SinCosDecoder {
            // Offsets from code 0, so the hot path needs no centring.
            sin_offset: offset(cal.sin_offset) + f32::from(AdcCode::MID.0),
            cos_offset: offset(cal.cos_offset) + f32::from(AdcCode::MID.0),
            sin_gain: gain(cal.sin_amplitude),
            cos_gain: gain(cal.cos_amplitude) / cos_phi,
            tan_phi: sin_phi / cos_phi,
            max_step: periods(config.max_step_periods),
            gate: periods(config.glitch_gate_periods),
            gate_now: periods(config.max_step_periods),
            config,
            angle: 0,
            step: 0,
            periods: 0,
            raw_angle: 0,
            last_rejected: false,
            started: false,
            error_count: 0,
            fault: false,
        }
    }

    /// Sets the glitch gate (periods of the scale, 0–0.49) without restarting the decoder:
    /// the angle, its step and the period count run on, so the position found by homing
    /// still holds. A calibration that changes what the gate must pass calls it (out of
    /// line: it runs once per routine, from flash, not from the control path's CCM SRAM).
    #[inline(never)]
    pub fn set_glitch_gate(&mut self, periods: f32) {
        self.config.glitch_gate_periods = periods;
        self.gate = (clamp_f32(periods, 0.0, 0.49) * 4_294_967_296.0) as u32;
        // Before the second good sample the speed limit applies; the next good one
        // switches to the (new) gate.
        if self.gate_now != self.max_step {
            self.gate_now = self.gate;
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

    /// Re-lock, after a rejection, on a sample in the window (the slow path):
    /// - one that agrees with the previous raw sample at the current velocity and lies
    ///   within 3 gates of the extrapolation means the *state* was off (a sub-gate glitch
    ///   was accepted earlier), not the signal: take the measurement;
    /// - once the fault is latched the position is untrusted until re-homed anyway, so follow
    ///   any signal that is steady again, or the cause could never clear.
    #[cold]
    #[inline(never)]
    fn may_relock(&self, raw: u32, innovation: i32) -> bool {
        let raw_step = raw.wrapping_sub(self.raw_angle) as i32;
        if self.fault {
            raw_step.unsigned_abs() <= self.max_step
        } else {
            innovation.unsigned_abs() <= self.gate.saturating_mul(3)
                && raw_step.wrapping_sub(self.step).unsigned_abs() <= self.gate
        }
    }

    /// Decodes one sample.
    #[inline(always)]
    pub fn update(&mut self, codes: SinCosCodes) -> EncoderReading {
        // A channel at either rail (0 or full scale) is out of range whatever the other one
        // reads: a clipped signal (amplitude ×1.5 reaches the rails) can look in-window near
        // the axes. Nominal signals stay ≥ 48 codes inside the rails even with 25 % offsets.
        // (`code − 1` wraps 0 to 2³² − 1, so one compare per channel catches both rails.)
        let rail =
            |code: AdcCode| u32::from(code.0).wrapping_sub(1) >= u32::from(ADC_FULL_SCALE - 1);
        let railed = rail(codes.sin) || rail(codes.cos);
        let s = (f32::from(codes.sin.0) - self.sin_offset) * self.sin_gain;
        let c = (f32::from(codes.cos.0) - self.cos_offset) * self.cos_gain + s * self.tan_phi;
        let amplitude_squared = s * s + c * c;
        // |a² − mid| ≤ half-width is the window [lo², hi²] in one compare; NaN-safe (a NaN
        // fails it).
        let (lo, hi) = AMPLITUDE_WINDOW;
        let in_window = !railed
            && (amplitude_squared - 0.5 * (hi * hi + lo * lo)).abs() <= 0.5 * (hi * hi - lo * lo);
        let raw = angle_from(s, c);

        let predicted = self.angle.wrapping_add(self.step as u32);
        let innovation = raw.wrapping_sub(predicted) as i32;
        let step = raw.wrapping_sub(self.angle) as i32;
        // The speed limit applies to the first step (the innovation from rest), then the gate
        // bounds how fast the velocity may change: no separate speed check is needed.
        let good = in_window && (!self.started || innovation.unsigned_abs() <= self.gate_now);
        let relock = !good && in_window && self.last_rejected && self.may_relock(raw, innovation);

        let (new_angle, new_step) = if !self.started {
            // Not started: position 0 until a sample is good, then the fraction of a period
            // that sample shows; the period count starts at 0.
            self.started = good;
            let start = if good { raw } else { 0 };
            self.angle = start;
            (start, 0)
        } else if good {
            // From the third sample on, the velocity is known: the glitch gate applies.
            self.gate_now = self.gate;
            (raw, step)
        } else if relock {
            (raw, raw.wrapping_sub(self.raw_angle) as i32)
        } else {
            // Reject: extrapolate at constant velocity.
            (predicted, self.step)
        };
        // The carry out of the 32-bit angle is the period count: +1 when a forward move wraps
        // past 2³², −1 when a backward one wraps below 0. Every move is < ½ period (a step,
        // an extrapolation or a re-lock of ≤ 3 gates), so the sign of the difference is
        // the direction.
        let moved = new_angle.wrapping_sub(self.angle) as i32;
        let (_, carry) = self.angle.overflowing_add(moved as u32);
        self.periods = self
            .periods
            .wrapping_add(i32::from(carry))
            .wrapping_add(moved >> 31);
        self.angle = new_angle;
        self.step = new_step;
        self.raw_angle = raw;
        let accepted = good || relock;
        self.last_rejected = !accepted;

        if accepted {
            self.error_count = self.error_count.saturating_sub(1);
        } else {
            // Capped at twice the limit, so a signal that has come back clears the cause
            // within 1.5 × limit good samples (6 ms), however long it was gone.
            self.error_count = self
                .error_count
                .saturating_add(self.config.error_increment)
                .min(self.config.error_limit.saturating_mul(2));
            if self.error_count > self.config.error_limit {
                self.fault = true;
            }
        }

        EncoderReading {
            position: PositionCounts::from_bits(
                self.periods
                    .wrapping_shl(POSITION_FRAC_BITS)
                    .wrapping_add((self.angle >> (32 - POSITION_FRAC_BITS)) as i32),
            ),
            angle: self.angle,
            amplitude_squared,
            rejected: !accepted,
            signal_fault: self.fault,
        }
    }
}

/// Odd minimax polynomial for atan(z)/2π·2³² on z ∈ [0, 1], coefficients of z, z³, …, z¹¹
/// (fitted by linear programming on 4001 points; |error| ≤ 1.7e-6 rad in f32 Horner form).
const ATAN_TURNS_2_32: [f32; 6] = {
    const K: f64 = 4_294_967_296.0 / core::f64::consts::TAU;
    [
        (0.999_977_288_183_557_8 * K) as f32,
        (-0.332_622_056_531_323_4 * K) as f32,
        (0.193_532_828_486_098_68 * K) as f32,
        (-0.116_406_673_741_259_88 * K) as f32,
        (0.052_626_526_538_450_67 * K) as f32,
        (-0.011_711_402_984_908_477 * K) as f32,
    ]
};

/// Angle of (s, c) as a wrapping fraction of a turn (2³² = 2π); 0 for the origin or NaN.
///
/// Octant reduction, the polynomial [`ATAN_TURNS_2_32`] on the ratio in [0, 1] (its result
/// is already in 2⁻³² turns, 0..=2²⁹), then the octant is restored with exact integer
/// arithmetic.
#[inline]
pub fn angle_from(s: f32, c: f32) -> u32 {
    let (ax, ay) = (c.abs(), s.abs());
    let swapped = ay > ax;
    let (num, den) = if swapped { (ax, ay) } else { (ay, ax) };
    // One compare: NaN fails it.
    if den > 0.0 {
        let z = num / den; // 0..=1
        let z2 = z * z;
        let [k1, k3, k5, k7, k9, k11] = ATAN_TURNS_2_32;
        let p = ((((k11 * z2 + k9) * z2 + k7) * z2 + k5) * z2 + k3) * z2 + k1;
        // 0..=2²⁹ (π/4), the cast saturates.
        let mut a = (z * p) as u32;
        if swapped {
            a = (1u32 << 30).wrapping_sub(a);
        }
        if c < 0.0 {
            a = (1u32 << 31).wrapping_sub(a);
        }
        if s < 0.0 {
            a = a.wrapping_neg();
        }
        a
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::units::AdcCode;
    use core::f64::consts::TAU;

    fn codes(theta: f32, amp: f32) -> SinCosCodes {
        SinCosCodes {
            sin: AdcCode((2048.0 + amp * theta.sin()).round() as u16),
            cos: AdcCode((2048.0 + amp * theta.cos()).round() as u16),
        }
    }

    /// Exact angle in 2⁻³² turns, for comparison.
    fn exact_turns(s: f64, c: f64) -> f64 {
        s.atan2(c) / TAU * 4_294_967_296.0
    }

    #[test]
    fn angle_is_accurate_in_every_octant() {
        let mut worst = 0.0f64;
        for i in 0..100_000 {
            let th = i as f64 / 100_000.0 * TAU;
            let (s, c) = ((th.sin() * 1.3) as f32, (th.cos() * 1.3) as f32);
            let got = angle_from(s, c) as i32 as f64;
            let want = exact_turns(f64::from(s), f64::from(c));
            let mut e = (got - want).rem_euclid(4_294_967_296.0);
            if e > 2_147_483_648.0 {
                e -= 4_294_967_296.0;
            }
            worst = worst.max(e.abs());
        }
        // In radians.
        let rad = worst / 4_294_967_296.0 * TAU;
        assert!(rad < 2.5e-6, "worst {rad:e} rad");
        assert_eq!(angle_from(0.0, 0.0), 0);
        assert_eq!(angle_from(f32::NAN, 1.0), 0);
        assert_eq!(angle_from(0.0, -1.0), 1 << 31);
        assert_eq!(angle_from(1.0, 0.0), 1 << 30);
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
            let est = cfg.metres(r.position);
            worst = worst.max((est - x).abs());
            assert!(!r.signal_fault && !r.rejected);
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
            assert_eq!(r.rejected, i == 100);
            assert!(!r.signal_fault);
            last = r.position.to_bits();
        }
        let expect = 1.99 / core::f32::consts::TAU * (1u32 << 20) as f32;
        assert!((last as f32 - expect).abs() < 200.0, "{last} vs {expect}");
    }

    #[test]
    fn weak_signal_trips_the_error_filter_in_two_samples() {
        for amp in [0.2 * 1600.0, 1.5 * 1600.0] {
            let mut dec = SinCosDecoder::new(EncoderConfig::reference());
            for i in 0..50 {
                assert!(!dec.update(codes(0.01 * i as f32, 1600.0)).signal_fault);
            }
            let first = dec.update(codes(0.5, amp));
            let second = dec.update(codes(0.51, amp));
            assert!(first.rejected && !first.signal_fault);
            assert!(second.signal_fault, "amplitude {amp}");
            assert!(dec.cause_present());
        }
    }

    #[test]
    fn after_a_fault_the_decoder_follows_the_signal_again_so_the_cause_can_clear() {
        let mut dec = SinCosDecoder::new(EncoderConfig::reference());
        for i in 0..20 {
            dec.update(codes(0.01 * i as f32, 1600.0));
        }
        // Signal lost for a while (the extrapolation runs away), then back elsewhere.
        for _ in 0..100 {
            assert!(dec.update(codes(0.0, 200.0)).rejected);
        }
        assert!(dec.cause_present());
        for i in 0..200 {
            dec.update(codes(2.0 + 0.001 * i as f32, 1600.0));
        }
        assert!(!dec.cause_present());
        dec.clear_fault();
        assert!(!dec.update(codes(2.2, 1600.0)).signal_fault);
    }

    #[test]
    fn calibration_round_trips() {
        let truth = SinCosCalibration {
            sin_offset: 30.0,
            cos_offset: -25.0,
            sin_amplitude: 1640.0,
            cos_amplitude: 1560.0,
            phase_rad: 0.05,
        };
        let samples = (0..2000).map(|i| {
            // Uneven speed, 1.3 periods.
            let u = i as f32 / 2000.0;
            let th = core::f32::consts::TAU * 1.3 * u * u;
            let (s, c) = truth.codes_at(th);
            SinCosCodes {
                sin: AdcCode(s.round() as u16),
                cos: AdcCode(c.round() as u16),
            }
        });
        let fit = SinCosCalibration::from_traverse(samples).unwrap();
        assert!((fit.sin_offset - truth.sin_offset).abs() < 0.5, "{fit:?}");
        assert!((fit.cos_offset - truth.cos_offset).abs() < 0.5, "{fit:?}");
        assert!(
            (fit.sin_amplitude - truth.sin_amplitude).abs() < 0.5,
            "{fit:?}"
        );
        assert!(
            (fit.cos_amplitude - truth.cos_amplitude).abs() < 0.5,
            "{fit:?}"
        );
        assert!((fit.phase_rad - truth.phase_rad).abs() < 5e-4, "{fit:?}");
    }

    #[test]
    fn calibration_refuses_bad_traverses() {
        let few = (0..10).map(|i| codes(i as f32, 1600.0));
        assert_eq!(
            SinCosCalibration::from_traverse(few),
            Err(CalibrationError::TooFewSamples)
        );
        let short = (0..1000).map(|i| codes(i as f32 * 1e-3, 1600.0));
        assert_eq!(
            SinCosCalibration::from_traverse(short),
            Err(CalibrationError::IncompleteCoverage)
        );
        let stuck = (0..1000).map(|i| SinCosCodes {
            sin: AdcCode(2048),
            cos: codes(i as f32 * 0.01, 1600.0).cos,
        });
        assert!(SinCosCalibration::from_traverse(stuck).is_err());
    }
}
