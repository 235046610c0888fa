//! Emulated time: an integer count of 1/1.36 GHz units, so that every clock the firmware
//! uses is a whole number of units (170 MHz SYSCLK = 8, HSI16 = 85, the 1 MHz embassy tick
//! = 1,360, the 42.5 MHz ADC clock = 32, the 20 kHz PWM period = 68,000, the 32 kHz LSI =
//! 42,500). Nothing in the emulator reads a wall clock.

/// Time units per second.
pub const UNITS_PER_S: u64 = 1_360_000_000;
/// Time units per microsecond.
pub const UNITS_PER_US: u64 = UNITS_PER_S / 1_000_000;

/// Time units per cycle of a clock of `hz` (the clocks used are exact divisors).
pub fn units_per_cycle(hz: u64) -> f64 {
    UNITS_PER_S as f64 / hz as f64
}

/// `t` in seconds.
pub fn seconds(t: u64) -> f64 {
    t as f64 / UNITS_PER_S as f64
}

/// `t` in microseconds.
pub fn micros(t: u64) -> f64 {
    t as f64 / UNITS_PER_US as f64
}

/// Seconds as time units (rounded).
pub fn from_seconds(s: f64) -> u64 {
    (s * UNITS_PER_S as f64).round() as u64
}
