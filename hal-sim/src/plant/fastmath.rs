//! Fast, accurate `f64` sine and cosine for the plant's hot path (numerics, not physics).
//!
//! The plant evaluates a few angles per control period (electrical angle, encoder signals);
//! `libm`/glibc `sin_cos` cost ≈ 100+ instructions each. This is Cody–Waite reduction by
//! π/2 and the fdlibm kernel polynomials on [−π/4, π/4]: error below 2e-16 relative to the
//! reduced argument for |x| < 1e5 rad, far beyond what a 12-bit ADC or a 24 mm pitch needs.

// The kernel coefficients are fdlibm's, digit for digit.
#![allow(clippy::excessive_precision)]

use std::f64::consts::FRAC_2_PI;

/// π/2 in two parts (Cody–Waite): the high part has 33 significant bits, so `k·HI` is exact
/// for |k| < 2²⁰.
const PIO2_HI: f64 = 1.570_796_326_734_125_6;
const PIO2_LO: f64 = 6.077_100_506_506_192e-11;

// fdlibm __kernel_sin / __kernel_cos coefficients.
const S1: f64 = -1.666_666_666_666_663_2e-1;
const S2: f64 = 8.333_333_333_322_49e-3;
const S3: f64 = -1.984_126_982_985_795e-4;
const S4: f64 = 2.755_731_370_707_006_8e-6;
const S5: f64 = -2.505_076_025_340_686_3e-8;
const S6: f64 = 1.589_690_995_211_55e-10;
const C1: f64 = 4.166_666_666_666_660_2e-2;
const C2: f64 = -1.388_888_888_887_411e-3;
const C3: f64 = 2.480_158_728_947_673e-5;
const C4: f64 = -2.755_731_435_139_066_3e-7;
const C5: f64 = 2.087_572_321_298_175e-9;
const C6: f64 = -1.135_964_755_778_819_5e-11;

/// `(sin x, cos x)`.
#[inline]
pub fn sin_cos(x: f64) -> (f64, f64) {
    // Round to nearest by truncating x·2/π ± ½ (a conversion instruction; `round` is a
    // library call on baseline x86-64).
    let q = x * FRAC_2_PI;
    let ki = (q + 0.5f64.copysign(q)) as i64;
    let k = ki as f64;
    let r = (x - k * PIO2_HI) - k * PIO2_LO;
    let z = r * r;
    let s = r + r * z * (S1 + z * (S2 + z * (S3 + z * (S4 + z * (S5 + z * S6)))));
    let c = 1.0 - 0.5 * z + z * z * (C1 + z * (C2 + z * (C3 + z * (C4 + z * (C5 + z * C6)))));
    match ki & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// `⌊x⌋` as an integer, by conversion (`f64::floor` is a library call on baseline x86-64).
/// Exact for |x| < 2⁶³; saturates beyond, and NaN gives 0, as `x.floor() as i64` does.
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_i64_is_floor() {
        for x in [
            -2.5,
            -2.0,
            -1e-300,
            -0.0,
            0.0,
            1e-300,
            0.5,
            1.0,
            82_245.7,
            -82_245.7,
            1e300,
            -1e300,
            f64::NAN,
        ] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
    }

    #[test]
    fn matches_std_over_the_plant_range() {
        let mut worst: f64 = 0.0;
        for i in -200_000..=200_000 {
            let x = i as f64 * 1.234_567e-3;
            let (s, c) = sin_cos(x);
            worst = worst.max((s - x.sin()).abs()).max((c - x.cos()).abs());
        }
        assert!(worst < 1e-14, "worst {worst}");
    }
}
