//! The host's link to the running board through a debug probe (`fpc-sim link`), driven by
//! probe-rs's own ARM debug interface over the emulated chip's SWD port (DP, AHB-AP, the
//! core's debug registers: `pil/src/chip/dap.rs`): it reads and writes the RTT channels
//! through the memory access port alone and never halts the core; a `probe_rs::Session`
//! over the same port — as probe-rs's tools attach — is seen halting it.
//!
//! The ELF is `FPC_ELF` if set, else the `cargo fw` output; build it first (CI does).

use fpc::status::ModeKind;
use fpc_pil::chip::dap::DHCSR;
use fpc_pil::elf::Image;
use fpc_pil::faults::{run_with, Options, Scenario};

fn image() -> Image {
    Image::built(
        "FPC_ELF",
        "target/thumbv7em-none-eabihf/release/fpc",
        "build it: cargo fw",
    )
}

/// Telemetry frames per second at the default decimation (one frame per 10 control cycles
/// of 50 µs).
const FRAMES_PER_S: f64 = 2_000.0;

#[test]
fn a_ten_second_capture_through_the_probe_never_halts_the_stroking_machine() {
    let opts = Options::default();
    let r = run_with(&image(), Scenario::ProbeCapture, &opts).unwrap();
    let c = r.capture.clone().unwrap();
    println!(
        "probe capture: {c}; min clearance {:.3} mm",
        r.min_clearance_m * 1e3
    );
    assert_eq!(c.error, None);
    assert_eq!(opts.capture_s, 10.0);
    // Never halted, its debug registers never touched.
    assert_eq!((c.halts, r.halts), (0, 0));
    assert!(
        c.debug_register_touches.is_empty(),
        "{:?}",
        c.debug_register_touches
    );
    // Every frame of the 10 s came, whole, and makes one run log.
    let frames = f64::from(c.counters.telemetry.accepted);
    assert!(frames >= 0.999 * FRAMES_PER_S * c.seconds, "{}", c.counters);
    assert_eq!(c.counters.telemetry.rejected, 0);
    assert_eq!((c.counters.gaps, c.counters.firmware_dropped), (0, 0));
    assert!(
        c.rows as f64 >= 0.999 * frames,
        "{} rows of {frames} frames",
        c.rows
    );
    // The strokes went on: the machine running to the end, no fault, the clearance held.
    assert!(c.dead_points >= 60, "{} dead points", c.dead_points);
    assert!(r.faults.is_empty(), "{:?}", r.faults);
    assert_eq!(r.final_mode, Some(ModeKind::Running));
    assert!(r.resets.is_empty());
    assert!(r.min_clearance_m >= 0.6e-3, "{} m", r.min_clearance_m);
    // And `fpc-sim link flash` would refuse to halt it.
    let refusal = c.flash_refused.unwrap_or_default();
    println!("fpc-sim link flash: {refusal}");
    assert!(refusal.contains("the machine is running"), "{refusal}");
}

/// The witness: the emulated port sees what probe-rs 0.32's `Session` does — it halts the
/// core (DHCSR = DBGKEY | C_HALT | C_DEBUGEN) to clear the breakpoint unit, on attach and
/// again when dropped.
#[test]
fn a_probe_rs_session_on_the_same_port_is_seen_halting_the_core() {
    let opts = Options {
        capture_s: 0.05,
        ..Options::default()
    };
    let r = run_with(&image(), Scenario::ProbeSession, &opts).unwrap();
    let c = r.capture.unwrap();
    println!("probe-rs session: {c}");
    assert_eq!(c.error, None);
    // Two halts: the attach's and the drop's.
    assert_eq!(c.halts, 2, "{c:?}");
    let halting = |&(a, w): &(u32, Option<u32>)| a == DHCSR && w.is_some_and(|v| v & 3 == 3);
    assert!(c.debug_register_touches.iter().any(halting));
}
