//! The encoder signal faults of `docs/faults.md`, scenarios 1–4, at the decoder: what is rejected,
//! what latches the `encoder_signal` fault, and how fast. Plus the bad-input property: any
//! sequence of 16-bit codes decodes without panic and without an impossible position step.

mod support;

use fpc::ports::SinCosCodes;
use fpc::sensing::encoder::{
    EncoderConfig, SinCosCalibration, SinCosDecoder, NOMINAL_AMPLITUDE_CODES,
};
use fpc::units::AdcCode;
use proptest::prelude::*;
use support::sensing::{adc, encoder_codes, Rng};

const PERIOD_M: f64 = 0.024;
const DT_S: f64 = 50e-6;
/// 1 µm of encoder noise, in codes RMS per channel.
const NOISE: f64 = 0.42;

fn ideal() -> SinCosCalibration {
    SinCosCalibration::ideal(NOMINAL_AMPLITUDE_CODES)
}

/// A decoder that has followed the piston for 100 samples at `speed_mps` from `x0_m`;
/// returns it and the position of the next sample.
fn running(x0_m: f64, speed_mps: f64, rng: &mut Rng) -> (SinCosDecoder, f64) {
    let mut dec = SinCosDecoder::new(EncoderConfig::reference());
    let mut x = x0_m;
    for _ in 0..100 {
        let r = dec.update(encoder_codes(x, PERIOD_M, &ideal(), NOISE, rng));
        assert!(!r.rejected && !r.signal_fault);
        x += speed_mps * DT_S;
    }
    (dec, x)
}

#[test]
fn amplitude_out_of_window_latches_within_two_cycles_at_full_speed() {
    let mut rng = Rng::new(1);
    for gain in [0.2f32, 1.5] {
        for start in 0..16 {
            let x0 = 0.02 + start as f64 * PERIOD_M / 16.0;
            let (mut dec, mut x) = running(x0, 4.0, &mut rng);
            let weak = SinCosCalibration::ideal(NOMINAL_AMPLITUDE_CODES * gain);
            let mut latched_after = None;
            for k in 1..=10 {
                let r = dec.update(encoder_codes(x, PERIOD_M, &weak, NOISE, &mut rng));
                x += 4.0 * DT_S;
                if r.signal_fault {
                    latched_after = Some(k);
                    break;
                }
            }
            assert!(
                latched_after.is_some_and(|k| k <= 2),
                "gain {gain}, start {start}: latched after {latched_after:?} cycles"
            );
        }
    }
}

#[test]
fn a_channel_stuck_at_mid_scale_is_caught_within_a_quarter_period() {
    let mut rng = Rng::new(2);
    let mut worst_m = 0.0f64;
    for channel in 0..2 {
        for speed in [0.01, 0.3, 4.0] {
            for start in 0..64 {
                let x0 = 0.05 + start as f64 * PERIOD_M / 64.0;
                let (mut dec, mut x) = running(x0, speed, &mut rng);
                let onset = x;
                let mut caught = None;
                while x - onset < PERIOD_M {
                    let mut codes = encoder_codes(x, PERIOD_M, &ideal(), NOISE, &mut rng);
                    if channel == 0 {
                        codes.sin = AdcCode::MID;
                    } else {
                        codes.cos = AdcCode::MID;
                    }
                    if dec.update(codes).signal_fault {
                        caught = Some(x - onset);
                        break;
                    }
                    x += speed * DT_S;
                }
                let travel = caught.unwrap_or(f64::INFINITY);
                worst_m = worst_m.max(travel);
                assert!(
                    travel <= PERIOD_M / 4.0,
                    "channel {channel}, {speed} m/s, start {start}: {travel} m"
                );
            }
        }
    }
    println!(
        "stuck channel: caught after at most {:.2} mm of travel (limit {:.1} mm)",
        worst_m * 1e3,
        PERIOD_M / 4.0 * 1e3
    );
}

#[test]
fn a_single_phase_glitch_is_rejected_without_a_fault() {
    let mut rng = Rng::new(3);
    let m = f64::from(EncoderConfig::reference().m_per_count());
    let mut worst_m = 0.0f64;
    for jump_rad in [-3.0, -2.0, -0.5, -0.05, 0.05, 0.5, 2.0, 3.0] {
        for speed in [0.0, 1.0, 4.0] {
            let (mut dec, mut x) = running(0.03, speed, &mut rng);
            // The decoder's frame: its first sample was at 0.03 m, a fraction of a period.
            let offset = 0.03 - (0.03f64).rem_euclid(PERIOD_M);
            for k in 0..200 {
                let mut codes = encoder_codes(x, PERIOD_M, &ideal(), NOISE, &mut rng);
                if k == 50 {
                    let th = std::f64::consts::TAU * x / PERIOD_M + jump_rad;
                    codes = SinCosCodes {
                        sin: adc(2048.0 + 1600.0 * th.sin()),
                        cos: adc(2048.0 + 1600.0 * th.cos()),
                    };
                }
                let r = dec.update(codes);
                assert!(!r.signal_fault, "jump {jump_rad} at {speed} m/s: fault");
                let err = (f64::from(r.position.to_bits()) * m + offset - x).abs();
                worst_m = worst_m.max(err);
                x += speed * DT_S;
            }
        }
    }
    println!("phase glitch: worst position error {:.1} µm", worst_m * 1e6);
    assert!(worst_m < 0.05e-3);
}

#[test]
fn a_burst_latches_at_its_second_or_third_corrupt_sample_and_one_in_ten_within_20() {
    // 10 % of the samples replaced by random codes, for 20 ms (400 samples), many seeds.
    let mut latency = Vec::new();
    for seed in 0..200 {
        let mut rng = Rng::new(1000 + seed);
        let (mut dec, mut x) = running(0.05, 2.0, &mut rng);
        let mut latched = None;
        let mut corrupt = 0;
        for k in 0..400 {
            let mut codes = encoder_codes(x, PERIOD_M, &ideal(), NOISE, &mut rng);
            // Every tenth sample on average, at random; the first of the burst is corrupt.
            let corrupted = k == 0 || rng.uniform() < 0.1;
            if corrupted {
                codes = SinCosCodes {
                    sin: AdcCode((rng.next_u64() % 4096) as u16),
                    cos: AdcCode((rng.next_u64() % 4096) as u16),
                };
                corrupt += 1;
            }
            if dec.update(codes).signal_fault {
                // The fault is latched on a corrupt sample, the burst's second or third:
                // one corrupt sample is a glitch (#3), and a random code that happens to
                // lie on the circle may pass as one more.
                assert!(
                    corrupted,
                    "seed {seed}: latched on a clean sample {}",
                    k + 1
                );
                assert!(
                    (2..=3).contains(&corrupt),
                    "seed {seed}: latched at corrupt sample {corrupt}"
                );
                latched = Some((k + 1, corrupt));
                break;
            }
            x += 2.0 * DT_S;
        }
        latency.push(latched.expect("a 10 % burst must latch the fault"));
    }
    latency.sort_unstable();
    let worst = latency.iter().map(|l| l.0).max().unwrap_or(0);
    let median = latency[latency.len() / 2].0;
    let within_20 = latency.iter().filter(|l| l.0 <= 20).count();
    let worst_corrupt = latency.iter().map(|l| l.1).max().unwrap_or(0);
    println!(
        "10 % burst over 200 seeds: latched after median {median}, worst {worst} samples; \
         ≤ 20 samples in {within_20}/200; at most {worst_corrupt} corrupt samples seen"
    );
    // The filter trips on two bad samples within 48 (one glitch never does): every burst
    // latched at its second corrupt sample, or its third (asserted per burst above); so
    // within 20 samples of its start whenever those come that soon (1 − 0.9¹⁹ = 86 % of
    // random bursts: the figure printed is the seeds', not a bound).
    assert!(worst_corrupt <= 3);
    // Evenly spread, every tenth sample: latched at the second corrupt one, sample 11.
    let mut rng = Rng::new(7);
    let (mut dec, mut x) = running(0.05, 2.0, &mut rng);
    let mut latched_at = None;
    for k in 0..400 {
        let mut codes = encoder_codes(x, PERIOD_M, &ideal(), NOISE, &mut rng);
        if k % 10 == 0 {
            codes = SinCosCodes {
                sin: AdcCode((rng.next_u64() % 4096) as u16),
                cos: AdcCode((rng.next_u64() % 4096) as u16),
            };
        }
        if dec.update(codes).signal_fault {
            latched_at = Some(k + 1);
            break;
        }
        x += 2.0 * DT_S;
    }
    assert!(latched_at.is_some_and(|k| k <= 20), "{latched_at:?}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Whatever the codes (the whole u16 range, not only 12 bits), decoding neither panics
    /// nor, once a sample has been accepted, moves the position by half a period or more in
    /// one sample.
    #[test]
    fn any_codes_decode_without_panic_or_impossible_step(
        codes in proptest::collection::vec((any::<u16>(), any::<u16>()), 1..2000),
        phase in -0.5f32..0.5,
        amplitude in prop_oneof![Just(0.0f32), Just(f32::NAN), 1.0f32..5000.0],
    ) {
        let config = EncoderConfig {
            calibration: SinCosCalibration {
                sin_offset: amplitude * 0.1,
                cos_offset: -3.0,
                sin_amplitude: amplitude,
                cos_amplitude: 1600.0,
                phase_rad: phase,
            },
            ..EncoderConfig::reference()
        };
        let mut dec = SinCosDecoder::new(config);
        let mut last: Option<i32> = None;
        for (s, c) in codes {
            let r = dec.update(SinCosCodes { sin: AdcCode(s), cos: AdcCode(c) });
            if let Some(l) = last {
                prop_assert!(r.position.to_bits().wrapping_sub(l).unsigned_abs() < 1 << 19);
            }
            if !r.rejected || last.is_some() {
                last = Some(r.position.to_bits());
            }
            prop_assert!(r.amplitude_squared.is_finite());
        }
    }
}
