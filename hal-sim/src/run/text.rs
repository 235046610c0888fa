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

/// `'0'` in each of 8 bytes.
const ASCII_ZEROS: u64 = 0x3030_3030_3030_3030;

/// The 4 decimal digits of every number below 10⁴, one per byte, the first in the lowest
/// byte (`to_le_bytes` order), as numbers 0–9 (add [`ASCII_ZEROS`] for the text): 40 kB,
/// made when compiled. A look-up is a few instructions where arithmetic takes a dozen.
static FOUR_DIGITS: [u32; 10_000] = {
    let mut table = [0u32; 10_000];
    let mut n = 0;
    while n < 10_000 {
        let n32 = n as u32;
        table[n] = (n32 / 1000) | (n32 / 100 % 10) << 8 | (n32 / 10 % 10) << 16 | (n32 % 10) << 24;
        n += 1;
    }
    table
};

/// The 4 digits of `n` < 10⁴ ([`FOUR_DIGITS`]; 0 for a larger `n`, which never occurs).
#[inline(always)]
fn four_digits(n: u32) -> u32 {
    FOUR_DIGITS.get(n as usize).copied().unwrap_or(0)
}

/// The 8 decimal digits of `n` (< 10⁸), zero-padded, one per byte as [`FOUR_DIGITS`] has
/// them.
#[inline(always)]
fn eight_digits(n: u32) -> u64 {
    u64::from(four_digits(n / 10_000)) | (u64::from(four_digits(n % 10_000)) << 32)
}

/// Longest line [`Line`] holds by default, bytes (18 values of at most 36 characters and
/// their commas).
const LINE_BYTES: usize = 1024;

/// CSV text built in place: one line (the default), or many ([`Line::with_room`]) written
/// out in one piece.
pub struct Line {
    /// Fixed size: what it holds is `buf[..len]`.
    buf: Vec<u8>,
    len: usize,
}

impl Default for Line {
    fn default() -> Self {
        Self::with_room(0)
    }
}

impl Line {
    /// Room for `bytes` of text and one more line of at most [`LINE_BYTES`].
    pub fn with_room(bytes: usize) -> Self {
        Line {
            buf: vec![0; bytes + LINE_BYTES],
            len: 0,
        }
    }

    /// Bytes held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds nothing.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Empties the line.
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// The line so far.
    pub fn as_bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }

    /// Runs `f` on a cursor at the line's end and keeps what it appended (the cursor's
    /// length is a local, kept in a register while it writes: the byte stores through `buf`
    /// cannot change it).
    #[inline(always)]
    fn append(&mut self, f: impl FnOnce(&mut Cursor<'_>)) {
        let mut c = Cursor {
            buf: &mut self.buf,
            len: self.len,
        };
        f(&mut c);
        self.len = c.len;
    }

    /// Appends one byte (dropped if the line is full, which its room rules out).
    pub fn push(&mut self, b: u8) {
        self.append(|c| c.push(b));
    }

    /// Appends `text` (dropped if there is no room for it).
    pub fn extend(&mut self, text: &[u8]) {
        self.append(|c| c.put(text));
    }

    /// Appends a whole number.
    pub fn whole(&mut self, v: u64) {
        self.append(|c| c.whole(v));
    }

    /// Appends `v` rounded to `decimals` (≤ 14) decimals, or in its shortest round-trip form
    /// when it is not finite or too large for them.
    pub fn fixed(&mut self, v: f64, decimals: u32) {
        self.append(|c| c.fixed(v, decimals));
    }

    /// Appends `v` in its shortest round-trip form.
    pub fn shortest(&mut self, v: f64) {
        self.append(|c| c.shortest(v));
    }

    /// Appends the time of control cycle `cycle` (`cycle` × `period_us` µs) in seconds,
    /// exactly.
    pub fn time(&mut self, cycle: u64, period_us: u64) {
        self.append(|c| c.time(cycle, period_us));
    }

    /// Appends one row of the run log as CSV (no newline): the time of control cycle `cycle`
    /// (exact, from `period_us`), then `values` (in [`super::COLUMNS`]' order; the first, the
    /// time, is not read) each at its column's [`DECIMALS`].
    pub fn row(&mut self, cycle: u64, period_us: u64, values: &[f64; 18]) {
        self.append(|c| c.row(cycle, period_us, values));
    }
}

/// Writes text into `buf` from `len` on.
struct Cursor<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl Cursor<'_> {
    /// Appends one byte (dropped if the line is full, which its room rules out).
    #[inline(always)]
    fn push(&mut self, b: u8) {
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = b;
            self.len += 1;
        }
    }

    /// Appends `bytes` whole (dropped if the line is full, which its room rules out).
    fn put(&mut self, bytes: &[u8]) {
        let end = self.len + bytes.len();
        if let Some(d) = self.buf.get_mut(self.len..end) {
            d.copy_from_slice(bytes);
            self.len = end;
        }
    }

    /// Appends the first `n` (≤ 8) bytes of `text` (the text in `to_le_bytes` order): all 8
    /// are copied, a move of constant size, and the line grows by `n` (the rest is
    /// overwritten next). Dropped if the line is full, which its room rules out.
    /// Appends the decimal point and the `n` (1..=8) ASCII digits in the low bytes of
    /// `digits`: one eight-byte store with the point in front when they fit, else two.
    #[inline(always)]
    fn put_point_and_digits(&mut self, digits: u64, n: usize) {
        if n < 8 {
            self.put8(u64::from(b'.') | digits << 8, n + 1);
        } else {
            self.push(b'.');
            self.put8(digits, n);
        }
    }

    #[inline(always)]
    fn put8(&mut self, text: u64, n: usize) {
        if let Some(d) = self.buf.get_mut(self.len..self.len + 8) {
            d.copy_from_slice(&text.to_le_bytes());
            self.len += n.min(8);
        }
    }

    /// Appends a whole number.
    #[inline(always)]
    fn whole(&mut self, v: u64) {
        match u32::try_from(v) {
            // One digit (positions, angles, speeds): no arithmetic.
            Ok(digit) if digit < 10 => self.push(b'0' + digit as u8),
            Ok(small) if small < 100_000_000 => {
                let raw = eight_digits(small);
                // Leading zero digits are the low zero bytes (the first digit is byte 0).
                let skip = (raw.trailing_zeros() / 8).min(7);
                self.put8((raw | ASCII_ZEROS) >> (8 * skip), 8 - skip as usize);
            }
            _ => self.whole_large(v),
        }
    }

    /// [`Cursor::whole`] of 10⁸ or more.
    #[cold]
    #[inline(never)]
    fn whole_large(&mut self, v: u64) {
        self.whole(v / 100_000_000);
        self.put8(eight_digits((v % 100_000_000) as u32) | ASCII_ZEROS, 8);
    }

    /// Appends `whole`, then `.` and the `decimals` (1 to 16) digits of `frac` without
    /// trailing zeros (nothing when `frac` is zero). The point goes out in the same store as
    /// the first digits wherever they fit in one (a store and its length update fewer).
    #[inline(always)]
    fn decimal(&mut self, whole: u64, frac: u64, decimals: usize) {
        self.whole(whole);
        if frac == 0 {
            return;
        }
        const POINT: u64 = b'.' as u64;
        // All `decimals` digits (the low ones of 16: `hi` then `lo`), then the trailing
        // zeros cut off.
        let zeros = if decimals == 9 {
            // One digit above the low eight (positions, 1 nm): no table for it.
            let hi = frac / 100_000_000;
            let lo = eight_digits((frac % 100_000_000) as u32);
            self.put8(POINT | (hi.min(9) + u64::from(b'0')) << 8, 2);
            self.put8(lo | ASCII_ZEROS, 8);
            // `lo` all zeros: the one digit above is not (`frac` is not zero).
            if lo != 0 {
                lo.leading_zeros() / 8
            } else {
                8
            }
        } else if decimals > 8 {
            let lo = eight_digits((frac % 100_000_000) as u32);
            let hi = eight_digits((frac / 100_000_000) as u32);
            let n = decimals.min(16) - 8;
            self.put_point_and_digits((hi | ASCII_ZEROS) >> (8 * (8 - n)), n);
            self.put8(lo | ASCII_ZEROS, 8);
            // Trailing zero digits are the high zero bytes (the last digit is byte 7).
            if lo != 0 {
                lo.leading_zeros() / 8
            } else {
                8 + hi.leading_zeros() / 8
            }
        } else if decimals <= 4 {
            // Four digits are one stage fewer, in a `u32`.
            let four = four_digits((frac % 10_000) as u32);
            let n = decimals.max(1);
            let digits = u64::from((four | 0x3030_3030) >> (8 * (4 - n)));
            self.put8(POINT | digits << 8, n + 1);
            four.leading_zeros() / 8
        } else {
            let lo = eight_digits((frac % 100_000_000) as u32);
            let n = decimals.max(1);
            self.put_point_and_digits((lo | ASCII_ZEROS) >> (8 * (8 - n)), n);
            lo.leading_zeros() / 8
        };
        // Fewer than `decimals`: a non-zero `frac` has a non-zero digit.
        self.len = self.len.saturating_sub(zeros as usize);
    }

    /// Appends `v` rounded to `decimals` (≤ 14) decimals, or in its shortest round-trip form
    /// when it is not finite or too large for them.
    fn fixed(&mut self, v: f64, decimals: u32) {
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

    /// [`Cursor::fixed`] with the decimals known when compiled (the divisions become
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
        let magnitude = scaled.abs();
        // One comparison for both: NaN compares false.
        if magnitude < 9.0e18 {
            // Half away from zero, on the magnitude (`f64::round` is a library call without
            // SSE4.1): `−x − ½` is exactly `−(x + ½)`, so this is the signed value's rounding.
            let m = (magnitude + 0.5) as i64 as u64;
            if scaled < 0.0 && m != 0 {
                self.push(b'-');
            }
            self.decimal(m / scale, m % scale, decimals);
        } else {
            self.shortest(v);
        }
    }

    /// Appends `v` in its shortest round-trip form.
    fn shortest(&mut self, v: f64) {
        self.put(ryu::Buffer::new().format(v).as_bytes());
    }

    /// [`Line::row`], each value's [`DECIMALS`] spelled out here, so each
    /// value's decimals are known when compiled (`the_row_is_each_value_at_its_decimals`
    /// checks it against the table).
    fn row(&mut self, cycle: u64, period_us: u64, values: &[f64; 18]) {
        let [_, x, x_slave, theta, f_master, f_slave, p_a, p_b, x_ref, theta_ref, v, fault, p_a_true, p_b_true, vol_a, vol_b, p_suction, p_discharge] =
            *values;
        self.time(cycle, period_us);
        self.push(b',');
        self.fixed_at::<9>(x);
        self.push(b',');
        self.fixed_at::<9>(x_slave);
        self.push(b',');
        self.fixed_at::<7>(theta);
        self.push(b',');
        self.fixed_at::<4>(f_master);
        self.push(b',');
        self.fixed_at::<4>(f_slave);
        self.push(b',');
        self.fixed_at::<3>(p_a);
        self.push(b',');
        self.fixed_at::<3>(p_b);
        self.push(b',');
        self.fixed_at::<9>(x_ref);
        self.push(b',');
        self.fixed_at::<7>(theta_ref);
        self.push(b',');
        self.fixed_at::<7>(v);
        self.push(b',');
        // A fault code: a small whole number (a negative or fractional one never occurs).
        self.whole(fault as u64);
        self.push(b',');
        self.fixed_at::<3>(p_a_true);
        self.push(b',');
        self.fixed_at::<3>(p_b_true);
        self.push(b',');
        self.fixed_at::<14>(vol_a);
        self.push(b',');
        self.fixed_at::<14>(vol_b);
        self.push(b',');
        self.fixed_at::<3>(p_suction);
        self.push(b',');
        self.fixed_at::<3>(p_discharge);
    }

    /// Appends the time of control cycle `cycle` (`cycle` × `period_us` µs) in seconds,
    /// exactly.
    fn time(&mut self, cycle: u64, period_us: u64) {
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
    fn the_row_is_each_value_at_its_decimals() {
        let mut rng = ChaCha8Rng::seed_from_u64(18);
        for _ in 0..20_000 {
            let cycle = rng.random_range(0..10_000_000u64);
            let mut values = [0.0f64; 18];
            // Up to 10⁹: whole parts of eight digits and more, and values too large for their
            // decimals; now and then a NaN.
            for v in values.iter_mut() {
                let mag = 10f64.powi(rng.random_range(-12..10));
                *v = (rng.random::<f64>() * 2.0 - 1.0) * mag;
            }
            if rng.random_range(0..8) == 0 {
                values[rng.random_range(1..18)] = f64::NAN;
            }
            values[11] = f64::from(rng.random_range(0..40u8));
            let row = text(|o| o.row(cycle, 50, &values));
            let mut expected = text(|o| o.time(cycle, 50));
            for (k, (v, decimals)) in values.iter().zip(DECIMALS).enumerate().skip(1) {
                expected.push(',');
                expected += &match (k, decimals) {
                    (11, _) => text(|o| o.whole(*v as u64)),
                    (_, Some(d)) => text(|o| o.fixed(*v, d)),
                    (_, None) => text(|o| o.shortest(*v)),
                };
            }
            assert_eq!(row, expected);
        }
    }

    #[test]
    fn whole_numbers_of_every_length() {
        let mut v = 1u64;
        for _ in 0..19 {
            for w in [v - 1, v, v + 1, 3 * v, 9 * v + (v - 1)] {
                assert_eq!(text(|o| o.whole(w)), w.to_string());
            }
            v *= 10;
        }
        assert_eq!(text(|o| o.whole(u64::MAX)), u64::MAX.to_string());
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
