//! The private peripheral bus (0xE000_0000): the NVIC's and SCB's registers, DWT's cycle
//! counter, DBGMCU's IDCODE (ARMv7-M ARM §B3; RM0440 §47).
//!
//! The cycle counter counts while DWT_CTRL.CYCCNTENA and DEMCR.TRCENA are both set, and
//! holds its value otherwise (ARMv7-M ARM §C1.6.5: TRCENA is the DWT's global enable;
//! §C1.8.7: CYCCNTENA): a debugger that writes DEMCR = 0 on detach stops it.

use super::dap::DEMCR;
use super::*;

/// DEMCR.TRCENA: the DWT and ITM enabled.
const TRCENA: u32 = 1 << 24;

impl Soc {
    /// A CPU read of the private peripheral bus.
    pub(super) fn ppb_read(&mut self, addr: u32) -> u32 {
        match addr {
            0xE000_E100..=0xE000_E4EF => self.nvic.read_word(addr - 0xE000_E100).unwrap_or(0),
            0xE000_ED00 => 0x410F_C241,
            0xE000_ED04 => {
                let pending = self.nvic.takeable(nvic::THREAD_PRIORITY).unwrap_or(0) as u32;
                (self.ipsr as u32 & 0x1FF)
                    | (pending & 0x1FF) << 12
                    | u32::from(self.nvic.pending[nvic::PEND_SV]) << 28
                    | u32::from(self.nvic.pending[nvic::NMI]) << 31
            }
            0xE000_ED08 => self.nvic.vtor,
            0xE000_ED0C => 0xFA05_0000 | u32::from(self.nvic.prigroup) << 8,
            0xE000_ED10 => self.nvic.scr,
            0xE000_ED14 => self.nvic.ccr,
            0xE000_ED18..=0xE000_ED23 => {
                let first = (addr - 0xE000_ED18) as usize + 4;
                (0..4).fold(0, |acc, i| {
                    acc | u32::from(self.nvic.priority[first + i]) << (8 * i)
                })
            }
            0xE000_ED24 => self.nvic.shcsr,
            0xE000_ED28 => self.nvic.cfsr,
            0xE000_ED2C => self.nvic.hfsr,
            0xE000_ED38 => self.nvic.bfar,
            0xE000_1000 => self.dwt_ctrl,
            0xE000_1004 => self.cyccnt(),
            0xE004_2000 => 0x1000_6469, // DBGMCU_IDCODE: STM32G47x/48x, rev Z
            a => self.reg(a),
        }
    }

    pub(super) fn ppb_write(&mut self, addr: u32, value: u32, mask: u32) {
        let (counting, count) = (self.dwt_counting(), self.cyccnt());
        self.ppb_store(addr, value, mask);
        match (counting, self.dwt_counting()) {
            (true, false) => self.dwt_held = count,
            (false, true) => self.dwt_base = self.cycles_back(self.dwt_held),
            _ => {}
        }
    }

    /// Whether the cycle counter counts: DWT_CTRL.CYCCNTENA and DEMCR.TRCENA.
    fn dwt_counting(&self) -> bool {
        self.dwt_ctrl & 1 != 0 && self.reg(DEMCR) & TRCENA != 0
    }

    /// The cycle counter's value now.
    fn cyccnt(&self) -> u32 {
        if self.dwt_counting() {
            ((self.time - self.dwt_base) as f64 / self.units_per_cycle) as u64 as u32
        } else {
            self.dwt_held
        }
    }

    /// The time `cycles` core clocks ago (not before 0).
    fn cycles_back(&self, cycles: u32) -> u64 {
        self.time
            .saturating_sub((f64::from(cycles) * self.units_per_cycle) as u64)
    }

    fn ppb_store(&mut self, addr: u32, value: u32, mask: u32) {
        match addr & !3 {
            a @ 0xE000_E100..=0xE000_E4EF => self.nvic.write(a - 0xE000_E100, value, mask),
            0xE000_EF00 => self.nvic.write(0xE00, value, mask),
            0xE000_ED04 => {
                if value & (1 << 28) != 0 {
                    self.nvic.pending[nvic::PEND_SV] = true;
                }
                if value & (1 << 27) != 0 {
                    self.nvic.pending[nvic::PEND_SV] = false;
                }
                if value & (1 << 26) != 0 {
                    self.nvic.pending[nvic::SYS_TICK] = true;
                }
                if value & (1 << 31) != 0 {
                    self.nvic.pending[nvic::NMI] = true;
                }
            }
            0xE000_ED08 => self.nvic.vtor = value & !0x7F,
            0xE000_ED0C => {
                if value >> 16 == 0x05FA {
                    self.nvic.prigroup = ((value >> 8) & 7) as u8;
                    if value & 4 != 0 {
                        self.reset_pending = Some(ResetKind::Software);
                    }
                }
            }
            0xE000_ED10 => self.nvic.scr = value,
            0xE000_ED14 => self.nvic.ccr = value,
            a @ 0xE000_ED18..=0xE000_ED23 => {
                let first = (a - 0xE000_ED18) as usize + 4;
                for i in 0..4 {
                    if mask >> (8 * i) & 0xFF != 0 {
                        self.nvic.set_priority(first + i, (value >> (8 * i)) as u8);
                    }
                }
            }
            0xE000_ED24 => self.nvic.shcsr = value,
            0xE000_ED28 => self.nvic.cfsr &= !value,
            0xE000_ED2C => self.nvic.hfsr &= !value,
            0xE000_1000 => self.dwt_ctrl = value,
            0xE000_1004 => {
                // CYCCNT written: count on (or hold) from that value.
                self.dwt_held = value;
                self.dwt_base = self.cycles_back(value);
            }
            a => {
                let old = self.reg(a);
                self.regs.insert(a, (old & !mask) | (value & mask));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::dap::DEMCR;
    use super::super::{ChipOptions, Soc};
    use super::TRCENA;
    use crate::board::Board;

    const DWT_CTRL: u32 = 0xE000_1000;
    const CYCCNT: u32 = 0xE000_1004;

    fn soc() -> Soc {
        let opts = hal_sim::run::RunOptions::reference();
        let world = hal_sim::run::world(&opts.model, opts.seed, 0, 1e-3);
        Soc::new(&ChipOptions::default(), Board::new(world))
    }

    /// ARMv7-M ARM §C1.6.5, §C1.8.7: CYCCNT counts only with TRCENA and CYCCNTENA both set,
    /// holds its value while either is clear, and counts on from it.
    #[test]
    fn the_cycle_counter_counts_only_with_trcena_and_cyccntena() {
        let mut s = soc();
        let cycles = |s: &Soc, n: u32| (f64::from(n) * s.units_per_cycle) as u64;
        s.ppb_write(DWT_CTRL, 1, u32::MAX);
        s.time += cycles(&s, 1_000);
        assert_eq!(s.ppb_read(CYCCNT), 0, "CYCCNTENA without TRCENA");
        s.ppb_write(DEMCR, TRCENA, u32::MAX);
        s.time += cycles(&s, 1_000);
        assert_eq!(s.ppb_read(CYCCNT), 1_000);
        // A debugger's detach writing DEMCR = 0 stops it where it is.
        s.ppb_write(DEMCR, 0, u32::MAX);
        s.time += cycles(&s, 5_000);
        assert_eq!(s.ppb_read(CYCCNT), 1_000);
        s.ppb_write(DEMCR, TRCENA, u32::MAX);
        s.time += cycles(&s, 500);
        assert_eq!(s.ppb_read(CYCCNT), 1_500);
        // CYCCNTENA cleared: held too; a written value is where it goes on from.
        s.ppb_write(DWT_CTRL, 0, u32::MAX);
        s.ppb_write(CYCCNT, 7, u32::MAX);
        s.time += cycles(&s, 500);
        assert_eq!(s.ppb_read(CYCCNT), 7);
        s.ppb_write(DWT_CTRL, 1, u32::MAX);
        s.time += cycles(&s, 3);
        assert_eq!(s.ppb_read(CYCCNT), 10);
    }
}
