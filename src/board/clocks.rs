//! Clock tree: 170 MHz SYSCLK from HSI16 through the PLL, range-1 boost mode.
//!
//! HSI16 / M 4 = 4 MHz PLL input, × N 85 = 340 MHz VCO, / R 2 = 170 MHz SYSCLK. AHB, APB1 and
//! APB2 undivided, so every timer kernel clock is 170 MHz too (the PWM and dead-time
//! arithmetic in `pwm.rs` relies on it). The HSI is factory-trimmed to ±1 %; the board's
//! 24 MHz HSE (Nucleo X3, PF0/PF1, left free) would only matter for absolute time, which the
//! control loop never uses: every rate is derived from this one clock.
//!
//! ADC1/2 kernel clock = SYSCLK; embassy's ADC driver picks the /4 prescaler (42.5 MHz, under
//! the 60 MHz limit).

use embassy_stm32::rcc::{mux, Pll, PllMul, PllPreDiv, PllRDiv, PllSource, Sysclk};
use embassy_stm32::Config;

/// System, AHB, APB1/APB2 and timer clock, Hz.
pub const SYSCLK_HZ: u32 = 170_000_000;

/// The HAL configuration for the clock tree above.
pub fn config() -> Config {
    let mut config = Config::default();
    config.rcc.pll = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL85,
        divp: None,
        divq: None,
        divr: Some(PllRDiv::DIV2),
    });
    config.rcc.sys = Sysclk::PLL1_R;
    // Above 150 MHz the core regulator must be in range-1 boost mode (RM0440 §6.1.5).
    config.rcc.boost = true;
    config.rcc.mux.adc12sel = mux::Adcsel::SYS;
    config
}
