//! The hardware over-current trip and the system break inputs: protection that holds when
//! the software does not.
//!
//! # Phase currents → comparators → break
//! Each phase current (inline sensor, ±100 A over the ADC's 0–3.3 V, mid-scale 0 A: 48.8 mA
//! a code, `docs/firmware.md`, "The hardware over-current trip") also reaches a comparator's
//! non-inverting input; the inverting input is an internal DAC channel at [`TRIP_CODE`]
//! ([`TRIP_A`], 85 A, above the 70 A the software's check trips at and the 62.5 A a section's
//! peak force needs). The comparator's output goes, inside the chip, to its bridge timer's
//! break input (TIMx_AF1.BKCMPxE): a current above the threshold clears MOE in hardware, the
//! outputs go to their idle level (OSSI = 1, OIS = OISN = 0: all gates low) after the break
//! filter, whatever the core is doing — stalled, faulted, or hung with interrupts masked.
//!
//! | phase | signal pin (ADC) | comparator input | threshold | break |
//! |---|---|---|---|---|
//! | U1 | PA0 | COMP3_INP0 (same pin) | DAC3_CH1 | TIM1 |
//! | V1 | PA1 | COMP1_INP0 (same pin) | DAC3_CH1 | TIM1 |
//! | W1 | PA2 | COMP4_INP0 = PB0 (second trace) | DAC3_CH2 | TIM1 |
//! | U2 | PA6 | COMP6_INP0 = PB11 (second trace) | DAC4_CH2 | TIM8 |
//! | V2 | PA7 | COMP2_INP0 (same pin) | DAC3_CH2 | TIM8 |
//! | W2 | PC4 | COMP5_INP0 = PB13 (second trace) | DAC4_CH1 | TIM8 |
//!
//! (The inverting inputs per comparator: RM0440 §24.3.2, COMPx_CSR.INMSEL = 4 selects DAC3_CH1
//! for COMP1/3, DAC3_CH2 for COMP2/4, DAC4_CH1 for COMP5/7, DAC4_CH2 for COMP6.) Only seven
//! comparators exist, so each phase gets one: the trip watches every current *leaving* the
//! bridge. A current entering it through one phase leaves through the other two, so one of
//! those exceeds half of it: every phase current is bounded at 2 × 85 A = 170 A, any current
//! leaving the bridge at 85 A.
//!
//! Polarity: the comparator output is high above the threshold (POL = 0), the break input
//! active high (BDTR.BKP = 1, AF1.BKCMPxP = 0). Filter: BDTR.BKF = 3 (fCK_INT, N = 8: eight
//! 5.9 ns samples agree, 47 ns), against switching spikes. Hysteresis 20 mV (0.6 A).
//!
//! # Locks
//! Once configured, each COMPx_CSR is locked (LOCK: read-only until reset), and each timer's
//! BDTR is written once with LOCK level 3 (RM0440, TIMx_BDTR.LOCK): dead time, break enable,
//! polarity and filter, AOE, OSSI/OSSR, the idle levels, the channel polarities and output
//! modes can no longer change until reset, by a bug or a stray write. SYSCFG_CFGR2 connects
//! the core's LOCKUP output, the SRAM parity error and the PVD to every advanced timer's
//! break input (CLL, SPL, PVDL: write-once): a lock-up switches the bridges off at once
//! instead of after the watchdog's 3 ms, and so does the supply falling below the PVD
//! threshold ([`super::supply`]).
//!
//! # Reported and re-armed
//! The break flag (TIMx_SR.BIF) stays set: the control task reads both each cycle
//! ([`MotorPwm::tripped`](super::MotorPwm)) and latches `Overcurrent`, taking that section
//! out; `ClearFaults` clears the fault, after which BIF is cleared ([`rearm`]). With AOE = 0
//! MOE stays 0 until the firmware sets it again; while a comparator's output stays high the
//! break input holds MOE at 0 and BIF sets again at once.

use embassy_stm32::gpio::Flex;
use embassy_stm32::pac;
use embassy_stm32::pac::timer::TimAdv;
use embassy_stm32::peripherals::{PB0, PB11, PB13};
use embassy_stm32::Peri;
use fpc::units::{PerSection, Section};

/// Phase current that trips the hardware, A.
pub const TRIP_A: u32 = 85;
/// Full scale of the phase-current sensors on the board, A (at code 4095; mid-scale 2048 is
/// 0 A).
const SENSE_FULL_SCALE_A: u32 = 100;
/// The DAC code of [`TRIP_A`] (the DACs and the ADCs share VREF+).
pub const TRIP_CODE: u16 = (2048 + TRIP_A * 2048 / SENSE_FULL_SCALE_A) as u16;
const _: () = assert!(
    TRIP_CODE < 4095,
    "the threshold must be inside the sensor's range"
);

/// The comparators on each section's phases U, V, W: (COMPx number, INPSEL).
const MASTER: [(usize, u32); 3] = [(3, 0), (1, 0), (4, 0)];
const SLAVE: [(usize, u32); 3] = [(6, 0), (2, 0), (5, 0)];

/// COMPx_CSR fields (RM0440 §24.6).
mod csr {
    pub const EN: u32 = 1;
    /// INMSEL = 4: the comparator's DAC3/DAC4 channel.
    pub const INMSEL_DAC: u32 = 4 << 4;
    pub const INPSEL_SHIFT: u32 = 8;
    /// HYST = 2: 20 mV.
    pub const HYST_20MV: u32 = 2 << 16;
    pub const LOCK: u32 = 1 << 31;
}

/// The break configuration of a bridge timer's BDTR, written once with the rest of it
/// (RM0440, TIMx_BDTR: with LOCK set, the bits it locks must be written in the same access).
pub mod bdtr {
    /// BKE: break input 1 enabled.
    pub const BKE: u32 = 1 << 12;
    /// BKP: break input active high.
    pub const BKP: u32 = 1 << 13;
    /// BKF = 3: fCK_INT, N = 8.
    pub const BKF: u32 = 3 << 16;
    /// LOCK level 3.
    pub const LOCK3: u32 = 3 << 8;
}

/// TIMx_SR.BIF: a break occurred.
const SR_BIF: u32 = 1 << 7;

/// COMPx_CSR (COMP1 at 0x4001_0200, 4 bytes apart; RM0440 memory map).
fn comp(n: usize) -> pac::comp::Comp {
    match n {
        1 => pac::COMP1,
        2 => pac::COMP2,
        3 => pac::COMP3,
        4 => pac::COMP4,
        5 => pac::COMP5,
        6 => pac::COMP6,
        _ => pac::COMP7,
    }
}

/// TIMx_AF1 of a section's timer: its three comparators on the break input (BKCMPxE at bit
/// x, BKCMPxP = 0: not inverted), the BKIN pin not used.
pub fn af1(section: Section) -> u32 {
    let comps = match section {
        Section::Master => MASTER,
        Section::Slave => SLAVE,
    };
    comps.iter().fold(0, |w, (n, _)| w | 1 << n)
}

/// The second traces' pins (W1, U2, W2) to analog mode, the thresholds out on DAC3/DAC4's
/// internal channels, the six comparators on and locked. Call before the timers' break
/// inputs are enabled (`pwm.rs`), with the bridges' outputs off, and at least the DACs' and
/// comparators' start-up (a few µs) before: `init` starts them ahead of the ADCs, whose
/// regulators' start-ups (20 µs each, blocking) give it.
pub fn start_comparators(w1: Peri<'static, PB0>, u2: Peri<'static, PB11>, w2: Peri<'static, PB13>) {
    for mut pin in [Flex::new(w1), Flex::new(u2), Flex::new(w2)] {
        pin.set_as_analog();
    }
    embassy_stm32::rcc::enable_and_reset::<embassy_stm32::peripherals::DAC3>();
    embassy_stm32::rcc::enable_and_reset::<embassy_stm32::peripherals::DAC4>();
    for dac in [pac::DAC3, pac::DAC4] {
        // Both channels: normal mode, connected to on-chip peripherals only, no buffer
        // (MODEx = 3); HFSEL = 2 for an AHB clock above 160 MHz (RM0440, DAC_MCR).
        dac.mcr()
            .write_value(pac::dac::regs::Mcr(3 | 3 << 16 | 2 << 14));
        dac.dhr12r(0).write(|w| w.set_dhr(TRIP_CODE));
        dac.dhr12r(1).write(|w| w.set_dhr(TRIP_CODE));
        dac.cr().write_value(pac::dac::regs::Cr(1 | 1 << 16));
    }
    // The comparators' register interface is on SYSCFG's clock.
    pac::RCC.apb2enr().modify(|w| w.set_syscfgen(true));
    let _ = pac::RCC.apb2enr().read();
    for (n, inpsel) in MASTER.into_iter().chain(SLAVE) {
        let value = csr::EN | csr::INMSEL_DAC | inpsel << csr::INPSEL_SHIFT | csr::HYST_20MV;
        comp(n).csr().write_value(pac::comp::regs::Csr(value));
        comp(n)
            .csr()
            .write_value(pac::comp::regs::Csr(value | csr::LOCK));
    }
}

/// The core's lock-up, an SRAM parity error and the PVD on every advanced timer's break
/// input (SYSCFG_CFGR2: CLL, SPL, PVDL; each write-once until reset).
pub fn lock_system_breaks() {
    pac::SYSCFG.cfgr2().modify(|w| {
        w.set_cll(true);
        w.set_spl(true);
        w.set_pvdl(true);
    });
}

/// Which sections' break flag is set (their outputs were switched off by the break input).
pub fn tripped(tim1: TimAdv, tim8: TimAdv) -> PerSection<bool> {
    PerSection {
        master: tim1.sr().read().0 & SR_BIF != 0,
        slave: tim8.sr().read().0 & SR_BIF != 0,
    }
}

/// Clears the break flag of the sections marked (TIMx_SR is write-0-to-clear: every other
/// flag written 1 stays as it is).
pub fn rearm(tim: TimAdv) {
    tim.sr().write_value(pac::timer::regs::SrAdv(!SR_BIF));
}
