//! Current sense: the routine that measures each phase's ADC zero with the outputs off
//! ([`SenseAverage`]), and the monitor that watches the zero while the outputs are off
//! ([`SenseMonitor`]).

use super::{cycles, within, CalibrationError, Demand, Measurements, Outcome};
use crate::control::config::{CalibrationConfig, ControlConfig};
use crate::ports::PhaseCurrentCodes;
use crate::units::{PerSection, Section};

/// Current-sense offsets: the mean code of each phase with the outputs off.
#[derive(Clone, Debug)]
pub(super) struct SenseAverage {
    settle: u32,
    samples: u32,
    sums: PerSection<[f32; 3]>,
}

impl SenseAverage {
    pub(super) fn new(c: &CalibrationConfig, dt: f32) -> Self {
        SenseAverage {
            settle: cycles(c.sense_settle_s, dt),
            samples: 0,
            sums: PerSection::default(),
        }
    }

    pub(super) fn step(&mut self, c: &CalibrationConfig, m: &Measurements) -> Demand {
        if self.settle > 0 {
            self.settle -= 1;
            return Demand::Off;
        }
        for section in Section::ALL {
            for (sum, code) in self
                .sums
                .get_mut(section)
                .iter_mut()
                .zip(m.currents.get(section))
            {
                *sum += f32::from(code.centered());
            }
        }
        self.samples += 1;
        if self.samples < c.sense_samples.max(1) {
            return Demand::Off;
        }
        let n = self.samples as f32;
        let mean = |s: &[f32; 3]| s.map(|v| v / n);
        let offsets = PerSection {
            master: mean(&self.sums.master),
            slave: mean(&self.sums.slave),
        };
        for section in Section::ALL {
            for (phase, o) in offsets.get(section).iter().enumerate() {
                if !within(*o, c.sense_max_offset_codes) {
                    return Demand::Done(Err(CalibrationError::CurrentSenseOffset {
                        section,
                        phase: phase as u8,
                    }));
                }
            }
        }
        Demand::Done(Ok(Outcome::CurrentSense(offsets)))
    }
}

/// Watches the phase currents while the outputs are off: with no current flowing, their
/// mean must be zero once the calibrated offsets are taken off. A mean beyond
/// [`CalibrationConfig::sense_detect_a`] is a current-sense offset (drifted or never
/// calibrated); the controller then refuses to switch the outputs on until the current-sense
/// calibration has loaded new offsets.
///
/// A leaky mean of the raw codes (time constant 256 cycles = 12.8 ms), valid once 1024
/// outputs-off cycles have been seen; it runs only while the outputs are off.
#[derive(Clone, Debug, Default)]
pub struct SenseMonitor {
    mean_codes: PerSection<[f32; 3]>,
    seen: u16,
}

impl SenseMonitor {
    /// Cycles of outputs off before the mean is trusted.
    pub const VALID_AFTER: u16 = 1024;

    /// A monitor that has seen nothing.
    pub const fn new() -> Self {
        SenseMonitor {
            mean_codes: PerSection {
                master: [0.0; 3],
                slave: [0.0; 3],
            },
            seen: 0,
        }
    }

    /// One outputs-off sample of both sections' phase codes.
    pub fn observe(&mut self, currents: &PerSection<PhaseCurrentCodes>) {
        const ALPHA: f32 = 1.0 / 256.0;
        for section in Section::ALL {
            for (mean, code) in self
                .mean_codes
                .get_mut(section)
                .iter_mut()
                .zip(currents.get(section))
            {
                *mean += (f32::from(code.centered()) - *mean) * ALPHA;
            }
        }
        self.seen = self.seen.saturating_add(1);
    }

    /// The largest mean phase current with the outputs off, A, once valid (with the
    /// offsets of `config` taken off).
    pub fn residual_a(&self, config: &ControlConfig) -> Option<f32> {
        if self.seen < Self::VALID_AFTER {
            return None;
        }
        let mut worst = 0.0f32;
        for section in Section::ALL {
            let sense = config.current_sense.get(section);
            for (mean, offset) in self.mean_codes.get(section).iter().zip(sense.offset_codes) {
                let a = ((mean - offset) * sense.a_per_code).abs();
                // NaN sticks: a broken reading counts as the worst.
                if a > worst || a.is_nan() {
                    worst = a;
                }
            }
        }
        Some(worst)
    }

    /// Whether an offset is detected under `config`.
    pub fn offset_detected(&self, config: &ControlConfig) -> bool {
        self.residual_a(config)
            .is_some_and(|a| !within(a, config.calibration.sense_detect_a))
    }
}
