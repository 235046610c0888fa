//! The flash interface's caches as the emulated time pays them (RM0440's embedded flash memory,
//! "Read access latency", "Instruction cache memory", "Data cache memory"): with FLASH_ACR.ICEN an
//! instruction fetch from program flash that hits the 1 KiB instruction cache (32 lines of
//! 4 × 64 bits) costs no wait state; with DCEN a data read that hits the 256-byte data cache
//! (8 lines of 4 × 64 bits) neither. A miss pays FLASH_ACR.LATENCY and the 64-bit flash line
//! read is copied into the cache.
//!
//! The manual gives the size, not the placement or replacement policy: the model holds the
//! cache's 64-bit flash lines (128 for instructions, 32 for data) fully associative with
//! least-recently-used replacement. The prefetch buffer (PRFTEN, off in the firmware) is not
//! modelled. The periods' cycle figures ([`super::PeriodLoad`]) keep the no-cache bound;
//! only the time runs on this.

/// A cache of 64-bit flash lines, fully associative, least recently used replaced.
#[derive(Clone, Debug)]
pub struct LineCache {
    /// The lines held (address of the 64-bit line), most recently used last.
    lines: Vec<u32>,
    capacity: usize,
}

impl LineCache {
    /// The instruction cache: 1 KiB, 128 lines of 64 bits.
    pub fn instructions() -> Self {
        Self::with_lines(128)
    }

    /// The data cache: 256 bytes, 32 lines of 64 bits.
    pub fn data() -> Self {
        Self::with_lines(32)
    }

    fn with_lines(capacity: usize) -> Self {
        LineCache {
            lines: Vec::with_capacity(capacity),
            capacity,
        }
    }

    /// An access of 64-bit `line`: whether it hit; a miss brings it in.
    pub fn access(&mut self, line: u32) -> bool {
        if let Some(i) = self.lines.iter().rposition(|&l| l == line) {
            let l = self.lines.remove(i);
            self.lines.push(l);
            return true;
        }
        if self.lines.len() == self.capacity {
            self.lines.remove(0);
        }
        self.lines.push(line);
        false
    }

    /// Emptied (a reset of the chip or of the cache).
    pub fn clear(&mut self) {
        self.lines.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_loop_that_fits_hits_after_its_first_pass_and_one_that_does_not_always_misses() {
        let mut c = LineCache::instructions();
        let lines = |n: u32| (0..n).map(|i| 0x0800_0000 + 8 * i);
        assert!(lines(128).all(|l| !c.access(l)));
        assert!(lines(128).all(|l| c.access(l)));
        // 129 lines through 128 places in LRU order: each access evicts the next one needed.
        c.clear();
        for _ in 0..3 {
            assert!(lines(129).all(|l| !c.access(l)));
        }
    }

    #[test]
    fn the_least_recently_used_line_goes_first() {
        let mut c = LineCache::data();
        for i in 0..32 {
            c.access(8 * i);
        }
        assert!(c.access(0)); // line 0 now the most recent
        assert!(!c.access(8 * 32)); // evicts line 8
        assert!(c.access(0));
        assert!(!c.access(8));
    }
}
