//! The run log's rows as CSV text, fast: each value written with a fixed number of decimals
//! (its column's resolution, [`DECIMALS`]), trailing zeros dropped, by integer arithmetic —
//! three to four times cheaper than the shortest round-trip form, which a 20 kHz log of 18
//! columns cannot afford (1.6 million values per 10-cycle run).
//!
//! The resolutions are far below what the quantities are known to: 1 nm of position (the
//! encoders resolve ≈ 1 µm), 0.1 µrad of angle (the servo count is ≈ 50 µrad), 1 mPa of
//! pressure (one ADC code is 305 Pa), 0.1 mN of force, 10⁻¹⁴ m³ of volume (10⁻⁹ of the
//! smallest chamber). Times are exact. A value too large for its decimals, or not finite, is
//! written in the shortest round-trip form instead.

/// Decimals of each column of [`super::COLUMNS`]; `None`: exact (the time, as µs; the fault
/// code, a whole number).
pub const DECIMALS: [Option<u32>; 18] = [
    None,     // t_s
    Some(9),  // x_m
    Some(9),  // x_slave_m
    Some(7),  // theta_rad
    Some(4),  // f_master_n
    Some(4),  // f_slave_n
    Some(3),  // p_a_pa
    Some(3),  // p_b_pa
    Some(9),  // x_ref_m
    Some(7),  // theta_ref_rad
    Some(7),  // v_mps
    None,     // fault
    Some(3),  // p_a_true_pa
    Some(3),  // p_b_true_pa
    Some(14), // vol_a_m3
    Some(14), // vol_b_m3
    Some(3),  // p_suction_pa
    Some(3),  // p_discharge_pa
];

const POW10: [u64; 15] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
    10_000_000_000,
    100_000_000_000,
    1_000_000_000_000,
    10_000_000_000_000,
    100_000_000_000_000,
];

/// The two digits of every number 0–99.
const PAIRS: &[u8; 200] = b"\
0001020304050607080910111213141516171819\
2021222324252627282930313233343536373839\
4041424344454647484950515253545556575859\
6061626364656667686970717273747576777879\
8081828384858687888990919293949596979899";

/// Longest line [`Line`] holds, bytes (18 values of at most 36 characters and their commas).
const LINE_BYTES: usize = 1024;

/// One CSV line built on the stack, appended to the output in one copy.
pub struct Line {
    buf: [u8; LINE_BYTES],
    len: usize,
}

impl Default for Line {
    fn default() -> Self {
        Line {
            buf: [0; LINE_BYTES],
            len: 0,
        }
    }
}

impl Line {
    /// Empties the line.
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// The line so far.
    pub fn as_bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }

    /// Appends one byte (dropped if the line is full, which [`LINE_BYTES`] rules out).
    pub fn push(&mut self, b: u8) {
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = b;
            self.len += 1;
        }
    }

    fn bytes(&mut self, text: &[u8]) {
        for &b in text {
            self.push(b);
        }
    }

    /// Appends the `n` low decimal digits of `v` (zero-padded), two at a time.
    fn digits(&mut self, mut v: u64, n: usize) {
        let end = (self.len + n).min(LINE_BYTES);
        let mut i = end;
        while i >= self.len + 2 {
            let pair = (v % 100) as usize * 2;
            v /= 100;
            if let (Some(d), Some(p)) = (self.buf.get_mut(i - 2..i), PAIRS.get(pair..pair + 2)) {
                d.copy_from_slice(p);
            }
            i -= 2;
        }
        if i > self.len {
            if let Some(d) = self.buf.get_mut(i - 1) {
                *d = b'0' + (v % 10) as u8;
            }
        }
        self.len = end;
    }

    /// Appends a whole number.
    pub fn whole(&mut self, v: u64) {
        let n = v.checked_ilog10().map_or(1, |l| l as usize + 1);
        self.digits(v, n);
    }

    /// Appends `whole`, then `.` and the `decimals` digits of `frac` without trailing zeros
    /// (nothing when `frac` is zero).
    fn decimal(&mut self, whole: u64, mut frac: u64, mut decimals: usize) {
        self.whole(whole);
        if frac == 0 {
            return;
        }
        while frac.is_multiple_of(10) {
            frac /= 10;
            decimals -= 1;
        }
        self.push(b'.');
        self.digits(frac, decimals);
    }

    /// Appends `v` rounded to `decimals` (≤ 14) decimals, or in its shortest round-trip form
    /// when it is not finite or too large for them.
    pub fn fixed(&mut self, v: f64, decimals: u32) {
        match decimals {
            2 => self.fixed_at::<2>(v),
            3 => self.fixed_at::<3>(v),
            4 => self.fixed_at::<4>(v),
            6 => self.fixed_at::<6>(v),
            7 => self.fixed_at::<7>(v),
            9 => self.fixed_at::<9>(v),
            14 => self.fixed_at::<14>(v),
            d => match POW10.get(d as usize) {
                Some(&scale) => self.fixed_scaled(v, scale, d as usize),
                None => self.shortest(v),
            },
        }
    }

    /// [`Line::fixed`] with the decimals known when compiled (the divisions become
    /// multiplications).
    #[inline(always)]
    fn fixed_at<const D: usize>(&mut self, v: f64) {
        const { assert!(D < POW10.len()) };
        let scale = 10u64.pow(D as u32);
        self.fixed_scaled(v, scale, D);
    }

    #[inline(always)]
    fn fixed_scaled(&mut self, v: f64, scale: u64, decimals: usize) {
        let scaled = v * scale as f64;
        if scaled.is_nan() || scaled.abs() >= 9.0e18 {
            return self.shortest(v);
        }
        // Half away from zero (`f64::round` is a library call without SSE4.1).
        let n = (scaled + 0.5f64.copysign(scaled)) as i64;
        if n < 0 {
            self.push(b'-');
        }
        let m = n.unsigned_abs();
        self.decimal(m / scale, m % scale, decimals);
    }

    /// Appends `v` in its shortest round-trip form.
    pub fn shortest(&mut self, v: f64) {
        self.bytes(ryu::Buffer::new().format(v).as_bytes());
    }

    /// Appends the time of control cycle `cycle` (`cycle` × `period_us` µs) in seconds,
    /// exactly.
    pub fn time(&mut self, cycle: u64, period_us: u64) {
        let us = cycle.saturating_mul(period_us);
        self.decimal(us / 1_000_000, us % 1_000_000, 6);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn text(f: impl FnOnce(&mut Line)) -> String {
        let mut line = Line::default();
        f(&mut line);
        String::from_utf8(line.as_bytes().to_vec()).unwrap()
    }

    #[test]
    fn values_read_back_within_half_a_unit_of_their_last_decimal() {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        for _ in 0..200_000 {
            let d = rng.random_range(0..=14u32);
            let mag = 10f64.powi(rng.random_range(-12..6));
            let v = (rng.random::<f64>() * 2.0 - 1.0) * mag;
            let s = text(|o| o.fixed(v, d));
            let back: f64 = s.parse().unwrap();
            let unit = 10f64.powi(-(d as i32));
            assert!(
                (back - v).abs() <= 0.5 * unit + v.abs() * 4e-16,
                "{v} at {d} decimals → {s}"
            );
            assert!(!s.ends_with('0') || !s.contains('.'), "{s}");
            assert!(!s.ends_with('.'), "{s}");
        }
    }

    #[test]
    fn exact_values_print_as_people_write_them() {
        assert_eq!(text(|o| o.fixed(100_000.0, 3)), "100000");
        assert_eq!(text(|o| o.fixed(-4.356579, 4)), "-4.3566");
        assert_eq!(text(|o| o.fixed(0.004999947, 9)), "0.004999947");
        assert_eq!(text(|o| o.fixed(-0.0, 3)), "0");
        assert_eq!(text(|o| o.fixed(-0.00004, 3)), "0");
        assert_eq!(
            text(|o| o.fixed(3.326164142494852e-5, 14)),
            "0.00003326164142"
        );
        assert_eq!(text(|o| o.fixed(f64::NAN, 3)), "NaN");
        assert_eq!(text(|o| o.fixed(1e300, 3)), "1e300");
        assert_eq!(text(|o| o.time(1, 50)), "0.00005");
        assert_eq!(text(|o| o.time(20_000, 50)), "1");
        assert_eq!(text(|o| o.time(88_003, 50)), "4.40015");
        assert_eq!(text(|o| o.whole(7)), "7");
    }

    #[test]
    fn times_are_the_shortest_form_of_the_f64_time() {
        for cycle in (0..3_000_000u64).step_by(7) {
            let t = (cycle * 50) as f64 / 1e6;
            let ours = text(|o| o.time(cycle, 50));
            let back: f64 = ours.parse().unwrap();
            assert_eq!(back, t, "cycle {cycle}: {ours}");
        }
    }
}
