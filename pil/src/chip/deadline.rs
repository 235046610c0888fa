//! The control period against its true deadline: the duties computed from a sample must be in
//! TIM1/TIM8's compare registers before the update event that follows the sample, or they
//! go into force one period late (the compares are preloaded, OCxPE: RM0440's advanced-control
//! timers, "PWM mode": the preload register is transferred to the shadow register at each
//! update event).
//!
//! A sample opens when the ADC burst ends (the regular group's last conversion carried by
//! DMA, or the injected group's if there is no regular one): the firmware's interrupt is
//! pended from then on, so the latency to its entry (a masked interrupt, another handler
//! running) counts against the deadline. Each write of CCR1–CCR3 of TIM1 or TIM8 by the
//! control executor's interrupt (UART5, which runs the control step: the sample's duties;
//! the set-up's writes in thread mode are no sample's) while the sample is open is timed at
//! the end of the block that makes it (the emulator advances time a block at a time: an
//! upper bound). The sample closes at the next burst's end. If the control executor's
//! interrupt is still active then, the step overran its period: the compare writes it makes
//! before it returns are that sample's, each a missed update (a hung step that writes
//! nothing more misses none: the watchdog's case).
//!
//! A write after its own timer's update event since the sample is a missed update (the value
//! applies a period late, as on the chip); the deadline is the time from the burst's end to
//! TIM1's first update after it (TIM8 counts a few clocks behind it).

use super::*;

/// Compare registers of the bridges' phases (CCR1–CCR3; CCR4 of TIM1 is the ADC trigger).
const PHASE_CCRS: std::ops::Range<u32> = timers::reg::CCR1..timers::reg::CCR1 + 12;

/// One sample's timing against its update event.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SampleTiming {
    /// When the sample's burst ended, time units.
    pub end: u64,
    /// SYSCLK cycles from the burst's end to TIM1's next update event (`None`: the sample
    /// closed before one).
    pub deadline_cycles: Option<u64>,
    /// SYSCLK cycles from the burst's end to the last compare write of the sample (`None`: no
    /// compare was written, e.g. outputs off).
    pub write_cycles: Option<u64>,
    /// Some compare was written after its timer's update event: it applied a period late.
    pub missed: bool,
}

/// The sample in progress.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct OpenSample {
    /// When the burst ended, time units.
    end: u64,
    /// TIM1's first update event after it, time units.
    tim1_update: Option<u64>,
    /// Update events of TIM1 and TIM8 since it.
    updates: [u32; 2],
    /// The last compare write, time units.
    last_write: Option<u64>,
    missed: bool,
}

impl Soc {
    /// The ADC burst ended at `end` (time units; the event's instant, which the emulator
    /// handles at the first block boundary after it): the previous sample closes, a new one
    /// opens.
    pub(super) fn burst_ended(&mut self, end: u64) {
        if self.nvic.active[nvic::irq(irqn::UART5)] && self.overrun.is_none() {
            // The control step still runs as the next burst ends: the duties it writes
            // from now on, until its interrupt returns, are that sample's, past its update.
            self.overrun = self.sample.map(|s| s.end);
        }
        self.close_sample();
        self.sample = Some(OpenSample {
            end,
            ..OpenSample::default()
        });
    }

    /// Closes the open sample, recording it while [`Soc::recording`].
    fn close_sample(&mut self) {
        let Some(s) = self.sample.take() else {
            return;
        };
        if self.recording {
            let cycles =
                |t: u64| (t.saturating_sub(s.end) as f64 / self.units_per_cycle).round() as u64;
            self.samples.push(SampleTiming {
                end: s.end,
                deadline_cycles: s.tim1_update.map(cycles),
                write_cycles: s.last_write.map(cycles),
                missed: s.missed,
            });
        }
    }

    /// Timer `t` (0: TIM1, 1: TIM8) had an update event at `at` (time units).
    pub(super) fn timer_updated(&mut self, t: usize, at: u64) {
        if let Some(s) = self.sample.as_mut() {
            s.updates[t] += 1;
            if t == 0 && s.tim1_update.is_none() {
                s.tim1_update = Some(at);
            }
        }
    }

    /// The CPU wrote register `off` of timer `t` (0: TIM1, 1: TIM8); only the control
    /// executor's writes of the phases' compares are timed.
    pub(super) fn timer_written(&mut self, t: usize, off: u32) {
        if !PHASE_CCRS.contains(&off) || self.ipsr != nvic::irq(irqn::UART5) {
            return;
        }
        let now = self.time;
        if let Some(end) = self.overrun {
            if self.recording {
                let cycles = (now.saturating_sub(end) as f64 / self.units_per_cycle).round();
                self.samples.push(SampleTiming {
                    end,
                    deadline_cycles: None,
                    write_cycles: Some(cycles as u64),
                    missed: true,
                });
            }
            return;
        }
        if let Some(s) = self.sample.as_mut() {
            s.last_write = Some(now);
            s.missed |= s.updates[t] > 0;
        }
    }

    /// A reset: the sample in progress is dropped (its writes never come).
    pub(super) fn sample_dropped(&mut self) {
        self.sample = None;
        self.overrun = None;
    }

    /// The control executor's interrupt returned: a step that overran has ended.
    pub(super) fn control_returned(&mut self) {
        self.overrun = None;
    }
}

/// The samples' figures, as `fpc-pil` reports them per scenario.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct DeadlineFigures {
    /// Samples recorded.
    pub timed_samples: usize,
    /// The shortest deadline of them, SYSCLK cycles from the burst's end to the update event.
    pub deadline_cycles: u64,
    /// The latest last compare write of them, SYSCLK cycles from the burst's end.
    pub worst_cycle_cycles: u64,
    /// The mean of the last compare writes, cycles (over the samples that wrote).
    pub mean_cycle_cycles: f64,
    /// Samples whose compare writes applied a period late.
    pub missed_updates: usize,
}

impl DeadlineFigures {
    /// The figures of `samples`.
    pub fn of(samples: &[SampleTiming]) -> DeadlineFigures {
        let writes: Vec<u64> = samples.iter().filter_map(|s| s.write_cycles).collect();
        DeadlineFigures {
            timed_samples: samples.len(),
            deadline_cycles: samples
                .iter()
                .filter_map(|s| s.deadline_cycles)
                .min()
                .unwrap_or(0),
            worst_cycle_cycles: writes.iter().copied().max().unwrap_or(0),
            mean_cycle_cycles: writes.iter().sum::<u64>() as f64 / writes.len().max(1) as f64,
            missed_updates: samples.iter().filter(|s| s.missed).count(),
        }
    }
}

impl std::fmt::Display for DeadlineFigures {
    /// The figures in words, as `fpc-pil` and the PIL's tests print them.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "last compare write {:.0} cycles after the burst's end mean, {} worst, of a \
             deadline of {} ({:.0} %); {} of {} samples missed their update",
            self.mean_cycle_cycles,
            self.worst_cycle_cycles,
            self.deadline_cycles,
            100.0 * self.worst_cycle_cycles as f64 / self.deadline_cycles.max(1) as f64,
            self.missed_updates,
            self.timed_samples,
        )
    }
}
