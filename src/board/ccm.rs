//! The 20 kHz interrupt path's code in CCM SRAM: `memory.x` links it there (`.ccmram`, its
//! image stored in flash after the vector table), and [`copy_code`] copies the image over.
//!
//! From flash, the path waits 4 cycles at 170 MHz for every 64-bit line the instruction
//! cache (1 KiB) does not hold, and the path's code is larger than that cache: its timing
//! would depend on the cache's hit rate. From CCM SRAM the core fetches with zero wait
//! states on the I-code bus (RM0440 §2.1, §3.3.3), so the path's cycles are what the
//! instructions take (`fpc-pil run` counts them; `docs/bring-up.md` says how to confirm
//! them on the board with DWT CYCCNT).
//!
//! The copy runs at the start of [`super::init`], as soon as the clock is at 170 MHz
//! (≈ 30 µs for 28 KiB; at the 16 MHz reset clock, in cortex-m-rt's `__pre_init`, it took
//! over 1 ms more of the boot, which a piston coasting after a watchdog reset waits
//! through: `reset.rs`). Nothing in
//! that part of `.ccmram` can run before: its functions are the control path's, called only
//! by the control task and the DMA and control-executor interrupts, which `init` starts
//! later (`memory.x` keeps the time base's handler, which runs earlier, in flash).
//!
//! memcpy is the exception: the path calls it for its struct moves (a finished calibration
//! routine's record takes ≈ 1,500 instructions of it in one period, 62.7 µs of that period
//! under the no-cache bound from flash), and the boot calls it long before `init`. So
//! `memory.x` puts it first in `.ccmram` (up to `__eccmram_early`, under 1 KiB), and
//! `__pre_init` copies that part alone at reset (≈ 0.05 ms at 16 MHz; `reset.rs`), before
//! cortex-m-rt initialises RAM or anything can call it; `init` copies the rest.

// `fpc_copy_ccm_early`: copies `__sccmram` .. `__eccmram_early` from `__siccmram`, 16
// bytes per LDM/STM pair. Called by `__pre_init` at reset (`reset.rs`), before RAM is
// initialised, with the stack pointer set; hence assembly, saving the callee-saved
// registers it uses.
core::arch::global_asm!(
    ".section .text.fpc_copy_ccm_early,\"ax\"",
    ".global fpc_copy_ccm_early",
    ".type fpc_copy_ccm_early,%function",
    ".thumb_func",
    "fpc_copy_ccm_early:",
    "    push {{r4, r5}}",
    "    ldr r0, =__sccmram",
    "    ldr r1, =__eccmram_early",
    "    ldr r2, =__siccmram",
    "0:  cmp r0, r1",
    "    bhs 1f",
    "    ldmia r2!, {{r3, r4, r5, r12}}",
    "    stmia r0!, {{r3, r4, r5, r12}}",
    "    b 0b",
    "1:  pop {{r4, r5}}",
    "    bx lr",
    "    .ltorg",
);

// `fpc_copy_ccm_code`: copies the rest of `.ccmram`'s image (`__siccmram_late`, in flash)
// to `__eccmram_early` .. `__eccmram` (CCM SRAM), 16 bytes per LDM/STM pair. In assembly so
// that no call of a function that is itself in the image can appear in it.
core::arch::global_asm!(
    ".section .text.fpc_copy_ccm_code,\"ax\"",
    ".global fpc_copy_ccm_code",
    ".type fpc_copy_ccm_code,%function",
    ".thumb_func",
    "fpc_copy_ccm_code:",
    "    push {{r4, r5, r6, lr}}",
    "    ldr r0, =__eccmram_early",
    "    ldr r1, =__eccmram",
    "    ldr r2, =__siccmram_late",
    "0:  cmp r0, r1",
    "    bhs 1f",
    "    ldmia r2!, {{r3, r4, r5, r6}}",
    "    stmia r0!, {{r3, r4, r5, r6}}",
    "    b 0b",
    "1:  pop {{r4, r5, r6, pc}}",
    "    .ltorg",
);

extern "C" {
    fn fpc_copy_ccm_code();
}

/// Copies the CCM SRAM code's image from flash to CCM SRAM (all but memcpy, which
/// `__pre_init` copied at reset). Called once by [`super::init`] before anything in it can
/// run.
pub fn copy_code() {
    // SAFETY: `memory.x` aligns `__eccmram_early` and `.ccmram`'s end to 16 bytes in CCM
    // SRAM, and the image in flash is word aligned (LDM/STM need 4); the routine saves what
    // it uses of the callee-saved registers. Nothing of this part of `.ccmram` has run yet
    // (see the module header; memcpy, which has, is below `__eccmram_early` and not
    // rewritten) and nothing else writes CCM SRAM.
    unsafe { fpc_copy_ccm_code() }
}
