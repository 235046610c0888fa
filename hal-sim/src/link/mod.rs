//! The host link to the running board: the RTT channels as a [`Channels`] transport, and the
//! session logic `fpc-sim link` runs on them — telemetry from up 1 into a capture and a run
//! log, commands out on down 0 with their answers from up 2, defmt from up 0, and a
//! calibration routine awaited and its report printed ([`report`]).
//!
//! | channel | direction | carries |
//! |---|---|---|
//! | up 0 | board → host | defmt log frames |
//! | up 1 | board → host | telemetry frames ([`fpc::link::telemetry`]) |
//! | up 2 | board → host | command replies and rejections ([`fpc::link::commands`]) |
//! | down 0 | host → board | commands |
//!
//! Transports: [`rtt::RttChannels`] finds the RTT control block in the target's memory and
//! reads and writes the channels there, over any [`memory::TargetMemory`] — the simulated
//! board's RAM ([`crate::board::ram`]) in the tests, an emulated firmware image, or a probe.
//! [`simprobe::SimProbe`] is a host attached that way to the simulated board, for whole bench
//! sessions in the tests. [`Replay`] plays recorded channel contents. [`probe`] (cargo feature `probe`, off by
//! default) attaches to the board with the `probe-rs` library.

pub mod bench;
pub mod defmt;
pub mod memory;
#[cfg(feature = "probe")]
pub mod probe;
pub mod replay;
pub mod report;
pub mod rtt;
pub mod scope;
pub mod session;
pub mod simprobe;

pub use replay::Replay;

/// The chip of the controller board, as probe-rs names it.
pub const CHIP: &str = "STM32G474RETx";

pub use fpc::link::channels::{DOWN_COMMANDS, UP_DEFMT, UP_REPLIES, UP_TELEMETRY};

/// The board's RTT channels, by number: what the session logic needs of a transport.
///
/// A read returns what the channel holds now (possibly nothing, `Ok(0)`); a recorded
/// channel that has ended returns an error of kind [`std::io::ErrorKind::UnexpectedEof`]
/// (a live board's channels never end).
pub trait Channels {
    /// Reads up to `buf.len()` bytes from up-channel `channel`.
    fn read_up(&mut self, channel: usize, buf: &mut [u8]) -> std::io::Result<usize>;
    /// Writes as many of `bytes` as down-channel `channel` has room for; returns how many.
    fn write_down(&mut self, channel: usize, bytes: &[u8]) -> std::io::Result<usize>;
    /// Lets the board run for `d` while the host waits: a live board runs by itself (the
    /// host sleeps); an emulated one is run for it.
    fn pause(&mut self, d: std::time::Duration) {
        std::thread::sleep(d);
    }
}

impl<C: Channels + ?Sized> Channels for Box<C> {
    fn read_up(&mut self, channel: usize, buf: &mut [u8]) -> std::io::Result<usize> {
        (**self).read_up(channel, buf)
    }

    fn write_down(&mut self, channel: usize, bytes: &[u8]) -> std::io::Result<usize> {
        (**self).write_down(channel, bytes)
    }

    fn pause(&mut self, d: std::time::Duration) {
        (**self).pause(d);
    }
}

/// Whether `e` says a recorded channel has ended.
pub fn is_end(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::UnexpectedEof
}
