//! In-memory ports for running one firmware task body on its own, in lock-step with a clock
//! stepped by hand: a queue the task reads bytes from ([`ByteQueue`], a [`ByteSource`]),
//! a buffer it writes frames to ([`ByteSink`], a [`FrameSink`]) and the clock it sleeps on
//! ([`SteppedClock`]). Each is a shared handle: clone it, give one clone to the task and
//! keep the other to feed, read or step it. What the link's behaviour tests run the
//! firmware's command task against (`tests/commands_arrive_over_the_link.rs`,
//! `hal-sim/tests/link_streams_recorded_channels.rs`).

use std::cell::{Cell, RefCell};
use std::collections::VecDeque;
use std::future::poll_fn;
use std::rc::Rc;
use std::task::Poll;

use fpc::ports::{ByteSource, Clock, FrameSink, Sleep};
use fpc::units::Ticks;

/// Bytes waiting for a task to read them.
#[derive(Clone, Debug, Default)]
pub struct ByteQueue(pub Rc<RefCell<VecDeque<u8>>>);

impl ByteQueue {
    /// Queues `bytes` behind what waits.
    pub fn push(&self, bytes: &[u8]) {
        self.0.borrow_mut().extend(bytes);
    }
}

impl ByteSource for ByteQueue {
    fn read(&mut self, buf: &mut [u8]) -> usize {
        let mut q = self.0.borrow_mut();
        let n = buf.len().min(q.len());
        for (slot, b) in buf.iter_mut().zip(q.drain(..n)) {
            *slot = b;
        }
        n
    }
}

/// Everything a task wrote, in order (it never refuses a frame).
#[derive(Clone, Debug, Default)]
pub struct ByteSink(pub Rc<RefCell<Vec<u8>>>);

impl ByteSink {
    /// A copy of what was written.
    pub fn bytes(&self) -> Vec<u8> {
        self.0.borrow().clone()
    }

    /// Forgets what was written.
    pub fn clear(&self) {
        self.0.borrow_mut().clear();
    }
}

impl FrameSink for ByteSink {
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.0.borrow_mut().extend_from_slice(bytes);
        bytes.len()
    }
}

/// A clock that moves only when stepped; a task sleeping on it wakes once it has reached
/// the deadline (when polled again).
#[derive(Clone, Debug, Default)]
pub struct SteppedClock(pub Rc<Cell<u32>>);

impl SteppedClock {
    /// Moves the clock on by `ticks` (wrapping, as the timer does).
    pub fn step(&self, ticks: u32) {
        self.0.set(self.0.get().wrapping_add(ticks));
    }
}

impl Clock for SteppedClock {
    fn now(&self) -> Ticks {
        Ticks(self.0.get())
    }
}

impl Sleep for SteppedClock {
    async fn until(&mut self, deadline: Ticks) {
        poll_fn(|_| {
            if Ticks(self.0.get()).reached(deadline) {
                Poll::Ready(())
            } else {
                Poll::Pending
            }
        })
        .await
    }
}
