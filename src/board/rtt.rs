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

use fpc::ports::{ByteSource, FrameSink};
use rtt_target::{rtt_init, ChannelMode, DownChannel, UpChannel};

/// The telemetry up-channel.
pub struct TelemetryChannel(UpChannel);

impl FrameSink for TelemetryChannel {
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.0.write(bytes)
    }
}

/// The command-reply up-channel.
pub struct ReplyChannel(UpChannel);

impl FrameSink for ReplyChannel {
    fn write(&mut self, bytes: &[u8]) -> usize {
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
    rtt_target::set_defmt_channel(channels.up.0);
    (
        TelemetryChannel(channels.up.1),
        ReplyChannel(channels.up.2),
        CommandChannel(channels.down.0),
    )
}
