//! The emulated STM32G474RE: unicorn's Cortex-M4 core, and everything around it the firmware
//! touches, modelled from RM0440 and the ARMv7-M architecture manual.
//!
//! | part | where |
//! |---|---|
//! | exceptions: entry, return, tail-chaining, WFE/SEV, faults | [`cpu`] |
//! | NVIC and SCB | [`nvic`] |
//! | SCB's other registers, DWT, DBGMCU (the private peripheral bus) | [`ppb`] |
//! | TIM1, TIM8, TIM2, TIM4; the lock of TIM1/TIM8's output settings | [`timers`] |
//! | TIM1/TIM8's output stage and break | [`output_stage`] |
//! | COMP1–7, their threshold DACs (DAC3, DAC4), SYSCFG_CFGR2 | [`comp`] |
//! | ADC1/ADC2 dual mode | [`adc`] |
//! | DMA1 and DMAMUX | [`dma`] |
//! | flash interface, option bytes, ECC, the calibration store | [`flash`] |
//! | the flash interface's instruction and data caches, as time pays them | [`art`] |
//! | IWDG | [`iwdg`] |
//! | RCC (clocks, reset flags, peripheral resets), PWR | [`rcc`] |
//! | the peripheral bus: register dispatch, DAC1, GPIOB's input | [`bus`] |
//! | the peripherals' events and interrupt lines, the plant's step | [`events`] |
//! | time, cycles and the period's load | [`load`] |
//! | each sample's compare writes against the update event | [`deadline`] |
//! | the emulator: memory map, boot, resets, power, probe access | [`emulator`] |
//!
//! Time is the CPU's: each executed block advances it by its clock cycles as counted per
//! instruction from the Cortex-M4 TRM ([`timing`], with the wait states of flash and the
//! exception entries and returns) at the current SYSCLK, or, with [`ChipOptions::cpi`], by
//! its instructions times that CPI. The periods' cycle figures are counted either way. The CPU is stopped at the instants
//! the peripherals do something (a timer boundary, the end of an ADC burst, the end of a
//! flash operation, the watchdog's expiry). Interrupts are taken between blocks, where the
//! NVIC's priorities, PRIMASK and BASEPRI allow.
//!
//! The PCB around the chip is [`crate::board`]: which analog signal each ADC pin carries,
//! and what the bridges and the servo make of the compare registers and the DAC.

pub mod adc;
pub mod art;
mod bus;
pub mod comp;
pub mod cpu;
pub mod dap;
pub mod deadline;
pub mod dma;
mod emulator;
mod events;
pub mod flash;
pub mod halt;
pub mod iwdg;
mod load;
pub mod nvic;
pub mod output_stage;
mod ppb;
mod rcc;
pub mod timers;
pub mod timing;

pub use deadline::{DeadlineFigures, SampleTiming};
pub use emulator::{Chip, ChipError};
pub use load::PeriodLoad;

use std::collections::HashMap;

use unicorn_engine::{Arch, Mode, Prot, RegisterARM, Unicorn};

use crate::board::Board;
use crate::elf::Image;
use crate::time::{units_per_cycle, UNITS_PER_US};
use adc::Adc;
use dma::Dma;
use flash::{Flash, FLASH_BASE, FLASH_BYTES, STORE_BASE, STORE_BYTES};
use iwdg::Iwdg;
use nvic::{irq, Nvic};
use rcc::{RCC_CSR_BORRSTF, RCC_CSR_PINRSTF};
use timers::Timer;

/// RAM (SRAM1 + SRAM2, 128 KiB).
pub const RAM: (u32, u32) = (0x2000_0000, 128 * 1024);
/// Flash wait states at 170 MHz (FLASH_ACR.LATENCY = 4, RM0440 Table 9), paid by each
/// flash access in the upper-bound model (no cache hit, no prefetch). The chip charges
/// FLASH_ACR.LATENCY as programmed (0 at the 16 MHz reset clock).
pub const FLASH_WAIT_STATES: u64 = 4;

/// CCM SRAM (32 KiB; zero wait states on the I-code and D-code buses, RM0440 §2.1).
pub const CCM: (u32, u32) = (0x1000_0000, 32 * 1024);
/// System memory (the bootloader), OTP, option bytes, engineering bytes: read only (RM0440
/// memory map, 0x1FFF_0000–0x1FFF_7FFF). Nothing is mapped from there to SRAM1's start, so a
/// stack that overflows below 0x2000_0000 meets a bus error.
const SYSMEM: (u32, u32) = (0x1FFF_0000, 0x8000);
/// Peripherals (APB1, APB2, AHB1, AHB2).
const PERIPH: (u32, u32) = (0x4000_0000, 0x2000_0000);
/// Private peripheral bus (NVIC, SCB, SysTick, DWT, DBGMCU).
const PPB: (u32, u32) = (0xE000_0000, 0x10_0000);

/// Peripheral bases (RM0440 memory map).
mod base {
    pub const TIM2: u32 = 0x4000_0000;
    pub const TIM4: u32 = 0x4000_0800;
    pub const IWDG: u32 = 0x4000_3000;
    pub const PWR: u32 = 0x4000_7000;
    pub const TIM1: u32 = 0x4001_2C00;
    pub const TIM8: u32 = 0x4001_3400;
    pub const DMA1: u32 = 0x4002_0000;
    pub const DMAMUX1: u32 = 0x4002_0800;
    pub const RCC: u32 = 0x4002_1000;
    pub const FLASH: u32 = 0x4002_2000;
    pub const ADC1: u32 = 0x5000_0000;
    pub const ADC2: u32 = 0x5000_0100;
    pub const ADC12: u32 = 0x5000_0300;
    pub const DAC1: u32 = 0x5000_0800;
}

/// Device interrupt numbers (RM0440 table 97).
pub mod irqn {
    /// FLASH global.
    pub const FLASH: usize = 4;
    /// DMA1 channel 1.
    pub const DMA1_CH1: usize = 11;
    /// TIM2 global.
    pub const TIM2: usize = 28;
    /// UART5 global (the firmware's control executor).
    pub const UART5: usize = 53;
}

/// Options of the emulated chip.
#[derive(Clone, Debug)]
pub struct ChipOptions {
    /// `None` (the default): time advances by the cycles counted per instruction
    /// ([`timing`]), an upper bound. `Some(cpi)`: by instructions × this CPI (`--cpi`, to
    /// see what a faster core would do). The periods' cycle figures are counted either way.
    pub cpi: Option<f64>,
    /// LSI frequency, Hz (the IWDG's clock).
    pub lsi_hz: f64,
    /// FLASH_OPTR as programmed (DBANK is bit 22).
    pub optr: u32,
    /// Count the interrupt path's flash lines and flash data reads per period (for the cycle
    /// model of `fpc-pil save-timing`; a memory hook on the program flash slows the emulation).
    pub flash_timing: bool,
}

impl Default for ChipOptions {
    fn default() -> Self {
        ChipOptions {
            cpi: None,
            lsi_hz: 32_000.0,
            optr: flash::OPTR_BRINGUP,
            flash_timing: false,
        }
    }
}

/// Why the chip reset.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResetKind {
    /// Power-on (BORRSTF, PINRSTF).
    PowerOn,
    /// The IWDG reached 0 (IWDGRSTF, PINRSTF).
    Watchdog,
    /// SCB AIRCR.SYSRESETREQ (SFTRSTF, PINRSTF).
    Software,
}

/// A reset that happened, and when.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResetRecord {
    /// Emulated time, s.
    pub at_s: f64,
    /// Why.
    pub kind: ResetKind,
}

/// Everything the chip holds besides the core's registers: the unicorn user data.
pub struct Soc {
    /// Emulated time, units of [`crate::time`].
    pub time: u64,
    frac: f64,
    cpi: Option<f64>,
    /// The last block's end address and how its last instruction may branch (its refill is
    /// added when the next block shows whether it was taken).
    branch: Option<(u32, timing::Flow)>,
    /// An exception return whose cycles are due: 12, or 6 if an entry tail-chains to it.
    return_due: Option<u32>,
    /// The 64-bit flash line the instruction fetch is in (for the wait states).
    fetch_line: u32,
    /// The flash interface's instruction cache, as the time pays it.
    icache: art::LineCache,
    /// The flash interface's data cache, as the time pays it.
    dcache: art::LineCache,
    /// Per-block counts of the period's interrupt path (with [`Soc::profile`]).
    profile_now: HashMap<u32, (u64, u64)>,
    /// Record, per block address, the instructions and cycles of each period's interrupt
    /// path, and keep those of the period with the most cycles.
    pub profile: bool,
    /// With [`Soc::profile`]: how many of the periods with the most cycles to keep in
    /// [`Soc::profile_top`] (1 unless set: the worst).
    pub profile_keep: usize,
    /// The [`Soc::profile_keep`] periods with the most cycles so far, most first.
    pub profile_top: Vec<ProfiledPeriod>,
    /// Time units per SYSCLK cycle now.
    units_per_cycle: f64,
    /// SYSCLK, Hz.
    pub sysclk_hz: u64,
    /// Instructions executed since power-on.
    pub instructions: u64,
    deadline: u64,
    /// The NVIC and SCB.
    pub nvic: Nvic,
    /// The exception being handled (IPSR), as the chip entered it.
    pub ipsr: usize,
    /// The event register (WFE).
    pub event: bool,
    /// Asleep in WFE.
    pub sleeping: bool,
    stop: Option<cpu::Stop>,
    blocks: cpu::BlockCache,
    regs: HashMap<u32, u32>,
    tim1: Timer,
    tim8: Timer,
    tim2: Timer,
    tim4: Timer,
    adc1: Adc,
    adc2: Adc,
    adc_ccr: u32,
    dma: Dma,
    /// The flash interface and the calibration store's array.
    pub flash: Flash,
    /// The comparators, their DACs and SYSCFG_CFGR2.
    pub comps: comp::Comparators,
    /// Every break the advanced timers took from their break inputs.
    pub breaks: Vec<BreakRecord>,
    /// The IWDG.
    pub iwdg: Iwdg,
    dac_dhr: u32,
    dac_cr: u32,
    dac_mcr: u32,
    dwt_ctrl: u32,
    /// While the cycle counter counts: the time its count was 0 (counted back).
    dwt_base: u64,
    /// While it does not: the count it holds.
    dwt_held: u32,
    /// The ADC burst in flight: (injected end, regular end), time units.
    burst: Option<(u64, u64)>,
    /// The PCB and the plant.
    pub board: Board,
    /// Next plant step while the PWM timer is stopped.
    plant_next: u64,
    /// Set when the plant advanced (a PWM period ended).
    pub plant_stepped: bool,
    /// A period is over and the plant is due to step: the chip waits for the host, which
    /// looks at the plant as the firmware left it (as `fpc-sim run` does between polling
    /// the tasks and advancing the plant).
    pub held: bool,
    /// The host has looked: the held step may go.
    release: bool,
    /// A reset to carry out.
    pub reset_pending: Option<ResetKind>,
    /// Every reset so far.
    pub resets: Vec<ResetRecord>,
    /// Reset flags as RCC_CSR shows them.
    csr_flags: u32,
    /// The load of the PWM period in progress.
    period: PeriodLoad,
    /// Loads of the finished periods since recording began.
    pub periods: Vec<PeriodLoad>,
    /// Record [`Soc::periods`] and [`Soc::samples`].
    pub recording: bool,
    /// The sample in progress (from an ADC burst's end to the next).
    sample: Option<deadline::OpenSample>,
    /// The burst end of a sample whose control step overran its period and still runs.
    overrun: Option<u64>,
    /// Timings of the finished samples since recording began.
    pub samples: Vec<SampleTiming>,
    /// An interrupt path is open (handler mode entered from thread mode).
    path_open: bool,
    /// A debugger's halt in progress ([`halt`]).
    pub halt: Option<halt::Halt>,
    /// Halts of the core since power-on (a debugger's; the host's link must make none).
    pub halts: u32,
    /// The debug port as a probe reaches it ([`dap`]).
    pub dap: dap::DebugPort,
    /// The core is in lockup (a fault while entering HardFault, or in it): it executes
    /// nothing until a reset (ARMv7-M B1.5.15).
    pub locked_up: bool,
    /// When the core locked up, s.
    pub lockups: Vec<f64>,
    /// The core is stalled on a flash access until this instant (a read of a bank being
    /// programmed or erased): no instruction runs, the peripherals go on.
    pub stall_until: Option<u64>,
    /// Stop the control executor for good at its next entry (a hung control task).
    pub hang_pending: bool,
    /// Raise a bus fault (HardFault) at the control executor's next entry.
    pub bus_fault_pending: bool,
    /// The ADCs never convert (a dead analog front end: the control task starves).
    pub adc_dead: bool,
    /// Address of a `b .` the hang sends the core to.
    pub spin_address: u32,
    /// HardFaults the core raised.
    pub faults_taken: u32,
    /// An error of the emulation raised inside a hook.
    pub error: Option<String>,
    /// Memory reads of the calibration store since power-on.
    pub store_reads: u64,
    /// The chip is unpowered (after a power cut, until [`Chip::power_on`]).
    pub powered: bool,
    /// A RAM word to read at each entry of the control executor (the RTT command channel's
    /// read offset, which the firmware's command task advances).
    pub watch_word: Option<u32>,
    /// The plant cycle of the last entry of the control executor, and `watch_word` then.
    pub control_entry: Option<(u64, u32)>,
    /// Milestones of each boot, the first time each is reached after a reset: (emulated
    /// time, s; what).
    pub milestones: Vec<(f64, Milestone)>,
    /// Address of the image's `main` (for [`Milestone::Main`]).
    pub main_address: u32,
    /// Address of the image's `fpc::tasks::control_cycle` (for [`Milestone::ControlCycle`];
    /// 0 if the image has none).
    pub control_cycle_address: u32,
    /// [`ChipOptions::flash_timing`].
    pub flash_timing: bool,
    /// The 64-bit flash lines of the period's interrupt path so far (instruction fetches).
    path_lines: std::collections::HashSet<u32>,
    /// The 64-bit flash lines of the period's interrupt path's data reads so far.
    path_data_lines: std::collections::HashSet<u32>,
    /// The flash line the last instruction fetch was in.
    last_line: u32,
}

/// One period's interrupt path, block by block ([`Soc::profile_top`]).
#[derive(Clone, Debug, Default)]
pub struct ProfiledPeriod {
    /// When the period ended (the plant's step), emulated s.
    pub end_s: f64,
    /// The interrupt path's cycles in it ([`PeriodLoad::path_cycles`]).
    pub path_cycles: u64,
    /// Block address → (instructions, cycles).
    pub blocks: HashMap<u32, (u64, u64)>,
}

/// A break an advanced timer took from its break input (the hardware switching a bridge
/// off), and what the core did meanwhile.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BreakRecord {
    /// 0: TIM1 (section 1), 1: TIM8 (section 2).
    pub timer: usize,
    /// When the break input's source crossed (the plant step that carried the current), s.
    pub crossed_at_s: f64,
    /// When the outputs were in their safe state: the comparator's propagation and the break
    /// filter later, s.
    pub safe_at_s: f64,
    /// Instructions the core executed between the crossing and the safe state.
    pub instructions_between: u64,
}

/// A step of a boot the chip notices (the first time after each reset).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Milestone {
    /// The core fetches the reset vector.
    Reset,
    /// `main` entered: the runtime has zeroed `.bss` and copied `.data` (at the 16 MHz
    /// reset clock).
    Main,
    /// SYSCLK switched to the PLL (RCC_CFGR.SW).
    Pll,
    /// TIM1's counter started (CR1.CEN): the PWM and the ADC bursts run.
    PwmStarted,
    /// The IWDG started (key 0xCCCC).
    WatchdogStarted,
    /// The control executor's interrupt entered for the first time (the control task's
    /// first poll).
    ControlTask,
    /// The control task's first cycle (`fpc::tasks::control_cycle` entered): the step built,
    /// the first sampling burst in. `hal_sim::board::exec::BOOT_US` models the time to here.
    ControlCycle,
    /// A bridge's main output enable (TIM1 or TIM8 BDTR.MOE) set.
    OutputsOn,
}

impl Soc {
    /// TIM1's (`timer` 0) or TIM8's (1) register at offset `off` ([`timers::reg`]) as last
    /// written (CCRx, CCER, BDTR: the registers the output stage reads); 0 elsewhere.
    pub fn timer_register(&self, timer: usize, off: u32) -> u32 {
        let t = if timer == 0 { &self.tim1 } else { &self.tim8 };
        t.regs.get((off / 4) as usize).copied().unwrap_or(0)
    }

    /// DAC1 channel 1's output code (DHR12R1 as transferred to the output).
    pub fn dac_code(&self) -> u16 {
        (self.dac_dhr & 0xFFF) as u16
    }

    /// DMA1 channel `c`'s memory address (CMAR): where the firmware asked its transfers to go.
    pub fn dma_memory_address(&self, c: usize) -> u32 {
        self.dma.ch.get(c).map_or(0, |ch| ch[3])
    }

    /// Notes `m` if it is the first since the last reset.
    pub(crate) fn milestone(&mut self, m: Milestone) {
        let since_reset = self
            .milestones
            .iter()
            .rposition(|(_, x)| *x == Milestone::Reset)
            .unwrap_or(0);
        if !self.milestones[since_reset..].iter().any(|(_, x)| *x == m) {
            self.milestones.push((crate::time::seconds(self.time), m));
        }
    }
}

impl Soc {
    fn new(options: &ChipOptions, board: Board) -> Self {
        let mut flash = Flash::new();
        flash.optr = options.optr;
        Soc {
            time: 0,
            frac: 0.0,
            cpi: options.cpi,
            branch: None,
            return_due: None,
            fetch_line: u32::MAX,
            icache: art::LineCache::instructions(),
            dcache: art::LineCache::data(),
            profile_now: HashMap::new(),
            profile: false,
            profile_keep: 1,
            profile_top: Vec::new(),
            units_per_cycle: units_per_cycle(16_000_000),
            sysclk_hz: 16_000_000,
            instructions: 0,
            deadline: 0,
            nvic: Nvic::default(),
            ipsr: 0,
            event: false,
            sleeping: false,
            stop: None,
            blocks: cpu::BlockCache::new(),
            regs: HashMap::new(),
            tim1: Timer::new(0xFFFF),
            tim8: Timer::new(0xFFFF),
            tim2: Timer::new(0xFFFF_FFFF),
            tim4: Timer::new(0xFFFF),
            adc1: Adc::new(),
            adc2: Adc::new(),
            adc_ccr: 0,
            dma: Dma::default(),
            flash,
            comps: comp::Comparators::default(),
            breaks: Vec::new(),
            iwdg: Iwdg::new(options.lsi_hz),
            dac_dhr: 0,
            dac_cr: 0,
            dac_mcr: 0,
            dwt_ctrl: 0,
            dwt_base: 0,
            dwt_held: 0,
            burst: None,
            board,
            plant_next: 50 * UNITS_PER_US,
            plant_stepped: false,
            held: false,
            release: false,
            reset_pending: None,
            resets: Vec::new(),
            csr_flags: RCC_CSR_BORRSTF | RCC_CSR_PINRSTF,
            period: PeriodLoad::default(),
            periods: Vec::new(),
            recording: false,
            sample: None,
            overrun: None,
            samples: Vec::new(),
            path_open: false,
            stall_until: None,
            halt: None,
            halts: 0,
            dap: dap::DebugPort::default(),
            locked_up: false,
            lockups: Vec::new(),
            hang_pending: false,
            bus_fault_pending: false,
            adc_dead: false,
            spin_address: 0,
            faults_taken: 0,
            error: None,
            store_reads: 0,
            powered: true,
            watch_word: None,
            control_entry: None,
            milestones: vec![(0.0, Milestone::Reset)],
            main_address: 0,
            control_cycle_address: 0,
            flash_timing: options.flash_timing,
            path_lines: std::collections::HashSet::new(),
            path_data_lines: std::collections::HashSet::new(),
            last_line: u32::MAX,
        }
    }
}
