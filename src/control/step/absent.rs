//! Parts absent since boot ([`crate::safety::absent`]): watched while the outputs have never
//! been enabled, and the moment they are.

use super::sense::Sensed;
use super::ControlStep;
use crate::safety::absent::{Absent, Part};
use crate::safety::faults::Fault;

/// Above this speed with the encoders present, m/s, a piston found moving before the outputs
/// were ever enabled means the machine is live (a reset in motion): parts lost are faults.
const MOVING_AT_BOOT_MPS: f32 = 0.05;

impl ControlStep {
    /// Before the outputs are first enabled: which parts are absent now
    /// ([`crate::safety::absent`]). Encoders back after being absent have their filters
    /// reset (nothing was homed: no zero to lose). A piston found moving means the machine
    /// is live after all (a reset in motion): from then on a part lost is its fault.
    #[cold]
    #[inline(never)]
    pub(super) fn watch_absent(&mut self, s: &Sensed) {
        let encoders_absent = self.sensing.encoders_absent();
        if !encoders_absent && self.sensing.encoder_trouble(&s.master, &s.slave) {
            self.sensing.clear_faults(true);
        }
        // The velocity is judged once the differentiator's window holds only samples of
        // encoders present (twice its length: no step from a flat input left in it).
        let present = &mut self.supervision.encoders_present_cycles;
        *present = if encoders_absent {
            0
        } else {
            present.saturating_add(1)
        };
        let settled = usize::from(*present) >= 2 * self.config.sg_window;
        // A bench operation moves the piston itself (a phase's current pulls it; a turn of
        // the rotation breaks the seal's grip and the cogging moves it).
        #[cfg(feature = "bench")]
        let settled = settled && !self.supervision.bench_since_boot;
        if settled && s.derivatives.velocity_mps.abs() > MOVING_AT_BOOT_MPS {
            self.supervision.energised = true;
            self.publish.absent = Absent::NONE;
            if !self.supervision.supply_good {
                self.supply_lost();
            }
            return;
        }
        let mut absent = Absent::NONE;
        absent.set(Part::Supply, !self.supervision.supply_good);
        absent.set(Part::Encoders, encoders_absent);
        absent.set(Part::Pressures, self.sensing.pressures.bad_cycles > 0);
        self.publish.absent = absent;
    }

    /// Whether `fault` only reports a part absent since boot (no reaction: nothing moves).
    pub(super) fn absent_at_boot(&self, fault: Fault) -> bool {
        !self.supervision.energised
            && matches!(
                fault,
                Fault::SupplyLoss | Fault::EncoderSignal | Fault::PressureSensor
            )
    }

    /// The outputs are about to be enabled: from now on a part lost is its fault.
    pub(super) fn energise(&mut self) {
        self.supervision.energised = true;
        self.publish.absent = Absent::NONE;
    }
}
