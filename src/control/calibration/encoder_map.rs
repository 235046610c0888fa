//! The encoder-difference map (paper §4.2, Fig. 6): the slave encoder's reading against the
//! master's, mapped as a function of the position within the magnetic pitch and of the
//! direction, with a correction coefficient for the velocity. The correction the firmware
//! applies to the slave's reading with it is `sensing::encoder_map`.
//!
//! The paper found the difference "with a very clear pattern and a step corresponding with a
//! magnetic pitch, … larger during the piston movement from left to right", and proposed
//! "mapping the linear dependency of the measured difference in function of the piston
//! position and … applying a correction coefficient for the velocity". The map is that:
//!
//! `d(x, v) = S·(frac(u − u₀) − ½) + D_dir + k_v·v`, with `u` the master encoder's phase
//! within its period (`x/λ` in its own frame), so
//! - a **saw** of height `S` rising linearly with the position and stepping back once a pitch
//!   at the phase `u₀` (the linear dependency on the position, and the step);
//! - a **direction part** `D_dir`, one value moving toward +x and one toward −x, blended
//!   linearly over ±`blend_mps` through standstill;
//! - a **velocity coefficient** `k_v` (a skew between the two encoders' sampling instants
//!   reads as a difference proportional to the speed).
//!
//! **The routine** (homed): constant-velocity sweeps over whole periods, out and back, at two
//! speeds; each cruise sample's difference `x_slave − x_master` (both in the homed frame, as
//! the status reports them) goes into one of [`MAP_BINS`] bins of the master's phase and into
//! the mean of its (speed, direction). Each sweep covers whole periods at a constant speed,
//! so every bin holds the same share of every sweep's samples: the direction and velocity
//! parts add the same constant to every bin's mean, and the bins less their overall mean are
//! the saw alone (whose mean over a period is zero). Then, over several cycles (the fit must
//! not take a cycle's time at once):
//! - `k_v` from how each direction's mean changes between the two speeds, `D_dir` from the
//!   means with the velocity part removed;
//! - for [`STEP_CANDIDATES`] step phases `u₀` the bin-averaged saw of unit height (a bin that
//!   holds the step averages both sides of it) is fitted to the bins by least squares, and
//!   the `u₀` that leaves the least residual is kept with its `S`.
//!
//! A difference the map cannot hold (a pattern other than one saw a pitch, a scale
//! difference along the stroke) stays in the corrected reading; the routine reports the RMS
//! the fit leaves ([`EncoderMap::residual_m`]).

use super::{cycles, CalibrationError, Demand, Measurements, Outcome};
use crate::control::config::{CalibrationConfig, ControlConfig};
use crate::motion::trajectory::Setpoint;
use crate::real::max_f32;
use crate::sensing::encoder::EncoderConfig;
pub use crate::sensing::encoder_map::EncoderMap;

/// Bins of the master's phase within a period.
pub const MAP_BINS: usize = 16;

/// Step phases tried by each of the fit's two passes: the first over the whole period, the
/// second over ±1/`STEP_CANDIDATES` of a period around the first's best (the step is then
/// located to 1/`STEP_CANDIDATES`² of a period, 0.4 µm at 24 mm: a step placed a few µm
/// wrong leaves its whole height over those µm of every pitch).
pub const STEP_CANDIDATES: usize = 240;

/// Step phases evaluated per control cycle during the fit.
const CANDIDATES_PER_CYCLE: usize = 8;

/// The slave decoder's configuration with `config`'s map loaded: its glitch gate widened by
/// the map's step height. The scale's step moves the slave's reading by `|S|` within one
/// sample, which departs from constant velocity by `|S|` on top of what the gate allows; with
/// the gate as it is (50 µm against a 0.1 mm step) the decoder extrapolates over the step and
/// re-locks a cycle or two later, while the map steps at once, leaving those samples a whole
/// step wrong. Without a map: `config.encoder_slave` as it is.
pub fn slave_encoder(config: &ControlConfig) -> EncoderConfig {
    let mut slave = config.encoder_slave;
    if let Some(map) = &config.encoder_map {
        if map.period_m > 0.0 {
            slave.glitch_gate_periods += libm::fabsf(map.saw_m) / map.period_m;
        }
    }
    slave
}

/// One leg of the routine.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Leg {
    /// Hold still.
    Rest,
    /// A constant-velocity sweep at speed `speed` (index into the configured speeds),
    /// away from the start (`out`) or back.
    Sweep { speed: usize, out: bool },
}

const LEGS: [Leg; 8] = [
    Leg::Rest,
    Leg::Sweep {
        speed: 0,
        out: true,
    },
    Leg::Rest,
    Leg::Sweep {
        speed: 0,
        out: false,
    },
    Leg::Rest,
    Leg::Sweep {
        speed: 1,
        out: true,
    },
    Leg::Rest,
    Leg::Sweep {
        speed: 1,
        out: false,
    },
];

/// Direction index: 0 toward +x, 1 toward −x (for the (speed, direction) means).
fn dir_index(dir: f32) -> usize {
    usize::from(dir < 0.0)
}

/// The running routine.
#[derive(Clone, Debug)]
pub(super) struct EncoderMapper {
    leg: usize,
    elapsed: u32,
    start_m: f32,
    direction: f32,
    cruise_m: f32,
    /// Per bin: samples and Σ difference, m (the saw's bin values, m, once the fit begins).
    bin_n: [u16; MAP_BINS],
    bin_sum: [f32; MAP_BINS],
    /// Per speed and direction: samples, Σ difference (m), Σ velocity (m/s).
    leg_n: [[u32; 2]; 2],
    leg_sum: [[f32; 2]; 2],
    leg_v: [[f32; 2]; 2],
    fit: Option<Fit>,
}

/// The fit's state, over several cycles (the saw's bin values are the mapper's `bin_sum`).
#[derive(Clone, Copy, Debug)]
struct Fit {
    /// The next step phase to try, and the pass (0: coarse, 1: fine).
    next: u16,
    pass: u8,
    /// The coarse pass's best step phase, the fine pass's centre.
    centre: f32,
    /// (residual, height, step phase) of the best so far.
    best: (f32, f32, f32),
    /// The direction parts and the velocity coefficient: (D₊, D₋, k_v).
    parts: (f32, f32, f32),
}

impl EncoderMapper {
    /// Starts the routine from `position_m` (homed frame).
    pub(super) fn new(config: &ControlConfig, position_m: f32) -> Result<Self, CalibrationError> {
        let c = &config.calibration;
        let cruise_m = c.map_periods.max(1) as f32 * config.encoder_master.period_m;
        let span = Self::span_for(c, cruise_m);
        let (near, far) = (config.target_clearance_m, c.sweep_margin_m);
        let (lo, hi) = (near, config.travel_m - near);
        let direction = if position_m >= lo && position_m + span <= hi - far {
            1.0
        } else if position_m <= hi && position_m - span >= lo + far {
            -1.0
        } else {
            return Err(CalibrationError::NoRoom);
        };
        Ok(EncoderMapper {
            leg: 0,
            elapsed: 0,
            start_m: position_m,
            direction,
            cruise_m,
            bin_n: [0; MAP_BINS],
            bin_sum: [0.0; MAP_BINS],
            leg_n: [[0; 2]; 2],
            leg_sum: [[0.0; 2]; 2],
            leg_v: [[0.0; 2]; 2],
            fit: None,
        })
    }

    /// The sweeps' configuration at speed `k`.
    fn sweep_config(c: &CalibrationConfig, k: usize) -> CalibrationConfig {
        CalibrationConfig {
            sweep_speed_mps: c
                .map_speeds_mps
                .get(k)
                .copied()
                .unwrap_or(c.sweep_speed_mps),
            sweep_accel_mps2: c.map_accel_mps2,
            ..*c
        }
    }

    /// Longest sweep (the faster speed's ramps), m.
    fn span_for(c: &CalibrationConfig, cruise_m: f32) -> f32 {
        let [a, b] = c.map_speeds_mps;
        let v = max_f32(a, b);
        cruise_m + v * v / c.map_accel_mps2
    }

    /// The length of a sweep at speed `k`, m.
    fn span_at(&self, c: &CalibrationConfig, k: usize) -> f32 {
        let s = Self::sweep_config(c, k);
        self.cruise_m + s.sweep_speed_mps * s.sweep_speed_mps / s.sweep_accel_mps2
    }

    /// One cycle of the routine.
    ///
    /// Kept out of line (and so in flash, outside `.ccmram`): the routine runs only at
    /// commissioning, and every byte of the 20 kHz path's code in CCM SRAM is copied there
    /// at each boot, before the control task can brake (`src/board/ccm.rs`).
    #[inline(never)]
    pub(super) fn step(&mut self, config: &ControlConfig, m: &Measurements) -> Demand {
        let c = &config.calibration;
        let dt = config.sample_time_s;
        if let Some(fit) = &mut self.fit {
            return fit.step(&self.bin_sum, self.start_m, config);
        }
        let Some(&leg) = LEGS.get(self.leg) else {
            return self.begin_fit();
        };
        self.elapsed += 1;
        let t = self.elapsed as f32 * dt;
        // Where the last sweep ended: out at the far end, back at the start.
        let at_far =
            self.leg > 0 && matches!(LEGS.get(self.leg - 1), Some(Leg::Sweep { out: true, .. }));
        let (setpoint, done) = match leg {
            Leg::Rest => {
                let here = match LEGS.get(self.leg.wrapping_sub(1)) {
                    Some(Leg::Sweep { speed, out: true }) if at_far => {
                        self.start_m + self.direction * self.span_at(c, *speed)
                    }
                    _ => self.start_m,
                };
                (
                    Setpoint::at_rest(here),
                    self.elapsed >= cycles(c.sweep_rest_s, dt),
                )
            }
            Leg::Sweep { speed, out } => {
                let sc = Self::sweep_config(c, speed);
                let dir = if out { self.direction } else { -self.direction };
                let from = if out {
                    self.start_m
                } else {
                    self.start_m + self.direction * self.span_at(c, speed)
                };
                let (sp, cruising, done) =
                    super::sweeps::trapezoid(&sc, self.cruise_m, from, dir, t);
                if cruising {
                    self.add(config, m, speed, dir);
                }
                (sp, done)
            }
        };
        if done {
            self.leg += 1;
            self.elapsed = 0;
        }
        Demand::Track {
            setpoint,
            master_only: false,
            slave_d_a: 0.0,
        }
    }

    /// One cruise sample at speed `k` moving in direction `dir`: the difference as the
    /// encoders read it (a map already loaded corrects the slave's reading: added back).
    fn add(&mut self, config: &ControlConfig, m: &Measurements, k: usize, dir: f32) {
        let loaded = config
            .encoder_map
            .map_or(0.0, |map| map.difference_m(m.angle.master, m.velocity_mps));
        let d = m.slave_position_m - m.position_m + loaded;
        let j = dir_index(dir);
        let bin = ((m.angle.master as u64 * MAP_BINS as u64) >> 32) as usize;
        if let (Some(n), Some(s)) = (self.bin_n.get_mut(bin), self.bin_sum.get_mut(bin)) {
            *n = n.saturating_add(1);
            *s += d;
        }
        if let (Some(n), Some(s), Some(v)) = (
            self.leg_n.get_mut(k).and_then(|l| l.get_mut(j)),
            self.leg_sum.get_mut(k).and_then(|l| l.get_mut(j)),
            self.leg_v.get_mut(k).and_then(|l| l.get_mut(j)),
        ) {
            *n += 1;
            *s += d;
            *v += m.velocity_mps;
        }
    }

    /// The sweeps are done: the direction parts and the velocity coefficient, then the saw's
    /// bins for the fit.
    fn begin_fit(&mut self) -> Demand {
        let mean = |s: f32, n: u32| if n > 0 { s / n as f32 } else { 0.0 };
        // Per speed k and direction j: mean difference D and mean velocity V.
        let at = |k: usize, j: usize| {
            let n = self
                .leg_n
                .get(k)
                .and_then(|l| l.get(j))
                .copied()
                .unwrap_or(0);
            let s = self
                .leg_sum
                .get(k)
                .and_then(|l| l.get(j))
                .copied()
                .unwrap_or(0.0);
            let v = self
                .leg_v
                .get(k)
                .and_then(|l| l.get(j))
                .copied()
                .unwrap_or(0.0);
            (mean(s, n), mean(v, n))
        };
        let (d_p0, v_p0) = at(0, 0);
        let (d_p1, v_p1) = at(1, 0);
        let (d_m0, v_m0) = at(0, 1);
        let (d_m1, v_m1) = at(1, 1);
        let slope = |d0: f32, d1: f32, v0: f32, v1: f32| {
            if (v1 - v0).abs() > 1e-6 {
                (d1 - d0) / (v1 - v0)
            } else {
                0.0
            }
        };
        let k_v = 0.5 * (slope(d_p0, d_p1, v_p0, v_p1) + slope(d_m0, d_m1, v_m0, v_m1));
        let plus = 0.5 * ((d_p0 - k_v * v_p0) + (d_p1 - k_v * v_p1));
        let minus = 0.5 * ((d_m0 - k_v * v_m0) + (d_m1 - k_v * v_m1));
        // The bins less their overall mean: the saw alone (module header).
        if self.bin_n.contains(&0) {
            return Demand::Done(Err(CalibrationError::MapIncomplete));
        }
        let (n_all, s_all) = self
            .bin_n
            .iter()
            .zip(&self.bin_sum)
            .fold((0u32, 0.0f32), |(n, s), (bn, bs)| {
                (n + u32::from(*bn), s + bs)
            });
        let overall = mean(s_all, n_all);
        for (b, n) in self.bin_sum.iter_mut().zip(&self.bin_n) {
            *b = mean(*b, u32::from(*n)) - overall;
        }
        self.fit = Some(Fit {
            next: 0,
            pass: 0,
            centre: 0.0,
            best: (f32::INFINITY, 0.0, 0.0),
            parts: (plus, minus, k_v),
        });
        Demand::Track {
            setpoint: Setpoint::at_rest(self.start_m),
            master_only: false,
            slave_d_a: 0.0,
        }
    }
}

/// The bin-averaged unit saw `frac(u − u₀) − ½` over bin `k` of [`MAP_BINS`].
fn unit_saw_bin(k: usize, u0: f32) -> f32 {
    let w = 1.0 / MAP_BINS as f32;
    let a = k as f32 * w;
    // The step's place within this bin, if it lies there (circularly).
    let p = {
        let s = u0 - a;
        s - libm::floorf(s)
    };
    if p < w {
        // [a, u₀): the top of the saw; [u₀, a + w): its bottom.
        let q = w - p;
        (p * (0.5 - 0.5 * p) + q * (-0.5 + 0.5 * q)) / w
    } else {
        let mid = a + 0.5 * w - u0;
        mid - libm::floorf(mid) - 0.5
    }
}

impl Fit {
    /// Evaluates the next candidates against the saw's bin values `saw`, m, the piston held
    /// at `hold_m`; done once all are.
    fn step(&mut self, saw: &[f32; MAP_BINS], hold_m: f32, config: &ControlConfig) -> Demand {
        for _ in 0..CANDIDATES_PER_CYCLE {
            if usize::from(self.next) >= STEP_CANDIDATES {
                break;
            }
            let n = STEP_CANDIDATES as f32;
            let u0 = if self.pass == 0 {
                f32::from(self.next) / n
            } else {
                // ±1/n around the coarse best, wrapped into [0, 1).
                let u = self.centre + (2.0 * f32::from(self.next) / n - 1.0) / n;
                u - libm::floorf(u)
            };
            let (mut sm, mut mm, mut ss) = (0.0f32, 0.0f32, 0.0f32);
            for (k, s) in saw.iter().enumerate() {
                let model = unit_saw_bin(k, u0);
                sm += s * model;
                mm += model * model;
                ss += s * s;
            }
            if mm > 0.0 {
                let height = sm / mm;
                let residual = ss - height * sm;
                if residual < self.best.0 {
                    self.best = (residual, height, u0);
                }
            }
            self.next += 1;
        }
        if usize::from(self.next) >= STEP_CANDIDATES && self.pass == 0 {
            self.pass = 1;
            self.next = 0;
            self.centre = self.best.2;
        }
        if usize::from(self.next) < STEP_CANDIDATES || self.pass == 0 {
            return Demand::Track {
                setpoint: Setpoint::at_rest(hold_m),
                master_only: false,
                slave_d_a: 0.0,
            };
        }
        let (residual, height, u0) = self.best;
        let (plus, minus, k_v) = self.parts;
        Demand::Done(Ok(Outcome::EncoderMap(EncoderMap {
            period_m: config.encoder_master.period_m,
            saw_m: height,
            step_phase: u0,
            toward_plus_m: plus,
            toward_minus_m: minus,
            velocity_s: k_v,
            blend_mps: config.calibration.map_blend_mps,
            residual_m: libm::sqrtf(max_f32(residual, 0.0) / MAP_BINS as f32),
        })))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::calibration::TURN;

    #[test]
    fn the_bin_averaged_saw_is_the_saw_away_from_the_step_and_its_mean_across_it() {
        // Step at the start of bin 5: every bin is a plain sample of the saw.
        let w = 1.0 / MAP_BINS as f32;
        let u0 = 5.0 * w;
        let at_mid = |k: usize| {
            let s = (k as f32 + 0.5) * w - u0;
            s - libm::floorf(s) - 0.5
        };
        for k in 0..MAP_BINS {
            assert!((unit_saw_bin(k, u0) - at_mid(k)).abs() < 1e-5, "bin {k}");
        }
        // Step in the middle of bin 5: that bin averages the top and the bottom to ≈ 0.
        let mid = unit_saw_bin(5, 5.5 * w);
        assert!(mid.abs() < 1e-5, "{mid}");
        // Over a period the unit saw's bins average to zero wherever it steps.
        for u0 in [0.0, 0.013, 0.5, 0.77] {
            let sum: f32 = (0..MAP_BINS).map(|k| unit_saw_bin(k, u0)).sum();
            assert!(sum.abs() < 1e-4, "{u0}: {sum}");
        }
    }

    #[test]
    fn the_map_predicts_the_saw_the_direction_part_and_the_velocity_part() {
        let map = EncoderMap {
            period_m: 0.024,
            saw_m: 1e-4,
            step_phase: 0.25,
            toward_plus_m: 3e-5,
            toward_minus_m: -2e-5,
            velocity_s: 1e-6,
            blend_mps: 0.005,
            residual_m: 0.0,
        };
        let phase = |u: f32| (u * TURN) as u32;
        // Just after the step, moving toward +x at 1 m/s: the saw's bottom, D₊, k_v·v.
        let d = map.difference_m(phase(0.2501), 1.0);
        assert!((d - (-0.5e-4 + 3e-5 + 1e-6)).abs() < 1e-7, "{d}");
        // Just before it, moving toward −x at 2 m/s.
        let d = map.difference_m(phase(0.2499), -2.0);
        assert!((d - (0.5e-4 - 2e-5 - 2e-6)).abs() < 1e-7, "{d}");
        // At rest the direction part is their mean.
        let d = map.difference_m(phase(0.75), 0.0);
        assert!((d - 0.5e-5).abs() < 1e-7, "{d}");
    }

    #[test]
    fn the_fit_finds_the_step_and_the_height_from_noisy_bins() {
        let (height, u0) = (-8e-5f32, 0.6312f32);
        let mut saw = [0.0f32; MAP_BINS];
        for (k, s) in saw.iter_mut().enumerate() {
            // ±1 µm of deterministic "noise".
            *s = height * unit_saw_bin(k, u0) + 1e-6 * libm::sinf(7.0 * k as f32);
        }
        let mut fit = Fit {
            next: 0,
            pass: 0,
            centre: 0.0,
            best: (f32::INFINITY, 0.0, 0.0),
            parts: (0.0, 0.0, 0.0),
        };
        let config = ControlConfig::reference();
        let mut cycles = 0;
        let map = loop {
            cycles += 1;
            match fit.step(&saw, 0.05, &config) {
                Demand::Done(Ok(Outcome::EncoderMap(m))) => break m,
                Demand::Track { .. } => {}
                d => panic!("{d:?}"),
            }
        };
        assert_eq!(cycles, 2 * STEP_CANDIDATES / CANDIDATES_PER_CYCLE);
        assert!((map.step_phase - u0).abs() <= 1e-3, "{}", map.step_phase);
        assert!(
            (map.saw_m - height).abs() < 0.05 * height.abs(),
            "{}",
            map.saw_m
        );
        assert!(map.residual_m < 3e-6, "{}", map.residual_m);
    }
}
