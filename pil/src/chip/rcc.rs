//! RCC (RM0440 §7): the clocks from the PLL registers, the reset flags, the peripheral
//! resets of the xxxRSTR registers; PWR, and the reset values of the register-file
//! peripherals; the system reset of every peripheral.

use super::*;

/// RCC_CSR reset flags.
pub(super) const RCC_CSR_BORRSTF: u32 = 1 << 27;
pub(super) const RCC_CSR_PINRSTF: u32 = 1 << 26;
pub(super) const RCC_CSR_SFTRSTF: u32 = 1 << 28;
pub(super) const RCC_CSR_IWDGRSTF: u32 = 1 << 29;

/// Reset values of the register-file peripherals (RM0440), where not 0.
pub(super) fn reset_value(addr: u32) -> u32 {
    match addr {
        0x4002_1000 => 0x0000_0500, // RCC_CR: HSION, HSIRDY
        0x4002_1008 => 0x0000_0005, // RCC_CFGR: HSI16
        0x4002_100C => 0x0000_1000, // RCC_PLLCFGR
        0x4002_1094 => 0x0000_0000, // RCC_CSR (the flags are kept apart)
        0x4000_7000 => 0x0000_0200, // PWR_CR1: range 1
        0x4000_7008 => 0x0000_8000, // PWR_CR3
        0x4000_7080 => 0x0000_0100, // PWR_CR5: R1MODE = 1
        0x4800_0000 => 0xABFF_FFFF, // GPIOA_MODER
        0x4800_0400 => 0xFFFF_FEBF, // GPIOB_MODER
        0x4800_0800 | 0x4800_0C00 | 0x4800_1000 | 0x4800_1400 | 0x4800_1800 => 0xFFFF_FFFF,
        0xE000_EF34 => 0xC000_0000, // FPCCR: ASPEN, LSPEN
        _ => 0,
    }
}

impl Soc {
    /// Peripheral registers to their values after a system reset (RAM and flash contents
    /// stay; the RCC keeps its reset flags; the IWDG stops; the plant goes on).
    pub(super) fn reset_peripherals(&mut self) {
        self.units_per_cycle = units_per_cycle(16_000_000);
        self.sysclk_hz = 16_000_000;
        self.nvic = Nvic::default();
        self.ipsr = 0;
        self.branch = None;
        self.return_due = None;
        self.fetch_line = u32::MAX;
        self.blocks.forget_ram();
        self.event = false;
        self.sleeping = false;
        self.stop = None;
        self.regs.clear();
        self.tim1 = Timer::new(0xFFFF);
        self.tim8 = Timer::new(0xFFFF);
        self.tim2 = Timer::new(0xFFFF_FFFF);
        self.tim4 = Timer::new(0xFFFF);
        self.adc1 = Adc::new();
        self.adc2 = Adc::new();
        self.adc_ccr = 0;
        self.dma = Dma::default();
        self.flash.reset();
        self.comps = super::comp::Comparators::default();
        self.iwdg = Iwdg::new(self.iwdg.lsi_hz);
        self.dac_dhr = 0;
        self.dac_cr = 0;
        self.dac_mcr = 0;
        self.dwt_ctrl = 0;
        self.dwt_held = 0;
        self.burst = None;
        self.plant_next = self.time + 50 * UNITS_PER_US;
        self.reset_pending = None;
        self.path_open = false;
        self.sample_dropped();
        self.caches_cleared();
        self.hang_pending = false;
        self.stall_until = None;
        self.locked_up = false;
        self.bus_fault_pending = false;
        self.board.dma_writes.clear();
        self.watch_word = None;
        self.control_entry = None;
    }

    /// The timer kernel clock period (APB prescalers are 1 in this firmware; an APB
    /// prescaler > 1 would double it, RM0440 §7.2).
    pub(super) fn timer_clock(&self) -> f64 {
        self.units_per_cycle * self.ahb_div()
    }

    pub(super) fn ahb_div(&self) -> f64 {
        let hpre = (self.reg(base::RCC + 0x08) >> 4) & 0xF;
        if hpre < 8 {
            1.0
        } else {
            [2.0, 4.0, 8.0, 16.0, 64.0, 128.0, 256.0, 512.0][(hpre - 8) as usize]
        }
    }

    /// The PLL's "P" output period, time units, if enabled (RCC_PLLCFGR: PLLPEN, PLLPDIV or
    /// PLLP).
    pub(super) fn pll_p_period(&self) -> Option<f64> {
        let pll = self.reg(base::RCC + 0x0C);
        if pll & (1 << 16) == 0 {
            return None;
        }
        let input = match pll & 3 {
            3 => 24_000_000u64,
            _ => 16_000_000,
        };
        let m = u64::from((pll >> 4) & 0xF) + 1;
        let n = u64::from((pll >> 8) & 0x7F);
        let pdiv = u64::from(pll >> 27);
        let p = match pdiv {
            0 if pll & (1 << 17) != 0 => 17,
            0 => 7,
            d => d,
        };
        let hz = (input / m * n / p).max(1);
        Some(crate::time::units_per_cycle(hz))
    }

    pub(super) fn reg(&self, addr: u32) -> u32 {
        self.regs
            .get(&addr)
            .copied()
            .unwrap_or_else(|| reset_value(addr))
    }

    /// The SYSCLK the RCC selects now.
    pub(super) fn sysclk(&self) -> u64 {
        let cfgr = self.reg(base::RCC + 0x08);
        match cfgr & 3 {
            3 => {
                let pll = self.reg(base::RCC + 0x0C);
                let input = match pll & 3 {
                    3 => 24_000_000u64,
                    _ => 16_000_000,
                };
                let m = u64::from((pll >> 4) & 0xF) + 1;
                let n = u64::from((pll >> 8) & 0x7F);
                let r = 2 * (u64::from((pll >> 25) & 3) + 1);
                input / m * n / r
            }
            2 => 24_000_000,
            _ => 16_000_000,
        }
    }

    pub(super) fn clocks_changed(&mut self) {
        let hz = self.sysclk();
        if hz == self.sysclk_hz {
            return;
        }
        self.sysclk_hz = hz;
        self.units_per_cycle = units_per_cycle(hz);
        let (now, clk) = (self.time, self.timer_clock());
        for t in [
            &mut self.tim1,
            &mut self.tim8,
            &mut self.tim2,
            &mut self.tim4,
        ] {
            t.clock_changed(now, clk);
        }
    }

    pub(super) fn rcc_write(&mut self, addr: u32, value: u32) {
        let o = addr - base::RCC;
        let mut v = value;
        match o {
            // CR: the oscillators and the PLL are ready as soon as enabled.
            0x00 => {
                v &= !((1 << 10) | (1 << 17) | (1 << 25));
                v |= ((v >> 8) & 1) << 10 | ((v >> 16) & 1) << 17 | ((v >> 24) & 1) << 25;
            }
            // CFGR: SWS follows SW.
            0x08 => v = (v & !0xC) | ((v & 3) << 2),
            // BDCR, CSR, CRRCR: xxxRDY follows xxxON.
            0x90 | 0x98 => v = (v & !2) | ((v & 1) << 1),
            0x94 => {
                v = (v & !2) | ((v & 1) << 1);
                if v & (1 << 23) != 0 {
                    // RMVF clears the reset flags.
                    self.csr_flags = 0;
                    v &= !(1 << 23);
                }
            }
            0x28 | 0x2C | 0x38 | 0x40 => {
                for bit in 0..32 {
                    if v >> bit & 1 == 1 {
                        self.reset_block(o, bit);
                    }
                }
            }
            _ => {}
        }
        self.regs.insert(addr, v);
        if o == 0x08 || o == 0x0C {
            self.clocks_changed();
        }
        if o == 0x08 && v & 3 == 3 {
            self.milestone(Milestone::Pll);
        }
    }

    /// RCC_xxxRSTR bit `bit` of register `o` set: that peripheral back to reset values.
    pub(super) fn reset_block(&mut self, o: u32, bit: u32) {
        let clk = self.timer_clock();
        let _ = clk;
        match (o, bit) {
            (0x28, 0) => {
                self.dma = Dma {
                    mux: self.dma.mux,
                    ..Dma::default()
                }
            }
            (0x28, 2) => self.dma.mux = [0; 16],
            (0x2C, 13) => {
                self.adc1 = Adc::new();
                self.adc2 = Adc::new();
                self.adc_ccr = 0;
            }
            (0x2C, 16) => {
                self.dac_cr = 0;
                self.dac_dhr = 0;
                self.dac_mcr = 0;
            }
            (0x38, 0) => self.tim2 = Timer::new(0xFFFF_FFFF),
            (0x38, 2) => self.tim4 = Timer::new(0xFFFF),
            (0x38, 28) => {
                let pwr = base::PWR;
                self.regs.retain(|&a, _| !(pwr..pwr + 0x400).contains(&a));
            }
            (0x40, 11) => self.tim1 = Timer::new(0xFFFF),
            (0x40, 13) => self.tim8 = Timer::new(0xFFFF),
            _ => {}
        }
    }
}
