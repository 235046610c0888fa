//! The NVIC and the SCB's exception registers (ARMv7-M ARM B1.5, B3.2, B3.4): enables,
//! pending and active bits, priorities with PRIGROUP, and the choice of the exception to
//! take. Unicorn 2 has none of this (its `armv7m_nvic_*` functions are stubs and its
//! exception exit is a no-op), so the chip takes exceptions itself ([`super::cpu`]).
//!
//! Exception numbers as the architecture counts them: 2 NMI, 3 HardFault, 4–6 the
//! configurable faults, 11 SVCall, 14 PendSV, 15 SysTick, 16 + n the device's IRQ n.

/// Exceptions the chip has: 16 system slots and the STM32G474's 102 interrupts (RM0440
/// table 97).
pub const EXCEPTIONS: usize = 16 + 102;

/// NMI.
pub const NMI: usize = 2;
/// HardFault.
pub const HARD_FAULT: usize = 3;
/// PendSV.
pub const PEND_SV: usize = 14;
/// SysTick.
pub const SYS_TICK: usize = 15;

/// Exception number of device interrupt `irq`.
pub const fn irq(n: usize) -> usize {
    16 + n
}

/// Priority of thread mode: below every exception.
pub const THREAD_PRIORITY: i32 = 256;

/// Priority bits the STM32G4 implements (the top four of each byte).
const PRIORITY_MASK: u8 = 0xF0;

/// NVIC and SCB exception state.
#[derive(Clone, Debug)]
pub struct Nvic {
    /// Interrupt enables (system exceptions are always enabled).
    pub enabled: [bool; EXCEPTIONS],
    /// Pending bits.
    pub pending: [bool; EXCEPTIONS],
    /// Active bits (taken and not yet returned).
    pub active: [bool; EXCEPTIONS],
    /// Priority bytes (system handlers from SHPR1–3, interrupts from NVIC_IPR).
    pub priority: [u8; EXCEPTIONS],
    /// AIRCR.PRIGROUP.
    pub prigroup: u8,
    /// VTOR.
    pub vtor: u32,
    /// SCR (SEVONPEND is bit 4).
    pub scr: u32,
    /// CCR.
    pub ccr: u32,
    /// SHCSR.
    pub shcsr: u32,
    /// CFSR (MMFSR, BFSR, UFSR).
    pub cfsr: u32,
    /// HFSR.
    pub hfsr: u32,
    /// BFAR.
    pub bfar: u32,
}

impl Default for Nvic {
    fn default() -> Self {
        let mut enabled = [false; EXCEPTIONS];
        enabled[..16].fill(true);
        Nvic {
            enabled,
            pending: [false; EXCEPTIONS],
            active: [false; EXCEPTIONS],
            priority: [0; EXCEPTIONS],
            prigroup: 0,
            vtor: 0,
            scr: 0,
            // STKALIGN set at reset on the Cortex-M4.
            ccr: 0x200,
            shcsr: 0,
            cfsr: 0,
            hfsr: 0,
            bfar: 0,
        }
    }
}

impl Nvic {
    /// The group (pre-emption) priority of exception `n`: fixed −3..−1 for Reset, NMI and
    /// HardFault, else the priority byte with the subpriority bits cleared.
    pub fn group_priority(&self, n: usize) -> i32 {
        match n {
            1 => -3,
            NMI => -2,
            HARD_FAULT => -1,
            _ => {
                let sub_bits = u32::from(self.prigroup) + 1;
                let mask = (0xFFu32 << sub_bits) & 0xFF;
                (u32::from(self.priority[n]) & mask) as i32
            }
        }
    }

    /// The execution priority from the active exceptions alone (no masks).
    pub fn active_priority(&self) -> i32 {
        (1..EXCEPTIONS)
            .filter(|&n| self.active[n])
            .map(|n| self.group_priority(n))
            .min()
            .unwrap_or(THREAD_PRIORITY)
    }

    /// The execution priority with PRIMASK and BASEPRI applied (B1.5.4).
    pub fn execution_priority(&self, primask: bool, basepri: u8) -> i32 {
        let mut p = self.active_priority();
        if basepri != 0 {
            let sub_bits = u32::from(self.prigroup) + 1;
            let mask = (0xFFu32 << sub_bits) & 0xFF;
            p = p.min((u32::from(basepri & PRIORITY_MASK) & mask) as i32);
        }
        if primask {
            p = p.min(0);
        }
        p
    }

    /// The pending, enabled exception of highest priority (lowest number wins a tie) that
    /// may pre-empt `execution_priority`, if any.
    pub fn takeable(&self, execution_priority: i32) -> Option<usize> {
        let mut best: Option<(i32, usize)> = None;
        for n in 1..EXCEPTIONS {
            if !(self.pending[n] && self.enabled[n]) {
                continue;
            }
            let p = self.group_priority(n);
            if p < execution_priority && best.is_none_or(|(bp, _)| p < bp) {
                best = Some((p, n));
            }
        }
        best.map(|(_, n)| n)
    }

    /// Whether any enabled exception is pending (a cheap test before [`Nvic::takeable`]).
    pub fn any_pending(&self) -> bool {
        self.pending
            .iter()
            .zip(&self.enabled)
            .any(|(&p, &e)| p && e)
    }

    /// Sets a priority byte as the hardware stores it (unimplemented low bits read 0).
    pub fn set_priority(&mut self, n: usize, value: u8) {
        if (4..EXCEPTIONS).contains(&n) {
            self.priority[n] = value & PRIORITY_MASK;
        }
    }

    /// Reads one of the NVIC's word registers at offset `off` from 0xE000_E100, if it is one.
    pub fn read_word(&self, off: u32) -> Option<u32> {
        let bits = |v: &[bool; EXCEPTIONS], word: u32| -> u32 {
            (0..32).fold(0, |acc, b| {
                let n = 16 + (word * 32 + b) as usize;
                if n < EXCEPTIONS && v[n] {
                    acc | (1 << b)
                } else {
                    acc
                }
            })
        };
        match off {
            0x000..=0x03C => Some(bits(&self.enabled, off / 4)),
            0x080..=0x0BC => Some(bits(&self.enabled, (off - 0x80) / 4)),
            0x100..=0x13C => Some(bits(&self.pending, (off - 0x100) / 4)),
            0x180..=0x1BC => Some(bits(&self.pending, (off - 0x180) / 4)),
            0x200..=0x23C => Some(bits(&self.active, (off - 0x200) / 4)),
            0x300..=0x3EF => {
                let first = 16 + (off - 0x300) as usize;
                Some((0..4).fold(0, |acc, i| {
                    let n = first + i;
                    let p = if n < EXCEPTIONS { self.priority[n] } else { 0 };
                    acc | u32::from(p) << (8 * i)
                }))
            }
            _ => None,
        }
    }

    /// Writes the bytes `mask` of `value` to the NVIC register at offset `off` from
    /// 0xE000_E100 (set/clear registers act on the bits written as 1).
    pub fn write(&mut self, off: u32, value: u32, mask: u32) {
        let word_bits = |word: u32| (0..32).map(move |b| (16 + (word * 32 + b) as usize, b));
        let v = value & mask;
        match off & !3 {
            o @ 0x000..=0x03C => {
                for (n, b) in word_bits(o / 4) {
                    if n < EXCEPTIONS && v >> b & 1 == 1 {
                        self.enabled[n] = true;
                    }
                }
            }
            o @ 0x080..=0x0BC => {
                for (n, b) in word_bits((o - 0x80) / 4) {
                    if n < EXCEPTIONS && v >> b & 1 == 1 {
                        self.enabled[n] = false;
                    }
                }
            }
            o @ 0x100..=0x13C => {
                for (n, b) in word_bits((o - 0x100) / 4) {
                    if n < EXCEPTIONS && v >> b & 1 == 1 {
                        self.pending[n] = true;
                    }
                }
            }
            o @ 0x180..=0x1BC => {
                for (n, b) in word_bits((o - 0x180) / 4) {
                    if n < EXCEPTIONS && v >> b & 1 == 1 {
                        self.pending[n] = false;
                    }
                }
            }
            o @ 0x300..=0x3EF => {
                let first = 16 + (o - 0x300) as usize;
                for i in 0..4 {
                    if mask >> (8 * i) & 0xFF != 0 {
                        self.set_priority(first + i, (value >> (8 * i)) as u8);
                    }
                }
            }
            0xE00 => {
                // STIR (0xE000_EF00): pends interrupt INTID.
                let n = 16 + (value & 0x1FF) as usize;
                if n < EXCEPTIONS {
                    self.pending[n] = true;
                }
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_higher_priority_interrupt_preempts_and_ties_go_to_the_lower_number() {
        let mut n = Nvic::default();
        for (irq_n, p) in [(11, 0x10), (53, 0x20), (28, 0x30)] {
            n.enabled[irq(irq_n)] = true;
            n.set_priority(irq(irq_n), p);
            n.pending[irq(irq_n)] = true;
        }
        assert_eq!(n.takeable(THREAD_PRIORITY), Some(irq(11)));
        n.pending[irq(11)] = false;
        n.active[irq(11)] = true;
        // Active at 0x10: the 0x20 one waits.
        assert_eq!(n.takeable(n.active_priority()), None);
        n.active[irq(11)] = false;
        assert_eq!(n.takeable(n.execution_priority(false, 0)), Some(irq(53)));
        // PRIMASK masks all configurable priorities, BASEPRI those at or below it.
        assert_eq!(n.takeable(n.execution_priority(true, 0)), None);
        assert_eq!(n.takeable(n.execution_priority(false, 0x20)), None);
        assert_eq!(n.takeable(n.execution_priority(false, 0x30)), Some(irq(53)));
    }

    #[test]
    fn registers_read_back_as_written() {
        let mut n = Nvic::default();
        n.write(0x004, 1 << 21, !0); // ISER1 bit 21: IRQ 53
        assert!(n.enabled[irq(53)]);
        assert_eq!(n.read_word(0x004), Some(1 << 21));
        n.write(0x300 + 52, 0x2F << 8, 0xFF00); // IPR byte 53
        assert_eq!(n.priority[irq(53)], 0x20);
        n.write(0xE00, 53, !0);
        assert!(n.pending[irq(53)]);
        n.write(0x184, 1 << 21, !0);
        assert!(!n.pending[irq(53)]);
    }
}
