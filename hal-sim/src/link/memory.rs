//! A target's memory as a debug probe sees it: bytes read and written at addresses while the
//! target runs. It is all the RTT transport ([`crate::link::rtt`]) needs of a target, so the
//! same transport runs on a real board (through probe-rs), on the simulated board's RAM
//! ([`crate::board::ram::SimRam`], implemented here) and on an emulated firmware image
//! (implemented where the emulator lives).
//!
//! # Implementing it
//! Two methods, [`TargetMemory::read`] and [`TargetMemory::write`], over any address type
//! the implementer has; errors are [`std::io::Error`]s whose message names the address.
//! The 32-bit word accessors have defaults built on them (little-endian, as on a
//! Cortex-M). On a target that runs while it is read (a real board), override
//! [`TargetMemory::read_words`] and [`TargetMemory::write_word`] so each aligned word is one
//! 32-bit bus access: the RTT offsets are words the firmware updates as it runs, and a word
//! read byte by byte can be torn. Memory that is stopped while it is accessed (the
//! simulator, an emulator between instructions) can keep the defaults.
//!
//! ```
//! use std::io;
//! use hal_sim::link::memory::TargetMemory;
//!
//! /// 1 KiB of RAM at 0x2000_0000, say an emulator's.
//! struct Ram(Vec<u8>);
//!
//! impl TargetMemory for Ram {
//!     fn read(&mut self, address: u64, buf: &mut [u8]) -> io::Result<()> {
//!         let at = address.checked_sub(0x2000_0000).ok_or(io::ErrorKind::InvalidInput)? as usize;
//!         let src = self.0.get(at..at + buf.len()).ok_or(io::ErrorKind::InvalidInput)?;
//!         buf.copy_from_slice(src);
//!         Ok(())
//!     }
//!     fn write(&mut self, address: u64, bytes: &[u8]) -> io::Result<()> {
//!         let at = address.checked_sub(0x2000_0000).ok_or(io::ErrorKind::InvalidInput)? as usize;
//!         let dst = self.0.get_mut(at..at + bytes.len()).ok_or(io::ErrorKind::InvalidInput)?;
//!         dst.copy_from_slice(bytes);
//!         Ok(())
//!     }
//! }
//!
//! let mut ram = Ram(vec![0; 1024]);
//! ram.write_word(0x2000_0010, 0xDEAD_BEEF).unwrap();
//! let mut w = [0u32; 1];
//! ram.read_words(0x2000_0010, &mut w).unwrap();
//! assert_eq!(w[0], 0xDEAD_BEEF);
//! ```

use std::io;

use crate::board::ram::SimRam;

/// A target's memory, read and written at byte addresses (32-bit targets: the addresses
/// fit a `u32`; `u64` as probe-rs has them).
pub trait TargetMemory {
    /// Reads `buf.len()` bytes from `address` on. An address the target does not map is an
    /// error, never zeros.
    fn read(&mut self, address: u64, buf: &mut [u8]) -> io::Result<()>;

    /// Writes `bytes` from `address` on.
    fn write(&mut self, address: u64, bytes: &[u8]) -> io::Result<()>;

    /// Reads `words.len()` little-endian 32-bit words from `address` (4-byte aligned) on;
    /// each word must be read in one access on a running target (see the module header).
    fn read_words(&mut self, address: u64, words: &mut [u32]) -> io::Result<()> {
        let mut bytes = vec![0u8; 4 * words.len()];
        self.read(address, &mut bytes)?;
        for (w, b) in words.iter_mut().zip(bytes.chunks_exact(4)) {
            *w = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        Ok(())
    }

    /// Writes one little-endian 32-bit word at `address` (4-byte aligned), in one access on
    /// a running target.
    fn write_word(&mut self, address: u64, word: u32) -> io::Result<()> {
        self.write(address, &word.to_le_bytes())
    }
}

impl<M: TargetMemory + ?Sized> TargetMemory for &mut M {
    fn read(&mut self, address: u64, buf: &mut [u8]) -> io::Result<()> {
        (**self).read(address, buf)
    }
    fn write(&mut self, address: u64, bytes: &[u8]) -> io::Result<()> {
        (**self).write(address, bytes)
    }
    fn read_words(&mut self, address: u64, words: &mut [u32]) -> io::Result<()> {
        (**self).read_words(address, words)
    }
    fn write_word(&mut self, address: u64, word: u32) -> io::Result<()> {
        (**self).write_word(address, word)
    }
}

impl<M: TargetMemory + ?Sized> TargetMemory for Box<M> {
    fn read(&mut self, address: u64, buf: &mut [u8]) -> io::Result<()> {
        (**self).read(address, buf)
    }
    fn write(&mut self, address: u64, bytes: &[u8]) -> io::Result<()> {
        (**self).write(address, bytes)
    }
    fn read_words(&mut self, address: u64, words: &mut [u32]) -> io::Result<()> {
        (**self).read_words(address, words)
    }
    fn write_word(&mut self, address: u64, word: u32) -> io::Result<()> {
        (**self).write_word(address, word)
    }
}

/// The simulated board's RAM, as a probe sees it.
impl TargetMemory for SimRam {
    fn read(&mut self, address: u64, buf: &mut [u8]) -> io::Result<()> {
        SimRam::read(self, address, buf).map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))
    }

    fn write(&mut self, address: u64, bytes: &[u8]) -> io::Result<()> {
        SimRam::write(self, address, bytes)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))
    }
}
