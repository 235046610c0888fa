//! The independent watchdog (RM0440 §37): the key register, the prescaler and reload
//! registers with their update delay in the LSI domain, and the 12-bit down-counter.
//!
//! What matters for the firmware, straight from the reference manual:
//! - writing 0xCCCC starts the watchdog, and the counter then counts down **from its reset
//!   value 0xFFF**, not from RLR (§37.3.2); only a reload (0xAAAA) loads RLR;
//! - PR and RLR are write-protected until 0x5555 is written; a write reaches the LSI domain
//!   only after a few LSI cycles, during which SR.PVU / SR.RVU read 1, and a reload in that
//!   time still uses the old value;
//! - a write of PR or RLR while its update is still under way (SR.PVU / SR.RVU = 1) is not
//!   taken: "the prescaler/reload value can be updated only when PVU/RVU is reset";
//! - the chip resets when the counter, having reached 0, counts once more: a window of
//!   RL + 1 ticks (the manual's timeout table: RL = 0 gives one tick, 0xFFF 4096), with
//!   IWDGRSTF in RCC_CSR;
//! - the LSI is not 32 kHz but within the datasheet's 29.5–34 kHz over temperature
//!   ([`Iwdg::lsi_hz`], `ChipOptions::lsi_hz`).

use crate::time::UNITS_PER_S;

/// LSI cycles a PR or RLR write takes to reach the watchdog's clock domain (RM0440: the
/// update "can take up to 6 LSI cycles"; the value used is the worst case).
const UPDATE_LSI_CYCLES: u64 = 6;

/// The IWDG.
#[derive(Clone, Debug)]
pub struct Iwdg {
    /// Nominal LSI frequency, Hz (32 kHz; the datasheet's range is 29.5–34 kHz).
    pub lsi_hz: f64,
    unlocked: bool,
    pr: u32,
    rlr: u32,
    /// Values in force in the LSI domain, and when pending writes land there.
    pr_active: u32,
    rlr_active: u32,
    pr_lands: Option<u64>,
    rlr_lands: Option<u64>,
    /// Counting: the counter's value at `loaded_at` (time units).
    counting: Option<(u32, u64)>,
}

impl Iwdg {
    /// At reset: stopped, PR = 0 (/4), RLR = 0xFFF.
    pub fn new(lsi_hz: f64) -> Self {
        Iwdg {
            lsi_hz,
            unlocked: false,
            pr: 0,
            rlr: 0xFFF,
            pr_active: 0,
            rlr_active: 0xFFF,
            pr_lands: None,
            rlr_lands: None,
            counting: None,
        }
    }

    /// Time units per counter tick with prescaler code `pr`.
    fn units_per_tick(&self, pr: u32) -> f64 {
        let div = 4u32 << pr.min(6);
        UNITS_PER_S as f64 / self.lsi_hz * f64::from(div)
    }

    fn settle(&mut self, now: u64) {
        if self.pr_lands.is_some_and(|t| now >= t) {
            // A prescaler change re-times the count from here.
            if let Some((v, at)) = self.counting {
                // The whole ticks counted so far; the tick under way goes on from its start.
                let per_tick = self.units_per_tick(self.pr_active);
                let ticks = ((now - at) as f64 / per_tick) as u32;
                let tick_start = at + (f64::from(ticks) * per_tick) as u64;
                self.counting = Some((v.saturating_sub(ticks), tick_start));
            }
            self.pr_active = self.pr;
            self.pr_lands = None;
        }
        if self.rlr_lands.is_some_and(|t| now >= t) {
            self.rlr_active = self.rlr;
            self.rlr_lands = None;
        }
    }

    fn lsi_cycles(&self, n: u64) -> u64 {
        (n as f64 * UNITS_PER_S as f64 / self.lsi_hz).ceil() as u64
    }

    /// A debugger's freeze (DBGMCU DBG_IWDG_STOP) for `units`: the countdown and the writes
    /// on their way to the LSI domain end that much later.
    pub fn delay(&mut self, units: u64) {
        if let Some((v, at)) = self.counting {
            self.counting = Some((v, at + units));
        }
        for lands in [&mut self.pr_lands, &mut self.rlr_lands]
            .into_iter()
            .flatten()
        {
            *lands += units;
        }
    }

    /// The reverse of [`Iwdg::delay`]: a freeze that ended `units` sooner than planned.
    pub fn advance(&mut self, units: u64) {
        if let Some((v, at)) = self.counting {
            self.counting = Some((v, at.saturating_sub(units)));
        }
        for lands in [&mut self.pr_lands, &mut self.rlr_lands]
            .into_iter()
            .flatten()
        {
            *lands = lands.saturating_sub(units);
        }
    }

    /// Whether the watchdog has been started.
    pub fn running(&self) -> bool {
        self.counting.is_some()
    }

    /// The counter value at `now` (0xFFF when stopped).
    pub fn counter(&mut self, now: u64) -> u32 {
        self.settle(now);
        match self.counting {
            Some((v, at)) => {
                let ticks = ((now - at) as f64 / self.units_per_tick(self.pr_active)) as u32;
                v.saturating_sub(ticks)
            }
            None => 0xFFF,
        }
    }

    /// When the counter counts past 0 (the reset: RL + 1 ticks after a reload), if running.
    pub fn expiry(&self) -> Option<u64> {
        let (v, at) = self.counting?;
        // A pending prescaler write lands first; the estimate is refined when it does.
        let t = at as f64 + f64::from(v + 1) * self.units_per_tick(self.pr_active);
        let t = t.ceil() as u64;
        Some(match self.pr_lands {
            Some(lands) if lands < t => lands,
            _ => t,
        })
    }

    /// Re-evaluates at `now`; true if the counter has reached 0.
    pub fn expired(&mut self, now: u64) -> bool {
        self.settle(now);
        match self.counting {
            Some((v, at)) => {
                let ticks = (now - at) as f64 / self.units_per_tick(self.pr_active);
                ticks + 1e-9 >= f64::from(v + 1)
            }
            None => false,
        }
    }

    /// A CPU read at offset `off`.
    pub fn read(&mut self, off: u32, now: u64) -> u32 {
        self.settle(now);
        match off {
            0x04 => self.pr,
            0x08 => self.rlr,
            0x0C => u32::from(self.pr_lands.is_some()) | u32::from(self.rlr_lands.is_some()) << 1,
            0x10 => 0xFFF,
            _ => 0,
        }
    }

    /// A CPU write at offset `off`.
    pub fn write(&mut self, off: u32, value: u32, now: u64) {
        self.settle(now);
        match off {
            0x00 => match value & 0xFFFF {
                0x5555 => self.unlocked = true,
                0xCCCC => {
                    self.unlocked = false;
                    if self.counting.is_none() {
                        // RM0440 §37.3.2: counts down from the reset value 0xFFF.
                        self.counting = Some((0xFFF, now));
                    }
                }
                0xAAAA => {
                    self.unlocked = false;
                    if self.counting.is_some() {
                        self.counting = Some((self.rlr_active, now));
                    }
                }
                _ => self.unlocked = false,
            },
            // Not taken while the previous write is still on its way (PVU / RVU).
            0x04 if self.unlocked && self.pr_lands.is_none() => {
                self.pr = value & 7;
                self.pr_lands = Some(now + self.lsi_cycles(UPDATE_LSI_CYCLES));
            }
            0x08 if self.unlocked && self.rlr_lands.is_none() => {
                self.rlr = value & 0xFFF;
                self.rlr_lands = Some(now + self.lsi_cycles(UPDATE_LSI_CYCLES));
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::{from_seconds, seconds};

    /// RM0440 §37.3.2: after 0xCCCC the counter starts from 0xFFF; the timeout is RL + 1
    /// ticks (the timeout table: 4096 ticks, 512 ms at /4 and 32 kHz, for RL = 0xFFF).
    #[test]
    fn started_as_embassy_does_the_first_window_is_4096_ticks() {
        let mut w = Iwdg::new(32_000.0);
        // 0x5555, PR = 0 (/4), RLR = 159, 0xCCCC: the sequence.
        w.write(0x00, 0x5555, 0);
        w.write(0x04, 0, 0);
        w.write(0x08, 159, 0);
        w.write(0x00, 0xCCCC, 0);
        let mut fresh = w.clone();
        let first = seconds(reset_time(&mut fresh));
        assert!((first - 0.512).abs() < 1e-6, "{first}");
        // A reload once RLR has landed gives the 20 ms window.
        let t = from_seconds(0.001);
        w.write(0x00, 0xAAAA, t);
        let window = seconds(reset_time(&mut w) - t);
        assert!((window - 0.020).abs() < 1e-6, "{window}");
    }

    /// When the watchdog resets the chip, following its events as the chip does.
    fn reset_time(w: &mut Iwdg) -> u64 {
        loop {
            let t = w.expiry().unwrap();
            if w.expired(t) {
                return t;
            }
        }
    }

    /// RM0440, IWDG_SR.RVU: "the reload value can be updated only when RVU is reset"; a
    /// reload meanwhile uses the value in force.
    #[test]
    fn a_reload_before_rlr_lands_uses_the_old_value() {
        let mut w = Iwdg::new(32_000.0);
        w.write(0x00, 0xCCCC, 0);
        w.write(0x00, 0x5555, 0);
        w.write(0x08, 23, 0);
        assert_eq!(w.read(0x0C, 0), 2, "RVU busy");
        w.write(0x00, 0xAAAA, 1);
        assert_eq!(w.counter(1), 0xFFF);
        let later = from_seconds(0.001);
        assert_eq!(w.read(0x0C, later), 0);
        w.write(0x00, 0xAAAA, later);
        assert_eq!(w.counter(later), 23);
    }

    /// RM0440, IWDG_SR.PVU/RVU: a PR or RLR write while the previous one is still being
    /// transferred (its flag set) is not taken.
    #[test]
    fn a_write_while_the_update_flag_is_set_is_not_taken() {
        let mut w = Iwdg::new(32_000.0);
        w.write(0x00, 0x5555, 0);
        w.write(0x08, 159, 0);
        w.write(0x08, 23, 10);
        let later = from_seconds(0.001);
        assert_eq!(w.read(0x08, later), 159);
        w.write(0x00, 0x5555, later);
        w.write(0x08, 23, later);
        assert_eq!(w.read(0x08, later), 23);
        // Without the 0x5555 key, nothing is taken at all.
        let mut v = Iwdg::new(32_000.0);
        v.write(0x08, 23, 0);
        assert_eq!(v.read(0x08, 0), 0xFFF);
    }

    /// Datasheet: LSI 29.5–34 kHz. The firmware's running window (RL 23 at /4) is 3.0 ms at
    /// 32 kHz, 3.25 ms at 29.5 kHz and 2.82 ms at 34 kHz.
    #[test]
    fn the_window_follows_the_lsi_within_its_range() {
        for (hz, ms) in [(29_500.0, 3.254), (32_000.0, 3.0), (34_000.0, 2.824)] {
            let mut w = Iwdg::new(hz);
            w.write(0x00, 0x5555, 0);
            w.write(0x08, 23, 0);
            w.write(0x00, 0xCCCC, 0);
            let t = from_seconds(0.001);
            w.write(0x00, 0xAAAA, t);
            let window = seconds(reset_time(&mut w) - t) * 1e3;
            assert!((window - ms).abs() < 1e-3, "{hz} Hz: {window} ms");
        }
    }
}
