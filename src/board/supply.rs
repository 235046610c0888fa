//! The drive board's power-good input (PB5): an undervoltage comparator on the power stage
//! holds it high while the DC link is above its threshold (`[supply] power_good_voltage_v`
//! of the machine model, 500 V on the reference board). The pin's pull-down makes a broken
//! wire or an unpowered comparator read as a supply loss, the safe side.
//!
//! A comparator rather than an ADC reading of the link: the burst's regular sequence and
//! its DMA stay as they are (no rank added to the 20 kHz burst), there are no free ADC3–5
//! pins on the LQFP64, and one GPIO read in the 1 kHz supervision task is all the detection
//! needs (`docs/firmware.md`, "A supply loss in motion").

use embassy_stm32::gpio::{Input, Pull};
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
