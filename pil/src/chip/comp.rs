//! The comparators COMP1–7 and the internal DACs that set their thresholds (DAC3, DAC4), and
//! SYSCFG_CFGR2's system break locks (RM0440 §24 COMP, §22 DAC, §9 SYSCFG).
//!
//! - COMPx_CSR (SYSCFG + 0x200 + 4·(x − 1)): EN, INMSEL (4: the comparator's DAC3/DAC4
//!   channel — DAC3_CH1 for COMP1/3, DAC3_CH2 for COMP2/4, DAC4_CH1 for COMP5/7, DAC4_CH2 for
//!   COMP6; 0–3: fractions of VREFINT), INPSEL (its pin IO1 or IO2), POL, VALUE (read only:
//!   the output) and LOCK (the whole register read-only until reset, LOCK included).
//! - The output is high when the non-inverting input is above the inverting one, inverted
//!   by POL; the board says what voltage each input pin carries.
//! - DAC3/DAC4: DHR12Rx is the output (no trigger), in force with ENx; MCR's MODE and HFSEL
//!   are kept as written (the channels here only feed the comparators).
//! - SYSCFG_CFGR2: CLL, SPL, PVDL, ECCL are set-once (cleared only by reset).
//!
//! Timing: the output follows the inputs after [`PROPAGATION_NS`], an assumption of the
//! board model (the datasheet's propagation delay of the G4's fast comparators is tens of
//! ns; checked on the bench, `docs/bring-up.md`).
//!
//! The manual's text is not in this repository's references: written from RM0440 rev. 8
//! as the team read it and ST's SVD field layouts (stm32-metapac 21, `comp_v2`, `dac_v3`,
//! `syscfg_g4`), each rule cited in its unit test.

/// Comparator propagation delay assumed, ns.
pub const PROPAGATION_NS: f64 = 50.0;
/// VREFINT, V (the datasheet's typical).
const VREFINT_V: f64 = 1.212;
/// VREF+ (= VDDA on the board), V.
pub const VREF_V: f64 = 3.3;

/// CSR bits.
mod csr {
    pub const EN: u32 = 1;
    pub const POL: u32 = 1 << 15;
    pub const VALUE: u32 = 1 << 30;
    pub const LOCK: u32 = 1 << 31;
}

/// The seven comparators, the two threshold DACs and SYSCFG_CFGR2.
#[derive(Clone, Debug, Default)]
pub struct Comparators {
    /// COMP1..7 CSR as written (VALUE kept apart).
    pub csr: [u32; 7],
    /// Outputs (after POL).
    pub out: [bool; 7],
    /// DAC3, DAC4: CR, MCR, DHR12R1, DHR12R2.
    dac: [[u32; 4]; 2],
    /// SYSCFG_CFGR2.
    pub cfgr2: u32,
}

impl Comparators {
    /// A CPU read of COMPx_CSR (`n` 0..7).
    pub fn read_csr(&self, n: usize) -> u32 {
        self.csr[n] | if self.out[n] { csr::VALUE } else { 0 }
    }

    /// A CPU write of COMPx_CSR: ignored once locked.
    pub fn write_csr(&mut self, n: usize, value: u32) {
        if self.csr[n] & csr::LOCK == 0 {
            self.csr[n] = value & !csr::VALUE;
        }
    }

    /// A CPU read of DAC3 (`d` 0) or DAC4 (1) at `off`.
    pub fn read_dac(&self, d: usize, off: u32) -> u32 {
        match off {
            0x00 => self.dac[d][0],
            0x3C => self.dac[d][1],
            0x08 => self.dac[d][2],
            0x14 => self.dac[d][3],
            0x2C => self.dac[d][2],
            0x30 => self.dac[d][3],
            _ => 0,
        }
    }

    /// A CPU write of DAC3 (`d` 0) or DAC4 (1) at `off`.
    pub fn write_dac(&mut self, d: usize, off: u32, value: u32) {
        match off {
            0x00 => self.dac[d][0] = value,
            0x3C => self.dac[d][1] = value,
            0x08 => self.dac[d][2] = value & 0xFFF,
            0x14 => self.dac[d][3] = value & 0xFFF,
            _ => {}
        }
    }

    /// A CPU write of SYSCFG_CFGR2: its lock bits only ever set.
    pub fn write_cfgr2(&mut self, value: u32) {
        self.cfgr2 |= value & 0xF;
    }

    /// The voltage on comparator `n`'s inverting input, V.
    fn inm_v(&self, n: usize) -> Option<f64> {
        let inmsel = self.csr[n] >> 4 & 7;
        let dac = |d: usize, ch: usize| {
            let en = self.dac[d][0] >> (16 * ch) & 1 == 1;
            en.then(|| f64::from(self.dac[d][2 + ch]) / 4095.0 * VREF_V)
        };
        match inmsel {
            0..=3 => Some(VREFINT_V * f64::from(inmsel + 1) / 4.0),
            4 => match n + 1 {
                1 | 3 => dac(0, 0),
                2 | 4 => dac(0, 1),
                5 | 7 => dac(1, 0),
                _ => dac(1, 1),
            },
            // DAC1/DAC2 and the INM pins carry nothing the comparators are used with here.
            _ => None,
        }
    }

    /// Updates every comparator's output from the voltages on the pins: `inp_v(n, inpsel)`
    /// is what the board puts on comparator `n`'s non-inverting input (None: nothing).
    pub fn update(&mut self, inp_v: impl Fn(usize, u32) -> Option<f64>) {
        for n in 0..7 {
            let c = self.csr[n];
            let raw = c & csr::EN != 0
                && match (inp_v(n, c >> 8 & 1), self.inm_v(n)) {
                    (Some(p), Some(m)) => p > m,
                    _ => false,
                };
            self.out[n] = raw != (c & csr::POL != 0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RM0440 §24.3.2 (COMPx_CSR.INMSEL): 4 selects DAC3_CH1 for COMP1 and COMP3, DAC3_CH2
    /// for COMP2 and COMP4, DAC4_CH1 for COMP5 and COMP7, DAC4_CH2 for COMP6; the output is
    /// high when INP > INM, inverted by POL; a disabled comparator's output is low.
    #[test]
    fn each_comparator_compares_its_pin_with_its_dac_channel() {
        let mut c = Comparators::default();
        c.write_dac(0, 0x08, 3000); // DAC3_CH1
        c.write_dac(0, 0x14, 1000); // DAC3_CH2
        c.write_dac(0, 0x00, 1 | 1 << 16);
        for n in 0..4 {
            c.write_csr(n, csr::EN | 4 << 4);
        }
        let two_v = |_: usize, _: u32| Some(2.0);
        c.update(two_v);
        // 2 V against 2.42 V (COMP1/3) and 0.81 V (COMP2/4).
        assert_eq!(&c.out[..4], &[false, true, false, true]);
        c.write_csr(0, csr::EN | 4 << 4 | csr::POL);
        c.update(two_v);
        assert!(c.out[0]);
        c.write_csr(1, 4 << 4);
        c.update(two_v);
        assert!(!c.out[1], "disabled");
        assert_ne!(c.read_csr(0) & csr::VALUE, 0);
    }

    /// RM0440 §24.6, COMPx_CSR.LOCK: once set, the whole register, LOCK included, is
    /// read-only until reset. SYSCFG_CFGR2's CLL, SPL, PVDL, ECCL: set by software, cleared
    /// only by a system reset.
    #[test]
    fn a_locked_comparator_and_the_system_break_locks_stay_as_they_are() {
        let mut c = Comparators::default();
        c.write_csr(2, csr::EN | 4 << 4 | csr::LOCK);
        c.write_csr(2, 0);
        assert_eq!(c.csr[2], csr::EN | 4 << 4 | csr::LOCK);
        c.write_cfgr2(0b101);
        c.write_cfgr2(0);
        assert_eq!(c.cfgr2, 0b101);
    }
}
