//! The rotation servo: its quadrature encoder on TIM4 and its analog torque command on DAC1.

use core::mem::ManuallyDrop;

use embassy_stm32::gpio::Flex;
use embassy_stm32::pac;
use embassy_stm32::pac::dac::vals::Mode;
use embassy_stm32::pac::timer::vals::FilterValue;
use embassy_stm32::peripherals::{DAC1, PA4, TIM4};
use embassy_stm32::timer::qei::Qei;
use embassy_stm32::Peri;
use fpc::ports::{QuadratureInput, TorqueOutput};
use fpc::units::{DacCode, ADC_FULL_SCALE};

/// Input filter of both encoder channels: fSAMPLING = fDTS/16 with N = 8 (TIM4 CKD = 00, so
/// fDTS = the 170 MHz timer clock): a level must hold 8 × 94 ns = 753 ns to count, so cable pick-up
/// (PWM edges of the bridges next to it) shorter than that is rejected. At 4096 counts/rev
/// and 100 rev/s the ×4 edges are 2.44 µs apart, 3.2× the filter delay.
pub const ENCODER_FILTER: FilterValue = FilterValue::FDTS_DIV16_N8;

/// [`QuadratureInput`]: TIM4 in encoder mode 3 (both edges of both channels, ×4), 16-bit
/// counter wrapping at 65535; the library extends it.
///
/// The encoder's A/B outputs must drive both levels (push-pull, or a differential line
/// receiver on the board for an RS-422 encoder), at 3.3 V logic levels. The inputs have the
/// internal pull-ups on (25–55 kΩ) so that an unplugged cable reads a steady high instead of
/// counting noise; they are far too weak for an open-collector encoder (≈ 4 µs rise with
/// 100 pF of cable, against 2.44 µs between edges at 100 rev/s), which needs external
/// pull-ups of about 1 kΩ.
///
/// Never dropped (the control task owns it for the program's life): a dropped encoder would
/// return its pins to analog inputs and stop the count the rotation's position rests on.
pub struct ServoEncoder(ManuallyDrop<Qei<'static, TIM4>>);

impl ServoEncoder {
    /// Wraps an encoder-mode timer and sets its input filter ([`ENCODER_FILTER`]) with the
    /// counter stopped: embassy's constructor starts the counter (CEN) before it switches
    /// the pins to their alternate function, unfiltered. The counter is then cleared, so
    /// nothing counted without the filter remains, and started again.
    pub fn new(qei: Qei<'static, TIM4>) -> Self {
        let tim = pac::TIM4;
        tim.cr1().modify(|w| w.set_cen(false));
        tim.ccmr_input(0).modify(|w| {
            w.set_icf(0, ENCODER_FILTER);
            w.set_icf(1, ENCODER_FILTER);
        });
        tim.cnt().write(|w| w.set_cnt(0));
        tim.cr1().modify(|w| w.set_cen(true));
        ServoEncoder(ManuallyDrop::new(qei))
    }
}

impl QuadratureInput for ServoEncoder {
    fn count(&mut self) -> u16 {
        self.0.count()
    }
}

/// [`TorqueOutput`]: DAC1 channel 1, buffered, 12-bit right-aligned, mid-scale = 0 torque.
///
/// Written through the PAC rather than embassy's `DacChannel`, whose constructor enables
/// the channel with the data register still at its reset value 0 (full negative torque)
/// before the caller can write mid-scale.
///
/// The pin is never dropped (the control task owns it for the program's life): a dropped pin
/// would leave the analog mode the DAC's output needs.
pub struct ServoTorque {
    _dac: Peri<'static, DAC1>,
    _pin: ManuallyDrop<Flex<'static>>,
}

impl ServoTorque {
    /// Brings DAC1 channel 1 up at zero torque: data register at mid-scale first, then the
    /// channel enable.
    pub fn new(dac: Peri<'static, DAC1>, pin: Peri<'static, PA4>) -> Self {
        let mut pin = Flex::new(pin);
        pin.set_as_analog();
        embassy_stm32::rcc::enable_and_reset::<DAC1>();
        let regs = pac::DAC1;
        // Mode bits are writable only with the channel off. HFSEL = 0b10: AHB above
        // 160 MHz (RM0440, DAC_MCR).
        regs.mcr().modify(|w| {
            w.set_hfsel(0b10);
            w.set_mode(0, Mode::NORMAL_EXT_BUFEN);
        });
        regs.dhr12r(0).write(|w| w.set_dhr(DacCode::MID.0));
        regs.cr().modify(|w| w.set_en(0, true));
        ServoTorque {
            _dac: dac,
            _pin: ManuallyDrop::new(pin),
        }
    }
}

impl TorqueOutput for ServoTorque {
    fn write(&mut self, code: DacCode) {
        // The DAC silently drops bits above 12; saturate instead of wrapping.
        pac::DAC1
            .dhr12r(0)
            .write(|w| w.set_dhr(code.0.min(ADC_FULL_SCALE)));
    }
}
