//! ADC1 and ADC2 with their common registers (RM0440 §21), and the DMA1 channel and
//! DMAMUX route that carry the regular conversions into RAM (§12–13).
//!
//! Modelled: the power-up and calibration handshakes (ADVREGEN, ADCAL self-clearing, ADEN →
//! ADRDY, ADDIS), the injected and regular sequences (JSQR, SQR1, SMPR1/2) converted on the
//! external trigger the master's EXTSEL/JEXTSEL select, dual mode (ADC12_CCR.DUAL: the
//! master's trigger starts both; MDMA packs each regular pair into ADC12_CDR, ADC2 in the
//! high half), the conversion time from the sampling times and the ADC clock, JDR1–4 and
//! the DMA channel (circular, memory increment, NDTR, transfer-complete flag and interrupt).
//!
//! The converted value of a channel is the board's ([`super::Analog`]): which pin the
//! sequence names is the firmware's business, what that pin carries is the PCB's.

/// One ADC's registers.
#[derive(Clone, Debug)]
pub struct Adc {
    /// Register file, word index = offset / 4 (0x00–0xB4).
    pub regs: [u32; 0xB8 / 4],
}

/// Register offsets.
pub mod reg {
    /// ISR.
    pub const ISR: u32 = 0x00;
    /// CR.
    pub const CR: u32 = 0x08;
    /// CFGR.
    pub const CFGR: u32 = 0x0C;
    /// SMPR1.
    pub const SMPR1: u32 = 0x14;
    /// SMPR2.
    pub const SMPR2: u32 = 0x18;
    /// SQR1.
    pub const SQR1: u32 = 0x30;
    /// DR.
    pub const DR: u32 = 0x40;
    /// JSQR.
    pub const JSQR: u32 = 0x4C;
    /// JDR1 (JDR2..4 follow).
    pub const JDR1: u32 = 0x80;
}

/// CR bits.
const ADEN: u32 = 1;
const ADDIS: u32 = 1 << 1;
const ADSTART: u32 = 1 << 2;
const JADSTART: u32 = 1 << 3;
const ADSTP: u32 = 1 << 4;
const JADSTP: u32 = 1 << 5;
const ADCAL: u32 = 1 << 31;

/// Sampling times of the SMPx codes, ADC clock cycles.
const SAMPLE_CYCLES: [f64; 8] = [2.5, 6.5, 12.5, 24.5, 47.5, 92.5, 247.5, 640.5];
/// Conversion time after sampling at 12 bits, ADC clock cycles.
const CONVERSION_CYCLES: f64 = 12.5;

impl Adc {
    /// At reset: deep power-down, JQDIS set (RM0440 reset values).
    pub fn new() -> Self {
        let mut regs = [0; 0xB8 / 4];
        regs[(reg::CR / 4) as usize] = 0x2000_0000;
        regs[(reg::CFGR / 4) as usize] = 0x8000_0000;
        Adc { regs }
    }

    /// Register value.
    pub fn r(&self, off: u32) -> u32 {
        self.regs.get((off / 4) as usize).copied().unwrap_or(0)
    }

    fn set(&mut self, off: u32, v: u32) {
        if let Some(r) = self.regs.get_mut((off / 4) as usize) {
            *r = v;
        }
    }

    /// A CPU write.
    pub fn write(&mut self, off: u32, value: u32) {
        match off {
            reg::ISR => {
                let v = self.r(reg::ISR) & !value;
                self.set(reg::ISR, v);
            }
            reg::CR => {
                // The command bits are set by software and cleared by hardware: a 0 written
                // to them changes nothing (RM0440 ADC_CR, "rs").
                let commands = ADEN | ADDIS | ADSTART | JADSTART | ADSTP | JADSTP | ADCAL;
                let mut v = (value & !commands) | ((self.r(reg::CR) | value) & commands);
                if v & ADCAL != 0 {
                    // Calibration completes at once (its ~1 µs is below the model's grain).
                    v &= !ADCAL;
                }
                if v & ADDIS != 0 {
                    v &= !(ADDIS | ADEN | ADSTART | JADSTART);
                } else if v & ADEN != 0 {
                    let isr = self.r(reg::ISR) | 1;
                    self.set(reg::ISR, isr);
                }
                if v & ADSTP != 0 {
                    v &= !(ADSTP | ADSTART);
                }
                if v & JADSTP != 0 {
                    v &= !(JADSTP | JADSTART);
                }
                self.set(reg::CR, v);
            }
            // JDRx and DR are read-only.
            o if o == reg::DR || (reg::JDR1..reg::JDR1 + 16).contains(&o) => {}
            o => self.set(o, value),
        }
    }

    /// Whether the regular group is armed on a rising external trigger `extsel`.
    pub fn regular_armed(&self, extsel: u32) -> bool {
        let cfgr = self.r(reg::CFGR);
        self.r(reg::CR) & (ADEN | ADSTART) == (ADEN | ADSTART)
            && (cfgr >> 10) & 3 == 1
            && (cfgr >> 5) & 0x1F == extsel
    }

    /// Whether the injected group is armed on a rising external trigger `jextsel`.
    pub fn injected_armed(&self, jextsel: u32) -> bool {
        let jsqr = self.r(reg::JSQR);
        self.r(reg::CR) & (ADEN | JADSTART) == (ADEN | JADSTART)
            && (jsqr >> 7) & 3 == 1
            && (jsqr >> 2) & 0x1F == jextsel
    }

    /// The injected sequence's channels.
    pub fn injected_channels(&self) -> Vec<u32> {
        let jsqr = self.r(reg::JSQR);
        let n = (jsqr & 3) + 1;
        (0..n).map(|i| (jsqr >> (9 + 6 * i)) & 0x1F).collect()
    }

    /// The regular sequence's channels (up to the four in SQR1).
    pub fn regular_channels(&self) -> Vec<u32> {
        let sqr1 = self.r(reg::SQR1);
        let n = ((sqr1 & 0xF) + 1).min(4);
        (0..n).map(|i| (sqr1 >> (6 + 6 * i)) & 0x1F).collect()
    }

    /// ADC clock cycles to sample and convert channel `ch`.
    pub fn conversion_cycles(&self, ch: u32) -> f64 {
        let (reg, i) = if ch < 10 {
            (reg::SMPR1, ch)
        } else {
            (reg::SMPR2, ch - 10)
        };
        let code = (self.r(reg) >> (3 * i)) & 7;
        SAMPLE_CYCLES[code as usize] + CONVERSION_CYCLES
    }

    /// Stores an injected result in JDR`rank`+1 and flags JEOS.
    pub fn set_jdr(&mut self, rank: usize, value: u16) {
        self.set(reg::JDR1 + 4 * rank as u32, u32::from(value));
        let isr = self.r(reg::ISR) | (1 << 5) | (1 << 6);
        self.set(reg::ISR, isr);
    }

    /// Stores a regular result in DR and flags EOC (EOS on the last rank).
    pub fn set_dr(&mut self, value: u16, last: bool) {
        self.set(reg::DR, u32::from(value));
        let isr = self.r(reg::ISR) | (1 << 2) | if last { 1 << 3 } else { 0 };
        self.set(reg::ISR, isr);
    }
}

impl Default for Adc {
    fn default() -> Self {
        Adc::new()
    }
}

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
    fn the_sequences_and_times_come_from_the_registers() {
        let mut a = Adc::new();
        // JL = 2, JSQ1..3 = 1, 2, 3, JEXTSEL 8, JEXTEN rising.
        a.write(
            reg::JSQR,
            2 | (8 << 2) | (1 << 7) | (1 << 9) | (2 << 15) | (3 << 21),
        );
        a.write(reg::SMPR1, 1 << 3);
        a.write(reg::CR, ADEN | JADSTART);
        assert!(a.injected_armed(8));
        assert!(!a.injected_armed(9));
        assert_eq!(a.injected_channels(), vec![1, 2, 3]);
        assert_eq!(a.conversion_cycles(1), 19.0);
        assert_eq!(a.conversion_cycles(2), 15.0);
    }

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
}
