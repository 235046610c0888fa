//! Port traits: every piece of hardware the control logic touches, as a small trait.
//!
//! The firmware implements these once for the STM32G474 board (`src/board/`, MCU only) and
//! `hal-sim` implements them once for the simulated plant. The logic is generic over them
//! (static dispatch, no trait objects), so the very same task bodies run on both.
//!
//! Sampling model: on the board, TIM1's update at the PWM centre triggers one burst of
//! conversions (phase currents by injected ADC, encoder sin/cos and pressures by regular
//! ADC) and the end of that burst wakes the control task ([`CycleTrigger`]). The synchronous
//! `read` methods then return the samples of that burst; they never block.
#![allow(async_fn_in_trait)] // single-core executors: the futures never need `Send`.

use crate::units::{AdcCode, DacCode, PerSection, PhaseDuties, Section, Ticks};

/// Sin and cos channels of one 1 Vpp sin/cos encoder, as raw ADC codes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct SinCosCodes {
    /// Sine channel.
    pub sin: AdcCode,
    /// Cosine channel.
    pub cos: AdcCode,
}

/// Both encoders of the linear axis, sampled in the same burst.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct EncoderCodes {
    /// Encoder on the master section (the position the controller uses).
    pub master: SinCosCodes,
    /// Encoder on the slave section (cross-check and correction).
    pub slave: SinCosCodes,
}

/// Phase currents of one section (phases U, V, W) as raw ADC codes, mid-scale = 0 A.
pub type PhaseCurrentCodes = [AdcCode; 3];

/// The four pressure channels, raw ADC codes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct PressureCodes {
    /// Chamber A (small x).
    pub chamber_a: AdcCode,
    /// Chamber B (large x).
    pub chamber_b: AdcCode,
    /// Suction line.
    pub suction: AdcCode,
    /// Discharge line.
    pub discharge: AdcCode,
}

/// Waits for the next control cycle: the end of the sampling burst at the PWM centre.
pub trait CycleTrigger {
    /// Completes once per control period with the time of the sampling instant.
    async fn next_cycle(&mut self) -> Ticks;
}

/// Monotonic time base.
pub trait Clock {
    /// Now, in wrapping microsecond ticks.
    fn now(&self) -> Ticks;
}

/// Waiting on the time base, for the slow (thread-mode) tasks.
pub trait Sleep {
    /// Completes at or after `deadline`.
    async fn until(&mut self, deadline: Ticks);
}

/// The two sin/cos encoders of the linear axis.
pub trait EncoderInput {
    /// Samples of the current burst.
    fn read(&mut self) -> EncoderCodes;
}

/// Phase-current sensing of both motor sections (injected ADC, mid-PWM).
pub trait CurrentInput {
    /// Phase-current codes of `section` from the current burst.
    fn read(&mut self, section: Section) -> PhaseCurrentCodes;
}

/// Three-phase PWM outputs of both motor sections.
pub trait PwmOutput {
    /// Sets the duties of `section`; they take effect at the next PWM period.
    fn write(&mut self, section: Section, duties: PhaseDuties);
    /// Switches every output of every section off (all six gates low): safe torque off.
    fn disable(&mut self);
    /// Switches the outputs of the sections marked `true` on and of the others off: a
    /// section taken out of service (overcurrent, its encoder lost) stops switching while
    /// the other one drives.
    fn enable(&mut self, sections: PerSection<bool>);
    /// Which sections' hardware over-current trip has switched their outputs off (latched by
    /// the hardware until [`PwmOutput::rearm`]). A board without such a trip never reports
    /// one.
    fn tripped(&mut self) -> PerSection<bool> {
        PerSection::default()
    }
    /// Re-arms the hardware over-current trip of the sections marked `true` (after
    /// `ClearFaults`); a trip whose cause persists latches again at once.
    fn rearm(&mut self, sections: PerSection<bool>) {
        let _ = sections;
    }
}

/// The servo's quadrature counter (hardware 16-bit, wrapping).
pub trait QuadratureInput {
    /// Raw counter value.
    fn count(&mut self) -> u16;
}

/// The servo drive's analog torque command (DAC).
pub trait TorqueOutput {
    /// Writes the torque command code; [`DacCode::MID`] is zero torque.
    fn write(&mut self, code: DacCode);
}

/// Chamber and line pressure sensors.
pub trait PressureInput {
    /// Samples of the current burst.
    fn read(&mut self) -> PressureCodes;
}

/// The drive board's power-good input: an undervoltage comparator on the power stage says
/// whether the DC link is above its threshold (`docs/firmware.md`, "A supply loss in
/// motion"). Read by the 1 kHz supervision task, never by the 20 kHz path.
pub trait SupplyMonitor {
    /// Whether the link is above the power-good threshold now.
    fn power_good(&mut self) -> bool;
}

/// All ports of the 20 kHz control task, bundled so the task takes one argument.
pub struct ControlPorts<T, E, C, P, Q, S, R> {
    /// Cycle trigger (end of the sampling burst).
    pub cycle: T,
    /// Linear-axis encoders.
    pub encoders: E,
    /// Phase currents.
    pub currents: C,
    /// Motor PWM.
    pub pwm: P,
    /// Servo quadrature counter.
    pub quadrature: Q,
    /// Servo torque command.
    pub servo: S,
    /// Pressure sensors.
    pub pressures: R,
}

/// The independent watchdog: once started it resets the MCU unless fed in time.
pub trait Watchdog {
    /// Restarts the watchdog's countdown.
    fn feed(&mut self);
}

/// A byte stream to the host: the RTT telemetry up-channel on the board, a buffer in the
/// simulator.
/// Where commands arrive: the RTT down-channel on the MCU, a buffer in tests.
pub trait ByteSource {
    /// Copies the bytes waiting (at most `buf.len()`) into `buf` without blocking; returns
    /// how many.
    fn read(&mut self, buf: &mut [u8]) -> usize;
}

/// Where a byte stream leaves the board: the RTT up-channels (telemetry, command replies)
/// on the MCU, a buffer in the simulator.
pub trait FrameSink {
    /// Takes as many of `bytes` as fit now, without blocking; returns how many it took.
    /// A sink should take a whole frame or nothing (RTT "no block, skip"): the telemetry
    /// task then never tears a frame, and counts what it could not send.
    fn write(&mut self, bytes: &[u8]) -> usize;
}

/// Why a calibration save failed (the previous record, if any, is still the one stored).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum SaveError {
    /// The flash refused a write or an erase (or the power went).
    Flash,
    /// The storage is damaged beyond repair: erase the store's pages and calibrate again.
    Corrupted,
    /// The flash reported success but reading the record back gave something else: a
    /// write the flash controller failed without saying so (embassy-stm32 0.6's async
    /// driver clears the error flags in its interrupt, `docs/upstream-flash-error-flags.md`).
    Verify,
}

/// Operator-facing events, reported by the supervision task (never from the 20 kHz path):
/// the board logs them with defmt at fixed levels, the simulator records them.
pub trait EventLog {
    /// A fault was latched (defmt `error`).
    fn fault_latched(&mut self, fault: crate::safety::faults::Fault);
    /// A limit became active (defmt `warn`).
    fn limit_active(&mut self, limits: crate::safety::supervisor::LimitFlags);
    /// The operating mode changed (defmt `info`).
    fn mode_changed(&mut self, mode: crate::status::ModeKind);
    /// The parts absent since boot changed (defmt `warn`; empty: every part is there).
    fn absent_changed(&mut self, absent: crate::safety::absent::Absent);
    /// A calibration record was saved to flash, or the save failed (defmt `info` / `error`).
    fn calibration_saved(&mut self, result: Result<(), SaveError>);
}
