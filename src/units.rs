//! Boundary types: time ticks, ADC/DAC codes, PWM duties and the two motor sections.
//!
//! Everything that crosses the hardware boundary is a newtype so that a raw code can never
//! be mistaken for a physical value. Physical quantities inside the logic are `f32` in SI
//! units with the unit in the name (`force_n`, `pressure_pa`); conversions happen once, at
//! the edge, in the module that owns the sensor.

/// Control-loop period of the linear axis, s (20 kHz, `docs/machine.md`).
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
        Duty::from_code_number(f * 65535.0 + 0.5)
    }

    /// From a code number, 0..=65535 plus the 0.5 that rounds it (truncated), known not to
    /// be NaN (a NaN would give 0 %); out-of-range saturates.
    #[inline(always)]
    pub fn from_code_number(code: f32) -> Duty {
        // `as u32` is one VCVT on the Cortex-M4 (it saturates: negative → 0, above 2³² − 1 →
        // 2³² − 1) and the cap at 65535 one integer compare; the same result as `as u16`,
        // which compares the float against both ends instead.
        Duty((code as u32).min(u32::from(u16::MAX)) as u16)
    }

    /// The duty as a fraction in [0, 1].
    #[inline]
    pub fn fraction(self) -> f32 {
        f32::from(self.0) / 65535.0
    }

    /// The compare value, 0..=`arr`, that makes this duty on a centre-aligned timer counting
    /// to `arr` (PWM mode 1: high while CNT < CCR), rounded to nearest: what the board
    /// writes to CCRx.
    #[inline]
    pub const fn compare_value(self, arr: u16) -> u16 {
        ((self.0 as u32 * arr as u32 + 0x8000) >> 16) as u16
    }

    /// The duty compare value `c` makes on a timer counting to `arr` (c/arr; above `arr`,
    /// always high), to the nearest Q0.16 step.
    #[inline]
    pub const fn of_compare(c: u32, arr: u32) -> Duty {
        let arr = if arr == 0 { 1 } else { arr };
        let c = if c > arr { arr } else { c };
        let q = (c as u64 * 65535 + arr as u64 / 2) / arr as u64;
        Duty(if q > 65535 { 65535 } else { q as u16 })
    }

    /// This duty as the board's timers make it: rounded to one of their
    /// [`PWM_COMPARE_STEPS`] compare steps per period (what the bridge applies).
    #[inline]
    pub const fn as_switched(self) -> Duty {
        Duty::of_compare(
            self.compare_value(PWM_COMPARE_STEPS) as u32,
            PWM_COMPARE_STEPS as u32,
        )
    }
}

/// Compare steps of the board's PWM timers per period: TIM1/TIM8's auto-reload value,
/// 170 MHz / (2 × 20 kHz) centre-aligned (`src/board/pwm.rs` checks it is its ARR). A duty
/// is switched in steps of 1/4250 of the period, ≈ 15 Q0.16 steps.
pub const PWM_COMPARE_STEPS: u16 = 4250;

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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
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
    fn a_switched_duty_is_the_nearest_timer_step() {
        let steps = f64::from(PWM_COMPARE_STEPS);
        for raw in (0..=u16::MAX).step_by(7).chain([u16::MAX]) {
            let d = Duty(raw);
            let c = d.compare_value(PWM_COMPARE_STEPS);
            // The board's rounding: the compare value nearest to duty·ARR (Q0.16 scale).
            let exact = f64::from(raw) * steps / 65536.0;
            assert!((f64::from(c) - exact).abs() <= 0.5, "{raw}: {c} vs {exact}");
            // What that compare value makes, c/ARR, to half a Q0.16 step.
            let switched = d.as_switched().fraction();
            assert!(
                (f64::from(switched) - f64::from(c) / steps).abs() <= 0.5 / 65535.0 + 1e-7,
                "{raw}"
            );
        }
        assert_eq!(Duty::of_compare(4250, 4250), Duty(65535));
        assert_eq!(Duty::of_compare(9999, 4250), Duty(65535));
        assert_eq!(Duty::of_compare(0, 4250), Duty(0));
        assert_eq!(Duty::of_compare(1, 0), Duty(65535));
        assert_eq!(Duty::HALF.as_switched(), Duty::of_compare(2125, 4250));
    }

    #[test]
    fn adc_code_centering_is_total() {
        assert_eq!(AdcCode(0).centered(), -2048);
        assert_eq!(AdcCode(4095).centered(), 2047);
        assert_eq!(AdcCode(u16::MAX).centered(), 2047);
    }
}
