//! Quadrature decoding of the servo's incremental encoder.
//!
//! The timer in encoder mode gives a 16-bit count that wraps. [`QuadratureCounter`] extends
//! it to an `i64` by accumulating the wrapping difference between reads, which is exact as
//! long as fewer than 2¹⁵ counts pass between two reads (at 20 kHz: 655 Mcounts/s — far
//! beyond the servo).

/// Extends a wrapping 16-bit hardware count to a wide signed count.
#[derive(Clone, Copy, Debug, Default)]
pub struct QuadratureCounter {
    last: u16,
    wide: i64,
    started: bool,
}

impl QuadratureCounter {
    /// A counter whose first read defines zero.
    pub const fn new() -> Self {
        QuadratureCounter {
            last: 0,
            wide: 0,
            started: false,
        }
    }

    /// Feeds a raw hardware count; returns the wide count since the first read.
    #[inline]
    pub fn update(&mut self, raw: u16) -> i64 {
        if !self.started {
            self.started = true;
            self.last = raw;
        }
        let step = raw.wrapping_sub(self.last) as i16;
        self.last = raw;
        // Wrapping: two instructions on the M4 where a saturating i64 add takes a dozen; at
        // most 2¹⁵ counts a read, the wide count reaches ±2⁶³ only after centuries.
        self.wide = self.wide.wrapping_add(i64::from(step));
        self.wide
    }

    /// The wide count of the last update.
    pub fn count(&self) -> i64 {
        self.wide
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn counts_through_the_wrap_both_ways() {
        let mut q = QuadratureCounter::new();
        let mut raw: u16 = 65_500;
        q.update(raw);
        for _ in 0..1000 {
            raw = raw.wrapping_add(7);
            q.update(raw);
        }
        assert_eq!(q.count(), 7000);
        for _ in 0..2000 {
            raw = raw.wrapping_sub(7);
            q.update(raw);
        }
        assert_eq!(q.count(), -7000);
    }

    proptest! {
        /// Any start and any moves of fewer than 2¹⁵ counts between reads: the wide count is
        /// exactly the sum of the moves, however often the 16-bit counter wraps.
        #[test]
        fn wide_count_is_the_sum_of_the_moves(
            start in any::<u16>(),
            moves in proptest::collection::vec(-32_767i32..=32_767, 0..2000),
        ) {
            let mut q = QuadratureCounter::new();
            prop_assert_eq!(q.update(start), 0);
            let mut raw = start;
            let mut sum = 0i64;
            for m in moves {
                raw = raw.wrapping_add(m as u16);
                sum += i64::from(m);
                prop_assert_eq!(q.update(raw), sum);
            }
        }

        /// Any sequence of raw values at all: no panic, and each read moves the count by at
        /// most 2¹⁵.
        #[test]
        fn any_raw_sequence_is_total(raws in proptest::collection::vec(any::<u16>(), 0..2000)) {
            let mut q = QuadratureCounter::new();
            let mut last = 0i64;
            for r in raws {
                let c = q.update(r);
                prop_assert!((c - last).abs() <= 32_768);
                last = c;
            }
        }
    }
}
