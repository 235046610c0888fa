//! The gate-driver inputs as TIM1/TIM8's output stage drives them: every pin's level from
//! the output-stage registers — BDTR.MOE, OSSI, OSSR; CCER.CCxE, CCxNE, CCxP, CCxNP;
//! CR2.OISx, OISxN; the compare mode and value behind OCxREF — as RM0440 Table 265
//! ("Output control bits for complementary tim_ocx and tim_ocxn channels with break
//! feature") gives them, not from MOE alone.
//!
//! A pin the timer does not drive (Hi-Z: the output disabled) is held low by the gate
//! driver's pull-down (`docs/bring-up.md`: the phase outputs are active high and need
//! pull-downs). With the counter running a driven pin follows OCxREF over the PWM period,
//! so each pin is judged over the period: never high, high for part of it, or always high.

use super::timers::Timer;
use super::Soc;

/// A gate input over one PWM period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gate {
    /// Low the whole period (the switch is off).
    Never,
    /// High for part of the period (switching), or a level the registers do not fix (OCxREF
    /// frozen, toggled, or in a mode this model does not follow).
    Sometimes,
    /// High the whole period (the switch is on).
    Always,
}

impl Gate {
    fn of_level(high: bool) -> Gate {
        if high {
            Gate::Always
        } else {
            Gate::Never
        }
    }

    /// The level inverted (a polarity bit, or the complementary output).
    fn inverted(self) -> Gate {
        match self {
            Gate::Never => Gate::Always,
            Gate::Always => Gate::Never,
            Gate::Sometimes => Gate::Sometimes,
        }
    }

    fn xor(self, invert: bool) -> Gate {
        if invert {
            self.inverted()
        } else {
            self
        }
    }
}

/// Register offsets of the advanced timers' output stage (RM0440 TIM1/TIM8 register map).
mod reg {
    pub const CR2: u32 = 0x04;
    pub const CCMR1: u32 = 0x18;
    pub const CCMR2: u32 = 0x1C;
    pub const CCER: u32 = 0x20;
    pub const ARR: u32 = 0x2C;
    pub const BDTR: u32 = 0x44;
}

/// OCxREF of channel `ch` (0-based, CH1–CH3) over a period: from its output compare mode
/// (OCxM, 4 bits) and the compare value in force against ARR.
fn reference(t: &Timer, ch: usize) -> Gate {
    let ccmr = t.regs[((if ch < 2 { reg::CCMR1 } else { reg::CCMR2 }) / 4) as usize];
    let shift = 8 * (ch % 2);
    let ocm = ((ccmr >> (4 + shift)) & 7) | ((ccmr >> (16 + shift)) & 1) << 3;
    let ccr = t.active_ccr[ch];
    let arr = t.regs[(reg::ARR / 4) as usize];
    // PWM mode 1: active while CNT < CCR (centre-aligned: both ways), so never at CCR = 0
    // and always at CCR > ARR (RM0440 "PWM mode").
    let pwm1 = if ccr == 0 {
        Gate::Never
    } else if ccr > arr {
        Gate::Always
    } else {
        Gate::Sometimes
    };
    match ocm {
        0b0100 => Gate::Never,  // force inactive
        0b0101 => Gate::Always, // force active
        0b0110 => pwm1,
        0b0111 => pwm1.inverted(),
        _ => Gate::Sometimes,
    }
}

/// The two gate inputs (high side OCx, low side OCxN) of channel `ch` of `t`; `halted_frozen`
/// when the core is halted with the timer's DBG_TIMx_STOP set: its outputs are disabled as
/// if MOE were 0 (RM0440, the advanced timers' debug mode).
pub fn channel(t: &Timer, ch: usize, halted_frozen: bool) -> [Gate; 2] {
    let bdtr = t.regs[(reg::BDTR / 4) as usize];
    let ccer = t.regs[(reg::CCER / 4) as usize];
    let cr2 = t.regs[(reg::CR2 / 4) as usize];
    let moe = bdtr & (1 << 15) != 0 && !halted_frozen;
    let ossi = bdtr & (1 << 10) != 0;
    let ossr = bdtr & (1 << 11) != 0;
    let bits = ccer >> (4 * ch);
    let (cce, ccp, ccne, ccnp) = (bits & 1 != 0, bits & 2 != 0, bits & 4 != 0, bits & 8 != 0);
    let ois = cr2 & (1 << (8 + 2 * ch)) != 0;
    let oisn = cr2 & (1 << (9 + 2 * ch)) != 0;
    // Hi-Z: the pull-down holds the gate low.
    let hi_z = Gate::Never;
    if !moe {
        // MOE = 0: with OSSI = 1 and an output enabled, both go to their idle levels (after
        // the dead time); otherwise the timer releases them (Hi-Z).
        return if ossi && (cce || ccne) {
            [Gate::of_level(ois), Gate::of_level(oisn)]
        } else {
            [hi_z, hi_z]
        };
    }
    let r = reference(t, ch);
    // Off-state (OSSR = 1): the disabled output driven to its inactive level, CCxP / CCxNP.
    let off = |enabled: bool, polarity: bool| {
        if enabled {
            None
        } else if ossr {
            Some(Gate::of_level(polarity))
        } else {
            Some(hi_z)
        }
    };
    let high = off(cce, ccp).unwrap_or_else(|| r.xor(ccp));
    let low = off(ccne, ccnp).unwrap_or_else(|| {
        if cce {
            // Complementary to OCxREF (with dead time).
            r.inverted().xor(ccnp)
        } else {
            // CCxE = 0, CCxNE = 1: OCxN follows OCxREF.
            r.xor(ccnp)
        }
    });
    if !cce && !ccne && !ossr {
        return [hi_z, hi_z];
    }
    [high, low]
}

impl Soc {
    /// The twelve gate inputs over the PWM period now: section 1 (TIM1) then section 2
    /// (TIM8), phases U, V, W, each (high side, low side).
    pub fn gates(&self) -> [[Gate; 2]; 6] {
        let mut out = [[Gate::Never; 2]; 6];
        for (i, (t, frozen)) in [
            (&self.tim1, self.debug.frozen_advanced(0)),
            (&self.tim8, self.debug.frozen_advanced(1)),
        ]
        .into_iter()
        .enumerate()
        {
            for ch in 0..3 {
                out[3 * i + ch] = channel(t, ch, frozen);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A timer as the firmware configures it: PWM mode 1 with preload on CH1–3, both outputs
    /// enabled, OSSI = OSSR = 1, ARR 4250, duties at `ccr`.
    fn firmware_like(moe: bool, ccr: u32, cr2: u32) -> Timer {
        let mut t = Timer::new(0xFFFF);
        t.regs[(reg::ARR / 4) as usize] = 4250;
        t.regs[(reg::CCMR1 / 4) as usize] = (0b110 << 4) | (0b110 << 12);
        t.regs[(reg::CCMR2 / 4) as usize] = 0b110 << 4;
        t.regs[(reg::CCER / 4) as usize] = 0x555;
        t.regs[(reg::BDTR / 4) as usize] = (u32::from(moe) << 15) | (1 << 11) | (1 << 10);
        t.regs[(reg::CR2 / 4) as usize] = cr2;
        t.active_ccr = [ccr; 4];
        t
    }

    #[test]
    fn at_reset_nothing_is_driven() {
        let t = Timer::new(0xFFFF);
        for ch in 0..3 {
            assert_eq!(channel(&t, ch, false), [Gate::Never; 2]);
        }
    }

    #[test]
    fn moe_clear_drives_the_idle_levels_and_an_idle_low_side_on_is_caught() {
        let t = firmware_like(false, 2125, 0);
        assert_eq!(channel(&t, 0, false), [Gate::Never; 2]);
        // OIS1N = 1: with MOE clear the low side is on, which MOE alone would not show.
        let t = firmware_like(false, 2125, 1 << 9);
        assert_eq!(channel(&t, 0, false), [Gate::Never, Gate::Always]);
        assert_eq!(channel(&t, 1, false), [Gate::Never; 2]);
    }

    #[test]
    fn zero_duty_with_moe_set_turns_every_low_side_on() {
        let t = firmware_like(true, 0, 0);
        for ch in 0..3 {
            assert_eq!(channel(&t, ch, false), [Gate::Never, Gate::Always]);
        }
        let t = firmware_like(true, 2125, 0);
        assert_eq!(channel(&t, 2, false), [Gate::Sometimes; 2]);
    }

    #[test]
    fn a_frozen_timer_on_a_halt_disables_its_outputs_as_if_moe_were_clear() {
        let t = firmware_like(true, 0, 0);
        assert_eq!(channel(&t, 0, true), [Gate::Never; 2]);
    }
}
