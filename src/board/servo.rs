//! The rotation servo: its quadrature encoder on TIM4 and its analog torque command on DAC1.

use embassy_stm32::dac::{DacChannel, Value};
use embassy_stm32::mode::Blocking;
use embassy_stm32::peripherals::TIM4;
use embassy_stm32::timer::qei::Qei;
use fpc::ports::{QuadratureInput, TorqueOutput};
use fpc::units::{DacCode, ADC_FULL_SCALE};

/// [`QuadratureInput`]: TIM4 in encoder mode 3 (both edges of both channels, ×4), 16-bit
/// counter wrapping at 65535; the library extends it.
pub struct ServoEncoder(Qei<'static, TIM4>);

impl ServoEncoder {
    /// Wraps a configured encoder-mode timer.
    pub fn new(qei: Qei<'static, TIM4>) -> Self {
        ServoEncoder(qei)
    }
}

impl QuadratureInput for ServoEncoder {
    fn count(&mut self) -> u16 {
        self.0.count()
    }
}

/// [`TorqueOutput`]: DAC1 channel 1, buffered, 12-bit right-aligned, mid-scale = 0 torque.
pub struct ServoTorque(DacChannel<'static, Blocking>);

impl ServoTorque {
    /// Wraps the DAC channel and sets it to zero torque.
    pub fn new(dac: DacChannel<'static, Blocking>) -> Self {
        let mut torque = ServoTorque(dac);
        torque.write(DacCode::MID);
        torque
    }
}

impl TorqueOutput for ServoTorque {
    fn write(&mut self, code: DacCode) {
        // The DAC silently drops bits above 12; saturate instead of wrapping.
        self.0.set(Value::Bit12Right(code.0.min(ADC_FULL_SCALE)));
    }
}
