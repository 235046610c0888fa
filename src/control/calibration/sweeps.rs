//! The sweep routines (cogging map, slave misalignment): rests and constant-velocity legs
//! under position control, with their cruise samples projected on harmonics.

use super::{
    within, CalibrationConfig, CalibrationError, Demand, Measurements, Misalignment, Outcome,
    Routine, TURN,
};
use crate::angle::{sin_cos_turns, turns};
use crate::control::config::ControlConfig;
use crate::motion::trajectory::Setpoint;
use crate::physics::balance::PistonForces;
use crate::physics::cogging::{HarmonicMap, MAP_HARMONICS};
use crate::real::clamp_f32;

/// One leg of a sweep routine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Leg {
    /// Hold still while the slave's d-current goes from `from` to `to` (× the routine's
    /// current).
    Rest { from: f32, to: f32 },
    /// A constant-velocity sweep, away from the start (`out`) or back; its samples go to
    /// accumulator `slot`.
    Sweep { out: bool, slot: usize },
}

/// Cogging: one sweep out and back.
const COGGING_LEGS: [Leg; 4] = [
    Leg::Rest { from: 0.0, to: 0.0 },
    Leg::Sweep { out: true, slot: 0 },
    Leg::Rest { from: 0.0, to: 0.0 },
    Leg::Sweep {
        out: false,
        slot: 1,
    },
];

/// Misalignment: out and back with +I on the slave, then with −I.
const MISALIGNMENT_LEGS: [Leg; 9] = [
    Leg::Rest { from: 0.0, to: 1.0 },
    Leg::Sweep { out: true, slot: 0 },
    Leg::Rest { from: 1.0, to: 1.0 },
    Leg::Sweep {
        out: false,
        slot: 1,
    },
    Leg::Rest {
        from: 1.0,
        to: -1.0,
    },
    Leg::Sweep { out: true, slot: 2 },
    Leg::Rest {
        from: -1.0,
        to: -1.0,
    },
    Leg::Sweep {
        out: false,
        slot: 3,
    },
    Leg::Rest {
        from: -1.0,
        to: 0.0,
    },
];

/// What the sweeps accumulate over their cruises. Sums, not samples, and one set for both
/// cogging directions (their cruises hold the same number of samples, so the sum over both
/// is the mean of the two directions' projections): the state rides in the controller's mode.
#[derive(Clone, Copy, Debug)]
enum Sums {
    /// Σ y·sin(kθ), Σ y·cos(kθ) of the cogging estimate y, k = 1..=4, over `n` samples.
    Cogging {
        n: u32,
        sin: [f32; MAP_HARMONICS],
        cos: [f32; MAP_HARMONICS],
    },
    /// Per sweep (slot): samples and Σ master force, N; Σ (slave − master encoder angle),
    /// periods, over all.
    Misalignment {
        n: [u32; 4],
        master_n: [f32; 4],
        encoder_periods: f32,
    },
}

/// Sweep routines (cogging, misalignment): legs of rest and constant-velocity sweeps under
/// position control.
#[derive(Clone, Debug)]
pub(super) struct Sweeps {
    legs: &'static [Leg],
    leg: usize,
    elapsed: u32,
    /// Where the sweeps start and their direction away from it (+1 or −1).
    start_m: f32,
    direction: f32,
    /// Distance at cruise speed, m.
    cruise_m: f32,
    /// The piston is at the far end (an odd number of sweeps done).
    far: bool,
    sums: Sums,
}

impl Sweeps {
    /// Starts the sweeps of `routine` (cogging or misalignment) from `position_m`.
    pub(super) fn new(
        config: &ControlConfig,
        position_m: f32,
        routine: Routine,
    ) -> Result<Self, CalibrationError> {
        let c = &config.calibration;
        // Which sums the sweeps collect follows from the routine, never from the identity of
        // the leg table (a `const` has no fixed address to compare).
        let misalignment = routine == Routine::Misalignment;
        let (periods, legs): (u32, &'static [Leg]) = if misalignment {
            (c.misalign_periods, &MISALIGNMENT_LEGS)
        } else {
            (c.cogging_periods, &COGGING_LEGS)
        };
        let cruise_m = periods.max(1) as f32 * config.motor.electrical_period_m;
        let v = c.sweep_speed_mps;
        let span = cruise_m + v * v / c.sweep_accel_mps2;
        // The far end keeps the margin from the head; the start is wherever the piston is
        // (within the commanded range).
        let (near, far) = (config.target_clearance_m, c.sweep_margin_m);
        let (lo, hi) = (near, config.travel_m - near);
        let direction = if position_m >= lo && position_m + span <= hi - far {
            1.0
        } else if position_m <= hi && position_m - span >= lo + far {
            -1.0
        } else {
            return Err(CalibrationError::NoRoom);
        };
        Ok(Sweeps {
            legs,
            leg: 0,
            elapsed: 0,
            start_m: position_m,
            direction,
            cruise_m,
            far: false,
            sums: if misalignment {
                Sums::Misalignment {
                    n: [0; 4],
                    master_n: [0.0; 4],
                    encoder_periods: 0.0,
                }
            } else {
                Sums::Cogging {
                    n: 0,
                    sin: [0.0; MAP_HARMONICS],
                    cos: [0.0; MAP_HARMONICS],
                }
            },
        })
    }

    pub(super) fn step(
        &mut self,
        config: &ControlConfig,
        m: &Measurements,
        routine: Routine,
    ) -> Demand {
        let c = &config.calibration;
        let dt = config.sample_time_s;
        let misalignment = routine == Routine::Misalignment;
        let Some(&leg) = self.legs.get(self.leg) else {
            return Demand::Done(self.finish(config));
        };
        self.elapsed += 1;
        let t = self.elapsed as f32 * dt;
        let (setpoint, d_level, done) = match leg {
            Leg::Rest { from, to } => {
                let f = clamp_f32(t / c.sweep_rest_s, 0.0, 1.0);
                let here = if self.far {
                    self.start_m + self.direction * self.span(c)
                } else {
                    self.start_m
                };
                (Setpoint::at_rest(here), from + (to - from) * f, f >= 1.0)
            }
            Leg::Sweep { out, slot } => {
                let dir = if out { self.direction } else { -self.direction };
                let from = if out {
                    self.start_m
                } else {
                    self.start_m + self.direction * self.span(c)
                };
                let (sp, cruising, done) = trapezoid(c, self.cruise_m, from, dir, t);
                let d = if misalignment {
                    if slot < 2 {
                        1.0
                    } else {
                        -1.0
                    }
                } else {
                    0.0
                };
                if cruising {
                    self.sums.add(config, m, slot);
                }
                if done {
                    self.far = out;
                }
                (sp, d, done)
            }
        };
        if done {
            self.leg += 1;
            self.elapsed = 0;
        }
        Demand::Track {
            setpoint,
            master_only: misalignment,
            slave_d_a: d_level * c.misalign_current_a,
        }
    }

    /// Total length of a sweep, m.
    fn span(&self, c: &CalibrationConfig) -> f32 {
        let v = c.sweep_speed_mps;
        self.cruise_m + v * v / c.sweep_accel_mps2
    }

    fn finish(&self, config: &ControlConfig) -> Result<Outcome, CalibrationError> {
        match self.sums {
            Sums::Misalignment {
                n,
                master_n,
                encoder_periods,
            } => {
                let [a, b, c, d] = [0, 1, 2, 3].map(|k| {
                    let count = n.get(k).copied().unwrap_or(0).max(1) as f32;
                    master_n.get(k).copied().unwrap_or(0.0) / count
                });
                // (+I − −I) on the way out and on the way back: 2·K_f·I·sin ε each.
                let delta_n = 0.5 * ((a - c) + (b - d));
                let full = 2.0
                    * config.motor.force_constant_n_per_a
                    * config.calibration.misalign_current_a;
                let sin_eps = delta_n / full;
                if !within(sin_eps, 0.9) {
                    return Err(CalibrationError::MisalignmentImplausible);
                }
                let eps_periods = libm::asinf(sin_eps) / core::f32::consts::TAU;
                let slave = config.angle_offset.slave.wrapping_add(turns(eps_periods));
                let lambda = config.motor.electrical_period_m;
                let between = config.angle_offset.master.wrapping_sub(slave) as i32 as f32 / TURN;
                let total: u32 = n.iter().sum();
                Ok(Outcome::Misalignment(Misalignment {
                    slave_angle_offset: slave,
                    correction_periods: eps_periods,
                    misalignment_m: between * lambda,
                    encoder_offset_m: encoder_periods / total.max(1) as f32 * lambda,
                }))
            }
            Sums::Cogging { n, sin, cos } => {
                // The projection 2/n·Σ over both directions: their mean (friction cancels).
                let k = 2.0 / n.max(1) as f32;
                Ok(Outcome::Cogging(HarmonicMap {
                    period_m: config.motor.electrical_period_m,
                    sin_n: sin.map(|v| v * k),
                    cos_n: cos.map(|v| v * k),
                }))
            }
        }
    }
}

impl Sums {
    fn add(&mut self, config: &ControlConfig, m: &Measurements, slot: usize) {
        match self {
            Sums::Cogging { n, sin, cos } => {
                // The cogging estimate: what neither the motors nor the gas explain at
                // constant velocity — the balance with friction left in it, which the two
                // directions' mean cancels.
                let y = PistonForces::known(m.force_n.master + m.force_n.slave, m.gas_force_n, 0.0)
                    .unexplained_n(config.moving_mass_kg, 0.0);
                let period = config.motor.electrical_period_m;
                let (s1, c1) = sin_cos_turns(turns(m.position_m / period));
                let (mut s, mut c) = (s1, c1);
                for (ss, sc) in sin.iter_mut().zip(cos.iter_mut()) {
                    *ss += y * s;
                    *sc += y * c;
                    let next = s * c1 + c * s1;
                    c = c * c1 - s * s1;
                    s = next;
                }
                *n += 1;
            }
            Sums::Misalignment {
                n,
                master_n,
                encoder_periods,
            } => {
                if let (Some(count), Some(sum)) = (n.get_mut(slot), master_n.get_mut(slot)) {
                    *count += 1;
                    *sum += m.force_n.master;
                }
                let between = m.angle.slave.wrapping_sub(m.angle.master) as i32;
                *encoder_periods += between as f32 / TURN;
            }
        }
    }
}

/// A trapezoidal sweep from `from_m` in direction `dir`: accelerate, `cruise_m` at the
/// sweep speed, decelerate. Returns the setpoint at `t_s`, whether it is cruising (a whole
/// number of cycles over exactly `cruise_m`) and whether it is over.
pub(super) fn trapezoid(
    c: &CalibrationConfig,
    cruise_m: f32,
    from_m: f32,
    dir: f32,
    t_s: f32,
) -> (Setpoint, bool, bool) {
    let v = c.sweep_speed_mps;
    let a = c.sweep_accel_mps2;
    let ta = v / a;
    let da = 0.5 * v * ta;
    let tc = cruise_m / v;
    let (x, vel, acc, cruising) = if t_s < ta {
        (0.5 * a * t_s * t_s, a * t_s, a, false)
    } else if t_s < ta + tc {
        (da + v * (t_s - ta), v, 0.0, true)
    } else if t_s < 2.0 * ta + tc {
        let td = t_s - ta - tc;
        (
            da + cruise_m + v * td - 0.5 * a * td * td,
            v - a * td,
            -a,
            false,
        )
    } else {
        (2.0 * da + cruise_m, 0.0, 0.0, false)
    };
    let done = t_s >= 2.0 * ta + tc;
    (
        Setpoint {
            position_m: from_m + dir * x,
            velocity_mps: dir * vel,
            acceleration_mps2: dir * acc,
        },
        cruising,
        done,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_sweep_routine_collects_its_own_sums() {
        let config = ControlConfig::reference();
        let mis = Sweeps::new(&config, 0.01, Routine::Misalignment).unwrap();
        assert!(matches!(mis.sums, Sums::Misalignment { .. }));
        assert_eq!(mis.legs.len(), MISALIGNMENT_LEGS.len());
        let cog = Sweeps::new(&config, 0.01, Routine::Cogging).unwrap();
        assert!(matches!(cog.sums, Sums::Cogging { .. }));
        assert_eq!(cog.legs.len(), COGGING_LEGS.len());
    }
}
