//! Wiring faults between the board and the machine, as a new or rewired machine may have
//! them (none by default): a section's motor leads b and c swapped, so its field turns the
//! other way for the same duties; an encoder's sin and cos swapped, so it counts the other
//! way (its reading is `λ/4 − x`). The swap sits at the motor's and the encoder's
//! connectors: the board's phase-current sensors are on its legs, so leg b's sensor reads the
//! winding that leg b drives.

use fpc::ports::{PhaseCurrentCodes, SinCosCodes};
use fpc::units::{PerSection, PhaseDuties, Section};

/// The wiring faults of one run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Wiring {
    /// Each section's phase leads b and c swapped at the motor.
    pub swapped_phases: PerSection<bool>,
    /// Each encoder's sin and cos channels swapped (the encoder reads backwards).
    pub reversed_encoder: PerSection<bool>,
}

/// `[a, b, c]` as `[a, c, b]` when `swap`.
fn legs<T: Copy>(swap: bool, [a, b, c]: [T; 3]) -> [T; 3] {
    if swap {
        [a, c, b]
    } else {
        [a, b, c]
    }
}

impl Wiring {
    /// Whether every lead is where it belongs.
    pub fn is_correct(&self) -> bool {
        *self == Wiring::default()
    }

    /// The duties the windings of `section` receive when the board's legs carry `duties`.
    pub fn to_windings(&self, section: Section, duties: PhaseDuties) -> PhaseDuties {
        legs(*self.swapped_phases.get(section), duties)
    }

    /// What the board's leg sensors of `section` read when its windings carry `codes`.
    pub fn to_legs(&self, section: Section, codes: PhaseCurrentCodes) -> PhaseCurrentCodes {
        legs(*self.swapped_phases.get(section), codes)
    }

    /// What the board reads from the encoder of `section` when it sends `codes`.
    pub fn encoder(&self, section: Section, codes: SinCosCodes) -> SinCosCodes {
        if *self.reversed_encoder.get(section) {
            SinCosCodes {
                sin: codes.cos,
                cos: codes.sin,
            }
        } else {
            codes
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpc::units::{AdcCode, Duty};

    #[test]
    fn a_swapped_pair_exchanges_legs_b_and_c_of_its_section_only() {
        let w = Wiring {
            swapped_phases: PerSection {
                master: false,
                slave: true,
            },
            ..Wiring::default()
        };
        let d = [Duty(0), Duty::HALF, Duty(65535)];
        assert_eq!(w.to_windings(Section::Master, d), d);
        assert_eq!(
            w.to_windings(Section::Slave, d),
            [Duty(0), Duty(65535), Duty::HALF]
        );
        let codes = [AdcCode(1), AdcCode(2), AdcCode(3)];
        assert_eq!(
            w.to_legs(Section::Slave, codes),
            [AdcCode(1), AdcCode(3), AdcCode(2)]
        );
        assert!(!w.is_correct());
    }
}
