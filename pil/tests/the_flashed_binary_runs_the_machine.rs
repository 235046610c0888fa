//! The release firmware ELF (the binary a user flashes) in the emulated STM32G474 on the
//! reference machine: the main job's scenario meets its figures, and each fault of
//! issue #28 ends as `faults.md` says. The tests of items 1, 2, 4, 5 and 6 fail on the
//! firmware before #28 (its ELF, run through the same scenarios, shows the defect each
//! names).
//!
//! The ELF is `FPC_ELF` if set, else the `cargo fw` output; build it first (CI does).

use std::path::PathBuf;

use fpc_pil::chip::ResetKind;
use fpc_pil::elf::Image;
use fpc_pil::faults::{run, Report, Scenario};

fn image() -> Image {
    let path = std::env::var_os("FPC_ELF")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../target/thumbv7em-none-eabihf/release/fpc")
        });
    Image::read(&path).unwrap_or_else(|e| panic!("{e}"))
}

fn scenario(s: Scenario) -> Report {
    run(&image(), s).unwrap_or_else(|e| panic!("{}: {e}", s.name()))
}

/// Item 1: the watchdog's first window is 20 ms (LSI 32 kHz, /4, reload 159), not the
/// 4096 ticks the counter starts from: a board whose control task never runs (dead ADCs)
/// resets within it. Before #28: at 0.514 s.
#[test]
fn a_boot_that_never_feeds_the_watchdog_resets_within_20_ms() {
    let r = scenario(Scenario::BootWindow);
    let first = r.resets.first().expect("no reset within 0.7 s");
    assert_eq!(first.kind, ResetKind::Watchdog);
    // Started ≈ 2 ms after power-on; 160 ticks of 125 µs; LSI tolerance aside.
    assert!(
        first.at_s < 0.025,
        "first watchdog reset at {:.4} s",
        first.at_s
    );
}

/// Item 2: a fault while stroking ends in the fault path's own reset (not the watchdog's),
/// the next boot logs its cause and brakes. Before #28: the watchdog reset first, and the
/// boot reported a hung task.
#[test]
fn a_fault_while_stroking_resets_by_the_fault_path_and_the_next_boot_logs_its_cause() {
    let r = scenario(Scenario::FaultPath);
    let t = r.injected_at_s.expect("not injected");
    let first = r.resets.first().expect("no reset");
    assert_eq!(first.kind, ResetKind::Software, "{:?}", r.resets);
    assert!(
        first.at_s - t < 0.004,
        "reset {:.4} s after the fault",
        first.at_s - t
    );
    assert!(
        !r.lines("the previous run ended on the fault path: HardFault")
            .is_empty(),
        "the cause was not logged after the reset"
    );
    // Braked as after a hung task.
    assert!(
        r.faults.iter().any(|f| f == "watchdog_reset"),
        "{:?}",
        r.faults
    );
}

/// A hung control task: the watchdog resets within its ≈ 3 ms running window, and the
/// next boot brakes (fault watchdog_reset latched, the stroke stopped).
#[test]
fn a_hung_control_task_is_reset_by_the_watchdog_and_braked() {
    let r = scenario(Scenario::HungControl);
    let t = r.injected_at_s.expect("not injected");
    let first = r.resets.first().expect("no reset");
    assert_eq!(first.kind, ResetKind::Watchdog);
    assert!(
        first.at_s - t < 0.0036,
        "reset {:.4} s after the hang",
        first.at_s - t
    );
    assert!(!r.lines("reset by the independent watchdog").is_empty());
    assert!(
        r.faults.iter().any(|f| f == "watchdog_reset"),
        "{:?}",
        r.faults
    );
    assert_eq!(r.resets.len(), 1, "{:?}", r.resets);
}

/// Item 4: the supply cut during a save leaves a torn, ECC-poisoned double word; the next
/// boot's read of it raises an NMI, which erases the store and resets once: the board then
/// boots with the calibration missing. Before #28: a reset loop.
#[test]
fn a_power_cut_during_a_save_ends_with_the_calibration_missing_never_a_reset_loop() {
    let r = scenario(Scenario::TornSave);
    let after_power: Vec<_> = r.resets.iter().skip(1).collect();
    assert!(
        after_power.len() <= 1,
        "resets after power-on: {:?}",
        after_power
    );
    assert!(!r.lines("flash double ECC error").is_empty());
    let last_boot = r.lines("Start refused until calibrated");
    assert!(
        last_boot
            .last()
            .is_some_and(|(_, l)| l.contains("calibration_missing")),
        "{:?}",
        last_boot
    );
}

/// Item 5: a program that the flash controller ends with PROGERR is reported, not logged
/// as saved. Before #28: "calibration saved" (embassy's async driver clears the flag).
#[test]
fn a_flash_error_during_a_save_is_reported_as_not_saved() {
    let r = scenario(Scenario::SaveError);
    assert!(
        r.lines("calibration saved").is_empty(),
        "{:?}",
        r.lines("saved")
    );
    assert!(!r.lines("calibration not saved").is_empty());
}

/// Item 6: option bytes with DBANK = 0 are a boot fault naming the check; nothing runs.
/// Before #28: the board ran, its store's erases aimed at other pages.
#[test]
fn a_single_bank_flash_is_refused_at_boot() {
    let r = scenario(Scenario::SingleBank);
    assert!(!r.lines("boot check failed: FlashBankLayout").is_empty());
    assert!(r.lines("running: control").is_empty());
    assert!(r.final_mode.is_none(), "telemetry came: the tasks ran");
}
