//! The RTT transport: the board's channels read and written through its memory, the way a
//! debug probe does it — the control block found in RAM (by its id, or at the address the
//! ELF's `_SEGGER_RTT` names), up-channels drained by advancing their read offsets,
//! down-channels filled by advancing their write offsets. It runs over any
//! [`TargetMemory`]: a probe's, the simulated board's RAM, an emulator's.
//!
//! Written from SEGGER's description of the control block (a 32-bit target):
//!
//! | offset | what |
//! |---|---|
//! | 0 | id, 16 bytes: `"SEGGER RTT"` and NULs |
//! | 16 | number of up-channels (word) |
//! | 20 | number of down-channels (word) |
//! | 24 | one 24-byte descriptor per channel, up-channels first: name pointer, buffer pointer, size, write offset, read offset, flags |
//!
//! Each channel is a ring buffer with one byte always free: read = write means empty. On an
//! up-channel the target moves the write offset and the host the read offset; on a
//! down-channel the reverse. A host never writes the other side's offset, so a running
//! target and a host never race on a word.
//!
//! A block is taken only when it is whole: the id matches, the counts are plausible, every
//! channel in use has a buffer inside the target's memory and offsets inside its buffer.
//! Offsets found out of range later (the firmware crashed, or the RAM was overwritten) are
//! an error naming the channel, never bytes read from the wrong place.

use std::io;
use std::ops::Range;

use super::memory::TargetMemory;
use super::Channels;

/// The control block's id.
pub const ID: &[u8; 16] = b"SEGGER RTT\0\0\0\0\0\0";
/// Most channels of either direction a control block may declare (SEGGER's default is 3;
/// more means the id was found in other data).
pub const MAX_CHANNELS: u32 = 16;
/// Largest channel buffer taken as plausible, bytes.
pub const MAX_BUFFER: u32 = 1 << 20;
const HEADER_BYTES: u64 = 24;
const DESCRIPTOR_BYTES: u64 = 24;
/// Byte offsets of the offset words in a descriptor.
const WRITE: u64 = 12;
const READ: u64 = 16;
/// Longest channel name read, bytes.
const NAME_BYTES: usize = 32;

/// Where to look for the control block.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Locate {
    /// At this address (the ELF's `_SEGGER_RTT` symbol).
    At(u64),
    /// Anywhere in these address ranges (the target's RAM): exactly one whole block must be
    /// found.
    Scan(Vec<Range<u64>>),
}

/// One channel of the control block.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelInfo {
    /// Its number among the channels of its direction.
    pub number: usize,
    /// Its name, if it has a readable one.
    pub name: Option<String>,
    /// Address of its descriptor.
    pub descriptor: u64,
    /// Address of its ring buffer.
    pub buffer: u64,
    /// Size of its ring buffer, bytes.
    pub size: u32,
}

/// A control block found in a target's memory.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ControlBlock {
    /// Its address.
    pub address: u64,
    /// The up-channels in use (target → host), by number.
    pub up: Vec<ChannelInfo>,
    /// The down-channels in use (host → target), by number.
    pub down: Vec<ChannelInfo>,
}

impl ControlBlock {
    /// Finds the control block in `memory`, as `locate` says; the error says why none (or
    /// more than one) was taken.
    pub fn find<M: TargetMemory + ?Sized>(
        memory: &mut M,
        locate: &Locate,
    ) -> Result<ControlBlock, String> {
        match locate {
            Locate::At(address) => ControlBlock::read_at(memory, *address)
                .map_err(|why| format!("no RTT control block at {address:#010x}: {why}")),
            Locate::Scan(ranges) => {
                let mut found = Vec::new();
                let mut rejected = Vec::new();
                for range in ranges {
                    let len = usize::try_from(range.end.saturating_sub(range.start))
                        .map_err(|_| format!("cannot scan {range:#x?}: too large"))?;
                    let mut bytes = vec![0u8; len];
                    memory
                        .read(range.start, &mut bytes)
                        .map_err(|e| format!("cannot read the target's RAM {range:#x?}: {e}"))?;
                    let hits = bytes
                        .windows(ID.len())
                        .enumerate()
                        .filter(|(_, w)| *w == ID)
                        .map(|(i, _)| range.start + i as u64);
                    for address in hits {
                        match ControlBlock::read_at(memory, address) {
                            Ok(block) => found.push(block),
                            Err(why) => rejected.push(format!("{address:#010x}: {why}")),
                        }
                    }
                }
                match found.len() {
                    1 => Ok(found.remove(0)),
                    0 if rejected.is_empty() => Err(format!(
                        "no RTT control block in the target's RAM ({}): is the firmware \
                         running, and past its RTT set-up?",
                        ranges_text(ranges)
                    )),
                    0 => Err(format!(
                        "no whole RTT control block in the target's RAM ({}); the id was found \
                         but the block is not usable: {}",
                        ranges_text(ranges),
                        rejected.join("; ")
                    )),
                    _ => Err(format!(
                        "{} RTT control blocks in the target's RAM (at {}): give the one to use \
                         (the firmware ELF names it)",
                        found.len(),
                        found
                            .iter()
                            .map(|b| format!("{:#010x}", b.address))
                            .collect::<Vec<_>>()
                            .join(", ")
                    )),
                }
            }
        }
    }

    /// The block at `address`, if it is a whole one.
    fn read_at<M: TargetMemory + ?Sized>(
        memory: &mut M,
        address: u64,
    ) -> Result<ControlBlock, String> {
        if !address.is_multiple_of(4) {
            return Err("not word-aligned".into());
        }
        let mut id = [0u8; 16];
        memory
            .read(address, &mut id)
            .map_err(|e| format!("cannot read it: {e}"))?;
        if &id != ID {
            return Err("the id is not \"SEGGER RTT\"".into());
        }
        let mut counts = [0u32; 2];
        memory
            .read_words(address + 16, &mut counts)
            .map_err(|e| format!("cannot read it: {e}"))?;
        let [n_up, n_down] = counts;
        if n_up == 0 || n_up > MAX_CHANNELS || n_down > MAX_CHANNELS {
            return Err(format!(
                "it declares {n_up} up- and {n_down} down-channels (1..{MAX_CHANNELS} and \
                 0..{MAX_CHANNELS} expected)"
            ));
        }
        let mut channels = |first: u32, count: u32, kind: &str| {
            let mut out = Vec::new();
            for number in 0..count {
                let descriptor =
                    address + HEADER_BYTES + DESCRIPTOR_BYTES * u64::from(first + number);
                if let Some(info) = read_channel(memory, descriptor, number as usize)
                    .map_err(|why| format!("{kind}-channel {number}: {why}"))?
                {
                    out.push(info);
                }
            }
            Ok::<_, String>(out)
        };
        let up = channels(0, n_up, "up")?;
        let down = channels(n_up, n_down, "down")?;
        Ok(ControlBlock { address, up, down })
    }

    /// Up-channel `number`, if the block has it.
    pub fn up_channel(&self, number: usize) -> Option<&ChannelInfo> {
        self.up.iter().find(|c| c.number == number)
    }

    /// Down-channel `number`, if the block has it.
    pub fn down_channel(&self, number: usize) -> Option<&ChannelInfo> {
        self.down.iter().find(|c| c.number == number)
    }

    /// Reads what up-channel `number` holds now (at most `buf.len()` bytes) and frees it
    /// for the target. `Ok(0)`: nothing new.
    pub fn read_up<M: TargetMemory + ?Sized>(
        &self,
        memory: &mut M,
        number: usize,
        buf: &mut [u8],
    ) -> io::Result<usize> {
        let c = self.up_channel(number).ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::NotFound,
                format!("the target has no RTT up-channel {number}"),
            )
        })?;
        let (write, mut read) = offsets(memory, c, "up")?;
        let size = u64::from(c.size);
        let mut total = 0;
        while total < buf.len() {
            let end = if read > write { size } else { write };
            let n = usize::try_from(end - read)
                .unwrap_or(usize::MAX)
                .min(buf.len() - total);
            if n == 0 {
                break;
            }
            let dst = buf.get_mut(total..total + n).unwrap_or_default();
            memory.read(c.buffer + read, dst)?;
            total += n;
            read = (read + n as u64) % size;
        }
        if total > 0 {
            memory.write_word(c.descriptor + READ, read as u32)?;
        }
        Ok(total)
    }

    /// Writes as many of `bytes` as down-channel `number` has room for now; returns how
    /// many.
    pub fn write_down<M: TargetMemory + ?Sized>(
        &self,
        memory: &mut M,
        number: usize,
        bytes: &[u8],
    ) -> io::Result<usize> {
        let c = self.down_channel(number).ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::NotFound,
                format!("the target has no RTT down-channel {number}"),
            )
        })?;
        let (mut write, read) = offsets(memory, c, "down")?;
        let size = u64::from(c.size);
        let mut total = 0;
        while total < bytes.len() {
            // One byte stays free: the write offset may not catch up with the read offset.
            let room = if read > write {
                read - write - 1
            } else if read == 0 {
                size - write - 1
            } else {
                size - write
            };
            let n = usize::try_from(room)
                .unwrap_or(usize::MAX)
                .min(bytes.len() - total);
            if n == 0 {
                break;
            }
            memory.write(
                c.buffer + write,
                bytes.get(total..total + n).unwrap_or_default(),
            )?;
            total += n;
            write = (write + n as u64) % size;
        }
        if total > 0 {
            memory.write_word(c.descriptor + WRITE, write as u32)?;
        }
        Ok(total)
    }
}

/// The channel described at `descriptor`: `None` if unused (no buffer), an error if its
/// words cannot be right.
fn read_channel<M: TargetMemory + ?Sized>(
    memory: &mut M,
    descriptor: u64,
    number: usize,
) -> Result<Option<ChannelInfo>, String> {
    let mut w = [0u32; 6];
    memory
        .read_words(descriptor, &mut w)
        .map_err(|e| format!("cannot read its descriptor: {e}"))?;
    let [name, buffer, size, write, read, _flags] = w;
    if buffer == 0 {
        return Ok(None);
    }
    if !(2..=MAX_BUFFER).contains(&size) {
        return Err(format!("buffer size {size} (2..={MAX_BUFFER} expected)"));
    }
    if write >= size || read >= size {
        return Err(format!(
            "offsets write {write}, read {read} outside its {size}-byte buffer"
        ));
    }
    let (first, last) = (u64::from(buffer), u64::from(buffer) + u64::from(size) - 1);
    for at in [first, last] {
        memory.read(at, &mut [0u8]).map_err(|e| {
            format!("its buffer {first:#010x}..={last:#010x} is not in the target's memory: {e}")
        })?;
    }
    Ok(Some(ChannelInfo {
        number,
        name: read_name(memory, u64::from(name)),
        descriptor,
        buffer: u64::from(buffer),
        size,
    }))
}

/// The NUL-terminated name at `address` (names may live in flash, which a memory without
/// it cannot read: then no name).
fn read_name<M: TargetMemory + ?Sized>(memory: &mut M, address: u64) -> Option<String> {
    if address == 0 {
        return None;
    }
    let mut bytes = Vec::new();
    for i in 0..NAME_BYTES as u64 {
        let mut b = [0u8];
        memory.read(address + i, &mut b).ok()?;
        if b[0] == 0 {
            return Some(String::from_utf8_lossy(&bytes).into_owned());
        }
        bytes.push(b[0]);
    }
    None
}

/// Reads everything up-channel `number` holds into `out`, as a host that keeps up does;
/// returns the bytes read.
pub fn drain_up<M: TargetMemory + ?Sized>(
    block: &ControlBlock,
    memory: &mut M,
    number: usize,
    out: &mut Vec<u8>,
) -> io::Result<usize> {
    let mut buf = [0u8; 4096];
    let mut total = 0;
    loop {
        let n = block.read_up(memory, number, &mut buf)?;
        if n == 0 {
            return Ok(total);
        }
        out.extend_from_slice(buf.get(..n).unwrap_or_default());
        total += n;
    }
}

/// A channel's (write, read) offsets, checked against its size.
fn offsets<M: TargetMemory + ?Sized>(
    memory: &mut M,
    c: &ChannelInfo,
    kind: &str,
) -> io::Result<(u64, u64)> {
    let mut w = [0u32; 2];
    memory.read_words(c.descriptor + WRITE, &mut w)?;
    let [write, read] = w;
    if write >= c.size || read >= c.size {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "RTT {kind}-channel {} ({}): offsets write {write}, read {read} outside its \
                 {}-byte buffer: the control block is corrupted (did the firmware crash or \
                 restart?)",
                c.number,
                c.name.as_deref().unwrap_or("no name"),
                c.size
            ),
        ));
    }
    Ok((u64::from(write), u64::from(read)))
}

fn ranges_text(ranges: &[Range<u64>]) -> String {
    ranges
        .iter()
        .map(|r| format!("{:#010x}..{:#010x}", r.start, r.end))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The board's RTT channels through its memory: a [`Channels`] transport.
#[derive(Debug)]
pub struct RttChannels<M> {
    memory: M,
    block: ControlBlock,
}

impl<M: TargetMemory> RttChannels<M> {
    /// Finds the control block in `memory` (as `locate` says) and attaches to it.
    pub fn attach(mut memory: M, locate: &Locate) -> Result<RttChannels<M>, String> {
        let block = ControlBlock::find(&mut memory, locate)?;
        Ok(RttChannels { memory, block })
    }

    /// A transport over `memory` for a block found before (no search: cheap).
    pub fn with_block(memory: M, block: ControlBlock) -> RttChannels<M> {
        RttChannels { memory, block }
    }

    /// The control block attached to.
    pub fn block(&self) -> &ControlBlock {
        &self.block
    }

    /// The memory, for other reads and writes.
    pub fn memory_mut(&mut self) -> &mut M {
        &mut self.memory
    }

    /// The memory and the block, taken apart.
    pub fn into_parts(self) -> (M, ControlBlock) {
        (self.memory, self.block)
    }
}

impl<M: TargetMemory> Channels for RttChannels<M> {
    fn read_up(&mut self, channel: usize, buf: &mut [u8]) -> io::Result<usize> {
        self.block.read_up(&mut self.memory, channel, buf)
    }

    fn write_down(&mut self, channel: usize, bytes: &[u8]) -> io::Result<usize> {
        self.block.write_down(&mut self.memory, channel, bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::ram::{SimRam, CONTROL_BLOCK, RAM_BASE};
    use fpc::link::channels::{
        COMMANDS_BYTES, DOWN_COMMANDS, TELEMETRY_BYTES, UP_REPLIES, UP_TELEMETRY,
    };
    use proptest::prelude::*;

    fn booted() -> SimRam {
        let mut ram = SimRam::new();
        ram.boot_rtt();
        ram
    }

    fn ram_scan() -> Locate {
        Locate::Scan(vec![SimRam::range()])
    }

    /// Everything up-channel `n` holds, read in pieces of `piece` bytes.
    fn drain<M: TargetMemory>(link: &mut RttChannels<M>, n: usize, piece: usize) -> Vec<u8> {
        let mut out = Vec::new();
        let mut buf = vec![0u8; piece];
        loop {
            let k = link.read_up(n, &mut buf).unwrap();
            if k == 0 {
                return out;
            }
            out.extend_from_slice(&buf[..k]);
        }
    }

    #[test]
    fn the_block_is_found_in_ram_with_the_firmwares_channels() {
        let mut ram = booted();
        let block = ControlBlock::find(&mut ram, &ram_scan()).unwrap();
        assert_eq!(block.address, u64::from(CONTROL_BLOCK));
        let names = |cs: &[ChannelInfo]| -> Vec<(Option<String>, u32)> {
            cs.iter().map(|c| (c.name.clone(), c.size)).collect()
        };
        let table = |specs: &[fpc::link::channels::ChannelSpec]| -> Vec<(Option<String>, u32)> {
            specs
                .iter()
                .map(|s| (Some(s.name.to_string()), s.size as u32))
                .collect()
        };
        assert_eq!(names(&block.up), table(&fpc::link::channels::UP));
        assert_eq!(names(&block.down), table(&fpc::link::channels::DOWN));
        let at = ControlBlock::find(&mut ram, &Locate::At(u64::from(CONTROL_BLOCK))).unwrap();
        assert_eq!(at, block);
    }

    #[test]
    fn before_the_firmware_set_it_up_there_is_no_block() {
        let mut ram = SimRam::new();
        let e = RttChannels::attach(&mut ram, &ram_scan()).unwrap_err();
        assert!(
            e.contains("no RTT control block in the target's RAM"),
            "{e}"
        );
        let e = ControlBlock::find(&mut ram, &Locate::At(u64::from(CONTROL_BLOCK))).unwrap_err();
        assert!(e.contains("the id is not"), "{e}");
        let e = ControlBlock::find(&mut ram, &Locate::At(0x0800_0000)).unwrap_err();
        assert!(
            e.contains("cannot read it") && e.contains("outside the board's RAM"),
            "{e}"
        );
    }

    #[test]
    fn the_id_in_other_data_is_passed_over_and_two_whole_blocks_are_refused() {
        let mut ram = booted();
        // Noise, and the id in a string a program might hold, with nonsense after it.
        let noise: Vec<u8> = (0..4096u32)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect();
        ram.write(u64::from(RAM_BASE) + 0x6000, &noise).unwrap();
        ram.write(u64::from(RAM_BASE) + 0x6100, ID).unwrap();
        ram.write(u64::from(RAM_BASE) + 0x6203, ID).unwrap();
        let block = ControlBlock::find(&mut ram, &ram_scan()).unwrap();
        assert_eq!(block.address, u64::from(CONTROL_BLOCK));
        // A copy of the whole block elsewhere: ambiguous, refused.
        let mut copy = vec![0u8; 120];
        ram.read(u64::from(CONTROL_BLOCK), &mut copy).unwrap();
        ram.write(u64::from(RAM_BASE) + 0x7000, &copy).unwrap();
        let e = ControlBlock::find(&mut ram, &ram_scan()).unwrap_err();
        assert!(
            e.contains("2 RTT control blocks") && e.contains("0x20007000"),
            "{e}"
        );
        // Only the id, with the rest of the block still zero: not taken.
        let mut ram = SimRam::new();
        ram.write(u64::from(CONTROL_BLOCK), ID).unwrap();
        let e = ControlBlock::find(&mut ram, &ram_scan()).unwrap_err();
        assert!(e.contains("declares 0 up-"), "{e}");
    }

    #[test]
    fn telemetry_written_by_the_firmware_reads_back_in_order_across_the_wrap() {
        let mut ram = booted();
        let block = ControlBlock::find(&mut ram, &ram_scan()).unwrap();
        let mut sent = Vec::new();
        let mut got = Vec::new();
        let mut skipped = 0;
        for i in 0..2000u32 {
            let frame: Vec<u8> = (0..56).map(|k| (i * 7 + k) as u8).collect();
            if ram.write_up(UP_TELEMETRY, &frame) == frame.len() {
                sent.extend_from_slice(&frame);
            } else {
                skipped += 1;
            }
            // The host reads 1 KiB every 25 frames: slower than the firmware writes.
            if i % 25 == 0 {
                let mut link = RttChannels::with_block(&mut ram, block.clone());
                let mut buf = [0u8; 1024];
                let n = link.read_up(UP_TELEMETRY, &mut buf).unwrap();
                got.extend_from_slice(&buf[..n]);
            }
        }
        let mut link = RttChannels::with_block(&mut ram, block);
        got.extend(drain(&mut link, UP_TELEMETRY, 300));
        assert!(skipped > 0, "the host was slower: frames were skipped");
        assert!(sent.len() > 3 * TELEMETRY_BYTES, "the ring wrapped");
        assert_eq!(
            got, sent,
            "every frame written, whole and in order; none torn"
        );
    }

    #[test]
    fn commands_written_by_the_host_reach_the_firmware_and_a_full_channel_takes_part() {
        let mut ram = booted();
        let mut link = RttChannels::attach(&mut ram, &ram_scan()).unwrap();
        let bytes: Vec<u8> = (0..1000u32).map(|i| (i % 251) as u8).collect();
        let n = link.write_down(DOWN_COMMANDS, &bytes).unwrap();
        assert_eq!(n, COMMANDS_BYTES - 1, "one byte always stays free");
        assert_eq!(link.write_down(DOWN_COMMANDS, &bytes[n..]).unwrap(), 0);
        let (ram, _) = link.into_parts();
        let mut got = vec![0u8; 100];
        assert_eq!(ram.read_down(DOWN_COMMANDS, &mut got), 100);
        assert_eq!(got, bytes[..100]);
        let mut link = RttChannels::attach(&mut *ram, &ram_scan()).unwrap();
        let m = link.write_down(DOWN_COMMANDS, &bytes[n..]).unwrap();
        assert_eq!(m, 100, "the room the firmware freed, across the wrap");
        let mut rest = vec![0u8; 2000];
        let k = ram.read_down(DOWN_COMMANDS, &mut rest);
        assert_eq!(&rest[..k], &bytes[100..n + m]);
    }

    #[test]
    fn a_corrupted_block_is_an_error_naming_the_channel_not_wrong_bytes() {
        let mut ram = booted();
        let mut link = RttChannels::attach(&mut ram, &ram_scan()).unwrap();
        let descriptor = link.block().up_channel(UP_REPLIES).unwrap().descriptor;
        link.memory_mut()
            .write_word(descriptor + WRITE, 600)
            .unwrap();
        let e = link.read_up(UP_REPLIES, &mut [0u8; 64]).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidData);
        assert!(
            e.to_string()
                .contains("up-channel 2 (replies): offsets write 600"),
            "{e}"
        );
        let e = link.read_up(7, &mut [0u8; 4]).unwrap_err();
        assert!(e.to_string().contains("no RTT up-channel 7"), "{e}");
        // Found so at attach time: refused, with the reason.
        let e = RttChannels::attach(&mut ram, &ram_scan()).unwrap_err();
        assert!(e.contains("up-channel 2: offsets write 600"), "{e}");
    }

    proptest! {
        /// Any interleaving of firmware writes and host reads of any sizes: the host reads
        /// exactly the writes that were taken, in order.
        #[test]
        fn any_interleaving_delivers_what_was_taken_in_order(
            steps in proptest::collection::vec((1usize..700, 1usize..3000, any::<bool>()), 1..200)
        ) {
            let mut ram = booted();
            let block = ControlBlock::find(&mut ram, &ram_scan()).unwrap();
            let mut sent = Vec::new();
            let mut got = Vec::new();
            for (i, (write, read, host_reads)) in steps.into_iter().enumerate() {
                let bytes: Vec<u8> = (0..write).map(|k| (i * 31 + k) as u8).collect();
                let n = ram.write_up(UP_TELEMETRY, &bytes);
                prop_assert!(n == 0 || n == bytes.len());
                sent.extend_from_slice(&bytes[..n]);
                if host_reads {
                    let mut link = RttChannels::with_block(&mut ram, block.clone());
                    let mut buf = vec![0u8; read];
                    let k = link.read_up(UP_TELEMETRY, &mut buf).unwrap();
                    got.extend_from_slice(&buf[..k]);
                }
            }
            let mut link = RttChannels::with_block(&mut ram, block);
            got.extend(drain(&mut link, UP_TELEMETRY, 512));
            prop_assert_eq!(got, sent);
        }
    }
}
