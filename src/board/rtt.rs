//! RTT channels: defmt logs, the telemetry stream, command replies and the command input.
//!
//! | channel | direction | size | what |
//! |---|---|---|---|
//! | up 0 `defmt` | target → host | 1 KiB | defmt logs (never from the 20 kHz path) |
//! | up 1 `telemetry` | target → host | 8 KiB | COBS telemetry frames (`fpc::link::telemetry`) |
//! | up 2 `replies` | target → host | 512 B | command replies and rejections (`fpc::link`) |
//! | down 0 `commands` | host → target | 256 B | command frames (`fpc::link`) |
//!
//! The up-channels run in "no block, skip" mode: a write that does not fit is dropped whole
//! (the telemetry task counts it), so a slow or absent host can never stall the firmware or
//! tear a frame.
//!
//! The host can change a channel's mode: probe-rs sets `defmt` to "block if full" when it
//! attaches. rtt-target's writes obey the mode, and its defmt logger writes inside a
//! critical section, so a full buffer would stop every interrupt, the 20 kHz control one
//! included, until the host reads. defmt therefore goes through [`Logger`] here, which
//! writes with [`fpc::link::rtt_up::write_or_skip`] and never reads the mode flags. The
//! telemetry and reply channels are written from thread mode with interrupts enabled, and
//! set back to "no block, skip" before each write.

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use cortex_m::interrupt::{CriticalSection, Mutex};
use fpc::link::rtt_up::{write_or_skip, UpBuffer};
use fpc::ports::{ByteSource, FrameSink};
use rtt_target::{rtt_init, ChannelMode, DownChannel, UpChannel};

/// The telemetry up-channel.
pub struct TelemetryChannel(UpChannel);

impl FrameSink for TelemetryChannel {
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.0.set_mode(ChannelMode::NoBlockSkip);
        self.0.write(bytes)
    }
}

/// The command-reply up-channel.
pub struct ReplyChannel(UpChannel);

impl FrameSink for ReplyChannel {
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.0.set_mode(ChannelMode::NoBlockSkip);
        self.0.write(bytes)
    }
}

/// The command down-channel.
pub struct CommandChannel(DownChannel);

impl ByteSource for CommandChannel {
    fn read(&mut self, buf: &mut [u8]) -> usize {
        self.0.read(buf)
    }
}

/// Sets up the RTT control block and routes defmt to up-channel 0. Call once, before the
/// first log.
pub fn init() -> (TelemetryChannel, ReplyChannel, CommandChannel) {
    let channels = rtt_init! {
        up: {
            0: { size: 1024, mode: ChannelMode::NoBlockSkip, name: "defmt" }
            1: { size: 8192, mode: ChannelMode::NoBlockSkip, name: "telemetry" }
            2: { size: 512, mode: ChannelMode::NoBlockSkip, name: "replies" }
        }
        down: {
            0: { size: 256, name: "commands" }
        }
    };
    // Up-channel 0 is written by [`Logger`] through the control block, not through this
    // handle.
    let _defmt = channels.up.0;
    (
        TelemetryChannel(channels.up.1),
        ReplyChannel(channels.up.2),
        CommandChannel(channels.down.0),
    )
}

/// Up-channel 0 in the RTT control block, laid out as SEGGER defines it (and rtt-target
/// builds it): the header is 16 id bytes and two `usize` counts, then the up-channels.
#[repr(C)]
struct RawChannel {
    name: *const u8,
    buffer: *mut u8,
    size: usize,
    write: AtomicUsize,
    read: AtomicUsize,
    flags: AtomicUsize,
}

/// Size of the control block header before the first up-channel.
const HEADER_BYTES: usize = 16 + 2 * core::mem::size_of::<usize>();

extern "C" {
    /// The control block `rtt_init!` defines.
    #[link_name = "_SEGGER_RTT"]
    static CONTROL_BLOCK: u8;
}

/// The defmt up-channel as an [`UpBuffer`]; only [`Logger`] makes one, inside its critical
/// section.
struct DefmtUp(&'static RawChannel);

impl DefmtUp {
    /// Up-channel 0, or `None` before [`init`] has set it up (no buffer yet).
    fn get() -> Option<Self> {
        // SAFETY: `_SEGGER_RTT` is the static control block of `rtt_init!`, in RAM for the
        // whole run, with up-channel 0 right after its header; its fields are plain words
        // and atomics, valid to read at any time (zero before `init`). Only the logger,
        // holding its critical section, writes this channel.
        let channel = unsafe {
            &*core::ptr::addr_of!(CONTROL_BLOCK)
                .add(HEADER_BYTES)
                .cast::<RawChannel>()
        };
        // SAFETY: see above; `buffer` is written once by `init` before `size` is read.
        let buffer = unsafe { core::ptr::addr_of!(channel.buffer).read_volatile() };
        (!buffer.is_null()).then_some(DefmtUp(channel))
    }
}

impl UpBuffer for DefmtUp {
    fn size(&self) -> usize {
        // SAFETY: a plain word of the static control block (see `get`).
        unsafe { core::ptr::addr_of!(self.0.size).read_volatile() }
    }
    fn read_offset(&self) -> usize {
        self.0.read.load(Ordering::SeqCst)
    }
    fn write_offset(&self) -> usize {
        self.0.write.load(Ordering::SeqCst)
    }
    fn copy_in(&mut self, at: usize, bytes: &[u8]) {
        // SAFETY: `write_or_skip` keeps `at + bytes.len()` within `size`, the length of the
        // buffer `init` gave this channel; the host only reads bytes before our write offset.
        unsafe {
            let buffer = core::ptr::addr_of!(self.0.buffer).read_volatile();
            core::ptr::copy_nonoverlapping(bytes.as_ptr(), buffer.add(at), bytes.len());
        }
    }
    fn commit(&mut self, write: usize) {
        self.0.write.store(write, Ordering::SeqCst);
    }
}

/// The defmt logger: one frame at a time inside a critical section (frames from different
/// priorities must not interleave), each chunk written whole or dropped, never waiting.
#[defmt::global_logger]
struct Logger;

/// A frame is being written.
static TAKEN: AtomicBool = AtomicBool::new(false);
/// A log began while a frame was being written (only a fault handler can do that, the
/// frame masks interrupts): that nested frame is dropped, the outer one goes on.
static NESTED: AtomicBool = AtomicBool::new(false);
/// Whether interrupts were enabled when the frame began, restored at its end.
static INTERRUPTS_WERE_ON: Mutex<Cell<bool>> = Mutex::new(Cell::new(false));
static ENCODER: Mutex<RefCell<defmt::Encoder>> = Mutex::new(RefCell::new(defmt::Encoder::new()));

fn write_chunk(bytes: &[u8]) {
    if let Some(mut channel) = DefmtUp::get() {
        write_or_skip(&mut channel, bytes);
    }
}

// SAFETY: `acquire` and `release` bracket each frame in one critical section (interrupts
// masked from the first to the last byte), so the encoder and the channel have one user; a
// nested frame (from a fault handler) touches neither.
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        let were_on = cortex_m::register::primask::read().is_active();
        cortex_m::interrupt::disable();
        if TAKEN.swap(true, Ordering::Relaxed) {
            // Interrupts were already masked by the outer frame: nothing to restore.
            NESTED.store(true, Ordering::Relaxed);
            return;
        }
        // SAFETY: interrupts are masked just above, until `release`.
        let cs = unsafe { CriticalSection::new() };
        INTERRUPTS_WERE_ON.borrow(&cs).set(were_on);
        ENCODER.borrow(&cs).borrow_mut().start_frame(write_chunk);
    }

    unsafe fn flush() {}

    unsafe fn release() {
        if NESTED.swap(false, Ordering::Relaxed) {
            return;
        }
        // SAFETY: called after `acquire`, interrupts still masked.
        let cs = unsafe { CriticalSection::new() };
        ENCODER.borrow(&cs).borrow_mut().end_frame(write_chunk);
        TAKEN.store(false, Ordering::Relaxed);
        if INTERRUPTS_WERE_ON.borrow(&cs).get() {
            // SAFETY: restores the state `acquire` found.
            unsafe { cortex_m::interrupt::enable() };
        }
    }

    unsafe fn write(bytes: &[u8]) {
        if NESTED.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: called between `acquire` and `release`, interrupts masked.
        let cs = unsafe { CriticalSection::new() };
        ENCODER.borrow(&cs).borrow_mut().write(bytes, write_chunk);
    }
}
