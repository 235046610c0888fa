//! The advanced-control timers' output stage and break (TIM1, TIM8; RM0440 §28.3:
//! "Complementary outputs and dead-time insertion", "Using the break function"; the register
//! descriptions of TIMx_BDTR, TIMx_CCER, TIMx_CR2, TIMx_AF1, TIMx_SR).
//!
//! What a bridge's gates do is decided here, from the registers, not from MOE alone:
//!
//! - MOE = 1, CCxE = CCxNE = 1, OCxM a PWM mode: the pair switches complementarily with the
//!   dead time (DTG, in tDTS) inserted at each edge; CCxP/CCxNP invert each output.
//! - MOE = 0 and OSSI = 1: both outputs driven to their idle levels OISx/OISxN (the pins'
//!   levels, after a dead time). OSSI = 0: both outputs disabled — the pins float.
//! - The break input (BDTR.BKE, active level BKP, filter BKF; its sources in TIMx_AF1: the
//!   BKIN pin and the comparators, each comparator's polarity in BKCMPxP for COMP1–4)
//!   clears MOE asynchronously and sets SR.BIF; while it is active MOE cannot be set.
//!
//! The lock of these settings (BDTR.LOCK) is a rule of the register writes:
//! [`super::timers::unlocked_bits`].
//!
//! The manual's text is not in this repository's references: these rules were written from
//! RM0440 rev. 8 as the team read it and the field layouts of ST's SVD (stm32-metapac 21,
//! `timer_v2`), and each is cited in its unit test.

use super::timers::{bdtr, reg, Timer};
use crate::board::{Bridge, MIN_DEAD_TIME_NS};

/// TIMx_AF1.
pub const AF1: u32 = 0x60;
/// SR.BIF.
pub const SR_BIF: u32 = 1 << 7;
/// SR.SBIF.
pub const SR_SBIF: u32 = 1 << 13;

/// The bridge that the output stage of `t` drives now (RM0440, "Output control bits for
/// complementary OCx and OCxN channels with break feature").
pub fn bridge(t: &Timer) -> Bridge {
    let bdtr = t.regs[(reg::BDTR / 4) as usize];
    let ccer = t.regs[(reg::CCER / 4) as usize];
    let cr2 = t.regs[(reg::CR2 / 4) as usize];
    if bdtr & bdtr::MOE == 0 {
        if ccer & 0x555 == 0 {
            // No phase output enabled: the timer drives nothing (its reset state, before the
            // firmware takes the pins); the gate drivers' pull-downs hold the gates low.
            return Bridge::Off;
        }
        if bdtr & bdtr::OSSI == 0 {
            return Bridge::Unsafe(
                "MOE = 0 with OSSI = 0: the gate outputs are disabled and float",
            );
        }
        for ch in 0..3 {
            let (e, ne) = (ccer >> (4 * ch) & 1, ccer >> (4 * ch + 2) & 1);
            let (ois, oisn) = (cr2 >> (8 + 2 * ch) & 1, cr2 >> (9 + 2 * ch) & 1);
            if (e == 1 && ois == 1) || (ne == 1 && oisn == 1) {
                return Bridge::Unsafe(
                    "an idle level (OISx/OISxN) is high: a gate is held on with MOE = 0",
                );
            }
            if e == 0 || ne == 0 {
                return Bridge::Unsafe(
                    "a phase output disabled (CCxE/CCxNE = 0) with MOE = 0: it floats",
                );
            }
        }
        return Bridge::Off;
    }
    let mut inverted = [false; 3];
    for (ch, inv) in inverted.iter_mut().enumerate() {
        let (e, p) = (ccer >> (4 * ch) & 1, ccer >> (4 * ch + 1) & 1);
        let (ne, np) = (ccer >> (4 * ch + 2) & 1, ccer >> (4 * ch + 3) & 1);
        if e == 0 || ne == 0 {
            return Bridge::Unsafe(
                "MOE = 1 with a phase's output or complementary output disabled",
            );
        }
        if p != np {
            return Bridge::Unsafe("CCxP differs from CCxNP: both gates of a phase on at once");
        }
        let ccmr = t.regs[((0x18 + 4 * (ch as u32 / 2)) / 4) as usize] >> (8 * (ch % 2));
        let ocm = (ccmr >> 4 & 7) | (ccmr >> 16 & 1) << 3;
        match ocm {
            6 => *inv = p == 1,
            7 => *inv = p == 0,
            _ => return Bridge::Unsafe("a phase channel not in PWM mode 1 or 2 with MOE = 1"),
        }
    }
    Bridge::Switching { inverted }
}

/// The dead time the output stage inserts, in kernel clocks (RM0440, TIMx_BDTR.DTG with
/// CR1.CKD: tDTS = 1, 2 or 4 kernel clocks).
pub fn dead_time_clocks(t: &Timer) -> u32 {
    let dtg = t.regs[(reg::BDTR / 4) as usize] & bdtr::DTG;
    let ckd = 1 << (t.regs[0] >> 8 & 3).min(2);
    let dts = match dtg >> 5 {
        0..=3 => dtg & 0x7F,
        4 | 5 => (64 + (dtg & 0x3F)) * 2,
        6 => (32 + (dtg & 0x1F)) * 8,
        _ => (32 + (dtg & 0x1F)) * 16,
    };
    dts * ckd
}

/// The break input's level from the comparators (`comp_out[n]`: COMPn+1's output, already
/// with its own POL) as TIMx_AF1 routes them: true if the break is active.
pub fn break_active(t: &Timer, comp_out: &[bool; 7]) -> bool {
    let bdtr = t.regs[(reg::BDTR / 4) as usize];
    if bdtr & bdtr::BKE == 0 {
        return false;
    }
    let af1 = t.regs[(AF1 / 4) as usize];
    // OR of the enabled sources; COMP1–4 each inverted by its BKCMPxP (RM0440, TIMx_AF1).
    let level = (0..7).any(|n| {
        let enabled = af1 >> (1 + n) & 1 == 1;
        let inverted = n < 4 && af1 >> (10 + n) & 1 == 1;
        enabled && (comp_out[n] != inverted)
    });
    // BKP = 1: active high.
    level == (bdtr & bdtr::BKP != 0)
}

/// The break filter's delay in kernel clocks: N consecutive samples at fSAMPLING (RM0440,
/// TIMx_BDTR.BKF, the same encoding as the input filters' ICF).
pub fn break_filter_clocks(t: &Timer) -> u32 {
    let bkf = t.regs[(reg::BDTR / 4) as usize] >> 16 & 0xF;
    let dts = 1 << (t.regs[0] >> 8 & 3).min(2);
    let (div, n) = match bkf {
        0 => (1, 0),
        1 => (1, 2),
        2 => (1, 4),
        3 => (1, 8),
        4 => (2 * dts, 6),
        5 => (2 * dts, 8),
        6 => (4 * dts, 6),
        7 => (4 * dts, 8),
        8 => (8 * dts, 6),
        9 => (8 * dts, 8),
        10 => (16 * dts, 5),
        11 => (16 * dts, 6),
        12 => (16 * dts, 8),
        13 => (32 * dts, 5),
        14 => (32 * dts, 6),
        _ => (32 * dts, 8),
    };
    div * n
}

/// The break acts: MOE cleared, BIF set (RM0440, "Using the break function").
pub fn apply_break(t: &mut Timer) {
    t.regs[(reg::BDTR / 4) as usize] &= !bdtr::MOE;
    t.regs[(reg::SR / 4) as usize] |= SR_BIF;
}

/// A system break (SYSCFG_CFGR2's sources: the core's LOCKUP, the PVD, SRAM parity, ECC):
/// MOE cleared, BIF and SBIF set, with the break input enabled (BKE; taken as gating the
/// system sources as it gates the others — an assumption, the timer here has BKE = 1).
pub fn apply_system_break(t: &mut Timer) {
    if t.regs[(reg::BDTR / 4) as usize] & bdtr::BKE != 0 {
        apply_break(t);
        t.regs[(reg::SR / 4) as usize] |= SR_SBIF;
    }
}

impl super::Soc {
    /// The bridges as the two output stages drive them now, checked against what the board
    /// can take: an unsafe state, or a dead time below the bridge's minimum
    /// ([`MIN_DEAD_TIME_NS`]), ends the emulation with the reason (the bridge
    /// would be destroyed, or its gates left to the pull-downs).
    pub(super) fn bridges(&mut self) -> [Bridge; 2] {
        if !self.powered {
            return [Bridge::Off; 2];
        }
        let clock_ns = self.timer_clock() / (crate::time::UNITS_PER_US as f64 / 1000.0);
        let mut out = [Bridge::Off; 2];
        for (i, t) in [&self.tim1, &self.tim8].into_iter().enumerate() {
            let b = if self.outputs_frozen(i) {
                // Frozen by a debugger's halt: the outputs disabled as with MOE = 0.
                let mut off = t.clone();
                off.regs[(reg::BDTR / 4) as usize] &= !bdtr::MOE;
                bridge(&off)
            } else {
                bridge(t)
            };
            let name = ["TIM1 (section 1)", "TIM8 (section 2)"][i];
            match b {
                Bridge::Unsafe(why) => {
                    self.error.get_or_insert(format!("board: {name}: {why}"));
                }
                Bridge::Switching { .. } => {
                    let dead_ns = f64::from(dead_time_clocks(t)) * clock_ns;
                    if dead_ns < MIN_DEAD_TIME_NS {
                        self.error.get_or_insert(format!(
                            "board: {name}: dead time {dead_ns:.0} ns, below the bridge's {:.0} ns: \
                             shoot-through",
                            MIN_DEAD_TIME_NS
                        ));
                    }
                }
                Bridge::Off if t.regs[(reg::CCER / 4) as usize] & 0x555 != 0 => {
                    // The outputs taken, not yet switching: the dead time they will switch
                    // with is already set.
                    let dead_ns = f64::from(dead_time_clocks(t)) * clock_ns;
                    if dead_ns < MIN_DEAD_TIME_NS {
                        self.error.get_or_insert(format!(
                            "board: {name}: dead time {dead_ns:.0} ns, below the bridge's {:.0} ns: \
                             shoot-through at the first switching",
                            MIN_DEAD_TIME_NS
                        ));
                    }
                }
                Bridge::Off => {}
            }
            out[i] = b;
        }
        out
    }

    /// A system break (SYSCFG_CFGR2: the core's lock-up, the PVD) on both bridge timers.
    pub(super) fn system_break(&mut self) {
        apply_system_break(&mut self.tim1);
        apply_system_break(&mut self.tim8);
    }

    /// The comparators against the board's signals as the plant step just left them, and
    /// the breaks they cause. The hardware acts here, in the peripheral model at the plant
    /// step's emulated time, before the core runs again: the outputs are in their safe state
    /// a comparator propagation and a break filter after the crossing, whatever the firmware
    /// does.
    pub(super) fn check_breaks(&mut self) {
        let board = &self.board;
        self.comps
            .update(|n, inpsel| board.comparator_input_v(n, inpsel));
        let clock_ns = self.timer_clock() / (crate::time::UNITS_PER_US as f64 / 1000.0);
        let now_s = crate::time::seconds(self.time);
        let at_crossing = self.instructions;
        for i in 0..2 {
            let t = if i == 0 {
                &mut self.tim1
            } else {
                &mut self.tim8
            };
            let active = break_active(t, &self.comps.out);
            if active && !t.break_active {
                let delay_ns =
                    super::comp::PROPAGATION_NS + f64::from(break_filter_clocks(t)) * clock_ns;
                apply_break(t);
                self.breaks.push(super::BreakRecord {
                    timer: i,
                    crossed_at_s: now_s,
                    safe_at_s: now_s + delay_ns * 1e-9,
                    instructions_between: self.instructions - at_crossing,
                });
            }
            t.break_active = active;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tim() -> Timer {
        let mut t = Timer::new(0xFFFF);
        // PWM mode 1 on CH1..3 with preload, both outputs enabled, OSSI = OSSR = 1.
        t.write(0x18, 0x6868, 0, 1.0);
        t.write(reg::CCMR2, 0x68, 0, 1.0);
        t.write(reg::CCER, 0x555, 0, 1.0);
        t.write(reg::BDTR, bdtr::OSSI | bdtr::OSSR | 85, 0, 1.0);
        t
    }

    /// RM0440, output control table: MOE = 0, OSSI = 1 → OCx = OISx, OCxN = OISxN (driven
    /// idle levels); OSSI = 0 → outputs disabled (not driven by the timer).
    #[test]
    fn with_moe_clear_the_idle_levels_decide_and_ossi_clear_floats() {
        let mut t = tim();
        assert_eq!(bridge(&t), Bridge::Off);
        t.write(reg::CR2, 1 << 8, 0, 1.0);
        assert!(matches!(bridge(&t), Bridge::Unsafe(m) if m.contains("OISx")));
        let mut u = tim();
        u.write(reg::BDTR, 85, 0, 1.0);
        assert!(matches!(bridge(&u), Bridge::Unsafe(m) if m.contains("OSSI = 0")));
    }

    /// RM0440, complementary outputs: with MOE = 1 the pair switches; CCxP = CCxNP = 1
    /// inverts both (the high side conducts for the period less the compare value); CCxP ≠
    /// CCxNP turns both gates of a phase on together.
    #[test]
    fn polarity_inverts_a_pair_or_shorts_it() {
        let mut t = tim();
        t.write(reg::BDTR, bdtr::OSSI | bdtr::OSSR | 85 | bdtr::MOE, 0, 1.0);
        assert_eq!(
            bridge(&t),
            Bridge::Switching {
                inverted: [false; 3]
            }
        );
        t.write(reg::CCER, 0x55F, 0, 1.0);
        assert_eq!(
            bridge(&t),
            Bridge::Switching {
                inverted: [true, false, false]
            }
        );
        t.write(reg::CCER, 0x557, 0, 1.0);
        assert!(matches!(bridge(&t), Bridge::Unsafe(m) if m.contains("CCxP")));
    }

    /// RM0440, TIMx_BDTR.DTG: DTG[7:5] = 0xx → DTG[7:0] × tDTS; 10x → (64 + DTG[5:0]) × 2 ×
    /// tDTS; 110 → (32 + DTG[4:0]) × 8 × tDTS; 111 → (32 + DTG[4:0]) × 16 × tDTS; tDTS from
    /// CR1.CKD. And BKF = 3: fSAMPLING = fCK_INT, N = 8.
    #[test]
    fn dead_time_and_break_filter_from_their_fields() {
        let mut t = tim();
        assert_eq!(dead_time_clocks(&t), 85);
        t.regs[(reg::BDTR / 4) as usize] = 0x80 | 5;
        assert_eq!(dead_time_clocks(&t), 138);
        t.regs[(reg::BDTR / 4) as usize] = 0xE0 | 1;
        t.regs[0] = 1 << 8;
        assert_eq!(dead_time_clocks(&t), 33 * 16 * 2);
        t.regs[(reg::BDTR / 4) as usize] = 3 << 16;
        t.regs[0] = 0;
        assert_eq!(break_filter_clocks(&t), 8);
    }

    /// RM0440, TIMx_AF1: BKCMPxE routes COMPx to the break input, BKCMPxP (COMP1–4) inverts
    /// it; TIMx_BDTR.BKP sets the active level; nothing acts with BKE = 0.
    #[test]
    fn the_break_input_is_the_enabled_comparators_at_the_set_polarity() {
        let mut t = tim();
        let mut comp = [false; 7];
        t.write(AF1, 1 << 3, 0, 1.0); // COMP3
        assert!(!break_active(&t, &comp), "BKE = 0");
        t.write(reg::BDTR, bdtr::OSSI | 85 | bdtr::BKE | bdtr::BKP, 0, 1.0);
        assert!(!break_active(&t, &comp));
        comp[2] = true;
        assert!(break_active(&t, &comp));
        comp[2] = false;
        comp[4] = true;
        assert!(!break_active(&t, &comp), "COMP5 is not routed");
        // BKP = 0: active low, so a comparator at rest (low) breaks.
        t.write(reg::BDTR, bdtr::OSSI | 85 | bdtr::BKE, 0, 1.0);
        assert!(break_active(&t, &[false; 7]));
        apply_break(&mut t);
        assert_ne!(t.regs[(reg::SR / 4) as usize] & SR_BIF, 0);
    }
}
