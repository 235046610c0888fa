//! The `test-timing` bring-up build (docs/bring-up.md, "Timing the control step on the
//! board") in the emulated STM32G474: its own count of the control step (DWT CYCCNT, from
//! the end-of-burst interrupt's entry to the last duty write) agrees with the emulator's
//! count of the same step, and goes on counting after a debugger has written DEMCR = 0 —
//! what probe-rs's generic ARMv7-M sequence does on detach (`debug_core_stop`), and what
//! stops the cycle counter (TRCENA, ARMv7-M ARM §C1.6.5; the emulator's rule is unit-tested
//! in `chip::ppb`). The build without the re-enable at each step (its code before this test)
//! fails here: 0 cycles counted after the DEMCR write.
//!
//! The ELF is `FPC_TIMING_ELF` if set, else where CI puts it: `bash scripts/fw-test-elf.sh
//! test-timing` (target/fpc-test-timing).

use fpc::control::command::Command;
use fpc_pil::chip::dap::{ctrl, DapRegister, DEMCR};
use fpc_pil::elf::Image;
use fpc_pil::session::Session;

/// How much shorter the build's count may be than the emulator's, cycles: the emulator
/// counts from the burst's end (the DMA's last transfer) to the last compare write, the build
/// from its handler's first instructions to just after that write. Between the two starts lie
/// the DMA's transfer-complete flag reaching the NVIC, the exception entry (12 cycles of
/// stacking, the vector fetch), the handler's prologue and the read-modify-writes of DEMCR
/// and DWT_CTRL on the private peripheral bus; after the write, one GPIO write.
const SHORTER_BY_AT_MOST: i64 = 200;

fn timing_image() -> Image {
    Image::built(
        "FPC_TIMING_ELF",
        "target/fpc-test-timing",
        "build it: bash scripts/fw-test-elf.sh test-timing",
    )
}

/// STEP_CYCLES as the bench reads it (`probe-rs read b32 ADDR 2`): the last step's count and
/// the largest since the boot.
fn step_cycles(s: &Session, at: u32) -> [u32; 2] {
    let mut b = [0u8; 8];
    s.chip
        .read_mem(at, &mut b)
        .unwrap_or_else(|e| panic!("{e}"));
    let word = |i: usize| u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    [word(0), word(4)]
}

/// Over a window of `seconds` from now: the largest step the build counted (STEP_CYCLES[1],
/// zeroed at the window's start) and the emulator's largest (its samples, cleared likewise).
fn largest_over(s: &mut Session, at: u32, seconds: f64) -> (u32, u64) {
    s.chip
        .write_mem(at, &[0u8; 8])
        .unwrap_or_else(|e| panic!("{e}"));
    s.chip.soc().samples.clear();
    let t = s.chip.time_s();
    s.run_until(t + seconds).unwrap_or_else(|e| panic!("{e}"));
    let emulated = s
        .chip
        .soc_ref()
        .samples
        .iter()
        .filter_map(|x| x.write_cycles)
        .max();
    (
        step_cycles(s, at)[1],
        emulated.expect("no compare written in the window"),
    )
}

/// The build's count against the emulator's: positive and not more than
/// [`SHORTER_BY_AT_MOST`] below it.
fn agrees(when: &str, build: u32, emulated: u64) {
    println!("{when}: the build's largest step {build} cycles, the emulator's {emulated}");
    let short = emulated as i64 - i64::from(build);
    assert!(
        build > 0 && (0..=SHORTER_BY_AT_MOST).contains(&short),
        "{when}: the build counted {build} cycles where the emulator counted {emulated}"
    );
}

/// A debugger writes DEMCR through the AHB-AP, as a probe does: debug power up, CSW 32-bit,
/// TAR, DRW.
fn probe_writes_demcr(s: &mut Session, value: u32) {
    let chip = &mut s.chip;
    let dp_ctrl = DapRegister::Dp {
        address: 0x4,
        bank: Some(0),
    };
    chip.dap_write(dp_ctrl, ctrl::CDBGPWRUPREQ | ctrl::CSYSPWRUPREQ)
        .expect("CTRL/STAT");
    chip.dap_write(DapRegister::Ap(0x00), 0x2300_0002)
        .expect("CSW");
    chip.dap_write(DapRegister::Ap(0x04), DEMCR).expect("TAR");
    chip.dap_write(DapRegister::Ap(0x0C), value).expect("DRW");
    chip.dap_write(DapRegister::Ap(0x04), DEMCR).expect("TAR");
    let read = chip.dap_read(DapRegister::Ap(0x0C)).expect("DRW");
    assert_eq!(read, value, "DEMCR as the probe reads it back");
}

#[test]
fn the_step_count_agrees_with_the_emulator_and_survives_a_cleared_demcr() {
    let image = timing_image();
    let at = image
        .symbol("STEP_CYCLES")
        .expect("the test-timing ELF has STEP_CYCLES");
    let mut s = fpc_pil::run::at_rest(&image).unwrap_or_else(|e| panic!("{e}"));
    s.run_until(0.02).unwrap_or_else(|e| panic!("{e}"));
    // Homing: the sections drive the piston, so every step writes its duties.
    s.chip.soc().recording = true;
    while !s.send(Command::Home) {
        s.step().unwrap_or_else(|e| panic!("{e}"));
    }
    let (build, emulated) = largest_over(&mut s, at, 0.02);
    agrees("homing, 20 ms", build, emulated);

    // The detach of probe-rs's generic sequence: DEMCR = 0, TRCENA with it.
    probe_writes_demcr(&mut s, 0);
    let (build, emulated) = largest_over(&mut s, at, 0.02);
    agrees("the 20 ms after DEMCR = 0", build, emulated);
    let last = step_cycles(&s, at)[0];
    assert!(
        last > 0,
        "the last step counted 0 cycles: the counter stopped"
    );
}
