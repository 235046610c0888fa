//! Time and cycles: each executed block advances the emulated time (by its counted cycles,
//! the flash's wait states as its caches leave them ([`super::art`]), or by its instructions
//! at a fixed CPI), and the PWM period's load adds up the instructions, cycles and flash wait
//! states (no cache: the bound) of its interrupt path (`pil/README.md`, "Cycles").

use super::*;

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

/// FLASH_ACR.ICEN: the instruction cache enabled (RM0440, "Flash access control register").
const ACR_ICEN: u32 = 1 << 9;
/// FLASH_ACR.DCEN: the data cache enabled.
const ACR_DCEN: u32 = 1 << 10;

/// The end of APB1 and APB2 (RM0440's memory map, "peripheral register boundary addresses"):
/// AHB1 starts here, AHB2 at 0x4800_0000.
const APB_END: u32 = 0x4002_0000;

/// Wait cycles of a CPU access to an APB peripheral (TIM1, TIM8, TIM2, TIM4, IWDG, PWR): the
/// access crosses the bus matrix to an AHB/APB bridge (RM0440 §2.1, Figure 1), and an APB
/// transfer takes a setup and an access phase (AMBA APB protocol: at least 2 PCLK cycles,
/// PCLK = HCLK here), one more than an AHB data phase, plus the bridge's own stage. An upper
/// end: the store buffer hides a write's wait from the core, which this does not model.
pub const PERIPHERAL_WAIT_APB: u64 = 2;

/// Wait cycles of a CPU access to an AHB peripheral (DMA, RCC, flash interface, ADC, DAC):
/// the bus matrix's arbitration, no bridge.
pub const PERIPHERAL_WAIT_AHB: u64 = 1;

impl Soc {
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
    pub(super) fn flash_read(&mut self, addr: u32, size: u32) {
        let ws = self.flash_latency();
        if self.path_open {
            self.period.path_wait_cycles += ws;
        }
        let cached = self.flash.acr & ACR_DCEN != 0 && self.dcache.access(addr & !7);
        self.account_apart(ws, if cached { 0 } else { ws }, false);
        if self.flash_timing && self.path_open {
            self.period.path_flash_reads += 1;
            self.path_data_lines.insert(addr & !7);
            self.path_data_lines
                .insert(addr.wrapping_add(size.max(1) - 1) & !7);
        }
    }

    /// Advances time by the block of code at `addr` (`size` bytes) that is about to run.
    pub(super) fn execute(&mut self, addr: u32, size: u32, b: &timing::Block) {
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
        // Wait states: each move of the fetch into another 64-bit line of program flash (the
        // periods' figures: no cache), and of those the instruction cache's misses (the time).
        let mut wait = 0;
        let mut timed_wait = 0;
        let in_flash = (FLASH_BASE..STORE_BASE).contains(&addr);
        let icen = self.flash.acr & ACR_ICEN != 0;
        if in_flash && size > 0 {
            let mut line = addr & !7;
            while line < addr + size {
                if line != self.fetch_line {
                    let ws = self.flash_latency();
                    wait += ws;
                    if !(icen && self.icache.access(line)) {
                        timed_wait += ws;
                    }
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
            None => (cycles - wait + timed_wait) as f64,
        };
        self.advance(cycles_f);
    }

    /// A CPU access (read or write) of the peripheral register at `addr`: the wait cycles of
    /// the bus matrix and bridges on top of the load or store's own 2 cycles
    /// ([`PERIPHERAL_WAIT_APB`], [`PERIPHERAL_WAIT_AHB`]).
    pub(super) fn peripheral_access(&mut self, addr: u32) {
        let wait = if addr < APB_END {
            PERIPHERAL_WAIT_APB
        } else {
            PERIPHERAL_WAIT_AHB
        };
        self.account(wait, false);
    }

    /// FLASH_ACR.LATENCY: the wait states of a flash access now.
    pub(super) fn flash_latency(&self) -> u64 {
        u64::from(self.flash.acr & 0xF)
    }

    /// Advances time by `cycles` clock cycles.
    pub(super) fn advance(&mut self, cycles: f64) {
        self.frac += cycles * self.units_per_cycle;
        let whole = self.frac.floor();
        self.frac -= whole;
        self.time += whole as u64;
    }

    /// Cycles spent outside the instructions (exception entry and return, wait states of a
    /// data read): counted in the interrupt path if `path` (or if one is open), and in time
    /// unless time runs at a fixed CPI.
    pub(super) fn account(&mut self, cycles: u64, path: bool) {
        self.account_apart(cycles, cycles, path);
    }

    /// [`Soc::account`] with a cost that differs between the interrupt path's figure (the
    /// no-cache bound) and the time (the caches as FLASH_ACR enables them).
    fn account_apart(&mut self, figure: u64, time: u64, path: bool) {
        if path || self.path_open {
            self.period.path_cycles += figure;
        }
        if self.cpi.is_none() {
            self.advance(time as f64);
        }
    }

    /// The flash interface's caches emptied (a reset).
    pub(super) fn caches_cleared(&mut self) {
        self.icache.clear();
        self.dcache.clear();
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
}
