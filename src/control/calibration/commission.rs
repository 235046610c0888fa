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

use super::{CalibrationError, Demand, Forced, Measurements, Outcome};
use crate::angle::turns;
use crate::control::config::ControlConfig;
use crate::physics::motor::Dq;
use crate::real::clamp_f32;
use crate::units::{PerSection, Section};

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

/// The commissioning of both sections, one after the other.
#[derive(Clone, Debug)]
pub(super) struct Commissioner {
    section: Section,
    /// Program counter within the section's sequence, and cycles spent in its step.
    pc: u32,
    elapsed: u32,
    /// The forced angle where the step started, and now; the current (fraction of full).
    from_angle: u32,
    angle: u32,
    level: f32,
    /// Sum of both encoders' positions over the averaging window, m.
    window: [f32; 2],
    window_n: u32,
    /// Both encoders' mean positions at rest: before, between and after the turns, m.
    rest: [[f32; 2]; 3],
    /// Forward displacements (master encoder, slave encoder) of each section, m.
    forward: [[f32; 2]; 2],
}

/// A step of a section's program.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Step {
    /// The current ramps up (to 1) or down (to 0).
    Ramp { to: f32 },
    /// Wait (the first pull).
    Settle,
    /// The angle turns by this many periods from where it is.
    Turn { periods: f32 },
    /// Wait, then average both encoders into `rest[k]`.
    Measure { k: usize },
    /// This section is done.
    Next,
}

impl Commissioner {
    pub(super) fn new() -> Self {
        Commissioner {
            section: Section::Master,
            pc: 0,
            elapsed: 0,
            from_angle: 0,
            angle: 0,
            level: 0.0,
            window: [0.0; 2],
            window_n: 0,
            rest: [[0.0; 2]; 3],
            forward: [[0.0; 2]; 2],
        }
    }

    /// The distance the piston may travel either way from where it starts, periods: the
    /// first pull (half a period), the approach and the turn.
    pub(super) fn reach_periods(config: &ControlConfig) -> f32 {
        let c = &config.calibration;
        0.5 + c.align_approach_periods + c.commission_periods
    }

    fn program(&self, config: &ControlConfig) -> Step {
        let c = &config.calibration;
        let n = c.commission_periods;
        match self.pc {
            0 => Step::Ramp { to: 1.0 },
            1 => Step::Settle,
            2 => Step::Turn {
                periods: c.align_approach_periods,
            },
            3 => Step::Measure { k: 0 },
            4 => Step::Turn { periods: n },
            5 => Step::Measure { k: 1 },
            6 => Step::Turn { periods: -n },
            7 => Step::Measure { k: 2 },
            8 => Step::Ramp { to: 0.0 },
            _ => Step::Next,
        }
    }

    /// One cycle of the routine. Kept out of line (and so in flash, outside `.ccmram`): it
    /// runs only at commissioning, and the 20 kHz path's code in CCM SRAM has no room for it.
    #[inline(never)]
    pub(super) fn step(&mut self, config: &ControlConfig, m: &Measurements) -> Demand {
        let c = &config.calibration;
        let t = self.elapsed as f32 * config.sample_time_s;
        if self.pc == 0 && self.elapsed == 0 {
            // Start where the present offset puts the magnets (the smallest first pull).
            let believed = m.angle.get(self.section);
            self.angle = believed.wrapping_add(*config.angle_offset.get(self.section));
            self.from_angle = self.angle;
        }
        self.elapsed += 1;
        let finished = match self.program(config) {
            Step::Ramp { to } => {
                let f = clamp_f32(t / c.align_ramp_s, 0.0, 1.0);
                self.level = (1.0 - to) + (2.0 * to - 1.0) * f;
                f >= 1.0
            }
            Step::Settle => t >= c.commission_first_settle_s,
            Step::Turn { periods } => {
                let duration = periods.abs() / c.align_rate_periods_per_s;
                let f = if duration > 0.0 {
                    clamp_f32(t / duration, 0.0, 1.0)
                } else {
                    1.0
                };
                self.angle = self.from_angle.wrapping_add(turns(periods * f));
                f >= 1.0
            }
            Step::Measure { k } => {
                if t > c.align_settle_s {
                    self.window[0] += m.position_m;
                    self.window[1] += m.slave_position_m;
                    self.window_n += 1;
                }
                let done = t >= c.align_settle_s + c.align_average_s;
                if done {
                    let n = self.window_n.max(1) as f32;
                    if let Some(rest) = self.rest.get_mut(k) {
                        *rest = [self.window[0] / n, self.window[1] / n];
                    }
                    (self.window, self.window_n) = ([0.0; 2], 0);
                }
                done
            }
            Step::Next => return self.next_section(config),
        };
        if finished {
            self.pc += 1;
            self.elapsed = 0;
            self.from_angle = self.angle;
        }
        let vector = Forced {
            angle: self.angle,
            current: Dq {
                d: self.level * c.align_current_a,
                q: 0.0,
            },
        };
        let mut demand = PerSection::default();
        *demand.get_mut(self.section) = Some(vector);
        Demand::Forced(demand)
    }

    /// The section's turns checked and kept; the next section started, or the findings.
    fn next_section(&mut self, config: &ControlConfig) -> Demand {
        let half = 0.5 * config.calibration.commission_periods * config.motor.electrical_period_m;
        let [before, between, after] = self.rest;
        let mut forward = [0.0; 2];
        for (f, ((b, w), a)) in forward
            .iter_mut()
            .zip(before.iter().zip(between).zip(after))
        {
            *f = w - b;
            let back = a - w;
            // Moved at least half the turn each way, and back the other way.
            let moved = f.abs() >= half && back.abs() >= half && (*f > 0.0) != (back > 0.0);
            if !moved {
                return Demand::Done(Err(CalibrationError::NoMotion {
                    section: self.section,
                }));
            }
        }
        let slot = match self.section {
            Section::Master => 0,
            Section::Slave => 1,
        };
        if let Some(row) = self.forward.get_mut(slot) {
            *row = forward;
        }
        if self.section == Section::Master {
            *self = Commissioner {
                section: Section::Slave,
                forward: self.forward,
                ..Commissioner::new()
            };
            return Demand::Forced(PerSection::default());
        }
        Demand::Done(self.findings(config))
    }

    fn findings(&self, config: &ControlConfig) -> Result<Outcome, CalibrationError> {
        let c = &config.calibration;
        let sign = self.forward.map(|row| row.map(|d| d > 0.0));
        let (reversed, ambiguous) = explain(sign).ok_or(CalibrationError::EncoderSigns)?;
        let lambda = config.motor.electrical_period_m;
        let pitch = |row: [f32; 2]| (row[0].abs() + row[1].abs()) * 0.5 / c.commission_periods;
        let [master, slave] = self.forward.map(pitch);
        let ok = |p: f32| (p / lambda - 1.0).abs() <= c.commission_pitch_tolerance;
        Ok(Outcome::Commission(Commissioning {
            reversed,
            ambiguous,
            pitch_m: PerSection { master, slave },
            pitch_ok: PerSection {
                master: ok(master),
                slave: ok(slave),
            },
        }))
    }
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
