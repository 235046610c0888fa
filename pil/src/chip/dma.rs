//! DMA1 and DMAMUX1 (RM0440 §12–13): the channel that carries the ADCs' regular
//! conversions into RAM (circular, memory increment, NDTR, transfer-complete flag and
//! interrupt).

/// DMA1 (channel registers 20 bytes apart from 0x08) and DMAMUX1's channel routes.
#[derive(Clone, Debug, Default)]
pub struct Dma {
    /// ISR.
    pub isr: u32,
    /// Per channel: CCR, CNDTR, CPAR, CMAR.
    pub ch: [[u32; 4]; 8],
    /// NDTR reload value of each channel (what was written while disabled).
    pub reload: [u32; 8],
    /// DMAMUX1 CxCR (request id in bits 0..7).
    pub mux: [u32; 16],
}

impl Dma {
    /// A CPU read of DMA1 at `off`.
    pub fn read(&self, off: u32) -> u32 {
        match off {
            0x00 => self.isr,
            0x08..=0xA3 => {
                let c = ((off - 0x08) / 20) as usize;
                let r = ((off - 0x08) % 20 / 4) as usize;
                self.ch
                    .get(c)
                    .and_then(|ch| ch.get(r))
                    .copied()
                    .unwrap_or(0)
            }
            _ => 0,
        }
    }

    /// A CPU write of DMA1 at `off`.
    pub fn write(&mut self, off: u32, value: u32) {
        match off {
            0x04 => {
                // IFCR: clearing GIFx clears all of channel x's flags.
                for c in 0..8 {
                    let nibble = (value >> (4 * c)) & 0xF;
                    if nibble & 1 != 0 {
                        self.isr &= !(0xF << (4 * c));
                    } else {
                        self.isr &= !(nibble << (4 * c));
                    }
                }
            }
            0x08..=0xA3 => {
                let c = ((off - 0x08) / 20) as usize;
                let r = ((off - 0x08) % 20 / 4) as usize;
                if c < 8 && r < 4 {
                    if r == 1 {
                        self.reload[c] = value & 0xFFFF;
                    }
                    self.ch[c][r] = value;
                }
            }
            _ => {}
        }
    }

    /// Transfers one word of a peripheral request on channel `c`: where to write it in
    /// memory, or `None` if the channel is off. Counts NDTR down, reloads it in circular
    /// mode and sets the flags; returns the address and whether the transfer completed.
    pub fn transfer(&mut self, c: usize) -> Option<(u32, bool)> {
        let [ccr, ndtr, _par, mar] = self.ch[c];
        if ccr & 1 == 0 || ndtr == 0 {
            return None;
        }
        let msize = 1u32 << ((ccr >> 10) & 3);
        let done = self.reload[c].saturating_sub(ndtr);
        let at = if ccr & (1 << 7) != 0 {
            mar + done * msize
        } else {
            mar
        };
        let left = ndtr - 1;
        let complete = left == 0;
        // Flags: GIF (0), TCIF (1), HTIF (2).
        let mut flags = 1;
        if complete {
            flags |= 2;
        }
        if left == self.reload[c] / 2 {
            flags |= 4;
        }
        self.isr |= flags << (4 * c);
        self.ch[c][1] = if complete && ccr & (1 << 5) != 0 {
            self.reload[c]
        } else {
            left
        };
        Some((at, complete))
    }

    /// A peripheral's request on channel `c`, `value` what its peripheral register (CPAR)
    /// reads: the memory write it makes — address, bytes (MSIZE) and the data read at PSIZE
    /// (zero-extended, or truncated to MSIZE; RM0440 §12, "Programmable data width") — or
    /// `None` if the channel is off, or set to read memory (DIR = 1: nothing lands in memory).
    pub fn peripheral_to_memory(&mut self, c: usize, value: u32) -> Option<(u32, u32, u32)> {
        let ccr = self.ch[c][0];
        let (at, _) = self.transfer(c)?;
        if ccr & (1 << 4) != 0 {
            return None;
        }
        let width = |code: u32| 8 * (1u32 << code.min(2));
        let read = match width(ccr >> 8 & 3) {
            32 => value,
            w => value & ((1 << w) - 1),
        };
        let msize = width(ccr >> 10 & 3) / 8;
        let data = match msize {
            4 => read,
            m => read & ((1 << (8 * m)) - 1),
        };
        Some((at, msize, data))
    }

    /// The interrupt line of channel `c`: a flag enabled in CCR (TCIE 1, HTIE 2, TEIE 3).
    pub fn irq(&self, c: usize) -> bool {
        let ccr = self.ch[c][0];
        let flags = (self.isr >> (4 * c)) & 0xF;
        (flags & 2 != 0 && ccr & 2 != 0)
            || (flags & 4 != 0 && ccr & 4 != 0)
            || (flags & 8 != 0 && ccr & 8 != 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_circular_channel_completes_every_ndtr_words() {
        let mut d = Dma::default();
        d.write(0x0C, 4);
        d.write(0x14, 0x2000_0100);
        // EN, TCIE, CIRC, MINC, 32-bit.
        d.write(0x08, 1 | 2 | (1 << 5) | (1 << 7) | (2 << 8) | (2 << 10));
        let at: Vec<_> = (0..5).map(|_| d.transfer(0).unwrap()).collect();
        assert_eq!(
            at,
            vec![
                (0x2000_0100, false),
                (0x2000_0104, false),
                (0x2000_0108, false),
                (0x2000_010C, true),
                (0x2000_0100, false),
            ]
        );
        assert!(d.irq(0));
        d.write(0x04, 1);
        assert!(!d.irq(0));
    }

    /// RM0440 §12 (DMA_CCRx: DIR, PSIZE, MSIZE; "Programmable data width, alignment and
    /// endianness"): the channel reads PSIZE bits of its peripheral register and writes them
    /// zero-extended at MSIZE; with DIR = 1 it reads memory, so nothing lands there.
    #[test]
    fn the_data_width_and_direction_come_from_the_channel() {
        let mut d = Dma::default();
        d.write(0x0C, 4);
        d.write(0x14, 0x2000_0100);
        // EN, MINC, PSIZE 32, MSIZE 32.
        d.write(0x08, 1 | (1 << 7) | (2 << 8) | (2 << 10));
        assert_eq!(
            d.peripheral_to_memory(0, 0x0ABC_0123),
            Some((0x2000_0100, 4, 0x0ABC_0123))
        );
        // PSIZE 16: the high half (ADC2's code in ADC12_CDR) is lost.
        d.write(0x08, 0);
        d.write(0x08, 1 | (1 << 7) | (1 << 8) | (2 << 10));
        assert_eq!(
            d.peripheral_to_memory(0, 0x0ABC_0123),
            Some((0x2000_0104, 4, 0x0123))
        );
        d.write(0x08, 0);
        d.write(0x08, 1 | (1 << 4) | (1 << 7) | (2 << 8) | (2 << 10));
        assert_eq!(d.peripheral_to_memory(0, 0x0ABC_0123), None);
    }
}
