//! The sampling burst: ADC1 and ADC2 in dual mode (injected simultaneous + regular
//! simultaneous), both groups triggered by TIM1 TRGO2 at the PWM counter peak; one DMA
//! channel moves the regular pairs; its transfer-complete interrupt ends the burst and wakes
//! the control task.
//!
//! One trigger, in order:
//! 1. Injected group, 3 ranks × 19 ADC clocks (6.5-cycle sampling) ≈ 1.3 µs: the three phase
//!    currents of section 1 on ADC1 and of section 2 on ADC2, pairwise at the same instant.
//! 2. Regular group, 2 × 25 + 2 × 37 ADC clocks ≈ 2.9 µs: encoder sin (ADC1) with its cos
//!    (ADC2) at the same instant, master then slave; then the pressures, slower sampling
//!    (24.5 cycles) for the sensors' higher source impedance.
//! 3. Dual-mode DMA (MDMA, 12-bit) moves each regular pair as one 32-bit word from ADC12_CDR
//!    (ADC1 in the low half) into [`REGULAR`], circularly; the transfer-complete interrupt
//!    of the fourth word is the end of the burst (≈ 4.3 µs after the peak).
//!
//! The tick is the DMA interrupt, not the injected end-of-sequence, because the regular
//! group converts after the injected one: only once the last regular pair is in RAM is the
//! whole burst there. There are too few ADC3/4/5 pins on the LQFP64 (the TIM1 outputs take
//! them) to put encoders and pressures on other converters.
//!
//! The interrupt copies the burst (injected data registers and the DMA buffer) into a
//! [`Burst`] and signals it; [`SampleTrigger::next_cycle`] stores it as the current burst,
//! which the input ports read until the next cycle, so every port of a cycle sees the same
//! burst even if the control task runs late.

use core::cell::Cell;
use core::sync::atomic::{AtomicU32, Ordering};

use embassy_stm32::adc::{AdcChannel, Exten, InjectedTrigger, RegularTrigger, RxDma};
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::InterruptExt;
use embassy_stm32::pac;
use embassy_stm32::pac::adc::regs::{Cfgr, Jsqr};
use embassy_stm32::pac::adc::vals::{Adcaldif, Adstp, Dmaen, Ovrmod, SampleTime};
use embassy_stm32::pac::adccommon::regs::Ccr;
use embassy_stm32::pac::adccommon::vals::{Dmacfg, Dual, Mdma, Presc};
use embassy_stm32::pac::bdma::vals::{Dir, Pl, Size};
use embassy_stm32::peripherals::{ADC1, ADC2, DMA1_CH1};
use embassy_stm32::triggers::TIM1_TRGO2;
use embassy_stm32::Peri;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;
use fpc::ports::{
    CurrentInput, CycleTrigger, EncoderCodes, EncoderInput, PhaseCurrentCodes, PressureCodes,
    PressureInput, SinCosCodes,
};
use fpc::units::{AdcCode, Section, Ticks};

use super::critical::ControlRawMutex;

use super::fault::{boot_fault, BootCheck};
use super::time::now_ticks;

/// Injected ranks per ADC: the three phase currents of one section.
pub const INJECTED_RANKS: usize = 3;
/// Regular ranks per ADC.
pub const REGULAR_RANKS: usize = 4;

/// Regular rank of each signal pair (ADC1 signal / ADC2 signal).
mod rank {
    /// Master encoder sin / cos.
    pub const ENCODER_MASTER: usize = 0;
    /// Slave encoder sin / cos.
    pub const ENCODER_SLAVE: usize = 1;
    /// Chamber A / chamber B pressure.
    pub const CHAMBERS: usize = 2;
    /// Suction / discharge pressure.
    pub const LINES: usize = 3;
}

/// Sampling time of each injected rank (phase currents, fast channels, low impedance).
const INJECTED_SAMPLE: SampleTime = SampleTime::CYCLES6_5;
/// Sampling time of each regular rank: encoders, then pressures.
const REGULAR_SAMPLE: [SampleTime; REGULAR_RANKS] = [
    SampleTime::CYCLES12_5,
    SampleTime::CYCLES12_5,
    SampleTime::CYCLES24_5,
    SampleTime::CYCLES24_5,
];

/// DMA1 channel 1 (index 0), fed by DMAMUX1 channel 0 (DMAMUX channels 0–7 serve DMA1).
const DMA_CHANNEL: usize = 0;

/// Hardware channel numbers of one ADC's burst, in rank order.
pub struct Sequence {
    /// Injected ranks: phase currents U, V, W.
    pub injected: [u8; INJECTED_RANKS],
    /// Regular ranks, as in [`rank`].
    pub regular: [u8; REGULAR_RANKS],
}

/// The ADC1 channel number of `pin`, with the pin switched to analog (a pin ADC1 cannot
/// convert does not compile).
pub fn adc1_channel(pin: impl AdcChannel<ADC1>) -> u8 {
    pin.degrade_adc().get_hw_channel()
}

/// The ADC2 channel number of `pin`, with the pin switched to analog.
pub fn adc2_channel(pin: impl AdcChannel<ADC2>) -> u8 {
    pin.degrade_adc().get_hw_channel()
}

/// The regular pairs, written by the DMA only: one 32-bit word per rank, ADC1 (master) in
/// bits 0..16, ADC2 (slave) in bits 16..32. Atomics because the DMA writes behind the
/// compiler's back; they compile to plain loads.
static REGULAR: [AtomicU32; REGULAR_RANKS] = [const { AtomicU32::new(0) }; REGULAR_RANKS];

/// One complete burst.
#[derive(Clone, Copy)]
struct Burst {
    /// End of the burst (DMA interrupt), a fixed ≈ 4 µs after the sampling instant.
    t: Ticks,
    /// Phase currents: index 0 = section 1 (ADC1), 1 = section 2 (ADC2).
    currents: [[u16; INJECTED_RANKS]; 2],
    /// Regular pairs as moved by the DMA.
    regular: [u32; REGULAR_RANKS],
}

impl Burst {
    /// All codes zero, before the first burst.
    const EMPTY: Burst = Burst {
        t: Ticks(0),
        currents: [[0; INJECTED_RANKS]; 2],
        regular: [0; REGULAR_RANKS],
    };

    /// The ADC1 and ADC2 codes of regular rank `r`.
    fn pair(&self, r: usize) -> (AdcCode, AdcCode) {
        let word = self.regular[r];
        (AdcCode(word as u16), AdcCode((word >> 16) as u16))
    }
}

/// Hands each burst from the DMA interrupt to the control task (latest wins).
static BURST_READY: Signal<ControlRawMutex, Burst> = Signal::new();
/// The burst of the current control cycle, read by the input ports.
static CURRENT: Mutex<ControlRawMutex, Cell<Burst>> = Mutex::new(Cell::new(Burst::EMPTY));

fn current() -> Burst {
    CURRENT.lock(Cell::get)
}

/// The ADC voltage regulators' start-up, in SYSCLK cycles for `cortex_m::asm::delay`: 20 µs
/// (T_ADCVREG_STUP, the datasheet's maximum). The delay takes at least what it asks (two
/// cycles a loop asked, three to five taken on the M4).
const REGULATOR_STARTUP_CYCLES: u32 = 20 * (super::clocks::SYSCLK_HZ / 1_000_000);

/// Clocks ADC1 and ADC2 (kernel clock SYSCLK / 4 = 42.5 MHz, under the 60 MHz maximum), starts
/// both regulators together, waits their start-up once, and calibrates both single-ended
/// together (RM0440's ADC chapter, "ADC deep-power-down mode and ADC voltage regulator",
/// "Calibration", "Single-ended and differential input channels": no channel is
/// differential, so no differential calibration). Leaves both disabled. Embassy's `Adc::new` does the same one ADC
/// at a time with three 20 µs waits each: ≈ 0.5 ms of the boot, which delays the brake after
/// a watchdog reset.
fn power_up_and_calibrate(_adc1: Peri<'static, ADC1>, _adc2: Peri<'static, ADC2>) {
    embassy_stm32::rcc::enable_and_reset::<ADC1>();
    embassy_stm32::rcc::enable_and_reset::<ADC2>();
    pac::ADC12_COMMON.ccr().modify(|w| w.set_presc(Presc::DIV4));
    for adc in [pac::ADC1, pac::ADC2] {
        adc.cr().modify(|w| {
            w.set_deeppwd(false);
            w.set_advregen(true);
        });
    }
    cortex_m::asm::delay(REGULATOR_STARTUP_CYCLES);
    for adc in [pac::ADC1, pac::ADC2] {
        adc.cr().modify(|w| w.set_adcaldif(Adcaldif::SINGLE_ENDED));
        adc.cr().modify(|w| w.set_adcal(true));
    }
    for adc in [pac::ADC1, pac::ADC2] {
        while adc.cr().read().adcal() {}
    }
}

/// Configures ADC1/ADC2 and the DMA and arms them; nothing converts until TIM1 runs.
///
/// `master` is ADC1's sequence (section-1 currents, sin channels, chamber A, suction),
/// `slave` ADC2's (section-2 currents, cos channels, chamber B, discharge).
pub fn start(
    adc1: Peri<'static, ADC1>,
    adc2: Peri<'static, ADC2>,
    dma: Peri<'static, DMA1_CH1>,
    master: &Sequence,
    slave: &Sequence,
) -> Sampler {
    power_up_and_calibrate(adc1, adc2);
    let (p_adc1, p_adc2) = (pac::ADC1, pac::ADC2);

    // The dual-mode bits may only be written with both ADCs disabled.
    for adc in [p_adc1, p_adc2] {
        cr_command(adc, |w| w.set_addis(true));
        while adc.cr().read().aden() {}
    }
    let mut ccr = pac::ADC12_COMMON.ccr().read();
    ccr.set_dual(Dual::DUAL_RJ);
    ccr.set_mdma(Mdma::ENABLED12B10B);
    ccr.set_dmacfg(Dmacfg::CIRCULAR);
    pac::ADC12_COMMON.ccr().write_value(ccr);

    let injected_signal = InjectedTrigger::<ADC1>::signal(&TIM1_TRGO2);
    let regular_signal = RegularTrigger::<ADC1>::signal(&TIM1_TRGO2);
    let mut written = [(Cfgr(0), Jsqr(0)); 2];
    for (n, (adc, sequence, is_master)) in [(p_adc1, master, true), (p_adc2, slave, false)]
        .into_iter()
        .enumerate()
    {
        for &ch in &sequence.injected {
            set_sample_time(adc, ch, INJECTED_SAMPLE);
        }
        for (&ch, &time) in sequence.regular.iter().zip(&REGULAR_SAMPLE) {
            set_sample_time(adc, ch, time);
        }
        // In dual mode the master's trigger starts both; the slave's must stay software
        // (RM0440, dual ADC modes), else it could start on its own.
        let edge = if is_master {
            Exten::RISING_EDGE
        } else {
            Exten::DISABLED
        };
        // CFGR first: JQDIS must be set before JSQR is written, else the write goes into the
        // injected context queue instead of being the one fixed sequence.
        let mut cfgr = adc.cfgr().read();
        cfgr.set_cont(false);
        cfgr.set_discen(false);
        cfgr.set_jdiscen(false);
        cfgr.set_jauto(false);
        cfgr.set_jqdis(true);
        // Never stall on a late DMA: keep converting, the newest data wins.
        cfgr.set_ovrmod(Ovrmod::OVERWRITE);
        // Dual mode moves data through ADC12_CDR (MDMA), not the per-ADC DMA.
        cfgr.set_dmaen(Dmaen::DISABLE);
        cfgr.set_extsel(regular_signal);
        cfgr.set_exten(edge);
        adc.cfgr().write_value(cfgr);

        let mut jsqr = Jsqr(0);
        jsqr.set_jl(INJECTED_RANKS as u8 - 1);
        for (i, &ch) in sequence.injected.iter().enumerate() {
            jsqr.set_jsq(i, ch);
        }
        jsqr.set_jextsel(injected_signal);
        jsqr.set_jexten(edge);
        if !super::mutation::is("jsqr-while-jadstart") {
            adc.jsqr().write_value(jsqr);
        }

        adc.sqr1().write(|w| {
            w.set_l(REGULAR_RANKS as u8 - 1);
            for (i, &ch) in sequence.regular.iter().enumerate() {
                w.set_sq(i, ch);
            }
        });
        written[n] = (cfgr, jsqr);
    }

    configure_dma(&dma);

    for adc in [p_adc1, p_adc2] {
        adc.isr().write(|w| w.set_adrdy(true));
        cr_command(adc, |w| w.set_aden(true));
        while !adc.isr().read().adrdy() {}
    }
    // Arm both groups; in dual mode the master's start bits drive the slave too.
    cr_command(p_adc1, |w| {
        w.set_jadstart(true);
        w.set_adstart(true);
    });
    if super::mutation::is("jsqr-while-jadstart") {
        for (adc, (_, jsqr)) in [p_adc1, p_adc2].into_iter().zip(written) {
            adc.jsqr().write_value(jsqr);
        }
    }

    check_readback(ccr, &written);

    interrupt::DMA1_CHANNEL1.set_priority(super::BURST_PRIORITY);
    // SAFETY: the handler below is ready (its statics are const-initialised) and no critical
    // section is open here that unmasking this interrupt could break.
    unsafe { interrupt::DMA1_CHANNEL1.enable() };

    Sampler {
        trigger: SampleTrigger,
        encoders: EncoderAdc,
        currents: CurrentAdc,
        pressures: PressureAdc,
    }
}

/// Reads back what [`start`] wrote, with both ADCs armed: ADC12_CCR, then each ADC's CFGR
/// and JSQR. A mismatch (a write the hardware ignored, e.g. with the ADC enabled, or JSQR
/// queued) is a [`BootCheck`] fault: the sampling instant or the channel map would be wrong.
fn check_readback(ccr: Ccr, written: &[(Cfgr, Jsqr); 2]) {
    if pac::ADC12_COMMON.ccr().read() != ccr {
        boot_fault(BootCheck::Adc12Ccr);
    }
    for (adc, &(cfgr, jsqr)) in [pac::ADC1, pac::ADC2].into_iter().zip(written) {
        if adc.cfgr().read() != cfgr {
            boot_fault(BootCheck::AdcCfgr);
        }
        if adc.jsqr().read() != jsqr {
            boot_fault(BootCheck::AdcJsqr);
        }
    }
}

/// Issues ADC_CR commands. Its enable/disable/start/stop/calibrate bits act when written
/// with 1 (and read back as 1 while busy), so a plain read-modify-write would re-issue every
/// command still in progress; clear them all, keep the regulator bits, then set `f`'s.
fn cr_command(adc: pac::adc::Adc, f: impl FnOnce(&mut pac::adc::regs::Cr)) {
    adc.cr().modify(|w| {
        w.set_aden(false);
        w.set_addis(false);
        w.set_adstart(false);
        w.set_jadstart(false);
        w.set_adstp(Adstp::from_bits(0));
        w.set_jadstp(Adstp::from_bits(0));
        w.set_adcal(false);
        f(w);
    });
}

fn set_sample_time(adc: pac::adc::Adc, ch: u8, time: SampleTime) {
    let ch = usize::from(ch);
    if ch < 10 {
        adc.smpr().modify(|w| w.set_smp(ch, time));
    } else {
        adc.smpr2().modify(|w| w.set_smp(ch - 10, time));
    }
}

/// DMA1 channel 1: ADC12_CDR → [`REGULAR`], 32-bit words, circular, transfer-complete
/// interrupt.
fn configure_dma(dma: &Peri<'static, DMA1_CH1>) {
    let request = RxDma::<ADC1>::request(&**dma);
    pac::DMAMUX1
        .ccr(DMA_CHANNEL)
        .write(|w| w.set_dmareq_id(request));
    let ch = pac::DMA1.ch(DMA_CHANNEL);
    ch.cr().write(|w| w.set_en(false));
    ch.par()
        .write_value(pac::ADC12_COMMON.cdr().as_ptr() as u32);
    // The DMA writes nothing but these four words, forever: they are 'static atomics, so
    // no Rust reference ever aliases a plain value the hardware changes.
    ch.mar().write_value(REGULAR.as_ptr() as u32);
    ch.ndtr().write(|w| w.set_ndt(REGULAR_RANKS as u16));
    ch.cr().write(|w| {
        w.set_dir(Dir::FROM_PERIPHERAL);
        w.set_psize(if super::mutation::is("dma-psize-16") {
            Size::BITS16
        } else {
            Size::BITS32
        });
        w.set_msize(Size::BITS32);
        w.set_minc(true);
        w.set_circ(true);
        w.set_pl(Pl::VERY_HIGH);
        w.set_tcie(true);
        w.set_en(true);
    });
}

/// End of the burst: the last regular pair is in RAM (and the injected group finished
/// before the regular one started).
#[interrupt]
fn DMA1_CHANNEL1() {
    super::test_build::burst_begins();
    pac::DMA1.ifcr().write(|w| w.set_gif(DMA_CHANNEL, true));
    let t = now_ticks();
    let injected = |adc: pac::adc::Adc| core::array::from_fn(|i| adc.jdr(i).read().jdata());
    BURST_READY.signal(Burst {
        t,
        currents: [injected(pac::ADC1), injected(pac::ADC2)],
        regular: core::array::from_fn(|i| REGULAR[i].load(Ordering::Acquire)),
    });
}

/// The input ports of one burst, handed to the control task.
pub struct Sampler {
    /// [`CycleTrigger`].
    pub trigger: SampleTrigger,
    /// [`EncoderInput`].
    pub encoders: EncoderAdc,
    /// [`CurrentInput`].
    pub currents: CurrentAdc,
    /// [`PressureInput`].
    pub pressures: PressureAdc,
}

/// [`CycleTrigger`]: completes at the end of each burst (20 kHz).
pub struct SampleTrigger;

impl CycleTrigger for SampleTrigger {
    async fn next_cycle(&mut self) -> Ticks {
        let burst = BURST_READY.wait().await;
        super::test_build::control_cycle();
        CURRENT.lock(|c| c.set(burst));
        burst.t
    }
}

/// [`EncoderInput`]: both sin/cos encoders of the current burst.
pub struct EncoderAdc;

impl EncoderInput for EncoderAdc {
    fn read(&mut self) -> EncoderCodes {
        let burst = current();
        let (sin, cos) = burst.pair(rank::ENCODER_MASTER);
        let master = SinCosCodes { sin, cos };
        let (sin, cos) = burst.pair(rank::ENCODER_SLAVE);
        EncoderCodes {
            master,
            slave: SinCosCodes { sin, cos },
        }
    }
}

/// [`CurrentInput`]: phase currents of the current burst.
pub struct CurrentAdc;

impl CurrentInput for CurrentAdc {
    fn read(&mut self, section: Section) -> PhaseCurrentCodes {
        current().currents[section as usize].map(AdcCode)
    }
}

/// [`PressureInput`]: the four pressures of the current burst.
pub struct PressureAdc;

impl PressureInput for PressureAdc {
    fn read(&mut self) -> PressureCodes {
        let burst = current();
        let (chamber_a, chamber_b) = burst.pair(rank::CHAMBERS);
        let (suction, discharge) = burst.pair(rank::LINES);
        PressureCodes {
            chamber_a,
            chamber_b,
            suction,
            discharge,
        }
    }
}
