//! Motor PWM: TIM1 (section 1, master) and TIM8 (section 2, slave), centre-aligned
//! complementary PWM at 20 kHz with 500 ns dead time, TIM8 started by TIM1 so both count in
//! phase, and TIM1's channel 4 marking the counter peak for the ADC burst.
//!
//! Embassy's pin types (`PwmPin`, `ComplementaryPwmPin`) check and set the pins' alternate
//! functions; the timers are written here through the PAC. Not through embassy's
//! `ComplementaryPwm`: its constructor sets MOE = 1 and starts the counter before the
//! caller can set the idle state, and it has no API for the rest (idle levels with MOE = 0,
//! master/slave start, TRGO2 from OC4REF, exact ARR).
//!
//! Order at boot ([`IdleBridges::new`], then [`IdleBridges::start`]): each timer is
//! configured with its counter stopped, MOE = 0, OSSI = 1 and the channels enabled, so its
//! outputs are forced to the idle level (low) *before* the pins are switched from their reset
//! state (analog, undriven) to the timer's alternate function; MOE is never written 1 at
//! boot.
//!
//! Timing of one period (counter 0 → ARR → 0, 2·ARR timer clocks = 50 µs):
//! - PWM mode 1: a phase's high side conducts while CNT < CCR, i.e. centred on CNT = 0;
//!   the low sides all conduct around the peak CNT = ARR.
//! - CH4 in PWM mode 2 with CCR4 = ARR − 1 raises OC4REF one clock before the peak; TRGO2
//!   carries it to the ADCs, so currents are sampled in the middle of the low-side window
//!   (valid for inline and low-side shunt sensing alike).
//! - RCR = 1, written just after the counters start: the update event (preload → active
//!   duties) then happens only at the peaks ("RCR written after launching the counter: UEV on
//!   overflow", RM0440 repetition counter), the instant of the sampling. Duties written from
//!   burst k take effect at peak k + 1, so each high-side pulse (centred on a trough) keeps
//!   one duty and stays symmetric, and the control task has a whole period minus the burst
//!   (≈ 45 µs) to write them. Both boot-time facts this relies on (TIM8 started by TIM1,
//!   update at the peak) are checked in [`MotorPwm::start`].
//! - TIM8 starts a few timer clocks (≈ 20 ns) after TIM1: the trigger is resynchronised.

use core::mem::ManuallyDrop;

use embassy_stm32::pac;
use embassy_stm32::pac::timer::vals::{Ckd, Cms, Dir, Mms, Mms2, Ocm, Ossi, Ossr, Sms, Ts};
use embassy_stm32::pac::timer::TimAdv;
use embassy_stm32::peripherals::{TIM1, TIM8};
use embassy_stm32::timer::complementary_pwm::ComplementaryPwmPin;
use embassy_stm32::timer::simple_pwm::PwmPin;
use embassy_stm32::timer::{Ch1, Ch2, Ch3};
use embassy_stm32::Peri;
use fpc::ports::PwmOutput;
use fpc::units::{PerSection, PhaseDuties, Section};

use super::clocks::SYSCLK_HZ;
use super::mutation;

/// PWM (and control) frequency, Hz.
pub const PWM_HZ: u32 = 20_000;
/// Auto-reload value: centre-aligned counting takes 2·ARR timer clocks per period.
pub const PWM_ARR: u16 = (SYSCLK_HZ / (2 * PWM_HZ)) as u16;
const _: () = assert!(
    SYSCLK_HZ.is_multiple_of(2 * PWM_HZ),
    "PWM period must be exact"
);
/// Dead time inserted at every complementary transition, ns.
pub const DEAD_TIME_NS: u32 = 500;
/// BDTR.DTG for [`DEAD_TIME_NS`] with CKD = 1 (tDTS = one timer clock, 5.88 ns): below 128
/// the dead time is simply DTG·tDTS.
const DEAD_TIME_DTG: u8 = (DEAD_TIME_NS * (SYSCLK_HZ / 1_000_000) / 1000) as u8;
const _: () = assert!(DEAD_TIME_DTG < 128, "dead time needs the DTG[7] ranges");
/// CCR4 of TIM1: OC4REF (PWM mode 2) rises one clock before the counter peak.
const ADC_TRIGGER_CCR: u16 = PWM_ARR - 1;
/// The three phase channels (CH1..CH3, zero-based).
const PHASES: [usize; 3] = [0, 1, 2];
/// CH4, zero-based: TIM1's ADC trigger, no pin.
const TRIGGER_CHANNEL: usize = 3;

/// The timer of a section.
fn timer(section: Section) -> TimAdv {
    match section {
        Section::Master => pac::TIM1,
        Section::Slave => pac::TIM8,
    }
}

const _: () = assert!(
    PWM_ARR == fpc::units::PWM_COMPARE_STEPS,
    "the simulators switch the duties in steps of fpc::units::PWM_COMPARE_STEPS"
);

/// Q0.16 duty to a compare value in 0..=ARR, rounded to nearest.
#[inline]
fn compare_value(duty: fpc::units::Duty) -> u16 {
    duty.compare_value(PWM_ARR)
}

/// The gate pins of one section (high side, low side per phase), held so they stay in
/// their alternate function.
// Only held, never read: dropping a pin would disconnect it from the timer.
#[allow(dead_code)]
pub struct SectionPins<T> {
    /// Phase U: CH1 / CH1N.
    pub u: (
        PwmPin<'static, T, Ch1>,
        ComplementaryPwmPin<'static, T, Ch1>,
    ),
    /// Phase V: CH2 / CH2N.
    pub v: (
        PwmPin<'static, T, Ch2>,
        ComplementaryPwmPin<'static, T, Ch2>,
    ),
    /// Phase W: CH3 / CH3N.
    pub w: (
        PwmPin<'static, T, Ch3>,
        ComplementaryPwmPin<'static, T, Ch3>,
    ),
}

/// Both timers configured, counters stopped, outputs forced to their idle level (low):
/// the state in which the gate pins may be handed to the timers.
pub struct IdleBridges {
    tim1: Peri<'static, TIM1>,
    tim8: Peri<'static, TIM8>,
}

impl IdleBridges {
    /// Clocks and resets TIM1 and TIM8 and programs timing, idle state and channel
    /// enables; nothing counts and MOE stays 0.
    pub fn new(tim1: Peri<'static, TIM1>, tim8: Peri<'static, TIM8>) -> Self {
        embassy_stm32::rcc::enable_and_reset::<TIM1>();
        embassy_stm32::rcc::enable_and_reset::<TIM8>();
        for section in Section::ALL {
            configure_section(timer(section), section);
        }
        IdleBridges { tim1, tim8 }
    }

    /// Takes the gate pins (switched to the timers after [`IdleBridges::new`]), programs
    /// synchronisation and the ADC trigger, and starts both counters in phase. Outputs stay
    /// off (MOE = 0) until [`PwmOutput::enable`].
    ///
    /// Call after the ADCs are armed: the first TIM1 peak starts the first burst.
    pub fn start(self, section1: SectionPins<TIM1>, section2: SectionPins<TIM8>) -> MotorPwm {
        let tim1 = pac::TIM1;
        // CH4 → OC4REF → TRGO2 → ADC1/2 trigger (see the module header).
        tim1.ccmr_output(1).modify(|w| {
            w.set_ocm(TRIGGER_CHANNEL - 2, Ocm::PWM_MODE2);
            w.set_ocpe(TRIGGER_CHANNEL - 2, true);
        });
        tim1.ccr(TRIGGER_CHANNEL)
            .write(|w| w.set_ccr(ADC_TRIGGER_CCR));
        tim1.cr2().modify(|w| {
            // TRGO = counter enable: starts TIM8 (trigger mode) with TIM1.
            w.set_mms(Mms::ENABLE);
            w.set_mms2(Mms2::COMPARE_OC4);
        });
        // TIM8 slave: ITR0 is TIM1's TRGO (RM0440, TIMx internal trigger connection). TS is
        // chosen before the slave mode is armed, as the reference manual requires.
        let tim8 = pac::TIM8;
        tim8.smcr().modify(|w| w.set_ts(Ts::ITR0));
        tim8.smcr().modify(|w| w.set_sms(Sms::TRIGGER_MODE));

        for section in Section::ALL {
            let tim = timer(section);
            // Counter to 0, counting up, ARR/CCR preloads transferred, repetition counter
            // loaded with 0 (RCR is still 0).
            tim.egr().write(|w| w.set_ug(true));
            tim.sr().write_value(Default::default());
        }
        cortex_m::interrupt::free(|_| {
            tim1.cr1().modify(|w| w.set_cen(true));
            // Must land before the first peak, 25 µs away: that peak then updates (the
            // repetition counter is 0) and reloads 1, so every later update is on a peak.
            for section in Section::ALL {
                timer(section).rcr().write(|w| w.set_rep(1));
            }
        });
        check_started_in_phase();
        for section in Section::ALL {
            lock(timer(section));
        }

        MotorPwm {
            _timers: (self.tim1, self.tim8),
            _pins: ManuallyDrop::new((section1, section2)),
        }
    }
}

/// [`PwmOutput`] for both sections. Owns the timers and the gate pins.
///
/// The pins are never dropped: a dropped pin returns to an analog input, which would leave
/// its gate driver's input floating instead of driven low by the timer's idle state. The
/// control task owns them for the program's life, so no drop code exists for them.
pub struct MotorPwm {
    _timers: (Peri<'static, TIM1>, Peri<'static, TIM8>),
    _pins: ManuallyDrop<(SectionPins<TIM1>, SectionPins<TIM8>)>,
}

/// Verifies at boot what the timing rests on: TIM8 was started by TIM1's TRGO (the ITR
/// mapping), and each timer's first update comes at a peak (the counter then counts down).
fn check_started_in_phase() {
    for section in Section::ALL {
        let tim = timer(section);
        // One PWM period is 8500 CPU cycles; the first update is half of that away.
        let mut budget = 4 * SYSCLK_HZ / PWM_HZ;
        while !tim.sr().read().uif() && budget > 0 {
            budget -= 1;
        }
        let direction = tim.cr1().read().dir();
        defmt::assert!(budget > 0, "{} did not start", section);
        defmt::assert!(
            direction == Dir::DOWN,
            "{}: update not at the counter peak",
            section
        );
    }
}

/// Freezes the timer's protection until reset (RM0440, TIMx_BDTR.LOCK level 3): dead time,
/// break, AOE, OSSI/OSSR, the idle levels (CR2.OISx/OISNx), the channels' polarities
/// (CCER) and output modes (CCMRx.OCxM, OCxPE). The write repeats BDTR as it stands (MOE 0)
/// with LOCK; from here only MOE and the compare values change.
fn lock(tim: TimAdv) {
    let bdtr = tim.bdtr().read().0 & !(1 << 15);
    tim.bdtr()
        .write_value(pac::timer::regs::BdtrAdv(bdtr | super::trip::bdtr::LOCK3));
}

/// Timing, idle state and channel enables of one section's timer, counter stopped.
fn configure_section(tim: TimAdv, section: Section) {
    // The hardware over-current trip: the section's comparators on the break input
    // (`trip.rs`; they run already, their outputs low).
    tim.af1()
        .write_value(pac::timer::regs::Af1Adv(super::trip::af1(section)));
    // Safe state first: with MOE = 0, OSSI = 1 and the channels enabled, every output is
    // driven to its idle level (OIS = OISN = 0: both gates low), not left floating. The
    // break input armed: active high, filtered (`trip::bdtr`). Locked in `start`.
    tim.bdtr().modify(|w| {
        w.set_moe(false);
        w.set_aoe(false);
        w.set_ossi(if mutation::is("ossi-clear") {
            Ossi::DISABLED
        } else {
            Ossi::IDLE_LEVEL
        });
        w.set_ossr(Ossr::IDLE_LEVEL);
        w.set_dtg(if mutation::is("dead-time-zero") {
            0
        } else {
            DEAD_TIME_DTG
        });
        if !mutation::is("bke-off") {
            w.0 |= super::trip::bdtr::BKE;
        }
        if !mutation::is("break-polarity-inverted") {
            w.0 |= super::trip::bdtr::BKP;
        }
        w.0 |= super::trip::bdtr::BKF;
    });
    tim.cr1().modify(|w| {
        w.set_cen(false);
        w.set_ckd(Ckd::DIV1);
        // Counts up and down; the update (repetition counter permitting) at both ends.
        w.set_cms(Cms::CENTER_ALIGNED3);
        w.set_arpe(true);
    });
    // PWM mode 1 with preloaded compare values on the phase channels (CH1, CH2 in CCMR1;
    // CH3 in CCMR2).
    for ch in PHASES {
        tim.ccmr_output(ch / 2).modify(|w| {
            w.set_ocm(ch % 2, Ocm::PWM_MODE1);
            w.set_ocpe(ch % 2, true);
        });
    }
    tim.cr2().modify(|w| {
        for ch in PHASES {
            w.set_ois(ch, mutation::is("ois-high") && ch == 0);
            w.set_oisn(ch, false);
        }
    });
    tim.psc().write_value(0);
    tim.arr().write(|w| w.set_arr(PWM_ARR));
    // Updates at every extreme until start() sets RCR = 1 at the right moment.
    tim.rcr().write(|w| w.set_rep(0));
    for ch in PHASES {
        tim.ccr(ch).write(|w| w.set_ccr(PWM_ARR / 2));
    }
    tim.ccer().modify(|w| {
        for ch in PHASES {
            w.set_cce(ch, true);
            w.set_ccne(ch, true);
        }
    });
}

impl PwmOutput for MotorPwm {
    fn write(&mut self, section: Section, duties: PhaseDuties) {
        let tim = timer(section);
        if mutation::is("late-duties") && section == Section::Master {
            // The duties reach the compare registers ≈ 6,000 cycles later: past the update
            // event that should put them in force (they are written ≈ 3,800 cycles after
            // the burst, the update comes 7,777 after it).
            cortex_m::asm::delay(6_000);
        }
        if mutation::is("control-critical-section") {
            // The global critical section at the control priority (against the rule of
            // `super::critical`).
            critical_section::with(|_| ());
        }
        for (ch, duty) in PHASES.into_iter().zip(duties) {
            tim.ccr(ch).write(|w| w.set_ccr(compare_value(duty)));
        }
        // The control task writes the slave section last.
        if section == Section::Slave {
            super::test_build::step_done();
        }
    }

    fn disable(&mut self) {
        super::safe_pwm_off();
    }

    fn tripped(&mut self) -> PerSection<bool> {
        super::trip::tripped(pac::TIM1, pac::TIM8)
    }

    fn rearm(&mut self, sections: PerSection<bool>) {
        for section in Section::ALL {
            if *sections.get(section) {
                super::trip::rearm(timer(section));
            }
        }
    }

    fn enable(&mut self, sections: PerSection<bool>) {
        // Until the next update the previous duties (50 % at start) are still active. Each
        // section has its own timer, so its main output enable switches it alone.
        for section in Section::ALL {
            let on = *sections.get(section);
            timer(section).bdtr().modify(|w| w.set_moe(on));
        }
    }
}
