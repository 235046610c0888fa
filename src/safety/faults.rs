//! Faults: one enum with stable numbers, the reaction each asks for, and the latched fault
//! set.
//!
//! Numbers are part of the telemetry and run-log contract (`fault` column): never reuse or
//! renumber. Each variant's doc line is written for the operator: what it means and the fix.
//! Faults latch; [`FaultSet::clear`] is only called on an explicit clear command once the
//! cause is gone (the controller checks that).

use crate::units::{PerSection, Section};

/// A fault condition. `0` is reserved for "no fault" in logs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
#[repr(u8)]
pub enum Fault {
    /// Sin/cos amplitude out of [0.7, 1.3] of nominal too often: check the encoder cable and
    /// the read-head gap, then re-home.
    EncoderSignal = 1,
    /// Master and slave encoders disagree by more than the limit: check both read heads.
    EncoderMismatch = 2,
    /// A pressure sensor reads open or shorted: check its wiring and supply.
    PressureSensor = 3,
    /// A chamber pressure does not follow the volume change: sensor stuck or port leaking.
    PressurePlausibility = 4,
    /// Position or force error above its limit for longer than the filter time: check for an
    /// obstruction, a lost section or wrong mass/friction parameters.
    FollowingError = 5,
    /// One motor section delivers no force: check its drive stage and phase wiring.
    SectionFault = 6,
    /// Phase current above the hardware limit: check for a short and the current-loop gains.
    Overcurrent = 7,
    /// Speed above 1.2 × the configured limit: check the trajectory and the load.
    Overspeed = 8,
    /// The piston could not be stopped before the clearance limit: review speed and limits.
    BrakingEnvelope = 9,
    /// The rotation is not where the linear phase needs it (ports untimed): check the servo.
    RotationSync = 10,
    /// The control step overran its 50 µs period: reduce the computational load.
    Deadline = 11,
    /// The MCU was reset by the independent watchdog: a task hung; read the logs.
    WatchdogReset = 12,
    /// Homing found no end stop within the search distance: check the mechanics.
    HomingFailed = 13,
    /// The stored configuration is invalid: reload a valid parameter set.
    ConfigInvalid = 14,
    /// The drive's supply was lost (the DC link fell below the power-good threshold): the
    /// piston was braked on the link's energy; check the mains, its fuses and contactor.
    SupplyLoss = 15,
}

impl Fault {
    /// Every fault, in number order.
    pub const ALL: [Fault; 15] = [
        Fault::EncoderSignal,
        Fault::EncoderMismatch,
        Fault::PressureSensor,
        Fault::PressurePlausibility,
        Fault::FollowingError,
        Fault::SectionFault,
        Fault::Overcurrent,
        Fault::Overspeed,
        Fault::BrakingEnvelope,
        Fault::RotationSync,
        Fault::Deadline,
        Fault::WatchdogReset,
        Fault::HomingFailed,
        Fault::ConfigInvalid,
        Fault::SupplyLoss,
    ];

    /// Stable snake_case name (run logs, JSON, command line).
    pub const fn name(self) -> &'static str {
        match self {
            Fault::EncoderSignal => "encoder_signal",
            Fault::EncoderMismatch => "encoder_mismatch",
            Fault::PressureSensor => "pressure_sensor",
            Fault::PressurePlausibility => "pressure_plausibility",
            Fault::FollowingError => "following_error",
            Fault::SectionFault => "section_fault",
            Fault::Overcurrent => "overcurrent",
            Fault::Overspeed => "overspeed",
            Fault::BrakingEnvelope => "braking_envelope",
            Fault::RotationSync => "rotation_sync",
            Fault::Deadline => "deadline",
            Fault::WatchdogReset => "watchdog_reset",
            Fault::HomingFailed => "homing_failed",
            Fault::ConfigInvalid => "config_invalid",
            Fault::SupplyLoss => "supply_loss",
        }
    }

    /// The fault with number `code`, if any.
    pub fn from_code(code: u8) -> Option<Fault> {
        Fault::ALL.iter().copied().find(|f| *f as u8 == code)
    }

    /// The reaction this fault asks for (`docs/faults.md`: SS1 while the position is still
    /// trustworthy, STO when it is not, and the drive's own reactions built on them).
    ///
    /// For the encoder faults this is the reaction when no encoder can be trusted; a
    /// detector that names the encoder at fault knows more, and its [`Trip`] says what
    /// follows: the other encoder stands in, the named one's section is dropped, SS1 on the
    /// other section ([`Trip::encoder_lost`], [`Trip::judged`]).
    pub const fn reaction(self) -> Reaction {
        match self {
            Fault::EncoderSignal => Reaction::BrakeWithoutPosition,
            Fault::EncoderMismatch | Fault::ConfigInvalid => Reaction::Sto,
            Fault::Overcurrent => Reaction::DropSection,
            Fault::WatchdogReset => Reaction::BrakeAfterReset,
            Fault::PressureSensor
            | Fault::PressurePlausibility
            | Fault::FollowingError
            | Fault::SectionFault
            | Fault::Overspeed
            | Fault::BrakingEnvelope
            | Fault::RotationSync
            | Fault::Deadline
            | Fault::HomingFailed => Reaction::Ss1,
            // The brake that needs the least of the link's energy (`docs/faults.md` #24):
            // an SS1 stop held against a sealed chamber runs the link flat in 80 ms.
            Fault::SupplyLoss => Reaction::BrakeWithoutPosition,
        }
    }
}

/// What the machine does when a fault latches: the stop functions of IEC 61800-5-2 (SS1,
/// STO) and the drive's own reactions built on them. [`Fault::reaction`] chooses one per
/// fault; the control step carries each out (`control/step/safe_state.rs`), and every one
/// ends with the outputs off and the fault latched until an explicit clear.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Reaction {
    /// Safe stop 1: a controlled stop on the braking envelope, held until holding the piston
    /// needs no force, then the outputs off. Needs the position (homed, trusted): without
    /// it, STO.
    Ss1,
    /// Safe torque off: the outputs off at once (the position cannot be trusted).
    Sto,
    /// The section with the larger phase current (the [`Trip`] names it) taken out of the
    /// allocation, then SS1 on the other (either section alone can stop the piston).
    DropSection,
    /// No position left (both encoders lost), or no supply (the DC link's energy must last
    /// until the piston is at rest): STO while the winding currents decay, then the windings
    /// short-circuited and the rotation turned to seal the chamber ahead, whose gas takes the
    /// piston's energy (`docs/faults.md` #22, #24).
    BrakeWithoutPosition,
    /// After a watchdog reset: the outputs off until the velocity estimate is valid, then a
    /// controlled stop in the encoders' own frame, the outputs off once holding needs no
    /// force; where the heads are is unknown until homing (`docs/faults.md` #12).
    BrakeAfterReset,
}

impl Reaction {
    /// Whether the reaction stops the piston under control (it needs a position it can
    /// trust), rather than switching the outputs off at once.
    pub const fn position_trusted(self) -> bool {
        matches!(
            self,
            Reaction::Ss1 | Reaction::DropSection | Reaction::BrakeAfterReset
        )
    }
}

/// A fault found, and what the machine does about it, as data: the reaction, and the sections
/// taken out of service. The detectors make it (the supervisor's verdict, the sense stage's
/// encoder checks); the control step's safe state carries it out, the sections first.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Trip {
    /// The fault latched.
    pub fault: Fault,
    /// What the machine does.
    pub reaction: Reaction,
    /// The sections taken out of the allocation (lost, or the hotter after an overcurrent);
    /// the others stop the piston.
    pub drop: PerSection<bool>,
}

impl Trip {
    /// `fault` with the reaction its kind asks for ([`Fault::reaction`]), no section named.
    pub const fn of(fault: Fault) -> Trip {
        Trip {
            fault,
            reaction: fault.reaction(),
            drop: PerSection {
                master: false,
                slave: false,
            },
        }
    }

    /// The same trip with `section` taken out of service as well.
    pub const fn dropping(mut self, section: Section) -> Trip {
        match section {
            Section::Master => self.drop.master = true,
            Section::Slave => self.drop.slave = true,
        }
        self
    }

    /// The encoder of `section` lost while the other still gives the position: the other
    /// stands in, the lost one's section (its commutation angle gone) is dropped, and the
    /// other section stops the piston (SS1) — unless the two disagreed before
    /// (`mismatch_latched`): then neither is trusted, STO.
    pub const fn encoder_lost(section: Section, mismatch_latched: bool) -> Trip {
        Trip {
            reaction: if mismatch_latched {
                Reaction::Sto
            } else {
                Reaction::Ss1
            },
            ..Trip::of(Fault::EncoderSignal)
        }
        .dropping(section)
    }

    /// An [`Fault::EncoderMismatch`] trip once the readings are judged: with a `suspect`
    /// (its readings show it is the wrong one) it is taken out as if lost and SS1 runs on the
    /// other section (the position carries at most the disagreement); with none, nothing
    /// says which one is right: STO, the table's reaction.
    pub const fn judged(self, suspect: Option<Section>) -> Trip {
        match suspect {
            Some(section) => Trip {
                reaction: Reaction::Ss1,
                ..self
            }
            .dropping(section),
            None => self,
        }
    }
}

/// Why the MCU last started, as the board reads it from its reset flags.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ResetCause {
    /// Power-on or brown-out: a normal start.
    PowerOn,
    /// The reset pin: a normal start.
    External,
    /// A software reset (SCB AIRCR.SYSRESETREQ, RCC_CSR.SFTRSTF; the pin flag is set too, as
    /// the reset drives NRST): a normal start. The fault path ends in one; its cause, kept
    /// across the reset, is logged separately.
    Software,
    /// The independent watchdog: a task hung. The machine starts with
    /// [`Fault::WatchdogReset`] latched and its outputs off.
    Watchdog,
}

/// The latched set of faults, in latch order for reporting.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct FaultSet {
    bits: u32,
    /// First fault latched (the cause; later ones are often consequences).
    first: Option<Fault>,
}

impl FaultSet {
    /// No fault.
    pub const fn new() -> Self {
        FaultSet {
            bits: 0,
            first: None,
        }
    }

    /// Latches `fault`; returns true if it was not latched before.
    pub fn latch(&mut self, fault: Fault) -> bool {
        let bit = 1u32 << (fault as u8);
        let new = self.bits & bit == 0;
        self.bits |= bit;
        if self.first.is_none() {
            self.first = Some(fault);
        }
        new
    }

    /// Whether `fault` is latched.
    pub fn contains(&self, fault: Fault) -> bool {
        self.bits & (1u32 << (fault as u8)) != 0
    }

    /// Whether no fault is latched.
    pub fn is_empty(&self) -> bool {
        self.bits == 0
    }

    /// The first latched fault (its code goes into the run log).
    pub fn first(&self) -> Option<Fault> {
        self.first
    }

    /// Latched faults in number order.
    pub fn iter(&self) -> impl Iterator<Item = Fault> + '_ {
        Fault::ALL.iter().copied().filter(|f| self.contains(*f))
    }

    /// Clears every fault (explicit operator command only).
    pub fn clear(&mut self) {
        *self = FaultSet::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_stable_and_unique() {
        for (i, f) in Fault::ALL.iter().enumerate() {
            assert_eq!(*f as u8 as usize, i + 1);
            assert_eq!(Fault::from_code(*f as u8), Some(*f));
        }
        assert_eq!(Fault::from_code(0), None);
    }

    #[test]
    fn the_reaction_is_a_controlled_stop_exactly_where_the_position_is_trusted() {
        // `docs/faults.md`: SS1 while the position is still trustworthy, STO when it is not. The
        // faults that take it away are the encoders' and a configuration that cannot be
        // believed; every other fault stops the piston under control but one: a supply loss
        // is braked without the position too, because SS1's hold against a sealed chamber
        // would run the DC link flat (docs/firmware.md, "A supply loss in motion").
        for f in Fault::ALL {
            let without_position = matches!(
                f,
                Fault::EncoderSignal
                    | Fault::EncoderMismatch
                    | Fault::ConfigInvalid
                    | Fault::SupplyLoss
            );
            assert_eq!(
                f.reaction().position_trusted(),
                !without_position,
                "{}",
                f.name()
            );
        }
        assert_eq!(Fault::Overcurrent.reaction(), Reaction::DropSection);
        assert_eq!(
            Fault::EncoderSignal.reaction(),
            Reaction::BrakeWithoutPosition
        );
        assert_eq!(Fault::WatchdogReset.reaction(), Reaction::BrakeAfterReset);
    }

    #[test]
    fn a_trip_names_the_section_it_takes_out() {
        let t = Trip::encoder_lost(Section::Slave, false);
        assert_eq!((t.fault, t.reaction), (Fault::EncoderSignal, Reaction::Ss1));
        assert_eq!((t.drop.master, t.drop.slave), (false, true));
        // The encoders disagreed before: neither is trusted.
        assert_eq!(
            Trip::encoder_lost(Section::Master, true).reaction,
            Reaction::Sto
        );
        let mismatch = Trip::of(Fault::EncoderMismatch);
        assert_eq!(mismatch.reaction, Reaction::Sto);
        let t = mismatch.judged(Some(Section::Master));
        assert_eq!((t.reaction, t.drop.master), (Reaction::Ss1, true));
        assert_eq!(mismatch.judged(None), mismatch);
        let t = Trip::of(Fault::Overcurrent).dropping(Section::Master);
        assert_eq!(
            (t.reaction, t.drop.master, t.drop.slave),
            (Reaction::DropSection, true, false)
        );
    }

    #[test]
    fn faults_latch_until_cleared() {
        let mut s = FaultSet::new();
        assert!(s.latch(Fault::Deadline));
        assert!(!s.latch(Fault::Deadline));
        s.latch(Fault::EncoderSignal);
        assert_eq!(s.first(), Some(Fault::Deadline));
        assert_eq!(s.iter().count(), 2);
        s.clear();
        assert!(s.is_empty());
    }
}
