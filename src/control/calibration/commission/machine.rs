//! The commissioning's state machine: the forced vector turned on each section in turn, both
//! encoders read at rest. In the host build and the firmware's `bench` build only
//! (`Routine::Commission` is refused in the release firmware: `Refusal::BenchBuildOnly`).

use super::super::{CalibrationError, Demand, Forced, Measurements, Outcome};
use super::{explain, Commissioning};
use crate::angle::turns;
use crate::control::config::ControlConfig;
use crate::physics::motor::Dq;
use crate::real::clamp_f32;
use crate::units::{PerSection, Section};

/// The commissioning of both sections, one after the other.
#[derive(Clone, Debug)]
pub(in crate::control::calibration) struct Commissioner {
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
    pub(in crate::control::calibration) fn new() -> Self {
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
    pub(in crate::control::calibration) fn reach_periods(config: &ControlConfig) -> f32 {
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
    pub(in crate::control::calibration) fn step(
        &mut self,
        config: &ControlConfig,
        m: &Measurements,
    ) -> Demand {
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
