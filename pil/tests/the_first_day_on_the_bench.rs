//! The first day on the bench (`docs/bring-up.md`, issue #41) on the release ELF: the board
//! boots with nothing connected and waits safely; the host link never halts a running
//! machine; a debugger that does halt it in motion is caught on resume and the piston
//! stopped.
//!
//! The ELF is `FPC_ELF` if set, else the `cargo fw` output; build it first (CI does).

use std::path::PathBuf;

use fpc_pil::chip::ChipOptions;
use fpc_pil::elf::Image;
use fpc_pil::run::{run, PilOptions};
use hal_sim::run::RunOptions;

fn image() -> Image {
    let path = std::env::var_os("FPC_ELF")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../target/thumbv7em-none-eabihf/release/fpc")
        });
    Image::read(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// PB5 low, the encoder inputs flat and the pressure inputs at 0 V for 2 s after power-on:
/// no gate input is ever high (judged each period from TIM1/TIM8's output stage: MOE, OSSI,
/// OSSR, OISx/OISxN, CCxE/CCxNE, the compare mode and value), the servo command stays at
/// zero torque, nothing latches, the four absent parts are reported (telemetry and defmt)
/// and `ClearFaults`, `Calibrate` and `Home` are answered with the reason. Then the link
/// comes up and the sensors are plugged in, in the same run: `Calibrate current_sense`,
/// `Home` and `Start` succeed and the main scenario's figures hold. On the firmware before
/// this (main at 3b6fed0) the low sides were on from ≈ 2 ms (`supply_loss` and
/// `encoder_signal` latched, their brake's zero duties with MOE set).
#[test]
fn a_bare_board_waits_with_every_gate_off_then_runs_the_main_scenario_once_connected() {
    let opts = PilOptions {
        image: image(),
        run: RunOptions::reference(),
        chip: ChipOptions::default(),
        compare_with_host: false,
        profile: false,
        bare_bench_s: Some(2.0),
    };
    let out = run(&opts, None).unwrap_or_else(|e| panic!("{e}"));
    let b = out.bare_bench.as_ref().expect("no bare-bench report");
    println!(
        "bare bench: {} periods over {} s, {} with a gate on (first {:?}), {} with servo torque; \
         faults {:?}; absent {:?}",
        b.periods,
        b.seconds,
        b.gate_on_periods,
        b.first_gate_on,
        b.servo_torque_periods,
        b.faults,
        b.absent
    );
    for l in &b.waiting_lines {
        println!("  log: {l}");
    }
    for a in &b.answers {
        println!("  answer: {a}");
    }
    println!("  then: {:?}", b.calibrate_after);
    assert!(b.periods >= 39_000, "{} periods", b.periods);
    assert_eq!(b.gate_on_periods, 0, "first gate on: {:?}", b.first_gate_on);
    assert_eq!(b.servo_torque_periods, 0);
    assert!(b.faults.is_empty(), "{:?}", b.faults);
    let parts = [
        "dc_link_off",
        "master_encoder_absent",
        "slave_encoder_absent",
        "pressure_sensors_absent",
    ];
    assert_eq!(b.absent, parts);
    for p in parts {
        assert!(
            b.waiting_lines.iter().any(|l| l.contains(p)),
            "{p} not logged: {:?}",
            b.waiting_lines
        );
    }
    let reason = "waiting for the DC link (power good low since reset)";
    for c in ["clear-faults", "calibrate current-sense", "home"] {
        assert!(
            b.answers
                .iter()
                .any(|a| a.starts_with(&format!("refused: {c}: {reason}"))),
            "{c}: {:?}",
            b.answers
        );
    }
    assert!(
        b.calibrate_after
            .as_deref()
            .is_some_and(|a| a.starts_with("accepted")),
        "{:?}",
        b.calibrate_after
    );
    // docs/bring-up.md §0 prints exactly these lines.
    let doc = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/bring-up.md"),
    )
    .expect("docs/bring-up.md");
    let section = doc
        .split("## 0. Nothing connected")
        .nth(1)
        .and_then(|s| s.split("## 1.").next())
        .expect("bring-up.md has no section 0");
    let block = section
        .split("```console")
        .nth(1)
        .and_then(|s| s.split("```").next())
        .expect("section 0 has no console block");
    let printed: Vec<&str> = block
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('$'))
        .collect();
    assert_eq!(printed.len(), 4, "{printed:?}");
    for line in printed {
        assert!(
            line == b.status_line || b.answers.iter().any(|a| a == line),
            "docs/bring-up.md §0 prints `{line}`; the firmware: {:?} / {:?}",
            b.status_line,
            b.answers
        );
    }
    let s = &out.summary;
    println!(
        "then the main scenario: {} cycles, faults {:?}, clearance {:?} m, dead point {:?} m, \
         discharge opening {:?}, worst period {:.1} µs",
        s.run.cycles,
        s.run.faults,
        s.run.min_head_clearance_m,
        s.run.dead_point_error_m,
        s.run.discharge_open_pressure_error,
        s.worst_cycle_us
    );
    assert_eq!(s.run.cycles, 10, "stopped early: {:?}", s.run.stopped_early);
    assert!(s.run.faults.is_empty(), "faults: {:?}", s.run.faults);
    assert!(s.run.min_head_clearance_m.expect("clearance") >= 0.6e-3);
    assert!(s.run.dead_point_error_m.expect("dead point") <= 0.1e-3);
    assert!(s.run.discharge_open_pressure_error.expect("opening").abs() <= 0.02);
    assert!(s.worst_cycle_us <= 50.0, "{:.1} µs", s.worst_cycle_us);
}

/// A 10 s capture on a running machine through the host link's own transport
/// (`hal_sim::link::debugport::NonHalting` over the emulated debug port's memory access
/// port, the RTT channels read and written as `fpc-sim link capture` does): the core is
/// never halted (the emulator counts halts and every DHCSR/DEMCR access through the debug
/// port: all 0) and the strokes go on. The witness: probe-rs 0.32's `Session` replayed on
/// the same port (its attach and detach) halts the core, and the firmware stops the machine.
#[test]
fn a_10_s_capture_through_the_debug_port_never_halts_the_core_and_the_strokes_go_on() {
    use fpc_pil::dap::{probe_rs_session_attach, probe_rs_session_detach};
    use fpc_pil::link::{capture, CaptureOptions};

    let report = capture(&image(), &CaptureOptions::default()).unwrap_or_else(|e| panic!("{e}"));
    println!("{report:#?}");
    assert!(report.capture_s >= 10.0);
    assert_eq!(report.halts, 0);
    assert_eq!(
        (
            report.dhcsr_reads,
            report.dhcsr_writes,
            report.demcr_reads,
            report.demcr_writes
        ),
        (0, 0, 0, 0)
    );
    assert!(report.faults.is_empty(), "{:?}", report.faults);
    // ≈ 2 kHz telemetry, none lost between the firmware and the host.
    assert!(report.frames >= 19_000, "{} frames", report.frames);
    assert_eq!(report.gaps, 0);
    // One cycle ≈ 0.44 s at the reference pressure ratio: ≈ 22 dead points at head A.
    assert!(
        report.dead_points >= 20,
        "{} dead points in 10 s",
        report.dead_points
    );
    assert!(report.min_clearance_m >= 0.3e-3);

    // The witness: the same scenario, probe-rs's session attached and dropped mid-capture.
    let opts = CaptureOptions {
        capture_s: 1.0,
        halting_session: Some((probe_rs_session_attach, probe_rs_session_detach)),
        ..CaptureOptions::default()
    };
    let witness = capture(&image(), &opts).unwrap_or_else(|e| panic!("{e}"));
    println!("{witness:#?}");
    assert!(witness.halts >= 2, "{} halts", witness.halts);
    assert!(witness.dhcsr_writes > 0);
    assert!(!witness.faults.is_empty(), "the halts went unnoticed");
}

/// A debugger halts the core in motion for 1, 5 and 20 ms at 24 phases of the stroke
/// cycle, DBGMCU freezing TIM1/TIM8 (outputs idle) and the IWDG as the firmware sets it,
/// TIM2 running on: on resume the firmware finds the gap, reports the stop (`deadline` up to
/// 2 ms, `core_halted` beyond: the encoders moved unseen) and brakes; the piston keeps
/// 0.3 mm from the heads in every case and is at rest at the end.
#[test]
fn a_debug_halt_in_motion_at_24_phases_is_caught_on_resume_and_keeps_the_head_clearance() {
    use fpc_pil::halt::halts_over_a_cycle;
    let image = image();
    let pr = RunOptions::reference().pressure_ratio;
    let durations = [1e-3, 5e-3, 20e-3];
    let started = std::time::Instant::now();
    let cases: Vec<_> = std::thread::scope(|scope| {
        let halves: Vec<_> = [0..12, 12..24]
            .into_iter()
            .map(|phases| {
                let image = &image;
                scope.spawn(move || halts_over_a_cycle(image, pr, phases, 24, &durations))
            })
            .collect();
        halves
            .into_iter()
            .flat_map(|h| h.join().expect("thread").unwrap_or_else(|e| panic!("{e}")))
            .collect()
    });
    let mut worst = f64::INFINITY;
    for c in &cases {
        println!(
            "phase {:2}/24 at {:.4} s, {:4.1} m/s, halted {:4.1} ms: min clearance {:.3} mm, \
             faults {:?}, then {} at {:.3} m/s",
            c.phase,
            c.at_s,
            c.speed_mps,
            c.halted_s * 1e3,
            c.min_clearance_m * 1e3,
            c.faults,
            c.final_mode.name(),
            c.final_speed_mps
        );
        worst = worst.min(c.min_clearance_m);
    }
    println!(
        "worst {:.3} mm over {} halts ({:.0} s wall)",
        worst * 1e3,
        cases.len(),
        started.elapsed().as_secs_f64()
    );
    assert_eq!(cases.len(), 72);
    for c in &cases {
        assert!(
            !c.faults.is_empty(),
            "phase {} {} s: no stop reported",
            c.phase,
            c.halted_s
        );
        assert!(c.final_speed_mps < 0.05, "phase {}: still moving", c.phase);
    }
    assert!(worst >= 0.3e-3, "{:.3} mm", worst * 1e3);
}
