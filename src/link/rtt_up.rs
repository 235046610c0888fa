//! Writing into an RTT up-buffer without ever waiting: a write goes in whole or is dropped
//! whole, whatever mode the channel's flags ask for.
//!
//! A SEGGER RTT up-channel is a ring buffer in target RAM with a write offset (ours) and a
//! read offset (the host's), plus mode flags the host may change at any time: probe-rs sets
//! the `defmt` channel to "block if full" when it attaches. A writer that obeys that flag
//! spins until the host reads — inside the defmt logger's critical section, which stops the
//! 20 kHz control interrupt with it. [`write_or_skip`] never reads the flags: it checks the
//! free space once and either copies or returns 0. One byte of the ring always stays free
//! (read offset = write offset means empty), as in SEGGER's implementation.

/// The ring buffer of one up-channel, as the writer needs it. The firmware implements it
/// over the RTT control block in RAM; tests over a `Vec`.
pub trait UpBuffer {
    /// Buffer size, bytes.
    fn size(&self) -> usize;
    /// The host's read offset, `0..size` if the host behaves.
    fn read_offset(&self) -> usize;
    /// Our write offset, `0..size`.
    fn write_offset(&self) -> usize;
    /// Copies `bytes` to offset `at`; callers guarantee `at + bytes.len() <= size()`.
    fn copy_in(&mut self, at: usize, bytes: &[u8]);
    /// Publishes a new write offset (after the bytes it covers are in place).
    fn commit(&mut self, write: usize);
}

/// Writes `bytes` to `ring` if all of them fit, else nothing. Never waits; returns the
/// number of bytes written (`bytes.len()` or 0). Offsets out of range (a confused host)
/// count as a full buffer.
pub fn write_or_skip(ring: &mut impl UpBuffer, bytes: &[u8]) -> usize {
    let size = ring.size();
    let (write, read) = (ring.write_offset(), ring.read_offset());
    if bytes.is_empty() || write >= size || read >= size {
        return 0;
    }
    let free = if read > write {
        read - write - 1
    } else {
        size - 1 - (write - read)
    };
    if bytes.len() > free {
        return 0;
    }
    let (head, tail) = bytes.split_at(bytes.len().min(size - write));
    ring.copy_in(write, head);
    if !tail.is_empty() {
        ring.copy_in(0, tail);
    }
    ring.commit((write + bytes.len()) % size);
    bytes.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;
    use std::time::Duration;

    /// SEGGER's mode flag for "block if full", the mode probe-rs sets on attach.
    const BLOCK_IF_FULL: usize = 2;

    /// An up-channel in host memory; `flags` is stored like the target's, and ignored.
    struct Ring {
        buffer: Vec<u8>,
        write: usize,
        read: usize,
        flags: usize,
    }

    impl Ring {
        fn new(size: usize) -> Self {
            Ring {
                buffer: vec![0; size],
                write: 0,
                read: 0,
                flags: BLOCK_IF_FULL,
            }
        }

        /// What the host would read now.
        fn drain(&mut self) -> Vec<u8> {
            let mut out = Vec::new();
            while self.read != self.write {
                out.push(self.buffer[self.read]);
                self.read = (self.read + 1) % self.buffer.len();
            }
            out
        }
    }

    impl UpBuffer for Ring {
        fn size(&self) -> usize {
            self.buffer.len()
        }
        fn read_offset(&self) -> usize {
            self.read
        }
        fn write_offset(&self) -> usize {
            self.write
        }
        fn copy_in(&mut self, at: usize, bytes: &[u8]) {
            self.buffer[at..at + bytes.len()].copy_from_slice(bytes);
        }
        fn commit(&mut self, write: usize) {
            self.write = write;
        }
    }

    #[test]
    fn log_write_returns_at_once_when_the_host_set_block_if_full_and_the_buffer_is_full() {
        // Run on another thread: a blocking writer would never return, and the test would
        // report it as a timeout instead of hanging.
        let (done, result) = mpsc::channel();
        std::thread::spawn(move || {
            let mut ring = Ring::new(64);
            assert_eq!(ring.flags, BLOCK_IF_FULL);
            assert_eq!(write_or_skip(&mut ring, &[1; 63]), 63, "63 of 64 bytes fit");
            let skipped = write_or_skip(&mut ring, &[2; 8]);
            done.send((skipped, ring.drain())).unwrap();
        });
        let (skipped, read) = result
            .recv_timeout(Duration::from_secs(5))
            .expect("the write blocked on a full buffer");
        assert_eq!(skipped, 0, "a write that does not fit is dropped");
        assert_eq!(read, vec![1; 63], "what was in the buffer is intact");
    }

    #[test]
    fn a_write_that_does_not_fit_is_dropped_whole_not_torn() {
        let mut ring = Ring::new(16);
        assert_eq!(write_or_skip(&mut ring, &[7; 10]), 10);
        assert_eq!(
            write_or_skip(&mut ring, &[8; 6]),
            0,
            "5 bytes free, 6 asked"
        );
        assert_eq!(ring.drain(), vec![7; 10]);
    }

    #[test]
    fn writes_wrap_around_the_ring_in_order() {
        let mut ring = Ring::new(16);
        let mut expected = Vec::new();
        for n in 0..40u8 {
            let frame = [n; 5];
            assert_eq!(write_or_skip(&mut ring, &frame), 5);
            expected.extend_from_slice(&frame);
            if n % 2 == 1 {
                assert_eq!(ring.drain(), expected);
                expected.clear();
            }
        }
    }

    #[test]
    fn offsets_out_of_range_count_as_full() {
        let mut ring = Ring::new(16);
        ring.read = 99;
        assert_eq!(write_or_skip(&mut ring, &[1]), 0);
        assert_eq!(ring.write, 0);
    }
}
