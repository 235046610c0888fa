//! The simulated board's RAM: the bytes a debug probe reads and writes while the firmware
//! runs. It holds the firmware's RTT control block and channel buffers, laid out as
//! `rtt_init!` lays them out on the MCU (32-bit words, little-endian; channel table:
//! [`fpc::link::channels`]).
//!
//! The firmware's side of the channels is here: the up-channels are written with the
//! firmware's own writer ([`fpc::link::rtt_up::write_or_skip`], the one `board/rtt.rs` uses),
//! the down-channel is read the way rtt-target reads it. The host's side is
//! `link::rtt`, which knows nothing of this module: it reads and writes these bytes
//! through `link::memory::TargetMemory`, as it does a real board's through a probe.
//!
//! # Layout
//! The control block sits at [`CONTROL_BLOCK`]: 16 id bytes (`"SEGGER RTT"`, NUL-padded),
//! the number of up- and of down-channels (one word each), then one 24-byte descriptor per
//! channel, up-channels first: name pointer, buffer pointer, size, write offset, read offset,
//! flags. The channel names follow the block, then the buffers. The addresses are this
//! simulator's choice (the linker chooses them on the MCU); a host never assumes them, it
//! finds the block by its id or by the ELF's `_SEGGER_RTT` symbol.

use std::ops::Range;

use fpc::link::channels::{ChannelSpec, DOWN, UP};
use fpc::link::rtt_up::{write_or_skip, UpBuffer};

/// First address of the board's SRAM (STM32G474: SRAM1 at `0x2000_0000`).
pub const RAM_BASE: u32 = 0x2000_0000;
/// RAM simulated, bytes: the firmware's RAM budget (32 KiB).
pub const RAM_BYTES: usize = 32 * 1024;
/// Address of the RTT control block (`_SEGGER_RTT`) in the simulated RAM.
pub const CONTROL_BLOCK: u32 = RAM_BASE + 0x0400;

/// The control block's id, as it reads in RAM once the block is complete.
const ID: &[u8; 16] = b"SEGGER RTT\0\0\0\0\0\0";
/// Bytes of the control block before the first channel descriptor (id, two counts).
const HEADER_BYTES: u32 = 16 + 2 * 4;
/// Bytes of one channel descriptor (six words).
const DESCRIPTOR_BYTES: u32 = 6 * 4;
/// Word offsets within a descriptor, bytes.
const NAME: u32 = 0;
const BUFFER: u32 = 4;
const SIZE: u32 = 8;
const WRITE: u32 = 12;
const READ: u32 = 16;
const FLAGS: u32 = 20;

/// An access outside the simulated RAM.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OutsideRam {
    /// First address of the access.
    pub address: u64,
    /// Its length, bytes.
    pub len: usize,
}

impl std::fmt::Display for OutsideRam {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} bytes at {:#010x} lie outside the board's RAM ({:#010x}..{:#010x})",
            self.len,
            self.address,
            RAM_BASE,
            u64::from(RAM_BASE) + RAM_BYTES as u64
        )
    }
}

impl std::error::Error for OutsideRam {}

/// The board's RAM.
#[derive(Clone, PartialEq, Eq)]
pub struct SimRam {
    bytes: Vec<u8>,
}

impl std::fmt::Debug for SimRam {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SimRam({} bytes at {RAM_BASE:#010x})", self.bytes.len())
    }
}

impl Default for SimRam {
    fn default() -> Self {
        SimRam::new()
    }
}

impl SimRam {
    /// RAM as at power-on: all zeros, no control block yet ([`SimRam::boot_rtt`] makes it).
    pub fn new() -> SimRam {
        SimRam {
            bytes: vec![0; RAM_BYTES],
        }
    }

    /// The addresses the RAM covers.
    pub fn range() -> Range<u64> {
        u64::from(RAM_BASE)..u64::from(RAM_BASE) + RAM_BYTES as u64
    }

    fn span(&self, address: u64, len: usize) -> Result<Range<usize>, OutsideRam> {
        let outside = OutsideRam { address, len };
        let start = address
            .checked_sub(u64::from(RAM_BASE))
            .and_then(|s| usize::try_from(s).ok())
            .ok_or(outside)?;
        let end = start.checked_add(len).ok_or(outside)?;
        (end <= self.bytes.len())
            .then_some(start..end)
            .ok_or(outside)
    }

    /// Reads `buf.len()` bytes from `address` on.
    pub fn read(&self, address: u64, buf: &mut [u8]) -> Result<(), OutsideRam> {
        let span = self.span(address, buf.len())?;
        buf.copy_from_slice(self.bytes.get(span).unwrap_or_default());
        Ok(())
    }

    /// Writes `bytes` from `address` on.
    pub fn write(&mut self, address: u64, bytes: &[u8]) -> Result<(), OutsideRam> {
        let span = self.span(address, bytes.len())?;
        if let Some(dst) = self.bytes.get_mut(span) {
            dst.copy_from_slice(bytes);
        }
        Ok(())
    }

    /// The little-endian word at `address` (0 outside the RAM: the firmware's own addresses
    /// are always inside).
    fn word(&self, address: u32) -> u32 {
        let mut w = [0u8; 4];
        let _ = self.read(u64::from(address), &mut w);
        u32::from_le_bytes(w)
    }

    fn set_word(&mut self, address: u32, value: u32) {
        let _ = self.write(u64::from(address), &value.to_le_bytes());
    }

    /// What the firmware's `rtt_init!` does at every boot: the control block zeroed, each
    /// channel's descriptor filled in (its buffer pointer last), then the header (the id
    /// last, written backwards, so a host never takes a half-made block for a whole one).
    /// Bytes in flight are lost, as on a reset.
    pub fn boot_rtt(&mut self) {
        let channels = UP.len() + DOWN.len();
        let block_bytes = HEADER_BYTES + DESCRIPTOR_BYTES * channels as u32;
        let _ = self.write(u64::from(CONTROL_BLOCK), &vec![0; block_bytes as usize]);
        let mut next = CONTROL_BLOCK + block_bytes;
        let mut place = |ram: &mut SimRam, bytes: &[u8]| {
            let at = next;
            let _ = ram.write(u64::from(at), bytes);
            next = (at + bytes.len() as u32).next_multiple_of(4);
            at
        };
        let specs: Vec<(u32, &ChannelSpec)> = UP
            .iter()
            .enumerate()
            .map(|(n, s)| (up_descriptor(n), s))
            .chain(
                DOWN.iter()
                    .enumerate()
                    .map(|(n, s)| (down_descriptor(n), s)),
            )
            .collect();
        let names: Vec<u32> = specs
            .iter()
            .map(|(_, s)| place(self, format!("{}\0", s.name).as_bytes()))
            .collect();
        for ((descriptor, spec), name) in specs.iter().zip(names) {
            let buffer = place(self, &vec![0; spec.size]);
            self.set_word(descriptor + NAME, name);
            self.set_word(descriptor + SIZE, spec.size as u32);
            // Mode "no block, skip" (0), as the firmware asks for.
            self.set_word(descriptor + FLAGS, 0);
            self.set_word(descriptor + BUFFER, buffer);
        }
        self.set_word(CONTROL_BLOCK + 16, UP.len() as u32);
        self.set_word(CONTROL_BLOCK + 20, DOWN.len() as u32);
        for (i, byte) in ID.iter().enumerate().rev() {
            let _ = self.write(u64::from(CONTROL_BLOCK) + i as u64, &[*byte]);
        }
    }

    /// The firmware writes `bytes` to up-channel `channel`: all of them or, if they do not
    /// fit, none (the firmware's [`write_or_skip`]). Returns the bytes written.
    pub fn write_up(&mut self, channel: usize, bytes: &[u8]) -> usize {
        if channel >= UP.len() {
            return 0;
        }
        let mut ring = Ring {
            ram: self,
            descriptor: up_descriptor(channel),
        };
        write_or_skip(&mut ring, bytes)
    }

    /// The firmware reads what the host wrote to down-channel `channel` (at most
    /// `buf.len()` bytes) and frees that space, as rtt-target's reader does (offsets out of
    /// range, a confused host, reset the channel to empty). Returns the bytes read.
    pub fn read_down(&mut self, channel: usize, buf: &mut [u8]) -> usize {
        if channel >= DOWN.len() {
            return 0;
        }
        let d = down_descriptor(channel);
        let (buffer, size) = (self.word(d + BUFFER), self.word(d + SIZE));
        let (write, mut read) = (self.word(d + WRITE), self.word(d + READ));
        if write >= size || read >= size {
            self.set_word(d + WRITE, 0);
            self.set_word(d + READ, 0);
            return 0;
        }
        let mut total = 0;
        while total < buf.len() {
            let end = if read > write { size } else { write };
            let n = ((end - read) as usize).min(buf.len() - total);
            if n == 0 {
                break;
            }
            if let Some(dst) = buf.get_mut(total..total + n) {
                let _ = self.read(u64::from(buffer + read), dst);
            }
            total += n;
            read += n as u32;
            if read >= size {
                read = 0;
            }
        }
        self.set_word(d + READ, read);
        total
    }
}

/// Address of up-channel `n`'s descriptor.
fn up_descriptor(n: usize) -> u32 {
    CONTROL_BLOCK + HEADER_BYTES + DESCRIPTOR_BYTES * n as u32
}

/// Address of down-channel `n`'s descriptor.
fn down_descriptor(n: usize) -> u32 {
    up_descriptor(UP.len() + n)
}

/// An up-channel's ring in RAM, as the firmware's writer sees it.
struct Ring<'r> {
    ram: &'r mut SimRam,
    descriptor: u32,
}

impl UpBuffer for Ring<'_> {
    fn size(&self) -> usize {
        self.ram.word(self.descriptor + SIZE) as usize
    }
    fn read_offset(&self) -> usize {
        self.ram.word(self.descriptor + READ) as usize
    }
    fn write_offset(&self) -> usize {
        self.ram.word(self.descriptor + WRITE) as usize
    }
    fn copy_in(&mut self, at: usize, bytes: &[u8]) {
        let buffer = self.ram.word(self.descriptor + BUFFER);
        let _ = self.ram.write(u64::from(buffer) + at as u64, bytes);
    }
    fn commit(&mut self, write: usize) {
        self.ram.set_word(self.descriptor + WRITE, write as u32);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpc::link::channels::{TELEMETRY_BYTES, UP_TELEMETRY};

    #[test]
    fn the_channels_fit_the_ram_and_boot_leaves_them_empty() {
        let mut ram = SimRam::new();
        ram.boot_rtt();
        let mut id = [0u8; 16];
        ram.read(u64::from(CONTROL_BLOCK), &mut id).unwrap();
        assert_eq!(&id, ID);
        let last = down_descriptor(DOWN.len() - 1);
        let end = ram.word(last + BUFFER) + ram.word(last + SIZE);
        assert!((end as usize) < RAM_BASE as usize + RAM_BYTES, "{end:#x}");
        assert_eq!(
            ram.word(up_descriptor(UP_TELEMETRY) + SIZE) as usize,
            TELEMETRY_BYTES
        );
        assert_eq!(ram.write_up(UP_TELEMETRY, &[1; 10]), 10);
        ram.boot_rtt();
        assert_eq!(
            ram.word(up_descriptor(UP_TELEMETRY) + WRITE),
            0,
            "a reset empties"
        );
    }

    #[test]
    fn accesses_outside_the_ram_are_refused() {
        let mut ram = SimRam::new();
        let mut b = [0u8; 4];
        assert!(ram.read(u64::from(RAM_BASE) - 1, &mut b).is_err());
        assert!(ram.read(SimRam::range().end - 3, &mut b).is_err());
        assert!(ram.read(SimRam::range().end - 4, &mut b).is_ok());
        let e = ram.write(0x0800_0000, &b).unwrap_err();
        assert!(e.to_string().contains("0x08000000"), "{e}");
        assert!(ram.write(u64::MAX - 1, &b).is_err());
    }
}
