//! Pressure sensing: ADC codes to pascal, with open/short detection.
//!
//! Sensors are 0–10 bar absolute, ratiometric, with a live zero: 0 bar at 10 % of the ADC
//! range and 10 bar at 90 %, so a broken wire (0 V) and a short to the rail read outside the
//! live band and are detected at once (NAMUR NE43 style). A sample outside the band is marked
//! invalid and must never reach the control law.

use crate::units::AdcCode;

/// Calibration of one pressure channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PressureCalibration {
    /// Code at 0 Pa absolute.
    pub zero_code: f32,
    /// Pascal per code.
    pub pa_per_code: f32,
    /// Codes below this are an open circuit.
    pub open_below: u16,
    /// Codes above this are a short to the rail.
    pub short_above: u16,
}

impl PressureCalibration {
    /// The reference sensor: 0 Pa at code 409.5, 1 MPa at code 3685.5, open below 5 % of
    /// full scale, short above 95 %.
    pub const fn reference() -> Self {
        PressureCalibration {
            zero_code: 409.5,
            pa_per_code: 1.0e6 / 3276.0,
            open_below: 205,
            short_above: 3890,
        }
    }

    /// The code a pressure reads as (inverse of [`PressureCalibration::convert`]); for the
    /// simulator and for tests. Saturates to the ADC range.
    pub fn code_for(&self, pressure_pa: f32) -> AdcCode {
        let c = self.zero_code + pressure_pa / self.pa_per_code;
        AdcCode((c + 0.5).clamp(0.0, 4095.0) as u16)
    }

    /// Converts a code, classifying it.
    #[inline]
    pub fn convert(&self, code: AdcCode) -> PressureSample {
        let status = if code.0 < self.open_below {
            PressureStatus::Open
        } else if code.0 > self.short_above {
            PressureStatus::Short
        } else {
            PressureStatus::Valid
        };
        PressureSample {
            pressure_pa: (f32::from(code.0) - self.zero_code) * self.pa_per_code,
            status,
        }
    }
}

/// Classification of a pressure sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum PressureStatus {
    /// In the live band.
    Valid,
    /// Below the live band: open circuit.
    Open,
    /// Above the live band: short to the rail.
    Short,
}

/// One converted pressure sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PressureSample {
    /// Absolute pressure, Pa (meaningless unless `status` is `Valid`).
    pub pressure_pa: f32,
    /// Validity.
    pub status: PressureStatus,
}

impl PressureSample {
    /// The pressure if the sample is valid.
    #[inline]
    pub fn valid(&self) -> Option<f32> {
        (self.status == PressureStatus::Valid).then_some(self.pressure_pa)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_classifies() {
        let cal = PressureCalibration::reference();
        for p in [0.0, 1.0e5, 5.1e5, 1.0e6] {
            let s = cal.convert(cal.code_for(p));
            assert_eq!(s.status, PressureStatus::Valid);
            assert!((s.pressure_pa - p).abs() < cal.pa_per_code);
        }
        assert_eq!(cal.convert(AdcCode(0)).status, PressureStatus::Open);
        assert_eq!(cal.convert(AdcCode(4095)).status, PressureStatus::Short);
        assert_eq!(cal.convert(AdcCode(0)).valid(), None);
    }
}
