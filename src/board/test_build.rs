//! Hooks of the bring-up test builds (`cargo fw-test FEATURE`, features in `Cargo.toml`,
//! steps in `docs/bring-up.md`). Each makes one fault the board's own fault handling must
//! then show on the bench, where a debugger cannot (a breakpoint halts the core and freezes
//! the watchdog; the fat-LTO release ELF has no `feed` or `control_run` to break on). Without
//! its feature every hook is an empty inline function: the release ELF has none of this.

/// Seconds after the boot at which the timed test faults strike: long enough to home and
/// start the strokes by hand.
pub const FAULT_AFTER_S: u64 = 5;

/// Whether a timed test fault is due: `FAULT_AFTER_S` of uptime have passed.
#[allow(dead_code)]
fn due() -> bool {
    embassy_time::Instant::now().as_secs() >= FAULT_AFTER_S
}

/// `test-starve-watchdog`: the supervision task's feeds stop (the watchdog then resets the
/// board within its running window).
#[inline(always)]
pub fn feed_allowed() -> bool {
    #[cfg(feature = "test-starve-watchdog")]
    if due() {
        return false;
    }
    true
}

/// `test-hang-control`: the control task spins for ever in its interrupt (the thread-mode
/// tasks starve with it, the end-of-burst interrupt above it goes on).
#[inline(always)]
pub fn control_cycle() {
    #[cfg(feature = "test-hang-control")]
    if due() {
        loop {
            cortex_m::asm::nop();
        }
    }
}

/// `test-panic-at-boot`: a panic during the board's bring-up, before the watchdog starts.
#[inline(always)]
pub fn board_init() {
    #[cfg(feature = "test-panic-at-boot")]
    panic!("test build: panic during board bring-up");
}

/// `test-panic-on-stop`: the command channel's bytes, watched for a `Stop` command.
#[derive(Default)]
pub struct StopWatch {
    #[cfg(feature = "test-panic-on-stop")]
    reader: fpc::link::commands::RequestReader,
}

impl StopWatch {
    /// Looks at `bytes` as the command task receives them; panics on a `Stop`.
    #[inline(always)]
    pub fn received(&mut self, bytes: &[u8]) {
        #[cfg(feature = "test-panic-on-stop")]
        for &b in bytes {
            use fpc::control::command::Command;
            use fpc::link::commands::Request;
            if let Some(Ok(Request::Command(Command::Stop))) = self.reader.push(b) {
                panic!("test build: panic on the Stop command");
            }
        }
        let _ = bytes;
    }
}

/// `test-timing`: the control step's time, core clocks from the end-of-burst interrupt's
/// entry to the last duty write (DWT CYCCNT): the last and the largest since the boot. Read
/// them with `probe-rs read b32 ADDR 2` (ADDR from the bring-up ELF: `nm … | grep
/// STEP_CYCLES`).
#[cfg(feature = "test-timing")]
#[no_mangle]
pub static STEP_CYCLES: [core::sync::atomic::AtomicU32; 2] =
    [const { core::sync::atomic::AtomicU32::new(0) }; 2];

#[cfg(feature = "test-timing")]
static STEP_START: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// `test-timing`: PA5 (the Nucleo LED, otherwise free) as a push-pull output, low, and the
/// cycle counter on. Call once in `board::init`.
#[inline(always)]
pub fn timing_init() {
    #[cfg(feature = "test-timing")]
    {
        use embassy_stm32::pac;
        pac::RCC.ahb2enr().modify(|w| w.set_gpioaen(true));
        let _ = pac::RCC.ahb2enr().read();
        pac::GPIOA.bsrr().write(|w| w.set_br(5, true));
        pac::GPIOA
            .moder()
            .modify(|w| w.set_moder(5, pac::gpio::vals::Moder::OUTPUT));
        // SAFETY: the cycle counter is enabled once at boot; nothing else uses DWT/DCB.
        let mut core = unsafe { cortex_m::Peripherals::steal() };
        core.DCB.enable_trace();
        core.DWT.enable_cycle_counter();
    }
}

/// `test-timing`: the end-of-burst interrupt begins (PA5 high, the count starts).
///
/// TRCENA and CYCCNTENA are set again first, before each count: a debugger's detach may
/// write DEMCR = 0 (probe-rs's generic ARMv7-M sequence does; its STM32 one does not), and
/// the counter then stands still (ARMv7-M ARM §C1.6.5), every step reading 0 cycles.
#[inline(always)]
pub fn burst_begins() {
    #[cfg(feature = "test-timing")]
    {
        use core::sync::atomic::Ordering;
        // SAFETY: only this build's timing uses DCB/DWT, from this interrupt; both writes
        // are read-modify-writes that set one enable bit each.
        let mut core = unsafe { cortex_m::Peripherals::steal() };
        core.DCB.enable_trace();
        core.DWT.enable_cycle_counter();
        STEP_START.store(cortex_m::peripheral::DWT::cycle_count(), Ordering::Relaxed);
        embassy_stm32::pac::GPIOA
            .bsrr()
            .write(|w| w.set_bs(5, true));
    }
}

/// `test-timing`: the control step wrote its last duty (PA5 low, the count recorded).
#[inline(always)]
pub fn step_done() {
    #[cfg(feature = "test-timing")]
    {
        use core::sync::atomic::Ordering;
        let cycles = cortex_m::peripheral::DWT::cycle_count()
            .wrapping_sub(STEP_START.load(Ordering::Relaxed));
        embassy_stm32::pac::GPIOA
            .bsrr()
            .write(|w| w.set_br(5, true));
        STEP_CYCLES[0].store(cycles, Ordering::Relaxed);
        STEP_CYCLES[1].fetch_max(cycles, Ordering::Relaxed);
    }
}
