//! Boundary types: time ticks, ADC/DAC codes, PWM duties and the two motor sections.
//!
//! Everything that crosses the hardware boundary is a newtype so that a raw code can never
//! be mistaken for a physical value. Physical quantities inside the logic are `f32` in SI
//! units with the unit in the name (`force_n`, `pressure_pa`); conversions happen once, at
//! the edge, in the module that owns the sensor.

/// Control-loop period of the linear axis, s (20 kHz, `machine.md`).
pub const CONTROL_PERIOD_S: f32 = 50e-6;
/// Control-loop period in microsecond ticks.
pub const CONTROL_PERIOD_US: u32 = 50;

/// A point on the monotonic time base, in microseconds, wrapping every 2³² µs (≈ 71.6 min).
///
/// Only differences are meaningful; they are taken with wrapping arithmetic, so the wrap is
/// invisible as long as compared instants are less than 2³¹ µs (≈ 35.8 min) apart.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Ticks(pub u32);

impl Ticks {
    /// Microseconds elapsed from `earlier` to `self` (negative if `earlier` is later).
    #[inline]
    pub fn since_us(self, earlier: Ticks) -> i32 {
        // Wrapping difference reinterpreted as signed: correct across the 2³² wrap.
        self.0.wrapping_sub(earlier.0) as i32
    }

    /// This instant moved `us` microseconds later (wrapping).
    #[inline]
    pub fn add_us(self, us: u32) -> Ticks {
        Ticks(self.0.wrapping_add(us))
    }

    /// True if `self` is at or after `other` (wrap-safe).
    #[inline]
    pub fn reached(self, other: Ticks) -> bool {
        self.since_us(other) >= 0
    }
}

/// Full scale of the 12-bit ADCs of the STM32G474.
pub const ADC_FULL_SCALE: u16 = 4095;

/// A raw 12-bit ADC conversion result, 0..=4095 (values above are clamped by users).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct AdcCode(pub u16);

impl AdcCode {
    /// Mid-scale code, the zero of a bipolar signal.
    pub const MID: AdcCode = AdcCode(2048);

    /// The code as a signed offset from mid-scale, −2048..=2047 (codes above full scale are
    /// clamped first, so the result is always in range).
    #[inline]
    pub fn centered(self) -> i16 {
        self.0.min(ADC_FULL_SCALE) as i16 - 2048
    }
}

/// A raw 12-bit DAC code, 0..=4095; mid-scale is zero torque on the servo drive input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct DacCode(pub u16);

impl DacCode {
    /// Zero command.
    pub const MID: DacCode = DacCode(2048);
}

/// PWM duty of one phase as a Q0.16 fraction of the period: 0 = low side always on,
/// 65535 ≈ high side always on. The board scales it to its timer's auto-reload value.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Duty(pub u16);

impl Duty {
    /// 50 % duty: zero average phase voltage.
    pub const HALF: Duty = Duty(32768);

    /// From a fraction in [0, 1]; out-of-range and NaN saturate (NaN → 50 %).
    #[inline]
    pub fn from_fraction(f: f32) -> Duty {
        if f.is_nan() {
            return Duty::HALF;
        }
        // `as` saturates on float→int conversion (negative → 0, above → 65535), so no clamp
        // (a library call on the M4) is needed.
        Duty((f * 65535.0 + 0.5) as u16)
    }

    /// The duty as a fraction in [0, 1].
    #[inline]
    pub fn fraction(self) -> f32 {
        f32::from(self.0) / 65535.0
    }
}

/// The three phase duties of one motor section.
pub type PhaseDuties = [Duty; 3];

/// The two linear-motor sections. Historically "master" carries the position encoder the
/// controller uses; here both are commanded by this board in the same cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Section {
    /// Section 1 (TIM1 on the board), with the master encoder.
    Master = 0,
    /// Section 2 (TIM8 on the board), with the slave encoder.
    Slave = 1,
}

impl Section {
    /// Both sections, in index order.
    pub const ALL: [Section; 2] = [Section::Master, Section::Slave];
}

/// One value per motor section, indexed by [`Section`] without any fallible indexing.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct PerSection<T> {
    /// Value for the master section.
    pub master: T,
    /// Value for the slave section.
    pub slave: T,
}

impl<T> PerSection<T> {
    /// The value for `s`.
    #[inline]
    pub fn get(&self, s: Section) -> &T {
        match s {
            Section::Master => &self.master,
            Section::Slave => &self.slave,
        }
    }

    /// The value for `s`, mutably.
    #[inline]
    pub fn get_mut(&mut self, s: Section) -> &mut T {
        match s {
            Section::Master => &mut self.master,
            Section::Slave => &mut self.slave,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_difference_survives_the_wrap() {
        let before = Ticks(u32::MAX - 20);
        let after = before.add_us(50);
        assert_eq!(after.0, 29);
        assert_eq!(after.since_us(before), 50);
        assert_eq!(before.since_us(after), -50);
        assert!(after.reached(before));
        assert!(!before.reached(after));
    }

    #[test]
    fn duty_saturates_and_maps_nan_to_half() {
        assert_eq!(Duty::from_fraction(-1.0), Duty(0));
        assert_eq!(Duty::from_fraction(2.0), Duty(65535));
        assert_eq!(Duty::from_fraction(f32::NAN), Duty::HALF);
        assert!((Duty::from_fraction(0.25).fraction() - 0.25).abs() < 1e-4);
    }

    #[test]
    fn adc_code_centering_is_total() {
        assert_eq!(AdcCode(0).centered(), -2048);
        assert_eq!(AdcCode(4095).centered(), 2047);
        assert_eq!(AdcCode(u16::MAX).centered(), 2047);
    }
}
