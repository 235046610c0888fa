//! Sensor models of the simulated board: the two sin/cos encoders (offsets, gain and phase
//! errors, noise, 12-bit quantisation, the slave's pitch error), the phase-current sensing
//! (offsets, noise), the four pressure sensors (first-order lag, offset, noise), the
//! sections' force readings as logged (gain, offset) and the servo's quadrature counter. Each holds its model section as it is; the laws of the
//! transducers and the scale (lag, offset, noise, pitch error) are `plant::sensing`'s, the
//! seeded noise they draw from `plant::noise`'s. What is the board's own here is the
//! converters: the ADC's quantisation and the firmware's calibration of the codes.

use fpc::drive::foc::CurrentSense;
use fpc::sensing::pressure::PressureCalibration;
use fpc::units::{AdcCode, Section};

use crate::plant::fastmath::sin_cos;
use crate::plant::model::{
    CurrentSensor, EncoderSensor, ForceSensor, MachineModel, PitchErrorEffect, PressureSensor,
};
use crate::plant::noise::Noise;
use crate::plant::sensing::Transducer;

/// A 12-bit ADC conversion of a value in codes (rounded, clamped to the range; NaN reads 0).
#[inline]
pub fn adc(code: f64) -> AdcCode {
    // `as` saturates (below 0 and NaN → 0), so only the top needs a bound.
    AdcCode(((code + 0.5) as u16).min(4095))
}

/// One sin/cos encoder at the ADC: the model's `[sensors.encoder_*]` on a scale of
/// period λ.
#[derive(Clone, Debug, PartialEq)]
pub struct EncoderModel {
    /// Signal period λ, m.
    pub period_m: f64,
    /// Amplitude, offsets, gain and phase errors, noise (the model's section).
    pub sensor: EncoderSensor,
}

impl EncoderModel {
    /// From the model's `[sensors.encoder_*]` section.
    pub fn new(period_m: f64, s: &EncoderSensor) -> Self {
        EncoderModel {
            period_m,
            sensor: s.clone(),
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
        let e = &self.sensor;
        let a = e.amplitude_codes;
        let c = if e.quadrature_error_rad == 0.0 {
            c
        } else {
            sin_cos(th + e.quadrature_error_rad).1
        };
        let sin = 2048.0 + e.sin_offset_codes + a * s;
        let cos = 2048.0 + e.cos_offset_codes + a * (1.0 + e.gain_mismatch) * c;
        (sin, cos)
    }

    /// Noise per channel, codes RMS.
    pub fn noise_codes(&self) -> f64 {
        self.sensor.noise_codes
    }
}

/// The four pressure sensors (chamber A, chamber B, suction, discharge): the firmware's
/// calibration of their codes and the model's `[sensors.pressure]` (lag, offsets, noise;
/// their laws are `plant::sensing`'s).
#[derive(Clone, Debug, PartialEq)]
pub struct PressureSensors {
    /// Calibration (the firmware's: the same codes mean the same pressures).
    pub calibration: PressureCalibration,
    /// Lag, offsets and noise.
    pub sensor: PressureSensor,
}

impl PressureSensors {
    /// The code transducer `t` gives with its lag at `lagged_pa`, noise drawn from `noise`.
    #[inline]
    pub fn code(&self, lagged_pa: f64, t: Transducer, noise: &mut Noise) -> AdcCode {
        let reading = self.sensor.noisy_reading_pa(lagged_pa, t, noise);
        self.calibration.code_for(reading as f32)
    }
}

impl Sensors {
    /// The current offsets of `section`'s three phases, A.
    pub fn current_offsets_a(&self, section: Section) -> [f64; 3] {
        match section {
            Section::Master => self.current_sensor.offset_master_a,
            Section::Slave => self.current_sensor.offset_slave_a,
        }
    }
}

/// Everything the simulated board senses with, and how.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensors {
    /// Encoder on the master section.
    pub encoder_master: EncoderModel,
    /// Encoder on the slave section.
    pub encoder_slave: EncoderModel,
    /// Pitch error of the slave encoder's scale, if any.
    pub slave_pitch_error: Option<PitchErrorEffect>,
    /// Current-sense calibration (the firmware's reference).
    pub current: CurrentSense,
    /// Current sensing's noise and offsets (the model's `[sensors.current]`).
    pub current_sensor: CurrentSensor,
    /// Pressure sensors.
    pub pressure: PressureSensors,
    /// What each section's force reading reports to the log.
    pub force: ForceSensor,
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
            current_sensor: CurrentSensor::default(),
            pressure: PressureSensors {
                calibration: PressureCalibration::reference(),
                sensor: PressureSensor::default(),
            },
            force: ForceSensor::default(),
            counts_per_rev: 4096,
        }
    }

    /// The sensors a model describes.
    pub fn from_model(model: &MachineModel) -> Self {
        let s = &model.sensors;
        Sensors {
            encoder_master: EncoderModel::new(model.encoder.period_m, &s.encoder_master),
            encoder_slave: EncoderModel::new(model.encoder.period_m, &s.encoder_slave),
            slave_pitch_error: model.effects.encoder_pitch_error.clone(),
            current: CurrentSense::reference(),
            current_sensor: s.current.clone(),
            pressure: PressureSensors {
                calibration: PressureCalibration::reference(),
                sensor: s.pressure.clone(),
            },
            force: s.force,
            counts_per_rev: model.servo.counts_per_rev,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_adc_rounds_and_clamps() {
        for x in [
            -1e9, -0.6, -0.5, -0.4, 0.0, 0.49, 0.5, 2047.5, 4094.6, 4095.4, 4095.6, 7e4, 1e30,
        ] {
            assert_eq!(adc(x).0, (x + 0.5).clamp(0.0, 4095.0) as u16, "{x}");
        }
        assert_eq!(adc(f64::NAN).0, 0);
    }
}
