//! Readiness: what the machine lacks to move, as distinct from what it lost.
//!
//! The logic supply comes up before the DC link is charged, and on the bench the drive board
//! often boots with no encoder, no pressure sensor and no bridge supply at all. A part that
//! has read absent since reset, with the outputs never switched on, is a **state**: the
//! machine waits (outputs off, MOE clear, servo at zero torque, no brake, nothing moves),
//! reports what is missing, refuses what would switch the outputs on (`Home`, `Start`,
//! `Calibrate`, the bench commands) with the reason, and stops refusing once the part reads
//! present. A part lost **after** the outputs were first switched on (or after a watchdog
//! reset, when the piston may still move) keeps its fault and that fault's reaction
//! (`docs/faults.md`).
//!
//! The stage takes values and returns values: [`Readiness::observe`] gets what the sensors
//! read this cycle ([`Presence`]) and gives what is absent ([`Absent`]); the control step
//! asks [`Readiness::energised`] before latching a loss as a fault, and [`Readiness::refusal`]
//! before a command that needs the parts.

use crate::control::command::Refusal;

/// The parts absent since reset, as bit flags (their numbers are a telemetry contract:
/// bits 3–6 of a frame's flags byte are these shifted left by 3; never renumber).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Absent(u8);

impl Absent {
    /// Nothing absent.
    pub const NONE: Absent = Absent(0);
    /// The DC link is off: the power-good input (PB5) has read low since reset.
    pub const DC_LINK: Absent = Absent(1);
    /// The master encoder gives no signal (its amplitude outside the window).
    pub const MASTER_ENCODER: Absent = Absent(2);
    /// The slave encoder gives no signal.
    pub const SLAVE_ENCODER: Absent = Absent(4);
    /// A pressure sensor reads open or shorted (0 V or the rail).
    pub const PRESSURE_SENSORS: Absent = Absent(8);
    /// Every part.
    pub const ALL: Absent = Absent(15);

    /// Each part with its stable name, in reporting order.
    pub const PARTS: [(Absent, &'static str); 4] = [
        (Absent::DC_LINK, "dc_link_off"),
        (Absent::MASTER_ENCODER, "master_encoder_absent"),
        (Absent::SLAVE_ENCODER, "slave_encoder_absent"),
        (Absent::PRESSURE_SENSORS, "pressure_sensors_absent"),
    ];

    /// The flags as a byte (bits 0–3).
    pub const fn bits(self) -> u8 {
        self.0
    }

    /// The flags of `bits` (bits above 3 are not parts: `None`).
    pub const fn from_bits(bits: u8) -> Option<Absent> {
        if bits & !Absent::ALL.0 == 0 {
            Some(Absent(bits))
        } else {
            None
        }
    }

    /// Whether every part of `other` is absent.
    pub const fn contains(self, other: Absent) -> bool {
        self.0 & other.0 == other.0 && other.0 != 0
    }

    /// Whether nothing is absent.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The union.
    pub const fn with(self, other: Absent) -> Absent {
        Absent(self.0 | other.0)
    }

    /// The names of the absent parts, in reporting order.
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        Absent::PARTS
            .into_iter()
            .filter(move |(p, _)| self.contains(*p))
            .map(|(_, n)| n)
    }

    /// The refusal that names the first absent part among `self` (none if empty).
    pub const fn refusal(self) -> Option<Refusal> {
        if self.0 & Absent::DC_LINK.0 != 0 {
            Some(Refusal::DcLinkOff)
        } else if self.0 & (Absent::MASTER_ENCODER.0 | Absent::SLAVE_ENCODER.0) != 0 {
            Some(Refusal::EncoderAbsent)
        } else if self.0 & Absent::PRESSURE_SENSORS.0 != 0 {
            Some(Refusal::PressureSensorAbsent)
        } else {
            None
        }
    }
}

/// What the sensors read in one cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Presence {
    /// The power-good input reads high (the DC link is above its threshold).
    pub dc_link: bool,
    /// The master encoder's signal is in its amplitude window (its decoder sees no cause).
    pub master_encoder: bool,
    /// The slave encoder's, likewise.
    pub slave_encoder: bool,
    /// All four pressure samples are valid (neither open nor shorted).
    pub pressure_sensors: bool,
}

impl Presence {
    /// The parts this reading says are absent.
    pub const fn absent(self) -> Absent {
        let mut bits = 0;
        if !self.dc_link {
            bits |= Absent::DC_LINK.0;
        }
        if !self.master_encoder {
            bits |= Absent::MASTER_ENCODER.0;
        }
        if !self.slave_encoder {
            bits |= Absent::SLAVE_ENCODER.0;
        }
        if !self.pressure_sensors {
            bits |= Absent::PRESSURE_SENSORS.0;
        }
        Absent(bits)
    }
}

/// Whether the machine has been energised since reset, and what it lacks while it has not.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Readiness {
    energised: bool,
    absent: Absent,
}

impl Default for Readiness {
    fn default() -> Self {
        Readiness::new()
    }
}

impl Readiness {
    /// At reset: never energised, nothing known absent yet (the first cycle's reading says).
    pub const fn new() -> Self {
        Readiness {
            energised: false,
            absent: Absent::NONE,
        }
    }

    /// The outputs were switched on (or the boot follows a watchdog reset, when the piston
    /// may still move and the brake after it switches them on): from now on a part that
    /// reads absent has been **lost**, a fault with its reaction; nothing is reported absent.
    pub fn energise(&mut self) {
        self.energised = true;
        self.absent = Absent::NONE;
    }

    /// Whether the outputs have been on since reset (a loss is then a fault).
    pub const fn energised(&self) -> bool {
        self.energised
    }

    /// One cycle's reading while never energised: the parts absent now (a part that reads
    /// present again is no longer reported). Energised, nothing is absent by definition.
    pub fn observe(&mut self, presence: Presence) -> Absent {
        if !self.energised {
            self.absent = presence.absent();
        }
        self.absent
    }

    /// What is absent now.
    pub const fn absent(&self) -> Absent {
        self.absent
    }

    /// Why a command that switches the outputs on must wait: the first absent part as a
    /// refusal (DC link, then the encoders, then the pressure sensors), or `None`.
    pub const fn refusal(&self) -> Option<Refusal> {
        self.absent.refusal()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bare() -> Presence {
        Presence {
            dc_link: false,
            master_encoder: false,
            slave_encoder: false,
            pressure_sensors: false,
        }
    }

    #[test]
    fn a_bare_board_waits_for_every_part_and_names_the_dc_link_first() {
        let mut r = Readiness::new();
        assert_eq!(r.observe(bare()), Absent::ALL);
        assert_eq!(r.refusal(), Some(Refusal::DcLinkOff));
        assert_eq!(
            r.absent().names().collect::<Vec<_>>(),
            [
                "dc_link_off",
                "master_encoder_absent",
                "slave_encoder_absent",
                "pressure_sensors_absent"
            ]
        );
        // The link comes up: the encoders are named next, then the pressures.
        let p = Presence {
            dc_link: true,
            ..bare()
        };
        r.observe(p);
        assert_eq!(r.refusal(), Some(Refusal::EncoderAbsent));
        r.observe(Presence {
            master_encoder: true,
            slave_encoder: true,
            ..p
        });
        assert_eq!(r.refusal(), Some(Refusal::PressureSensorAbsent));
        r.observe(Presence {
            dc_link: true,
            master_encoder: true,
            slave_encoder: true,
            pressure_sensors: true,
        });
        assert!(r.absent().is_empty());
        assert_eq!(r.refusal(), None);
    }

    #[test]
    fn once_energised_a_missing_part_is_a_loss_not_an_absence() {
        let mut r = Readiness::new();
        r.observe(bare());
        r.energise();
        assert!(r.energised());
        assert_eq!(r.observe(bare()), Absent::NONE);
        assert_eq!(r.refusal(), None);
    }

    #[test]
    fn the_flags_round_trip_and_refuse_unknown_bits() {
        for bits in 0..16u8 {
            assert_eq!(Absent::from_bits(bits).map(Absent::bits), Some(bits));
        }
        assert_eq!(Absent::from_bits(16), None);
        assert!(!Absent::NONE.contains(Absent::NONE));
        assert!(Absent::ALL.contains(Absent::SLAVE_ENCODER));
    }
}
