//! RTT channels: defmt logs, the telemetry stream, command replies and the command input
//! (numbers, names and sizes: [`fpc::link::channels`]).
//!
//! The up-channels are written with [`fpc::link::rtt_up::write_or_skip`]: a write that does
//! not fit is dropped whole (the telemetry task counts it), so a slow or absent host can never
//! stall the firmware or tear a frame, whatever mode the host sets in the channel's flags.
//!
//! Not rtt-target's own writer: the host can change a channel's mode (probe-rs sets `defmt`
//! to "block if full" when it attaches), rtt-target's writes obey it, and its defmt logger
//! writes inside a critical section, so a full buffer would stop every interrupt, the 20 kHz
//! control one included, until the host reads. And in "no block, skip" mode its `write`
//! returns the bytes it copied even when it then gives the write up uncommitted (the frame
//! reached the end of the ring and the rest did not fit after the wrap): the telemetry task
//! would take that for a partly sent frame, send its tail, and the host would reject a torn
//! frame the firmware never counted as dropped. Here every up-channel goes through
//! [`RawUp`], which reads the control block's words and never the mode flags; the command
//! down-channel is read with rtt-target's reader.

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use critical_section::{CriticalSection, Mutex, RestoreState};
use fpc::link::channels::{
    COMMANDS_BYTES, DEFMT_BYTES, REPLIES_BYTES, TELEMETRY_BYTES, UP_DEFMT, UP_REPLIES, UP_TELEMETRY,
};
use fpc::link::rtt_up::{write_or_skip, UpBuffer};
use fpc::ports::{ByteSource, FrameSink};
use rtt_target::{rtt_init, ChannelMode, DownChannel};

/// The telemetry up-channel (written by the telemetry task only).
pub struct TelemetryChannel(());

impl FrameSink for TelemetryChannel {
    fn write(&mut self, bytes: &[u8]) -> usize {
        RawUp::get(UP_TELEMETRY).map_or(0, |mut up| write_or_skip(&mut up, bytes))
    }
}

/// The command-reply up-channel (written by the command task only).
pub struct ReplyChannel(());

impl FrameSink for ReplyChannel {
    fn write(&mut self, bytes: &[u8]) -> usize {
        RawUp::get(UP_REPLIES).map_or(0, |mut up| write_or_skip(&mut up, bytes))
    }
}

/// The command down-channel.
pub struct CommandChannel(DownChannel, super::test_build::StopWatch);

impl ByteSource for CommandChannel {
    fn read(&mut self, buf: &mut [u8]) -> usize {
        let n = self.0.read(buf);
        self.1.received(buf.get(..n).unwrap_or_default());
        n
    }
}

/// Sets up the RTT control block and routes defmt to up-channel 0. Call once, before the
/// first log.
pub fn init() -> (TelemetryChannel, ReplyChannel, CommandChannel) {
    // The buffers (9.9 KiB) are in `.uninit`: their bytes mean nothing until the offsets,
    // which `rtt_init!` zeroes, say so, and zeroing them with `.bss` at the 16 MHz boot clock
    // took ≈ 0.9 ms of the time before the outputs can brake after a reset.
    let channels = rtt_init! {
        up: {
            0: { size: DEFMT_BYTES, mode: ChannelMode::NoBlockSkip, name: "defmt", section: ".uninit.rtt.up0" }
            1: { size: TELEMETRY_BYTES, mode: ChannelMode::NoBlockSkip, name: "telemetry", section: ".uninit.rtt.up1" }
            2: { size: REPLIES_BYTES, mode: ChannelMode::NoBlockSkip, name: "replies", section: ".uninit.rtt.up2" }
        }
        down: {
            0: { size: COMMANDS_BYTES, name: "commands", section: ".uninit.rtt.down0" }
        }
    };
    // The up-channels are written through the control block ([`RawUp`]), not through
    // rtt-target's handles.
    let _handles = channels.up;
    (
        TelemetryChannel(()),
        ReplyChannel(()),
        CommandChannel(channels.down.0, Default::default()),
    )
}

/// An up-channel in the RTT control block, laid out as SEGGER defines it (and rtt-target
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

/// An up-channel as an [`UpBuffer`]. Each channel has one writer: defmt's is [`Logger`]
/// (inside its critical section), telemetry's the telemetry task, replies' the command task.
struct RawUp(&'static RawChannel);

impl RawUp {
    /// Up-channel `number` (one of the three [`init`] sets up), or `None` before [`init`]
    /// has set it up (no buffer yet).
    fn get(number: usize) -> Option<Self> {
        if number > UP_REPLIES {
            return None;
        }
        // SAFETY: `_SEGGER_RTT` is the static control block of `rtt_init!`, in RAM for the
        // whole run, with its three up-channels right after its header (`number` is one of
        // them, checked above); their fields are plain words and atomics, valid to read at
        // any time (zero before `init`). Each channel has one writer (see the type).
        let channel = unsafe {
            &*core::ptr::addr_of!(CONTROL_BLOCK)
                .add(HEADER_BYTES + number * core::mem::size_of::<RawChannel>())
                .cast::<RawChannel>()
        };
        // SAFETY: see above; `buffer` is written once by `init` before `size` is read.
        let buffer = unsafe { core::ptr::addr_of!(channel.buffer).read_volatile() };
        (!buffer.is_null()).then_some(RawUp(channel))
    }
}

impl UpBuffer for RawUp {
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

/// The defmt logger: one frame at a time inside the global critical section
/// ([`super::critical`]: it masks the thread-mode and time interrupts, never the control
/// ones, which do not log), never waiting. The encoder hands its output over in
/// small chunks (rzcobs: down to single bytes), so a frame written chunk by chunk would be
/// torn when the channel fills part-way through it: its head in the buffer, a middle chunk
/// dropped, its tail (or the next frame) after it, and the host decoding garbage or a wrong
/// line. Each frame is therefore collected in [`FRAME`] and written whole at its end, or
/// dropped whole (no room, or longer than [`FRAME_BYTES`]).
#[defmt::global_logger]
struct Logger;

/// The longest defmt frame written, encoded bytes: the longest message here (a panic's file,
/// line and static message) is well under it; a longer frame is dropped whole.
const FRAME_BYTES: usize = 256;

/// The frame being written, and whether it outgrew [`FRAME_BYTES`].
static FRAME: Mutex<RefCell<(heapless::Vec<u8, FRAME_BYTES>, bool)>> =
    Mutex::new(RefCell::new((heapless::Vec::new(), false)));

/// A frame is being written.
static TAKEN: AtomicBool = AtomicBool::new(false);
/// A log began while a frame was being written (a panic or fault handler preempting it):
/// that nested frame is dropped, the outer one goes on.
static NESTED: AtomicBool = AtomicBool::new(false);
/// The critical section's restore state, taken when the frame began and given back at its
/// end.
static RESTORE: Mutex<Cell<RestoreState>> = Mutex::new(Cell::new(RestoreState::invalid()));
static ENCODER: Mutex<RefCell<defmt::Encoder>> = Mutex::new(RefCell::new(defmt::Encoder::new()));

/// Appends an encoded chunk to the frame being written (inside the logger's critical
/// section).
fn write_chunk(cs: CriticalSection, bytes: &[u8]) {
    let mut frame = FRAME.borrow(cs).borrow_mut();
    if frame.0.extend_from_slice(bytes).is_err() {
        frame.1 = true;
    }
}

/// Writes the collected frame to up 0 whole, or drops it; empties it for the next one.
fn commit_frame(cs: CriticalSection) {
    let mut frame = FRAME.borrow(cs).borrow_mut();
    if !frame.1 {
        if let Some(mut channel) = RawUp::get(UP_DEFMT) {
            write_or_skip(&mut channel, &frame.0);
        }
    }
    frame.0.clear();
    frame.1 = false;
}

// SAFETY: `acquire` and `release` bracket each frame in one global critical section, from
// the first to the last byte, and only the holder of `TAKEN` touches the encoder and the
// channel; a nested frame (from a handler that preempted the frame) touches neither.
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        // SAFETY: released in `release` (defmt pairs them), or at once when nested.
        let restore = unsafe { critical_section::acquire() };
        if TAKEN.swap(true, Ordering::Relaxed) {
            NESTED.store(true, Ordering::Relaxed);
            // SAFETY: the state this `acquire` just returned, released in order.
            unsafe { critical_section::release(restore) };
            return;
        }
        // SAFETY: inside the critical section taken just above, until `release`.
        let cs = unsafe { CriticalSection::new() };
        RESTORE.borrow(cs).set(restore);
        ENCODER
            .borrow(cs)
            .borrow_mut()
            .start_frame(|b| write_chunk(cs, b));
    }

    unsafe fn flush() {}

    unsafe fn release() {
        if NESTED.swap(false, Ordering::Relaxed) {
            return;
        }
        // SAFETY: called after `acquire`, still inside its critical section.
        let cs = unsafe { CriticalSection::new() };
        ENCODER
            .borrow(cs)
            .borrow_mut()
            .end_frame(|b| write_chunk(cs, b));
        commit_frame(cs);
        let restore = RESTORE.borrow(cs).get();
        TAKEN.store(false, Ordering::Relaxed);
        // SAFETY: ends the critical section `acquire` began, with its state.
        unsafe { critical_section::release(restore) };
    }

    unsafe fn write(bytes: &[u8]) {
        if NESTED.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: called between `acquire` and `release`, inside the critical section.
        let cs = unsafe { CriticalSection::new() };
        ENCODER
            .borrow(cs)
            .borrow_mut()
            .write(bytes, |b| write_chunk(cs, b));
    }
}
