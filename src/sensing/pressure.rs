//! Pressure sensing: ADC codes to pascal, with open/short and stuck detection.
//!
//! Sensors are 0–10 bar absolute, ratiometric, with a live zero: 0 bar at 10 % of the ADC
//! range and 10 bar at 90 %, so a broken wire (0 V) and a short to the rail read outside the
//! live band and are detected at once (NAMUR NE43 style). A sample outside the band is marked
//! invalid ([`PressureSample::valid`] is `None`) and must never reach the control law.
//!
//! Samples are taken in the control cycle's sampling burst (`ports::PressureInput`), so each
//! pressure belongs to the same instant as the encoder position.
//!
//! A *stuck* sensor reads a live value that no longer moves. [`StuckMonitor`] watches one
//! channel against the piston travel: a chamber's volume is affine in the position, and over a
//! stroke each way the pressure of a working chamber must move (compression alone changes it
//! by bars). A reading that stays within a few codes while the piston has travelled a
//! half-stroke in *both* directions is flagged: within two strokes of the sensor freezing,
//! wherever in the cycle it froze (`docs/faults.md` scenario 6). Noise keeps a live sensor out of
//! the band even where the physics holds the pressure flat (ports open, no compression).

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
        // The float→int cast saturates at 0 (and NaN → 0); cap the top at full scale.
        AdcCode(((c + 0.5) as u16).min(4095))
    }

    /// Converts a code, classifying it.
    #[inline]
    pub fn convert(&self, code: AdcCode) -> PressureSample {
        // In the live band by one unsigned compare of the distance from its bottom (a code
        // below it wraps to far above the band's width); the band's ends are in order
        // (`open_below ≤ short_above`, refused otherwise by `ControlConfig::check`).
        let (code16, open, short) = (code.0, self.open_below, self.short_above);
        let status = if code16.wrapping_sub(open) <= short.wrapping_sub(open) {
            PressureStatus::Valid
        } else if code16 < open {
            PressureStatus::Open
        } else {
            PressureStatus::Short
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

/// Settings of a [`StuckMonitor`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StuckConfig {
    /// A reading that stays within ± this many codes of where it was counts as not moving
    /// (4 codes ≈ 1.2 kPa: 2.5σ of the sensor's 0.5 kPa noise, and a frozen sensor's ADC
    /// noise stays inside it).
    pub band_codes: u16,
    /// Travel each way, m, over which a live reading must leave the band (half the 0.2 m
    /// working stroke: any half-stroke of a working chamber compresses or expands it).
    pub min_travel_m: f32,
}

impl StuckConfig {
    /// Reference: ±4 codes over 0.1 m each way.
    pub const fn reference() -> Self {
        StuckConfig {
            band_codes: 4,
            min_travel_m: 0.1,
        }
    }
}

/// Detects a pressure channel whose reading no longer follows the chamber volume.
///
/// Call [`StuckMonitor::update`] every cycle with the channel's code and the piston position
/// (either chamber: both volumes are affine in it). The verdict is the *cause*; latching
/// `Fault::PressurePlausibility` is the supervisor's. Cheap: a few compares and adds.
#[derive(Clone, Copy, Debug)]
pub struct StuckMonitor {
    config: StuckConfig,
    /// The code the reading was at when it last moved out of the band.
    reference: u16,
    last_position_m: f32,
    /// Travel since then, each way, m.
    forward_m: f32,
    backward_m: f32,
    started: bool,
}

impl StuckMonitor {
    /// A monitor; the first update sets its reference.
    pub const fn new(config: StuckConfig) -> Self {
        StuckMonitor {
            config,
            reference: 0,
            last_position_m: 0.0,
            forward_m: 0.0,
            backward_m: 0.0,
            started: false,
        }
    }

    /// Forgets the history (e.g. after the machine stood still for a while on purpose).
    pub fn reset(&mut self) {
        self.started = false;
    }

    /// One sample: the channel's raw code and the piston position, m. Returns whether the
    /// reading looks stuck (it stayed in its band over `min_travel_m` each way). A
    /// non-finite position is ignored.
    #[inline]
    pub fn update(&mut self, code: AdcCode, position_m: f32) -> bool {
        if !self.started {
            self.started = position_m.is_finite();
            self.reference = code.0;
            self.last_position_m = position_m;
            self.forward_m = 0.0;
            self.backward_m = 0.0;
            return false;
        }
        if code.0.abs_diff(self.reference) > self.config.band_codes {
            self.reference = code.0;
            self.forward_m = 0.0;
            self.backward_m = 0.0;
        }
        let dx = position_m - self.last_position_m;
        if dx.is_finite() {
            self.last_position_m = position_m;
            if dx > 0.0 {
                self.forward_m += dx;
            } else {
                self.backward_m -= dx;
            }
        }
        self.is_stuck()
    }

    /// The verdict of the last update.
    pub fn is_stuck(&self) -> bool {
        self.started
            && self.forward_m >= self.config.min_travel_m
            && self.backward_m >= self.config.min_travel_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use rand::{Rng as _, SeedableRng};
    use rand_chacha::ChaCha8Rng;

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
        // The band's ends are live, the codes just outside are not.
        for (code, status) in [
            (204, PressureStatus::Open),
            (205, PressureStatus::Valid),
            (3890, PressureStatus::Valid),
            (3891, PressureStatus::Short),
        ] {
            assert_eq!(cal.convert(AdcCode(code)).status, status, "code {code}");
        }
        assert_eq!(cal.convert(AdcCode(0)).valid(), None);
    }

    proptest! {
        /// Every 16-bit code converts to a finite pressure, and is valid exactly inside the
        /// live band.
        #[test]
        fn every_code_is_classified(code in any::<u16>()) {
            let cal = PressureCalibration::reference();
            let s = cal.convert(AdcCode(code));
            prop_assert!(s.pressure_pa.is_finite());
            let live = (cal.open_below..=cal.short_above).contains(&code);
            prop_assert_eq!(s.valid().is_some(), live);
        }

        /// Any codes and positions (NaN and ±inf included): no panic.
        #[test]
        fn the_stuck_monitor_is_total(
            samples in proptest::collection::vec(
                (any::<u16>(), prop_oneof![any::<f32>(), Just(f32::NAN), Just(f32::INFINITY)]),
                0..500,
            )
        ) {
            let mut m = StuckMonitor::new(StuckConfig::reference());
            for (c, x) in samples {
                m.update(AdcCode(c), x);
            }
        }
    }

    /// Chamber A of a running compressor, schematically: suction at 1 bar while its volume
    /// grows, polytropic compression to 3 bar, discharge at 3 bar. Code of the pressure at x.
    fn chamber_a_code(x: f32, toward_b: bool, cal: &PressureCalibration, noise: f32) -> AdcCode {
        let (lo, hi, dead) = (1.0e5f32, 3.0e5f32, 0.0005f32);
        let p = if toward_b {
            lo
        } else {
            // V from 0.2 m down: p·V^1.3 = const until the discharge pressure.
            (lo * libm::powf((0.2 + dead) / (x + dead), 1.3)).min(hi)
        };
        AdcCode((cal.zero_code + p / cal.pa_per_code + noise + 0.5) as u16)
    }

    /// Stroke position over a cycle: 0.005 → 0.205 → 0.005 m, `n` samples per stroke.
    fn stroke(k: usize, n: usize) -> (f32, bool) {
        let phase = k % (2 * n);
        let u = (phase % n) as f32 / n as f32;
        let s = 0.5 - 0.5 * libm::cosf(core::f32::consts::PI * u);
        if phase < n {
            (0.005 + 0.2 * s, true)
        } else {
            (0.205 - 0.2 * s, false)
        }
    }

    #[test]
    fn a_frozen_chamber_sensor_is_caught_within_two_strokes() {
        let cal = PressureCalibration::reference();
        let n = 1000; // samples per stroke
        let mut rng = ChaCha8Rng::seed_from_u64(0x2545_f491);
        let mut noise = || {
            // Two uniform draws: ±1.6 codes RMS, triangular.
            let mut u = || rng.random::<f32>() - 0.5;
            3.9 * (u() + u())
        };
        let mut worst_strokes = 0.0f32;
        for freeze_at in (0..2 * n).step_by(97) {
            let mut m = StuckMonitor::new(StuckConfig::reference());
            let start = 4 * n + freeze_at;
            let mut frozen = None;
            let mut caught = None;
            for k in 0..12 * n {
                let (x, toward_b) = stroke(k, n);
                let live = chamber_a_code(x, toward_b, &cal, noise());
                let code = if k >= start {
                    // The sensor froze; the ADC still adds its own ±1 code.
                    let f = *frozen.get_or_insert(live);
                    AdcCode(f.0.saturating_add((k % 3) as u16).saturating_sub(1))
                } else {
                    live
                };
                let stuck = m.update(code, x);
                assert!(!(stuck && k < start), "false alarm at sample {k}");
                if stuck {
                    caught = Some(k - start);
                    break;
                }
            }
            let strokes = caught.map_or(f32::INFINITY, |d| d as f32 / n as f32);
            worst_strokes = worst_strokes.max(strokes);
        }
        println!("frozen chamber sensor caught after at most {worst_strokes:.2} strokes");
        assert!(worst_strokes <= 2.0, "caught after {worst_strokes} strokes");
    }

    #[test]
    fn a_live_sensor_is_never_flagged_even_without_noise_while_compressing() {
        let cal = PressureCalibration::reference();
        let mut m = StuckMonitor::new(StuckConfig::reference());
        for k in 0..40_000 {
            let (x, toward_b) = stroke(k, 1000);
            assert!(!m.update(chamber_a_code(x, toward_b, &cal, 0.0), x));
        }
    }
}
