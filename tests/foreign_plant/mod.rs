//! A foreign plant: run logs of the free-piston machine written without `fpc` or `hal-sim`.
//!
//! The model-gap workflow must work on logs from machines and simulators it has never seen,
//! so this module shares no code and no convention with the project's own plant. It uses
//! only `std`, `rand` and `rand_chacha`; the physics laws are those of the machine digest
//! (`docs/machine.md`), implemented here afresh, in a deliberately different style:
//!
//! - **Plant**: a rigid piston, `m·ẍ = F_master + F_slave + (p_A − p_B)·A_eff − F_fr(ẋ) −
//!   F_cog(x)`, integrated with classical fourth-order Runge–Kutta on sub-steps of at most
//!   [`MAX_SUBSTEP_S`], split exactly where a delayed drive force switches.
//! - **Controller**: a discrete PD position loop at the log rate, on a first-order-filtered
//!   finite-difference velocity (no Savitzky–Golay), with feed-forward of the nominal mass,
//!   the nominal friction and the measured gas force. Its force is held (zero-order hold)
//!   until the next sample; each section commands half of it, the slave receiving the
//!   master's setpoint.
//! - **Logger**: one row per controller update, written *before* the held force acts (the
//!   force in row k acts over `[t_k, t_k+1)`), with fixed decimals as a rig's logger would:
//!   1 µm, 0.01 N, 0.1 Pa. Both drives report the force they **command**: with a slave lag
//!   the logged slave force is the lagged one; an actuator lag is not visible in the logged
//!   forces at all. Noise: 3 N on each force, 0.4 kPa on each pressure, 1 µm on each
//!   encoder (seeded, ChaCha).
//! - **Chambers**: *vented* (rotation at rest, θ = 0, both chambers breathe to ambient
//!   through an orifice: quasi-steady loss `Δp = k·v·|v|`, so the pressures differ by a
//!   small loss growing with speed; the log has no `ports` key), or *sealed*
//!   (`# ports = closed`: two closed chambers of bore-minus-rod area with 0.5 mm dead
//!   lengths, ideal gas with the energy equation, starting near ambient or precharged).
//! - **Trajectories**: sine strokes (back-to-back half-cosine moves), trapezoids (constant
//!   acceleration, cruise, constant deceleration, short dwells) and holds-and-moves, several
//!   strokes of different speeds (0.25–2.5 m/s, always one ≥ 1.5 m/s) per log, strokes
//!   added until 3–5 s are reached (3–7 s in all); holds-and-moves also creep at
//!   0.05–0.25 m/s and keep their accelerations ≤ 150 m/s². Sample rates 5, 10 or 20 kHz.
//! - **Nominal machine** drawn around the reference machine: mass 8–14 kg, bore 85–92 mm,
//!   rod 18–24 mm, Coulomb 30–50 N, viscous 15–35 N·s/m; travel 0.205 m, dead lengths
//!   0.5 mm, pole pitch 12 mm, encoder period 24 mm. The nominal model file
//!   ([`Generated::model_toml`]) holds only the keys `docs/formats.md` §2 requires.
//!
//! # Hidden effects and their detection floors
//! Each hidden effect is drawn at a random magnitude at or above a floor chosen so that it
//! is plainly visible above the noise on the trajectories this module draws (every log has
//! a stroke of at least 1.5 m/s over ≥ 0.1 m, i.e. ≥ 30 m/s² and ≥ 10 kN/s of force slope):
//!
//! | effect | drawn | floor, and why it is visible |
//! |---|---|---|
//! | `mass_error` | true mass = nominal·(1 ± 8–25 %) | 8 % of ≥ 8 kg at ≥ 30 m/s² ≥ 19 N, 6× the force noise |
//! | `coulomb_friction` | true = nominal ± 15–40 N (kept ≥ 5 N) | 15 N on every moving sample, 5× the force noise |
//! | `viscous_friction` | true = nominal ± 20–80 N·s/m (kept ≥ 0) | 20 N·s/m at 1.5 m/s = 30 N |
//! | `stribeck_friction` | static = Coulomb + 25–80 N, v_s 5–40 mm/s, exponent 1 or 2 | 25 N at every breakaway and creep; logs are holds-and-moves |
//! | `cogging` | A·sin(2πx/p + φ), A 15–60 N, p 12 or 24 mm | 15 N = 5× the force noise, periodic in x |
//! | `actuator_lag` | both sections act 0.3–1.5 ms after the command | 0.3 ms × 10 kN/s = 3 N on fast strokes, over thousands of samples |
//! | `slave_lag` | slave acts (and reports) the master's setpoint 0.4–1.5 ms late | ≥ 2 samples at 5 kHz; the logged forces differ by d·dF/dt ≥ 4 N |
//! | `encoder_pitch_error` | slave reads x + a·sin(2πx/λ + φ) + s·x, a 10–40 µm, \|s\| ≤ 2e-4 | 10 µm = 10× the encoder noise |
//! | `leakage` | laminar clearance leak A↔B, gap 15–40 µm, seal 50 mm | at 15 µm and 3 bar across, > 10 kPa/s of decay in a hold (sealed only) |
//! | `heat_transfer` | `Q̇ = UA·(T_wall − T)`, UA 1–20 W/K | at 1 W/K the compression heat relaxes by tens of kPa in a hold (sealed only) |
//!
//! Delays are drawn on a continuous range: the logger samples the slave's setpoint on its
//! own grid, so the logged slave force moves by whole samples while the force that acts on
//! the piston switches at the true instant.
//!
//! `port_restriction` is out of scope: it needs ports timed by the rotation, and this plant
//! does not turn.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;
use std::fmt::Write as _;

/// Ambient (and suction) pressure, Pa.
pub const AMBIENT_PA: f64 = 101_325.0;
/// Gas constant of air, J/(kg·K).
pub const GAS_CONSTANT: f64 = 287.0;
/// Ratio of specific heats of air.
pub const GAMMA: f64 = 1.4;
/// Gas and wall temperature at the start, K.
pub const TEMPERATURE_K: f64 = 293.15;
/// Dynamic viscosity of air, Pa·s.
pub const AIR_VISCOSITY_PA_S: f64 = 1.8e-5;
/// Head-to-head travel, m.
pub const TRAVEL_M: f64 = 0.205;
/// Dead length of each chamber, m.
pub const DEAD_LENGTH_M: f64 = 0.0005;
/// Magnet pole pitch, m.
pub const POLE_PITCH_M: f64 = 0.012;
/// North-to-north magnet pitch, m.
pub const NN_PITCH_M: f64 = 0.024;
/// Encoder signal period, m.
pub const ENCODER_PERIOD_M: f64 = 0.024;
/// Axial length of the piston clearance seal, m.
pub const SEAL_LENGTH_M: f64 = 0.05;
/// Standard deviation of each logged force, N.
pub const FORCE_NOISE_N: f64 = 3.0;
/// Standard deviation of each logged pressure, Pa.
pub const PRESSURE_NOISE_PA: f64 = 400.0;
/// Standard deviation of each encoder reading, m.
pub const POSITION_NOISE_M: f64 = 1e-6;
/// Longest Runge–Kutta sub-step, s.
pub const MAX_SUBSTEP_S: f64 = 25e-6;
/// Velocity over which the friction sign is smoothed (tanh), m/s.
const FRICTION_SMOOTHING_MPS: f64 = 1e-3;
/// Peak force of one motor section, N.
const SECTION_LIMIT_N: f64 = 5_000.0;
/// Largest acceleration of a holds-and-moves move, m/s² (the sine strokes reach ~100).
const MAX_MOVE_ACCEL_MPS2: f64 = 150.0;

/// An effect the nominal model lacks, by the names of `docs/formats.md` §3.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Effect {
    /// True moving mass differs from the nominal one.
    MassError,
    /// True Coulomb friction differs from the nominal one.
    CoulombFriction,
    /// True viscous friction differs from the nominal one.
    ViscousFriction,
    /// Static friction above Coulomb, decaying with speed (Stribeck).
    StribeckFriction,
    /// Detent force periodic in position.
    Cogging,
    /// Both sections act later than commanded.
    ActuatorLag,
    /// The slave section applies the master's setpoint late.
    SlaveLag,
    /// The slave encoder has a periodic and a scale error.
    EncoderPitchError,
    /// Laminar leak across the piston clearance (sealed chambers).
    Leakage,
    /// Heat exchange between the gas and the wall (sealed chambers).
    HeatTransfer,
}

impl Effect {
    /// Every effect this plant can hide.
    pub const ALL: [Effect; 10] = [
        Effect::MassError,
        Effect::CoulombFriction,
        Effect::ViscousFriction,
        Effect::StribeckFriction,
        Effect::Cogging,
        Effect::ActuatorLag,
        Effect::SlaveLag,
        Effect::EncoderPitchError,
        Effect::Leakage,
        Effect::HeatTransfer,
    ];

    /// The name the workflow reports.
    pub fn name(self) -> &'static str {
        match self {
            Effect::MassError => "mass_error",
            Effect::CoulombFriction => "coulomb_friction",
            Effect::ViscousFriction => "viscous_friction",
            Effect::StribeckFriction => "stribeck_friction",
            Effect::Cogging => "cogging",
            Effect::ActuatorLag => "actuator_lag",
            Effect::SlaveLag => "slave_lag",
            Effect::EncoderPitchError => "encoder_pitch_error",
            Effect::Leakage => "leakage",
            Effect::HeatTransfer => "heat_transfer",
        }
    }

    /// Whether the effect exists only with sealed chambers.
    pub fn sealed_only(self) -> bool {
        matches!(self, Effect::Leakage | Effect::HeatTransfer)
    }

    /// Whether the effect shows only in holds (and creeping moves).
    pub fn needs_holds(self) -> bool {
        matches!(
            self,
            Effect::StribeckFriction | Effect::Leakage | Effect::HeatTransfer
        )
    }
}

/// A hidden effect with the parameters the plant uses (the truth).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Hidden {
    /// True moving mass, kg.
    MassError {
        /// kg
        mass_kg: f64,
    },
    /// True Coulomb friction, N.
    CoulombFriction {
        /// N
        coulomb_n: f64,
    },
    /// True viscous friction, N·s/m.
    ViscousFriction {
        /// N·s/m
        viscous_ns_per_m: f64,
    },
    /// `F = (F_c + (F_s − F_c)·exp(−|v/v_s|^ζ))·sgn(v)`.
    StribeckFriction {
        /// Static (breakaway) friction F_s, N.
        static_n: f64,
        /// Stribeck velocity v_s, m/s.
        velocity_mps: f64,
        /// Exponent ζ.
        exponent: f64,
    },
    /// `F_cog = A·sin(2πx/p + φ)`, opposing +x in the force balance.
    Cogging {
        /// A, N
        amplitude_n: f64,
        /// p, m
        period_m: f64,
        /// φ, rad
        phase_rad: f64,
    },
    /// Both sections act `delay_s` after the command.
    ActuatorLag {
        /// s
        delay_s: f64,
    },
    /// The slave applies (and reports) the master's setpoint `delay_s` late.
    SlaveLag {
        /// s
        delay_s: f64,
    },
    /// Slave encoder reads `x + a·sin(2πx/λ + φ) + scale·x`.
    EncoderPitchError {
        /// a, m
        amplitude_m: f64,
        /// λ, m
        period_m: f64,
        /// φ, rad
        phase_rad: f64,
        /// Scale error, 1.
        scale: f64,
    },
    /// Laminar clearance leak `ṁ = π·D·h³/(24·μ·R·T·L)·(p_hi² − p_lo²)`.
    Leakage {
        /// Radial gap h, m.
        gap_m: f64,
        /// Seal length L, m.
        seal_length_m: f64,
    },
    /// `Q̇ = UA·(T_wall − T)` in each chamber.
    HeatTransfer {
        /// UA, W/K
        ua_w_per_k: f64,
        /// Wall temperature, K.
        wall_k: f64,
    },
}

impl Hidden {
    /// Which effect this is.
    pub fn effect(&self) -> Effect {
        match self {
            Hidden::MassError { .. } => Effect::MassError,
            Hidden::CoulombFriction { .. } => Effect::CoulombFriction,
            Hidden::ViscousFriction { .. } => Effect::ViscousFriction,
            Hidden::StribeckFriction { .. } => Effect::StribeckFriction,
            Hidden::Cogging { .. } => Effect::Cogging,
            Hidden::ActuatorLag { .. } => Effect::ActuatorLag,
            Hidden::SlaveLag { .. } => Effect::SlaveLag,
            Hidden::EncoderPitchError { .. } => Effect::EncoderPitchError,
            Hidden::Leakage { .. } => Effect::Leakage,
            Hidden::HeatTransfer { .. } => Effect::HeatTransfer,
        }
    }

    /// The parameters, by the model file's key names.
    pub fn params(&self) -> Vec<(&'static str, f64)> {
        match *self {
            Hidden::MassError { mass_kg } => vec![("mass_kg", mass_kg)],
            Hidden::CoulombFriction { coulomb_n } => vec![("coulomb_n", coulomb_n)],
            Hidden::ViscousFriction { viscous_ns_per_m } => {
                vec![("viscous_ns_per_m", viscous_ns_per_m)]
            }
            Hidden::StribeckFriction {
                static_n,
                velocity_mps,
                exponent,
            } => vec![
                ("static_n", static_n),
                ("velocity_mps", velocity_mps),
                ("exponent", exponent),
            ],
            Hidden::Cogging {
                amplitude_n,
                period_m,
                phase_rad,
            } => vec![
                ("amplitude_n", amplitude_n),
                ("period_m", period_m),
                ("phase_rad", phase_rad),
            ],
            Hidden::ActuatorLag { delay_s } | Hidden::SlaveLag { delay_s } => {
                vec![("delay_s", delay_s)]
            }
            Hidden::EncoderPitchError {
                amplitude_m,
                period_m,
                phase_rad,
                scale,
            } => vec![
                ("amplitude_m", amplitude_m),
                ("period_m", period_m),
                ("phase_rad", phase_rad),
                ("scale", scale),
            ],
            Hidden::Leakage {
                gap_m,
                seal_length_m,
            } => vec![("gap_m", gap_m), ("seal_length_m", seal_length_m)],
            Hidden::HeatTransfer { ua_w_per_k, wall_k } => {
                vec![("ua_w_per_k", ua_w_per_k), ("wall_k", wall_k)]
            }
        }
    }
}

/// What a case hides.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CaseKind {
    /// Nothing: the nominal model is the truth.
    Null,
    /// One effect.
    One(Effect),
    /// Two effects.
    Two(Effect, Effect),
    /// Three effects.
    Three(Effect, Effect, Effect),
}

impl CaseKind {
    /// The hidden effects.
    pub fn effects(self) -> Vec<Effect> {
        match self {
            CaseKind::Null => Vec::new(),
            CaseKind::One(a) => vec![a],
            CaseKind::Two(a, b) => vec![a, b],
            CaseKind::Three(a, b, c) => vec![a, b, c],
        }
    }
}

/// A force outside the workflow's library (issue #30): what a rig adds that no named effect
/// describes. The workflow should say what it is in the terms of its discovery basis
/// (`docs/formats.md`, "Beyond the library"): [`Form::discovered_terms`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Form {
    /// A cable carrier's spring, `F = −k·(x − x_rest)`.
    Spring {
        /// k, N/m
        stiffness_n_per_m: f64,
        /// Where it is relaxed, m.
        rest_m: f64,
    },
    /// A constant push toward +x (a tilted axis), N.
    Bias {
        /// N
        force_n: f64,
    },
    /// Air drag, `F = −c·v·|v|`.
    QuadraticDrag {
        /// c, N·s²/m²
        coefficient: f64,
    },
    /// The drives push `(1 + error)` times the force they command and report.
    ForceConstant {
        /// Relative error of the motor constant, 1.
        error: f64,
    },
    /// Coulomb friction rising by `rate_n_per_s` every second of the log (seals warming).
    DriftingFriction {
        /// N/s
        rate_n_per_s: f64,
    },
    /// Friction growing with the distance from `centre_m`, against the motion (a bore worn
    /// toward its ends): `F = −slope·|x − centre|·sgn(v)`. Outside the discovery basis too.
    PositionFriction {
        /// N/m
        slope_n_per_m: f64,
        /// Where it vanishes, m.
        centre_m: f64,
    },
    /// A hardening spring, `F = −k₃·(x − x_rest)³`.
    CubicSpring {
        /// k₃, N/m³
        k3_n_per_m3: f64,
        /// Where it is relaxed, m.
        rest_m: f64,
    },
}

/// The forms outside the library, by name, in a fixed order.
pub const FORMS: [&str; 5] = [
    "spring",
    "bias",
    "quadratic_drag",
    "force_constant_error",
    "drifting_friction",
];

impl Form {
    /// Its name in [`FORMS`].
    pub fn name(&self) -> &'static str {
        match self {
            Form::Spring { .. } => "spring",
            Form::Bias { .. } => "bias",
            Form::QuadraticDrag { .. } => "quadratic_drag",
            Form::ForceConstant { .. } => "force_constant_error",
            Form::DriftingFriction { .. } => "drifting_friction",
            Form::PositionFriction { .. } => "position_friction",
            Form::CubicSpring { .. } => "cubic_spring",
        }
    }

    /// The terms of the discovery basis this force is, on the piston along +x, SI.
    pub fn discovered_terms(&self) -> std::collections::BTreeMap<&'static str, f64> {
        let terms: Vec<(&'static str, f64)> = match *self {
            Form::Spring {
                stiffness_n_per_m,
                rest_m,
            } => vec![("x", -stiffness_n_per_m), ("1", stiffness_n_per_m * rest_m)],
            Form::Bias { force_n } => vec![("1", force_n)],
            Form::QuadraticDrag { coefficient } => vec![("v|v|", -coefficient)],
            Form::ForceConstant { error } => vec![("f_motor", error)],
            // The level rises as rate·t and acts against the motion (this plant smooths
            // sgn(v) over 1 mm/s, far below the strokes' speeds).
            Form::DriftingFriction { rate_n_per_s } => vec![("t*sgn(v)", -rate_n_per_s)],
            // Not a sum of the basis's terms: |x − centre| has a corner.
            Form::PositionFriction { .. } => vec![],
            // −k₃·(x − x_rest)³ expanded in powers of x.
            Form::CubicSpring {
                k3_n_per_m3,
                rest_m,
            } => vec![
                ("x^3", -k3_n_per_m3),
                ("x^2", 3.0 * k3_n_per_m3 * rest_m),
                ("x", -3.0 * k3_n_per_m3 * rest_m * rest_m),
                ("1", k3_n_per_m3 * rest_m.powi(3)),
            ],
        };
        terms.into_iter().collect()
    }

    /// Whether it shows only on brisk strokes: drag lives at speed, and where the force is
    /// mostly friction (holds and creeping moves) a motor-constant error reads as a mass and
    /// a Coulomb error to within the noise.
    fn needs_speed(name: &str) -> bool {
        matches!(name, "quadratic_drag" | "force_constant_error")
    }

    /// Draws the form `name` at a magnitude a rig shows (well above the 3 N of force noise):
    /// springs of 0.8–3 kN/m relaxed within 3 cm of mid travel, 30–120 N of bias either way,
    /// 5–20 N·s²/m² of drag, a motor constant 4–12 % off either way, friction rising
    /// 3–12 N/s; friction growing 400–1200 N/m away from a point within 3 cm of mid travel,
    /// a hardening spring of 3·10⁵–1.5·10⁶ N/m³ relaxed within 2 cm of it. `None` for an
    /// unknown name.
    fn draw(rng: &mut ChaCha8Rng, name: &str) -> Option<Form> {
        Some(match name {
            "spring" => Form::Spring {
                stiffness_n_per_m: uniform(rng, 800.0, 3000.0),
                rest_m: 0.5 * TRAVEL_M + uniform(rng, -0.03, 0.03),
            },
            "bias" => Form::Bias {
                force_n: sign(rng) * uniform(rng, 30.0, 120.0),
            },
            "quadratic_drag" => Form::QuadraticDrag {
                coefficient: uniform(rng, 5.0, 20.0),
            },
            "force_constant_error" => Form::ForceConstant {
                error: sign(rng) * uniform(rng, 0.04, 0.12),
            },
            "drifting_friction" => Form::DriftingFriction {
                rate_n_per_s: uniform(rng, 3.0, 12.0),
            },
            "position_friction" => Form::PositionFriction {
                slope_n_per_m: uniform(rng, 400.0, 1200.0),
                centre_m: 0.5 * TRAVEL_M + uniform(rng, -0.03, 0.03),
            },
            "cubic_spring" => Form::CubicSpring {
                k3_n_per_m3: uniform(rng, 3e5, 1.5e6),
                rest_m: 0.5 * TRAVEL_M + uniform(rng, -0.02, 0.02),
            },
            _ => return None,
        })
    }
}

/// The triples of library effects hidden together.
pub const TRIPLES: [(Effect, Effect, Effect); 5] = [
    (Effect::MassError, Effect::CoulombFriction, Effect::SlaveLag),
    (Effect::Cogging, Effect::SlaveLag, Effect::EncoderPitchError),
    (
        Effect::MassError,
        Effect::Cogging,
        Effect::EncoderPitchError,
    ),
    (
        Effect::ViscousFriction,
        Effect::ActuatorLag,
        Effect::EncoderPitchError,
    ),
    (Effect::Leakage, Effect::HeatTransfer, Effect::SlaveLag),
];

/// A sensor that reads wrong (`docs/formats.md` §3's `pressure_offset`, `pressure_gain`,
/// `force_offset`, `force_gain`): one chamber's transducer or one section's force reading.
/// A reading is `gain·value + offset`; the controller works from the readings as the logger
/// writes them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SensorError {
    /// Chamber A's (`chamber_b`: B's) transducer reads `p + offset_pa`.
    PressureOffset {
        /// Which chamber.
        chamber_b: bool,
        /// Pa
        offset_pa: f64,
    },
    /// Chamber A's (`chamber_b`: B's) transducer reads `gain·p`.
    PressureGain {
        /// Which chamber.
        chamber_b: bool,
        /// 1
        gain: f64,
    },
    /// The master's (`slave`: the slave's) force reading is `F + offset_n`.
    ForceOffset {
        /// Which section.
        slave: bool,
        /// N
        offset_n: f64,
    },
    /// The master's (`slave`: the slave's) force reading is `gain·F`.
    ForceGain {
        /// Which section.
        slave: bool,
        /// 1
        gain: f64,
    },
}

impl SensorError {
    /// Whether `name` is a pressure transducer's error (it needs the pressure channel, so
    /// sealed chambers).
    fn on_pressure(name: &str) -> bool {
        matches!(name, "pressure_offset" | "pressure_gain")
    }

    /// Draws the error `name` on one chamber or section chosen at random: a transducer
    /// 1–5 kPa off or its gain 1.5–6 % off, a force reading 15–60 N off or its gain 3–10 %
    /// off, either way. `None` for another name.
    fn draw(rng: &mut ChaCha8Rng, name: &str) -> Option<SensorError> {
        // No draw at all for another name: the other cases' streams stay as they were.
        if !matches!(
            name,
            "pressure_offset" | "pressure_gain" | "force_offset" | "force_gain"
        ) {
            return None;
        }
        let which = rng.random::<bool>();
        Some(match name {
            "pressure_offset" => SensorError::PressureOffset {
                chamber_b: which,
                offset_pa: sign(rng) * uniform(rng, 1000.0, 5000.0),
            },
            "pressure_gain" => SensorError::PressureGain {
                chamber_b: which,
                gain: 1.0 + sign(rng) * uniform(rng, 0.015, 0.06),
            },
            "force_offset" => SensorError::ForceOffset {
                slave: which,
                offset_n: sign(rng) * uniform(rng, 15.0, 60.0),
            },
            "force_gain" => SensorError::ForceGain {
                slave: which,
                gain: 1.0 + sign(rng) * uniform(rng, 0.03, 0.10),
            },
            _ => return None,
        })
    }

    /// Chamber A's and B's transducers, then the master's and the slave's readings, each as
    /// (gain, offset).
    fn readings(this: Option<SensorError>) -> [(f64, f64); 4] {
        let mut r = [(1.0, 0.0); 4];
        match this {
            Some(SensorError::PressureOffset {
                chamber_b,
                offset_pa,
            }) => r[usize::from(chamber_b)].1 = offset_pa,
            Some(SensorError::PressureGain { chamber_b, gain }) => {
                r[usize::from(chamber_b)].0 = gain;
            }
            Some(SensorError::ForceOffset { slave, offset_n }) => {
                r[2 + usize::from(slave)].1 = offset_n;
            }
            Some(SensorError::ForceGain { slave, gain }) => r[2 + usize::from(slave)].0 = gain,
            None => {}
        }
        r
    }
}

/// The nominal machine (what the user's model file says).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Machine {
    /// Moving mass, kg.
    pub mass_kg: f64,
    /// Cylinder bore, m.
    pub bore_m: f64,
    /// Rod diameter, m.
    pub rod_m: f64,
    /// Coulomb friction, N.
    pub coulomb_n: f64,
    /// Viscous friction, N·s/m.
    pub viscous_ns_per_m: f64,
}

impl Machine {
    /// Effective piston area, m².
    pub fn area_m2(&self) -> f64 {
        PI / 4.0 * (self.bore_m * self.bore_m - self.rod_m * self.rod_m)
    }
}

/// The chambers' configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Chambers {
    /// Open to ambient through an orifice: `p_A = p_amb − k·v·|v|`, `p_B = p_amb + k·v·|v|`.
    Vented {
        /// k, Pa·s²/m²
        loss_pa_s2_per_m2: f64,
    },
    /// Closed chambers, both starting at `start_pa` with the piston at `start_m`.
    Sealed {
        /// Pressure of both chambers at the start, Pa.
        start_pa: f64,
    },
}

/// The shape family of a trajectory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// Back-to-back half-cosine strokes.
    Sine,
    /// Trapezoidal velocity strokes with short dwells.
    Trapezoid,
    /// Holds of 0.15–0.6 s between moves to random positions, some creeping.
    HoldsAndMoves,
}

/// How a move accelerates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Profile {
    /// Half-cosine position: the velocity is a half sine.
    Cosine,
    /// Constant acceleration, cruise, constant deceleration.
    Trapezoid {
        /// Acceleration, m/s².
        accel_mps2: f64,
    },
}

/// One piece of a trajectory.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Segment {
    /// Stay at the current position.
    Hold {
        /// s
        duration_s: f64,
    },
    /// Move to `to_m`.
    Move {
        /// Target position, m.
        to_m: f64,
        /// Peak speed, m/s.
        peak_speed_mps: f64,
        /// Velocity profile.
        profile: Profile,
    },
}

/// A position reference: a start and a list of segments.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    /// The shape family.
    pub shape: Shape,
    /// Start position, m.
    pub start_m: f64,
    /// The pieces, in order.
    pub segments: Vec<Segment>,
}

/// A segment resolved in time.
#[derive(Clone, Copy, Debug)]
struct Timed {
    t0: f64,
    dur: f64,
    from: f64,
    to: f64,
    /// Cosine: unused; trapezoid: acceleration phase duration, cruise speed.
    t_acc: f64,
    v_cruise: f64,
    kind: u8, // 0 hold, 1 cosine, 2 trapezoid
}

impl Trajectory {
    fn resolve(&self) -> Vec<Timed> {
        let mut out = Vec::with_capacity(self.segments.len());
        let mut t = 0.0;
        let mut x = self.start_m;
        for seg in &self.segments {
            let timed = match *seg {
                Segment::Hold { duration_s } => Timed {
                    t0: t,
                    dur: duration_s,
                    from: x,
                    to: x,
                    t_acc: 0.0,
                    v_cruise: 0.0,
                    kind: 0,
                },
                Segment::Move {
                    to_m,
                    peak_speed_mps,
                    profile,
                } => {
                    let dist = (to_m - x).abs();
                    match profile {
                        Profile::Cosine => Timed {
                            t0: t,
                            dur: PI * dist / (2.0 * peak_speed_mps),
                            from: x,
                            to: to_m,
                            t_acc: 0.0,
                            v_cruise: 0.0,
                            kind: 1,
                        },
                        Profile::Trapezoid { accel_mps2 } => {
                            // Triangular when the distance is too short to cruise.
                            let v = peak_speed_mps.min((dist * accel_mps2).sqrt());
                            let t_acc = v / accel_mps2;
                            let cruise = (dist - v * t_acc) / v;
                            Timed {
                                t0: t,
                                dur: 2.0 * t_acc + cruise.max(0.0),
                                from: x,
                                to: to_m,
                                t_acc,
                                v_cruise: v,
                                kind: 2,
                            }
                        }
                    }
                }
            };
            t += timed.dur;
            x = timed.to;
            out.push(timed);
        }
        out
    }

    /// Total duration, s.
    pub fn duration_s(&self) -> f64 {
        self.resolve().iter().map(|s| s.dur).sum()
    }
}

/// Reference (position, velocity, acceleration) at time t of one resolved segment.
fn reference_in(seg: &Timed, t: f64) -> (f64, f64, f64) {
    let tau = (t - seg.t0).clamp(0.0, seg.dur);
    let delta = seg.to - seg.from;
    match seg.kind {
        1 if seg.dur > 0.0 => {
            let w = PI / seg.dur;
            (
                seg.from + 0.5 * delta * (1.0 - (w * tau).cos()),
                0.5 * delta * w * (w * tau).sin(),
                0.5 * delta * w * w * (w * tau).cos(),
            )
        }
        2 if seg.dur > 0.0 => {
            let dir = delta.signum();
            let v = seg.v_cruise;
            let a = v / seg.t_acc;
            let (s, sv, sa) = if tau < seg.t_acc {
                (0.5 * a * tau * tau, a * tau, a)
            } else if tau <= seg.dur - seg.t_acc {
                (0.5 * v * seg.t_acc + v * (tau - seg.t_acc), v, 0.0)
            } else {
                let r = seg.dur - tau;
                (delta.abs() - 0.5 * a * r * r, a * r, -a)
            };
            (seg.from + dir * s, dir * sv, dir * sa)
        }
        _ => (seg.to, 0.0, 0.0),
    }
}

/// Everything that defines one log.
#[derive(Clone, Debug, PartialEq)]
pub struct Case {
    /// The seed it was drawn from (and its noise is drawn from).
    pub seed: u64,
    /// What it hides.
    pub kind: CaseKind,
    /// Log (and controller) rate, Hz: 5, 10 or 20 kHz.
    pub rate_hz: f64,
    /// The position reference.
    pub trajectory: Trajectory,
    /// Vented or sealed chambers.
    pub chambers: Chambers,
    /// The nominal machine.
    pub nominal: Machine,
    /// The hidden effects.
    pub hidden: Vec<Hidden>,
    /// A force outside the library, if the case hides one (then `kind` is `Null`).
    pub form: Option<Form>,
    /// A sensor that reads wrong, if the case hides one (then `kind` is `Null`).
    pub sensor: Option<SensorError>,
    /// Position-loop bandwidth, Hz.
    pub loop_hz: f64,
    /// Position-loop damping ratio.
    pub loop_damping: f64,
    /// Cut-off of the velocity filter, Hz.
    pub velocity_filter_hz: f64,
}

/// The truth of a case: the hidden effects and the true machine.
#[derive(Clone, Debug, PartialEq)]
pub struct Truth {
    /// The hidden effects with their parameters.
    pub hidden: Vec<Hidden>,
}

impl Truth {
    /// Names of the hidden effects, sorted.
    pub fn names(&self) -> Vec<&'static str> {
        let mut n: Vec<_> = self.hidden.iter().map(|h| h.effect().name()).collect();
        n.sort_unstable();
        n
    }

    /// The hidden effect of this kind, if any.
    pub fn get(&self, effect: Effect) -> Option<&Hidden> {
        self.hidden.iter().find(|h| h.effect() == effect)
    }
}

/// One generated case: the log, the nominal model and the truth.
#[derive(Clone, Debug)]
pub struct Generated {
    /// The run log (`docs/formats.md` §1) as text.
    pub csv: String,
    /// The nominal model file (`docs/formats.md` §2, required keys only).
    pub model_toml: String,
    /// What the model lacks.
    pub truth: Truth,
    /// Number of rows in the log.
    pub rows: usize,
}

fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

fn sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.random::<bool>() {
        1.0
    } else {
        -1.0
    }
}

/// A standard normal deviate (Box–Muller; one of the pair is dropped for simplicity).
fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1 = rng.random::<f64>().max(1e-300);
    let u2 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

fn draw_hidden(rng: &mut ChaCha8Rng, effect: Effect, nominal: &Machine) -> Hidden {
    match effect {
        Effect::MassError => Hidden::MassError {
            mass_kg: nominal.mass_kg * (1.0 + sign(rng) * uniform(rng, 0.08, 0.25)),
        },
        Effect::CoulombFriction => {
            let delta = uniform(rng, 15.0, 40.0);
            // Lower only when the result stays a real friction (≥ 5 N).
            let s = if nominal.coulomb_n - delta >= 5.0 {
                sign(rng)
            } else {
                1.0
            };
            Hidden::CoulombFriction {
                coulomb_n: nominal.coulomb_n + s * delta,
            }
        }
        Effect::ViscousFriction => {
            let delta = uniform(rng, 20.0, 80.0);
            let s = if nominal.viscous_ns_per_m - delta >= 0.0 {
                sign(rng)
            } else {
                1.0
            };
            Hidden::ViscousFriction {
                viscous_ns_per_m: nominal.viscous_ns_per_m + s * delta,
            }
        }
        Effect::StribeckFriction => Hidden::StribeckFriction {
            static_n: nominal.coulomb_n + uniform(rng, 25.0, 80.0),
            velocity_mps: uniform(rng, 0.005, 0.040),
            exponent: if rng.random::<bool>() { 1.0 } else { 2.0 },
        },
        Effect::Cogging => Hidden::Cogging {
            amplitude_n: uniform(rng, 15.0, 60.0),
            period_m: if rng.random::<bool>() {
                POLE_PITCH_M
            } else {
                NN_PITCH_M
            },
            phase_rad: uniform(rng, -PI, PI),
        },
        Effect::ActuatorLag => Hidden::ActuatorLag {
            delay_s: uniform(rng, 0.3e-3, 1.5e-3),
        },
        Effect::SlaveLag => Hidden::SlaveLag {
            delay_s: uniform(rng, 0.4e-3, 1.5e-3),
        },
        Effect::EncoderPitchError => Hidden::EncoderPitchError {
            amplitude_m: uniform(rng, 10e-6, 40e-6),
            period_m: ENCODER_PERIOD_M,
            phase_rad: uniform(rng, -PI, PI),
            scale: uniform(rng, -2e-4, 2e-4),
        },
        Effect::Leakage => Hidden::Leakage {
            gap_m: uniform(rng, 15e-6, 40e-6),
            seal_length_m: SEAL_LENGTH_M,
        },
        Effect::HeatTransfer => Hidden::HeatTransfer {
            ua_w_per_k: uniform(rng, 1.0, 20.0),
            wall_k: TEMPERATURE_K,
        },
    }
}

/// Draws a trajectory of 3–7 s (strokes until 3–5 s are reached) within `[lo, hi]`, starting at `start`.
fn draw_trajectory(rng: &mut ChaCha8Rng, shape: Shape, lo: f64, hi: f64, start: f64) -> Trajectory {
    let target_s = uniform(rng, 3.0, 5.0);
    let mut segments = vec![Segment::Hold {
        duration_s: uniform(rng, 0.2, 0.4),
    }];
    let mut x = start;
    let mut t = segments_duration(&segments, start);
    // Strokes of different speeds; one fast stroke comes early so that every log has one.
    let fast_at = rng.random_range(0..2usize);
    let mut n = 0usize;
    let push = |segments: &mut Vec<Segment>, seg: Segment, x: &mut f64, t: &mut f64| {
        let traj = Trajectory {
            shape,
            start_m: *x,
            segments: vec![seg],
        };
        *t += traj.duration_s();
        if let Segment::Move { to_m, .. } = seg {
            *x = to_m;
        }
        segments.push(seg);
    };
    while t < target_s {
        let fast = n == fast_at;
        let speed = if fast {
            uniform(rng, 1.5, 2.5)
        } else {
            uniform(rng, 0.25, 2.5)
        };
        n += 1;
        match shape {
            Shape::Sine => {
                // A there-and-back pair at this speed, end to end.
                for _ in 0..2 {
                    let to = if (x - lo).abs() < (x - hi).abs() {
                        hi
                    } else {
                        lo
                    };
                    let seg = Segment::Move {
                        to_m: to,
                        peak_speed_mps: speed,
                        profile: Profile::Cosine,
                    };
                    push(&mut segments, seg, &mut x, &mut t);
                }
            }
            Shape::Trapezoid => {
                let accel = uniform(rng, 20.0, 80.0);
                for _ in 0..2 {
                    let to = if (x - lo).abs() < (x - hi).abs() {
                        hi
                    } else {
                        lo
                    };
                    let seg = Segment::Move {
                        to_m: to,
                        peak_speed_mps: speed,
                        profile: Profile::Trapezoid { accel_mps2: accel },
                    };
                    push(&mut segments, seg, &mut x, &mut t);
                    let dwell = uniform(rng, 0.0, 0.1);
                    if dwell > 0.01 {
                        push(
                            &mut segments,
                            Segment::Hold { duration_s: dwell },
                            &mut x,
                            &mut t,
                        );
                    }
                }
            }
            Shape::HoldsAndMoves => {
                // A move to a random target at least 30 mm away, then a hold; every third
                // move creeps (never the fast one).
                let mut to = uniform(rng, lo, hi);
                while (to - x).abs() < 0.03 {
                    to = uniform(rng, lo, hi);
                }
                let creep = n.is_multiple_of(3) && !fast;
                let v = if creep {
                    uniform(rng, 0.05, 0.25)
                } else {
                    speed
                };
                // Short fast moves would ask for hundreds of m/s²: the speed is capped so a
                // half-cosine move stays within MAX_MOVE_ACCEL_MPS2 (2v²/Δ), and the fast
                // move goes to the far end of the range.
                if fast {
                    to = if (x - lo).abs() > (x - hi).abs() {
                        lo
                    } else {
                        hi
                    };
                }
                let v = v.min((MAX_MOVE_ACCEL_MPS2 * (to - x).abs() / 2.0).sqrt());
                let profile = if rng.random::<bool>() {
                    Profile::Cosine
                } else {
                    Profile::Trapezoid {
                        accel_mps2: uniform(rng, 10.0, 60.0),
                    }
                };
                let seg = Segment::Move {
                    to_m: to,
                    peak_speed_mps: v,
                    profile,
                };
                push(&mut segments, seg, &mut x, &mut t);
                let hold = Segment::Hold {
                    duration_s: uniform(rng, 0.15, 0.6),
                };
                push(&mut segments, hold, &mut x, &mut t);
            }
        }
    }
    segments.push(Segment::Hold { duration_s: 0.1 });
    Trajectory {
        shape,
        start_m: start,
        segments,
    }
}

fn segments_duration(segments: &[Segment], start: f64) -> f64 {
    Trajectory {
        shape: Shape::Sine,
        start_m: start,
        segments: segments.to_vec(),
    }
    .duration_s()
}

/// Draws one case: the machine, its hidden effects, the chambers, the trajectory and rate.
pub fn draw_case(seed: u64, kind: CaseKind) -> Case {
    draw(seed, kind, None)
}

/// Draws one case that hides the force outside the library named `form` (one of
/// [`FORMS`]) and no library effect; `None` for an unknown name.
pub fn draw_form_case(seed: u64, form: &str) -> Option<Case> {
    FORMS
        .contains(&form)
        .then(|| draw(seed, CaseKind::Null, Some(form)))
}

/// Draws case `k` of the field-log form `form` (one of [`FIELD_FORMS`](crate::support::forms::FIELD_FORMS)): for `"triple"`,
/// the `k`-th of [`TRIPLES`] in turn; else the form or sensor error alone. `None` for an
/// unknown name.
pub fn draw_field_case(seed: u64, form: &str, k: usize) -> Option<Case> {
    if !crate::support::forms::FIELD_FORMS.contains(&form) {
        return None;
    }
    Some(if form == "triple" {
        let (a, b, c) = TRIPLES[k % TRIPLES.len()];
        draw(seed, CaseKind::Three(a, b, c), None)
    } else {
        draw(seed, CaseKind::Null, Some(form))
    })
}

fn draw(seed: u64, kind: CaseKind, form: Option<&str>) -> Case {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let effects = kind.effects();
    // Rounded as a user would write them: the model file then says exactly what the
    // plant uses.
    let round = |v: f64, step: f64| (v / step).round() * step;
    let nominal = Machine {
        mass_kg: round(uniform(&mut rng, 8.0, 14.0), 1e-3),
        bore_m: round(uniform(&mut rng, 0.085, 0.092), 1e-4),
        rod_m: round(uniform(&mut rng, 0.018, 0.024), 1e-4),
        coulomb_n: round(uniform(&mut rng, 30.0, 50.0), 0.01),
        viscous_ns_per_m: round(uniform(&mut rng, 15.0, 35.0), 0.01),
    };
    let rate_hz = [5_000.0, 10_000.0, 20_000.0][rng.random_range(0..3usize)];
    let sealed = effects.iter().any(|e| e.sealed_only())
        || form.is_some_and(SensorError::on_pressure)
        || rng.random_range(0..3u32) == 0;
    let chambers = if sealed {
        let start_pa = if rng.random_range(0..3u32) == 0 {
            uniform(&mut rng, 1.5e5, 2.2e5)
        } else {
            AMBIENT_PA * uniform(&mut rng, 0.99, 1.01)
        };
        Chambers::Sealed { start_pa }
    } else {
        // k = ρ/2·(A_eff/(C_d·A_o))² for an orifice of 10–14 mm, C_d 0.6–0.8.
        let rho = AMBIENT_PA / (GAS_CONSTANT * TEMPERATURE_K);
        let d_o = uniform(&mut rng, 0.010, 0.014);
        let cd = uniform(&mut rng, 0.6, 0.8);
        let ratio = nominal.area_m2() / (cd * PI / 4.0 * d_o * d_o);
        Chambers::Vented {
            loss_pa_s2_per_m2: 0.5 * rho * ratio * ratio,
        }
    };
    let shape = if effects.iter().any(|e| e.needs_holds()) {
        Shape::HoldsAndMoves
    } else if form.is_some_and(Form::needs_speed) {
        [Shape::Sine, Shape::Trapezoid][rng.random_range(0..2usize)]
    } else {
        [Shape::Sine, Shape::Trapezoid, Shape::HoldsAndMoves][rng.random_range(0..3usize)]
    };
    // Sealed strokes stay nearer the middle: 5 bar at most from ambient, ~6 from a precharge.
    let (lo, hi, start) = if sealed {
        (
            uniform(&mut rng, 0.045, 0.055),
            uniform(&mut rng, 0.150, 0.160),
            0.5 * TRAVEL_M,
        )
    } else {
        let lo = uniform(&mut rng, 0.028, 0.040);
        (lo, uniform(&mut rng, 0.165, 0.177), lo)
    };
    let trajectory = draw_trajectory(&mut rng, shape, lo, hi, start);
    let mut hidden: Vec<Hidden> = effects
        .iter()
        .map(|&e| draw_hidden(&mut rng, e, &nominal))
        .collect();
    // Stiction stands above the true Coulomb level, whichever that is.
    let coulomb_shift = hidden.iter().find_map(|h| match *h {
        Hidden::CoulombFriction { coulomb_n } => Some(coulomb_n - nominal.coulomb_n),
        _ => None,
    });
    for h in &mut hidden {
        if let Hidden::StribeckFriction { static_n, .. } = h {
            *static_n += coulomb_shift.unwrap_or(0.0);
        }
    }
    let loop_hz = uniform(&mut rng, 25.0, 40.0);
    let loop_damping = uniform(&mut rng, 0.6, 0.8);
    let velocity_filter_hz = uniform(&mut rng, 250.0, 400.0);
    // Drawn last, so that the library's cases are the same with or without forms.
    let sensor = form.and_then(|name| SensorError::draw(&mut rng, name));
    let form = form.and_then(|name| Form::draw(&mut rng, name));
    Case {
        seed,
        kind,
        rate_hz,
        trajectory,
        chambers,
        nominal,
        hidden,
        form,
        sensor,
        loop_hz,
        loop_damping,
        velocity_filter_hz,
    }
}

/// The true physics of one case, with every hidden effect applied.
#[derive(Clone, Copy, Debug)]
struct Physics {
    mass_kg: f64,
    area_m2: f64,
    bore_m: f64,
    coulomb_n: f64,
    static_n: f64,
    stribeck_mps: f64,
    stribeck_exp: f64,
    viscous: f64,
    cog_amp_n: f64,
    cog_k: f64,
    cog_phase: f64,
    /// Laminar leak coefficient `π·D·h³/(24·μ·R·L)`, kg·K/(s·Pa²); divided by T upstream.
    leak: f64,
    ua_w_per_k: f64,
    wall_k: f64,
    vent_k: Option<f64>,
    /// Spring of a form, (k, x_rest).
    spring: Option<(f64, f64)>,
    /// Constant push of a form, N.
    bias_n: f64,
    /// Drag coefficient of a form, N·s²/m².
    drag: f64,
    /// Friction growing along the bore of a form, (slope N/m, centre m).
    position_friction: Option<(f64, f64)>,
    /// Hardening spring of a form, (k₃ N/m³, x_rest m).
    cubic: Option<(f64, f64)>,
}

impl Physics {
    fn new(case: &Case) -> Physics {
        let n = &case.nominal;
        let mut p = Physics {
            mass_kg: n.mass_kg,
            area_m2: n.area_m2(),
            bore_m: n.bore_m,
            coulomb_n: n.coulomb_n,
            static_n: n.coulomb_n,
            stribeck_mps: 0.02,
            stribeck_exp: 1.0,
            viscous: n.viscous_ns_per_m,
            cog_amp_n: 0.0,
            cog_k: 0.0,
            cog_phase: 0.0,
            leak: 0.0,
            ua_w_per_k: 0.0,
            wall_k: TEMPERATURE_K,
            vent_k: match case.chambers {
                Chambers::Vented { loss_pa_s2_per_m2 } => Some(loss_pa_s2_per_m2),
                Chambers::Sealed { .. } => None,
            },
            spring: None,
            bias_n: 0.0,
            drag: 0.0,
            position_friction: None,
            cubic: None,
        };
        match case.form {
            Some(Form::Spring {
                stiffness_n_per_m,
                rest_m,
            }) => p.spring = Some((stiffness_n_per_m, rest_m)),
            Some(Form::Bias { force_n }) => p.bias_n = force_n,
            Some(Form::QuadraticDrag { coefficient }) => p.drag = coefficient,
            Some(Form::PositionFriction {
                slope_n_per_m,
                centre_m,
            }) => p.position_friction = Some((slope_n_per_m, centre_m)),
            Some(Form::CubicSpring {
                k3_n_per_m3,
                rest_m,
            }) => p.cubic = Some((k3_n_per_m3, rest_m)),
            // Applied where the drives act and where time passes (`generate`).
            Some(Form::ForceConstant { .. } | Form::DriftingFriction { .. }) | None => {}
        }
        let mut stribeck_static = None;
        for h in &case.hidden {
            match *h {
                Hidden::MassError { mass_kg } => p.mass_kg = mass_kg,
                Hidden::CoulombFriction { coulomb_n } => p.coulomb_n = coulomb_n,
                Hidden::ViscousFriction { viscous_ns_per_m } => p.viscous = viscous_ns_per_m,
                Hidden::StribeckFriction {
                    static_n,
                    velocity_mps,
                    exponent,
                } => {
                    stribeck_static = Some(static_n);
                    p.stribeck_mps = velocity_mps;
                    p.stribeck_exp = exponent;
                }
                Hidden::Cogging {
                    amplitude_n,
                    period_m,
                    phase_rad,
                } => {
                    p.cog_amp_n = amplitude_n;
                    p.cog_k = 2.0 * PI / period_m;
                    p.cog_phase = phase_rad;
                }
                Hidden::Leakage {
                    gap_m,
                    seal_length_m,
                } => {
                    p.leak = PI * p.bore_m * gap_m.powi(3)
                        / (24.0 * AIR_VISCOSITY_PA_S * GAS_CONSTANT * seal_length_m);
                }
                Hidden::HeatTransfer { ua_w_per_k, wall_k } => {
                    p.ua_w_per_k = ua_w_per_k;
                    p.wall_k = wall_k;
                }
                Hidden::ActuatorLag { .. }
                | Hidden::SlaveLag { .. }
                | Hidden::EncoderPitchError { .. } => {}
            }
        }
        // Without a Stribeck effect the static level is the (true) Coulomb one.
        p.static_n = stribeck_static.unwrap_or(p.coulomb_n);
        p
    }

    fn friction(&self, v: f64) -> f64 {
        let level = if self.static_n > self.coulomb_n {
            let r = (v / self.stribeck_mps).abs();
            let decay = if self.stribeck_exp == 1.0 {
                (-r).exp()
            } else {
                (-r.powf(self.stribeck_exp)).exp()
            };
            self.coulomb_n + (self.static_n - self.coulomb_n) * decay
        } else {
            self.coulomb_n
        };
        level * (v / FRICTION_SMOOTHING_MPS).tanh() + self.viscous * v
    }

    fn cogging(&self, x: f64) -> f64 {
        if self.cog_amp_n == 0.0 {
            0.0
        } else {
            self.cog_amp_n * (self.cog_k * x + self.cog_phase).sin()
        }
    }

    /// The force of a spring, bias, drag, bore-friction or cubic-spring form, toward +x.
    fn extra(&self, x: f64, v: f64) -> f64 {
        let spring = self.spring.map_or(0.0, |(k, rest)| -k * (x - rest));
        let bore = self.position_friction.map_or(0.0, |(slope, centre)| {
            -slope * (x - centre).abs() * (v / FRICTION_SMOOTHING_MPS).tanh()
        });
        let cubic = self
            .cubic
            .map_or(0.0, |(k3, rest)| -k3 * (x - rest).powi(3));
        spring + self.bias_n - self.drag * v * v.abs() + bore + cubic
    }

    fn vented_pressures(k: f64, v: f64) -> (f64, f64) {
        let loss = k * v * v.abs();
        (AMBIENT_PA - loss, AMBIENT_PA + loss)
    }

    /// State: x, v, p_A, p_B, m_A, m_B (sealed; vented ignores the gas entries).
    fn derivative(&self, s: &[f64; 6], motor_n: f64) -> [f64; 6] {
        let (x, v) = (s[0], s[1]);
        let (pa, pb) = match self.vent_k {
            Some(k) => Physics::vented_pressures(k, v),
            None => (s[2], s[3]),
        };
        let accel = (motor_n + (pa - pb) * self.area_m2 - self.friction(v) - self.cogging(x)
            + self.extra(x, v))
            / self.mass_kg;
        if self.vent_k.is_some() {
            return [v, accel, 0.0, 0.0, 0.0, 0.0];
        }
        let (ma, mb) = (s[4], s[5]);
        let va = self.area_m2 * (x + DEAD_LENGTH_M);
        let vb = self.area_m2 * (TRAVEL_M - x + DEAD_LENGTH_M);
        let dva = self.area_m2 * v;
        let dvb = -dva;
        let ta = pa * va / (ma * GAS_CONSTANT);
        let tb = pb * vb / (mb * GAS_CONSTANT);
        // Leak A→B (negative: B→A), temperature of the upstream chamber.
        let leak_ab = if self.leak > 0.0 {
            let t_up = if pa >= pb { ta } else { tb };
            self.leak / t_up * (pa * pa - pb * pb)
        } else {
            0.0
        };
        let (qa, qb) = if self.ua_w_per_k > 0.0 {
            (
                self.ua_w_per_k * (self.wall_k - ta),
                self.ua_w_per_k * (self.wall_k - tb),
            )
        } else {
            (0.0, 0.0)
        };
        // dp/dt = γR/V·(ṁ_in·T_up − ṁ_out·T) − γ·p/V·dV/dt + (γ−1)/V·Q̇
        let (enth_a, enth_b) = if leak_ab >= 0.0 {
            (-leak_ab * ta, leak_ab * ta)
        } else {
            (-leak_ab * tb, leak_ab * tb)
        };
        let dpa =
            GAMMA * GAS_CONSTANT / va * enth_a - GAMMA * pa / va * dva + (GAMMA - 1.0) / va * qa;
        let dpb =
            GAMMA * GAS_CONSTANT / vb * enth_b - GAMMA * pb / vb * dvb + (GAMMA - 1.0) / vb * qb;
        [v, accel, dpa, dpb, -leak_ab, leak_ab]
    }

    fn rk4(&self, s: &mut [f64; 6], motor_n: f64, h: f64) {
        let add = |a: &[f64; 6], k: &[f64; 6], f: f64| {
            let mut o = *a;
            for (oi, ki) in o.iter_mut().zip(k) {
                *oi += f * ki;
            }
            o
        };
        let k1 = self.derivative(s, motor_n);
        let k2 = self.derivative(&add(s, &k1, 0.5 * h), motor_n);
        let k3 = self.derivative(&add(s, &k2, 0.5 * h), motor_n);
        let k4 = self.derivative(&add(s, &k3, h), motor_n);
        for i in 0..6 {
            s[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }

    /// Integrates over `len` seconds with a constant motor force.
    fn advance(&self, s: &mut [f64; 6], motor_n: f64, len: f64) {
        if len <= 0.0 {
            return;
        }
        let n = (len / MAX_SUBSTEP_S).ceil().max(1.0);
        let h = len / n;
        for _ in 0..n as usize {
            self.rk4(s, motor_n, h);
        }
    }

    fn pressures(&self, s: &[f64; 6]) -> (f64, f64) {
        match self.vent_k {
            Some(k) => Physics::vented_pressures(k, s[1]),
            None => (s[2], s[3]),
        }
    }
}

/// A delay split into whole samples and the remainder within a sample.
#[derive(Clone, Copy, Debug)]
struct Shift {
    whole: usize,
    rest_s: f64,
}

impl Shift {
    fn new(delay_s: f64, period_s: f64) -> Shift {
        let q = delay_s / period_s;
        let mut whole = (q + 1e-9).floor();
        let mut rest = delay_s - whole * period_s;
        if rest < 1e-9 * period_s {
            rest = 0.0;
        }
        if rest >= period_s {
            whole += 1.0;
            rest -= period_s;
        }
        Shift {
            whole: whole as usize,
            rest_s: rest,
        }
    }
}

/// The command of sample `k − back`, or 0 before the log starts (the drives idle).
fn earlier(cmds: &[f64], k: usize, back: usize) -> f64 {
    k.checked_sub(back).map_or(0.0, |i| cmds[i])
}

/// Runs the case and writes its log, its nominal model and its truth.
pub fn generate(case: &Case) -> Generated {
    let mut rng = ChaCha8Rng::seed_from_u64(case.seed ^ 0x5eed_1095_u64.rotate_left(32));
    let mut phys = Physics::new(case);
    let period = 1.0 / case.rate_hz;
    // A motor-constant error scales what acts, not what is commanded and logged; drifting
    // friction raises the Coulomb level sample by sample.
    let (motor_gain, drift) = match case.form {
        Some(Form::ForceConstant { error }) => (1.0 + error, 0.0),
        Some(Form::DriftingFriction { rate_n_per_s }) => (1.0, rate_n_per_s),
        _ => (1.0, 0.0),
    };
    let coulomb_at_start = phys.coulomb_n;
    let [(ga, oa), (gb, ob), (gm, om), (gs, os)] = SensorError::readings(case.sensor);
    let timed = case.trajectory.resolve();
    let total_s = timed.iter().map(|s| s.dur).sum::<f64>();
    let rows = (total_s * case.rate_hz).floor() as usize;

    let mut actuator = 0.0;
    let mut slave = 0.0;
    let mut pitch: Option<(f64, f64, f64, f64)> = None;
    for h in &case.hidden {
        match *h {
            Hidden::ActuatorLag { delay_s } => actuator = delay_s,
            Hidden::SlaveLag { delay_s } => slave = delay_s,
            Hidden::EncoderPitchError {
                amplitude_m,
                period_m,
                phase_rad,
                scale,
            } => pitch = Some((amplitude_m, 2.0 * PI / period_m, phase_rad, scale)),
            _ => {}
        }
    }
    let master_shift = Shift::new(actuator, period);
    let slave_act_shift = Shift::new(actuator + slave, period);
    let slave_log_shift = Shift::new(slave, period);

    // Initial state: at rest at the start; sealed chambers at their start pressure.
    let mut s = [case.trajectory.start_m, 0.0, 0.0, 0.0, 0.0, 0.0];
    if let Chambers::Sealed { start_pa } = case.chambers {
        let va = phys.area_m2 * (s[0] + DEAD_LENGTH_M);
        let vb = phys.area_m2 * (TRAVEL_M - s[0] + DEAD_LENGTH_M);
        s[2] = start_pa;
        s[3] = start_pa;
        s[4] = start_pa * va / (GAS_CONSTANT * TEMPERATURE_K);
        s[5] = start_pa * vb / (GAS_CONSTANT * TEMPERATURE_K);
    }

    // Controller: PD on a filtered finite difference, with feed-forward, at the log rate.
    let nom = &case.nominal;
    let w = 2.0 * PI * case.loop_hz;
    let kp = nom.mass_kg * w * w;
    let kd = 2.0 * case.loop_damping * w * nom.mass_kg;
    let alpha = 1.0 - (-2.0 * PI * case.velocity_filter_hz * period).exp();
    let nominal_area = nom.area_m2();
    let mut v_filtered = 0.0;
    let mut x_prev: Option<f64> = None;

    let mut section_cmd: Vec<f64> = Vec::with_capacity(rows);
    let mut csv = String::with_capacity(rows * 72 + 256);
    csv.push_str("# source = foreign test plant (RK4 piston, PD loop), seed ");
    let _ = writeln!(csv, "{}", case.seed);
    if matches!(case.chambers, Chambers::Sealed { .. }) {
        csv.push_str("# ports = closed\n");
    }
    csv.push_str("t_s,x_m,x_slave_m,theta_rad,f_master_n,f_slave_n,p_a_pa,p_b_pa\n");

    let mut seg_i = 0usize;
    let quantise = |v: f64, step: f64| (v / step).round() * step;
    for k in 0..rows {
        let t = k as f64 * period;
        phys.coulomb_n = coulomb_at_start + drift * t;
        // Sensors.
        let x = s[0];
        let x_meas = quantise(x + POSITION_NOISE_M * gauss(&mut rng), 1e-6);
        let mut x_slave = x + POSITION_NOISE_M * gauss(&mut rng);
        if let Some((a, kw, ph, scale)) = pitch {
            x_slave += a * (kw * x + ph).sin() + scale * x;
        }
        let x_slave = quantise(x_slave, 1e-6);
        let (pa, pb) = phys.pressures(&s);
        let pa_meas = ga * pa + oa + PRESSURE_NOISE_PA * gauss(&mut rng);
        let pb_meas = gb * pb + ob + PRESSURE_NOISE_PA * gauss(&mut rng);

        // Reference.
        while seg_i + 1 < timed.len() && t >= timed[seg_i].t0 + timed[seg_i].dur {
            seg_i += 1;
        }
        let (x_ref, v_ref, a_ref) = reference_in(&timed[seg_i], t);

        // Velocity: first-order low-pass of the backward difference.
        let v_fd = x_prev.map_or(0.0, |p| (x_meas - p) / period);
        x_prev = Some(x_meas);
        v_filtered += alpha * (v_fd - v_filtered);

        let feed_forward = nom.mass_kg * a_ref
            + nom.coulomb_n * (v_ref / FRICTION_SMOOTHING_MPS).tanh()
            + nom.viscous_ns_per_m * v_ref
            - (pa_meas - pb_meas) * nominal_area;
        let total = kp * (x_ref - x_meas) + kd * (v_ref - v_filtered) + feed_forward;
        let per_section = (0.5 * total).clamp(-SECTION_LIMIT_N, SECTION_LIMIT_N);
        section_cmd.push(per_section);

        // The slave reports the setpoint it holds now: the master's, `slave` late.
        let slave_logged = earlier(
            &section_cmd,
            k,
            slave_log_shift.whole + usize::from(slave_log_shift.rest_s > 0.0),
        );
        let f_master = gm * per_section + om + FORCE_NOISE_N * gauss(&mut rng);
        let f_slave = gs * slave_logged + os + FORCE_NOISE_N * gauss(&mut rng);
        let _ = writeln!(
            csv,
            "{:.6},{:.6},{:.6},0.0000,{:.2},{:.2},{:.1},{:.1}",
            t, x_meas, x_slave, f_master, f_slave, pa_meas, pb_meas
        );

        // Plant over [t, t + period): each section's acting force switches once, at the
        // remainder of its delay; integrate piecewise between the switches.
        let mut cuts = [0.0, master_shift.rest_s, slave_act_shift.rest_s, period];
        cuts.sort_by(f64::total_cmp);
        for pair in cuts.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            if b - a <= 0.0 {
                continue;
            }
            let mid = 0.5 * (a + b);
            let acting = |sh: Shift| {
                let back = sh.whole + usize::from(mid < sh.rest_s);
                earlier(&section_cmd, k, back)
            };
            let motor = acting(master_shift) + acting(slave_act_shift);
            phys.advance(&mut s, motor_gain * motor, b - a);
        }
    }

    Generated {
        csv,
        model_toml: model_toml(nom),
        truth: Truth {
            hidden: case.hidden.clone(),
        },
        rows,
    }
}

/// The nominal model file: the keys `docs/formats.md` §2 requires, nothing else.
pub fn model_toml(m: &Machine) -> String {
    format!(
        "# nominal machine model of a foreign test plant (SI units)\n\
         [piston]\nmass_kg = {:.3}\nbore_m = {:.4}\nrod_m = {:.4}\ntravel_m = {:?}\n\
         dead_length_a_m = {:?}\ndead_length_b_m = {:?}\n\n\
         [friction]\ncoulomb_n = {:.2}\nviscous_ns_per_m = {:.2}\n\n\
         [gas]\ngamma = {:?}\ngas_constant_j_per_kg_k = {:?}\ntemperature_k = {:?}\nambient_pa = {:?}\n\n\
         [motor]\npole_pitch_m = {:?}\nslave_follows_master = true\n\n\
         [encoder]\nperiod_m = {:?}\n",
        m.mass_kg,
        m.bore_m,
        m.rod_m,
        TRAVEL_M,
        DEAD_LENGTH_M,
        DEAD_LENGTH_M,
        m.coulomb_n,
        m.viscous_ns_per_m,
        GAMMA,
        GAS_CONSTANT,
        TEMPERATURE_K,
        AMBIENT_PA,
        POLE_PITCH_M,
        ENCODER_PERIOD_M,
    )
}
