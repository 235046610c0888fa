//! The peripheral bus: a CPU access to 0x4000_0000–0x5FFF_FFFF dispatched to the model of
//! the peripheral at that address (RM0440 memory map); DAC1 and GPIOB's input register,
//! whose models are a few registers.

use super::*;

/// COMP1_CSR (COMP2..7 follow, 4 bytes apart).
const COMP_CSR: u32 = 0x4001_0200;
/// SYSCFG_CFGR2.
const SYSCFG_CFGR2: u32 = 0x4001_001C;
/// DAC3 (DAC4 follows at + 0x400).
const DAC3: u32 = 0x5000_1000;

/// GPIOB's input data register.
const GPIOB_IDR: u32 = 0x4800_0410;

impl Soc {
    /// A CPU read of a peripheral register.
    pub(super) fn periph_read(&mut self, addr: u32) -> u32 {
        let now = self.time;
        let off = |b: u32| addr - b;
        match addr {
            a if (base::TIM1..base::TIM1 + 0x400).contains(&a) => {
                self.tim1.read(off(base::TIM1), now)
            }
            a if (base::TIM8..base::TIM8 + 0x400).contains(&a) => {
                self.tim8.read(off(base::TIM8), now)
            }
            a if (base::TIM2..base::TIM2 + 0x400).contains(&a) => {
                self.tim2.read(off(base::TIM2), now)
            }
            a if (base::TIM4..base::TIM4 + 0x400).contains(&a) => {
                if off(base::TIM4) == timers::reg::CNT {
                    u32::from(self.board.quadrature())
                } else {
                    self.tim4.read(off(base::TIM4), now)
                }
            }
            a if (base::IWDG..base::IWDG + 0x400).contains(&a) => {
                self.iwdg.read(off(base::IWDG), now)
            }
            // GPIOB_IDR: PB5 is the DC link's power-good input (the board's comparator on
            // the plant's link: high while the mains holds it); the other pins read low.
            GPIOB_IDR => u32::from(self.board.power_good()) << 5,
            a if (base::FLASH..base::FLASH + 0x400).contains(&a) => {
                self.flash.read_reg(off(base::FLASH))
            }
            a if (base::ADC1..base::ADC1 + 0x100).contains(&a) => {
                self.adc1.read(off(base::ADC1), now)
            }
            a if (base::ADC2..base::ADC2 + 0x100).contains(&a) => {
                self.adc2.read(off(base::ADC2), now)
            }
            a if a == base::ADC12 + 0x08 => self.adc_ccr,
            a if a == base::ADC12 + 0x0C => {
                (self.adc1.r(adc::reg::DR) & 0xFFFF) | (self.adc2.r(adc::reg::DR) & 0xFFFF) << 16
            }
            a if (base::DMA1..base::DMA1 + 0x400).contains(&a) => self.dma.read(off(base::DMA1)),
            a if (base::DMAMUX1..base::DMAMUX1 + 0x40).contains(&a) => {
                self.dma.mux[(off(base::DMAMUX1) / 4) as usize % 16]
            }
            a if (base::DAC1..base::DAC1 + 0x400).contains(&a) => match off(base::DAC1) {
                0x00 => self.dac_cr,
                0x08 => self.dac_dhr,
                0x2C => self.dac_dhr & 0xFFF,
                0x3C => self.dac_mcr,
                _ => 0,
            },
            a if (COMP_CSR..COMP_CSR + 28).contains(&a) => {
                self.comps.read_csr(((a - COMP_CSR) / 4) as usize)
            }
            SYSCFG_CFGR2 => self.comps.cfgr2,
            a if (DAC3..DAC3 + 0x800).contains(&a) => self
                .comps
                .read_dac(((a - DAC3) / 0x400) as usize, (a - DAC3) % 0x400),
            a if a == base::RCC + 0x94 => {
                let csr = self.reg(a) & 0x00FF_FFFF;
                csr | self.csr_flags
            }
            a => self.reg(a),
        }
    }

    /// A CPU write of a peripheral register (whole word as it now stands: `value`, of which
    /// `raw` bits were written).
    pub(super) fn periph_write(&mut self, addr: u32, value: u32) {
        let now = self.time;
        let clk = self.timer_clock();
        let off = |b: u32| addr - b;
        match addr {
            a if (base::TIM1..base::TIM1 + 0x400).contains(&a) => {
                let started = self.tim1.write(off(base::TIM1), value, now, clk);
                self.timer_written(0, off(base::TIM1));
                if started {
                    self.milestone(Milestone::PwmStarted);
                }
                let mms = (self.tim1.regs[1] >> 4) & 7;
                let smcr = self.tim8.regs[2];
                let sms = (smcr & 7) | ((smcr >> 16) & 1) << 3;
                let ts = ((smcr >> 4) & 7) | ((smcr >> 20) & 3) << 3;
                // TRGO = counter enable starts TIM8 in trigger mode on ITR0 (RM0440 TIMx
                // internal trigger connection: ITR0 of TIM8 is TIM1).
                if started && mms == 1 && sms == 0b0110 && ts == 0 {
                    self.tim8.trigger_start(now, clk);
                }
            }
            a if (base::TIM8..base::TIM8 + 0x400).contains(&a) => {
                self.tim8.write(off(base::TIM8), value, now, clk);
                self.timer_written(1, off(base::TIM8));
            }
            a if (base::TIM2..base::TIM2 + 0x400).contains(&a) => {
                self.tim2.write(off(base::TIM2), value, now, clk);
            }
            a if (base::TIM4..base::TIM4 + 0x400).contains(&a) => {
                self.tim4.write(off(base::TIM4), value, now, clk);
            }
            a if (base::IWDG..base::IWDG + 0x400).contains(&a) => {
                if off(base::IWDG) == 0 && value & 0xFFFF == 0xCCCC {
                    self.milestone(Milestone::WatchdogStarted);
                }
                self.iwdg.write(off(base::IWDG), value, now)
            }
            a if (base::FLASH..base::FLASH + 0x400).contains(&a) => {
                self.flash.write_reg(off(base::FLASH), value, now);
                if std::mem::take(&mut self.flash.bus_error) {
                    // A precise data bus error (BFARVALID, PRECISERR), escalated to HardFault.
                    self.stop = Some(super::cpu::Stop::Fault((1 << 9) | (1 << 15), Some(addr)));
                }
                self.note_flash_state();
            }
            a if (base::ADC1..base::ADC1 + 0x100).contains(&a) => {
                self.adc_write(1, off(base::ADC1), value)
            }
            a if (base::ADC2..base::ADC2 + 0x100).contains(&a) => {
                self.adc_write(2, off(base::ADC2), value)
            }
            a if a == base::ADC12 + 0x08 => self.adc_ccr_write(value),
            a if (base::DMA1..base::DMA1 + 0x400).contains(&a) => {
                self.dma.write(off(base::DMA1), value)
            }
            a if (base::DMAMUX1..base::DMAMUX1 + 0x40).contains(&a) => {
                self.dma.mux[(off(base::DMAMUX1) / 4) as usize % 16] = value
            }
            a if (base::DAC1..base::DAC1 + 0x400).contains(&a) => match off(base::DAC1) {
                0x00 => self.dac_cr = value,
                0x08 => self.dac_dhr = value & 0xFFF,
                0x3C => self.dac_mcr = value,
                _ => {}
            },
            a if (base::RCC..base::RCC + 0x400).contains(&a) => self.rcc_write(a, value),
            a if (COMP_CSR..COMP_CSR + 28).contains(&a) => {
                self.comps.write_csr(((a - COMP_CSR) / 4) as usize, value)
            }
            SYSCFG_CFGR2 => self.comps.write_cfgr2(value),
            a if (DAC3..DAC3 + 0x800).contains(&a) => {
                self.comps
                    .write_dac(((a - DAC3) / 0x400) as usize, (a - DAC3) % 0x400, value)
            }
            a => {
                self.regs.insert(a, value);
            }
        }
        let moe = |t: &Timer| t.regs[(timers::reg::BDTR / 4) as usize] & (1 << 15) != 0;
        if moe(&self.tim1) || moe(&self.tim8) {
            self.milestone(Milestone::OutputsOn);
        }
        self.update_irqs();
    }
}

/// The bytes of `size` at `addr` out of the word holding it.
pub(super) fn extract(word: u32, addr: u32, size: usize) -> u32 {
    let shift = (addr & 3) * 8;
    if size >= 4 {
        word
    } else {
        (word >> shift) & ((1u32 << (8 * size)) - 1)
    }
}

/// `old` with the `size` bytes at `addr` replaced by `value`.
pub(super) fn merge(old: u32, addr: u32, size: usize, value: u32) -> u32 {
    let shift = (addr & 3) * 8;
    let mask = ((1u32 << (8 * size)) - 1) << shift;
    (old & !mask) | ((value << shift) & mask)
}
