//! Calibration routines: the machine parameters no drawing gives, measured on the machine by
//! the controller itself and loaded into its [`ControlConfig`].
//!
//! | routine | unknown | method | fills |
//! |---|---|---|---|
//! | [`Routine::CurrentSense`] | ADC zero of each phase | outputs off, average | `current_sense.*.offset_codes` |
//! | [`Routine::Alignment`] | encoder angle ↔ magnets, per section | a current vector at a forced angle, one section at a time, approached from both sides at 8 angles over a period | `angle_offset.*` |
//! | [`Routine::Misalignment`] | the slave's frame against the master's (Eq. 4's sine error) | the master alone holds the position on constant-velocity sweeps while the slave carries a d-current of ±I: the master's force changes by `2·K_f·I·sin ε` | `angle_offset.slave`; reports `D_dif` and the master−slave encoder offset |
//! | [`Routine::Cogging`] | detent force over the pitch | constant-velocity sweeps both ways under position control, `−(F_motors + F_gas)` fitted by harmonics; the two directions' average cancels friction | `allocation.cogging` |
//! | [`Routine::Commission`] | phase order, encoder direction, pitch, per section (a new or rewired machine, before alignment) | a current vector at a forced angle turned a period forward and back, both encoders read at rest ([`commission`]) | nothing: reports [`Commissioning`] |
//! | [`Routine::EncoderMap`] | the slave encoder's difference from the master's (paper §4.2, Fig. 6) | constant-velocity sweeps both ways at two speeds; the difference binned over the master's period, fitted as a saw stepping once a pitch, a part per direction and a velocity coefficient ([`encoder_map`]) | `encoder_map` (the slave's reading corrected) |
//!
//! Each routine is a state machine. While one runs, the controller calls
//! [`Calibration::step`] once per cycle with what it measured ([`Measurements`]) and does what
//! the returned [`Demand`] says: outputs off, a current vector in a forced frame, or position
//! control along a sweep. The last demand carries the [`Outcome`], which the controller loads
//! ([`Outcome::apply`]) and records ([`Calibrated`]). None of this runs in the normal step.
//!
//! The routines live in [`sense`] (current-sense zero and its monitor), [`align`] (angle
//! alignment) and [`sweeps`] (cogging, misalignment); this module holds what they share.
//! What they find survives a power cut: [`record`] encodes it (versioned, CRC-32) and
//! [`store`] keeps it in NOR flash, saved by a thread-mode task after each routine and loaded
//! at boot ([`crate::control::step::ControlStep::load_calibration`]).
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

use crate::control::config::ControlConfig;
use crate::motion::trajectory::Setpoint;
use crate::physics::cogging::HarmonicMap;
use crate::physics::motor::Dq;
use crate::ports::PhaseCurrentCodes;
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
    /// The slave encoder's difference from the master's, mapped and corrected (homed;
    /// optional: the machine runs without it).
    EncoderMap = 4,
    /// Phase order, encoder direction and pitch of both sections (forced current vector;
    /// works before homing; loads nothing).
    Commission = 5,
}

impl Routine {
    /// Every routine, in number order (and in the order a new machine runs them, homing
    /// between alignment and misalignment).
    pub const ALL: [Routine; 6] = [
        Routine::CurrentSense,
        Routine::Alignment,
        Routine::Misalignment,
        Routine::Cogging,
        Routine::EncoderMap,
        Routine::Commission,
    ];

    /// Stable snake_case name.
    pub const fn name(self) -> &'static str {
        match self {
            Routine::CurrentSense => "current_sense",
            Routine::Alignment => "alignment",
            Routine::Misalignment => "misalignment",
            Routine::Cogging => "cogging",
            Routine::EncoderMap => "encoder_map",
            Routine::Commission => "commission",
        }
    }

    /// The routine with number `code`.
    pub fn from_code(code: u8) -> Option<Routine> {
        Routine::ALL.iter().copied().find(|r| *r as u8 == code)
    }

    /// Whether this build runs the routine: the commissioning only on the host and in the
    /// firmware's `bench` build (Cargo.toml).
    pub const fn in_this_build(self) -> bool {
        !matches!(self, Routine::Commission) || cfg!(feature = "bench")
    }

    /// Whether the routine moves the piston under position control (it needs the zero).
    pub const fn needs_homing(self) -> bool {
        matches!(
            self,
            Routine::Misalignment | Routine::Cogging | Routine::EncoderMap
        )
    }
}

/// What a routine sees in one cycle.
#[derive(Clone, Copy, Debug)]
pub struct Measurements<'a> {
    /// Position (the homed frame once homed, else the raw frame), m.
    pub position_m: f32,
    /// The slave encoder's position in the same frame, m.
    pub slave_position_m: f32,
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
    /// The encoder-difference map.
    EncoderMap(EncoderMap),
    /// The wiring's findings (nothing to load).
    Commission(Commissioning),
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
            Outcome::EncoderMap(map) => config.encoder_map = Some(*map),
            Outcome::Commission(_) => {}
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
    /// The encoder map's sweeps left part of the period without a sample: the piston did not
    /// move as commanded. Check that it is free to move, then map again.
    MapIncomplete,
    /// The piston did not follow the section's turning vector (less than half the turn on
    /// an encoder, or not back): check the section's three phases are connected, the
    /// piston is free and away from the heads, and both encoders' signals.
    NoMotion {
        /// The section.
        section: Section,
    },
    /// The encoders' signs fit no wiring (one encoder read the sections' turns one way, the
    /// other differently): an encoder miscounts; check its signals.
    EncoderSigns,
}

impl core::fmt::Display for CalibrationError {
    /// What failed and what to check, in a line (the variants' own documentation).
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let section = |s: &Section| match s {
            Section::Master => "master",
            Section::Slave => "slave",
        };
        match self {
            CalibrationError::CurrentSenseOffset { section: s, phase } => write!(
                f,
                "the {} section's phase {} current zero is beyond the plausible range: check \
                 its sense amplifier and its supply",
                section(s),
                char::from(b'a' + phase % 3)
            ),
            CalibrationError::AlignmentSpread { section: s } => write!(
                f,
                "the mover did not follow the {} section's forced vector (the estimates \
                 disagree): the section gives no force or the mover is blocked; check its phases",
                section(s)
            ),
            CalibrationError::MisalignmentImplausible => f.write_str(
                "the master's force did not change as a slave frame error would explain: check \
                 the slave's phases and both force constants",
            ),
            CalibrationError::NoRoom => {
                f.write_str("no room for the sweeps between the heads from where the piston is")
            }
            CalibrationError::MapIncomplete => f.write_str(
                "the encoder map's sweeps left part of the period without a sample: check that \
                 the piston is free to move, then map again",
            ),
            CalibrationError::NoMotion { section: s } => write!(
                f,
                "the piston did not follow the {} section's turning vector: check its three \
                 phases are connected, the piston is free and away from the heads, and both \
                 encoders' signals",
                section(s)
            ),
            CalibrationError::EncoderSigns => f.write_str(
                "the encoders' signs fit no wiring: an encoder miscounts; check its signals",
            ),
        }
    }
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
    /// The last commissioning's findings (not stored: the wiring is checked again after a
    /// power cut). The bench build's.
    #[cfg(feature = "bench")]
    pub commission: Option<Commissioning>,
    /// The last routine that failed, and why.
    pub last_error: Option<(Routine, CalibrationError)>,
}

impl Calibrated {
    /// Records a routine's result. Out of line in the bench build (in flash, not the 20 kHz
    /// path's CCM SRAM, which its commissioning arm would grow): it runs once at the end of a
    /// routine.
    #[cfg_attr(feature = "bench", inline(never))]
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
            // Held in the configuration alone (`ControlConfig::encoder_map`), not in the
            // record: a record is copied whole at every boot and save, and the map is not
            // stored in flash (mapped again after a power cut).
            Ok(Outcome::EncoderMap(_)) => {}
            #[cfg(feature = "bench")]
            Ok(Outcome::Commission(found)) => self.commission = Some(found),
            #[cfg(not(feature = "bench"))]
            Ok(Outcome::Commission(_)) => {}
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
    EncoderMap(EncoderMapper),
    #[cfg(feature = "bench")]
    Commission(Commissioner),
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
            #[cfg(feature = "bench")]
            (Routine::Commission, at) => {
                // The mover may go the reach either way (the wiring decides which).
                let reach = Commissioner::reach_periods(config) * lambda;
                if !at.is_none_or(|x| x - reach >= near && x + reach <= config.travel_m - near) {
                    return Err(CalibrationError::NoRoom);
                }
                State::Commission(Commissioner::new())
            }
            // Refused before it gets here (`Refusal::BenchBuildOnly`).
            #[cfg(not(feature = "bench"))]
            (Routine::Commission, _) => return Err(CalibrationError::NoRoom),
            (_, None) => return Err(CalibrationError::NoRoom),
            (Routine::Misalignment | Routine::Cogging, Some(position_m)) => {
                State::Sweeps(Sweeps::new(config, position_m, routine)?)
            }
            (Routine::EncoderMap, Some(position_m)) => {
                State::EncoderMap(EncoderMapper::new(config, position_m)?)
            }
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
            State::EncoderMap(e) => e.step(config, m),
            #[cfg(feature = "bench")]
            State::Commission(c) => c.step(config, m),
        }
    }
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

mod align;
pub mod commission;
pub mod encoder_map;
pub mod record;
pub mod report;
mod sense;
pub mod store;
mod sweeps;

use align::Aligner;
#[cfg(feature = "bench")]
use commission::Commissioner;
pub use commission::Commissioning;
pub use encoder_map::EncoderMap;
use encoder_map::EncoderMapper;
use sense::SenseAverage;
pub use sense::SenseMonitor;
use sweeps::Sweeps;

#[cfg(test)]
mod tests {
    use super::sweeps::trapezoid;
    use super::*;
    use crate::control::config::CalibrationConfig;
    use crate::units::AdcCode;

    #[test]
    fn routine_codes_are_stable() {
        for (i, r) in Routine::ALL.iter().enumerate() {
            assert_eq!(*r as u8 as usize, i);
            assert_eq!(Routine::from_code(i as u8), Some(*r));
        }
        assert_eq!(Routine::from_code(Routine::ALL.len() as u8), None);
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
                slave_position_m: 0.0,
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
