//! The debug side of the chip: the core's halting-debug registers (ARMv7-M ARM C1.6: DHCSR,
//! DEMCR, DFSR) as a debugger reaches them through the debug port's memory access port, and
//! the STM32G474's DBGMCU (RM0440 §47.16: the freeze of TIM1/TIM8/TIM2/TIM4 and the IWDG while
//! the core is halted).
//!
//! What a halt does here, from the manuals:
//! - a write of DHCSR with the key 0xA05F in bits 31:16, C_DEBUGEN and C_HALT halts the core
//!   (S_HALT reads 1, DFSR.HALTED is set); C_HALT written 0 resumes it. C_DEBUGEN can only be
//!   written through the debug port: a write from the core leaves it as it is (ARMv7-M C1.6.2);
//! - while the core is halted, each timer whose DBG_TIMx_STOP bit is set stops counting, and
//!   an advanced timer's outputs are then "disabled (as if the MOE bit was reset)": with
//!   OSSI = 1 driven to their idle levels (the advanced timers' debug mode); the IWDG stops
//!   with DBG_IWDG_STOP. What is not frozen runs on: TIM2 (the firmware's time base), the ADC
//!   chain (no trigger comes from a frozen TIM1), the DAC (it holds its last code);
//! - DEMCR's vector-catch bits and TRCENA are reset by a power-on reset only: a system reset
//!   (the watchdog's, the fault path's) with VC_CORERESET set and halting debug enabled halts
//!   the core at the reset vector (C1.6.3).
//!
//! Every halt and every write of DHCSR or DEMCR through the debug port is counted, so a host
//! transport can be shown to touch neither.

/// DHCSR, DEMCR, DFSR and DBGMCU addresses.
pub mod addr {
    /// Debug Halting Control and Status Register.
    pub const DHCSR: u32 = 0xE000_EDF0;
    /// Debug Core Register Selector.
    pub const DCRSR: u32 = 0xE000_EDF4;
    /// Debug Core Register Data.
    pub const DCRDR: u32 = 0xE000_EDF8;
    /// Debug Exception and Monitor Control Register.
    pub const DEMCR: u32 = 0xE000_EDFC;
    /// Debug Fault Status Register.
    pub const DFSR: u32 = 0xE000_ED30;
    /// Flash Patch and Breakpoint control.
    pub const FP_CTRL: u32 = 0xE000_2000;
    /// DBGMCU base (IDCODE).
    pub const DBGMCU: u32 = 0xE004_2000;
}

/// DHCSR.C_DEBUGEN.
pub const C_DEBUGEN: u32 = 1;
/// DHCSR.C_HALT.
pub const C_HALT: u32 = 1 << 1;
/// DHCSR.C_STEP.
pub const C_STEP: u32 = 1 << 2;
/// DHCSR.C_MASKINTS.
pub const C_MASKINTS: u32 = 1 << 3;
/// DHCSR.S_REGRDY.
pub const S_REGRDY: u32 = 1 << 16;
/// DHCSR.S_HALT.
pub const S_HALT: u32 = 1 << 17;
/// The key a DHCSR write must carry in bits 31:16.
pub const DBGKEY: u32 = 0xA05F_0000;
/// DEMCR.VC_CORERESET.
pub const VC_CORERESET: u32 = 1;
/// DEMCR.VC_HARDERR.
pub const VC_HARDERR: u32 = 1 << 10;
/// DEMCR.TRCENA.
pub const TRCENA: u32 = 1 << 24;

/// DBGMCU_APB1FZR1 bits (RM0440): TIM2, TIM4, IWDG.
pub mod apb1 {
    /// DBG_TIM2_STOP.
    pub const TIM2: u32 = 1;
    /// DBG_TIM4_STOP.
    pub const TIM4: u32 = 1 << 2;
    /// DBG_IWDG_STOP.
    pub const IWDG: u32 = 1 << 12;
}

/// DBGMCU_APB2FZR bits (RM0440): TIM1, TIM8.
pub mod apb2 {
    /// DBG_TIM1_STOP.
    pub const TIM1: u32 = 1 << 11;
    /// DBG_TIM8_STOP.
    pub const TIM8: u32 = 1 << 13;
}

/// Who accessed a debug register.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Master {
    /// The core's own load or store.
    Core,
    /// A debugger through the debug port's memory access port.
    Dap,
}

/// The debug registers and the halt state.
#[derive(Clone, Debug, Default)]
pub struct Debug {
    /// DHCSR's control bits (C_*).
    pub dhcsr: u32,
    /// DEMCR.
    pub demcr: u32,
    /// DFSR (sticky, write 1 to clear).
    pub dfsr: u32,
    /// FP_CTRL (the breakpoint unit; a debugger clears its comparators on attach).
    pub fp_ctrl: u32,
    /// DBGMCU_CR, APB1FZR1, APB1FZR2, APB2FZR.
    pub dbgmcu: [u32; 4],
    /// The core is halted (Debug state).
    pub halted: bool,
    /// Times the core entered Debug state since power-on.
    pub halts: u32,
    /// Emulated time the core spent halted since power-on, time units.
    pub halted_units: u64,
    /// When the current halt began, time units.
    pub halted_since: Option<u64>,
    /// Writes of DHCSR through the debug port.
    pub dhcsr_writes: u32,
    /// Writes of DEMCR through the debug port.
    pub demcr_writes: u32,
    /// Reads of DHCSR through the debug port (S_RETIRE_ST, S_RESET_ST clear on read).
    pub dhcsr_reads: u32,
    /// Reads of DEMCR through the debug port.
    pub demcr_reads: u32,
}

/// What a debug register write asks of the core.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HaltRequest {
    /// Nothing changes.
    None,
    /// Enter Debug state.
    Halt,
    /// Leave Debug state.
    Resume,
}

impl Debug {
    /// The halting-debug registers' power-on state.
    pub fn new() -> Self {
        Debug::default()
    }

    /// Whether a system reset now leaves the core halted at the reset vector (vector catch).
    pub fn catches_reset(&self) -> bool {
        self.dhcsr & C_DEBUGEN != 0 && self.demcr & VC_CORERESET != 0
    }

    /// Whether the core is halted with advanced timer `i` (0: TIM1, 1: TIM8) frozen, its
    /// outputs then disabled as if MOE were 0.
    pub fn frozen_advanced(&self, i: usize) -> bool {
        let bit = if i == 0 { apb2::TIM1 } else { apb2::TIM8 };
        self.halted && self.dbgmcu[3] & bit != 0
    }

    /// Whether the core is halted with APB1 freeze bit `bit` set.
    pub fn frozen_apb1(&self, bit: u32) -> bool {
        self.halted && self.dbgmcu[1] & bit != 0
    }

    /// A read of the debug register at `a`, if it is one.
    pub fn read(&mut self, a: u32, from: Master) -> Option<u32> {
        Some(match a {
            addr::DHCSR => {
                if from == Master::Dap {
                    self.dhcsr_reads += 1;
                }
                let s = if self.halted { S_HALT | S_REGRDY } else { 0 };
                (self.dhcsr & 0xFFFF) | s
            }
            addr::DEMCR => {
                if from == Master::Dap {
                    self.demcr_reads += 1;
                }
                self.demcr
            }
            addr::DFSR => self.dfsr,
            addr::FP_CTRL => self.fp_ctrl | (6 << 4) | (2 << 8),
            a if (addr::DBGMCU + 4..addr::DBGMCU + 0x14).contains(&a) => {
                self.dbgmcu[((a - addr::DBGMCU - 4) / 4) as usize]
            }
            _ => return None,
        })
    }

    /// A write of `value` to the debug register at `a` (whole word); returns whether the core
    /// must halt or resume, or `None` if `a` is no debug register.
    pub fn write(&mut self, a: u32, value: u32, from: Master) -> Option<HaltRequest> {
        Some(match a {
            addr::DHCSR => {
                if from == Master::Dap {
                    self.dhcsr_writes += 1;
                }
                if value & 0xFFFF_0000 != DBGKEY {
                    return Some(HaltRequest::None);
                }
                let mut c = value & (C_DEBUGEN | C_HALT | C_STEP | C_MASKINTS);
                if from == Master::Core {
                    c = (c & !C_DEBUGEN) | (self.dhcsr & C_DEBUGEN);
                }
                self.dhcsr = c;
                let halt = c & C_DEBUGEN != 0 && c & C_HALT != 0;
                match (halt, self.halted) {
                    (true, false) => HaltRequest::Halt,
                    (false, true) => HaltRequest::Resume,
                    _ => HaltRequest::None,
                }
            }
            addr::DEMCR => {
                if from == Master::Dap {
                    self.demcr_writes += 1;
                }
                self.demcr = value;
                HaltRequest::None
            }
            addr::DFSR => {
                self.dfsr &= !value;
                HaltRequest::None
            }
            addr::FP_CTRL => {
                // KEY (bit 1) must be set for ENABLE to be written.
                if value & 2 != 0 {
                    self.fp_ctrl = value & 1;
                }
                HaltRequest::None
            }
            a if (addr::DBGMCU + 4..addr::DBGMCU + 0x14).contains(&a) => {
                self.dbgmcu[((a - addr::DBGMCU - 4) / 4) as usize] = value;
                HaltRequest::None
            }
            _ => return None,
        })
    }

    /// The core entered Debug state at `now`.
    pub fn entered(&mut self, now: u64) {
        self.halted = true;
        self.halts += 1;
        self.halted_since = Some(now);
        self.dfsr |= 1;
        self.dhcsr |= C_HALT;
    }

    /// The core left Debug state at `now`.
    pub fn left(&mut self, now: u64) {
        self.halted = false;
        if let Some(t) = self.halted_since.take() {
            self.halted_units += now.saturating_sub(t);
        }
    }

    /// A system reset: DHCSR's C_* bits, DEMCR and the DBGMCU registers are kept (reset
    /// only at power-on; DBGMCU is in the debug domain); the breakpoint unit too.
    pub fn system_reset(&mut self) {}

    /// A power-on reset: everything to its reset value, the counts kept.
    pub fn power_on(&mut self) {
        *self = Debug {
            halts: self.halts,
            halted_units: self.halted_units,
            dhcsr_writes: self.dhcsr_writes,
            demcr_writes: self.demcr_writes,
            dhcsr_reads: self.dhcsr_reads,
            demcr_reads: self.demcr_reads,
            ..Debug::default()
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_keyed_dap_write_halts_and_the_core_cannot_enable_halting_itself() {
        let mut d = Debug::new();
        // Without the key: ignored.
        assert_eq!(
            d.write(addr::DHCSR, C_DEBUGEN | C_HALT, Master::Dap),
            Some(HaltRequest::None)
        );
        // The core cannot set C_DEBUGEN, so it cannot halt itself.
        assert_eq!(
            d.write(addr::DHCSR, DBGKEY | C_DEBUGEN | C_HALT, Master::Core),
            Some(HaltRequest::None)
        );
        assert_eq!(
            d.write(addr::DHCSR, DBGKEY | C_DEBUGEN | C_HALT, Master::Dap),
            Some(HaltRequest::Halt)
        );
        d.entered(100);
        assert_eq!(d.read(addr::DHCSR, Master::Dap).unwrap() & S_HALT, S_HALT);
        assert_eq!(
            d.write(addr::DHCSR, DBGKEY | C_DEBUGEN, Master::Dap),
            Some(HaltRequest::Resume)
        );
        d.left(350);
        assert_eq!((d.halts, d.halted_units, d.dhcsr_writes), (1, 250, 3));
    }

    #[test]
    fn the_freeze_bits_act_only_while_halted() {
        let mut d = Debug::new();
        d.write(addr::DBGMCU + 0x10, apb2::TIM1, Master::Core);
        assert!(!d.frozen_advanced(0));
        d.entered(0);
        assert!(d.frozen_advanced(0));
        assert!(!d.frozen_advanced(1));
    }
}
