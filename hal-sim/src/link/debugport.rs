//! The board's memory through the debug port's memory access port (MEM-AP), never through a
//! debug session: what the host link needs of a running machine, and nothing that can stop it.
//!
//! probe-rs 0.32's `Session` halts the core when it attaches (to clear the breakpoint unit:
//! `Session::new` → `clear_all_hw_breakpoints` → `halted_access`, `probe-rs/src/session.rs`)
//! and again when it is dropped, and single-steps it before letting it run (`Armv7m::run`);
//! upstream issue probe-rs#3135, "Attach without halting", is open. A halt freezes TIM1/TIM8
//! with their outputs idle while TIM2 runs on (the firmware's DBGMCU setting): the force is
//! cut for as long as the probe's round trips take, then the firmware stops the machine. So
//! the link goes around the session: it powers the debug port up, selects the MEM-AP and
//! moves 32-bit words to and from RAM (the RTT control block and its buffers) — the same bus
//! accesses a debugger's memory view makes while the core runs.
//!
//! [`MemAccessPort`] is what a transport must give: attach, word reads, word writes, detach.
//! The probe implements it with probe-rs's ARM debug interface (feature `probe`,
//! [`crate::link::probe`]); the PIL implements it on the emulated chip's debug port, whose
//! DHCSR/DEMCR accesses and halts are counted, so the test of a capture runs this very code.
//! [`NonHalting`] puts the RTT transport ([`TargetMemory`]) on top and refuses, by
//! construction, every address outside RAM and the peripherals: the core's System Control
//! Space (DHCSR at 0xE000_EDF0, DEMCR at 0xE000_EDFC, the breakpoint and watchpoint units) and
//! DBGMCU are never read or written.

use std::io;

use super::memory::TargetMemory;

/// A debug port's memory access port: 32-bit accesses to the target's bus while it runs.
pub trait MemAccessPort {
    /// Connects: powers the debug port up and selects the memory access port. Touches no core
    /// register (no halt, no DHCSR or DEMCR access).
    fn attach(&mut self) -> io::Result<()>;
    /// Reads `words.len()` words from the word-aligned `address` on, one bus access each.
    fn read_words(&mut self, address: u32, words: &mut [u32]) -> io::Result<()>;
    /// Writes `words` from the word-aligned `address` on, one bus access each.
    fn write_words(&mut self, address: u32, words: &[u32]) -> io::Result<()>;
    /// Disconnects. Touches no core register.
    fn detach(&mut self) -> io::Result<()>;
}

/// Lowest address the link refuses: the Cortex-M4's private peripheral bus (ITM, DWT, FPB,
/// the System Control Space with DHCSR and DEMCR) and the vendor system region (DBGMCU).
pub const FIRST_REFUSED: u32 = 0xE000_0000;

/// The board's memory for the RTT transport, through a [`MemAccessPort`], restricted to the
/// addresses below [`FIRST_REFUSED`].
#[derive(Debug)]
pub struct NonHalting<P: MemAccessPort> {
    port: P,
}

impl<P: MemAccessPort> NonHalting<P> {
    /// Attaches through `port`.
    pub fn attach(mut port: P) -> io::Result<NonHalting<P>> {
        port.attach()?;
        Ok(NonHalting { port })
    }

    /// The port.
    pub fn port(&self) -> &P {
        &self.port
    }

    /// The port, mutably (to step an emulated target between accesses).
    pub fn port_mut(&mut self) -> &mut P {
        &mut self.port
    }

    /// Detaches, giving the port back. (Dropped instead, the port is released by its own
    /// drop: probe-rs closes the debug interface.)
    pub fn detach(mut self) -> io::Result<P> {
        self.port.detach()?;
        Ok(self.port)
    }

    /// The words covering `address..address + len`, checked against the refused range.
    fn span(address: u64, len: usize) -> io::Result<(u32, usize)> {
        let end = address
            .checked_add(len as u64)
            .filter(|&e| e <= u64::from(FIRST_REFUSED))
            .ok_or_else(|| {
                io::Error::new(
                    io::ErrorKind::PermissionDenied,
                    format!(
                        "{address:#x}+{len}: the link reaches RAM and the peripherals only, \
                         never the core's debug registers (0xE000_0000 and up)"
                    ),
                )
            })?;
        let first = (address & !3) as u32;
        let words = end.div_ceil(4) as usize - (address / 4) as usize;
        Ok((first, words))
    }
}

impl<P: MemAccessPort> TargetMemory for NonHalting<P> {
    fn read(&mut self, address: u64, buf: &mut [u8]) -> io::Result<()> {
        if buf.is_empty() {
            return Ok(());
        }
        let (first, n) = Self::span(address, buf.len())?;
        let mut words = vec![0u32; n];
        self.port.read_words(first, &mut words)?;
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        let skip = (address - u64::from(first)) as usize;
        buf.copy_from_slice(&bytes[skip..skip + buf.len()]);
        Ok(())
    }

    /// Whole words are written as they are; the bytes of a partial word are merged into
    /// what it holds (the down-channel's data: the firmware reads it, never writes it).
    fn write(&mut self, address: u64, bytes: &[u8]) -> io::Result<()> {
        if bytes.is_empty() {
            return Ok(());
        }
        let (first, n) = Self::span(address, bytes.len())?;
        let skip = (address - u64::from(first)) as usize;
        let mut words = vec![0u32; n];
        let partial = skip != 0 || !(skip + bytes.len()).is_multiple_of(4);
        if partial {
            self.port.read_words(first, &mut words)?;
        }
        let mut raw: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        raw[skip..skip + bytes.len()].copy_from_slice(bytes);
        let words: Vec<u32> = raw
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        self.port.write_words(first, &words)
    }

    fn read_words(&mut self, address: u64, words: &mut [u32]) -> io::Result<()> {
        let (first, _) = Self::span(address, 4 * words.len())?;
        self.port.read_words(first, words)
    }

    fn write_word(&mut self, address: u64, word: u32) -> io::Result<()> {
        let (first, _) = Self::span(address, 4)?;
        self.port.write_words(first, &[word])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 64 bytes of RAM at 0x2000_0000, every access logged.
    #[derive(Default)]
    struct Logged {
        ram: Vec<u32>,
        log: Vec<(char, u32)>,
    }

    impl MemAccessPort for Logged {
        fn attach(&mut self) -> io::Result<()> {
            self.ram = vec![0; 16];
            Ok(())
        }
        fn read_words(&mut self, address: u32, words: &mut [u32]) -> io::Result<()> {
            for (i, w) in words.iter_mut().enumerate() {
                let a = address + 4 * i as u32;
                self.log.push(('r', a));
                *w = self.ram[((a - 0x2000_0000) / 4) as usize];
            }
            Ok(())
        }
        fn write_words(&mut self, address: u32, words: &[u32]) -> io::Result<()> {
            for (i, w) in words.iter().enumerate() {
                let a = address + 4 * i as u32;
                self.log.push(('w', a));
                self.ram[((a - 0x2000_0000) / 4) as usize] = *w;
            }
            Ok(())
        }
        fn detach(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn bytes_go_as_aligned_words_and_partial_words_are_merged() {
        let mut m = NonHalting::attach(Logged::default()).unwrap();
        m.write(0x2000_0003, &[1, 2, 3]).unwrap();
        let mut b = [0u8; 8];
        m.read(0x2000_0000, &mut b).unwrap();
        assert_eq!(b, [0, 0, 0, 1, 2, 3, 0, 0]);
        assert!(m.port().log.iter().all(|(_, a)| a % 4 == 0));
        m.write_word(0x2000_0008, 0xDEAD_BEEF).unwrap();
        let mut w = [0u32; 1];
        m.read_words(0x2000_0008, &mut w).unwrap();
        assert_eq!(w[0], 0xDEAD_BEEF);
    }

    #[test]
    fn the_debug_registers_are_refused_before_any_access() {
        let mut m = NonHalting::attach(Logged::default()).unwrap();
        for (a, n) in [(0xE000_EDF0u64, 4usize), (0xE000_EDFC, 4), (0xDFFF_FFFE, 4)] {
            let e = m.read(a, &mut vec![0; n]).unwrap_err();
            assert_eq!(e.kind(), io::ErrorKind::PermissionDenied);
            assert!(m.write_word(a, 0).is_err());
        }
        assert!(m.port().log.is_empty(), "{:?}", m.port().log);
    }
}
