//! The drive board's power-good input (PB5): an undervoltage comparator on the power stage
//! holds it high while the DC link is above its threshold (`[supply] power_good_voltage_v`
//! of the machine model, 500 V on the reference board). The pin's pull-down makes a broken
//! wire or an unpowered comparator read as a supply loss, the safe side.
//!
//! A comparator rather than an ADC reading of the link: the burst's regular sequence and
//! its DMA stay as they are (no rank added to the 20 kHz burst), there are no free ADC3–5
//! pins on the LQFP64, and one GPIO read in the 1 kHz supervision task is all the detection
//! needs (`docs/firmware.md`, "A supply loss in motion").
//!
//! The MCU's own supply (VDD, 3.3 V from the board's flyback off the link) is watched by the
//! chip: the brown-out reset at level 2 or more (option bytes, checked at boot:
//! `BootCheck::BrownOutLevel`) and the PVD at 2.9 V ([`start_pvd`]), whose output
//! SYSCFG_CFGR2.PVDL connects to the bridges' break inputs (`trip.rs`): as VDD sags the
//! bridges go off in hardware before the core runs out of specification, instead of being
//! left to a core running below its rated supply until the brown-out reset.

use embassy_stm32::gpio::{Input, Pull};
use embassy_stm32::pac;
use embassy_stm32::peripherals::PB5;
use embassy_stm32::Peri;

/// The power-good input.
pub struct PowerGood {
    pin: Input<'static>,
}

impl PowerGood {
    /// PB5 as an input with its pull-down (low = supply lost).
    pub fn new(pin: Peri<'static, PB5>) -> Self {
        PowerGood {
            pin: Input::new(pin, Pull::Down),
        }
    }
}

impl fpc::ports::SupplyMonitor for PowerGood {
    fn power_good(&mut self) -> bool {
        self.pin.is_high()
    }
}

/// PWR_CR2.PLS = 6: the PVD's threshold at 2.9 V falling (datasheet VPVD6), above the BOR's
/// level 2 (≈ 2.2 V) and below the 3.3 V supply's tolerance.
const PVD_LEVEL: u32 = 6;

/// Enables the PVD at [`PVD_LEVEL`] (PWR_CR2.PVDE); `trip::lock_system_breaks` then routes
/// its output to the bridges' break inputs. Call before that.
pub fn start_pvd() {
    pac::RCC.apb1enr1().modify(|w| w.set_pwren(true));
    let _ = pac::RCC.apb1enr1().read();
    pac::PWR
        .cr2()
        .modify(|w| w.0 = (w.0 & !0xF) | PVD_LEVEL << 1 | 1);
}
