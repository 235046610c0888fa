//! The supervise stage: the machine's limits checked against each cycle's measurements, the
//! host's heartbeat timed, the supply watched. What it finds is a [`Trip`] (the fault, its
//! reaction, the sections to drop) for the safe state to carry out.

use crate::safety::faults::Trip;
use crate::safety::supervisor::{Observation, Supervisor, SupervisorConfig};

/// The supervision's state: the per-cycle checks, the host's heartbeat and the power-good
/// input as last read.
#[derive(Clone, Debug)]
#[repr(C)]
pub(super) struct Supervision {
    /// Time since the last heartbeat, s; `None` until the host sends one (and after it was
    /// lost, until it is back).
    pub heartbeat_s: Option<f32>,
    /// Time without a heartbeat after which the piston parks, s (a host's `SetParameter`).
    pub heartbeat_timeout_s: f32,
    /// The power-good input as the supervision task last read it.
    pub supply_good: bool,
    /// The outputs have been enabled since boot (or may be live: a watchdog reset, a piston
    /// found moving). Until then a part absent is a state, not a fault
    /// ([`crate::safety::absent`]).
    pub energised: bool,
    /// Consecutive cycles with both encoders present, while not energised (saturating).
    pub encoders_present_cycles: u16,
    /// A bench operation has run since boot: a piston found moving is its doing, not a
    /// reset in motion (the bench build's).
    #[cfg(feature = "bench")]
    pub bench_since_boot: bool,
    pub supervisor: Supervisor,
}

impl Supervision {
    pub(super) fn new(heartbeat_timeout_s: f32) -> Self {
        Supervision {
            heartbeat_s: None,
            heartbeat_timeout_s,
            supply_good: true,
            energised: false,
            encoders_present_cycles: 0,
            #[cfg(feature = "bench")]
            bench_since_boot: false,
            supervisor: Supervisor::new(),
        }
    }

    /// The limits checked against this cycle's `observation`: the first fault found, if any.
    #[inline(always)]
    pub(super) fn check(
        &mut self,
        c: &SupervisorConfig,
        observation: &Observation,
    ) -> Option<Trip> {
        self.supervisor.check(c, observation)
    }

    /// A heartbeat from the host: the first arms the host watchdog, every one restarts it.
    pub(super) fn heartbeat(&mut self) {
        self.heartbeat_s = Some(0.0);
    }

    /// One cycle of `dt` s on the host watchdog: true once the host has been silent for the
    /// timeout (then disarmed until the host is back: the caller parks the piston, which is
    /// not a fault).
    #[inline(always)]
    pub(super) fn host_lost(&mut self, dt: f32) -> bool {
        if let Some(elapsed) = self.heartbeat_s.as_mut() {
            *elapsed += dt;
            if *elapsed >= self.heartbeat_timeout_s {
                self.heartbeat_s = None;
                return true;
            }
        }
        false
    }

    /// What the power-good input reads now: true when it has just fallen (the supply lost).
    #[inline(always)]
    pub(super) fn supply(&mut self, good: bool) -> bool {
        let lost = !good && self.supply_good;
        self.supply_good = good;
        lost
    }
}
