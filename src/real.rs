//! The scalar the physics laws are written over: `f32` on the MCU, `f64` in the simulator.
//!
//! Each physical law (friction, gas force, nozzle flow, …) is written once, generic over
//! [`Real`], so the firmware's feed-forward, the simulator's plant and the model-gap workflow
//! evaluate the same formula. `f32` goes through `micromath` (fast, FPU-friendly, the same on
//! host and MCU — called through its trait explicitly so std's methods never shadow it on the
//! host); `f64` goes through `libm`.

/// √x in `f32`, accurate to ~1 ulp·few: micromath's bit-trick seed (±5 %) refined by two
/// Newton steps (±5 % → ±0.13 % → ±1e-6). Cheaper than a software `sqrtf` on the MCU and the
/// same on the host. NaN for negative input, 0 for 0.
#[inline]
pub fn sqrt_f32(x: f32) -> f32 {
    if x <= 0.0 {
        return if x == 0.0 { 0.0 } else { f32::NAN };
    }
    let y = micromath::F32Ext::sqrt(x);
    let y = 0.5 * (y + x / y);
    0.5 * (y + x / y)
}

/// The larger of `a` and `b` by a plain comparison: the Cortex-M4's FPU (FPv4) has no
/// `VMAXNM`, so `f32::max` is a library call with NaN handling; this is a compare and a
/// conditional move. With a NaN it returns `b`.
#[inline(always)]
pub fn max_f32(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// The smaller of `a` and `b` by a plain comparison (see [`max_f32`]). With a NaN: `b`.
#[inline(always)]
pub fn min_f32(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// `x` limited to `[lo, hi]` by plain comparisons (see [`max_f32`]); NaN gives `lo`.
#[inline(always)]
pub fn clamp_f32(x: f32, lo: f32, hi: f32) -> f32 {
    if x > lo {
        if x < hi {
            x
        } else {
            hi
        }
    } else {
        lo
    }
}

/// `x` limited to `[lo, hi]`, NaN to 0, by one comparison with `lo` (whose flags tell
/// above, at-or-below and unordered apart) and one with `hi`: a saturated command that a NaN
/// must not drive to either end.
#[inline(always)]
pub fn clamp_or_zero_f32(x: f32, lo: f32, hi: f32) -> f32 {
    if x > lo {
        if x < hi {
            x
        } else {
            hi
        }
    } else if x <= lo {
        lo
    } else {
        0.0
    }
}

/// `x % y` (C's `fmodf`: the exact remainder, with the sign of `x`), by the shift-and-subtract
/// loop on the significands (musl's `fmodf`). The same result as `%` for every input — the
/// remainder is exact, so there is only one right answer — without the library routine the
/// `%` operator calls on the Cortex-M4, which divides in u64 and links ≈ 1.5 KiB of 64-bit
/// division. One loop pass per binade between `x` and `y` (a few for an angle mod 2π).
pub fn fmod_f32(x: f32, y: f32) -> f32 {
    let mut ux = x.to_bits();
    let mut uy = y.to_bits();
    let mut ex = ((ux >> 23) & 0xFF) as i32;
    let mut ey = ((uy >> 23) & 0xFF) as i32;
    let sign = ux & 0x8000_0000;
    if uy << 1 == 0 || y.is_nan() || ex == 0xFF {
        return f32::NAN;
    }
    if ux << 1 <= uy << 1 {
        return if ux << 1 == uy << 1 { 0.0 * x } else { x };
    }
    // Significands with their hidden bit; subnormals normalised (exponent below 1).
    (ux, ex) = significand(ux, ex);
    (uy, ey) = significand(uy, ey);
    // x mod y, one binade at a time.
    while ex > ey {
        let i = ux.wrapping_sub(uy);
        if i >> 31 == 0 {
            if i == 0 {
                return 0.0 * x;
            }
            ux = i;
        }
        ux <<= 1;
        ex -= 1;
    }
    let i = ux.wrapping_sub(uy);
    if i >> 31 == 0 {
        if i == 0 {
            return 0.0 * x;
        }
        ux = i;
    }
    while ux >> 23 == 0 {
        ux <<= 1;
        ex -= 1;
    }
    // Back to a float (a subnormal if the exponent fell below 1).
    if ex > 0 {
        ux = (ux - (1 << 23)) | ((ex as u32) << 23);
    } else {
        ux >>= (1 - ex) as u32;
    }
    f32::from_bits(ux | sign)
}

/// `x % y` in `f64` (C's `fmod`: the exact remainder, with the sign of `x`), the same for
/// every input as `%` and `libm::fmod`, whose bit-by-bit loop (one pass per binade between
/// `x` and `y`: ≈ 90 x86 instructions for an angle of a thousand radians mod 2π) this skips
/// while the quotient is below 2²⁶: with `q = trunc(x/y)` (exact, or one too large in
/// magnitude where `x/y` rounds up to an integer) and `y = y_h + y_l` split into 26 and 27
/// significant bits (Veltkamp), `q·y_h` and `q·y_l` are exact, `x − q·y_h` is exact
/// (Sterbenz: within a factor 2 of `x`), and the last difference is the exact remainder,
/// which is representable; one `y` added back corrects a quotient one too large, exactly.
#[inline]
pub fn rem_f64(x: f64, y: f64) -> f64 {
    let t = x / y;
    let y_abs = libm::fabs(y);
    // Also refuses NaN, infinities and y = 0 (t not finite), and a y whose split would
    // overflow or whose parts would underflow: the library routine handles them.
    if !(libm::fabs(t) < 67_108_864.0 && y_abs > 1e-270 && y_abs < 1e290) {
        return libm::fmod(x, y);
    }
    let q = t as i64 as f64;
    let c = 134_217_729.0 * y;
    let y_h = c - (c - y);
    let y_l = y - y_h;
    let r = (x - q * y_h) - q * y_l;
    let r = if x >= 0.0 {
        if r < 0.0 {
            r + y_abs
        } else {
            r
        }
    } else if r > 0.0 {
        r - y_abs
    } else {
        r
    };
    if r == 0.0 {
        0.0 * x // a zero with the sign of x, as fmod gives
    } else {
        r
    }
}

/// [`fmod_f32`]'s operand as (significand with its hidden bit at bit 23, exponent), from its
/// bits and biased exponent `e` (a subnormal, `e` = 0, normalised: the exponent goes below 1).
fn significand(bits: u32, mut e: i32) -> (u32, i32) {
    if e == 0 {
        let mut i = bits << 9;
        while i >> 31 == 0 {
            e -= 1;
            i <<= 1;
        }
        (bits << (1 - e) as u32, e)
    } else {
        ((bits & (u32::MAX >> 9)) | (1 << 23), e)
    }
}

/// i64 → f32 in two exact halves, `hi·2³² + lo` with `lo` the signed low word: a plain
/// `as f32` is a ~35-instruction library call (`__aeabi_l2f`) on the Cortex-M4, this is
/// about seven. Exact (the same as `as f32`) for |m| < 2²⁴; beyond, one rounding in the sum,
/// plus one in `hi` only above 2⁵⁶ (relative error ≤ 2⁻²³ either way). Domain: m ≤ 2⁶³ −
/// 2³¹ (above, `m − lo` wraps and the sign comes out wrong); the callers' values are far
/// smaller (the differentiator's Gram moments below 2⁵⁶, the servo's count within a few
/// turns of its base).
#[inline(always)]
pub fn i64_to_f32(m: i64) -> f32 {
    let lo = m as i32;
    // m − lo is a multiple of 2³², so the shift is exact and |hi| ≤ 2³¹.
    let hi = (m.wrapping_sub(i64::from(lo)) >> 32) as i32;
    hi as f32 * 4_294_967_296.0 + lo as f32
}

/// A floating-point scalar with the few operations the physics needs.
pub trait Real:
    Copy
    + PartialOrd
    + core::ops::Add<Output = Self>
    + core::ops::Sub<Output = Self>
    + core::ops::Mul<Output = Self>
    + core::ops::Div<Output = Self>
    + core::ops::Neg<Output = Self>
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// π.
    const PI: Self;
    /// From an `f32` constant.
    fn of(x: f32) -> Self;
    /// To `f32` (rounding).
    fn to_f32(self) -> f32;
    /// |x|.
    fn abs(self) -> Self;
    /// eˣ.
    fn exp(self) -> Self;
    /// xʸ for x ≥ 0.
    fn powf(self, y: Self) -> Self;
    /// √x for x ≥ 0.
    fn sqrt(self) -> Self;
    /// sin x.
    fn sin(self) -> Self;
    /// cos x.
    fn cos(self) -> Self;
    /// tanh x.
    fn tanh(self) -> Self;
    /// The larger of the two (NaN-ignoring like `f32::max`).
    fn max(self, other: Self) -> Self;
    /// The smaller of the two.
    fn min(self, other: Self) -> Self;
    /// `self % y`: the exact remainder, with the sign of `self` (C's `fmod`).
    fn rem(self, y: Self) -> Self;
}

impl Real for f32 {
    const ZERO: f32 = 0.0;
    const ONE: f32 = 1.0;
    const PI: f32 = core::f32::consts::PI;
    #[inline]
    fn of(x: f32) -> f32 {
        x
    }
    #[inline]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline]
    fn abs(self) -> f32 {
        micromath::F32Ext::abs(self)
    }
    #[inline]
    fn exp(self) -> f32 {
        // libm, not micromath: exact to an ulp where micromath's is off by ~1e-3, and shorter
        // on the M4 (a table and a short polynomial, no division).
        libm::expf(self)
    }
    #[inline]
    fn powf(self, y: f32) -> f32 {
        // libm, not micromath: micromath's powf is off by several per cent, and the callers
        // (isentropic volumes, once per stroke; a non-unit Stribeck exponent) need it exact.
        libm::powf(self, y)
    }
    #[inline]
    fn sqrt(self) -> f32 {
        sqrt_f32(self)
    }
    #[inline]
    fn sin(self) -> f32 {
        micromath::F32Ext::sin(self)
    }
    #[inline]
    fn cos(self) -> f32 {
        micromath::F32Ext::cos(self)
    }
    #[inline]
    fn tanh(self) -> f32 {
        // tanh x = 1 − 2/(e^{2x}+1); saturates cleanly for large |x|.
        let e = libm::expf(2.0 * clamp_f32(self, -20.0, 20.0));
        1.0 - 2.0 / (e + 1.0)
    }
    #[inline]
    fn max(self, other: f32) -> f32 {
        max_f32(self, other)
    }
    #[inline]
    fn min(self, other: f32) -> f32 {
        min_f32(self, other)
    }
    #[inline]
    fn rem(self, y: f32) -> f32 {
        fmod_f32(self, y)
    }
}

impl Real for f64 {
    const ZERO: f64 = 0.0;
    const ONE: f64 = 1.0;
    const PI: f64 = core::f64::consts::PI;
    #[inline]
    fn of(x: f32) -> f64 {
        f64::from(x)
    }
    #[inline]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline]
    fn abs(self) -> f64 {
        libm::fabs(self)
    }
    #[inline]
    fn exp(self) -> f64 {
        libm::exp(self)
    }
    #[inline]
    fn powf(self, y: f64) -> f64 {
        libm::pow(self, y)
    }
    #[inline]
    fn sqrt(self) -> f64 {
        libm::sqrt(self)
    }
    #[inline]
    fn sin(self) -> f64 {
        libm::sin(self)
    }
    #[inline]
    fn cos(self) -> f64 {
        libm::cos(self)
    }
    #[inline]
    fn tanh(self) -> f64 {
        libm::tanh(self)
    }
    #[inline]
    fn max(self, other: f64) -> f64 {
        f64::max(self, other)
    }
    #[inline]
    fn min(self, other: f64) -> f64 {
        f64::min(self, other)
    }
    #[inline]
    fn rem(self, y: f64) -> f64 {
        rem_f64(self, y)
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn clamp_or_zero_is_the_clamp_with_nan_to_zero() {
        use super::{clamp_f32, clamp_or_zero_f32};
        let specials = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            1e-30,
            -1e-30,
        ];
        let limits = [0.0f32, 1.0, 400.0, 5000.0, f32::INFINITY];
        let mut x = -7000.0f32;
        let mut values = specials.to_vec();
        while x < 7000.0 {
            values.push(x);
            x += 13.37;
        }
        for limit in limits {
            for &v in values.iter().chain(&[limit, -limit]) {
                let want = if v.is_nan() {
                    0.0
                } else {
                    clamp_f32(v, -limit, limit)
                };
                let got = clamp_or_zero_f32(v, -limit, limit);
                assert_eq!(got.to_bits(), want.to_bits(), "{v} within ±{limit}");
            }
        }
    }

    #[test]
    fn fmod_f32_is_bit_identical_to_the_remainder_operator() {
        use super::fmod_f32;
        use rand::{Rng, SeedableRng};
        let same = |x: f32, y: f32| {
            let (got, want) = (fmod_f32(x, y), x % y);
            assert!(
                got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                "{x:e} % {y:e}: {got:e}, want {want:e}"
            );
        };
        let tau = core::f32::consts::TAU;
        let special = [
            0.0,
            -0.0,
            f32::MIN_POSITIVE,
            1e-45,
            -3e-42,
            1.0,
            -1.0,
            tau,
            -tau,
            2.0 * tau,
            1e30,
            -7.5e37,
            f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        for &x in &special {
            for &y in &special {
                same(x, y);
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for _ in 0..1_000_000 {
            // Any bit patterns, and the angles the synchroniser wraps.
            same(f32::from_bits(rng.random()), f32::from_bits(rng.random()));
            same(rng.random_range(-2000.0f32..2000.0), tau);
        }
    }

    #[test]
    fn rem_f64_is_bit_identical_to_the_remainder_operator() {
        use super::rem_f64;
        use rand::{Rng, SeedableRng};
        let same = |x: f64, y: f64| {
            let (got, want) = (rem_f64(x, y), x % y);
            assert!(
                got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                "{x:e} % {y:e}: {got:e}, want {want:e}"
            );
        };
        let tau = core::f64::consts::TAU;
        let special = [
            0.0,
            -0.0,
            f64::MIN_POSITIVE,
            5e-324,
            1.0,
            -1.0,
            tau,
            -tau,
            2.0 * tau,
            3.0 * tau,
            -7.0 * tau,
            67_108_863.0 * tau,
            67_108_864.0 * tau,
            1e30,
            f64::MAX,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        for &x in &special {
            for &y in &special {
                same(x, y);
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for _ in 0..1_000_000 {
            // Any bit patterns; angles of every size mod 2π; exact multiples and their
            // neighbours, where the quotient rounds up.
            same(f64::from_bits(rng.random()), f64::from_bits(rng.random()));
            same(rng.random_range(-1e4..1e4), tau);
            same(rng.random_range(-4e8..4e8), tau);
            let k = rng.random_range(-100_000i64..100_000) as f64 * tau;
            for x in [
                k,
                f64::from_bits(k.to_bits().wrapping_add(1)),
                f64::from_bits(k.to_bits().wrapping_sub(1)),
            ] {
                same(x, tau);
            }
            same(rng.random_range(-50.0..50.0), rng.random_range(1e-3..10.0));
        }
    }

    #[test]
    fn i64_to_f32_by_halves_is_exact_below_2_24_and_within_an_ulp_beyond() {
        use super::i64_to_f32;
        for m in [
            0i64,
            1,
            -1,
            4095,
            -4096,
            12_288,
            -12_288,
            (1 << 24) - 1,
            -(1 << 24),
        ] {
            assert_eq!(i64_to_f32(m), m as f32, "{m}");
        }
        let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
        for shift in 0..64 {
            for _ in 0..200 {
                // xorshift64: values of every magnitude, both signs.
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let m = (x as i64) >> shift;
                let err = (f64::from(i64_to_f32(m)) - m as f64).abs();
                assert!(err <= (m as f64).abs() * 2f64.powi(-23), "{m}");
            }
        }
        // The ends of the domain.
        assert_eq!(i64_to_f32(i64::MIN), i64::MIN as f32);
        let top = i64::MAX - (1 << 31);
        assert_eq!(i64_to_f32(top), top as f32);
    }

    #[test]
    fn f32_exp_and_tanh_are_accurate_enough_for_the_friction_law() {
        use super::Real;
        let mut worst_exp = 0.0f64;
        let mut worst_tanh = 0.0f64;
        for i in -2000..=200 {
            let x = i as f32 * 0.01;
            let e = (f64::from(Real::exp(x)) - f64::from(x).exp()).abs() / f64::from(x).exp();
            worst_exp = worst_exp.max(e);
            let t = (f64::from(Real::tanh(x)) - f64::from(x).tanh()).abs();
            worst_tanh = worst_tanh.max(t);
        }
        println!(
            "worst relative exp error {worst_exp:.2e}, worst absolute tanh error {worst_tanh:.2e}"
        );
        // 0.3 % of the 20 N Stribeck term is 0.06 N: far below the friction uncertainty.
        assert!(worst_exp < 3e-3 && worst_tanh < 1e-3);
    }

    #[test]
    fn refined_sqrt_is_accurate() {
        let mut worst = 0.0f64;
        let mut x = 1e-6f32;
        while x < 1e7 {
            let err = (f64::from(super::sqrt_f32(x)) - f64::from(x).sqrt()) / f64::from(x).sqrt();
            worst = worst.max(err.abs());
            x *= 1.37;
        }
        assert!(worst < 2e-6, "{worst}");
        assert!(super::sqrt_f32(-1.0).is_nan());
        assert_eq!(super::sqrt_f32(0.0), 0.0);
    }
}
