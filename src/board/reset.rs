//! What runs at reset before cortex-m-rt's own start-up (`__pre_init`): the early part of
//! the CCM SRAM code (memcpy, [`super::ccm`]) and the zeroing of the zero-initialised
//! statics (`.bss`), 32 bytes per store instead of cortex-m-rt's 4.
//!
//! Why: every reset — a watchdog's after a hung task among them — runs this at the 16 MHz
//! reset clock, with the outputs off and a piston that may be coasting toward a head
//! (`docs/firmware.md`, "The fault sweep": as an expander nothing but the sections brakes it
//! into a dead point). cortex-m-rt zeroes `.bss` one word per loop (`stm r0!, {r2}`, then
//! compare, branch): ≈ 6 cycles per word, 1.7 ms for the firmware's 18 KiB, more than half
//! of the boot. One STM of eight zeroed registers per loop stores 32 bytes in ≈ 14 cycles.
//!
//! How: `memory.x` gathers every `.bss` input section (and `COMMON`) into `.bss.fast`,
//! placed before cortex-m-rt's `.bss` (which is left empty, so its own loop runs no
//! iteration) and padded to a multiple of 32 bytes between `__sbss_fast` and `__ebss_fast`.
//! `.data` is still copied by cortex-m-rt (24 bytes), `.uninit` is still left as it is.

// `__pre_init`: cortex-m-rt calls it first at reset, with the stack pointer set and RAM not
// initialised (hence assembly: nothing here may rely on a static). Saves the callee-saved
// registers it uses, calls `fpc_copy_ccm_early` (`ccm.rs`), then zeroes `__sbss_fast` ..
// `__ebss_fast` with r2–r8 and r12.
core::arch::global_asm!(
    ".section .text.__pre_init,\"ax\"",
    ".global __pre_init",
    ".type __pre_init,%function",
    ".thumb_func",
    "__pre_init:",
    "    push {{r4, r5, r6, r7, r8, lr}}",
    "    bl fpc_copy_ccm_early",
    "    ldr r0, =__sbss_fast",
    "    ldr r1, =__ebss_fast",
    "    movs r2, #0",
    "    movs r3, #0",
    "    movs r4, #0",
    "    movs r5, #0",
    "    movs r6, #0",
    "    movs r7, #0",
    "    mov r8, r2",
    "    mov r12, r2",
    "0:  cmp r0, r1",
    "    bhs 1f",
    "    stmia r0!, {{r2, r3, r4, r5, r6, r7, r8, r12}}",
    "    b 0b",
    "1:  pop {{r4, r5, r6, r7, r8, pc}}",
    "    .ltorg",
);
