//! The encoder-difference map of the paper's §4.2 (Fig. 6) as a firmware calibration routine,
//! on the paper rig's encoders (`docs/studies/paper-rig.toml`: the slave encoder reads a saw
//! of the declared 0.1 mm stepping once a magnetic pitch, 0.05 mm more moving toward head B).
//! The routine (`Calibrate EncoderMap`) maps the difference on slow sweeps; with the map
//! loaded, the slave's reading differs from the master's by at most 10 % of what it did
//! (RMS), moving either way, on strokes at three speeds well above the sweeps': on the
//! machine that has just mapped (the slave decoder's glitch gate widened as the routine
//! ends, its position running on) and with the map given at start-up, when the decoders are
//! built. (The map is not part of the flash record: it is mapped again after a power cut.)

mod support;

use fpc::control::calibration::Routine;
use hal_sim::plant::chambers::PortMode;
use hal_sim::plant::model::MachineModel;
use support::drive::*;

const PAPER_RIG: &str = include_str!("../docs/studies/paper-rig.toml");

/// Stroke speeds the correction is judged at, m/s (the map's sweeps run at 0.1 and 0.4).
const SPEEDS: [f32; 3] = [1.0, 2.3, 4.1];

/// Half-width of the band around the saw's step where the slave's decoder is still catching
/// up with the step, m: the 0.1 mm step exceeds the decoder's 50 µm glitch gate, so it is
/// extrapolated over and re-locked a cycle or two later (50 µs each, ≤ 0.2 mm at 4.1 m/s).
const STEP_BAND_M: f64 = 0.25e-3;

/// One direction's slave − master reading: (mean, RMS about the mean, RMS about the mean
/// of the samples more than [`STEP_BAND_M`] from the step, share of samples within it), m.
type Spread = (f64, f64, f64, f64);

/// The slave − master reading on strokes at `speed`, moving toward +x and toward −x
/// (samples faster than 0.1 m/s). The mean is the encoders' offset as homing left it; the
/// RMS about it is the pattern the map is for. `step_phase` places the step (fraction of a
/// period from the homed zero); `None` before there is a map: every sample counts as away.
fn difference(bench: &mut Bench, speed: f32, step_phase: Option<f64>) -> [Spread; 2] {
    let mut all = [(0.0f64, 0.0f64, 0u32); 2];
    let mut away = [(0.0f64, 0.0f64, 0u32); 2];
    bench.strokes(3.1, speed, 6, |_, s| {
        let v = f64::from(s.velocity_mps);
        if v.abs() > 0.1 {
            let d = f64::from(s.slave_position_m - s.position_m);
            let k = usize::from(v < 0.0);
            all[k].0 += d;
            all[k].1 += d * d;
            all[k].2 += 1;
            let near = step_phase.is_some_and(|u0| {
                let u = f64::from(s.position_m) / PERIOD_M - u0;
                (u - u.round()).abs() * PERIOD_M < STEP_BAND_M
            });
            if !near {
                away[k].0 += d;
                away[k].1 += d * d;
                away[k].2 += 1;
            }
        }
    });
    let spread = |(s, q, n): (f64, f64, u32)| {
        let n = f64::from(n.max(1));
        let mean = s / n;
        (mean, (q / n - mean * mean).max(0.0).sqrt())
    };
    [0, 1].map(|k| {
        let (mean, rms) = spread(all[k]);
        let (_, rms_away) = spread(away[k]);
        let near = 1.0 - f64::from(away[k].2) / f64::from(all[k].2.max(1));
        (mean, rms, rms_away, near)
    })
}

/// The encoders' period, m.
const PERIOD_M: f64 = 0.024;

#[test]
fn the_mapped_slave_reading_differs_from_the_masters_by_a_tenth_of_what_it_did() {
    let model = MachineModel::parse(PAPER_RIG).expect("the paper rig's model");
    let truth = model
        .effects
        .encoder_pitch_error
        .clone()
        .expect("its pitch error");
    let mut bench = Bench::new(&model, hal_sim::run::control_config(&model), 11, 0.05);
    bench.home();
    let before: Vec<[Spread; 2]> = SPEEDS
        .iter()
        .map(|&v| difference(&mut bench, v, None))
        .collect();

    // Mapped as on a commissioning, on a machine fresh from power-up: the start-up bypass
    // open (the rotation is not driven during a routine), homed first (the sweeps start
    // from the park position).
    let mut mapping = Bench::new(&model, hal_sim::run::control_config(&model), 11, 0.05);
    mapping.world_mut().plant.port_mode = PortMode::Unloaded;
    mapping.home();
    calibrate(&mut mapping, Routine::EncoderMap);
    let map = mapping.step.config().encoder_map.expect("the encoder map");
    println!(
        "map: saw {:.1} µm stepping at {:.3} of the period, toward +x {:+.1} µm, toward −x \
         {:+.1} µm, velocity coefficient {:+.2} µm per m/s, fit residual {:.2} µm",
        map.saw_m * 1e6,
        map.step_phase,
        map.toward_plus_m * 1e6,
        map.toward_minus_m * 1e6,
        map.velocity_s * 1e6,
        map.residual_m * 1e6
    );
    // What the routine found, against the plant's truth: the saw's height and the direction
    // part (the plant has no velocity skew between the encoders).
    assert!(
        (f64::from(map.saw_m).abs() - truth.step_m).abs() < 0.1 * truth.step_m,
        "saw {} m",
        map.saw_m
    );
    let direction = f64::from(map.toward_plus_m - map.toward_minus_m);
    assert!(
        (direction - truth.direction_m).abs() < 0.2 * truth.direction_m,
        "{direction} m"
    );
    assert!(map.velocity_s.abs() < 2e-6, "{} s", map.velocity_s);

    // Judged twice: on the machine that has just run the routine (homed again with the
    // ports timed), and with the map loaded as a commissioned machine loads its calibration
    // at start-up.
    mapping.world_mut().plant.port_mode = PortMode::Timed;
    mapping.home();
    let mut config = hal_sim::run::control_config(&model);
    config.encoder_map = Some(map);
    let mut loaded = Bench::new(&model, config, 11, 0.05);
    loaded.home();
    for (machine, mapped) in [
        ("loaded at start-up", &mut loaded),
        ("just mapped", &mut mapping),
    ] {
        judge(machine, mapped, &before, &map);
    }
}

/// The slave − master pattern left on `mapped` at the three speeds, against `before`:
/// ≤ 10 % of it, both directions, and the directions' means together.
fn judge(
    machine: &str,
    mapped: &mut Bench,
    before: &[[Spread; 2]],
    map: &fpc::control::calibration::EncoderMap,
) {
    println!("{machine}:");
    let mut worst: f64 = 0.0;
    let mut worst_away: f64 = 0.0;
    for (speed, before) in SPEEDS.iter().zip(before) {
        let after = difference(mapped, *speed, Some(f64::from(map.step_phase)));
        for (k, way) in ["toward +x", "toward −x"].iter().enumerate() {
            let ratio = after[k].1 / before[k].1;
            let ratio_away = after[k].2 / before[k].1;
            worst = worst.max(ratio);
            worst_away = worst_away.max(ratio_away);
            println!(
                "{speed} m/s {way}: slave − master {:+.1} µm ± {:.1} µm RMS before, \
                 {:+.1} µm ± {:.2} µm after ({:.1} % of the pattern left; {:.1} % more than \
                 {:.2} mm from the step, {:.2} % of the samples within it)",
                before[k].0 * 1e6,
                before[k].1 * 1e6,
                after[k].0 * 1e6,
                after[k].1 * 1e6,
                100.0 * ratio,
                100.0 * ratio_away,
                STEP_BAND_M * 1e3,
                100.0 * after[k].3
            );
        }
        // The direction part is gone: the two directions' means within 10 µm of each other
        // (measured 0.4–2.8 µm; 50 µm before).
        let split = (after[0].0 - after[1].0).abs();
        assert!(
            split < 10e-6,
            "{speed} m/s: directions {:.1} µm apart",
            split * 1e6
        );
    }
    // ≤ 10 % of the pattern left, both directions, three speeds (measured 5.9–7.0 % just
    // mapped, 5.8–9.7 % given at start-up: what is left is the encoders' noise, ≈ 2 µm RMS).
    // It needs the slave decoder's glitch gate widened by the map's step
    // (`encoder_map::slave_encoder`, and `set_glitch_gate` as the routine ends): with the
    // plain 50 µm gate the decoder extrapolates over the scale's 0.1 mm step and re-locks a
    // cycle or two later, leaving those samples a whole step wrong (measured 13.6–25.5 % on
    // the machine that had just mapped). Away from the step alone (beyond ±0.25 mm)
    // 5.5–6.7 %.
    assert!(
        worst_away <= 0.10,
        "{machine}: {:.1} % of the pattern left away from the step",
        100.0 * worst_away
    );
    assert!(
        worst <= 0.10,
        "{machine}: {:.1} % of the pattern left",
        100.0 * worst
    );
}
