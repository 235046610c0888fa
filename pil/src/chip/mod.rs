//! The emulated STM32G474RE: unicorn's Cortex-M4 core, and everything around it the firmware
//! touches, modelled from RM0440 and the ARMv7-M architecture manual.
//!
//! | part | where |
//! |---|---|
//! | exceptions: entry, return, tail-chaining, WFE/SEV, faults | [`cpu`] |
//! | NVIC and SCB | [`nvic`] |
//! | TIM1, TIM8, TIM2, TIM4 | [`timers`] |
//! | ADC1/ADC2 dual mode, DMA1 and DMAMUX | [`adc`] |
//! | flash interface, option bytes, ECC, the calibration store | [`flash`] |
//! | IWDG | [`iwdg`] |
//! | halting debug (DHCSR, DEMCR), DBGMCU's freeze, the debug port's memory access | [`debug`] |
//! | the gate-driver inputs from TIM1/TIM8's output stage | [`gates`] |
//! | RCC (clocks, reset flags, peripheral resets), PWR, DAC1, DWT, the rest | here |
//!
//! Time is the CPU's: each executed block advances it by its instructions times the CPI
//! ([`ChipOptions::cpi`], 1.5 by default) at the current SYSCLK, or by its clock cycles as
//! counted per instruction from the Cortex-M4 TRM ([`timing`], with the wait states of
//! flash and the exception entries and returns). The periods' cycle figures are counted
//! either way. The CPU is stopped at the instants
//! the peripherals do something (a timer boundary, the end of an ADC burst, the end of a
//! flash operation, the watchdog's expiry). Interrupts are taken between blocks, where the
//! NVIC's priorities, PRIMASK and BASEPRI allow.
//!
//! The PCB around the chip is [`crate::board`]: which analog signal each ADC pin carries,
//! and what the bridges and the servo make of the compare registers and the DAC.

pub mod adc;
pub mod cpu;
pub mod debug;
pub mod flash;
pub mod gates;
pub mod iwdg;
pub mod nvic;
pub mod timers;
pub mod timing;

use std::collections::HashMap;

use unicorn_engine::{Arch, Mode, Prot, RegisterARM, Unicorn};

use crate::board::Board;
use crate::elf::Image;
use crate::time::{units_per_cycle, UNITS_PER_US};
use adc::{Adc, Dma};
use flash::{Flash, FLASH_BASE, FLASH_BYTES, STORE_BASE, STORE_BYTES};
use iwdg::Iwdg;
use nvic::{irq, Nvic};
use timers::Timer;

/// RAM (SRAM1 + SRAM2, 128 KiB).
pub const RAM: (u32, u32) = (0x2000_0000, 128 * 1024);
/// Flash wait states at 170 MHz (FLASH_ACR.LATENCY = 4, RM0440 Table 9), paid by each
/// flash access in the upper-bound model (no cache hit, no prefetch). The chip charges
/// FLASH_ACR.LATENCY as programmed (0 at the 16 MHz reset clock).
pub const FLASH_WAIT_STATES: u64 = 4;

/// CCM SRAM (32 KiB; zero wait states on the I-code and D-code buses, RM0440 §2.1).
pub const CCM: (u32, u32) = (0x1000_0000, 32 * 1024);
/// System memory, OTP, option bytes, engineering bytes.
const SYSMEM: (u32, u32) = (0x1FFF_0000, 0x1_0000);
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

/// ADC12 external trigger codes of TIM1_TRGO2 (RM0440 tables 163/165).
const EXTSEL_TIM1_TRGO2: u32 = 10;
const JEXTSEL_TIM1_TRGO2: u32 = 8;

/// Options of the emulated chip.
#[derive(Clone, Debug)]
pub struct ChipOptions {
    /// `Some(cpi)`: time advances by instructions × this CPI (the default: 1.5, the typical
    /// figure, `pil/README.md`). `None`: by the cycles counted per instruction ([`timing`]),
    /// an upper bound. The periods' cycle figures are counted either way.
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
            cpi: Some(crate::DEFAULT_CPI),
            lsi_hz: 32_000.0,
            optr: flash::OPTR_FACTORY,
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

/// What the peripherals add up over one PWM period, for the instruction figures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PeriodLoad {
    /// Instructions executed in handler mode (interrupts, the control executor).
    pub handler: u64,
    /// Instructions executed in thread mode.
    pub thread: u64,
    /// Exceptions taken.
    pub exceptions: u32,
    /// Handler-mode instructions from the first exception entry until the return to
    /// thread mode (the interrupt path of the period, nested and tail-chained handlers
    /// included).
    pub interrupt_path: u64,
    /// Clock cycles of the interrupt path ([`timing`]: the instructions' cycles and branch
    /// refills, the exception entries and returns, and the flash wait states of
    /// [`PeriodLoad::path_wait_cycles`]).
    pub path_cycles: u64,
    /// The part of [`PeriodLoad::path_cycles`] that is flash wait states: 4 for each move of
    /// the instruction fetch into another 64-bit line of program flash, for each data read of
    /// program flash, and for each vector fetch (the upper bound: no cache, no prefetch).
    pub path_wait_cycles: u64,
    /// Instructions of the interrupt path fetched from program flash (the rest run from
    /// CCM SRAM).
    pub path_flash_instructions: u64,
    /// With [`ChipOptions::flash_timing`]: distinct 64-bit flash lines the interrupt path
    /// fetched instructions from (each a flash access unless the instruction cache holds it).
    pub path_lines: u32,
    /// With [`ChipOptions::flash_timing`]: how often the interrupt path's instruction fetch
    /// moved into another 64-bit flash line (each a flash access if no cache held any line).
    pub path_line_entries: u32,
    /// With [`ChipOptions::flash_timing`]: the interrupt path's data reads of program flash
    /// (literal pools, constants, tables; the vector fetches are not in it): each a flash
    /// access while the data cache is off.
    pub path_flash_reads: u32,
    /// With [`ChipOptions::flash_timing`]: distinct 64-bit flash lines of those data reads.
    pub path_data_lines: u32,
    /// A flash program or erase was in progress at some point of the period.
    pub flash_busy: bool,
    /// The data cache was off (FLASH_ACR.DCEN = 0) at some point of the period.
    pub dcache_off: bool,
}

/// Everything the chip holds besides the core's registers: the unicorn user data.
#[derive(Clone)]
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
    /// Per-block counts of the period's interrupt path (with [`Soc::profile`]).
    profile_now: HashMap<u32, (u64, u64)>,
    /// Record, per block address, the instructions and cycles of each period's interrupt
    /// path, and keep those of the period with the most cycles.
    pub profile: bool,
    /// The profile of the period with the most cycles so far: (its cycles, block address →
    /// (instructions, cycles)).
    pub profile_worst: (u64, HashMap<u32, (u64, u64)>),
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
    /// The IWDG.
    pub iwdg: Iwdg,
    /// The halting-debug registers, DBGMCU and the halt state.
    pub debug: debug::Debug,
    dac_dhr: u32,
    dac_cr: u32,
    dac_mcr: u32,
    dwt_ctrl: u32,
    dwt_base: u64,
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
    /// Record [`Soc::periods`].
    pub recording: bool,
    /// An interrupt path is open (handler mode entered from thread mode).
    path_open: bool,
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
            profile_now: HashMap::new(),
            profile: false,
            profile_worst: (0, HashMap::new()),
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
            iwdg: Iwdg::new(options.lsi_hz),
            debug: debug::Debug::new(),
            dac_dhr: 0,
            dac_cr: 0,
            dac_mcr: 0,
            dwt_ctrl: 0,
            dwt_base: 0,
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
            path_open: false,
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

    /// Notes the flash interface's state in the period's load (busy, data cache off).
    pub(crate) fn note_flash_state(&mut self) {
        self.period.flash_busy |= self.flash.busy();
        self.period.dcache_off |= self.flash.acr & (1 << 10) == 0;
    }

    /// With [`ChipOptions::flash_timing`]: the interrupt path executed `size` bytes of code
    /// at `addr`.
    pub(crate) fn fetched(&mut self, addr: u32, size: u32) {
        if self.flash_timing && self.path_open && addr < STORE_BASE && size > 0 {
            let mut line = addr & !7;
            while line < addr + size {
                self.path_lines.insert(line);
                if line != self.last_line {
                    self.period.path_line_entries += 1;
                    self.last_line = line;
                }
                line += 8;
            }
        }
    }

    /// The interrupt path begins (an exception entry from thread mode): its first fetch is
    /// from a new line.
    pub(crate) fn path_entered(&mut self) {
        self.last_line = u32::MAX;
    }

    /// With [`ChipOptions::flash_timing`]: the interrupt path read `size` bytes of program
    /// flash at `addr` as data.
    fn flash_read(&mut self, addr: u32, size: u32) {
        let ws = self.flash_latency();
        if self.path_open {
            self.period.path_wait_cycles += ws;
        }
        self.account(ws, false);
        if self.flash_timing && self.path_open {
            self.period.path_flash_reads += 1;
            self.path_data_lines.insert(addr & !7);
            self.path_data_lines
                .insert(addr.wrapping_add(size.max(1) - 1) & !7);
        }
    }

    /// Advances time by the block of code at `addr` (`size` bytes) that is about to run.
    fn execute(&mut self, addr: u32, size: u32, b: &timing::Block) {
        let n = b.instructions;
        self.instructions += u64::from(n);
        let mut cycles = u64::from(b.cycles);
        if let Some(c) = self.return_due.take() {
            self.account(u64::from(c), true);
        }
        // The refill of the last block's branch, if it was taken.
        if let Some((end, flow)) = self.branch.take() {
            let taken = match flow {
                timing::Flow::Next => false,
                timing::Flow::Branch => true,
                timing::Flow::Conditional => addr != end,
            };
            if taken {
                cycles += u64::from(timing::BRANCH_REFILL);
            }
        }
        self.branch = Some((addr.wrapping_add(size), b.flow));
        // Wait states: each move of the fetch into another 64-bit line of program flash.
        let mut wait = 0;
        let in_flash = (FLASH_BASE..STORE_BASE).contains(&addr);
        if in_flash && size > 0 {
            let mut line = addr & !7;
            while line < addr + size {
                if line != self.fetch_line {
                    wait += self.flash_latency();
                    self.fetch_line = line;
                }
                line += 8;
            }
        } else {
            self.fetch_line = u32::MAX;
        }
        cycles += wait;
        if self.ipsr != 0 {
            self.period.handler += u64::from(n);
            if self.path_open {
                self.period.interrupt_path += u64::from(n);
                self.period.path_cycles += cycles;
                self.period.path_wait_cycles += wait;
                if in_flash {
                    self.period.path_flash_instructions += u64::from(n);
                }
                if self.profile {
                    let e = self.profile_now.entry(addr).or_default();
                    e.0 += u64::from(n);
                    e.1 += cycles;
                }
            }
        } else {
            self.period.thread += u64::from(n);
        }
        let cycles_f = match self.cpi {
            Some(cpi) => f64::from(n) * cpi,
            None => cycles as f64,
        };
        self.advance(cycles_f);
    }

    /// FLASH_ACR.LATENCY: the wait states of a flash access now.
    fn flash_latency(&self) -> u64 {
        u64::from(self.flash.acr & 0xF)
    }

    /// Advances time by `cycles` clock cycles.
    fn advance(&mut self, cycles: f64) {
        self.frac += cycles * self.units_per_cycle;
        let whole = self.frac.floor();
        self.frac -= whole;
        self.time += whole as u64;
    }

    /// Cycles spent outside the instructions (exception entry and return, wait states of a
    /// data read): counted in the interrupt path if `path` (or if one is open), and in time
    /// unless time runs at a fixed CPI.
    fn account(&mut self, cycles: u64, path: bool) {
        if path || self.path_open {
            self.period.path_cycles += cycles;
        }
        if self.cpi.is_none() {
            self.advance(cycles as f64);
        }
    }

    /// An exception was entered: 12 cycles (ARM DDI 0439B §3.3.1: entry latency with
    /// zero-wait memory), 6 if it tail-chains to a return, plus 17 if the frame is the
    /// extended one (S0–S15 and FPSCR: the lazily stacked FP state, counted as stacked), plus
    /// the vector fetch's wait states when the table is in flash.
    pub(crate) fn exception_entered(&mut self, extended: bool, vector_in_flash: bool) {
        let mut cycles = match self.return_due.take() {
            Some(_) => 6,
            None => 12,
        };
        if extended {
            cycles += 17;
        }
        if vector_in_flash {
            let ws = self.flash_latency();
            cycles += ws;
            if self.path_open {
                self.period.path_wait_cycles += ws;
            }
        }
        // An interrupt taken between a branch and its target: the refill is paid.
        if let Some((_, timing::Flow::Branch | timing::Flow::Conditional)) = self.branch.take() {
            cycles += u64::from(timing::BRANCH_REFILL);
        }
        self.fetch_line = u32::MAX;
        self.account(cycles, true);
    }

    /// An exception returned: its 12 cycles (plus 17 to unstack an extended frame) are due,
    /// 6 instead if another exception tail-chains (counted at that entry).
    pub(crate) fn exception_returned(&mut self, extended: bool) {
        self.branch = None;
        self.fetch_line = u32::MAX;
        if extended {
            self.account(17, true);
        }
        self.return_due = Some(12);
    }

    /// Peripheral registers to their values after a system reset (RAM and flash contents
    /// stay; the RCC keeps its reset flags; the IWDG stops; the plant goes on).
    fn reset_peripherals(&mut self) {
        self.units_per_cycle = units_per_cycle(16_000_000);
        self.sysclk_hz = 16_000_000;
        self.nvic = Nvic::default();
        self.ipsr = 0;
        self.branch = None;
        self.return_due = None;
        self.fetch_line = u32::MAX;
        self.blocks.forget_ram();
        self.event = false;
        self.sleeping = false;
        self.stop = None;
        self.regs.clear();
        self.tim1 = Timer::new(0xFFFF);
        self.tim8 = Timer::new(0xFFFF);
        self.tim2 = Timer::new(0xFFFF_FFFF);
        self.tim4 = Timer::new(0xFFFF);
        self.adc1 = Adc::new();
        self.adc2 = Adc::new();
        self.adc_ccr = 0;
        self.dma = Dma::default();
        self.flash.reset();
        self.iwdg = Iwdg::new(self.iwdg.lsi_hz);
        self.dac_dhr = 0;
        self.dac_cr = 0;
        self.dac_mcr = 0;
        self.dwt_ctrl = 0;
        self.burst = None;
        self.plant_next = self.time + 50 * UNITS_PER_US;
        self.reset_pending = None;
        self.path_open = false;
        self.hang_pending = false;
        self.bus_fault_pending = false;
        self.board.dma_writes.clear();
        self.watch_word = None;
        self.control_entry = None;
    }

    /// The timer kernel clock period (APB prescalers are 1 in this firmware; an APB
    /// prescaler > 1 would double it, RM0440 §7.2).
    fn timer_clock(&self) -> f64 {
        self.units_per_cycle * self.ahb_div()
    }

    fn ahb_div(&self) -> f64 {
        let hpre = (self.reg(base::RCC + 0x08) >> 4) & 0xF;
        if hpre < 8 {
            1.0
        } else {
            [2.0, 4.0, 8.0, 16.0, 64.0, 128.0, 256.0, 512.0][(hpre - 8) as usize]
        }
    }

    fn reg(&self, addr: u32) -> u32 {
        self.regs
            .get(&addr)
            .copied()
            .unwrap_or_else(|| reset_value(addr))
    }

    /// The SYSCLK the RCC selects now.
    fn sysclk(&self) -> u64 {
        let cfgr = self.reg(base::RCC + 0x08);
        match cfgr & 3 {
            3 => {
                let pll = self.reg(base::RCC + 0x0C);
                let input = match pll & 3 {
                    3 => 24_000_000u64,
                    _ => 16_000_000,
                };
                let m = u64::from((pll >> 4) & 0xF) + 1;
                let n = u64::from((pll >> 8) & 0x7F);
                let r = 2 * (u64::from((pll >> 25) & 3) + 1);
                input / m * n / r
            }
            2 => 24_000_000,
            _ => 16_000_000,
        }
    }

    fn clocks_changed(&mut self) {
        let hz = self.sysclk();
        if hz == self.sysclk_hz {
            return;
        }
        self.sysclk_hz = hz;
        self.units_per_cycle = units_per_cycle(hz);
        let (now, clk) = (self.time, self.timer_clock());
        for t in [
            &mut self.tim1,
            &mut self.tim8,
            &mut self.tim2,
            &mut self.tim4,
        ] {
            t.clock_changed(now, clk);
        }
    }

    /// The ADC clock period: synchronous HCLK/1, /2, /4 (CKMODE), or the asynchronous kernel
    /// clock (SYSCLK with ADC12SEL = system) divided by PRESC.
    fn adc_clock(&self) -> f64 {
        let ckmode = (self.adc_ccr >> 16) & 3;
        if ckmode != 0 {
            return self.units_per_cycle * self.ahb_div() * f64::from(1u32 << (ckmode - 1));
        }
        const PRESC: [f64; 12] = [1., 2., 4., 6., 8., 10., 12., 16., 32., 64., 128., 256.];
        let presc = ((self.adc_ccr >> 18) & 0xF) as usize;
        self.units_per_cycle * PRESC.get(presc).copied().unwrap_or(256.0)
    }

    /// Updates the NVIC's pending bits from the peripherals' interrupt lines (level
    /// sensitive: a line still high is pended again).
    fn update_irqs(&mut self) {
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
    fn pwm_running(&self) -> bool {
        self.tim1.running()
    }

    /// The next instant a peripheral does something.
    fn next_event(&self) -> u64 {
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

    fn tim1_trgo2_is_oc4(&self) -> bool {
        (self.tim1.regs[1] >> 20) & 0xF == 7
    }

    /// Handles every peripheral event due at the current time.
    fn process_events(&mut self) {
        loop {
            let now = self.time;
            let mut handled = false;
            if self.pwm_running() {
                if self.tim1_trgo2_is_oc4() && self.tim1.next_oc4_rise().is_some_and(|t| t <= now) {
                    self.tim1.fire_oc4();
                    self.adc_trigger();
                    handled = true;
                }
                if self.tim1.next_boundary().is_some_and(|t| t <= now) {
                    if self.tim1.next_is_update_at_peak() && !self.release {
                        // The period is over: the host looks first (see `held`).
                        self.held = true;
                        return;
                    }
                    self.release = false;
                    let b = self.tim1.fire_boundary();
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
                let b = self.tim8.fire_boundary();
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
    fn pwm_period_end(&mut self) {
        // The compare values just transferred act over the next period; the plant first
        // runs the one that ended with the values in force during it.
        self.step_plant();
        let arr = self.tim1.regs[(timers::reg::ARR / 4) as usize];
        self.board.latch_duties(0, self.tim1.active_ccr, arr);
    }

    fn step_plant(&mut self) {
        let moe = |t: &Timer| t.regs[(timers::reg::BDTR / 4) as usize] & (1 << 15) != 0;
        let dac = if self.dac_cr & 1 != 0 && self.powered {
            self.dac_dhr & 0xFFF
        } else {
            2048
        };
        // A timer frozen by a debug halt has its outputs disabled as if MOE were 0.
        let on = if self.powered {
            [
                moe(&self.tim1) && !self.debug.frozen_advanced(0),
                moe(&self.tim8) && !self.debug.frozen_advanced(1),
            ]
        } else {
            [false, false]
        };
        self.board.step(on, dac as u16);
        if self.recording {
            self.period.path_lines = self.path_lines.len() as u32;
            self.period.path_data_lines = self.path_data_lines.len() as u32;
            self.periods.push(self.period);
            if self.profile && self.period.path_cycles > self.profile_worst.0 {
                self.profile_worst = (
                    self.period.path_cycles,
                    std::mem::take(&mut self.profile_now),
                );
            }
        }
        self.profile_now.clear();
        self.path_lines.clear();
        self.path_data_lines.clear();
        self.period = PeriodLoad::default();
        self.note_flash_state();
        self.plant_stepped = true;
    }

    /// TIM1_TRGO2: both ADCs start their injected then regular sequences if armed.
    fn adc_trigger(&mut self) {
        let dual = self.adc_ccr & 0x1F;
        let inj = self.adc1.injected_armed(JEXTSEL_TIM1_TRGO2);
        let reg = self.adc1.regular_armed(EXTSEL_TIM1_TRGO2);
        if !(inj || reg) || self.burst.is_some() || self.adc_dead {
            return;
        }
        let clk = self.adc_clock();
        let time_of = |a: &Adc, chans: Vec<u32>| -> f64 {
            chans.iter().map(|&c| a.conversion_cycles(c)).sum::<f64>() * clk
        };
        // In dual mode the slave converts alongside; the group ends with the slower one.
        let slave = dual != 0;
        let inj_t = if inj {
            let mut t = time_of(&self.adc1, self.adc1.injected_channels());
            if slave {
                t = t.max(time_of(&self.adc2, self.adc2.injected_channels()));
            }
            t
        } else {
            0.0
        };
        let reg_t = if reg {
            let mut t = time_of(&self.adc1, self.adc1.regular_channels());
            if slave {
                t = t.max(time_of(&self.adc2, self.adc2.regular_channels()));
            }
            t
        } else {
            0.0
        };
        let now = self.time;
        let inj_end = if inj {
            now + inj_t.ceil() as u64
        } else {
            u64::MAX
        };
        let reg_end = now + (inj_t + reg_t).ceil() as u64;
        self.burst = Some((if inj { inj_end } else { u64::MAX }, reg_end));
        if !inj {
            self.burst = Some((u64::MAX, reg_end));
        }
        if !reg {
            // Only the injected group: nothing to carry by DMA.
            self.burst = Some((inj_end, u64::MAX));
        }
    }

    fn injected_done(&mut self) {
        let dual = self.adc_ccr & 0x1F != 0;
        for (rank, ch) in self.adc1.injected_channels().into_iter().enumerate() {
            let v = self.board.analog(1, ch);
            self.adc1.set_jdr(rank, v);
        }
        if dual {
            for (rank, ch) in self.adc2.injected_channels().into_iter().enumerate() {
                let v = self.board.analog(2, ch);
                self.adc2.set_jdr(rank, v);
            }
        }
        let reg = self.burst.map(|(_, r)| r).unwrap_or(u64::MAX);
        self.burst = if reg == u64::MAX {
            None
        } else {
            Some((u64::MAX, reg))
        };
    }

    /// The regular sequence converted: each pair to ADC12_CDR and on by DMA. Returns the
    /// memory writes to make (address, word).
    fn regular_done(&mut self) {
        self.burst = None;
        let ch1 = self.adc1.regular_channels();
        let ch2 = self.adc2.regular_channels();
        let mdma = (self.adc_ccr >> 14) & 3;
        let request = self.dma.mux[0] & 0x7F;
        let n = ch1.len();
        for (i, &c1) in ch1.iter().enumerate() {
            let a = self.board.analog(1, c1);
            let b = ch2.get(i).map(|&c| self.board.analog(2, c)).unwrap_or(0);
            self.adc1.set_dr(a, i + 1 == n);
            self.adc2.set_dr(b, i + 1 == n);
            // DMAMUX request 5 is ADC1 (RM0440 table 91); MDMA packs the pair.
            if mdma != 0 && request == 5 {
                if let Some((at, _)) = self.dma.transfer(0) {
                    let word = u32::from(a) | u32::from(b) << 16;
                    self.board.dma_writes.push((at, word));
                }
            }
        }
    }

    /// A CPU read of a peripheral register.
    fn periph_read(&mut self, addr: u32) -> u32 {
        let now = self.time;
        let off = |b: u32| addr - b;
        match addr {
            a if (base::TIM1..base::TIM1 + 0x400).contains(&a) => {
                self.tim1.read(off(base::TIM1), now)
            }
            a if (base::TIM8..base::TIM8 + 0x400).contains(&a) => {
                self.tim8.read(off(base::TIM8), now)
            }
            a if (base::TIM2..base::TIM2 + 0x400).contains(&a) => {
                self.tim2.read(off(base::TIM2), now)
            }
            a if (base::TIM4..base::TIM4 + 0x400).contains(&a) => {
                if off(base::TIM4) == timers::reg::CNT {
                    u32::from(self.board.quadrature())
                } else {
                    self.tim4.read(off(base::TIM4), now)
                }
            }
            a if (base::IWDG..base::IWDG + 0x400).contains(&a) => {
                self.iwdg.read(off(base::IWDG), now)
            }
            // GPIOB_IDR: PB5 is the DC link's power-good input (the board's comparator on
            // the plant's link: high while the mains holds it); the other pins read low.
            GPIOB_IDR => u32::from(self.board.power_good()) << 5,
            a if (base::FLASH..base::FLASH + 0x400).contains(&a) => {
                self.flash.read_reg(off(base::FLASH))
            }
            a if (base::ADC1..base::ADC1 + 0x100).contains(&a) => self.adc1.r(off(base::ADC1)),
            a if (base::ADC2..base::ADC2 + 0x100).contains(&a) => self.adc2.r(off(base::ADC2)),
            a if a == base::ADC12 + 0x08 => self.adc_ccr,
            a if a == base::ADC12 + 0x0C => {
                (self.adc1.r(adc::reg::DR) & 0xFFFF) | (self.adc2.r(adc::reg::DR) & 0xFFFF) << 16
            }
            a if (base::DMA1..base::DMA1 + 0x400).contains(&a) => self.dma.read(off(base::DMA1)),
            a if (base::DMAMUX1..base::DMAMUX1 + 0x40).contains(&a) => {
                self.dma.mux[(off(base::DMAMUX1) / 4) as usize % 16]
            }
            a if (base::DAC1..base::DAC1 + 0x400).contains(&a) => match off(base::DAC1) {
                0x00 => self.dac_cr,
                0x08 => self.dac_dhr,
                0x2C => self.dac_dhr & 0xFFF,
                0x3C => self.dac_mcr,
                _ => 0,
            },
            a if a == base::RCC + 0x94 => {
                let csr = self.reg(a) & 0x00FF_FFFF;
                csr | self.csr_flags
            }
            a => self.reg(a),
        }
    }

    /// A CPU write of a peripheral register (whole word as it now stands: `value`, of which
    /// `raw` bits were written).
    fn periph_write(&mut self, addr: u32, value: u32) {
        let now = self.time;
        let clk = self.timer_clock();
        let off = |b: u32| addr - b;
        match addr {
            a if (base::TIM1..base::TIM1 + 0x400).contains(&a) => {
                let started = self.tim1.write(off(base::TIM1), value, now, clk);
                if started {
                    self.milestone(Milestone::PwmStarted);
                }
                let mms = (self.tim1.regs[1] >> 4) & 7;
                let smcr = self.tim8.regs[2];
                let sms = (smcr & 7) | ((smcr >> 16) & 1) << 3;
                let ts = ((smcr >> 4) & 7) | ((smcr >> 20) & 3) << 3;
                // TRGO = counter enable starts TIM8 in trigger mode on ITR0 (RM0440 TIMx
                // internal trigger connection: ITR0 of TIM8 is TIM1).
                if started && mms == 1 && sms == 0b0110 && ts == 0 {
                    self.tim8.trigger_start(now, clk);
                }
            }
            a if (base::TIM8..base::TIM8 + 0x400).contains(&a) => {
                self.tim8.write(off(base::TIM8), value, now, clk);
            }
            a if (base::TIM2..base::TIM2 + 0x400).contains(&a) => {
                self.tim2.write(off(base::TIM2), value, now, clk);
            }
            a if (base::TIM4..base::TIM4 + 0x400).contains(&a) => {
                self.tim4.write(off(base::TIM4), value, now, clk);
            }
            a if (base::IWDG..base::IWDG + 0x400).contains(&a) => {
                if off(base::IWDG) == 0 && value & 0xFFFF == 0xCCCC {
                    self.milestone(Milestone::WatchdogStarted);
                }
                self.iwdg.write(off(base::IWDG), value, now)
            }
            a if (base::FLASH..base::FLASH + 0x400).contains(&a) => {
                self.flash.write_reg(off(base::FLASH), value, now);
                self.note_flash_state();
            }
            a if (base::ADC1..base::ADC1 + 0x100).contains(&a) => {
                self.adc1.write(off(base::ADC1), value)
            }
            a if (base::ADC2..base::ADC2 + 0x100).contains(&a) => {
                self.adc2.write(off(base::ADC2), value)
            }
            a if a == base::ADC12 + 0x08 => self.adc_ccr = value,
            a if (base::DMA1..base::DMA1 + 0x400).contains(&a) => {
                self.dma.write(off(base::DMA1), value)
            }
            a if (base::DMAMUX1..base::DMAMUX1 + 0x40).contains(&a) => {
                self.dma.mux[(off(base::DMAMUX1) / 4) as usize % 16] = value
            }
            a if (base::DAC1..base::DAC1 + 0x400).contains(&a) => match off(base::DAC1) {
                0x00 => self.dac_cr = value,
                0x08 => self.dac_dhr = value & 0xFFF,
                0x3C => self.dac_mcr = value,
                _ => {}
            },
            a if (base::RCC..base::RCC + 0x400).contains(&a) => self.rcc_write(a, value),
            a => {
                self.regs.insert(a, value);
            }
        }
        let moe = |t: &Timer| t.regs[(timers::reg::BDTR / 4) as usize] & (1 << 15) != 0;
        if moe(&self.tim1) || moe(&self.tim8) {
            self.milestone(Milestone::OutputsOn);
        }
        self.update_irqs();
    }

    fn rcc_write(&mut self, addr: u32, value: u32) {
        let o = addr - base::RCC;
        let mut v = value;
        match o {
            // CR: the oscillators and the PLL are ready as soon as enabled.
            0x00 => {
                v &= !((1 << 10) | (1 << 17) | (1 << 25));
                v |= ((v >> 8) & 1) << 10 | ((v >> 16) & 1) << 17 | ((v >> 24) & 1) << 25;
            }
            // CFGR: SWS follows SW.
            0x08 => v = (v & !0xC) | ((v & 3) << 2),
            // BDCR, CSR, CRRCR: xxxRDY follows xxxON.
            0x90 | 0x98 => v = (v & !2) | ((v & 1) << 1),
            0x94 => {
                v = (v & !2) | ((v & 1) << 1);
                if v & (1 << 23) != 0 {
                    // RMVF clears the reset flags.
                    self.csr_flags = 0;
                    v &= !(1 << 23);
                }
            }
            0x28 | 0x2C | 0x38 | 0x40 => {
                for bit in 0..32 {
                    if v >> bit & 1 == 1 {
                        self.reset_block(o, bit);
                    }
                }
            }
            _ => {}
        }
        self.regs.insert(addr, v);
        if o == 0x08 || o == 0x0C {
            self.clocks_changed();
        }
        if o == 0x08 && v & 3 == 3 {
            self.milestone(Milestone::Pll);
        }
    }

    /// RCC_xxxRSTR bit `bit` of register `o` set: that peripheral back to reset values.
    fn reset_block(&mut self, o: u32, bit: u32) {
        let clk = self.timer_clock();
        let _ = clk;
        match (o, bit) {
            (0x28, 0) => {
                self.dma = Dma {
                    mux: self.dma.mux,
                    ..Dma::default()
                }
            }
            (0x28, 2) => self.dma.mux = [0; 16],
            (0x2C, 13) => {
                self.adc1 = Adc::new();
                self.adc2 = Adc::new();
                self.adc_ccr = 0;
            }
            (0x2C, 16) => {
                self.dac_cr = 0;
                self.dac_dhr = 0;
                self.dac_mcr = 0;
            }
            (0x38, 0) => self.tim2 = Timer::new(0xFFFF_FFFF),
            (0x38, 2) => self.tim4 = Timer::new(0xFFFF),
            (0x38, 28) => {
                let pwr = base::PWR;
                self.regs.retain(|&a, _| !(pwr..pwr + 0x400).contains(&a));
            }
            (0x40, 11) => self.tim1 = Timer::new(0xFFFF),
            (0x40, 13) => self.tim8 = Timer::new(0xFFFF),
            _ => {}
        }
    }

    /// A CPU read of the private peripheral bus.
    fn ppb_read(&mut self, addr: u32) -> u32 {
        if let Some(v) = self.debug.read(addr, debug::Master::Core) {
            return v;
        }
        match addr {
            0xE000_E100..=0xE000_E4EF => self.nvic.read_word(addr - 0xE000_E100).unwrap_or(0),
            0xE000_ED00 => 0x410F_C241,
            0xE000_ED04 => {
                let pending = self.nvic.takeable(nvic::THREAD_PRIORITY).unwrap_or(0) as u32;
                (self.ipsr as u32 & 0x1FF)
                    | (pending & 0x1FF) << 12
                    | u32::from(self.nvic.pending[nvic::PEND_SV]) << 28
                    | u32::from(self.nvic.pending[nvic::NMI]) << 31
            }
            0xE000_ED08 => self.nvic.vtor,
            0xE000_ED0C => 0xFA05_0000 | u32::from(self.nvic.prigroup) << 8,
            0xE000_ED10 => self.nvic.scr,
            0xE000_ED14 => self.nvic.ccr,
            0xE000_ED18..=0xE000_ED23 => {
                let first = (addr - 0xE000_ED18) as usize + 4;
                (0..4).fold(0, |acc, i| {
                    acc | u32::from(self.nvic.priority[first + i]) << (8 * i)
                })
            }
            0xE000_ED24 => self.nvic.shcsr,
            0xE000_ED28 => self.nvic.cfsr,
            0xE000_ED2C => self.nvic.hfsr,
            0xE000_ED38 => self.nvic.bfar,
            0xE000_1000 => self.dwt_ctrl,
            0xE000_1004 => {
                if self.dwt_ctrl & 1 != 0 {
                    ((self.time - self.dwt_base) as f64 / self.units_per_cycle) as u64 as u32
                } else {
                    0
                }
            }
            0xE004_2000 => 0x1000_6469, // DBGMCU_IDCODE: STM32G47x/48x, rev Z
            a => self.reg(a),
        }
    }

    fn ppb_write(&mut self, addr: u32, value: u32, mask: u32) {
        let word = addr & !3;
        let old = self.debug.read(word, debug::Master::Core);
        if let Some(old) = old {
            let merged = (old & !mask) | (value & mask);
            if let Some(request) = self.debug.write(word, merged, debug::Master::Core) {
                self.debug_request(request);
            }
            return;
        }
        match addr & !3 {
            a @ 0xE000_E100..=0xE000_E4EF => self.nvic.write(a - 0xE000_E100, value, mask),
            0xE000_EF00 => self.nvic.write(0xE00, value, mask),
            0xE000_ED04 => {
                if value & (1 << 28) != 0 {
                    self.nvic.pending[nvic::PEND_SV] = true;
                }
                if value & (1 << 27) != 0 {
                    self.nvic.pending[nvic::PEND_SV] = false;
                }
                if value & (1 << 26) != 0 {
                    self.nvic.pending[nvic::SYS_TICK] = true;
                }
                if value & (1 << 31) != 0 {
                    self.nvic.pending[nvic::NMI] = true;
                }
            }
            0xE000_ED08 => self.nvic.vtor = value & !0x7F,
            0xE000_ED0C => {
                if value >> 16 == 0x05FA {
                    self.nvic.prigroup = ((value >> 8) & 7) as u8;
                    if value & 4 != 0 {
                        self.reset_pending = Some(ResetKind::Software);
                    }
                }
            }
            0xE000_ED10 => self.nvic.scr = value,
            0xE000_ED14 => self.nvic.ccr = value,
            a @ 0xE000_ED18..=0xE000_ED23 => {
                let first = (a - 0xE000_ED18) as usize + 4;
                for i in 0..4 {
                    if mask >> (8 * i) & 0xFF != 0 {
                        self.nvic.set_priority(first + i, (value >> (8 * i)) as u8);
                    }
                }
            }
            0xE000_ED24 => self.nvic.shcsr = value,
            0xE000_ED28 => self.nvic.cfsr &= !value,
            0xE000_ED2C => self.nvic.hfsr &= !value,
            0xE000_1000 => {
                if value & 1 != 0 && self.dwt_ctrl & 1 == 0 {
                    self.dwt_base = self.time;
                }
                self.dwt_ctrl = value;
            }
            0xE000_1004 => {
                // CYCCNT written: count on from that value.
                self.dwt_base = self
                    .time
                    .saturating_sub((f64::from(value) * self.units_per_cycle) as u64);
            }
            a => {
                let old = self.reg(a);
                self.regs.insert(a, (old & !mask) | (value & mask));
            }
        }
    }
}

impl Soc {
    /// Carries out what a debug register write asked: the core enters or leaves Debug state.
    pub(crate) fn debug_request(&mut self, request: debug::HaltRequest) {
        match request {
            debug::HaltRequest::Halt => self.halt_core(),
            debug::HaltRequest::Resume => self.resume_core(),
            debug::HaltRequest::None => {}
        }
    }

    /// The core enters Debug state now: the timers and the watchdog whose DBGMCU freeze bit
    /// is set stop (RM0440 DBGMCU); TIM4's freeze is not modelled (the encoder count comes
    /// from the plant) and is refused as an emulation error.
    fn halt_core(&mut self) {
        if self.debug.halted {
            return;
        }
        let now = self.time;
        self.debug.entered(now);
        if self.debug.frozen_advanced(0) {
            self.tim1.freeze(now);
            // The plant steps every 50 µs while the PWM timer does not count.
            self.plant_next = now + 50 * UNITS_PER_US;
        }
        if self.debug.frozen_advanced(1) {
            self.tim8.freeze(now);
        }
        if self.debug.frozen_apb1(debug::apb1::TIM2) {
            self.tim2.freeze(now);
        }
        if self.debug.frozen_apb1(debug::apb1::TIM4) {
            self.error = Some("DBG_TIM4_STOP set: a frozen encoder counter is not modelled".into());
        }
        if self.debug.frozen_apb1(debug::apb1::IWDG) {
            self.iwdg.pause(now);
        }
    }

    /// The core leaves Debug state now: what was frozen goes on from where it stopped.
    fn resume_core(&mut self) {
        if !self.debug.halted {
            return;
        }
        let now = self.time;
        for t in [
            &mut self.tim1,
            &mut self.tim8,
            &mut self.tim2,
            &mut self.tim4,
        ] {
            t.thaw(now);
        }
        self.iwdg.resume(now);
        self.debug.left(now);
    }
}

/// GPIOB's input data register.
const GPIOB_IDR: u32 = 0x4800_0410;

/// RCC_CSR reset flags.
const RCC_CSR_BORRSTF: u32 = 1 << 27;
const RCC_CSR_PINRSTF: u32 = 1 << 26;
const RCC_CSR_SFTRSTF: u32 = 1 << 28;
const RCC_CSR_IWDGRSTF: u32 = 1 << 29;

/// Reset values of the register-file peripherals (RM0440), where not 0.
fn reset_value(addr: u32) -> u32 {
    match addr {
        0x4002_1000 => 0x0000_0500, // RCC_CR: HSION, HSIRDY
        0x4002_1008 => 0x0000_0005, // RCC_CFGR: HSI16
        0x4002_100C => 0x0000_1000, // RCC_PLLCFGR
        0x4002_1094 => 0x0000_0000, // RCC_CSR (the flags are kept apart)
        0x4000_7000 => 0x0000_0200, // PWR_CR1: range 1
        0x4000_7008 => 0x0000_8000, // PWR_CR3
        0x4000_7080 => 0x0000_0100, // PWR_CR5: R1MODE = 1
        0x4800_0000 => 0xABFF_FFFF, // GPIOA_MODER
        0x4800_0400 => 0xFFFF_FEBF, // GPIOB_MODER
        0x4800_0800 | 0x4800_0C00 | 0x4800_1000 | 0x4800_1400 | 0x4800_1800 => 0xFFFF_FFFF,
        0xE000_EF34 => 0xC000_0000, // FPCCR: ASPEN, LSPEN
        _ => 0,
    }
}

/// The chip: the core and the [`Soc`].
pub struct Chip {
    /// The unicorn engine, whose user data is the [`Soc`].
    pub uc: Unicorn<'static, Soc>,
    image: Image,
}

/// An error of the emulation itself (not of the firmware).
#[derive(Debug)]
pub struct ChipError(pub String);

impl std::fmt::Display for ChipError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ChipError {}

fn uc_err(what: &str) -> impl Fn(unicorn_engine::uc_error) -> ChipError + '_ {
    move |e| ChipError(format!("unicorn: {what}: {e:?}"))
}

impl Chip {
    /// A powered chip with `image` in its flash and `board` around it, held in reset (call
    /// [`Chip::power_on`]).
    pub fn new(image: Image, board: Board, options: ChipOptions) -> Result<Chip, ChipError> {
        Chip::with_soc(image, Soc::new(&options, board))
    }

    /// A second chip in the state this one is in now — core registers, RAM, CCM SRAM, every
    /// peripheral, the plant — which then runs on by itself: a scenario forked at an instant
    /// (the debug halts at 24 phases of one stroke cycle).
    pub fn fork(&self) -> Result<Chip, ChipError> {
        let mut chip = Chip::with_soc(self.image.clone(), self.uc.get_data().clone())?;
        for (base, size) in [RAM, CCM, SYSMEM] {
            let mut bytes = vec![0u8; size as usize];
            self.uc
                .mem_read(u64::from(base), &mut bytes)
                .map_err(uc_err("fork read"))?;
            chip.uc
                .mem_write(u64::from(base), &bytes)
                .map_err(uc_err("fork write"))?;
        }
        // Register by register: unicorn's context restore copies the whole CPU state
        // structure, pointers to the source engine's timers included (freed twice later).
        use RegisterARM as R;
        let read = |r: R| self.uc.reg_read(r).map_err(uc_err("fork reg"));
        let xpsr = read(R::XPSR)?;
        for r in [R::CONTROL, R::MSP, R::PSP] {
            chip.uc.reg_write(r, read(r)?).map_err(uc_err("fork reg"))?;
        }
        let general = [
            R::R0,
            R::R1,
            R::R2,
            R::R3,
            R::R4,
            R::R5,
            R::R6,
            R::R7,
            R::R8,
            R::R9,
            R::R10,
            R::R11,
            R::R12,
            R::SP,
            R::LR,
            R::PRIMASK,
            R::BASEPRI,
            R::FAULTMASK,
            R::FPSCR,
        ];
        let fp = [
            R::S0,
            R::S1,
            R::S2,
            R::S3,
            R::S4,
            R::S5,
            R::S6,
            R::S7,
            R::S8,
            R::S9,
            R::S10,
            R::S11,
            R::S12,
            R::S13,
            R::S14,
            R::S15,
            R::S16,
            R::S17,
            R::S18,
            R::S19,
            R::S20,
            R::S21,
            R::S22,
            R::S23,
            R::S24,
            R::S25,
            R::S26,
            R::S27,
            R::S28,
            R::S29,
            R::S30,
            R::S31,
        ];
        for r in general.into_iter().chain(fp) {
            chip.uc.reg_write(r, read(r)?).map_err(uc_err("fork reg"))?;
        }
        chip.uc
            .reg_write(R::XPSR_NZCVQG, xpsr)
            .map_err(uc_err("fork xpsr"))?;
        chip.uc
            .reg_write(R::IPSR, xpsr & 0x1FF)
            .map_err(uc_err("fork ipsr"))?;
        chip.uc
            .reg_write(R::EPSR, (xpsr & 0x0600_FC00) | (1 << 24))
            .map_err(uc_err("fork epsr"))?;
        chip.uc
            .reg_write(R::PC, read(R::PC)? | 1)
            .map_err(uc_err("fork pc"))?;
        Ok(chip)
    }

    /// A chip around `soc`, its flash holding `image`.
    fn with_soc(image: Image, soc: Soc) -> Result<Chip, ChipError> {
        let mut uc = Unicorn::new_with_data(Arch::ARM, Mode::THUMB | Mode::MCLASS, soc)
            .map_err(uc_err("new"))?;
        uc.ctl_set_cpu_model(unicorn_engine::ArmCpuModel::CORTEX_M4 as i32)
            .map_err(uc_err("cpu model"))?;
        // Program flash below the store: read and execute only (a stray write is a bus
        // fault). The store's pages are the flash model's.
        uc.mem_map(
            u64::from(FLASH_BASE),
            u64::from(STORE_BASE - FLASH_BASE),
            Prot::READ | Prot::EXEC,
        )
        .map_err(uc_err("map flash"))?;
        let erased = vec![0xFF; (STORE_BASE - FLASH_BASE) as usize];
        uc.mem_write(u64::from(FLASH_BASE), &erased)
            .map_err(uc_err("erase flash"))?;
        for (addr, bytes) in &image.segments {
            if *addr >= FLASH_BASE && *addr < FLASH_BASE + FLASH_BYTES {
                uc.mem_write(u64::from(*addr), bytes)
                    .map_err(uc_err("load"))?;
            }
        }
        uc.mmio_map(
            u64::from(STORE_BASE),
            u64::from(STORE_BYTES),
            Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize| {
                let soc = uc.get_data_mut();
                soc.store_reads += 1;
                let v = soc.flash.read_array(STORE_BASE + off as u32, size);
                if soc.flash.nmi {
                    soc.update_irqs();
                    let _ = uc.emu_stop();
                }
                u64::from(v)
            }),
            Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize, value: u64| {
                let soc = uc.get_data_mut();
                let now = soc.time;
                soc.flash
                    .write_array(STORE_BASE + off as u32, value as u32, size, now);
                if soc.flash.power_cut {
                    soc.powered = false;
                    soc.plant_next = soc.time + 50 * UNITS_PER_US;
                    let _ = uc.emu_stop();
                }
            }),
        )
        .map_err(uc_err("map store"))?;
        for (b, size) in [RAM, CCM, SYSMEM] {
            uc.mem_map(u64::from(b), u64::from(size), Prot::ALL)
                .map_err(uc_err("map ram"))?;
        }
        // The flash size register (RM0440 §47.2): 512 KiB.
        uc.mem_write(0x1FFF_75E0, &512u16.to_le_bytes())
            .map_err(uc_err("flash size"))?;
        uc.mmio_map(
            u64::from(PERIPH.0),
            u64::from(PERIPH.1),
            Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize| {
                let addr = PERIPH.0 + off as u32;
                let word = uc.get_data_mut().periph_read(addr & !3);
                u64::from(extract(word, addr, size))
            }),
            Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize, value: u64| {
                let addr = PERIPH.0 + off as u32;
                let soc = uc.get_data_mut();
                let word = addr & !3;
                let merged = if size == 4 {
                    value as u32
                } else {
                    let old = soc.periph_read(word);
                    merge(old, addr, size, value as u32)
                };
                // Flag registers written with a byte/half-word access still clear only what
                // they write: the models take the whole word.
                soc.periph_write(word, merged);
                cpu::after_write(uc);
            }),
        )
        .map_err(uc_err("map peripherals"))?;
        uc.mmio_map(
            u64::from(PPB.0),
            u64::from(PPB.1),
            Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize| {
                let addr = PPB.0 + off as u32;
                let word = uc.get_data_mut().ppb_read(addr & !3);
                u64::from(extract(word, addr, size))
            }),
            Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize, value: u64| {
                let addr = PPB.0 + off as u32;
                let shift = (addr & 3) * 8;
                let mask = if size >= 4 {
                    !0
                } else {
                    ((1u32 << (8 * size)) - 1) << shift
                };
                let v = (value as u32) << shift;
                uc.get_data_mut().ppb_write(addr, v, mask);
                cpu::after_write(uc);
            }),
        )
        .map_err(uc_err("map ppb"))?;
        // A `b .` in erased flash below the store, where a hung task is sent.
        let spin = STORE_BASE - 0x10;
        uc.mem_write(u64::from(spin), &[0xFE, 0xE7])
            .map_err(uc_err("spin"))?;
        uc.get_data_mut().spin_address = spin;
        uc.get_data_mut().main_address = image.symbol("main").unwrap_or(0) & !1;
        // The function itself (legacy mangling, any hash), not a long-branch thunk to it.
        uc.get_data_mut().control_cycle_address = image
            .symbols
            .iter()
            .find(|(n, _)| n.starts_with("_ZN3fpc5tasks13control_cycle17h"))
            .map_or(0, |(_, a)| *a & !1);
        {
            uc.add_mem_hook(
                unicorn_engine::HookType::MEM_READ,
                u64::from(FLASH_BASE),
                u64::from(STORE_BASE - 1),
                |uc, _kind, addr, size, _value| {
                    uc.get_data_mut().flash_read(addr as u32, size as u32);
                    true
                },
            )
            .map_err(uc_err("flash read hook"))?;
        }
        cpu::install_hooks(&mut uc)?;
        Ok(Chip { uc, image })
    }

    /// The firmware image.
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// The peripherals' state.
    pub fn soc(&mut self) -> &mut Soc {
        self.uc.get_data_mut()
    }

    /// The peripherals' state (read only).
    pub fn soc_ref(&self) -> &Soc {
        self.uc.get_data()
    }

    /// Emulated time, s.
    pub fn time_s(&self) -> f64 {
        crate::time::seconds(self.uc.get_data().time)
    }

    /// Brings the core out of reset as the hardware does: MSP and PC from the vector table
    /// at 0x0800_0000 (BOOT0 low: flash aliased at 0), registers cleared.
    pub fn boot(&mut self) -> Result<(), ChipError> {
        let mut v = [0u8; 8];
        self.uc
            .mem_read(u64::from(FLASH_BASE), &mut v)
            .map_err(uc_err("vectors"))?;
        let sp = u32::from_le_bytes([v[0], v[1], v[2], v[3]]);
        let pc = u32::from_le_bytes([v[4], v[5], v[6], v[7]]);
        for r in [
            RegisterARM::R0,
            RegisterARM::R1,
            RegisterARM::R2,
            RegisterARM::R3,
            RegisterARM::R4,
            RegisterARM::R5,
            RegisterARM::R6,
            RegisterARM::R7,
            RegisterARM::R8,
            RegisterARM::R9,
            RegisterARM::R10,
            RegisterARM::R11,
            RegisterARM::R12,
        ] {
            self.uc.reg_write(r, 0).map_err(uc_err("reg"))?;
        }
        self.uc
            .reg_write(RegisterARM::PRIMASK, 0)
            .map_err(uc_err("primask"))?;
        self.uc
            .reg_write(RegisterARM::BASEPRI, 0)
            .map_err(uc_err("basepri"))?;
        self.uc
            .reg_write(RegisterARM::CONTROL, 0)
            .map_err(uc_err("control"))?;
        self.uc
            .reg_write(RegisterARM::IPSR, 0)
            .map_err(uc_err("ipsr"))?;
        self.uc
            .reg_write(RegisterARM::MSP, u64::from(sp))
            .map_err(uc_err("msp"))?;
        self.uc
            .reg_write(RegisterARM::SP, u64::from(sp))
            .map_err(uc_err("sp"))?;
        self.uc
            .reg_write(RegisterARM::LR, 0xFFFF_FFFF)
            .map_err(uc_err("lr"))?;
        self.uc
            .reg_write(RegisterARM::PC, u64::from(pc | 1))
            .map_err(uc_err("pc"))?;
        let soc = self.uc.get_data_mut();
        soc.ipsr = 0;
        soc.sleeping = false;
        soc.event = false;
        Ok(())
    }

    /// A system reset of `kind`: the peripherals to their reset values (RAM and flash kept),
    /// the reset flags set, and the core started from the reset vector.
    pub fn reset(&mut self, kind: ResetKind) -> Result<(), ChipError> {
        let soc = self.uc.get_data_mut();
        let at_s = crate::time::seconds(soc.time);
        soc.reset_peripherals();
        soc.csr_flags |= RCC_CSR_PINRSTF
            | match kind {
                ResetKind::PowerOn => RCC_CSR_BORRSTF,
                ResetKind::Watchdog => RCC_CSR_IWDGRSTF,
                ResetKind::Software => RCC_CSR_SFTRSTF,
            };
        soc.resets.push(ResetRecord { at_s, kind });
        soc.milestones.push((at_s, Milestone::Reset));
        soc.board.outputs_off();
        // The debug domain survives a system reset: leaving Debug state, the core halts at
        // the reset vector if a debugger armed the vector catch (and never disarmed it).
        if kind == ResetKind::PowerOn {
            soc.debug.power_on();
        }
        soc.debug.halted = false;
        soc.debug.halted_since = None;
        let caught = soc.debug.catches_reset();
        self.boot()?;
        if caught {
            let soc = self.uc.get_data_mut();
            soc.debug.dfsr |= 1 << 3;
            soc.halt_core();
        }
        Ok(())
    }

    /// A debugger's read of the word at `addr` through the debug port's memory access port,
    /// while the core runs: memory as the bus gives it (RAM, flash, peripherals), the debug
    /// registers counted (`Soc::debug`).
    pub fn dap_read(&mut self, addr: u32) -> Result<u32, ChipError> {
        let a = addr & !3;
        let soc = self.uc.get_data_mut();
        if (PPB.0..PPB.0 + PPB.1).contains(&a) {
            if let Some(v) = soc.debug.read(a, debug::Master::Dap) {
                return Ok(v);
            }
            return Ok(soc.ppb_read(a));
        }
        if (PERIPH.0..PERIPH.0 + PERIPH.1).contains(&a) {
            return Ok(soc.periph_read(a));
        }
        let mut w = [0u8; 4];
        self.read_mem(a, &mut w)?;
        Ok(u32::from_le_bytes(w))
    }

    /// A debugger's write of the word `value` at `addr` through the debug port's memory
    /// access port: a write of DHCSR may halt or resume the core.
    pub fn dap_write(&mut self, addr: u32, value: u32) -> Result<(), ChipError> {
        let a = addr & !3;
        let soc = self.uc.get_data_mut();
        if (PPB.0..PPB.0 + PPB.1).contains(&a) {
            match soc.debug.write(a, value, debug::Master::Dap) {
                Some(request) => soc.debug_request(request),
                None => soc.ppb_write(a, value, !0),
            }
            return Ok(());
        }
        if (PERIPH.0..PERIPH.0 + PERIPH.1).contains(&a) {
            soc.periph_write(a, value);
            return Ok(());
        }
        self.write_mem(a, &value.to_le_bytes())
    }

    /// Cuts the supply: the core stops, the outputs go low, the plant runs on; the
    /// flash keeps what the cut left. [`Chip::power_on`] brings it back.
    pub fn power_off(&mut self) {
        let soc = self.uc.get_data_mut();
        soc.powered = false;
        soc.plant_next = soc.time + 50 * UNITS_PER_US;
        soc.board.outputs_off();
    }

    /// Power returns: RAM is lost (filled with a pattern, as SRAM powers up undefined), a
    /// power-on reset.
    pub fn power_on(&mut self) -> Result<(), ChipError> {
        let junk: Vec<u8> = (0..RAM.1)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect();
        self.uc
            .mem_write(u64::from(RAM.0), &junk)
            .map_err(uc_err("ram"))?;
        // CCM SRAM too; as UDF instructions, so that code run from it before the firmware
        // copies its image there faults at once.
        self.uc
            .mem_write(u64::from(CCM.0), &vec![0xDE; CCM.1 as usize])
            .map_err(uc_err("ccm"))?;
        let soc = self.uc.get_data_mut();
        soc.powered = true;
        soc.csr_flags = 0;
        self.reset(ResetKind::PowerOn)
    }

    /// Runs the chip until the plant has advanced one PWM period (or one 50 µs step while
    /// the PWM is stopped).
    pub fn run_period(&mut self) -> Result<(), ChipError> {
        cpu::run_until_plant_step(self)
    }

    /// Reads target memory (as a debug probe does, without stopping anything).
    pub fn read_mem(&self, addr: u32, buf: &mut [u8]) -> Result<(), ChipError> {
        if (STORE_BASE..STORE_BASE + STORE_BYTES).contains(&addr) {
            let soc = self.uc.get_data();
            let off = (addr - STORE_BASE) as usize;
            for (i, b) in buf.iter_mut().enumerate() {
                *b = soc.flash.store.get(off + i).copied().unwrap_or(0xFF);
            }
            return Ok(());
        }
        self.uc
            .mem_read(u64::from(addr), buf)
            .map_err(uc_err("read"))
    }

    /// Writes target memory (as a debug probe does).
    pub fn write_mem(&mut self, addr: u32, bytes: &[u8]) -> Result<(), ChipError> {
        self.uc
            .mem_write(u64::from(addr), bytes)
            .map_err(uc_err("write"))
    }

    /// The program counter.
    pub fn pc(&self) -> u32 {
        self.uc.reg_read(RegisterARM::PC).unwrap_or(0) as u32
    }
}

/// The bytes of `size` at `addr` out of the word holding it.
fn extract(word: u32, addr: u32, size: usize) -> u32 {
    let shift = (addr & 3) * 8;
    if size >= 4 {
        word
    } else {
        (word >> shift) & ((1u32 << (8 * size)) - 1)
    }
}

/// `old` with the `size` bytes at `addr` replaced by `value`.
fn merge(old: u32, addr: u32, size: usize, value: u32) -> u32 {
    let shift = (addr & 3) * 8;
    let mask = ((1u32 << (8 * size)) - 1) << shift;
    (old & !mask) | ((value << shift) & mask)
}

/// The chip's memory as a debug probe sees it (reads and writes while the core runs), for
/// `hal-sim`'s RTT reader.
impl hal_sim::link::memory::TargetMemory for Chip {
    fn read(&mut self, address: u64, buf: &mut [u8]) -> std::io::Result<()> {
        let a = u32::try_from(address).map_err(std::io::Error::other)?;
        self.read_mem(a, buf)
            .map_err(|e| std::io::Error::other(e.0))
    }

    fn write(&mut self, address: u64, bytes: &[u8]) -> std::io::Result<()> {
        let a = u32::try_from(address).map_err(std::io::Error::other)?;
        self.write_mem(a, bytes)
            .map_err(|e| std::io::Error::other(e.0))
    }
}
