//! The private peripheral bus (0xE000_0000): the NVIC's and SCB's registers, DWT's cycle
//! counter, DBGMCU's IDCODE (ARMv7-M ARM §B3; RM0440 §47).

use super::*;

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
            0xE000_1004 => {
                if self.dwt_ctrl & 1 != 0 {
                    ((self.time - self.dwt_base) as f64 / self.units_per_cycle) as u64 as u32
                } else {
                    0
                }
            }
            0xE004_2000 => 0x1000_6469, // DBGMCU_IDCODE: STM32G47x/48x, rev Z
            a => self.reg(a),
        }
    }

    pub(super) fn ppb_write(&mut self, addr: u32, value: u32, mask: u32) {
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
            0xE000_1000 => {
                if value & 1 != 0 && self.dwt_ctrl & 1 == 0 {
                    self.dwt_base = self.time;
                }
                self.dwt_ctrl = value;
            }
            0xE000_1004 => {
                // CYCCNT written: count on from that value.
                self.dwt_base = self
                    .time
                    .saturating_sub((f64::from(value) * self.units_per_cycle) as u64);
            }
            a => {
                let old = self.reg(a);
                self.regs.insert(a, (old & !mask) | (value & mask));
            }
        }
    }
}
