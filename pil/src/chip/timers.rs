//! The timers the firmware uses (RM0440 §28–30): TIM1/TIM8 (advanced-control, centre-aligned
//! PWM with repetition counter and preloaded compares), TIM2 (embassy's time base: up-counting,
//! compare flags, update flag) and TIM4 (encoder mode: the counter is the servo encoder's
//! count, which the board supplies).
//!
//! A write changes only what the register's rules let it change: not the read-only and
//! preloaded fields, and on TIM1/TIM8 not what the lock of the output stage's settings
//! freezes (BDTR.LOCK, RM0440 "Locking mechanism": [`unlocked_bits`]). What the output stage
//! makes of those settings is [`super::output_stage`].
//!
//! A running counter is kept as an origin in time rather than ticked: its value, its next
//! event and its flags are computed from the time when asked, so the emulator only stops the
//! CPU at the instants something happens.

/// Register offsets shared by the timers (RM0440 TIMx register maps).
pub mod reg {
    /// Control 1.
    pub const CR1: u32 = 0x00;
    /// Control 2.
    pub const CR2: u32 = 0x04;
    /// Slave mode control.
    pub const SMCR: u32 = 0x08;
    /// DMA/interrupt enable.
    pub const DIER: u32 = 0x0C;
    /// Status.
    pub const SR: u32 = 0x10;
    /// Event generation.
    pub const EGR: u32 = 0x14;
    /// Capture/compare mode 2 (CH3, CH4).
    pub const CCMR2: u32 = 0x1C;
    /// Counter.
    pub const CNT: u32 = 0x24;
    /// Prescaler.
    pub const PSC: u32 = 0x28;
    /// Auto-reload.
    pub const ARR: u32 = 0x2C;
    /// Repetition counter.
    pub const RCR: u32 = 0x30;
    /// Compare 1 (CCR2..4 follow every 4 bytes).
    pub const CCR1: u32 = 0x34;
    /// Break and dead time.
    pub const BDTR: u32 = 0x44;
    /// Capture/compare mode 1 (CH1, CH2).
    pub const CCMR1: u32 = 0x18;
    /// Capture/compare enable.
    pub const CCER: u32 = 0x20;
}

/// TIMx_BDTR's fields (break and dead-time register, RM0440; the field layout of ST's SVD,
/// `timer_v2`).
pub mod bdtr {
    /// DTG[7:0]: the dead-time generator setup.
    pub const DTG: u32 = 0xFF;
    /// LOCK[1:0]: the lock level, writable once after reset.
    pub const LOCK: u32 = 3 << 8;
    /// OSSI: off-state selection for idle mode (MOE = 0).
    pub const OSSI: u32 = 1 << 10;
    /// OSSR: off-state selection for run mode (MOE = 1).
    pub const OSSR: u32 = 1 << 11;
    /// BKE: break enable.
    pub const BKE: u32 = 1 << 12;
    /// BKP: break polarity (1: active high).
    pub const BKP: u32 = 1 << 13;
    /// AOE: automatic output enable.
    pub const AOE: u32 = 1 << 14;
    /// MOE: main output enable.
    pub const MOE: u32 = 1 << 15;
    /// BKF[3:0]: break filter.
    pub const BKF: u32 = 0xF << 16;
    /// BK2F, BK2E, BK2P, BKDSRM, BK2DSRM, BKBID, BK2BID.
    pub const BREAK2_AND_BIDIR: u32 = 0x3FF << 20;
}

/// CR2 bits of the idle levels: OISx at 8 + 2·x, OISxN at 9 + 2·x.
const CR2_OIS: u32 = 0x3F << 8;

/// CR1.CEN.
const CEN: u32 = 1;
/// CR1.URS.
const URS: u32 = 1 << 2;
/// CR1.DIR.
const DIR: u32 = 1 << 4;
/// CR1.ARPE.
const ARPE: u32 = 1 << 7;

/// One timer's registers and counter.
#[derive(Clone, Debug)]
pub struct Timer {
    /// Register file (word index = offset / 4), as the CPU reads it, preload values for the
    /// preloaded registers.
    pub regs: [u32; 0x70 / 4],
    /// The compare values in force (shadow registers), CCR1..CCR4.
    pub active_ccr: [u32; 4],
    /// ARR in force.
    active_arr: u32,
    /// PSC in force.
    active_psc: u32,
    /// Repetition down-counter.
    rep: u32,
    /// Counting: the time of counter position 0 (see [`Timer::position`]), and the time
    /// units per counter tick.
    origin: Option<(u64, f64)>,
    /// Counter boundaries already handled (peaks and troughs, or overflows).
    boundaries_done: u64,
    /// Compare matches already flagged, per channel (in periods).
    matches_done: [u64; 4],
    /// Counter value while stopped.
    stopped_cnt: u32,
    /// Stopped by a debugger's freeze (DBGMCU), to go on at its end.
    frozen: bool,
    /// It froze counting down (centre-aligned, after the peak).
    frozen_down: bool,
    /// Counter bits (16 or 32).
    pub width_mask: u32,
    /// The break input is active (advanced timers): MOE cannot be set.
    pub break_active: bool,
}

/// The bits of a write to register `off` that lock level `level` (BDTR.LOCK) lets change; the
/// rest keep their old value (RM0440, "Locking mechanism" and TIMx_BDTR.LOCK). Level 1
/// freezes DTG, BKE, BKP, BKF, AOE and the break-2 fields (BDTR) and OISx/OISxN (CR2); level
/// 2 adds CCxP/CCxNP of the channels in output (CCER) and OSSI/OSSR; level 3 adds OCxM/OCxPE
/// of the channels in output (CCMRx). LOCK itself is written once; MOE is never locked.
/// `regs` is the register file (word index = offset / 4).
pub fn unlocked_bits(off: u32, level: u32, regs: &[u32]) -> u32 {
    let ccmr_output = |ccmr: u32, half: u32| (ccmr >> (8 * half)) & 3 == 0;
    match (off, level) {
        (_, 0) => !0,
        (reg::BDTR, _) => {
            // LOCK itself is write-once; MOE is never locked.
            let mut locked = bdtr::LOCK | bdtr::DTG | bdtr::BKE | bdtr::BKP | bdtr::BKF;
            locked |= bdtr::AOE | bdtr::BREAK2_AND_BIDIR;
            if level >= 2 {
                locked |= bdtr::OSSI | bdtr::OSSR;
            }
            !locked
        }
        (reg::CR2, _) => !CR2_OIS,
        (reg::CCER, l) if l >= 2 => {
            // CCxP/CCxNP of the channels configured as outputs.
            let ccmr1 = regs[(0x18 / 4) as usize];
            let ccmr2 = regs[(reg::CCMR2 / 4) as usize];
            let mut locked = 0;
            for ch in 0..4u32 {
                let ccmr = if ch < 2 { ccmr1 } else { ccmr2 };
                if ccmr_output(ccmr, ch % 2) {
                    locked |= 0b1010 << (4 * ch);
                }
            }
            !locked
        }
        (0x18 | reg::CCMR2, 3) => {
            // OCxM (bits 6:4 and 16) and OCxPE (bit 3) of each output half.
            let ccmr = regs[(off / 4) as usize];
            let mut locked = 0;
            for half in 0..2 {
                if ccmr_output(ccmr, half) {
                    locked |= (0x78 << (8 * half)) | (1 << (16 + 8 * half));
                }
            }
            !locked
        }
        _ => !0,
    }
}

/// What a counter boundary did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Boundary {
    /// An update event happened (preloads transferred, UIF set).
    pub update: bool,
    /// At the counter peak (centre-aligned) rather than the trough.
    pub peak: bool,
}

impl Timer {
    /// A timer at its reset values, `width_mask` 0xFFFF or 0xFFFF_FFFF.
    pub fn new(width_mask: u32) -> Self {
        let mut t = Timer {
            regs: [0; 0x70 / 4],
            active_ccr: [0; 4],
            active_arr: width_mask,
            active_psc: 0,
            rep: 0,
            origin: None,
            boundaries_done: 0,
            matches_done: [0; 4],
            stopped_cnt: 0,
            frozen: false,
            frozen_down: false,
            width_mask,
            break_active: false,
        };
        t.regs[(reg::ARR / 4) as usize] = width_mask;
        t
    }

    fn r(&self, off: u32) -> u32 {
        self.regs[(off / 4) as usize]
    }

    fn centre_aligned(&self) -> bool {
        (self.r(reg::CR1) >> 5) & 3 != 0
    }

    /// Counting period in ticks: 2·ARR centre-aligned, ARR + 1 edge-aligned.
    fn period_ticks(&self) -> u64 {
        let arr = u64::from(self.active_arr);
        if self.centre_aligned() {
            2 * arr.max(1)
        } else {
            arr + 1
        }
    }

    /// Whether the counter runs.
    pub fn running(&self) -> bool {
        self.origin.is_some()
    }

    /// Ticks counted since the origin at `now`.
    fn ticks_at(&self, now: u64) -> u64 {
        match self.origin {
            Some((o, per_tick)) => ((now.saturating_sub(o)) as f64 / per_tick) as u64,
            None => 0,
        }
    }

    /// Counter value at `now`.
    pub fn cnt(&self, now: u64) -> u32 {
        if self.origin.is_none() {
            return self.stopped_cnt;
        }
        let p = self.ticks_at(now) % self.period_ticks();
        let arr = u64::from(self.active_arr);
        let c = if self.centre_aligned() && p > arr {
            2 * arr - p
        } else {
            p
        };
        c as u32 & self.width_mask
    }

    /// Counting down (centre-aligned, after the peak) at `now`.
    fn counting_down(&self, now: u64) -> bool {
        self.origin.is_some()
            && self.centre_aligned()
            && self.ticks_at(now) % self.period_ticks() >= u64::from(self.active_arr)
    }

    /// Starts counting from the current counter value, ticks of `units_per_tick_clock`
    /// (the kernel clock) times the prescaler.
    fn start(&mut self, now: u64, units_per_clock: f64) {
        let per_tick = units_per_clock * f64::from(self.active_psc + 1);
        let cnt = u64::from(self.stopped_cnt);
        let origin = now as f64 - cnt as f64 * per_tick;
        self.origin = Some((origin.max(0.0) as u64, per_tick));
        self.boundaries_done = self.ticks_at(now) / self.boundary_ticks();
        self.matches_done = [self.ticks_at(now) / self.period_ticks(); 4];
    }

    /// A debugger's freeze (DBGMCU): the counter stops at its value at `now` — or, if the
    /// run loop has an event of it still to handle (`due`: the first, at or before `now`),
    /// just before that event, which then comes at the thaw.
    pub fn freeze(&mut self, now: u64, due: Option<u64>) {
        if self.origin.is_some() {
            let at = now.min(due.map_or(now, |d| d.saturating_sub(1)));
            self.stopped_cnt = self.cnt(at);
            self.frozen_down = self.counting_down(at);
            self.origin = None;
            self.frozen = true;
        }
    }

    /// The freeze ends at `now`: the counter goes on from where it stopped, in the direction
    /// it counted.
    pub fn thaw(&mut self, now: u64, units_per_clock: f64) {
        if std::mem::take(&mut self.frozen) {
            self.start(now, units_per_clock);
            if self.frozen_down {
                // `start` puts the count on the way up; a centre-aligned counter that froze
                // counting down resumes at the mirror point of the period.
                let per_tick = units_per_clock * f64::from(self.active_psc + 1);
                let back = (self.period_ticks() - 2 * u64::from(self.stopped_cnt)) as f64;
                if let Some((o, t)) = self.origin {
                    self.origin = Some(((o as f64 - back * per_tick).max(0.0) as u64, t));
                }
                self.boundaries_done = self.ticks_at(now) / self.boundary_ticks();
                self.matches_done = [self.ticks_at(now) / self.period_ticks(); 4];
            }
        }
    }

    /// Ticks between boundaries: ARR (centre-aligned: peak, trough, ...) or ARR + 1.
    fn boundary_ticks(&self) -> u64 {
        if self.centre_aligned() {
            u64::from(self.active_arr.max(1))
        } else {
            u64::from(self.active_arr) + 1
        }
    }

    /// Rebases the counter at `now` (after a change of clock, prescaler or counter value).
    fn rebase(&mut self, now: u64, units_per_clock: f64) {
        if self.origin.is_some() {
            self.stopped_cnt = self.cnt(now);
            self.start(now, units_per_clock);
        }
    }

    /// The update event: preloads into force, the repetition counter reloaded.
    fn update_event(&mut self, set_flag: bool) {
        self.active_arr = self.r(reg::ARR) & self.width_mask;
        self.active_psc = self.r(reg::PSC) & 0xFFFF;
        for ch in 0..4 {
            self.active_ccr[ch] = self.r(reg::CCR1 + 4 * ch as u32) & self.width_mask;
        }
        self.rep = self.r(reg::RCR) & 0xFFFF;
        if set_flag {
            self.regs[(reg::SR / 4) as usize] |= 1;
        }
    }

    /// Time of the next counter boundary after the handled ones, if counting.
    pub fn next_boundary(&self) -> Option<u64> {
        let (o, per_tick) = self.origin?;
        let k = self.boundaries_done + 1;
        Some(o + (k as f64 * self.boundary_ticks() as f64 * per_tick).ceil() as u64)
    }

    /// Whether the next boundary is an update event at a counter peak.
    pub fn next_is_update_at_peak(&self) -> bool {
        let peak = !self.centre_aligned() || (self.boundaries_done + 1) % 2 == 1;
        peak && self.rep == 0
    }

    /// Handles the next boundary (call when [`Timer::next_boundary`] is due).
    pub fn fire_boundary(&mut self) -> Boundary {
        self.boundaries_done += 1;
        let peak = !self.centre_aligned() || self.boundaries_done % 2 == 1;
        let update = if self.rep == 0 {
            let before = self.period_ticks();
            self.update_event(true);
            // An ARR change moves the boundaries: keep the handled count consistent.
            if before != self.period_ticks() {
                if let Some((o, per_tick)) = self.origin {
                    let done = self.boundaries_done;
                    let t = o as f64 + done as f64 * (before as f64 / 2.0) * per_tick;
                    self.origin = Some((t as u64, per_tick));
                    self.boundaries_done = 0;
                }
            }
            true
        } else {
            self.rep -= 1;
            false
        };
        Boundary { update, peak }
    }

    /// Time of the next rising edge of OC4REF in PWM mode 2 (CNT reaching CCR4 while
    /// counting up): TIM1's TRGO2, the ADC trigger.
    pub fn next_oc4_rise(&self) -> Option<u64> {
        let (o, per_tick) = self.origin?;
        let ccr4 = u64::from(self.active_ccr[3]);
        let period = self.period_ticks();
        let k = self.matches_done[3];
        Some(o + ((k * period + ccr4) as f64 * per_tick).ceil() as u64)
    }

    /// Marks the OC4REF edge of [`Timer::next_oc4_rise`] handled; sets CC4IF.
    pub fn fire_oc4(&mut self) {
        self.matches_done[3] += 1;
        self.regs[(reg::SR / 4) as usize] |= 1 << 4;
    }

    /// Edge-aligned up-counting compare match of channel `ch` (0-based): the next time CNT
    /// equals CCRx.
    pub fn next_match(&self, ch: usize) -> Option<u64> {
        let (o, per_tick) = self.origin?;
        let ccr = u64::from(self.r(reg::CCR1 + 4 * ch as u32) & self.width_mask);
        let period = self.period_ticks();
        if ccr >= period {
            return None;
        }
        let k = self.matches_done[ch];
        Some(o + ((k * period + ccr) as f64 * per_tick).ceil() as u64)
    }

    /// Marks the match of [`Timer::next_match`] handled; sets CCxIF.
    pub fn fire_match(&mut self, ch: usize) {
        self.matches_done[ch] += 1;
        self.regs[(reg::SR / 4) as usize] |= 2 << ch;
    }

    /// Re-aims the compare matches after a CCR or counter change, so that a match already
    /// passed in this period is not flagged again and one still ahead is.
    fn reaim_matches(&mut self, now: u64) {
        if self.origin.is_none() {
            return;
        }
        let period = self.period_ticks();
        let ticks = self.ticks_at(now);
        for ch in 0..4 {
            let ccr = u64::from(self.r(reg::CCR1 + 4 * ch as u32) & self.width_mask);
            let cycle = ticks / period;
            // Matched already this period if the counter is past it.
            self.matches_done[ch] = if ticks % period > ccr {
                cycle + 1
            } else {
                cycle
            };
        }
    }

    /// A CPU read of register `off` at `now`.
    pub fn read(&self, off: u32, now: u64) -> u32 {
        match off {
            reg::CNT => self.cnt(now),
            reg::CR1 => {
                let v = self.r(reg::CR1) & !DIR;
                if self.counting_down(now) {
                    v | DIR
                } else {
                    v
                }
            }
            reg::EGR => 0,
            o if (o as usize) / 4 < self.regs.len() => self.r(o),
            _ => 0,
        }
    }

    /// A CPU write of `value` to register `off` at `now`; `units_per_clock` is the kernel
    /// clock's period. Returns true if CEN rose (TIM1's TRGO in MMS = enable mode).
    pub fn write(&mut self, off: u32, value: u32, now: u64, units_per_clock: f64) -> bool {
        let i = (off / 4) as usize;
        if i >= self.regs.len() {
            return false;
        }
        match off {
            reg::SR => {
                // rc_w0: writing 0 clears, 1 leaves.
                self.regs[i] &= value;
            }
            reg::EGR => {
                if value & 1 != 0 {
                    // UG: counter to 0 (counting up), preloads transferred; UIF unless URS.
                    let set_flag = self.r(reg::CR1) & URS == 0;
                    self.update_event(set_flag);
                    self.stopped_cnt = 0;
                    if self.origin.is_some() {
                        self.start(now, units_per_clock);
                    }
                }
            }
            reg::CNT => {
                self.regs[i] = value;
                self.stopped_cnt = value & self.width_mask;
                if self.origin.is_some() {
                    self.start(now, units_per_clock);
                }
                self.reaim_matches(now);
            }
            reg::CR1 => {
                let was = self.r(reg::CR1) & CEN != 0;
                // DIR is read-only in centre-aligned mode.
                self.regs[i] = value & !DIR;
                let on = value & CEN != 0;
                if on && !was {
                    self.start(now, units_per_clock);
                    self.reaim_matches(now);
                    return true;
                }
                if !on && was {
                    self.stopped_cnt = self.cnt(now);
                    self.origin = None;
                }
            }
            o if (reg::CCR1..reg::CCR1 + 16).contains(&o) => {
                self.regs[i] = value;
                // Compare preload off: in force at once.
                let ch = ((o - reg::CCR1) / 4) as usize;
                let ccmr = self.r(0x18 + 4 * (ch as u32 / 2));
                let ocpe = ccmr >> (3 + 8 * (ch % 2)) & 1;
                if ocpe == 0 {
                    self.active_ccr[ch] = value & self.width_mask;
                }
                self.reaim_matches(now);
            }
            reg::ARR => {
                self.regs[i] = value;
                if self.r(reg::CR1) & ARPE == 0 {
                    self.active_arr = value & self.width_mask;
                    self.rebase(now, units_per_clock);
                }
            }
            reg::BDTR => {
                let level = self.r(reg::BDTR) >> 8 & 3;
                let mask = unlocked_bits(off, level, &self.regs);
                let mut v = (self.regs[i] & !mask) | (value & mask);
                if self.break_active {
                    // MOE cannot be set while the break input is active.
                    v &= !bdtr::MOE;
                }
                self.regs[i] = v;
            }
            reg::CR2 | 0x18 | reg::CCMR2 | 0x20 => {
                let level = self.r(reg::BDTR) >> 8 & 3;
                let mask = unlocked_bits(off, level, &self.regs);
                self.regs[i] = (self.regs[i] & !mask) | (value & mask);
            }
            _ => self.regs[i] = value,
        }
        false
    }

    /// Starts the counter as a trigger-mode slave does on its trigger.
    pub fn trigger_start(&mut self, now: u64, units_per_clock: f64) {
        if self.r(reg::CR1) & CEN == 0 {
            self.regs[0] |= CEN;
            self.start(now, units_per_clock);
            self.reaim_matches(now);
        }
    }

    /// The kernel clock changed: counting goes on at the new rate from `now`.
    pub fn clock_changed(&mut self, now: u64, units_per_clock: f64) {
        self.rebase(now, units_per_clock);
    }

    /// Whether an interrupt is requested: a flag of SR enabled in DIER.
    pub fn irq(&self) -> bool {
        self.r(reg::SR) & self.r(reg::DIER) & 0x1FFF != 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 170 MHz timer clock, in time units.
    const CLK: f64 = 8.0;

    #[test]
    fn centre_aligned_with_rcr_1_updates_at_every_peak_only() {
        let mut t = Timer::new(0xFFFF);
        t.write(reg::CR1, (3 << 5) | ARPE, 0, CLK);
        t.write(reg::ARR, 4250, 0, CLK);
        t.write(reg::EGR, 1, 0, CLK);
        t.write(reg::SR, 0, 0, CLK);
        t.write(reg::CR1, (3 << 5) | ARPE | CEN, 1000, CLK);
        t.write(reg::RCR, 1, 1000, CLK);
        let mut peaks = Vec::new();
        for _ in 0..6 {
            let at = t.next_boundary().unwrap();
            let b = t.fire_boundary();
            peaks.push((at - 1000, b.update, b.peak));
        }
        // 4250 ticks of 8 units = 34,000 units = 25 µs to the first peak, then every 25 µs.
        assert_eq!(
            peaks,
            vec![
                (34_000, true, true),
                (68_000, false, false),
                (102_000, true, true),
                (136_000, false, false),
                (170_000, true, true),
                (204_000, false, false),
            ]
        );
        // Counting down just after a peak.
        assert!(t.read(reg::CR1, 1000 + 34_000 + 80) & DIR != 0);
        assert_eq!(t.cnt(1000 + 34_000 + 80), 4240);
    }

    #[test]
    fn an_up_counter_flags_its_compare_matches_and_overflows() {
        let mut t = Timer::new(0xFFFF_FFFF);
        t.write(reg::PSC, 169, 0, CLK);
        t.write(reg::ARR, 0xFFFF, 0, CLK);
        t.write(reg::EGR, 1, 0, CLK);
        t.write(reg::CCR1 + 4, 100, 0, CLK);
        t.write(reg::CR1, CEN, 0, CLK);
        // 1 µs ticks: CNT = µs.
        assert_eq!(t.cnt(1360 * 50), 50);
        assert_eq!(t.next_match(1), Some(1360 * 100));
        t.fire_match(1);
        assert_eq!(t.read(reg::SR, 0) & 4, 4);
        assert_eq!(t.next_match(1), Some(1360 * (100 + 65536)));
        assert_eq!(t.next_boundary(), Some(1360 * 65536));
    }

    /// RM0440, TIMx_BDTR.LOCK: "level 1: DTG, BKE, BKP, AOE ... in BDTR and OISx/OISxN in
    /// CR2 can no longer be written; level 2: also CCxP/CCxNP (channels in output) and
    /// OSSR/OSSI; level 3: also OCxM/OCxPE (channels in output)". LOCK itself is written
    /// once after reset; MOE is never locked.
    #[test]
    fn lock_level_3_freezes_the_protection_but_not_moe() {
        let mut t = Timer::new(0xFFFF);
        // PWM mode 1 on CH1..3 with preload, both outputs enabled, OSSI = OSSR = 1.
        t.write(reg::CCMR1, 0x6868, 0, 1.0);
        t.write(reg::CCMR2, 0x68, 0, 1.0);
        t.write(reg::CCER, 0x555, 0, 1.0);
        t.write(reg::BDTR, bdtr::OSSI | bdtr::OSSR | 85, 0, 1.0);
        t.write(
            reg::BDTR,
            bdtr::OSSI | bdtr::OSSR | 85 | bdtr::BKE | 3 << 8,
            0,
            1.0,
        );
        t.write(reg::BDTR, bdtr::MOE, 0, 1.0);
        let b = t.regs[(reg::BDTR / 4) as usize];
        assert_eq!(b & 0xFF, 85, "DTG");
        assert_ne!(b & bdtr::BKE, 0, "BKE");
        assert_ne!(b & bdtr::OSSI, 0, "OSSI");
        assert_eq!(b & bdtr::LOCK, 3 << 8, "LOCK");
        assert_ne!(b & bdtr::MOE, 0, "MOE is not locked");
        t.write(reg::CR2, 0x3F << 8, 0, 1.0);
        assert_eq!(t.regs[1] & CR2_OIS, 0, "OIS");
        t.write(reg::CCER, 0xFFF, 0, 1.0);
        assert_eq!(t.regs[(reg::CCER / 4) as usize] & 0xAAA, 0, "CCxP/CCxNP");
        t.write(0x18, 0x7070, 0, 1.0);
        assert_eq!(t.regs[6] & 0x7070, 0x6060, "OCxM");
    }
}
