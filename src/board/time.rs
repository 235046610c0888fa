//! The time base: embassy-time (TIM2, 1 MHz ticks) behind the [`Clock`] and [`Sleep`] ports.

use embassy_time::{Duration, Instant, Timer};
use fpc::ports::{Clock, Sleep};
use fpc::units::Ticks;

/// Now, in wrapping microsecond ticks (the low 32 bits of embassy's 64-bit microseconds).
#[inline]
pub fn now_ticks() -> Ticks {
    Ticks(Instant::now().as_micros() as u32)
}

/// [`Clock`] on embassy-time.
pub struct BoardClock;

impl Clock for BoardClock {
    fn now(&self) -> Ticks {
        now_ticks()
    }
}

/// [`Sleep`] on embassy-time's timer queue.
pub struct BoardSleep;

impl Sleep for BoardSleep {
    async fn until(&mut self, deadline: Ticks) {
        // The deadline wraps every 2³² µs; embassy's instants do not. Convert through the
        // signed distance from now, which is exact while the deadline is < 35 min away.
        let now = Instant::now();
        let ahead_us = deadline.since_us(Ticks(now.as_micros() as u32));
        if ahead_us > 0 {
            Timer::at(now + Duration::from_micros(ahead_us as u64)).await;
        }
    }
}
