//! Electrical-angle alignment: a current vector at forced angles, approached from both
//! sides, tells where each section's encoder angle sits against its magnets.

use super::{within, CalibrationError, Demand, Forced, Measurements, Outcome, TURN};
use crate::angle::turns;
use crate::control::config::{CalibrationConfig, ControlConfig};
use crate::physics::motor::Dq;
use crate::real::{clamp_f32, max_f32, min_f32};
use crate::units::{PerSection, Section};

/// What the forced vector of the section being aligned does now.
#[derive(Clone, Copy, Debug, PartialEq)]
enum AlignStep {
    /// The current ramps up (to 1) or down (to 0) at the present angle.
    Ramp { to: f32 },
    /// Wait (the first pull).
    Settle,
    /// The angle moves to `target`.
    Move { target: u32 },
    /// Wait, then average the encoder angle: one estimate.
    Measure,
    /// This section is done.
    Next,
}

/// Electrical-angle alignment of both sections, one after the other.
#[derive(Clone, Debug)]
pub(super) struct Aligner {
    section: Section,
    /// Program counter within the section's sequence, and cycles spent in its step.
    pc: u32,
    elapsed: u32,
    /// Where the step started: the forced angle and the current (fraction of full).
    from_angle: u32,
    level: f32,
    angle: u32,
    /// The section's first angle, one approach below where the magnets are believed to be.
    base: u32,
    /// The section's first reading of (forced − encoder): the estimates are taken relative
    /// to it, so none of them sits at the wrap.
    reference: Option<u32>,
    /// Sum of (forced − encoder − reference) over the averaging window, periods.
    window_sum: f32,
    window_n: u32,
    /// The section's estimates so far (relative to `reference`, periods): count, sum and
    /// range. Running figures, not a list: the state rides in the controller's mode.
    count: u32,
    sum: f32,
    lowest: f32,
    highest: f32,
    found: PerSection<u32>,
}

impl Aligner {
    pub(super) fn new(config: &ControlConfig) -> Self {
        Aligner {
            section: Section::Master,
            pc: 0,
            elapsed: 0,
            from_angle: 0,
            level: 0.0,
            angle: 0,
            base: 0,
            reference: None,
            window_sum: 0.0,
            window_n: 0,
            count: 0,
            sum: 0.0,
            lowest: 0.0,
            highest: 0.0,
            found: config.angle_offset,
        }
    }

    fn points(c: &CalibrationConfig) -> u32 {
        c.align_points.clamp(1, 64)
    }

    /// The section's program: ramp the current up at `base` (one approach below the first
    /// angle), settle, then for each angle θₖ = base + approach + k/points: up to θₖ (from
    /// below), measure, up to θₖ + approach, down to θₖ (from above), measure; finally ramp
    /// down.
    fn program(&self, c: &CalibrationConfig) -> AlignStep {
        let points = Self::points(c);
        let approach = turns(c.align_approach_periods);
        let per_point = 5;
        match self.pc {
            0 => AlignStep::Ramp { to: 1.0 },
            1 => AlignStep::Settle,
            pc if pc < 2 + per_point * points => {
                let k = (pc - 2) / per_point;
                let theta = self
                    .base
                    .wrapping_add(approach)
                    .wrapping_add((TURN / points as f32 * k as f32) as u32);
                match (pc - 2) % per_point {
                    0 | 3 => AlignStep::Move { target: theta },
                    2 => AlignStep::Move {
                        target: theta.wrapping_add(approach),
                    },
                    _ => AlignStep::Measure,
                }
            }
            pc if pc == 2 + per_point * points => AlignStep::Ramp { to: 0.0 },
            _ => AlignStep::Next,
        }
    }

    pub(super) fn step(&mut self, config: &ControlConfig, m: &Measurements) -> Demand {
        let c = &config.calibration;
        let dt = config.sample_time_s;
        let encoder = *m.angle.get(self.section);
        if self.pc == 0 && self.elapsed == 0 {
            // Start where the present offset puts the magnets, one approach below the first
            // angle (so the first approach is from below).
            let believed = encoder.wrapping_add(*config.angle_offset.get(self.section));
            self.base = believed.wrapping_sub(turns(c.align_approach_periods));
            self.angle = self.base;
            self.from_angle = self.base;
        }
        let step = self.program(c);
        self.elapsed += 1;
        let t = self.elapsed as f32 * dt;
        let finished = match step {
            AlignStep::Ramp { to } => {
                let ramp = c.align_ramp_s;
                let start = 1.0 - to;
                self.level = if t >= ramp {
                    to
                } else {
                    start + (to - start) * t / ramp
                };
                t >= ramp
            }
            AlignStep::Settle => t >= c.align_first_settle_s,
            AlignStep::Move { target } => {
                let span = target.wrapping_sub(self.from_angle) as i32 as f32;
                let duration = (span / TURN).abs() / c.align_rate_periods_per_s;
                let f = if duration > 0.0 {
                    clamp_f32(t / duration, 0.0, 1.0)
                } else {
                    1.0
                };
                self.angle = self.from_angle.wrapping_add((span * f) as i32 as u32);
                f >= 1.0
            }
            AlignStep::Measure => {
                if t > c.align_settle_s {
                    let raw = self.angle.wrapping_sub(encoder);
                    let reference = *self.reference.get_or_insert(raw);
                    self.window_sum += raw.wrapping_sub(reference) as i32 as f32 / TURN;
                    self.window_n += 1;
                }
                let done = t >= c.align_settle_s + c.align_average_s;
                if done && self.window_n > 0 {
                    let e = self.window_sum / self.window_n as f32;
                    if self.count == 0 {
                        (self.lowest, self.highest) = (e, e);
                    }
                    self.lowest = min_f32(self.lowest, e);
                    self.highest = max_f32(self.highest, e);
                    self.sum += e;
                    self.count += 1;
                    self.window_sum = 0.0;
                    self.window_n = 0;
                }
                done
            }
            AlignStep::Next => {
                match self.finish_section(c) {
                    Ok(offset) => *self.found.get_mut(self.section) = offset,
                    Err(e) => return Demand::Done(Err(e)),
                }
                if self.section == Section::Slave {
                    return Demand::Done(Ok(Outcome::Alignment(self.found)));
                }
                self.section = Section::Slave;
                self.pc = 0;
                self.elapsed = 0;
                self.count = 0;
                self.sum = 0.0;
                self.level = 0.0;
                self.reference = None;
                return Demand::Forced(PerSection::default());
            }
        };
        if finished {
            self.pc += 1;
            self.elapsed = 0;
            self.from_angle = self.angle;
        }
        let kf = config.motor.force_constant_n_per_a;
        let vector = Forced {
            angle: self.angle,
            current: Dq {
                d: self.level * c.align_current_a,
                q: -self.level * c.align_damping_ns_per_m * m.velocity_mps / kf,
            },
        };
        let mut demand = PerSection::default();
        *demand.get_mut(self.section) = Some(vector);
        Demand::Forced(demand)
    }

    /// The section's offset from its estimates: their mean, refused if they spread too far.
    fn finish_section(&self, c: &CalibrationConfig) -> Result<u32, CalibrationError> {
        let err = CalibrationError::AlignmentSpread {
            section: self.section,
        };
        if self.count == 0 {
            return Err(err);
        }
        let mean = self.sum / self.count as f32;
        let spread = c.align_max_spread_periods;
        if !(within(self.highest - mean, spread) && within(mean - self.lowest, spread)) {
            return Err(err);
        }
        Ok(self.reference.unwrap_or(0).wrapping_add(turns(mean)))
    }
}
