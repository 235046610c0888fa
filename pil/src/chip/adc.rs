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
//!
//! As RM0440's ADC chapter states it (ADC_CR, ADC_JSQR, ADC_CFGR, ADCx_CCR; "ADC on-off
//! control", "Calibration"): the ADC leaves deep power-down only with DEEPPWD = 0, its
//! regulator needs tADCVREG_STUP (20 µs, datasheet) after ADVREGEN before a calibration or an
//! enable does anything, a calibration takes 116 ADC clock cycles (ADCAL reads 1 meanwhile);
//! ADEN gives ADRDY only then; JSQR is not written while JADSTART = 1, nor CFGR, SMPRx, SQRx
//! while a conversion is started (ADSTART or JADSTART), nor the common CCR's dual-mode,
//! DMA-mode and clock fields while either ADC is enabled; without a kernel clock (ADC12SEL =
//! 0 in asynchronous mode) nothing converts or calibrates; in dual mode the slave converts only
//! if it is itself enabled. Written from RM0440 rev. 8 as the team read it and ST's SVD field
//! layouts (stm32-metapac 21, `adc_g4`); each rule cited in its unit test.

use super::Soc;

/// One ADC's registers.
#[derive(Clone, Debug)]
pub struct Adc {
    /// Register file, word index = offset / 4 (0x00–0xB4).
    pub regs: [u32; 0xB8 / 4],
    /// When the voltage regulator is up (ADVREGEN set, DEEPPWD clear, tADCVREG_STUP later).
    vreg_ready_at: Option<u64>,
    /// A calibration in progress ends at this time (ADCAL reads 1 until then).
    cal_until: Option<u64>,
}

/// The regulator's start-up, time units (datasheet tADCVREG_STUP, 20 µs).
const VREG_STARTUP: u64 = 20 * crate::time::UNITS_PER_US;
/// A calibration's length, ADC clock cycles.
const CALIBRATION_CYCLES: f64 = 116.0;
/// ADC_CR.DEEPPWD, ADVREGEN.
const DEEPPWD: u32 = 1 << 29;
const ADVREGEN: u32 = 1 << 28;

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
        Adc {
            regs,
            vreg_ready_at: None,
            cal_until: None,
        }
    }

    /// Whether the regulator is up at `now`.
    fn regulator_up(&self, now: u64) -> bool {
        self.vreg_ready_at.is_some_and(|t| now >= t)
    }

    /// A CPU read at `now`: a calibration in progress reads ADCAL = 1 until it ends.
    pub fn read(&mut self, off: u32, now: u64) -> u32 {
        if let Some(end) = self.cal_until {
            if now >= end {
                self.cal_until = None;
                let cr = self.r(reg::CR) & !ADCAL;
                self.set(reg::CR, cr);
            }
        }
        self.r(off)
    }

    /// Whether the ADC is enabled and ready (ADEN with ADRDY reached).
    pub fn ready(&self) -> bool {
        self.r(reg::CR) & ADEN != 0 && self.r(reg::ISR) & 1 != 0
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

    /// A CPU write at `now`; `clock` is the ADC clock's period (None: no kernel clock).
    pub fn write(&mut self, off: u32, value: u32, now: u64, clock: Option<f64>) {
        let cr = self.r(reg::CR);
        let converting = cr & (ADSTART | JADSTART) != 0;
        match off {
            reg::ISR => {
                let v = self.r(reg::ISR) & !value;
                self.set(reg::ISR, v);
            }
            // Not written while an injected conversion is started (ADC_JSQR).
            reg::JSQR if cr & JADSTART != 0 => {}
            // Not written while a conversion is started (ADC_CFGR, ADC_SMPRx, ADC_SQRx).
            reg::CFGR | reg::SMPR1 | reg::SMPR2 | reg::SQR1 if converting => {}
            reg::CR => {
                // The command bits are set by software and cleared by hardware: a 0 written
                // to them changes nothing (RM0440 ADC_CR, "rs").
                let commands = ADEN | ADDIS | ADSTART | JADSTART | ADSTP | JADSTP | ADCAL;
                let mut v = (value & !commands) | ((cr | value) & commands);
                if v & DEEPPWD != 0 || v & ADVREGEN == 0 {
                    self.vreg_ready_at = None;
                } else if self.vreg_ready_at.is_none() {
                    self.vreg_ready_at = Some(now + VREG_STARTUP);
                }
                let powered = self.regulator_up(now) && clock.is_some();
                if value & ADCAL != 0 && cr & ADCAL == 0 {
                    match (powered, clock) {
                        (true, Some(c)) => {
                            self.cal_until = Some(now + (CALIBRATION_CYCLES * c).ceil() as u64);
                        }
                        // No regulator or no clock: the calibration never runs, nor ends.
                        _ => self.cal_until = None,
                    }
                }
                if v & ADDIS != 0 {
                    v &= !(ADDIS | ADEN | ADSTART | JADSTART);
                } else if v & ADEN != 0 {
                    if powered && self.cal_until.is_none() {
                        let isr = self.r(reg::ISR) | 1;
                        self.set(reg::ISR, isr);
                    } else if !powered {
                        // Enabled without a regulator or a clock: never ready.
                        v &= !ADEN;
                    }
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
        self.ready()
            && self.r(reg::CR) & ADSTART != 0
            && (cfgr >> 10) & 3 == 1
            && (cfgr >> 5) & 0x1F == extsel
    }

    /// Whether the injected group is armed on a rising external trigger `jextsel`.
    pub fn injected_armed(&self, jextsel: u32) -> bool {
        let jsqr = self.r(reg::JSQR);
        self.ready()
            && self.r(reg::CR) & JADSTART != 0
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
    /// clock RCC_CCIPR.ADC12SEL selects (1: PLL "P", 2: SYSCLK) divided by PRESC; None
    /// without one (ADC12SEL = 0, or the PLL's P output off).
    pub(super) fn adc_clock(&self) -> Option<f64> {
        let ckmode = (self.adc_ccr >> 16) & 3;
        if ckmode != 0 {
            return Some(self.units_per_cycle * self.ahb_div() * f64::from(1u32 << (ckmode - 1)));
        }
        let kernel = match (self.reg(super::base::RCC + 0x88) >> 28) & 3 {
            2 => self.units_per_cycle,
            1 => self.pll_p_period()?,
            _ => return None,
        };
        const PRESC: [f64; 12] = [1., 2., 4., 6., 8., 10., 12., 16., 32., 64., 128., 256.];
        let presc = ((self.adc_ccr >> 18) & 0xF) as usize;
        Some(kernel * PRESC.get(presc).copied().unwrap_or(256.0))
    }

    /// A CPU write of ADC1 (`n` 1) or ADC2 (2).
    pub(super) fn adc_write(&mut self, n: u8, off: u32, value: u32) {
        let (now, clock) = (self.time, self.adc_clock());
        let adc = if n == 1 {
            &mut self.adc1
        } else {
            &mut self.adc2
        };
        adc.write(off, value, now, clock);
    }

    /// A CPU write of ADC12_CCR: its DUAL, DELAY, DMACFG, MDMA, CKMODE and PRESC fields only
    /// while both ADCs are disabled (ADCx_CCR).
    pub(super) fn adc_ccr_write(&mut self, value: u32) {
        const LOCKED_WHILE_ENABLED: u32 =
            0x1F | 0xF << 8 | 0x3 << 13 | 0x3 << 14 | 0x3 << 16 | 0xF << 18;
        let enabled = (self.adc1.r(reg::CR) | self.adc2.r(reg::CR)) & ADEN != 0;
        let mask = if enabled { !LOCKED_WHILE_ENABLED } else { !0 };
        self.adc_ccr = (self.adc_ccr & !mask) | (value & mask);
    }

    /// TIM1_TRGO2 at `at` (time units): both ADCs start their injected then regular sequences
    /// if armed.
    pub(super) fn adc_trigger(&mut self, at: u64) {
        let dual = self.adc_ccr & 0x1F;
        let inj = self.adc1.injected_armed(JEXTSEL_TIM1_TRGO2);
        let reg = self.adc1.regular_armed(EXTSEL_TIM1_TRGO2);
        if !(inj || reg) || self.burst.is_some() || self.adc_dead {
            return;
        }
        let Some(clk) = self.adc_clock() else {
            return;
        };
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
        // The burst starts at the trigger's instant, which the emulator handles at the first
        // block boundary after it.
        let now = at;
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
        // The slave converts only if it is itself enabled.
        if dual && self.adc2.ready() {
            for (rank, ch) in self.adc2.injected_channels().into_iter().enumerate() {
                let v = self.board.analog(2, ch);
                self.adc2.set_jdr(rank, v);
            }
        }
        let reg = self.burst.map(|(_, r)| r).unwrap_or(u64::MAX);
        self.burst = if reg == u64::MAX {
            let inj = self.burst.map_or(self.time, |(i, _)| i);
            self.burst_ended(inj);
            None
        } else {
            Some((u64::MAX, reg))
        };
    }

    /// The regular sequence converted: each pair to ADC12_CDR and on by DMA. Returns the
    /// memory writes to make (address, word).
    pub(super) fn regular_done(&mut self) {
        let end = self.burst.map_or(self.time, |(_, r)| r);
        self.burst = None;
        self.burst_ended(end);
        let ch1 = self.adc1.regular_channels();
        let ch2 = self.adc2.regular_channels();
        let request = self.dma.mux[0] & 0x7F;
        let n = ch1.len();
        let slave = self.adc_ccr & 0x1F != 0 && self.adc2.ready();
        for (i, &c1) in ch1.iter().enumerate() {
            let a = self.board.analog(1, c1);
            self.adc1.set_dr(a, i + 1 == n);
            if slave {
                let b = ch2.get(i).map(|&c| self.board.analog(2, c)).unwrap_or(0);
                self.adc2.set_dr(b, i + 1 == n);
            }
            // DMAMUX request 5 is ADC1 (RM0440 table 91): the channel reads what its CPAR
            // points at (ADC12_CDR packs the pair in MDMA mode, ADC1_DR is the master's).
            let mdma = (self.adc_ccr >> 14) & 3;
            if request == 5 && (mdma != 0 || self.adc1.r(reg::CFGR) & 1 != 0) {
                let cpar = self.dma.ch[0][2];
                let value = self.periph_read(cpar & !3);
                if let Some((at, size, word)) = self.dma.peripheral_to_memory(0, value) {
                    self.board.dma_writes.push((at, word, size));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CLK: Option<f64> = Some(32.0);

    /// When [`ready_adc`]'s ADC is ready.
    const READY_AT: u64 = VREG_STARTUP + (CALIBRATION_CYCLES * 32.0) as u64;

    /// An ADC out of deep power-down with its regulator up, calibrated and enabled.
    fn ready_adc() -> Adc {
        let mut a = Adc::new();
        a.write(reg::CR, ADVREGEN, 0, CLK);
        let t = VREG_STARTUP;
        a.write(reg::CR, ADVREGEN | ADCAL, t, CLK);
        let t = t + (CALIBRATION_CYCLES * 32.0) as u64;
        a.read(reg::CR, t);
        a.write(reg::CR, ADVREGEN | ADEN, t, CLK);
        assert!(a.ready());
        a
    }

    #[test]
    fn the_sequences_and_times_come_from_the_registers() {
        let mut a = ready_adc();
        // JL = 2, JSQ1..3 = 1, 2, 3, JEXTSEL 8, JEXTEN rising.
        a.write(
            reg::JSQR,
            2 | (8 << 2) | (1 << 7) | (1 << 9) | (2 << 15) | (3 << 21),
            READY_AT,
            CLK,
        );
        a.write(reg::SMPR1, 1 << 3, READY_AT, CLK);
        a.write(reg::CR, ADVREGEN | ADEN | JADSTART, READY_AT, CLK);
        assert!(a.injected_armed(8));
        assert!(!a.injected_armed(9));
        assert_eq!(a.injected_channels(), vec![1, 2, 3]);
        assert_eq!(a.conversion_cycles(1), 19.0);
        assert_eq!(a.conversion_cycles(2), 15.0);
    }

    /// RM0440, ADC_JSQR: "the software is allowed to write these bits only when JADSTART = 0";
    /// ADC_CFGR, ADC_SMPRx, ADC_SQRx: only when ADSTART = 0 and JADSTART = 0.
    #[test]
    fn jsqr_is_not_written_while_an_injected_conversion_is_started() {
        let mut a = ready_adc();
        a.write(reg::JSQR, 1 << 9, READY_AT, CLK);
        a.write(reg::CR, ADVREGEN | ADEN | JADSTART, READY_AT, CLK);
        a.write(reg::JSQR, 5 << 9, READY_AT, CLK);
        assert_eq!(a.r(reg::JSQR), 1 << 9);
        a.write(reg::SMPR1, 7, READY_AT, CLK);
        assert_eq!(a.r(reg::SMPR1), 0);
        a.write(reg::CR, ADVREGEN | ADEN | JADSTP, READY_AT, CLK);
        a.write(reg::JSQR, 5 << 9, READY_AT, CLK);
        assert_eq!(a.r(reg::JSQR), 5 << 9);
    }

    /// RM0440, "ADC on-off control" and "Calibration": DEEPPWD = 0 and ADVREGEN = 1, then
    /// tADCVREG_STUP (20 µs, datasheet), before ADCAL or ADEN do anything; ADCAL reads 1 for
    /// the calibration's 116 ADC clock cycles; without a kernel clock nothing happens.
    #[test]
    fn the_regulator_start_up_and_the_calibration_take_their_time() {
        let mut a = Adc::new();
        a.write(reg::CR, ADEN, 0, CLK);
        assert!(!a.ready(), "in deep power-down");
        a.write(reg::CR, ADVREGEN, 0, CLK);
        a.write(reg::CR, ADVREGEN | ADEN, VREG_STARTUP / 2, CLK);
        assert!(!a.ready(), "before the regulator is up");
        a.write(reg::CR, ADVREGEN | ADCAL, VREG_STARTUP, CLK);
        assert_ne!(a.read(reg::CR, VREG_STARTUP + 100) & ADCAL, 0);
        let done = VREG_STARTUP + (CALIBRATION_CYCLES * 32.0) as u64;
        assert_eq!(a.read(reg::CR, done) & ADCAL, 0);
        let mut b = Adc::new();
        b.write(reg::CR, ADVREGEN, 0, None);
        b.write(reg::CR, ADVREGEN | ADEN, VREG_STARTUP, None);
        assert!(!b.ready(), "no ADC clock (ADC12SEL = 0)");
    }
}
