//! Calibration routines: the machine parameters no drawing gives, measured on the machine by
//! the controller itself and loaded into its [`ControlConfig`].
//!
//! | routine | unknown | method | fills |
//! |---|---|---|---|
//! | [`Routine::CurrentSense`] | ADC zero of each phase | outputs off, average | `current_sense.*.offset_codes` |
//! | [`Routine::Alignment`] | encoder angle ↔ magnets, per section | a current vector at a forced angle, one section at a time, approached from both sides at 8 angles over a period | `angle_offset.*` |
//! | [`Routine::Misalignment`] | the slave's frame against the master's (Eq. 4's sine error) | the master alone holds the position on constant-velocity sweeps while the slave carries a d-current of ±I: the master's force changes by `2·K_f·I·sin ε` | `angle_offset.slave`; reports `D_dif` and the master−slave encoder offset |
//! | [`Routine::Cogging`] | detent force over the pitch | constant-velocity sweeps both ways under position control, `−(F_motors + F_gas)` fitted by harmonics; the two directions' average cancels friction | `allocation.cogging` |
//!
//! Each routine is a state machine. While one runs, the controller calls
//! [`Calibration::step`] once per cycle with what it measured ([`Measurements`]) and does what
//! the returned [`Demand`] says: outputs off, a current vector in a forced frame, or position
//! control along a sweep. The last demand carries the [`Outcome`], which the controller loads
//! ([`Outcome::apply`]) and records ([`Calibrated`]). None of this runs in the normal step.
//!
//! Why each method:
//! - **Alignment**: a current vector at a forced angle pulls the mover until its magnets align
//!   with it; the encoder then reads where that angle is. Friction stops the mover short of the
//!   equilibrium, by `F_s/k` (about 2° here), on the side it came from: approaching each angle
//!   from below and from above and averaging cancels it. The cogging force shifts the
//!   equilibrium too, but periodically in the angle: averaging 8 angles spread over the period
//!   cancels its harmonics 1–7. A q-current `−k_d·v/K_f` in the forced frame damps the
//!   mover (friction alone leaves it ringing).
//! - **Misalignment**: the slave's d-current in a frame that is wrong by ε pushes with
//!   `−K_f·I·sin ε`; the master, holding the position, supplies the opposite. Comparing +I and
//!   −I on the same path (same friction, same cogging) leaves only that term.
//! - **Cogging**: at constant velocity the motors supply `F_fr(v) − F_gas − F_cog(x)`; friction
//!   changes sign with the direction and the mean over whole periods is dropped by the
//!   harmonic projection, so the average of both directions' harmonics is `F_cog`'s. The
//!   samples are spread evenly over exactly `n` periods (constant speed, whole cycles), which
//!   makes the projection exact.

use crate::angle::{sin_cos_turns, turns};
use crate::control::config::ControlConfig;
use crate::motion::trajectory::Setpoint;
use crate::physics::cogging::{HarmonicMap, MAP_HARMONICS};
use crate::physics::motor::Dq;
use crate::ports::PhaseCurrentCodes;
use crate::real::{clamp_f32, max_f32, min_f32};
use crate::units::{PerSection, Section};

/// 2³² as f32: one turn of a wrapping angle.
const TURN: f32 = 4_294_967_296.0;

/// A calibration routine.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
#[repr(u8)]
pub enum Routine {
    /// Zero-current offsets of the phase-current ADCs (outputs off).
    CurrentSense = 0,
    /// Electrical-angle offset of each section (forced current vector; works before homing).
    Alignment = 1,
    /// The slave's frame against the master's, and the encoders' offset (homed).
    Misalignment = 2,
    /// Cogging map (homed).
    Cogging = 3,
}

impl Routine {
    /// Every routine, in number order (and in the order a new machine runs them, homing
    /// between alignment and misalignment).
    pub const ALL: [Routine; 4] = [
        Routine::CurrentSense,
        Routine::Alignment,
        Routine::Misalignment,
        Routine::Cogging,
    ];

    /// Stable snake_case name.
    pub const fn name(self) -> &'static str {
        match self {
            Routine::CurrentSense => "current_sense",
            Routine::Alignment => "alignment",
            Routine::Misalignment => "misalignment",
            Routine::Cogging => "cogging",
        }
    }

    /// The routine with number `code`.
    pub fn from_code(code: u8) -> Option<Routine> {
        Routine::ALL.iter().copied().find(|r| *r as u8 == code)
    }

    /// Whether the routine moves the piston under position control (it needs the zero).
    pub const fn needs_homing(self) -> bool {
        matches!(self, Routine::Misalignment | Routine::Cogging)
    }
}

/// Parameters of the routines, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationConfig {
    /// Samples averaged per phase for the current-sense offsets (after `sense_settle_s`).
    pub sense_samples: u32,
    /// Time for the currents to decay after the outputs go off, s.
    pub sense_settle_s: f32,
    /// Largest plausible offset, codes: beyond it the sensor or its supply is broken and the
    /// offsets are not loaded.
    pub sense_max_offset_codes: f32,
    /// Residual mean phase current with the outputs off that counts as an offset, A.
    pub sense_detect_a: f32,
    /// Alignment current (d, in the forced frame), A.
    pub align_current_a: f32,
    /// Damping of the mover during alignment (q-current in the forced frame), N·s/m.
    pub align_damping_ns_per_m: f32,
    /// Angles per period at which each section is aligned (≥ 1; 8 cancel cogging harmonics
    /// 1–7).
    pub align_points: u32,
    /// How far past an angle the forced vector goes before approaching it from above,
    /// fraction of a period.
    pub align_approach_periods: f32,
    /// Speed of the forced angle, periods per s.
    pub align_rate_periods_per_s: f32,
    /// Ramp of the alignment current, s.
    pub align_ramp_s: f32,
    /// Wait after the first pull (the mover may jump half a period), s.
    pub align_first_settle_s: f32,
    /// Wait at each angle before the encoder is read, s.
    pub align_settle_s: f32,
    /// Averaging of the encoder angle at each angle, s.
    pub align_average_s: f32,
    /// Largest spread of one section's estimates around their mean, fraction of a period:
    /// more means the mover did not follow (blocked, or the section gives no force).
    pub align_max_spread_periods: f32,
    /// Cruise speed of the sweeps, m/s.
    pub sweep_speed_mps: f32,
    /// Acceleration at the ends of a sweep, m/s².
    pub sweep_accel_mps2: f32,
    /// Rest between sweeps, s.
    pub sweep_rest_s: f32,
    /// Distance kept from either head by a sweep, m.
    pub sweep_margin_m: f32,
    /// Periods covered at cruise speed by each cogging sweep.
    pub cogging_periods: u32,
    /// Periods covered at cruise speed by each misalignment sweep.
    pub misalign_periods: u32,
    /// d-current on the slave during the misalignment sweeps, A.
    pub misalign_current_a: f32,
}

impl CalibrationConfig {
    /// Reference parameters for the reference machine: alignment at 20 A (a spring of
    /// 4.2e5 N/m, so static friction leaves 0.14 mm = 2° and cogging 0.07 mm = 1°, both
    /// cancelled by the averaging), damping ζ ≈ 0.7 on 12 kg; sweeps at 0.1 m/s (the cogging
    /// at 4 Hz, far below the 40 Hz position loop); 15 A on the slave shifts the master's
    /// force by 2·80·15·sin ε = 42 N per degree.
    pub const fn reference() -> Self {
        CalibrationConfig {
            sense_samples: 4000,
            sense_settle_s: 2e-3,
            sense_max_offset_codes: 100.0,
            sense_detect_a: 0.5,
            align_current_a: 20.0,
            align_damping_ns_per_m: 3000.0,
            align_points: 8,
            align_approach_periods: 1.0 / 18.0,
            align_rate_periods_per_s: 2.0,
            align_ramp_s: 0.1,
            align_first_settle_s: 0.2,
            align_settle_s: 0.06,
            align_average_s: 0.02,
            align_max_spread_periods: 1.0 / 36.0,
            sweep_speed_mps: 0.1,
            sweep_accel_mps2: 1.0,
            sweep_rest_s: 0.1,
            sweep_margin_m: 0.01,
            cogging_periods: 4,
            misalign_periods: 2,
            misalign_current_a: 15.0,
        }
    }
}

/// What a routine sees in one cycle.
#[derive(Clone, Copy, Debug)]
pub struct Measurements<'a> {
    /// Position (the homed frame once homed, else the raw frame), m.
    pub position_m: f32,
    /// Velocity, m/s.
    pub velocity_mps: f32,
    /// Each section's encoder angle, without offset (wrapping, 2³² = one period).
    pub angle: PerSection<u32>,
    /// The raw phase-current codes of both sections.
    pub currents: &'a PerSection<PhaseCurrentCodes>,
    /// Each section's force from its measured q-current, N.
    pub force_n: PerSection<f32>,
    /// Gas force from the measured chamber pressures, N.
    pub gas_force_n: f32,
}

/// A current vector in a frame at a forced angle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Forced {
    /// The frame's electrical angle (wrapping, 2³² = one period); the encoder is not used.
    pub angle: u32,
    /// The d/q current in that frame, A.
    pub current: Dq<f32>,
}

/// What the controller must do this cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Demand {
    /// Outputs off.
    Off,
    /// Run each section's current loop on a forced vector (`None`: zero current in the
    /// section's own frame).
    Forced(PerSection<Option<Forced>>),
    /// Position control on this setpoint. With `master_only` the master carries the whole
    /// force and the slave only the injected `slave_d_a` (in its calibrated frame).
    Track {
        /// The setpoint.
        setpoint: Setpoint,
        /// The slave carries no share of the force.
        master_only: bool,
        /// d-current injected into the slave, A.
        slave_d_a: f32,
    },
    /// Finished (the controller loads the outcome, or keeps the error).
    Done(Result<Outcome, CalibrationError>),
}

/// The result of the misalignment routine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Misalignment {
    /// The slave's electrical-angle offset, corrected (wrapping, 2³² = one period).
    pub slave_angle_offset: u32,
    /// The correction found, fraction of a period (ε/2π).
    pub correction_periods: f32,
    /// `D_dif` of Eq. 4: how far the slave's magnets sit from the master's, seen through
    /// both sections' encoders and angle offsets, m (within ±λ/2).
    pub misalignment_m: f32,
    /// Slave encoder minus master encoder, mean over whole periods, m (within ±λ/2; the
    /// controller takes the encoders' offset at homing, this is for the record).
    pub encoder_offset_m: f32,
}

/// The result of one routine: parameters for the [`ControlConfig`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// Phase-current offsets, codes from mid-scale.
    CurrentSense(PerSection<[f32; 3]>),
    /// Electrical-angle offsets.
    Alignment(PerSection<u32>),
    /// The slave's offset against the master's.
    Misalignment(Misalignment),
    /// The cogging map.
    Cogging(HarmonicMap),
}

impl Outcome {
    /// Loads the parameters into `config`.
    pub fn apply(&self, config: &mut ControlConfig) {
        match self {
            Outcome::CurrentSense(offsets) => {
                config.current_sense.master.offset_codes = offsets.master;
                config.current_sense.slave.offset_codes = offsets.slave;
            }
            Outcome::Alignment(offsets) => config.angle_offset = *offsets,
            Outcome::Misalignment(m) => config.angle_offset.slave = m.slave_angle_offset,
            Outcome::Cogging(map) => config.allocation.cogging = *map,
        }
    }
}

/// Why a routine failed (nothing is loaded).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum CalibrationError {
    /// A phase's zero is beyond the plausible range: the current sensor or its reference is
    /// broken. Check the section's sense amplifier and its supply.
    CurrentSenseOffset {
        /// The section.
        section: Section,
        /// The phase (0 = a).
        phase: u8,
    },
    /// The mover did not follow the forced vector (the estimates disagree): the section
    /// gives no force, or the mover is blocked. Check the section's phases.
    AlignmentSpread {
        /// The section.
        section: Section,
    },
    /// The master's force did not change as a slave frame error would explain (more than
    /// the d-current can give): check the slave's phases and both force constants.
    MisalignmentImplausible,
    /// No room for the sweeps between the heads from where the piston is.
    NoRoom,
}

/// Every parameter the calibration has loaded so far, and the last failure.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Calibrated {
    /// Phase-current offsets, codes.
    pub current_sense: Option<PerSection<[f32; 3]>>,
    /// Electrical-angle offsets from the alignment.
    pub alignment: Option<PerSection<u32>>,
    /// The misalignment (refines the slave's offset).
    pub misalignment: Option<Misalignment>,
    /// The cogging map.
    pub cogging: Option<HarmonicMap>,
    /// The last routine that failed, and why.
    pub last_error: Option<(Routine, CalibrationError)>,
}

impl Calibrated {
    /// Records a routine's result.
    pub fn record(&mut self, routine: Routine, result: Result<Outcome, CalibrationError>) {
        match result {
            Ok(Outcome::CurrentSense(o)) => self.current_sense = Some(o),
            Ok(Outcome::Alignment(o)) => {
                self.alignment = Some(o);
                // A misalignment was measured against the old frames.
                self.misalignment = None;
            }
            Ok(Outcome::Misalignment(m)) => self.misalignment = Some(m),
            Ok(Outcome::Cogging(map)) => self.cogging = Some(map),
            Err(e) => self.last_error = Some((routine, e)),
        }
    }

    /// Loads everything recorded into `config` (a firmware that stored the results loads
    /// them this way at start-up).
    pub fn apply(&self, config: &mut ControlConfig) {
        let loaded = [
            self.current_sense.map(Outcome::CurrentSense),
            self.alignment.map(Outcome::Alignment),
            self.misalignment.map(Outcome::Misalignment),
            self.cogging.map(Outcome::Cogging),
        ];
        for outcome in loaded.iter().flatten() {
            outcome.apply(config);
        }
    }
}

/// A running routine.
#[derive(Clone, Debug)]
pub struct Calibration {
    routine: Routine,
    state: State,
}

#[derive(Clone, Debug)]
enum State {
    CurrentSense(SenseAverage),
    Alignment(Aligner),
    Sweeps(Sweeps),
}

impl Calibration {
    /// Starts `routine` with the piston at `position_m` in the homed frame (`None` before
    /// homing: then only the routines that do not need the zero can run, and the alignment
    /// trusts the operator to have left it room). Refused with [`CalibrationError::NoRoom`]
    /// when the routine's travel would not fit between the heads.
    pub fn new(
        routine: Routine,
        config: &ControlConfig,
        position_m: Option<f32>,
    ) -> Result<Self, CalibrationError> {
        let c = &config.calibration;
        let dt = config.sample_time_s;
        let lambda = config.motor.electrical_period_m;
        let near = config.target_clearance_m + c.sweep_margin_m;
        let state = match (routine, position_m) {
            (Routine::CurrentSense, _) => State::CurrentSense(SenseAverage::new(c, dt)),
            (Routine::Alignment, at) => {
                // The mover goes up to half a period either way to the first angle, then one
                // period and an approach forward.
                let room = at.is_none_or(|x| {
                    x - 0.5 * lambda >= near
                        && x + (1.5 + c.align_approach_periods) * lambda <= config.travel_m - near
                });
                if !room {
                    return Err(CalibrationError::NoRoom);
                }
                State::Alignment(Aligner::new(config))
            }
            (_, None) => return Err(CalibrationError::NoRoom),
            (Routine::Misalignment, Some(position_m)) => State::Sweeps(Sweeps::new(
                config,
                position_m,
                c.misalign_periods,
                &MISALIGNMENT_LEGS,
            )?),
            (Routine::Cogging, Some(position_m)) => State::Sweeps(Sweeps::new(
                config,
                position_m,
                c.cogging_periods,
                &COGGING_LEGS,
            )?),
        };
        Ok(Calibration { routine, state })
    }

    /// The routine running.
    pub fn routine(&self) -> Routine {
        self.routine
    }

    /// One cycle: what was measured in, what to do out.
    pub fn step(&mut self, config: &ControlConfig, m: &Measurements) -> Demand {
        match &mut self.state {
            State::CurrentSense(s) => s.step(&config.calibration, m),
            State::Alignment(a) => a.step(config, m),
            State::Sweeps(s) => s.step(config, m, self.routine),
        }
    }
}

/// Current-sense offsets: the mean code of each phase with the outputs off.
#[derive(Clone, Debug)]
struct SenseAverage {
    settle: u32,
    samples: u32,
    sums: PerSection<[f32; 3]>,
}

impl SenseAverage {
    fn new(c: &CalibrationConfig, dt: f32) -> Self {
        SenseAverage {
            settle: cycles(c.sense_settle_s, dt),
            samples: 0,
            sums: PerSection::default(),
        }
    }

    fn step(&mut self, c: &CalibrationConfig, m: &Measurements) -> Demand {
        if self.settle > 0 {
            self.settle -= 1;
            return Demand::Off;
        }
        for section in Section::ALL {
            for (sum, code) in self
                .sums
                .get_mut(section)
                .iter_mut()
                .zip(m.currents.get(section))
            {
                *sum += f32::from(code.centered());
            }
        }
        self.samples += 1;
        if self.samples < c.sense_samples.max(1) {
            return Demand::Off;
        }
        let n = self.samples as f32;
        let mean = |s: &[f32; 3]| s.map(|v| v / n);
        let offsets = PerSection {
            master: mean(&self.sums.master),
            slave: mean(&self.sums.slave),
        };
        for section in Section::ALL {
            for (phase, o) in offsets.get(section).iter().enumerate() {
                if !within(*o, c.sense_max_offset_codes) {
                    return Demand::Done(Err(CalibrationError::CurrentSenseOffset {
                        section,
                        phase: phase as u8,
                    }));
                }
            }
        }
        Demand::Done(Ok(Outcome::CurrentSense(offsets)))
    }
}

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
struct Aligner {
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
    fn new(config: &ControlConfig) -> Self {
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

    fn step(&mut self, config: &ControlConfig, m: &Measurements) -> Demand {
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

/// One leg of a sweep routine.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Leg {
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
struct Sweeps {
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
    fn new(
        config: &ControlConfig,
        position_m: f32,
        periods: u32,
        legs: &'static [Leg],
    ) -> Result<Self, CalibrationError> {
        let c = &config.calibration;
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
            sums: if core::ptr::eq(legs, MISALIGNMENT_LEGS.as_slice()) {
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

    fn step(&mut self, config: &ControlConfig, m: &Measurements, routine: Routine) -> Demand {
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
                // The cogging estimate: what neither the motors nor the gas explain.
                let y = -(m.force_n.master + m.force_n.slave + m.gas_force_n);
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
fn trapezoid(
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

/// `|x| ≤ limit`, false for NaN.
fn within(x: f32, limit: f32) -> bool {
    x.abs() <= limit
}

/// Whole cycles in `s` seconds.
fn cycles(s: f32, dt: f32) -> u32 {
    if dt > 0.0 && s > 0.0 {
        (s / dt) as u32
    } else {
        0
    }
}

/// Watches the phase currents while the outputs are off: with no current flowing, their
/// mean must be zero once the calibrated offsets are taken off. A mean beyond
/// [`CalibrationConfig::sense_detect_a`] is a current-sense offset (drifted or never
/// calibrated); the controller then refuses to switch the outputs on until the current-sense
/// calibration has loaded new offsets.
///
/// A leaky mean of the raw codes (time constant 256 cycles = 12.8 ms), valid once 1024
/// outputs-off cycles have been seen; it runs only while the outputs are off.
#[derive(Clone, Debug, Default)]
pub struct SenseMonitor {
    mean_codes: PerSection<[f32; 3]>,
    seen: u16,
}

impl SenseMonitor {
    /// Cycles of outputs off before the mean is trusted.
    pub const VALID_AFTER: u16 = 1024;

    /// A monitor that has seen nothing.
    pub const fn new() -> Self {
        SenseMonitor {
            mean_codes: PerSection {
                master: [0.0; 3],
                slave: [0.0; 3],
            },
            seen: 0,
        }
    }

    /// One outputs-off sample of both sections' phase codes.
    pub fn observe(&mut self, currents: &PerSection<PhaseCurrentCodes>) {
        const ALPHA: f32 = 1.0 / 256.0;
        for section in Section::ALL {
            for (mean, code) in self
                .mean_codes
                .get_mut(section)
                .iter_mut()
                .zip(currents.get(section))
            {
                *mean += (f32::from(code.centered()) - *mean) * ALPHA;
            }
        }
        self.seen = self.seen.saturating_add(1);
    }

    /// The largest mean phase current with the outputs off, A, once valid (with the
    /// offsets of `config` taken off).
    pub fn residual_a(&self, config: &ControlConfig) -> Option<f32> {
        if self.seen < Self::VALID_AFTER {
            return None;
        }
        let mut worst = 0.0f32;
        for section in Section::ALL {
            let sense = config.current_sense.get(section);
            for (mean, offset) in self.mean_codes.get(section).iter().zip(sense.offset_codes) {
                let a = ((mean - offset) * sense.a_per_code).abs();
                // NaN sticks: a broken reading counts as the worst.
                if a > worst || a.is_nan() {
                    worst = a;
                }
            }
        }
        Some(worst)
    }

    /// Whether an offset is detected under `config`.
    pub fn offset_detected(&self, config: &ControlConfig) -> bool {
        self.residual_a(config)
            .is_some_and(|a| !within(a, config.calibration.sense_detect_a))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::units::AdcCode;

    #[test]
    fn routine_codes_are_stable() {
        for (i, r) in Routine::ALL.iter().enumerate() {
            assert_eq!(*r as u8 as usize, i);
            assert_eq!(Routine::from_code(i as u8), Some(*r));
        }
        assert_eq!(Routine::from_code(4), None);
    }

    #[test]
    fn routines_that_travel_need_room_between_the_heads() {
        let config = ControlConfig::reference();
        let room = |r, x| Calibration::new(r, &config, x).map(|_| ());
        // Cogging: 4 periods (96 mm) at cruise speed plus 10 mm of ramps, 10 mm from a head.
        assert_eq!(room(Routine::Cogging, Some(0.01)), Ok(()));
        assert_eq!(room(Routine::Cogging, Some(0.19)), Ok(()));
        assert_eq!(
            room(Routine::Cogging, Some(0.1)),
            Err(CalibrationError::NoRoom)
        );
        assert_eq!(room(Routine::Cogging, None), Err(CalibrationError::NoRoom));
        assert_eq!(room(Routine::Misalignment, Some(0.1)), Ok(()));
        assert_eq!(room(Routine::Alignment, None), Ok(()));
        assert_eq!(room(Routine::Alignment, Some(0.1)), Ok(()));
        assert_eq!(
            room(Routine::Alignment, Some(0.18)),
            Err(CalibrationError::NoRoom)
        );
        assert_eq!(
            room(Routine::Alignment, Some(0.015)),
            Err(CalibrationError::NoRoom)
        );
    }

    #[test]
    fn the_trapezoid_cruises_over_exactly_the_distance() {
        let c = CalibrationConfig::reference();
        let dt = 50e-6;
        let mut cruise = Vec::new();
        let mut k = 1;
        loop {
            let (sp, cruising, done) = trapezoid(&c, 0.048, 0.02, -1.0, k as f32 * dt);
            if cruising {
                cruise.push(sp.position_m);
            }
            if done {
                assert!((sp.position_m - (0.02 - 0.048 - 0.01)).abs() < 1e-6);
                break;
            }
            k += 1;
        }
        // 48 mm at 0.1 m/s: 9600 samples, 5 µm apart.
        assert!((cruise.len() as i32 - 9600).abs() <= 1, "{}", cruise.len());
        assert!((cruise[0] - cruise[cruise.len() - 1] - 0.048).abs() < 2e-5);
    }

    #[test]
    fn current_sense_offsets_are_the_mean_codes_and_implausible_ones_are_refused() {
        let mut config = ControlConfig::reference();
        config.calibration.sense_samples = 100;
        let run = |codes: PerSection<PhaseCurrentCodes>| {
            let mut cal = Calibration::new(Routine::CurrentSense, &config, None).unwrap();
            let m = Measurements {
                position_m: 0.0,
                velocity_mps: 0.0,
                angle: PerSection::default(),
                currents: &codes,
                force_n: PerSection::default(),
                gas_force_n: 0.0,
            };
            loop {
                match cal.step(&config, &m) {
                    Demand::Off => {}
                    Demand::Done(r) => return r,
                    d => panic!("{d:?}"),
                }
            }
        };
        let codes = PerSection {
            master: [AdcCode(2058), AdcCode(2040), AdcCode(2048)],
            slave: [AdcCode(2048), AdcCode(2049), AdcCode(2030)],
        };
        let r = run(codes);
        assert_eq!(
            r,
            Ok(Outcome::CurrentSense(PerSection {
                master: [10.0, -8.0, 0.0],
                slave: [0.0, 1.0, -18.0]
            }))
        );
        let broken = PerSection {
            master: [AdcCode::MID; 3],
            slave: [AdcCode::MID, AdcCode(2400), AdcCode::MID],
        };
        assert_eq!(
            run(broken),
            Err(CalibrationError::CurrentSenseOffset {
                section: Section::Slave,
                phase: 1
            })
        );
    }

    #[test]
    fn the_monitor_sees_an_offset_the_config_does_not_cancel() {
        let mut config = ControlConfig::reference();
        let mut monitor = SenseMonitor::new();
        let codes = PerSection {
            master: [AdcCode(2068), AdcCode::MID, AdcCode::MID],
            slave: [AdcCode::MID; 3],
        };
        for _ in 0..SenseMonitor::VALID_AFTER - 1 {
            monitor.observe(&codes);
        }
        assert_eq!(monitor.residual_a(&config), None);
        for _ in 0..2000 {
            monitor.observe(&codes);
        }
        // 20 codes ≈ 0.98 A.
        assert!(monitor.offset_detected(&config));
        config.current_sense.master.offset_codes = [20.0, 0.0, 0.0];
        assert!(!monitor.offset_detected(&config));
    }

    #[test]
    fn a_recorded_calibration_loads_into_a_config() {
        let mut record = Calibrated::default();
        record.record(
            Routine::Alignment,
            Ok(Outcome::Alignment(PerSection {
                master: 5,
                slave: 7,
            })),
        );
        let mut map = HarmonicMap::none();
        map.sin_n[0] = 30.0;
        record.record(Routine::Cogging, Ok(Outcome::Cogging(map)));
        record.record(Routine::Misalignment, Err(CalibrationError::NoRoom));
        let mut config = ControlConfig::reference();
        record.apply(&mut config);
        assert_eq!(config.angle_offset.slave, 7);
        assert_eq!(config.allocation.cogging, map);
        assert_eq!(
            record.last_error,
            Some((Routine::Misalignment, CalibrationError::NoRoom))
        );
    }
}
