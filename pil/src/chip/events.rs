//! The peripherals' events on the emulated timeline (timer boundaries, ADC bursts, flash
//! operations, the watchdog's expiry), their interrupt lines into the NVIC, and the plant's
//! step at the end of each PWM period.

use super::*;

impl Soc {
    /// Updates the NVIC's pending bits from the peripherals' interrupt lines (level
    /// sensitive: a line still high is pended again).
    pub(super) fn update_irqs(&mut self) {
        let lines = [
            (irqn::TIM2, self.tim2.irq()),
            (irqn::DMA1_CH1, self.dma.irq(0)),
            (irqn::FLASH, self.flash.irq()),
        ];
        for (n, high) in lines {
            if high && !self.nvic.active[irq(n)] {
                self.nvic.pending[irq(n)] = true;
            }
        }
        if self.flash.nmi {
            self.flash.nmi = false;
            self.nvic.pending[nvic::NMI] = true;
        }
    }

    /// The PWM timer is counting (the plant then steps at its updates).
    pub(super) fn pwm_running(&self) -> bool {
        self.tim1.running()
    }

    /// The next instant a peripheral does something.
    pub(super) fn next_event(&self) -> u64 {
        let mut t = u64::MAX;
        let mut at = |x: Option<u64>| {
            if let Some(x) = x {
                t = t.min(x);
            }
        };
        if self.pwm_running() {
            at(self.tim1.next_boundary());
            if self.tim1_trgo2_is_oc4() {
                at(self.tim1.next_oc4_rise());
            }
        } else {
            at(Some(self.plant_next));
        }
        at(self.tim8.next_boundary());
        at(self.tim2.next_boundary());
        for ch in 0..2 {
            at(self.tim2.next_match(ch));
        }
        if let Some((inj, reg)) = self.burst {
            at(Some(if inj != u64::MAX { inj } else { reg }));
        }
        at(self.iwdg.expiry());
        at(self.flash.next_event());
        t
    }

    /// The plant's step while the chip has no supply.
    pub(crate) fn step_plant_unpowered(&mut self) {
        self.step_plant();
        self.plant_stepped = false;
    }

    pub(super) fn tim1_trgo2_is_oc4(&self) -> bool {
        (self.tim1.regs[1] >> 20) & 0xF == 7
    }

    /// Handles every peripheral event due at the current time.
    pub(super) fn process_events(&mut self) {
        loop {
            let now = self.time;
            let mut handled = false;
            if self.pwm_running() {
                if let Some(at) = self
                    .tim1
                    .next_oc4_rise()
                    .filter(|&t| t <= now && self.tim1_trgo2_is_oc4())
                {
                    self.tim1.fire_oc4();
                    self.adc_trigger(at);
                    handled = true;
                }
                if self.tim1.next_boundary().is_some_and(|t| t <= now) {
                    if self.tim1.next_is_update_at_peak() && !self.release {
                        // The period is over: the host looks first (see `held`).
                        self.held = true;
                        return;
                    }
                    self.release = false;
                    let at = self.tim1.next_boundary().unwrap_or(now);
                    let b = self.tim1.fire_boundary();
                    if b.update {
                        self.timer_updated(0, at);
                    }
                    if b.update && b.peak {
                        self.pwm_period_end();
                    }
                    handled = true;
                }
            } else if self.plant_next <= now {
                if !self.release {
                    self.held = true;
                    return;
                }
                self.release = false;
                self.plant_next += 50 * UNITS_PER_US;
                self.step_plant();
                handled = true;
            }
            if self.tim8.next_boundary().is_some_and(|t| t <= now) {
                let at = self.tim8.next_boundary().unwrap_or(now);
                let b = self.tim8.fire_boundary();
                if b.update {
                    self.timer_updated(1, at);
                }
                if b.update && b.peak {
                    // TIM8 counts a few clocks behind TIM1 (started by its trigger): its
                    // compare values go into force at its own update, just after TIM1's.
                    let arr = self.tim8.regs[(timers::reg::ARR / 4) as usize];
                    self.board.latch_duties(1, self.tim8.active_ccr, arr);
                }
                handled = true;
            }
            if self.tim2.next_boundary().is_some_and(|t| t <= now) {
                self.tim2.fire_boundary();
                handled = true;
            }
            for ch in 0..2 {
                if self.tim2.next_match(ch).is_some_and(|t| t <= now) {
                    self.tim2.fire_match(ch);
                    handled = true;
                }
            }
            if let Some((inj, reg)) = self.burst {
                if inj != u64::MAX && inj <= now {
                    self.injected_done();
                    handled = true;
                } else if inj == u64::MAX && reg <= now {
                    self.regular_done();
                    handled = true;
                }
            }
            if self.flash.next_event().is_some_and(|t| t <= now) {
                self.flash.finish();
                handled = true;
            }
            if self.iwdg.expiry().is_some_and(|t| t <= now) {
                if self.iwdg.expired(now) {
                    self.reset_pending = Some(ResetKind::Watchdog);
                    return;
                }
                handled = true;
            }
            if !handled {
                break;
            }
        }
        self.update_irqs();
    }

    /// TIM1 update at a peak: one PWM period ended.
    pub(super) fn pwm_period_end(&mut self) {
        // The compare values just transferred act over the next period; the plant first
        // runs the one that ended with the values in force during it.
        self.step_plant();
        let arr = self.tim1.regs[(timers::reg::ARR / 4) as usize];
        self.board.latch_duties(0, self.tim1.active_ccr, arr);
    }

    /// The period just ended, if among the [`Soc::profile_keep`] worst so far: kept in
    /// [`Soc::profile_top`] (of equal ones, the first).
    fn keep_profile(&mut self) {
        let cycles = self.period.path_cycles;
        let top = self.profile_keep > 0
            && (self.profile_top.len() < self.profile_keep
                || self
                    .profile_top
                    .last()
                    .is_some_and(|p| cycles > p.path_cycles));
        if top {
            let at = self
                .profile_top
                .partition_point(|p| p.path_cycles >= cycles);
            self.profile_top.insert(
                at,
                ProfiledPeriod {
                    end_s: crate::time::seconds(self.time),
                    path_cycles: cycles,
                    blocks: std::mem::take(&mut self.profile_now),
                },
            );
            self.profile_top.truncate(self.profile_keep);
        }
    }

    pub(super) fn step_plant(&mut self) {
        let dac = if self.dac_cr & 1 != 0 && self.powered {
            self.dac_dhr & 0xFFF
        } else {
            2048
        };
        let bridges = self.bridges();
        self.board.step(bridges, dac as u16);
        self.check_breaks();
        if self.recording {
            self.period.path_lines = self.path_lines.len() as u32;
            self.period.path_data_lines = self.path_data_lines.len() as u32;
            self.periods.push(self.period);
            if self.profile {
                self.keep_profile();
            }
        }
        self.profile_now.clear();
        self.path_lines.clear();
        self.path_data_lines.clear();
        self.period = PeriodLoad::default();
        self.note_flash_state();
        self.plant_stepped = true;
    }
}
