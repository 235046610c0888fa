//! The simulated board's RTT channels as the firmware's tasks see them: the tasks write the
//! up-channels and read the down-channel in the board's RAM ([`crate::board::ram`]),
//! exactly where the firmware's `rtt_init!` puts them; a host reads them there through the
//! RTT transport (`link::rtt`), as a probe does.

use fpc::link::channels::{DOWN_COMMANDS, UP_TELEMETRY};
use fpc::ports::{ByteSource, FrameSink};

use crate::board::world::WorldRef;

/// An RTT up-channel of the simulated board, as the firmware's task writes it: into the
/// board's RAM, whole or not at all (the firmware's `write_or_skip`).
pub struct SimUpChannel {
    world: WorldRef,
    channel: usize,
}

impl FrameSink for SimUpChannel {
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.world.borrow_mut().ram.write_up(self.channel, bytes)
    }
}

/// Up-channel `channel` of `world`'s board.
pub fn up_channel(world: &WorldRef, channel: usize) -> SimUpChannel {
    SimUpChannel {
        world: world.clone(),
        channel,
    }
}

/// The telemetry up-channel of `world`'s board.
pub fn telemetry_sink(world: &WorldRef) -> SimUpChannel {
    up_channel(world, UP_TELEMETRY)
}

/// The command down-channel of the simulated board, as the firmware's command task reads it.
pub struct SimCommandChannel {
    world: WorldRef,
}

impl ByteSource for SimCommandChannel {
    fn read(&mut self, buf: &mut [u8]) -> usize {
        self.world.borrow_mut().ram.read_down(DOWN_COMMANDS, buf)
    }
}

/// The command down-channel of `world`'s board.
pub fn command_channel(world: &WorldRef) -> SimCommandChannel {
    SimCommandChannel {
        world: world.clone(),
    }
}
