//! From the rig to the augmented model, with no hand edits: an effect hidden in the
//! simulated plant; the firmware's own tasks run the machine on the simulated board; a host
//! attached the way a probe attaches (the RTT control block found in the board's RAM, the
//! channels read and written there: `hal_sim::link::simprobe`) homes it, sets the telemetry,
//! declares the ports, starts it and arms the scope, all over the link; the telemetry capture
//! and the scope recording are decoded as `fpc-sim decode` decodes them; and `gap`, given the
//! model without the effect, names it within the field-log benchmark's tolerances (cogging
//! period ± 2 %, slave lag ± 0.05 ms), shrinks its channel, and — run again with the
//! augmented model it wrote — names nothing more. A null run (nothing hidden) names nothing.

mod support;

use fpc::link::telemetry::ChannelSet;
use hal_sim::board::capture::decode_capture;
use hal_sim::gap::{analyse, GapJson, GapOptions};
use hal_sim::runlog::RunLog;
use support::gap::*;
use support::rig::{bench, bench_with, Campaign};

fn gap_of(model: &str, log: &RunLog) -> (GapJson, String) {
    let out = analyse(model, log, &GapOptions::default())
        .unwrap_or_else(|f| panic!("gap failed: {}", f.message));
    (out.json, out.model_text)
}

/// `gap` with the model that lacks the effect names `effect` (alone), shrinks `channel` by
/// at least 70 %, and with the augmented model it wrote names nothing more. Returns the
/// first JSON and the augmented model.
fn names_it_and_closes_the_gap(
    model: &str,
    log: &RunLog,
    effect: &str,
    channel: &str,
) -> (GapJson, String) {
    let (j, augmented) = gap_of(model, log);
    show(effect, &j);
    assert_eq!(names(&j), [effect], "{:?}", j.effects);
    assert!(
        shrink(&j, channel) >= 0.70,
        "{channel} shrank {:.2}",
        shrink(&j, channel)
    );
    let (again, _) = gap_of(&augmented, log);
    show(&format!("{effect}, augmented model"), &again);
    assert!(again.effects.is_empty(), "{:?}", again.effects);
    (j, augmented)
}

/// The scope's recording matches the telemetry at the instants both have (the telemetry
/// carries the controller's own f32s; the scope its 16-bit codes, truncated: within one
/// unit): it recorded the cycles it says, at full rate.
fn scope_agrees_with_the_telemetry(scope: &RunLog, telemetry: &RunLog) {
    assert_eq!(scope.len(), fpc::link::scope::SCOPE_SAMPLES);
    assert_eq!(scope.meta("sample_rate_hz"), Some("20000"));
    let index = |log: &RunLog| -> std::collections::HashMap<i64, usize> {
        log.column("t_s")
            .unwrap()
            .iter()
            .enumerate()
            .map(|(i, t)| ((t * 1e6).round() as i64, i))
            .collect()
    };
    let at = index(telemetry);
    let mut compared = 0;
    for (k, t) in scope.column("t_s").unwrap().iter().enumerate() {
        let Some(&i) = at.get(&((t * 1e6).round() as i64)) else {
            continue;
        };
        let get = |log: &RunLog, c: &str, r: usize| log.column(c).unwrap()[r];
        assert_eq!(get(scope, "x_m", k), get(telemetry, "x_m", i), "x at {t}");
        for (c, tol) in [
            ("x_slave_m", 1.1e-7),
            ("f_master_n", 0.51),
            ("f_slave_n", 0.51),
            ("p_a_pa", 20.1),
            ("p_b_pa", 20.1),
            ("theta_rad", 1e-4),
        ] {
            let (a, b) = (get(scope, c, k), get(telemetry, c, i));
            assert!((a - b).abs() <= tol, "{c} at {t}: scope {a}, telemetry {b}");
        }
        compared += 1;
    }
    assert!(compared >= 20, "{compared} instants in common");
}

#[test]
fn cogging_hidden_in_the_plant_is_named_from_the_boards_capture_at_the_default_rate() {
    let c = bench(
        &cogging_truth(),
        14,
        fpc::link::telemetry::DEFAULT_DECIMATION,
        Campaign::Running {
            speed_mps: 2.3,
            seconds: 1.0,
        },
    );
    assert_eq!(c.decoded.log.meta("sample_rate_hz"), Some("2000"));
    let model = without_section(&reference(), "effects.cogging");
    let (j, _) = names_it_and_closes_the_gap(&model, &c.decoded.log, "cogging", "force");
    let period = param(&j, "cogging", "period_m");
    assert!((period - 0.024).abs() <= 0.02 * 0.024, "period {period}");
    assert_eq!(c.scope.len(), 1);
    assert_eq!(c.scope[0].meta("scope_trigger"), Some("strokes:4"));
    scope_agrees_with_the_telemetry(&c.scope[0], &c.decoded.log);
}

#[test]
fn a_slave_section_lag_is_named_within_0_05_ms_and_the_scope_shows_it_at_20_khz() {
    let truth = format!("{}\n[effects.slave_lag]\ndelay_s = 0.00075\n", reference());
    let c = bench(
        &truth,
        16,
        fpc::link::telemetry::DEFAULT_DECIMATION,
        Campaign::Running {
            speed_mps: 2.3,
            seconds: 1.0,
        },
    );
    let (j, augmented) =
        names_it_and_closes_the_gap(&reference(), &c.decoded.log, "slave_lag", "slave_force");
    let lag = param(&j, "slave_lag", "delay_s");
    assert!((lag - 0.75e-3).abs() <= 0.05e-3, "lag {lag}");
    // The augmented model's own run has the measured signature; the nominal model's has none.
    let run_lag = |text: &str| {
        let out = hal_sim::run::run(&hal_sim::run::RunOptions {
            model: hal_sim::plant::model::MachineModel::parse(text).unwrap(),
            cycles: 2,
            seed: 5,
            ..hal_sim::run::RunOptions::reference()
        })
        .unwrap();
        let col = |n: &str| out.log.column(n).unwrap();
        hal_sim::signal::xcorr_lag(col("f_master_n"), col("f_slave_n"), 50e-6, Some(60))
            .unwrap()
            .seconds
    };
    let (augmented_lag, nominal_lag) = (run_lag(&augmented), run_lag(&reference()));
    eprintln!(
        "slave force behind master in a run: augmented model {:.4} ms, nominal {:.4} ms",
        augmented_lag * 1e3,
        nominal_lag * 1e3
    );
    assert!((augmented_lag - 0.75e-3).abs() <= 0.05e-3);
    assert!(nominal_lag.abs() <= 0.05e-3);
    // The recording (25.6 ms around the fourth reversal, where the force turns fastest): the
    // slave force behind the master's by the paper's FFT method, at 50 µs resolution.
    let s = &c.scope[0];
    scope_agrees_with_the_telemetry(s, &c.decoded.log);
    let lag = hal_sim::signal::xcorr_lag(
        s.column("f_master_n").unwrap(),
        s.column("f_slave_n").unwrap(),
        50e-6,
        Some(60),
    )
    .unwrap();
    eprintln!(
        "scope: slave force behind master by {:.4} ms",
        lag.seconds * 1e3
    );
    assert!((lag.seconds - 0.75e-3).abs() <= 0.05e-3, "{lag:?}");
}

#[test]
fn a_leak_with_sealed_chambers_is_named_from_the_boards_closed_port_campaign() {
    let c = bench(
        &reference(),
        21,
        fpc::link::telemetry::DEFAULT_DECIMATION,
        Campaign::Sealed,
    );
    assert_eq!(c.decoded.log.meta("ports"), Some("closed"));
    assert!(c.decoded.log.meta("ports_from_s").is_some());
    let model = without_section(&reference(), "effects.leakage");
    let (j, _) = names_it_and_closes_the_gap(&model, &c.decoded.log, "leakage", "pressure");
    let gap_m = param(&j, "leakage", "gap_m");
    assert!((gap_m - 25e-6).abs() <= 0.05 * 25e-6, "gap {gap_m}");
    assert_eq!(c.scope[0].meta("ports"), Some("closed"));
    assert_eq!(c.scope[0].meta("scope_trigger"), Some("mode-change"));
    scope_agrees_with_the_telemetry(&c.scope[0], &c.decoded.log);
}

#[test]
fn nothing_hidden_nothing_named_running_or_sealed() {
    let running = bench(
        &reference(),
        31,
        fpc::link::telemetry::DEFAULT_DECIMATION,
        Campaign::Running {
            speed_mps: 2.3,
            seconds: 1.0,
        },
    );
    let (j, _) = gap_of(&reference(), &running.decoded.log);
    show("null, running", &j);
    assert!(j.effects.is_empty(), "{:?}", j.effects);
    let sealed = bench(
        &reference(),
        32,
        fpc::link::telemetry::DEFAULT_DECIMATION,
        Campaign::Sealed,
    );
    let (j, _) = gap_of(&reference(), &sealed.decoded.log);
    show("null, sealed", &j);
    assert!(j.effects.is_empty(), "{:?}", j.effects);
}

#[test]
fn a_probe_too_slow_for_the_rate_loses_frames_the_firmware_counts_and_the_log_stays_uniform() {
    // Every cycle (20 kHz, 58-byte frames: 1.16 MB/s) through a probe that carries 100 bytes
    // of the telemetry channel a millisecond (100 kB/s).
    let c = bench_with(
        &reference(),
        41,
        1,
        ChannelSet::ALL,
        Some(100),
        Campaign::Running {
            speed_mps: 2.3,
            seconds: 0.3,
        },
    );
    eprintln!("{}", c.counters);
    let d = &c.decoded;
    assert!(c.counters.firmware_dropped > 1000, "{}", c.counters);
    assert!(
        d.dropped > 1000 && d.gaps > 100 && d.left_out > 100,
        "{d:?}"
    );
    // What was kept is uniform: one frame every 50 µs, no gap inside.
    let t = d.log.column("t_s").unwrap();
    assert!(t.windows(2).all(|w| ((w[1] - w[0]) - 50e-6).abs() < 1e-9));
}

#[test]
fn a_capture_with_a_hole_or_cut_short_says_what_it_lost() {
    let c = bench(
        &reference(),
        42,
        fpc::link::telemetry::DEFAULT_DECIMATION,
        Campaign::Running {
            speed_mps: 2.3,
            seconds: 1.0,
        },
    );
    let whole = &c.decoded;
    // From power-on the frames say the ports are timed (the firmware's default) until the
    // host has declared the bypass: those two frames are left out, one break.
    assert_eq!((whole.gaps, whole.left_out), (1, 2));
    let frames = whole.log.len() + whole.left_out;
    let up1 = &c.raw[1];
    // A hole of 10 000 bytes (≈ 217 frames) at two thirds: the frame the hole cuts is
    // rejected, the log is the longer side, the rest counted as left out.
    let cut = 2 * up1.len() / 3;
    let mut holed = up1[..cut].to_vec();
    holed.extend_from_slice(&up1[cut + 10_000..]);
    let d = decode_capture(&holed, |_| {}).unwrap();
    assert_eq!(d.gaps, whole.gaps + 1);
    assert!(d.stats.rejected <= 1);
    assert_eq!(d.stats.accepted as usize, d.log.len() + d.left_out);
    let lost = frames - (d.log.len() + d.left_out);
    let frame = fpc::link::telemetry::DEFAULT_CHANNELS.wire_bytes();
    assert!(
        (10_000 / frame..=10_000 / frame + 2).contains(&lost),
        "{lost} frames lost"
    );
    assert!(d.log.len() >= d.left_out && d.left_out > 100, "{d:?}");
    // Cut short in the middle of a frame: that frame is never completed, the rest decodes.
    let short = decode_capture(&up1[..up1.len() - 30], |_| {}).unwrap();
    assert_eq!(short.log.len(), whole.log.len() - 1);
    assert_eq!((short.gaps, short.left_out), (whole.gaps, whole.left_out));
    // The scope recording on up 2, cut before its end: refused with what is missing.
    let up2 = &c.raw[2];
    assert_eq!(c.scope.len(), 1);
    let (recs, incomplete) = hal_sim::link::scope::decode_scope_capture(&up2[..up2.len() - 600]);
    assert!(
        recs.is_empty() && incomplete[0].contains("missing"),
        "{incomplete:?}"
    );
}
