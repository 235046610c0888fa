//! The stack, guarded and measured.
//!
//! **Guarded**: the firmware is linked through flip-link (`.cargo/config.toml`), which puts
//! the stack at the bottom of SRAM, below every static: a stack that overflows runs off
//! SRAM's start (0x2000_0000) into unmapped space, where the first push is a bus error —
//! and, as the HardFault's own stacking fails too, a lock-up, which SYSCFG_CFGR2.CLL turns
//! into a break of both bridges (`trip.rs`) until the watchdog resets. Without it the stack
//! grew from the top of SRAM down into `.uninit` and `.bss` without a fault.
//!
//! **Measured**: [`paint`] fills the free stack with [`PAINT`] at boot, once the tasks run;
//! [`high_water`] finds the lowest word that no longer holds it. `fpc-pil` reads the same
//! from the emulated RAM, as a probe would.

use core::sync::atomic::{AtomicU32, Ordering};

/// The pattern of a stack word never used since boot.
pub const PAINT: u32 = 0x5AC4_5AC4;
/// Bytes left unpainted below the stack pointer at [`paint`] (the painting's own frame).
const MARGIN: u32 = 64;

extern "C" {
    /// The initial stack pointer (cortex-m-rt; flip-link moves it under the statics).
    static _stack_start: u32;
    /// The first static in SRAM (`.data`'s start, cortex-m-rt).
    static __sdata: u32;
    /// The end of the statics (cortex-m-rt).
    static _stack_end: u32;
}

/// Where SRAM1 begins: the stack's lower bound under flip-link.
const SRAM_START: u32 = 0x2000_0000;

/// The stack's lowest address: SRAM's start when the statics lie above the stack
/// (flip-link), else the end of the statics (a build linked without it: the stack then
/// grows down into them, and only the space between is painted).
fn bottom() -> u32 {
    // Only the symbols' addresses are taken (no read): the linker defines them.
    let (data, end) = (
        core::ptr::addr_of!(__sdata) as u32,
        core::ptr::addr_of!(_stack_end) as u32,
    );
    if data >= top() {
        SRAM_START
    } else {
        (end + 31) & !31
    }
}

// `fpc_paint_stack(from, to)`: stores PAINT over [from, to), 32 bytes per STM (both 32-byte
// aligned, from ≤ to). In assembly: it runs below the caller's frame, over memory no Rust
// frame may own.
core::arch::global_asm!(
    ".section .text.fpc_paint_stack,\"ax\"",
    ".global fpc_paint_stack",
    ".type fpc_paint_stack,%function",
    ".thumb_func",
    "fpc_paint_stack:",
    "    push {{r4, r5, r6, r7, lr}}",
    "    ldr r2, =0x5AC45AC4",
    "    mov r3, r2",
    "    mov r4, r2",
    "    mov r5, r2",
    "    mov r6, r2",
    "    mov r7, r2",
    "    mov r12, r2",
    "    mov lr, r2",
    "0:  cmp r0, r1",
    "    bhs 1f",
    "    stmia r0!, {{r2, r3, r4, r5, r6, r7, r12, lr}}",
    "    b 0b",
    "1:  pop {{r4, r5, r6, r7, pc}}",
    "    .ltorg",
);

extern "C" {
    fn fpc_paint_stack(from: u32, to: u32);
}

/// The stack's top (the initial stack pointer).
fn top() -> u32 {
    // Only the symbol's address is taken (no read): the linker defines it.
    core::ptr::addr_of!(_stack_start) as u32
}

/// The stack's size, bytes: its lowest address to the initial stack pointer.
pub fn size() -> u32 {
    top().saturating_sub(bottom())
}

/// Paints the free stack, from SRAM's start to a little below the stack pointer now. Call
/// once, from thread mode (a task of the thread-mode executor) at boot.
pub fn paint() {
    let sp = cortex_m::register::msp::read();
    let to = sp.saturating_sub(MARGIN) & !31;
    let from = bottom();
    if to > from && sp <= top() {
        // SAFETY: [from, sp − MARGIN) is the stack's unused part (below the thread-mode
        // stack pointer, above the statics or SRAM's start: `bottom`), owned by no frame. An
        // exception taken meanwhile pushes its frames below that stack pointer, and the
        // routine runs again only once every such handler has returned: a word it stores is
        // never one a live frame holds. The routine saves the callee-saved registers it uses.
        unsafe { fpc_paint_stack(from, to) }
    }
}

/// Words [`high_water`] reads between two yields: ≈ 5,000 cycles, 30 µs at 170 MHz.
const SCAN_CHUNK_WORDS: u32 = 512;

/// The deepest the stack has reached since [`paint`], bytes from its top. The scan reads
/// up to the whole painted stack (≈ 17,000 words, ≈ 1 ms of the core at 170 MHz, more with
/// the 20 kHz interrupts taking their share): it yields to the other thread-mode tasks every
/// [`SCAN_CHUNK_WORDS`], so that the supervision task, which alone feeds the watchdog, is
/// never held off by it.
pub async fn high_water() -> u32 {
    let mut at = bottom();
    let mut chunk = 0;
    while at < top() {
        // SAFETY: an aligned word of SRAM1 inside the stack's range, read without a
        // reference (the stack's owner may be writing it: a torn view only moves the mark
        // by a word).
        let w = unsafe { (at as *const u32).read_volatile() };
        if w != PAINT {
            break;
        }
        at += 4;
        chunk += 1;
        if chunk == SCAN_CHUNK_WORDS {
            chunk = 0;
            embassy_futures::yield_now().await;
        }
    }
    top() - at
}

/// The high-water mark last logged, bytes.
static LOGGED: AtomicU32 = AtomicU32::new(0);

/// Logs the high-water mark when it has grown by 256 bytes or more since last logged (and the
/// first time): called by the stack-watch task.
pub async fn log_growth() {
    let used = high_water().await;
    if used >= LOGGED.load(Ordering::Relaxed) + 256 || LOGGED.load(Ordering::Relaxed) == 0 {
        LOGGED.store(used, Ordering::Relaxed);
        defmt::info!(
            "stack high-water: {=u32} of {=u32} bytes ({=u32} %)",
            used,
            size(),
            used * 100 / size().max(1)
        );
    }
}
