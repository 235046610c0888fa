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
//!
//! # Boost mode, by hand
//! Above 150 MHz the core regulator must be in range-1 boost mode: PWR_CR5.R1MODE = 0
//! (RM0440, PWR_CR5: R1MODE is bit 8, reset value 0x0000_0100). stm32-metapac 21.0.0 puts
//! R1MODE at bit 0, so embassy's `config.rcc.boost` clears a reserved bit and leaves the
//! regulator in normal mode (see `docs/upstream-pwr-cr5-r1mode.md`). And `embassy_stm32::init`
//! resets the PWR block (RCC_APB1RSTR1.PWRRST) before it sets the clocks, which would undo
//! a write made before it. So the boot goes in three steps ([`start`]):
//! 1. `embassy_stm32::init` with [`boot_config`]: HSI16, range 1 normal mode (legal up to
//!    150 MHz);
//! 2. clear bit 8 of PWR_CR5 ourselves and read it back;
//! 3. `embassy_stm32::rcc::reinit` with the 170 MHz [`rcc_config`] (it also restarts the
//!    time driver on the new timer clock); bit 8 is read back again afterwards.
//!
//! The switch itself is embassy's: it sets the AHB prescaler to /2 while still on HSI16,
//! clears "R1MODE" (its wrong bit; harmless, the register holds 0 there), sets four flash
//! wait states, waits, then selects the PLL and AHB /1 in one RCC_CFGR write. RM0440's
//! sequence would switch with AHB /2 and only go to /1 after 1 µs; embassy's single write
//! goes from 8 MHz to 170 MHz in one step. This is left as embassy does it (reported in the
//! same note); the workaround can go once the PAC places R1MODE right.

use embassy_stm32::pac;
use embassy_stm32::peripherals::RCC;
use embassy_stm32::rcc::{mux, Pll, PllMul, PllPreDiv, PllRDiv, PllSource, Sysclk};
use embassy_stm32::{Config, Peri};

/// System, AHB, APB1/APB2 and timer clock, Hz.
pub const SYSCLK_HZ: u32 = 170_000_000;

/// PWR_CR5.R1MODE per RM0440 (bit 8; 1 = range-1 normal, 0 = range-1 boost).
pub const PWR_CR5_R1MODE: u32 = 1 << 8;

/// The HAL configuration embassy boots with: its defaults, HSI16 as SYSCLK, no boost.
pub fn boot_config() -> Config {
    Config::default()
}

/// The 170 MHz clock tree above, applied by [`start`] once boost mode is on.
pub fn rcc_config() -> embassy_stm32::rcc::Config {
    let mut rcc = embassy_stm32::rcc::Config::default();
    rcc.pll = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL85,
        divp: None,
        divq: None,
        divr: Some(PllRDiv::DIV2),
    });
    rcc.sys = Sysclk::PLL1_R;
    // Embassy's half of the boost sequence (AHB /2, flash wait states for boost); the bit
    // it clears is the wrong one, [`enter_boost_mode`] clears the right one.
    rcc.boost = true;
    rcc.mux.adc12sel = mux::Adcsel::SYS;
    rcc
}

/// Range-1 boost mode: PWR clock on, PWR_CR5 bit 8 cleared. Returns whether it reads back
/// cleared. Call at HSI16 (range 1 normal mode is legal there), before [`rcc_config`].
pub fn enter_boost_mode() -> bool {
    pac::RCC.apb1enr1().modify(|w| w.set_pwren(true));
    // Read back so the clock is on before the PWR write (RM0440, peripheral clock enable
    // delay: two AHB/APB clocks).
    let _ = pac::RCC.apb1enr1().read();
    // Raw bit: the PAC's `set_r1mode` writes bit 0 (the upstream bug).
    pac::PWR.cr5().modify(|w| w.0 &= !PWR_CR5_R1MODE);
    boost_mode_on()
}

/// PWR_CR5 bit 8 reads 0: range-1 boost mode is selected.
pub fn boost_mode_on() -> bool {
    pac::PWR.cr5().read().0 & PWR_CR5_R1MODE == 0
}

/// PWR_CR5 bit 8 did not read back 0 (before or after the switch to the PLL): the core is
/// not in boost mode and must not run at 170 MHz.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoostModeOff;

/// Brings the clocks up as described in the module header. A failed read-back of the boost
/// bit is returned, not handled: the caller ends the boot (`board::init` →
/// `fault::boot_fault`; this module stays below the fault path, which times its reset
/// delay by [`SYSCLK_HZ`]).
pub fn start() -> Result<embassy_stm32::Peripherals, BoostModeOff> {
    let mut p = embassy_stm32::init(boot_config());
    if !enter_boost_mode() {
        return Err(BoostModeOff);
    }
    switch_to_pll(&mut p.RCC);
    if !boost_mode_on() {
        return Err(BoostModeOff);
    }
    Ok(p)
}

fn switch_to_pll(rcc: &mut Peri<'static, RCC>) {
    // Also restarts embassy-time's TIM2 at the new clock; nothing waits on time yet.
    embassy_stm32::rcc::reinit(rcc_config(), rcc);
}
