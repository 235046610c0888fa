//! The encoder-difference map of the paper's §4.2 (Fig. 6) as a firmware calibration routine,
//! on the paper rig's encoders (`docs/studies/paper-rig.toml`: the slave encoder reads a saw
//! of the declared 0.1 mm stepping once a magnetic pitch, 0.05 mm more moving toward head B).
//! The routine (`Calibrate EncoderMap`) maps the difference on slow sweeps; with the map
//! loaded, the slave's reading differs from the master's by at most 10 % of what it did
//! (RMS), moving either way, on strokes at three speeds well above the sweeps'.

mod support;

use fpc::control::calibration::Routine;
use hal_sim::plant::model::MachineModel;
use support::drive::*;

const PAPER_RIG: &str = include_str!("../docs/studies/paper-rig.toml");

/// Stroke speeds the correction is judged at, m/s (the map's sweeps run at 0.1 and 0.4).
const SPEEDS: [f32; 3] = [1.0, 2.3, 4.1];

/// RMS of the slave − master reading on strokes at `speed`, moving toward +x and toward −x
/// (samples faster than 0.1 m/s), m.
fn difference_rms(bench: &mut Bench, speed: f32) -> [f64; 2] {
    let mut sums = [(0.0f64, 0u32); 2];
    bench.strokes(3.1, speed, 6, |_, s| {
        let v = f64::from(s.velocity_mps);
        if v.abs() > 0.1 {
            let d = f64::from(s.slave_position_m - s.position_m);
            let k = usize::from(v < 0.0);
            sums[k].0 += d * d;
            sums[k].1 += 1;
        }
    });
    sums.map(|(s, n)| (s / f64::from(n.max(1))).sqrt())
}

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
    let before: Vec<[f64; 2]> = SPEEDS
        .iter()
        .map(|&v| difference_rms(&mut bench, v))
        .collect();

    // Mapped as on a commissioning: homed first (the sweeps start from the park position).
    bench.home();
    let found = calibrate(&mut bench, Routine::EncoderMap);
    let map = found.encoder_map.expect("the encoder map");
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

    for (speed, before) in SPEEDS.iter().zip(&before) {
        let after = difference_rms(&mut bench, *speed);
        for (k, way) in ["toward +x", "toward −x"].iter().enumerate() {
            let ratio = after[k] / before[k];
            println!(
                "{speed} m/s {way}: slave − master {:.1} µm RMS before, {:.2} µm after ({:.1} %)",
                before[k] * 1e6,
                after[k] * 1e6,
                100.0 * ratio
            );
            assert!(ratio <= 0.10, "{speed} m/s {way}: {:.1} %", 100.0 * ratio);
        }
    }
}
