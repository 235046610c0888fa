//! Wrapping fixed-point angles and their sine and cosine, and the one wrap of an angle in
//! radians ([`wrap_rad`], [`wrap_signed_rad`]) that the firmware, the plant and the
//! model-gap workflow share.
//!
//! An angle is a `u32` fraction of a turn: 2³² = 2π, so `i32::MIN..=i32::MAX` reads as
//! −π..π and wrap-around is free (the encoder's electrical angle is one). Sine and cosine
//! come from a 256-interval table with linear interpolation: |error| ≤ 7.6e-5 (the
//! interpolation error (2π/256)²/8), against micromath's 2e-3, in about a dozen instructions.
//! The table is computed at compile time from the Taylor series, in `f64`.

use crate::real::Real;

/// Entries per turn (the table holds one more, for interpolation across the last one).
const STEPS: usize = 256;

/// sin(2π·i/256) for i = 0..=256.
static SINE: [f32; STEPS + 1] = sine_table();

/// sin x for |x| ≤ π by its Taylor series (terms until they vanish in f64).
const fn taylor_sin(x: f64) -> f64 {
    let mut term = x;
    let mut sum = x;
    let mut n = 1u32;
    while n < 30 {
        let k = (2 * n) as f64;
        term = -term * x * x / (k * (k + 1.0));
        sum += term;
        n += 1;
    }
    sum
}

// Evaluated at compile time only: an index out of range is a build error, not a panic.
#[allow(clippy::indexing_slicing)]
const fn sine_table() -> [f32; STEPS + 1] {
    let mut t = [0.0f32; STEPS + 1];
    let mut i = 0;
    while i <= STEPS {
        let mut x = 2.0 * core::f64::consts::PI * (i as f64) / (STEPS as f64);
        if x > core::f64::consts::PI {
            x -= 2.0 * core::f64::consts::PI;
        }
        t[i] = taylor_sin(x) as f32;
        i += 1;
    }
    t
}

/// sin of a wrapping angle (2³² = one turn).
#[inline]
pub fn sin_turns(angle: u32) -> f32 {
    let i = (angle >> 24) as usize; // 0..=255: both i and i + 1 are in the table.
    let frac = (angle & 0x00FF_FFFF) as f32 * (1.0 / 16_777_216.0);
    let a = SINE.get(i).copied().unwrap_or(0.0);
    let b = SINE.get(i + 1).copied().unwrap_or(0.0);
    a + (b - a) * frac
}

/// (sin, cos) of a wrapping angle (2³² = one turn).
#[inline]
pub fn sin_cos_turns(angle: u32) -> (f32, f32) {
    (sin_turns(angle), sin_turns(angle.wrapping_add(1 << 30)))
}

/// The wrapping angle of `fraction` of a turn (any real; wraps; NaN and |fraction| ≥ 2²³,
/// where an f32 has no fractional part left, give 0).
///
/// Only 32-bit conversions, which the Cortex-M4F does in one instruction each: a 64-bit one
/// is a library call of some 40 instructions (the cogging compensation runs this every
/// cycle). The result is the exact truncation of `fraction`'s fractional part times 2³².
#[inline]
pub fn turns(fraction: f32) -> u32 {
    // One compare for both: NaN fails it.
    if fraction.abs() < 8_388_608.0 {
        // |fraction| < 2²³: the i32 holds its integer part, which an f32 holds exactly.
        let part = (fraction - fraction as i32 as f32) * 4_294_967_296.0; // in (-2³², 2³²), exact
        if part >= 0.0 {
            part as u32
        } else {
            (-part as u32).wrapping_neg()
        }
    } else {
        0
    }
}

/// An angle wrapped into [0, 2π), rad: `angle.rem_euclid(2π)` bit for bit (the same
/// rounding of `r + 2π` for a tiny negative remainder, NaN for NaN). Within one turn of the
/// range it is one comparison and at most one add, exact; beyond, the exact remainder
/// ([`Real::rem`]: on the MCU [`crate::real::fmod_f32`], no 64-bit division).
#[inline(always)]
pub fn wrap_rad<T: Real>(angle_rad: T) -> T {
    let turn = T::of(2.0) * T::PI;
    if angle_rad >= T::ZERO {
        if angle_rad < turn {
            return angle_rad;
        }
    } else if angle_rad > -turn {
        return angle_rad + turn;
    }
    wrap_far_rad(angle_rad)
}

/// [`wrap_rad`] of an angle beyond one turn of the range (or NaN): the exact remainder,
/// out of line so that the common case inlines small.
#[inline(never)]
fn wrap_far_rad<T: Real>(angle_rad: T) -> T {
    let turn = T::of(2.0) * T::PI;
    let r = angle_rad.rem(turn);
    if r < T::ZERO {
        r + turn
    } else {
        r
    }
}

/// An angle wrapped into [−π, π), rad (`wrap_rad(angle + π) − π`).
#[inline]
pub fn wrap_signed_rad<T: Real>(angle_rad: T) -> T {
    wrap_rad(angle_rad + T::PI) - T::PI
}

/// [`wrap_rad`] out of line, for cold paths that call it often (the stops and the brakes'
/// turns: a dozen inlined copies cost flash).
#[inline(never)]
pub fn wrap_rad_cold(angle_rad: f32) -> f32 {
    wrap_rad(angle_rad)
}

/// [`wrap_signed_rad`] on [`wrap_rad_cold`]: the shorter way round, rad in [−π, π).
#[inline]
pub fn wrap_signed_rad_cold(angle_rad: f32) -> f32 {
    wrap_rad_cold(angle_rad + core::f32::consts::PI) - core::f32::consts::PI
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_sine_and_cosine_are_accurate_everywhere() {
        let mut worst = 0.0f64;
        for k in 0..100_000u32 {
            let a = k.wrapping_mul(42_949); // spread over the whole turn
            let x = f64::from(a) / 4_294_967_296.0 * core::f64::consts::TAU;
            let (s, c) = sin_cos_turns(a);
            worst = worst
                .max((f64::from(s) - x.sin()).abs())
                .max((f64::from(c) - x.cos()).abs());
        }
        assert!(worst < 8e-5, "{worst}");
    }

    #[test]
    fn radians_wrap_as_the_euclidean_remainder_bit_for_bit() {
        let mut x: u64 = 0x2545_f491_4f6c_dd1d;
        let mut checked = 0;
        for k in -40_000i32..40_000 {
            // Every range: within a turn, a few turns, thousands; and the exact edges.
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let scale = [1e-3, 1.0, 7.0, 1e3, 1e6][(x % 5) as usize];
            let a = k as f64 * 1.7e-4 * scale;
            let want = a.rem_euclid(core::f64::consts::TAU);
            assert_eq!(wrap_rad(a).to_bits(), want.to_bits(), "{a:e}");
            let a32 = a as f32;
            let want32 = a32.rem_euclid(core::f32::consts::TAU);
            assert_eq!(wrap_rad(a32).to_bits(), want32.to_bits(), "{a32:e}");
            checked += 1;
        }
        for a in [
            0.0,
            core::f64::consts::TAU,
            -core::f64::consts::TAU,
            -0.0,
            12.5,
        ] {
            assert_eq!(
                wrap_rad(a).to_bits(),
                a.rem_euclid(core::f64::consts::TAU).to_bits()
            );
        }
        assert!(wrap_rad(f64::NAN).is_nan());
        assert!((wrap_signed_rad(3.5f64) - (3.5 - core::f64::consts::TAU)).abs() < 1e-15);
        assert!(checked > 10_000);
    }

    #[test]
    fn fractions_of_a_turn_wrap() {
        assert_eq!(turns(0.25), 1 << 30);
        assert_eq!(turns(1.25), 1 << 30);
        assert_eq!(turns(-0.25), 3 << 30);
        assert_eq!(turns(f32::NAN), 0);
        assert_eq!(turns(9.0e6), 0);
    }

    /// The 64-bit formulation `turns` replaced: the truncated fractional part times 2³².
    fn turns_via_i64(fraction: f32) -> u32 {
        let whole = fraction as i64 as f32;
        ((fraction - whole) * 4_294_967_296.0) as i64 as u32
    }

    #[test]
    fn turns_agrees_bit_for_bit_with_the_64_bit_conversion() {
        // Every sign and exponent up to 2²³ and mantissas spread over each binade, plus the
        // positions a stroke sees in pitches (x / 24 mm for |x| < 0.2 m) on a fine grid.
        let mut checked = 0u32;
        for bits in (0..0x4B00_0000u32).step_by(997) {
            for f in [f32::from_bits(bits), -f32::from_bits(bits)] {
                assert_eq!(turns(f), turns_via_i64(f), "{f:e}");
                checked += 1;
            }
        }
        for k in -400_000..=400_000 {
            let f = k as f32 * 2.0e-5;
            assert_eq!(turns(f), turns_via_i64(f), "{f:e}");
            checked += 1;
        }
        assert!(checked > 2_000_000);
    }
}
