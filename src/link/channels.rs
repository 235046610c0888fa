//! The firmware's RTT channels: numbers, names and buffer sizes. One table for the board's
//! `rtt_init!` (`board/rtt.rs`), the simulated board's RAM and the host link, so the
//! simulator lays out the channels the firmware does and the host finds them by number.
//!
//! | channel | direction | size | carries |
//! |---|---|---|---|
//! | up 0 `defmt` | board → host | 1 KiB | defmt log frames (never from the 20 kHz path) |
//! | up 1 `telemetry` | board → host | 8 KiB | telemetry frames ([`crate::link::telemetry`]) |
//! | up 2 `replies` | board → host | 512 B | command replies and rejections ([`crate::link::commands`]) |
//! | down 0 `commands` | host → board | 256 B | command frames |

/// Up-channel of the defmt log.
pub const UP_DEFMT: usize = 0;
/// Up-channel of the telemetry frames.
pub const UP_TELEMETRY: usize = 1;
/// Up-channel of the command replies.
pub const UP_REPLIES: usize = 2;
/// Down-channel of the commands.
pub const DOWN_COMMANDS: usize = 0;

/// Buffer of the defmt up-channel, bytes.
pub const DEFMT_BYTES: usize = 1024;
/// Buffer of the telemetry up-channel, bytes: 146 frames of 56 bytes, 146 ms at the default
/// 1 kHz frame rate between two reads of the host.
pub const TELEMETRY_BYTES: usize = 8192;
/// Buffer of the reply up-channel, bytes.
pub const REPLIES_BYTES: usize = 512;
/// Buffer of the command down-channel, bytes.
pub const COMMANDS_BYTES: usize = 256;

/// One channel as the firmware sets it up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChannelSpec {
    /// Its name in the control block.
    pub name: &'static str,
    /// Its ring buffer, bytes (one byte always stays free).
    pub size: usize,
}

/// The up-channels, by number.
pub const UP: [ChannelSpec; 3] = [
    ChannelSpec {
        name: "defmt",
        size: DEFMT_BYTES,
    },
    ChannelSpec {
        name: "telemetry",
        size: TELEMETRY_BYTES,
    },
    ChannelSpec {
        name: "replies",
        size: REPLIES_BYTES,
    },
];

/// The down-channels, by number.
pub const DOWN: [ChannelSpec; 1] = [ChannelSpec {
    name: "commands",
    size: COMMANDS_BYTES,
}];
