//! The independent watchdog (IWDG, LSI-clocked), fed only by the supervision task.

use embassy_stm32::peripherals::IWDG;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::Peri;
use fpc::ports::Watchdog;

/// Watchdog timeout, µs: 20 supervision periods of 1 ms. The LSI (32 kHz nominal,
/// 29.5–34 kHz over temperature) makes the real timeout 18.8–21.7 ms.
pub const WATCHDOG_TIMEOUT_US: u32 = 20_000;

/// The running IWDG. Once started it cannot be stopped (hardware), only fed.
pub struct BoardWatchdog(IndependentWatchdog<'static, IWDG>);

impl BoardWatchdog {
    /// Configures the IWDG for [`WATCHDOG_TIMEOUT_US`] and starts it.
    pub fn start(iwdg: Peri<'static, IWDG>) -> Self {
        let mut wdg = IndependentWatchdog::new(iwdg, WATCHDOG_TIMEOUT_US);
        wdg.unleash();
        BoardWatchdog(wdg)
    }
}

impl Watchdog for BoardWatchdog {
    fn feed(&mut self) {
        self.0.pet();
    }
}
