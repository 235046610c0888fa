//! What is simply not there since boot: the DC link not charged, the encoders or the
//! pressure sensors not connected. Until the outputs are first enabled these are states, not
//! faults (`docs/faults.md`, "Absent at boot"): nothing moves, so nothing needs braking; the
//! machine reports each part, refuses what would enable the outputs with the part named, and
//! stops refusing when the part appears. Once the outputs have been enabled, a part lost is
//! the fault it always was.

/// A part the machine needs before it may enable its outputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Part {
    /// The DC link: the power-good input (PB5) low.
    Supply = 0,
    /// An encoder: its sin/cos signal absent (the error-rate filter above half its limit).
    Encoders = 1,
    /// A chamber pressure sensor: its reading outside the valid band.
    Pressures = 2,
}

impl Part {
    /// Every part, in bit order.
    pub const ALL: [Part; 3] = [Part::Supply, Part::Encoders, Part::Pressures];

    /// Stable lower-case name (logs, the link's status).
    pub const fn name(self) -> &'static str {
        match self {
            Part::Supply => "supply",
            Part::Encoders => "encoders",
            Part::Pressures => "pressures",
        }
    }
}

/// The parts absent now, one bit each ([`Part`] as the bit number).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Absent(u8);

impl Absent {
    /// Nothing absent.
    pub const NONE: Absent = Absent(0);

    /// The set from its bits (bits above the last part ignored).
    pub const fn from_bits(bits: u8) -> Absent {
        Absent(bits & 0b111)
    }

    /// Its bits.
    pub const fn bits(self) -> u8 {
        self.0
    }

    /// `part` marked absent or present.
    pub fn set(&mut self, part: Part, absent: bool) {
        let bit = 1 << part as u8;
        if absent {
            self.0 |= bit;
        } else {
            self.0 &= !bit;
        }
    }

    /// Whether `part` is absent.
    pub const fn contains(self, part: Part) -> bool {
        self.0 & (1 << part as u8) != 0
    }

    /// Whether every part is there.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The first absent part (in [`Part::ALL`]'s order), if any.
    pub fn first(self) -> Option<Part> {
        Part::ALL.into_iter().find(|p| self.contains(*p))
    }

    /// The absent parts' names, comma-separated ("none" when every part is there).
    pub const fn names(self) -> &'static str {
        match self.0 & 0b111 {
            0 => "none",
            1 => "supply",
            2 => "encoders",
            3 => "supply, encoders",
            4 => "pressures",
            5 => "supply, pressures",
            6 => "encoders, pressures",
            _ => "supply, encoders, pressures",
        }
    }

    /// The absent parts, in bit order.
    pub fn iter(self) -> impl Iterator<Item = Part> {
        Part::ALL.into_iter().filter(move |p| self.contains(*p))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_set_and_clear_independently() {
        let mut a = Absent::NONE;
        assert!(a.is_empty() && a.first().is_none());
        a.set(Part::Pressures, true);
        a.set(Part::Supply, true);
        assert_eq!(
            a.iter().collect::<Vec<_>>(),
            [Part::Supply, Part::Pressures]
        );
        a.set(Part::Supply, false);
        assert_eq!(a.first(), Some(Part::Pressures));
        assert_eq!(Absent::from_bits(a.bits()), a);
        assert_eq!(Absent::from_bits(0xFF).bits(), 0b111);
        for bits in 0..8 {
            let a = Absent::from_bits(bits);
            let names: Vec<_> = a.iter().map(Part::name).collect();
            let want = if names.is_empty() {
                "none".to_string()
            } else {
                names.join(", ")
            };
            assert_eq!(a.names(), want);
        }
    }
}
