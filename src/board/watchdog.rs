//! The independent watchdog (IWDG, LSI-clocked), fed only by the supervision task.
//!
//! Two windows: [`BOOT_WATCHDOG_TIMEOUT_US`] from the start to the first feed (board bring-up
//! and building the control step come first, with the outputs off), then
//! [`WATCHDOG_TIMEOUT_US`] for good: the first feed shortens the reload value.
//!
//! The start is embassy's `new()` + `unleash()` (0x5555, PR, RLR, 0xCCCC), then a reload once
//! PR and RLR have reached the watchdog's clock domain (IWDG_SR = 0): RM0440 §37.3.2 starts
//! the down-counter from 0xFFF, not from RLR, so without that reload the first window would
//! be 4096 ticks (≈ 512 ms at /4) instead of 20 ms. That update takes up to 6 LSI cycles
//! (≈ 190 µs): [`BoardWatchdog::start`] comes early in the board's bring-up and
//! [`BoardWatchdog::settle`] waits and reloads at its end, so the wait overlaps the
//! bring-up instead of adding to the boot (which, after a watchdog reset, a coasting piston
//! waits through).

use embassy_stm32::pac;
use embassy_stm32::pac::iwdg::vals::Key;
use embassy_stm32::peripherals::IWDG;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::Peri;
use fpc::ports::Watchdog;
pub use fpc::tasks::{BOOT_WATCHDOG_TIMEOUT_US, WATCHDOG_TIMEOUT_US};

/// IWDG tick with the /4 prescaler embassy chooses for the boot window (the smallest that
/// reaches it; /4 covers up to 512 ms), µs at the nominal 32 kHz LSI.
const TICK_US: u32 = 125;
const _: () = assert!(
    BOOT_WATCHDOG_TIMEOUT_US <= 512_000,
    "the /4 prescaler must hold"
);
const _: () =
    assert!(WATCHDOG_TIMEOUT_US.is_multiple_of(TICK_US) && WATCHDOG_TIMEOUT_US >= 2 * TICK_US);

/// Reload value of the running window (LSI 29.5–34 kHz over temperature: 1.9–2.2 ms).
const RELOAD: u16 = (WATCHDOG_TIMEOUT_US / TICK_US - 1) as u16;

/// The running IWDG. Once started it cannot be stopped (hardware), only fed.
pub struct BoardWatchdog {
    wdg: IndependentWatchdog<'static, IWDG>,
    /// The running window is in force (after the first feed).
    running_window: bool,
}

impl BoardWatchdog {
    /// Configures the IWDG for the boot window and starts it. Its counter starts from 0xFFF
    /// (≤ 512 ms) until [`BoardWatchdog::settle`] reloads it with the boot window.
    pub fn start(iwdg: Peri<'static, IWDG>) -> Self {
        let mut wdg = IndependentWatchdog::new(iwdg, BOOT_WATCHDOG_TIMEOUT_US);
        wdg.unleash();
        if super::mutation::is("rlr-before-rvu") {
            // The running window written at once, while the boot window's RLR is still on its
            // way (RVU = 1).
            pac::IWDG.kr().write(|w| w.set_key(Key::ENABLE));
            pac::IWDG.rlr().write(|w| w.set_rl(RELOAD));
        }
        BoardWatchdog {
            wdg,
            running_window: false,
        }
    }

    /// Waits until PR and RLR have reached the watchdog's clock domain (PVU and RVU clear
    /// within 6 LSI cycles, ≈ 190 µs after [`BoardWatchdog::start`]), then reloads the
    /// counter with RLR: the boot window runs from here. Call once, at the end of the
    /// bring-up.
    pub fn settle(&mut self) {
        while pac::IWDG.sr().read().0 != 0 {}
        self.wdg.pet();
    }
}

impl Watchdog for BoardWatchdog {
    fn feed(&mut self) {
        if !super::test_build::feed_allowed() {
            return;
        }
        if !self.running_window {
            // Unlock and write the shorter reload; the IWDG takes it over within a few LSI
            // cycles (RVU), so at the latest the next feed reloads the counter with it.
            if super::mutation::is("iwdg-key-order-swapped") {
                pac::IWDG.rlr().write(|w| w.set_rl(RELOAD));
                pac::IWDG.kr().write(|w| w.set_key(Key::ENABLE));
            } else if !super::mutation::is("rlr-before-rvu") {
                pac::IWDG.kr().write(|w| w.set_key(Key::ENABLE));
                pac::IWDG.rlr().write(|w| w.set_rl(RELOAD));
            }
            self.running_window = true;
        }
        self.wdg.pet();
    }
}

/// The IWDG's reload key (IWDG_KR = 0xAAAA): no effect while the watchdog is stopped.
pub(super) fn reload_watchdog() {
    pac::IWDG.kr().write_value(pac::iwdg::regs::Kr(0xAAAA));
}
