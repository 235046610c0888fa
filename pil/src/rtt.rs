//! The RTT control block in the emulated target's RAM, read and written as a debug probe
//! does (SEGGER's layout, as rtt-target builds it): the up-channels are drained by moving
//! their read offset, the down-channel is filled by moving its write offset. Nothing else
//! of the target is touched.

use crate::chip::{Chip, ChipError};

/// Bytes of the header before the first channel: the 16-byte id and two counts.
const HEADER: u32 = 24;
/// Bytes of one channel descriptor: name, buffer, size, write, read, flags.
const CHANNEL: u32 = 24;

/// The control block of a running target.
#[derive(Clone, Copy, Debug)]
pub struct Rtt {
    base: u32,
    up: u32,
    down: u32,
}

fn word(chip: &Chip, at: u32) -> Result<u32, ChipError> {
    let mut b = [0u8; 4];
    chip.read_mem(at, &mut b)?;
    Ok(u32::from_le_bytes(b))
}

impl Rtt {
    /// The control block at `base`, once the target has initialised it (its id reads
    /// "SEGGER RTT"); `None` before.
    pub fn attach(chip: &Chip, base: u32) -> Result<Option<Rtt>, ChipError> {
        let mut id = [0u8; 16];
        chip.read_mem(base, &mut id)?;
        if !id.starts_with(b"SEGGER RTT") {
            return Ok(None);
        }
        let up = word(chip, base + 16)?;
        let down = word(chip, base + 20)?;
        if up > 16 || down > 16 {
            return Ok(None);
        }
        Ok(Some(Rtt { base, up, down }))
    }

    fn desc(&self, up: bool, channel: u32) -> Option<u32> {
        let (first, n) = if up {
            (self.base + HEADER, self.up)
        } else {
            (self.base + HEADER + self.up * CHANNEL, self.down)
        };
        (channel < n).then(|| first + channel * CHANNEL)
    }

    /// Reads what up-channel `channel` holds into `out`, as a probe does.
    pub fn read_up(
        &self,
        chip: &mut Chip,
        channel: u32,
        out: &mut Vec<u8>,
    ) -> Result<usize, ChipError> {
        let Some(d) = self.desc(true, channel) else {
            return Ok(0);
        };
        let buffer = word(chip, d + 4)?;
        let size = word(chip, d + 8)?;
        let write = word(chip, d + 12)?;
        let mut read = word(chip, d + 16)?;
        if size == 0 || write >= size || read >= size {
            return Ok(0);
        }
        let mut n = 0;
        while read != write {
            let end = if write > read { write } else { size };
            let mut chunk = vec![0u8; (end - read) as usize];
            chip.read_mem(buffer + read, &mut chunk)?;
            n += chunk.len();
            out.extend_from_slice(&chunk);
            read = if end == size { 0 } else { end };
        }
        chip.write_mem(d + 16, &read.to_le_bytes())?;
        Ok(n)
    }

    /// Writes as much of `bytes` as down-channel `channel` has room for; returns how many.
    pub fn write_down(
        &self,
        chip: &mut Chip,
        channel: u32,
        bytes: &[u8],
    ) -> Result<usize, ChipError> {
        let Some(d) = self.desc(false, channel) else {
            return Ok(0);
        };
        let buffer = word(chip, d + 4)?;
        let size = word(chip, d + 8)?;
        let mut write = word(chip, d + 12)?;
        let read = word(chip, d + 16)?;
        if size == 0 || write >= size || read >= size {
            return Ok(0);
        }
        let mut n = 0;
        for &b in bytes {
            let next = (write + 1) % size;
            if next == read {
                break;
            }
            chip.write_mem(buffer + write, &[b])?;
            write = next;
            n += 1;
        }
        chip.write_mem(d + 12, &write.to_le_bytes())?;
        Ok(n)
    }
}
