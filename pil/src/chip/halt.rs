//! A debugger's halt of the core (ARMv7-M ARM §C1.4, halting debug: C_HALT in DHCSR stops
//! instruction execution; RM0440 §47.16, the DBGMCU freeze registers). While halted no
//! instruction executes and no exception is taken; the peripherals run on, except those
//! the firmware froze in DBGMCU:
//!
//! - DBGMCU_APB2FZR (0xE004_2010) bit 11 DBG_TIM1_STOP, bit 13 DBG_TIM8_STOP: the counter
//!   stops, and the outputs are disabled as if MOE were cleared (they go to their idle
//!   levels with OSSI = 1) — [`super::output_stage::bridge`] of the timer with MOE clear;
//! - DBGMCU_APB1FZR1 (0xE004_2008) bit 0 DBG_TIM2_STOP, bit 12 DBG_IWDG_STOP: the counter
//!   (the watchdog's countdown) stops.
//!
//! A timer not frozen counts on; its output stage drives what its registers say (the duties
//! of the last period go on being applied). On resume every frozen counter continues from
//! where it stopped. The chip counts its halts ([`Soc::halts`]).

use super::*;

/// DBGMCU_APB1FZR1.
pub const DBGMCU_APB1FZR1: u32 = 0xE004_2008;
/// DBGMCU_APB2FZR.
pub const DBGMCU_APB2FZR: u32 = 0xE004_2010;

/// A halt in progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Halt {
    /// When the debugger resumes the core (time units).
    pub until: u64,
    /// TIM1, TIM8 frozen.
    pub pwm_frozen: [bool; 2],
    /// TIM2 frozen.
    pub tim2_frozen: bool,
    /// The independent watchdog frozen.
    pub iwdg_frozen: bool,
}

impl Soc {
    /// The debugger halts the core now for `units` (time units), with the freezes DBGMCU
    /// holds.
    pub fn halt_for(&mut self, units: u64) {
        let now = self.time;
        let apb1 = self.reg(DBGMCU_APB1FZR1);
        let apb2 = self.reg(DBGMCU_APB2FZR);
        let h = Halt {
            until: now + units,
            pwm_frozen: [apb2 >> 11 & 1 == 1, apb2 >> 13 & 1 == 1],
            tim2_frozen: apb1 & 1 == 1,
            iwdg_frozen: apb1 >> 12 & 1 == 1,
        };
        if h.pwm_frozen[0] {
            // TIM1's events still to handle: its boundary, and OC4's rise (the ADC trigger).
            let oc4 = self
                .tim1
                .next_oc4_rise()
                .filter(|_| self.tim1_trgo2_is_oc4());
            let due = [self.tim1.next_boundary(), oc4].into_iter().flatten().min();
            self.tim1.freeze(now, due);
            // The plant goes on in 50 µs steps without the PWM timer's updates.
            self.plant_next = now + 50 * crate::time::UNITS_PER_US;
        }
        if h.pwm_frozen[1] {
            let due = self.tim8.next_boundary();
            self.tim8.freeze(now, due);
        }
        if h.tim2_frozen {
            let due = [
                self.tim2.next_boundary(),
                self.tim2.next_match(0),
                self.tim2.next_match(1),
            ]
            .into_iter()
            .flatten()
            .min();
            self.tim2.freeze(now, due);
        }
        if h.iwdg_frozen {
            // The countdown stops for the halt's length: it ends that much later.
            self.iwdg.delay(units);
        }
        self.halts += 1;
        self.halt = Some(h);
    }

    /// The debugger resumes the core if its halt is over: the frozen counters go on from
    /// where they stopped. True while still halted.
    pub(super) fn halted(&mut self) -> bool {
        let Some(h) = self.halt else {
            return false;
        };
        let now = self.time;
        if now < h.until {
            return true;
        }
        let clk = self.timer_clock();
        if h.pwm_frozen[0] {
            self.tim1.thaw(now, clk);
        }
        if h.pwm_frozen[1] {
            self.tim8.thaw(now, clk);
        }
        if h.tim2_frozen {
            self.tim2.thaw(now, clk);
        }
        self.halt = None;
        false
    }

    /// Whether the output stage of bridge timer `i` (0: TIM1, 1: TIM8) is disabled by a
    /// halt that froze it.
    pub(super) fn outputs_frozen(&self, i: usize) -> bool {
        self.halt.is_some_and(|h| h.pwm_frozen[i])
    }
}

#[cfg(test)]
mod tests {
    use super::super::timers::Timer;

    /// RM0440 §47.16: a frozen counter stops and goes on from the same value.
    #[test]
    fn a_frozen_counter_resumes_where_it_stopped() {
        use super::super::timers::reg;
        let mut t = Timer::new(0xFFFF);
        t.regs[(reg::ARR / 4) as usize] = 999;
        t.write(reg::EGR, 1, 0, 1.0);
        t.write(reg::CR1, 1, 0, 1.0);
        let before = t.cnt(500);
        assert_eq!(before, 500);
        let due = t.next_boundary();
        t.freeze(500, due);
        assert_eq!(t.cnt(10_000), before);
        assert!(!t.running() && t.next_boundary().is_none());
        t.thaw(10_000, 1.0);
        assert_eq!(t.cnt(10_000), before);
        assert_eq!(t.cnt(10_100), (before + 100) % 1000);
    }
}
