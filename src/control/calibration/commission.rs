//! Commissioning of the linear motor's wiring: phase order, encoder direction and pitch.
//!
//! One section at a time carries a current vector at a forced angle (the alignment's
//! current, rate and waits), approached from below, which then turns `commission_periods`
//! electrical periods forward and back. Both encoders' positions are averaged at rest before,
//! between and after the turns. Undamped: the alignment's damping q-current pushes along the
//! motion where a phase pair or the encoder is reversed, so only friction settles the mover
//! after the first pull (`commission_first_settle_s`).
//!
//! - **Signs.** With the right wiring a forward turn moves the piston towards +x and both
//!   encoders read it so: the sign each encoder reads for each section's turn is
//!   `P_section · E_encoder`, where `P = −1` for a swapped phase pair and `E = −1` for a
//!   reversed encoder. The four signs fix the four unknowns only up to flipping all of them,
//!   so the finding is the explanation with the fewest faults: unique for none or one fault,
//!   ambiguous for two (each pattern of two faults has a complement of two that reads the
//!   same), never guessed.
//! - **Pitch.** The forward turn's displacement is a whole number of electrical periods
//!   (the N–N pitch, two pole pitches) as both encoders scale it, compared with the
//!   configured period. The cogging force, periodic in the period, shifts both ends alike;
//!   static friction leaves each end anywhere within `±F_s/k` of where the vector pulls
//!   (0.14 mm at 20 A on the reference machine), which the tolerance covers.
//! - **Motion.** A section whose turn moved either encoder by less than half the turn, or
//!   not back, gave no usable reading ([`CalibrationError::NoMotion`]).

use crate::units::PerSection;

#[cfg(feature = "bench")]
mod machine;
#[cfg(feature = "bench")]
pub(super) use machine::Commissioner;

/// A wiring fault the commissioning tells apart: bit flags of [`Commissioning::reversed`].
pub mod wiring {
    /// The master section's phases turn the other way (a swapped phase pair).
    pub const MASTER_PHASES: u8 = 1;
    /// The slave section's phases turn the other way.
    pub const SLAVE_PHASES: u8 = 2;
    /// The master encoder counts the other way.
    pub const MASTER_ENCODER: u8 = 4;
    /// The slave encoder counts the other way.
    pub const SLAVE_ENCODER: u8 = 8;
    /// All four.
    pub const ALL: u8 = 15;
}

/// What the commissioning found (nothing is loaded into the configuration).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Commissioning {
    /// The reversed parts of the simplest wiring that explains the signs ([`wiring`] flags;
    /// 0: all in order).
    pub reversed: u8,
    /// Two faults: the complement (`wiring::ALL ^ reversed`) explains the signs as well, so
    /// which pair it is cannot be told.
    pub ambiguous: bool,
    /// Each section's forward displacement per electrical period, mean of both encoders, m.
    pub pitch_m: PerSection<f32>,
    /// Whether each section's pitch is within `commission_pitch_tolerance` of the configured
    /// electrical period.
    pub pitch_ok: PerSection<bool>,
}

/// The wiring faults (fewest first) that explain the forward signs `sign[section][encoder]`
/// (true: towards +x), and whether another set of as many explains them too. `None`: no
/// wiring does (one encoder disagrees with itself between the sections).
pub fn explain(sign: [[bool; 2]; 2]) -> Option<(u8, bool)> {
    let mut best: Option<(u8, bool)> = None;
    for faults in 0..=wiring::ALL {
        let flipped = |bit: u8| faults & bit != 0;
        let fits = sign
            .iter()
            .zip([wiring::MASTER_PHASES, wiring::SLAVE_PHASES])
            .all(|(row, phases)| {
                row.iter()
                    .zip([wiring::MASTER_ENCODER, wiring::SLAVE_ENCODER])
                    .all(|(s, enc)| *s != (flipped(phases) ^ flipped(enc)))
            });
        if !fits {
            continue;
        }
        best = match best {
            None => Some((faults, false)),
            Some((b, _)) if faults.count_ones() < b.count_ones() => Some((faults, false)),
            Some((b, _)) if faults.count_ones() == b.count_ones() => Some((b, true)),
            keep => keep,
        };
    }
    best
}

#[cfg(test)]
mod tests {
    use super::wiring::*;
    use super::*;

    /// The forward signs a wiring with `faults` gives.
    fn signs(faults: u8) -> [[bool; 2]; 2] {
        let f = |bit: u8| faults & bit != 0;
        [MASTER_PHASES, SLAVE_PHASES]
            .map(|p| [MASTER_ENCODER, SLAVE_ENCODER].map(|e| !(f(p) ^ f(e))))
    }

    #[test]
    fn no_fault_and_each_single_fault_are_found_uniquely() {
        assert_eq!(explain(signs(0)), Some((0, false)));
        for fault in [MASTER_PHASES, SLAVE_PHASES, MASTER_ENCODER, SLAVE_ENCODER] {
            assert_eq!(explain(signs(fault)), Some((fault, false)), "{fault}");
        }
    }

    #[test]
    fn two_faults_are_ambiguous_with_their_complement() {
        for a in 0..4 {
            for b in a + 1..4 {
                let pair = (1u8 << a) | (1 << b);
                let (found, ambiguous) = explain(signs(pair)).unwrap();
                assert!(ambiguous, "{pair}");
                assert!(found == pair || found == ALL ^ pair, "{pair}: {found}");
            }
        }
        // Three faults read as the one they leave out.
        assert_eq!(
            explain(signs(ALL ^ SLAVE_ENCODER)),
            Some((SLAVE_ENCODER, false))
        );
    }

    #[test]
    fn signs_no_wiring_gives_are_refused() {
        assert_eq!(explain([[true, true], [true, false]]), None);
        assert_eq!(explain([[false, true], [true, true]]), None);
    }
}
