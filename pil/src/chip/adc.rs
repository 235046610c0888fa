//! ADC1 and ADC2 with their common registers (RM0440 §21); the DMA1 channel and DMAMUX
//! route that carry the regular conversions into RAM are [`super::dma`].
//!
//! Modelled: the power-up and calibration handshakes (ADVREGEN, ADCAL self-clearing, ADEN →
//! ADRDY, ADDIS), the injected and regular sequences (JSQR, SQR1, SMPR1/2) converted on the
//! external trigger the master's EXTSEL/JEXTSEL select, dual mode (ADC12_CCR.DUAL: the
//! master's trigger starts both; MDMA packs each regular pair into ADC12_CDR, ADC2 in the
//! high half), the conversion time from the sampling times and the ADC clock, JDR1–4 and
//! the hand-over of each regular pair to the DMA channel.
//!
//! The converted value of a channel is the board's ([`super::Analog`]): which pin the
//! sequence names is the firmware's business, what that pin carries is the PCB's.

use super::Soc;

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

    pub(super) fn set(&mut self, off: u32, v: u32) {
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

/// ADC12 external trigger codes of TIM1_TRGO2 (RM0440 tables 163/165).
const EXTSEL_TIM1_TRGO2: u32 = 10;
const JEXTSEL_TIM1_TRGO2: u32 = 8;

impl Soc {
    /// The ADC clock period: synchronous HCLK/1, /2, /4 (CKMODE), or the asynchronous kernel
    /// clock (SYSCLK with ADC12SEL = system) divided by PRESC.
    pub(super) fn adc_clock(&self) -> f64 {
        let ckmode = (self.adc_ccr >> 16) & 3;
        if ckmode != 0 {
            return self.units_per_cycle * self.ahb_div() * f64::from(1u32 << (ckmode - 1));
        }
        const PRESC: [f64; 12] = [1., 2., 4., 6., 8., 10., 12., 16., 32., 64., 128., 256.];
        let presc = ((self.adc_ccr >> 18) & 0xF) as usize;
        self.units_per_cycle * PRESC.get(presc).copied().unwrap_or(256.0)
    }

    /// TIM1_TRGO2: both ADCs start their injected then regular sequences if armed.
    pub(super) fn adc_trigger(&mut self) {
        let dual = self.adc_ccr & 0x1F;
        let inj = self.adc1.injected_armed(JEXTSEL_TIM1_TRGO2);
        let reg = self.adc1.regular_armed(EXTSEL_TIM1_TRGO2);
        if !(inj || reg) || self.burst.is_some() || self.adc_dead {
            return;
        }
        let clk = self.adc_clock();
        let time_of = |a: &Adc, chans: Vec<u32>| -> f64 {
            chans.iter().map(|&c| a.conversion_cycles(c)).sum::<f64>() * clk
        };
        // In dual mode the slave converts alongside; the group ends with the slower one.
        let slave = dual != 0;
        let inj_t = if inj {
            let mut t = time_of(&self.adc1, self.adc1.injected_channels());
            if slave {
                t = t.max(time_of(&self.adc2, self.adc2.injected_channels()));
            }
            t
        } else {
            0.0
        };
        let reg_t = if reg {
            let mut t = time_of(&self.adc1, self.adc1.regular_channels());
            if slave {
                t = t.max(time_of(&self.adc2, self.adc2.regular_channels()));
            }
            t
        } else {
            0.0
        };
        let now = self.time;
        let inj_end = if inj {
            now + inj_t.ceil() as u64
        } else {
            u64::MAX
        };
        let reg_end = now + (inj_t + reg_t).ceil() as u64;
        self.burst = Some((if inj { inj_end } else { u64::MAX }, reg_end));
        if !inj {
            self.burst = Some((u64::MAX, reg_end));
        }
        if !reg {
            // Only the injected group: nothing to carry by DMA.
            self.burst = Some((inj_end, u64::MAX));
        }
    }

    pub(super) fn injected_done(&mut self) {
        let dual = self.adc_ccr & 0x1F != 0;
        for (rank, ch) in self.adc1.injected_channels().into_iter().enumerate() {
            let v = self.board.analog(1, ch);
            self.adc1.set_jdr(rank, v);
        }
        if dual {
            for (rank, ch) in self.adc2.injected_channels().into_iter().enumerate() {
                let v = self.board.analog(2, ch);
                self.adc2.set_jdr(rank, v);
            }
        }
        let reg = self.burst.map(|(_, r)| r).unwrap_or(u64::MAX);
        self.burst = if reg == u64::MAX {
            None
        } else {
            Some((u64::MAX, reg))
        };
    }

    /// The regular sequence converted: each pair to ADC12_CDR and on by DMA. Returns the
    /// memory writes to make (address, word).
    pub(super) fn regular_done(&mut self) {
        self.burst = None;
        let ch1 = self.adc1.regular_channels();
        let ch2 = self.adc2.regular_channels();
        let mdma = (self.adc_ccr >> 14) & 3;
        let request = self.dma.mux[0] & 0x7F;
        let n = ch1.len();
        for (i, &c1) in ch1.iter().enumerate() {
            let a = self.board.analog(1, c1);
            let b = ch2.get(i).map(|&c| self.board.analog(2, c)).unwrap_or(0);
            self.adc1.set_dr(a, i + 1 == n);
            self.adc2.set_dr(b, i + 1 == n);
            // DMAMUX request 5 is ADC1 (RM0440 table 91); MDMA packs the pair.
            if mdma != 0 && request == 5 {
                if let Some((at, _)) = self.dma.transfer(0) {
                    let word = u32::from(a) | u32::from(b) << 16;
                    self.board.dma_writes.push((at, word));
                }
            }
        }
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
}
