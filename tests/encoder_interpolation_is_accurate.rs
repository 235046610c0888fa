//! Sin/cos interpolation over a full stroke: after calibrating a distorted encoder (5 % gain
//! mismatch, 2 % offsets, 3° quadrature error) from a slow traverse, the position is within
//! 10 µm everywhere; and what 1 mV of signal noise costs.

mod support;

use fpc::sensing::encoder::{
    EncoderConfig, SinCosCalibration, SinCosDecoder, CODES_PER_MV, NOMINAL_AMPLITUDE_CODES,
};
use support::sensing::{distorted_encoder, encoder_codes, Rng};

const PERIOD_M: f64 = 0.024;
/// The encoder's own noise (`docs/machine.md`: σ ≈ 1 µm after interpolation) in codes RMS per
/// channel: 1 µm·2π/λ·A.
const NOISE_1UM_CODES: f64 = 1e-6 * std::f64::consts::TAU / PERIOD_M * 1600.0;

/// Decodes a 0.2 m stroke (1 mm → 201 mm, 50 µm per sample) and returns the position errors,
/// m, against the truth (the first sample fixes the whole-period offset).
fn stroke_errors(config: EncoderConfig, truth: &SinCosCalibration, noise: f64) -> Vec<f64> {
    let mut rng = Rng::new(11);
    let mut dec = SinCosDecoder::new(config);
    let m = f64::from(config.m_per_count());
    let x0 = 0.001;
    let mut errors = Vec::new();
    for i in 0..=4000 {
        let x = x0 + i as f64 * 50e-6;
        let r = dec.update(encoder_codes(x, PERIOD_M, truth, noise, &mut rng));
        assert!(!r.signal_fault, "signal fault at x = {x}");
        // The decoder starts at the fraction of a period the first sample shows: x0 < λ.
        errors.push(f64::from(r.position.to_bits()) * m - x);
    }
    errors
}

fn calibrate(truth: &SinCosCalibration, noise: f64) -> SinCosCalibration {
    // A slow traverse over 1.5 periods at uneven speed (the creep of a commissioning move).
    let mut rng = Rng::new(5);
    let samples: Vec<_> = (0..6000)
        .map(|i| {
            let u = i as f64 / 6000.0;
            let x = 0.003 + 1.5 * PERIOD_M * (u + 0.1 * (7.0 * u).sin());
            encoder_codes(x, PERIOD_M, truth, noise, &mut rng)
        })
        .collect();
    SinCosCalibration::from_traverse(samples).expect("calibration traverse")
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, e| m.max(e.abs()))
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt()
}

#[test]
fn after_calibration_the_stroke_is_interpolated_within_10_um() {
    let truth = distorted_encoder();
    let fit = calibrate(&truth, NOISE_1UM_CODES);
    let calibrated = EncoderConfig {
        calibration: fit,
        ..EncoderConfig::reference()
    };
    let after = stroke_errors(calibrated, &truth, NOISE_1UM_CODES);
    let before = stroke_errors(EncoderConfig::reference(), &truth, NOISE_1UM_CODES);
    let ideal_after = stroke_errors(calibrated, &truth, 0.0);
    println!(
        "fitted {fit:?}\n\
         stroke error, 1 µm encoder noise: uncalibrated max {:.1} µm; calibrated max {:.2} µm, \
         RMS {:.2} µm; calibrated without noise max {:.2} µm",
        max_abs(&before) * 1e6,
        max_abs(&after) * 1e6,
        rms(&after) * 1e6,
        max_abs(&ideal_after) * 1e6,
    );
    assert!(max_abs(&before) > 50e-6, "the distortion should matter");
    assert!(max_abs(&after) <= 10e-6);
    assert!(max_abs(&ideal_after) <= 3e-6);
}

#[test]
fn noise_of_1_mv_costs_what_the_physics_says() {
    // 1 mV RMS per channel = 3.2 codes. Position noise of an ideal decoder: σ/A·λ/2π.
    let noise = CODES_PER_MV as f64;
    let theory_m = noise / f64::from(NOMINAL_AMPLITUDE_CODES) * PERIOD_M / std::f64::consts::TAU;
    // At this noise the steps are σ·√6 ≈ 19 µm RMS apart from constant velocity: the glitch
    // gate is widened to 8σ of that so that the figure is the decoder's, not the gate's.
    let config = EncoderConfig {
        glitch_gate_periods: 8.0 * theory_m as f32 * 6f32.sqrt() / PERIOD_M as f32,
        ..EncoderConfig::reference()
    };
    let mut rng = Rng::new(3);
    let mut dev = Vec::new();
    let mut added = Vec::new();
    let m = f64::from(config.m_per_count());
    let cal = SinCosCalibration::ideal(NOMINAL_AMPLITUDE_CODES);
    // Hold still at 64 positions across a period, 500 samples each.
    for k in 0..64 {
        let x = 0.05 + k as f64 / 64.0 * PERIOD_M;
        let mut dec = SinCosDecoder::new(config);
        let first = dec.update(encoder_codes(x, PERIOD_M, &cal, 0.0, &mut rng));
        let centre = f64::from(first.position.to_bits()) * m;
        for _ in 0..500 {
            let codes = encoder_codes(x, PERIOD_M, &cal, noise, &mut rng);
            let r = dec.update(codes);
            assert!(!r.signal_fault);
            let got = f64::from(r.position.to_bits()) * m;
            dev.push(got - centre);
            // The ideal decode of the same codes, f64 atan2: what the decoder itself adds.
            let s = f64::from(codes.sin.centered());
            let c = f64::from(codes.cos.centered());
            let mut ideal = s.atan2(c) / std::f64::consts::TAU * PERIOD_M;
            let base = centre - centre.rem_euclid(PERIOD_M);
            ideal += base;
            while ideal - got > PERIOD_M / 2.0 {
                ideal -= PERIOD_M;
            }
            while got - ideal > PERIOD_M / 2.0 {
                ideal += PERIOD_M;
            }
            added.push(got - ideal);
        }
    }
    let measured = rms(&dev);
    let own = rms(&added);
    // 1 µm RMS of position noise takes 0.13 mV RMS of signal noise in this scaling.
    let mv_for_1um = 1e-6 / theory_m;
    println!(
        "1 mV RMS = {CODES_PER_MV} codes: position noise {:.2} µm RMS (theory {:.2} µm); \
         the decoder itself adds {:.3} µm RMS; 1 µm RMS needs ≤ {:.2} mV RMS",
        measured * 1e6,
        theory_m * 1e6,
        own * 1e6,
        mv_for_1um
    );
    assert!((measured / theory_m - 1.0).abs() < 0.1);
    assert!(own < 0.1e-6);
}
