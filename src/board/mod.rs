//! The STM32G474RE board (LQFP64): every line of MCU glue, and the only place `unsafe` is
//! allowed (each use carries a `// SAFETY:` comment). Declared from `src/main.rs`, MCU only.
//!
//! [`init`] brings the board up and returns the concrete ports of `fpc::ports`; the library
//! never names anything in here.
//!
//! # Clocks and timing
//! 170 MHz from HSI16 via the PLL, boost mode ([`clocks`]). TIM1 and TIM8 count centre-aligned
//! at 20 kHz, in phase (TIM8 started by TIM1's TRGO); TIM1 CH4 marks each counter peak and
//! starts one ADC burst; the end of the burst (DMA transfer complete) is the 20 kHz control
//! tick ([`pwm`], [`adc`]). embassy-time runs on TIM2 at 1 MHz.
//!
//! # Pins
//! | signal | pin | peripheral | function |
//! |---|---|---|---|
//! | section 1 phase U high / low | PA8 / PA11 | TIM1 | CH1 / CH1N (AF6 / AF6) |
//! | section 1 phase V high / low | PA9 / PB14 | TIM1 | CH2 / CH2N (AF6 / AF6) |
//! | section 1 phase W high / low | PA10 / PB15 | TIM1 | CH3 / CH3N (AF6 / AF4) |
//! | section 2 phase U high / low | PC6 / PC10 | TIM8 | CH1 / CH1N (AF4 / AF4) |
//! | section 2 phase V high / low | PC7 / PC11 | TIM8 | CH2 / CH2N (AF4 / AF4) |
//! | section 2 phase W high / low | PC8 / PC12 | TIM8 | CH3 / CH3N (AF4 / AF4) |
//! | section 1 current U, V, W | PA0, PA1, PA2 | ADC1 | IN1, IN2, IN3, injected ranks 1–3 |
//! | section 2 current U, V, W | PA6, PA7, PC4 | ADC2 | IN3, IN4, IN5, injected ranks 1–3 |
//! | master encoder sin / cos | PA3 / PC5 | ADC1 / ADC2 | IN4 / IN11, regular rank 1 |
//! | slave encoder sin / cos | PB1 / PB2 | ADC1 / ADC2 | IN12 / IN12, regular rank 2 |
//! | pressure chamber A / B | PB12 / PC1 | ADC1 / ADC2 | IN11 / IN7, regular rank 3 |
//! | pressure suction / discharge | PC0 / PC2 | ADC1 / ADC2 | IN6 / IN8, regular rank 4 |
//! | servo encoder A / B | PB6 / PB7 | TIM4 | CH1 / CH2 (AF2), internal pull-ups, encoder mode 3, filter fDTS/16 N = 8 |
//! | servo torque command | PA4 | DAC1 | OUT1, buffered, mid-scale = 0 (written before enable) |
//! | DC-link power good | PB5 | GPIO | input, pull-down (low = supply lost), read at 1 kHz ([`supply`]) |
//! | over-current comparators | PA0, PA1, PB0 / PB11, PA7, PB13 (U1, V1, W1 / U2, V2, W2; PB0, PB11, PB13 by second traces) | COMP3, 1, 4 / 6, 2, 5 ([`trip`]) | analog, each phase against 85 A, into TIM1/TIM8's break |
//! | debug, defmt over RTT | PA13 / PA14 | SWD | SWDIO / SWCLK |
//!
//! The currents use the fast channels (IN1–IN5); PA2 carrying one of them costs the Nucleo's
//! LPUART1 virtual COM port, so telemetry goes over RTT (PA11 carries TIM1_CH1N, so USB FS
//! is not available). Also left free: PF0/PF1 (24 MHz HSE crystal), PB10 (TIM1_BKIN, AF12,
//! for an external trip), PA5/PC13 (Nucleo LED/button). Phase outputs are active high; the
//! gate-driver inputs need pull-downs, since the pins float from reset until [`init`].
//!
//! PB8 is BOOT0: with the factory option bytes (nSWBOOT0 = 1) its level at reset chooses
//! between flash and the system bootloader, so nothing may drive it: it carries no signal
//! (the over-current trip, once planned on PB8's TIM1_BKIN, moved to PB10 for this reason).
//!
//! # Interrupts (lower number = more urgent)
//! | vector | priority | use |
//! |---|---|---|
//! | DMA1_CHANNEL1 | 1 | end of burst: copy the samples, wake the control task |
//! | UART5 | 2 | the control executor (`InterruptExecutor`; the UART itself is unused) |
//! | TIM2 | 3 | embassy-time (only the thread-mode tasks wait on time) |
//! | FLASH | 4 | end of a flash program or erase (the calibration storage task) |
//! | thread mode | — | supervision (watchdog), telemetry, commands, calibration storage |
//!
//! # Flash
//! The program lives in bank 1 (`memory.x`'s FLASH is bank 1, so an image that would reach
//! bank 2 does not link); the last four 2 KiB pages of bank 2 (0x0807_E000 to
//! 0x0808_0000, cut from `memory.x`) hold the calibration store ([`CALIBRATION_STORE`]). In
//! dual-bank mode the banks read while the other is written, so a page erase (≈ 22 ms) in
//! bank 2 never stalls the control code. The async driver waits for the FLASH interrupt
//! instead of spinning in a critical section: embassy's *blocking* region writes and erases
//! run inside one, which would stop the 20 kHz control task for the whole erase.
//!
//! # Safe state
//! Motor outputs are off (MOE = 0, all gates driven low) from [`init`] until the control
//! task enables them, whenever it disables them, on a debugger halt (DBGMCU freezes TIM1/TIM8,
//! which also disables their outputs), and first thing on panic and HardFault
//! ([`fault::safe_outputs_off`]). The IWDG (≈ 20 ms) is fed only by the supervision task,
//! and only while the control task keeps checking in. Every fault path (panic, HardFault,
//! an unexpected interrupt, a failed boot read-back) ends in a reset of its own, so one
//! before the watchdog starts cannot hang the board.

mod adc;
mod ccm;
mod clocks;
pub mod critical;
mod fault;
mod mutation;
mod pwm;
mod reset;
pub mod rtt;
mod servo;
pub mod stack;
mod store_flash;
mod supply;
mod test_build;
mod time;
mod trip;
mod watchdog;

use embassy_executor::{InterruptExecutor, SendSpawner};
use embassy_stm32::gpio::{OutputType, Pull};
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::pac;
use embassy_stm32::timer::complementary_pwm::ComplementaryPwmPin;
use embassy_stm32::timer::qei::{self, Qei};
use embassy_stm32::timer::simple_pwm::PwmPin;

pub use adc::{CurrentAdc, EncoderAdc, PressureAdc, SampleTrigger};
pub use fault::take_kept_cause;
pub use pwm::MotorPwm;
pub use servo::{ServoEncoder, ServoTorque};
pub use supply::PowerGood;
pub use time::{BoardClock, BoardSleep};
pub use watchdog::BoardWatchdog;

/// The 20 kHz control task's ports on this board.
pub type ControlPorts = fpc::ports::ControlPorts<
    SampleTrigger,
    EncoderAdc,
    CurrentAdc,
    MotorPwm,
    ServoEncoder,
    ServoTorque,
    PressureAdc,
>;

/// Priority of the end-of-burst interrupt.
const BURST_PRIORITY: Priority = Priority::P1;
/// Priority of the control executor's interrupt: below the burst, above everything else.
const CONTROL_PRIORITY: Priority = Priority::P2;
/// Priority of embassy-time's TIM2 interrupt: never delays the control task.
const TIME_PRIORITY: Priority = Priority::P3;
/// Priority of the flash controller's interrupt: the least urgent (it only wakes the storage
/// task).
const FLASH_PRIORITY: Priority = Priority::P4;

/// The calibration store's bytes, offsets from the start of flash: the last four pages of
/// bank 2, which `memory.x` keeps out of the program.
pub const CALIBRATION_STORE: core::ops::Range<u32> = 0x7_E000..0x8_0000;

/// The calibration store on the MCU's flash.
pub type BoardCalibrationStore =
    fpc::control::calibration::store::CalibrationStore<store_flash::CheckedFlash>;

// The error flags are latched before embassy's handler clears them (`store_flash`).
embassy_stm32::bind_interrupts!(struct FlashIrqs {
    FLASH => store_flash::LatchFlashErrors, embassy_stm32::flash::InterruptHandler;
});

/// The board, brought up.
pub struct Board {
    /// Ports of the control task (motor outputs off).
    pub control: ControlPorts,
    /// Time base for the supervision task.
    pub clock: BoardClock,
    /// Waiting for the supervision task.
    pub sleep: BoardSleep,
    /// The running watchdog; feed it within [`watchdog::WATCHDOG_TIMEOUT_US`] (after a first
    /// feed within [`watchdog::BOOT_WATCHDOG_TIMEOUT_US`] of power-up).
    pub watchdog: BoardWatchdog,
    /// The calibration store (`None` if its range does not fit the flash's pages, which
    /// the boot then treats as an unreadable calibration).
    pub calibration: Option<BoardCalibrationStore>,
    /// The DC link's power-good input, for the supervision task.
    pub power_good: PowerGood,
}

/// Operator events as defmt logs, at the levels the project uses everywhere: error = a fault
/// latched, warn = a limit became active, info = a mode change.
pub struct DefmtEvents;

impl fpc::ports::EventLog for DefmtEvents {
    fn fault_latched(&mut self, fault: fpc::safety::faults::Fault) {
        defmt::error!("fault latched: {} ({=u8})", fault.name(), fault as u8);
    }
    fn limit_active(&mut self, limits: fpc::safety::supervisor::LimitFlags) {
        defmt::warn!("limit active: {}", limits);
    }
    fn mode_changed(&mut self, mode: fpc::status::ModeKind) {
        defmt::info!("mode: {}", mode.name());
    }
    fn absent_changed(&mut self, absent: fpc::safety::absent::Absent) {
        defmt::warn!("absent since boot: {=str}", absent.names());
    }
    fn calibration_saved(
        &mut self,
        result: Result<(), fpc::control::calibration::store::SaveError>,
    ) {
        match result {
            Ok(()) => defmt::info!("calibration saved"),
            Err(e) => defmt::error!("calibration not saved: {}", e),
        }
    }
}

/// Reads and clears the reset flags (RCC_CSR): why the MCU started.
pub fn take_reset_cause() -> fpc::safety::faults::ResetCause {
    use fpc::safety::faults::ResetCause;
    let csr = embassy_stm32::pac::RCC.csr().read();
    let cause = if csr.iwdgrstf() {
        ResetCause::Watchdog
    } else if csr.borrstf() {
        ResetCause::PowerOn
    } else if csr.sftrstf() {
        // Checked before the pin: a software reset drives NRST, so PINRSTF is set too.
        ResetCause::Software
    } else {
        ResetCause::External
    };
    // Clear the flags so the next reset reports its own cause.
    embassy_stm32::pac::RCC.csr().modify(|w| w.set_rmvf(true));
    cause
}

/// Brings the board up: clocks, debug freeze, servo I/O, ADC burst, PWM (running, outputs
/// off), watchdog (running). Call once, first thing.
pub fn init() -> Board {
    if mutation::is("stack-overflow") {
        overflow_the_stack();
    }
    // No output is configured yet: a failed clock check only logs and resets.
    let Ok(p) = clocks::start() else {
        fault::boot_fault(fault::BootCheck::BoostMode)
    };
    // The control path's code to CCM SRAM, at 170 MHz, before anything that may run it.
    ccm::copy_code();
    test_build::board_init();
    test_build::timing_init();
    check_option_bytes();
    freeze_on_debug_halt();
    // Started here, settled at the end: its register update (≈ 190 µs) overlaps the rest.
    let mut watchdog = BoardWatchdog::start(p.IWDG);
    interrupt::TIM2.set_priority(TIME_PRIORITY);

    let servo_encoder = ServoEncoder::new(Qei::new(
        p.TIM4,
        p.PB6,
        p.PB7,
        qei::Config {
            ch1_pull: Pull::Up,
            ch2_pull: Pull::Up,
            ..qei::Config::default()
        },
    ));
    let servo_torque = ServoTorque::new(p.DAC1, p.PA4);
    let power_good = PowerGood::new(p.PB5);

    use adc::{adc1_channel as adc1, adc2_channel as adc2};
    let master = adc::Sequence {
        injected: [adc1(p.PA0), adc1(p.PA1), adc1(p.PA2)],
        regular: [adc1(p.PA3), adc1(p.PB1), adc1(p.PB12), adc1(p.PC0)],
    };
    let slave = adc::Sequence {
        injected: [adc2(p.PA6), adc2(p.PA7), adc2(p.PC4)],
        regular: [adc2(p.PC5), adc2(p.PB2), adc2(p.PC1), adc2(p.PC2)],
    };
    // The over-current comparators, well before the timers' break inputs listen to them:
    // the ADCs' start-up below is the DACs' and comparators' start-up time (no wait of their
    // own in the boot, which delays the brake after a watchdog reset).
    trip::start_comparators(p.PB0, p.PB11, p.PB13);
    let sampler = adc::start(p.ADC1, p.ADC2, p.DMA1_CH1, &master, &slave);

    supply::start_pvd();
    trip::lock_system_breaks();
    // Timers first (outputs forced low), then the pins handed to them.
    let bridges = pwm::IdleBridges::new(p.TIM1, p.TIM8);
    let push_pull = OutputType::PushPull;
    let section1 = pwm::SectionPins {
        u: (
            PwmPin::new(p.PA8, push_pull),
            ComplementaryPwmPin::new(p.PA11, push_pull),
        ),
        v: (
            PwmPin::new(p.PA9, push_pull),
            ComplementaryPwmPin::new(p.PB14, push_pull),
        ),
        w: (
            PwmPin::new(p.PA10, push_pull),
            ComplementaryPwmPin::new(p.PB15, push_pull),
        ),
    };
    let section2 = pwm::SectionPins {
        u: (
            PwmPin::new(p.PC6, push_pull),
            ComplementaryPwmPin::new(p.PC10, push_pull),
        ),
        v: (
            PwmPin::new(p.PC7, push_pull),
            ComplementaryPwmPin::new(p.PC11, push_pull),
        ),
        w: (
            PwmPin::new(p.PC8, push_pull),
            ComplementaryPwmPin::new(p.PC12, push_pull),
        ),
    };
    let motor_pwm = bridges.start(section1, section2);

    let calibration = {
        interrupt::FLASH.set_priority(FLASH_PRIORITY);
        let flash = embassy_stm32::flash::Flash::new(p.FLASH, FlashIrqs);
        BoardCalibrationStore::new(store_flash::CheckedFlash::new(flash), CALIBRATION_STORE)
    };

    watchdog.settle();
    defmt::info!(
        "board up: {} Hz PWM, ARR {}, dead time {} ns",
        pwm::PWM_HZ,
        pwm::PWM_ARR,
        pwm::DEAD_TIME_NS
    );

    Board {
        control: fpc::ports::ControlPorts {
            cycle: sampler.trigger,
            encoders: sampler.encoders,
            currents: sampler.currents,
            pwm: motor_pwm,
            quadrature: servo_encoder,
            servo: servo_torque,
            pressures: sampler.pressures,
        },
        clock: BoardClock,
        sleep: BoardSleep,
        watchdog,
        calibration,
        power_good,
    }
}

/// The option bytes the firmware needs (`docs/bring-up.md`, step 0). Otherwise a boot
/// fault: no output has been configured yet.
/// - The flash in dual-bank mode (FLASH_OPTR.DBANK = 1, 2 KiB pages), as embassy's
///   `dual-bank` feature and [`CALIBRATION_STORE`] assume; embassy's async `Flash::new` does
///   not check it (its blocking constructor does).
/// - The brown-out reset at level 2 or above (FLASH_OPTR.BOR_LEV ≥ 2: ≈ 2.2 V).
fn check_option_bytes() {
    const OPTR_DBANK: u32 = 1 << 22;
    const OPTR_BOR_LEV_SHIFT: u32 = 8;
    const MIN_BOR_LEV: u32 = if mutation::is("bor-zero-accepted") {
        0
    } else {
        2
    };
    let optr = pac::FLASH.optr().read().0;
    if optr & OPTR_DBANK == 0 {
        fault::boot_fault(fault::BootCheck::FlashBankLayout);
    }
    if (optr >> OPTR_BOR_LEV_SHIFT) & 7 < MIN_BOR_LEV {
        fault::boot_fault(fault::BootCheck::BrownOutLevel);
    }
}

/// A debugger halt stops the motor timers (their outputs go to the idle state, as with
/// MOE = 0) and the watchdog, so stepping through code is safe and does not reset.
fn freeze_on_debug_halt() {
    pac::DBGMCU.apb2fzr().modify(|w| {
        w.set_tim1(true);
        w.set_tim8(true);
    });
    pac::DBGMCU.apb1lfzr().modify(|w| w.set_iwdg(true));
}

/// The `stack-overflow` mutation: a frame larger than SRAM.
#[inline(never)]
fn overflow_the_stack() {
    let mut big = [0u8; 100 * 1024];
    core::hint::black_box(&mut big);
}

/// Both bridges off: MOE = 0 on TIM1 and TIM8 (see [`pwm`] for the idle levels).
fn safe_pwm_off() {
    for tim in [pac::TIM1, pac::TIM8] {
        tim.bdtr().modify(|w| w.set_moe(false));
    }
}

/// Runs the 20 kHz control task above every thread-mode task.
static CONTROL_EXECUTOR: InterruptExecutor = InterruptExecutor::new();

#[interrupt]
fn UART5() {
    // SAFETY: UART5's vector is reserved for this executor (the peripheral is unused), and
    // this handler is the only caller of `on_interrupt`.
    unsafe { CONTROL_EXECUTOR.on_interrupt() }
}

/// Starts the control executor on the UART5 vector at [`CONTROL_PRIORITY`].
pub fn start_control_executor() -> SendSpawner {
    interrupt::UART5.set_priority(CONTROL_PRIORITY);
    CONTROL_EXECUTOR.start(interrupt::UART5)
}
