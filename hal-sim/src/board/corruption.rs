//! Sensor faults of the simulated board: what a broken sensor or cable does to each burst,
//! applied right after sampling. The fault injector arms them; the board knows nothing of
//! the injector.

use fpc::ports::{EncoderCodes, PressureCodes, SinCosCodes};
use fpc::units::{AdcCode, PerSection};
use rand::{Rng as _, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A pressure channel forced to a reading.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PressureHold {
    /// Reads what the sensor sees.
    #[default]
    Live,
    /// Freezes at the next reading (a stuck sensor), then holds it.
    FreezeNext,
    /// Reads this code (open circuit: 0; short to the rail: full scale; or frozen).
    Code(u16),
}

/// A burst of corrupt samples on the master encoder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseBurst {
    /// Samples left in the burst.
    pub samples_left: u32,
    /// Fraction of the samples corrupted (each independently; the first always, so the
    /// burst's start is defined).
    pub fraction: f64,
    /// The first sample has been corrupted.
    pub started: bool,
    /// Samples of the burst so far.
    pub sample: u32,
}

/// Sensor faults applied to each burst right after it is sampled (all off by default).
#[derive(Clone, Debug, Default)]
pub struct SensorCorruption {
    /// Encoder signals scaled about mid-scale by this gain, on the encoders marked.
    pub gain: Option<(f64, PerSection<bool>)>,
    /// Master encoder channel held at mid-scale: 0 = sin, 1 = cos.
    pub master_stuck_channel: Option<u8>,
    /// One master sample rotated by this phase, rad (cleared once applied).
    pub master_phase_jump_rad: Option<f64>,
    /// A noise burst on the master encoder (cleared when over).
    pub burst: Option<NoiseBurst>,
    /// Which samples of the last noise burst were corrupted, counted from its first (1): what
    /// the test of `docs/faults.md` #4 judges the latch against.
    pub burst_corrupted: Vec<u32>,
    /// Chamber A and B pressure channels.
    pub chambers: [PressureHold; 2],
    /// Added to the quadrature counter (wrapping): starts it just before its wrap.
    pub quadrature_offset: u16,
    rng: BurstRng,
}

impl SensorCorruption {
    /// No corruption yet, with its own random stream (noise bursts) from `seed`.
    pub fn seeded(seed: u64) -> Self {
        SensorCorruption {
            rng: BurstRng(ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_FA17_0000_0000)),
            ..Default::default()
        }
    }

    /// Whether anything is to be applied (tested once per period by the world).
    #[inline]
    pub fn active(&self) -> bool {
        self.gain.is_some()
            || self.master_stuck_channel.is_some()
            || self.master_phase_jump_rad.is_some()
            || self.burst.is_some()
            || self.chambers != [PressureHold::Live; 2]
            || self.quadrature_offset != 0
    }

    /// Corrupts one burst as configured.
    pub fn apply(
        &mut self,
        encoders: &mut EncoderCodes,
        pressures: &mut PressureCodes,
        quadrature: &mut u16,
    ) {
        if let Some((gain, on)) = self.gain {
            for (codes, on) in [
                (&mut encoders.master, on.master),
                (&mut encoders.slave, on.slave),
            ] {
                if on {
                    *codes = map_codes(*codes, |s, c| (s * gain, c * gain));
                }
            }
        }
        let m = &mut encoders.master;
        if let Some(jump) = self.master_phase_jump_rad.take() {
            let (sj, cj) = jump.sin_cos();
            // sin(θ + j) and cos(θ + j) from sin θ and cos θ: the amplitude kept, the phase
            // moved.
            *m = map_codes(*m, |s, c| (s * cj + c * sj, c * cj - s * sj));
        }
        match self.master_stuck_channel {
            Some(0) => m.sin = AdcCode::MID,
            Some(_) => m.cos = AdcCode::MID,
            None => {}
        }
        if let Some(b) = self.burst.as_mut() {
            let rng = &mut self.rng.0;
            if !b.started {
                self.burst_corrupted.clear();
            }
            b.sample += 1;
            if !b.started || rng.random::<f64>() < b.fraction {
                m.sin = AdcCode(rng.random_range(0..4096));
                m.cos = AdcCode(rng.random_range(0..4096));
                self.burst_corrupted.push(b.sample);
            }
            b.started = true;
            b.samples_left = b.samples_left.saturating_sub(1);
            if b.samples_left == 0 {
                self.burst = None;
            }
        }
        for (hold, code) in self
            .chambers
            .iter_mut()
            .zip([&mut pressures.chamber_a, &mut pressures.chamber_b])
        {
            match *hold {
                PressureHold::Live => {}
                PressureHold::FreezeNext => *hold = PressureHold::Code(code.0),
                PressureHold::Code(c) => *code = AdcCode(c),
            }
        }
        *quadrature = quadrature.wrapping_add(self.quadrature_offset);
    }
}

/// Applies `f` to a sin/cos pair centred on mid-scale, then converts back like the ADC.
fn map_codes(codes: SinCosCodes, f: impl Fn(f64, f64) -> (f64, f64)) -> SinCosCodes {
    let mid = f64::from(AdcCode::MID.0);
    let (s, c) = f(f64::from(codes.sin.0) - mid, f64::from(codes.cos.0) - mid);
    SinCosCodes {
        sin: crate::board::sensors::adc(mid + s),
        cos: crate::board::sensors::adc(mid + c),
    }
}

/// The noise bursts' random stream (its own, so a burst does not shift the sensor noise).
#[derive(Clone, Debug)]
struct BurstRng(ChaCha8Rng);

impl Default for BurstRng {
    fn default() -> Self {
        BurstRng(ChaCha8Rng::seed_from_u64(0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn burst(sin: u16, cos: u16, chamber_a: u16) -> (EncoderCodes, PressureCodes, u16) {
        let codes = SinCosCodes {
            sin: AdcCode(sin),
            cos: AdcCode(cos),
        };
        let p = PressureCodes {
            chamber_a: AdcCode(chamber_a),
            chamber_b: AdcCode(1000),
            suction: AdcCode(1000),
            discharge: AdcCode(1000),
        };
        (
            EncoderCodes {
                master: codes,
                slave: codes,
            },
            p,
            65_500,
        )
    }

    #[test]
    fn nothing_set_is_inactive() {
        assert!(!SensorCorruption::seeded(1).active());
    }

    #[test]
    fn a_phase_jump_moves_the_angle_and_keeps_the_amplitude_once() {
        let mut c = SensorCorruption::seeded(1);
        c.master_phase_jump_rad = Some(std::f64::consts::FRAC_PI_2);
        assert!(c.active());
        let (mut e, mut p, mut q) = burst(2048, 3648, 1000);
        c.apply(&mut e, &mut p, &mut q);
        // (sin, cos) = (0, 1) turned by π/2 is (1, 0); the slave is untouched.
        assert_eq!((e.master.sin.0, e.master.cos.0), (3648, 2048));
        assert_eq!((e.slave.sin.0, e.slave.cos.0), (2048, 3648));
        assert!(!c.active(), "one sample only");
    }

    #[test]
    fn pressure_channels_open_short_and_freeze() {
        let mut c = SensorCorruption::seeded(1);
        c.chambers = [PressureHold::FreezeNext, PressureHold::Code(4095)];
        let (mut e, mut p, mut q) = burst(2048, 3648, 1234);
        c.apply(&mut e, &mut p, &mut q);
        assert_eq!((p.chamber_a.0, p.chamber_b.0), (1234, 4095));
        let (mut e, mut p, mut q) = burst(2048, 3648, 2000);
        c.apply(&mut e, &mut p, &mut q);
        assert_eq!(p.chamber_a.0, 1234, "frozen at the first reading");
    }

    #[test]
    fn the_quadrature_offset_wraps_the_counter() {
        let mut c = SensorCorruption::seeded(1);
        c.quadrature_offset = 100;
        let (mut e, mut p, mut q) = burst(2048, 3648, 1000);
        c.apply(&mut e, &mut p, &mut q);
        assert_eq!(q, 65_500u16.wrapping_add(100));
    }

    #[test]
    fn a_burst_corrupts_its_first_sample_and_ends() {
        let mut c = SensorCorruption::seeded(3);
        c.burst = Some(NoiseBurst {
            samples_left: 4,
            fraction: 0.0,
            started: false,
            sample: 0,
        });
        let (mut e, mut p, mut q) = burst(2048, 3648, 1000);
        c.apply(&mut e, &mut p, &mut q);
        assert_ne!((e.master.sin.0, e.master.cos.0), (2048, 3648));
        for _ in 0..3 {
            let (mut e, mut p, mut q) = burst(2048, 3648, 1000);
            c.apply(&mut e, &mut p, &mut q);
            assert_eq!((e.master.sin.0, e.master.cos.0), (2048, 3648));
        }
        assert!(c.burst.is_none());
        assert_eq!(c.burst_corrupted, [1]);
    }
}
