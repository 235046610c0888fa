//! The calibration routines, run by the firmware's control step on the simulated machine
//! whose unknowns are set (`support::drive::machine_with_unknowns`: the slave's magnets 1.5 mm
//! off, offsets on five of six phase-current sensors, the cogging's phase), find those
//! unknowns within stated tolerances, and loading what they found makes the machine do what
//! it believes it does.
//!
//! Commissioning order, as on a new machine: current-sense offsets (outputs off), alignment
//! (before homing: the motor must push right to home), homing, misalignment, cogging.

mod support;

use fpc::control::calibration::{Calibrated, Routine};
use fpc::units::Section;
use hal_sim::plant::model::MachineModel;
use support::drive::*;

/// Current-sense codes per ampere (the reference sense: ±100 A over 12 bits).
const CODES_PER_A: f64 = 2048.0 / 100.0;

/// Strokes at 4.1 m/s against PR 5.1 with the parameters of `loaded`: (RMS of the true force
/// minus the force the firmware believes (its measured q-current × K_f), master and slave, N;
/// RMS of the true master − slave force difference, % of the RMS section force).
fn stroke_figures(model: &MachineModel, loaded: &Calibrated) -> ([f64; 2], f64) {
    let mut config = uncalibrated_config(model);
    loaded.apply(&mut config);
    let mut bench = Bench::new(model, config, 7, 0.05);
    bench.home();
    let (mut belief, mut diff, mut force, mut n) = ([0.0f64; 2], 0.0, 0.0, 0.0);
    bench.strokes(5.1, 4.1, 4, |w, s| {
        let (m, sl) = (w.plant.force_n.master, w.plant.force_n.slave);
        belief[0] += (m - f64::from(s.force_master_n)).powi(2);
        belief[1] += (sl - f64::from(s.force_slave_n)).powi(2);
        diff += (m - sl).powi(2);
        force += (0.5 * (m + sl)).powi(2);
        n += 1.0;
    });
    (
        belief.map(|b| (b / n).sqrt()),
        (diff / force).sqrt() * 100.0,
    )
}

#[test]
fn commissioning_finds_every_unknown_and_each_result_improves_the_machine() {
    let model = machine_with_unknowns();
    println!("commissioning the machine with unknowns:");
    let (bench, found) = commission(&model, 5);

    // Current-sense offsets: within 0.5 code (25 mA) of the sensors' true offsets.
    let sense = found.current_sense.expect("current-sense offsets");
    for (section, truth_a) in Section::ALL.iter().zip(CURRENT_OFFSETS_A) {
        for (got, want_a) in sense.get(*section).iter().zip(truth_a) {
            let want = want_a * CODES_PER_A;
            println!(
                "  {section:?} phase offset: found {got:7.3} codes, true {want:7.3} codes ({:+.3})",
                f64::from(*got) - want
            );
            assert!((f64::from(*got) - want).abs() <= 0.5);
        }
    }

    // Alignment: each section's electrical-angle offset within 1° (67 µm) of the truth
    // (master 0, its encoder sits on its magnets; slave −360°·D/λ).
    let slave_truth_deg = -MISALIGNMENT_M / 0.024 * 360.0;
    let aligned = found.alignment.expect("alignment");
    let (m_deg, s_deg) = (degrees(aligned.master), degrees(aligned.slave));
    println!(
        "  alignment: master {m_deg:+.3}° (true 0°), slave {s_deg:+.3}° (true {slave_truth_deg:+.3}°)"
    );
    assert!(m_deg.abs() <= 1.0);
    assert!((s_deg - slave_truth_deg).abs() <= 1.0);

    // Misalignment after alignment: D_dif within 20 µm, the slave's offset within 0.3°, the
    // encoders' offset (none in this plant) within 5 µm.
    let mis = found.misalignment.expect("misalignment");
    let slave_deg = degrees(mis.slave_angle_offset);
    println!(
        "  misalignment: D_dif {:.4} mm (true {:.4} mm), correction {:+.3}°, slave offset {slave_deg:+.3}°, \
         encoder offset {:+.2} µm",
        mis.misalignment_m * 1e3,
        MISALIGNMENT_M * 1e3,
        f64::from(mis.correction_periods) * 360.0,
        mis.encoder_offset_m * 1e6
    );
    assert!((f64::from(mis.misalignment_m) - MISALIGNMENT_M).abs() <= 20e-6);
    assert!((slave_deg - slave_truth_deg).abs() <= 0.3);
    assert!(mis.encoder_offset_m.abs() <= 5e-6);

    // Cogging: the fundamental within 5 % in amplitude and 3° in phase of the plant's law in
    // the homed frame; the higher harmonics (absent in the plant) below 1 N.
    let map = found.cogging.expect("cogging map");
    let cog = model
        .effects
        .cogging
        .as_ref()
        .expect("cogging in the model");
    let x_shift = bench.world().plant.x_m - f64::from(bench.status().position_m);
    let phase_truth = cog.phase_rad + std::f64::consts::TAU * x_shift / cog.period_m;
    let (a, b) = (f64::from(map.sin_n[0]), f64::from(map.cos_n[0]));
    let (amplitude, phase) = (a.hypot(b), b.atan2(a));
    let phase_err_deg = (phase - phase_truth).to_degrees();
    println!(
        "  cogging: {amplitude:.2} N at {:.2}° (true {:.2} N at {:.2}°), harmonics 2–4 {:.2?} / {:.2?} N",
        phase.to_degrees(),
        cog.amplitude_n,
        phase_truth.to_degrees(),
        &map.sin_n[1..],
        &map.cos_n[1..]
    );
    assert!((amplitude - cog.amplitude_n).abs() <= 0.05 * cog.amplitude_n);
    assert!(phase_err_deg.abs() <= 3.0);
    assert!(map.sin_n[1..]
        .iter()
        .chain(&map.cos_n[1..])
        .all(|c| c.abs() < 1.0));

    // What each result is worth, loaded one after the other (4.1 m/s strokes at PR 5.1).
    println!("  strokes at 4.1 m/s, PR 5.1, with the results loaded in turn:");
    let mut loaded = Calibrated::default();
    let mut figures = Vec::new();
    for stage in [
        "nothing",
        "current sense",
        "alignment",
        "misalignment",
        "cogging",
    ] {
        match stage {
            "current sense" => loaded.current_sense = found.current_sense,
            "alignment" => loaded.alignment = found.alignment,
            "misalignment" => loaded.misalignment = found.misalignment,
            "cogging" => loaded.cogging = found.cogging,
            _ => {}
        }
        let (belief, diff) = stroke_figures(&model, &loaded);
        println!(
            "    + {stage:13}: true − believed force {:5.1} N master, {:5.1} N slave RMS; \
             master − slave {diff:5.2} % RMS",
            belief[0], belief[1]
        );
        figures.push((belief, diff));
    }
    let (before, after) = (figures[0], figures[4]);
    // The offsets make each section's force differ from what the firmware measures (what
    // remains, ≈ 12 N, is the sensors' 0.1 A of noise); the misaligned slave pushes
    // 1 − cos 22.5° = 7.6 % less than the master.
    assert!(figures[1].0[0] < 0.35 * before.0[0], "current sense");
    assert!(after.0[1] < 0.2 * before.0[1], "slave belief");
    assert!(figures[2].1 < 0.2 * figures[1].1, "alignment");
    assert!(after.1 <= 1.0);
}

#[test]
fn the_misalignment_routine_alone_finds_the_slaves_frame() {
    // Without the alignment routine (both offsets at zero), the master holding the position
    // is the force sensor: the slave's d-current of ±15 A shows its frame error of 22.5°.
    let model = machine_with_unknowns();
    let mut bench = Bench::new(&model, uncalibrated_config(&model), 9, 0.05);
    calibrate(&mut bench, Routine::CurrentSense);
    bench.home();
    let found = calibrate(&mut bench, Routine::Misalignment);
    let mis = found.misalignment.expect("misalignment");
    let truth_deg = -MISALIGNMENT_M / 0.024 * 360.0;
    println!(
        "misalignment from unaligned frames: correction {:+.3}° (true {truth_deg:+.3}°), D_dif {:.4} mm",
        f64::from(mis.correction_periods) * 360.0,
        mis.misalignment_m * 1e3
    );
    assert!((f64::from(mis.correction_periods) * 360.0 - truth_deg).abs() <= 0.5);
    assert!((f64::from(mis.misalignment_m) - MISALIGNMENT_M).abs() <= 35e-6);
    assert_eq!(
        bench.step.config().angle_offset.slave,
        mis.slave_angle_offset,
        "loaded"
    );
}
