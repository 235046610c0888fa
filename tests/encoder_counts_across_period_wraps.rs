//! Period counting (`docs/faults.md` scenario 20): no jump at any period boundary — 10⁵ and more
//! boundary crossings, both ways, at random speeds and phases — and none where the position
//! counter itself wraps (after 2048 periods), through the decoder and the differentiator.

mod support;

use std::cell::Cell;

use fpc::sensing::differentiator::{SavitzkyGolay, SgConfig};
use fpc::sensing::encoder::{
    EncoderConfig, SinCosCalibration, SinCosDecoder, NOMINAL_AMPLITUDE_CODES,
};
use proptest::prelude::*;
use support::sensing::{encoder_codes, Rng};

const PERIOD_M: f64 = 0.024;

#[test]
fn no_jump_across_a_hundred_thousand_period_wraps() {
    let crossings = Cell::new(0u64);
    let worst = Cell::new(0.0f64);
    let config = EncoderConfig::reference();
    let m = f64::from(config.m_per_count());
    let cal = SinCosCalibration::ideal(NOMINAL_AMPLITUDE_CODES);
    let strategy = (
        any::<u64>(),
        // Vibration about a period boundary: amplitude (periods, 12–240 µm) and angular step
        // per sample as a fraction of the fastest that keeps the step-to-step change of
        // velocity ≤ 10 µm per sample (4000 m/s², five times the machine's).
        0.0005f64..0.01,
        0.2f64..1.0,
        -3.2f64..3.2,
        0usize..8,
    );
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig::with_cases(64));
    runner
        .run(&strategy, |(seed, amp, speed, phase, k)| {
            let mut rng = Rng::new(seed);
            let centre = (k as f64 + 1.0) * PERIOD_M;
            let amp_m = amp * PERIOD_M;
            let w = speed * (10e-6 / amp_m).sqrt();
            let mut dec = SinCosDecoder::new(config);
            let mut origin = None;
            let mut last_period = None;
            for i in 0..30_000 {
                let x = centre + amp_m * (w * i as f64 + phase).sin();
                let r = dec.update(encoder_codes(x, PERIOD_M, &cal, 0.42, &mut rng));
                prop_assert!(!r.rejected && !r.signal_fault, "rejected at {x}");
                let decoded = f64::from(r.position.to_bits()) * m;
                let o = *origin.get_or_insert(x - decoded);
                let err = (decoded + o - x).abs();
                worst.set(worst.get().max(err));
                prop_assert!(err < 10e-6, "error {err} m at sample {i}");
                let period = (x / PERIOD_M).floor();
                if last_period.is_some_and(|p| p != period) {
                    crossings.set(crossings.get() + 1);
                }
                last_period = Some(period);
            }
            Ok(())
        })
        .unwrap();
    println!(
        "{} period-boundary crossings, worst position error {:.2} µm",
        crossings.get(),
        worst.get() * 1e6
    );
    assert!(
        crossings.get() >= 100_000,
        "only {} crossings",
        crossings.get()
    );
}

#[test]
fn the_position_counter_wraps_without_a_jump_in_position_or_velocity() {
    // 4.5 m/s for 2100 periods: the i32 position (±2048 periods) wraps once.
    let config = EncoderConfig::reference();
    let m = f64::from(config.m_per_count());
    let cal = SinCosCalibration::ideal(NOMINAL_AMPLITUDE_CODES);
    let mut rng = Rng::new(9);
    let mut dec = SinCosDecoder::new(config);
    let mut sg = SavitzkyGolay::new(SgConfig {
        window: 25,
        order: 2,
        lag: 0,
        sample_time_s: 50e-6,
        m_per_count: config.m_per_count(),
    })
    .unwrap();
    let step_m = 4.5 * 50e-6;
    let samples = (2100.0 * PERIOD_M / step_m) as usize;
    let mut last = None;
    let mut wraps = 0;
    let mut worst_step = 0.0f64;
    let mut worst_v = 0.0f64;
    for i in 0..samples {
        let x = 0.001 + i as f64 * step_m;
        let r = dec.update(encoder_codes(x, PERIOD_M, &cal, 0.42, &mut rng));
        assert!(!r.rejected && !r.signal_fault);
        if let Some(l) = last {
            if r.position.to_bits() < l {
                wraps += 1;
            }
            let step = f64::from(r.position.to_bits().wrapping_sub(l)) * m;
            worst_step = worst_step.max((step - step_m).abs());
        }
        last = Some(r.position.to_bits());
        let d = sg.push(r.position);
        if i > 100 {
            worst_v = worst_v.max((f64::from(d.velocity_mps) - 4.5).abs());
        }
    }
    println!(
        "{samples} samples, {wraps} counter wraps: worst step error {:.2} µm, worst velocity \
         error {:.3} m/s",
        worst_step * 1e6,
        worst_v
    );
    assert_eq!(wraps, 1);
    assert!(worst_step < 10e-6);
    assert!(worst_v < 0.05);
}
