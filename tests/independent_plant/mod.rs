//! A second compressor plant, written apart from `hal-sim` to test the model-gap workflow on
//! data whose conventions it did not make.
//!
//! Nothing here comes from `fpc` or `hal_sim`: its own state vector and classical RK4
//! integrator, its own position controller (PD on a filtered finite-difference velocity,
//! run at the log rate, its force command held until the next sample), its own chamber
//! model (mass and temperature per chamber, energy equation), its own logger (the command as
//! it is issued, on time, fixed decimals, seeded noise: 1 µm, 3 N, 0.4 kPa). What it shares
//! with the workflow is only the physics the contract names (`docs/machine.md`, `docs/formats.md`).
//!
//! Chambers are either *vented* (the rotation at rest, both chambers breathing to ambient
//! through an orifice: their pressures differ by a flow loss ∝ v·|v|; the log has no `ports`
//! key) or *sealed* (`# ports = closed`: ideal gas, through-rod piston, both chambers of the
//! annulus area). `port_restriction` needs rotation-timed ports and is out of scope here.
//!
//! Each hidden effect is drawn above a floor at which it is plainly visible over the noise
//! (see [`draw_effect`]), so that a miss is the workflow's fault, not the data's.

#![allow(dead_code)] // each test file uses its own subset

use std::collections::BTreeMap;
use std::f64::consts::{PI, TAU};
use std::fmt::Write as _;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const R_GAS: f64 = 287.0;
const GAMMA: f64 = 1.4;
const T_AMBIENT: f64 = 293.15;
const P_AMBIENT: f64 = 101_325.0;
const AIR_VISCOSITY: f64 = 1.8e-5;
const SEAL_LENGTH: f64 = 0.05;
/// Vented chambers: Δp = K·v·|v| across each orifice, Pa/(m/s)².
const VENT_LOSS: f64 = 300.0;
/// Velocity below which the friction sign is smoothed, m/s.
const SIGN_SMOOTHING: f64 = 1e-3;

/// How the chambers are connected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Chambers {
    /// Open to ambient (no `ports` key).
    Vented,
    /// Both sealed (`# ports = closed`).
    Sealed,
}

/// Motion pattern.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trajectory {
    /// Sine strokes about mid travel at several speeds.
    Sine,
    /// Point-to-point moves with trapezoidal velocity and short dwells.
    Trapezoid,
    /// Slow and fast moves between random positions with holds.
    HoldsAndMoves,
}

/// The effects that can be hidden, with their true parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Hidden {
    /// The true mass is `factor` times the nominal.
    Mass { factor: f64 },
    /// The true Coulomb level is nominal + `delta_n`.
    Coulomb { delta_n: f64 },
    /// The true viscous coefficient is nominal + `delta`.
    Viscous { delta: f64 },
    /// Static friction above Coulomb, decaying with speed.
    Stribeck {
        excess_n: f64,
        velocity_mps: f64,
        exponent: f64,
    },
    /// Position-periodic force.
    Cogging {
        amplitude_n: f64,
        period_m: f64,
        phase_rad: f64,
    },
    /// Both sections' force acts `delay_s` after it is commanded.
    ActuatorLag { delay_s: f64 },
    /// The slave section applies the master's command `delay_s` late.
    SlaveLag { delay_s: f64 },
    /// The slave encoder reads `x + a·sin(2πx/p + φ) + scale·x`.
    PitchError {
        amplitude_m: f64,
        period_m: f64,
        phase_rad: f64,
        scale: f64,
    },
    /// Laminar clearance leak A↔B through a gap `gap_m` (sealed only).
    Leakage { gap_m: f64 },
    /// Wall heat transfer `ua_w_per_k` per chamber (sealed only).
    HeatTransfer { ua_w_per_k: f64 },
    /// Outside the library: a spring `−k·(x − x0)` (a cable carrier's).
    Spring { k_n_per_m: f64, x0_m: f64 },
    /// Outside the library: a constant force toward +x (a tilted axis).
    Bias { force_n: f64 },
    /// Outside the library: air drag `−c·v|v|`.
    QuadraticDrag { c_ns2_per_m2: f64 },
    /// Outside the library: the drives push `(1 + error)` times the force they report.
    ForceConstant { error: f64 },
    /// Outside the library: Coulomb friction rising `rate` N every second of the run.
    DriftingFriction { rate_n_per_s: f64 },
    /// Outside the library and the discovery basis: friction growing `k` N per metre away
    /// from `x0`, against the motion (a bore worn or tapered toward its ends).
    PositionFriction { k_n_per_m: f64, x0_m: f64 },
    /// Outside the library: a hardening spring `−k3·(x − x0)³`, N/m³ about `x0`.
    CubicSpring { k_n_per_m3: f64, x0_m: f64 },
    /// Chamber A's (or, `chamber_b`, B's) transducer reads `p + offset_pa`.
    PressureOffset { chamber_b: bool, offset_pa: f64 },
    /// Chamber A's (or, `chamber_b`, B's) transducer reads `gain·p`.
    PressureGain { chamber_b: bool, gain: f64 },
    /// The master's (or, `slave`, the slave's) force reading is `F + offset_n`.
    ForceOffset { slave: bool, offset_n: f64 },
    /// The master's (or, `slave`, the slave's) force reading is `gain·F`.
    ForceGain { slave: bool, gain: f64 },
}

impl Hidden {
    /// The workflow's name for it (`docs/formats.md` §3).
    pub fn name(&self) -> &'static str {
        match self {
            Hidden::Mass { .. } => "mass_error",
            Hidden::Coulomb { .. } => "coulomb_friction",
            Hidden::Viscous { .. } => "viscous_friction",
            Hidden::Stribeck { .. } => "stribeck_friction",
            Hidden::Cogging { .. } => "cogging",
            Hidden::ActuatorLag { .. } => "actuator_lag",
            Hidden::SlaveLag { .. } => "slave_lag",
            Hidden::PitchError { .. } => "encoder_pitch_error",
            Hidden::Leakage { .. } => "leakage",
            Hidden::HeatTransfer { .. } => "heat_transfer",
            Hidden::Spring { .. } => "spring",
            Hidden::Bias { .. } => "bias",
            Hidden::QuadraticDrag { .. } => "quadratic_drag",
            Hidden::ForceConstant { .. } => "force_constant_error",
            Hidden::DriftingFriction { .. } => "drifting_friction",
            Hidden::PositionFriction { .. } => "position_friction",
            Hidden::CubicSpring { .. } => "cubic_spring",
            Hidden::PressureOffset { .. } => "pressure_offset",
            Hidden::PressureGain { .. } => "pressure_gain",
            Hidden::ForceOffset { .. } => "force_offset",
            Hidden::ForceGain { .. } => "force_gain",
        }
    }

    /// For a force outside the library, the terms of the discovery basis (`docs/formats.md`,
    /// "Beyond the library") it is, in SI; `None` for a library effect.
    pub fn discovered_terms(&self) -> Option<BTreeMap<&'static str, f64>> {
        let terms: Vec<(&'static str, f64)> = match *self {
            Hidden::Spring { k_n_per_m, x0_m } => vec![("x", -k_n_per_m), ("1", k_n_per_m * x0_m)],
            Hidden::Bias { force_n } => vec![("1", force_n)],
            Hidden::QuadraticDrag { c_ns2_per_m2 } => vec![("v|v|", -c_ns2_per_m2)],
            Hidden::ForceConstant { error } => vec![("f_motor", error)],
            Hidden::DriftingFriction { rate_n_per_s } => vec![("t*sgn(v)", -rate_n_per_s)],
            // −k3·(x − x0)³ expanded in powers of x.
            Hidden::CubicSpring { k_n_per_m3, x0_m } => vec![
                ("x^3", -k_n_per_m3),
                ("x^2", 3.0 * k_n_per_m3 * x0_m),
                ("x", -3.0 * k_n_per_m3 * x0_m * x0_m),
                ("1", k_n_per_m3 * x0_m.powi(3)),
            ],
            _ => return None,
        };
        Some(terms.into_iter().collect())
    }
}

/// The forces outside the library the plant can hide, in a fixed order.
pub const FORMS: [&str; 5] = [
    "spring",
    "bias",
    "quadratic_drag",
    "force_constant_error",
    "drifting_friction",
];

/// The triples of library effects hidden together, compatible in their chamber and
/// trajectory needs.
pub const TRIPLES: [[&str; 3]; 5] = [
    ["mass_error", "coulomb_friction", "slave_lag"],
    ["cogging", "slave_lag", "encoder_pitch_error"],
    ["mass_error", "cogging", "encoder_pitch_error"],
    ["viscous_friction", "actuator_lag", "encoder_pitch_error"],
    ["leakage", "heat_transfer", "slave_lag"],
];

/// Every name [`Hidden`] can take, in a fixed order.
pub const EFFECTS: [&str; 10] = [
    "mass_error",
    "coulomb_friction",
    "viscous_friction",
    "stribeck_friction",
    "cogging",
    "actuator_lag",
    "slave_lag",
    "encoder_pitch_error",
    "leakage",
    "heat_transfer",
];

/// The nominal machine (what the user's model file says).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nominal {
    pub mass_kg: f64,
    pub bore_m: f64,
    pub rod_m: f64,
    pub travel_m: f64,
    pub dead_m: f64,
    pub coulomb_n: f64,
    pub viscous: f64,
    pub pole_pitch_m: f64,
    pub encoder_period_m: f64,
}

impl Nominal {
    fn draw(rng: &mut ChaCha8Rng) -> Self {
        Nominal {
            mass_kg: rng.random_range(8.0..14.0),
            bore_m: rng.random_range(0.085..0.092),
            rod_m: rng.random_range(0.018..0.024),
            travel_m: 0.205,
            dead_m: 0.0005,
            coulomb_n: rng.random_range(30.0..50.0),
            viscous: rng.random_range(15.0..35.0),
            pole_pitch_m: 0.012,
            encoder_period_m: 0.024,
        }
    }

    /// The annulus area both chambers act on, m² (a through-rod piston).
    pub fn area_m2(&self) -> f64 {
        PI / 4.0 * (self.bore_m * self.bore_m - self.rod_m * self.rod_m)
    }

    /// The model file a user would hold (`docs/formats.md` §2, required keys only).
    pub fn model_toml(&self) -> String {
        format!(
            "# nominal machine of the independent test plant\n\
             [piston]\nmass_kg = {:.4}\nbore_m = {:.5}\nrod_m = {:.5}\ntravel_m = {}\n\
             dead_length_a_m = {}\ndead_length_b_m = {}\n\n\
             [friction]\ncoulomb_n = {:.3}\nviscous_ns_per_m = {:.3}\n\n\
             [gas]\ngamma = {GAMMA}\ngas_constant_j_per_kg_k = {R_GAS}\n\
             temperature_k = {T_AMBIENT}\nambient_pa = {P_AMBIENT}\n\n\
             [motor]\npole_pitch_m = {}\nslave_follows_master = true\n\n\
             [encoder]\nperiod_m = {}\n",
            self.mass_kg,
            self.bore_m,
            self.rod_m,
            self.travel_m,
            self.dead_m,
            self.dead_m,
            self.coulomb_n,
            self.viscous,
            self.pole_pitch_m,
            self.encoder_period_m
        )
    }
}

/// One generated case.
#[derive(Clone, Debug)]
pub struct Case {
    pub seed: u64,
    pub rate_hz: f64,
    pub trajectory: Trajectory,
    pub chambers: Chambers,
    pub nominal: Nominal,
    pub hidden: Vec<Hidden>,
}

/// Which effects a case may hide (sealed chambers for the pressure effects, holds for
/// Stribeck).
pub fn needs(effect: &str) -> (Option<Chambers>, Option<Trajectory>) {
    match effect {
        "leakage" | "heat_transfer" => (Some(Chambers::Sealed), Some(Trajectory::HoldsAndMoves)),
        "stribeck_friction" => (Some(Chambers::Vented), Some(Trajectory::HoldsAndMoves)),
        // The pressure channel is compared only where the log says how the ports were.
        "pressure_offset" | "pressure_gain" => (Some(Chambers::Sealed), None),
        _ => (None, None),
    }
}

/// Draws an effect's true parameters above its detection floor:
/// mass ±8–25 %, Coulomb ±15–40 N, viscous ±20–80 N·s/m, Stribeck 25–80 N above Coulomb at
/// 5–40 mm/s (logs with creeping moves at 8–60 mm/s), cogging 15–60 N at the pole or N–N pitch, lags 0.4–1.5 ms (actuator) and
/// 0.4–1.5 ms (slave), both on the log's grid, pitch error 10–40 µm, leak gap 15–40 µm, UA 1–20 W/K.
pub fn draw_effect(effect: &str, nominal: &Nominal, rng: &mut ChaCha8Rng) -> Hidden {
    let sign = |rng: &mut ChaCha8Rng| if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    match effect {
        "mass_error" => Hidden::Mass {
            factor: 1.0 + sign(rng) * rng.random_range(0.08..0.25),
        },
        "coulomb_friction" => Hidden::Coulomb {
            delta_n: sign(rng) * rng.random_range(15.0..40.0f64).min(nominal.coulomb_n - 5.0),
        },
        "viscous_friction" => {
            let up = rng.random_range(20.0..80.0);
            let down = -rng.random_range(20.0..80.0f64).min(nominal.viscous);
            Hidden::Viscous {
                delta: if rng.random_bool(0.5) || nominal.viscous < 20.0 {
                    up
                } else {
                    down
                },
            }
        }
        "stribeck_friction" => Hidden::Stribeck {
            excess_n: rng.random_range(25.0..80.0),
            velocity_mps: rng.random_range(0.005..0.04),
            exponent: if rng.random_bool(0.5) { 1.0 } else { 2.0 },
        },
        "cogging" => Hidden::Cogging {
            amplitude_n: rng.random_range(15.0..60.0),
            period_m: if rng.random_bool(0.5) {
                nominal.pole_pitch_m
            } else {
                2.0 * nominal.pole_pitch_m
            },
            phase_rad: rng.random_range(-PI..PI),
        },
        "actuator_lag" => Hidden::ActuatorLag {
            delay_s: rng.random_range(0.4e-3..1.5e-3),
        },
        "slave_lag" => Hidden::SlaveLag {
            delay_s: rng.random_range(0.4e-3..1.5e-3),
        },
        "encoder_pitch_error" => Hidden::PitchError {
            amplitude_m: rng.random_range(10e-6..40e-6),
            period_m: nominal.encoder_period_m,
            phase_rad: rng.random_range(-PI..PI),
            scale: rng.random_range(-2e-4..2e-4),
        },
        "leakage" => Hidden::Leakage {
            gap_m: rng.random_range(15e-6..40e-6),
        },
        // The forms outside the library, at magnitudes a rig shows (well above the 3 N of
        // force noise): springs of 0.8–3 kN/m about a point within 3 cm of mid travel,
        // 30–120 N of bias, 5–20 N·s²/m² of drag, a force constant 4–12 % off, friction
        // rising 3–12 N/s.
        "spring" => Hidden::Spring {
            k_n_per_m: rng.random_range(800.0..3000.0),
            x0_m: 0.5 * nominal.travel_m + rng.random_range(-0.03..0.03),
        },
        "bias" => Hidden::Bias {
            force_n: sign(rng) * rng.random_range(30.0..120.0),
        },
        "quadratic_drag" => Hidden::QuadraticDrag {
            c_ns2_per_m2: rng.random_range(5.0..20.0),
        },
        "force_constant_error" => Hidden::ForceConstant {
            error: sign(rng) * rng.random_range(0.04..0.12),
        },
        "drifting_friction" => Hidden::DriftingFriction {
            rate_n_per_s: rng.random_range(3.0..12.0),
        },
        // The field logs' forms: friction growing 400–1200 N/m away from a point within 3 cm
        // of mid travel, a hardening spring of 3·10⁵–1.5·10⁶ N/m³ about a point within 2 cm
        // of it, a transducer 1–5 kPa off or its gain 1.5–6 % off, a force reading 15–60 N
        // off or its gain 3–10 % off, each on one chamber or section drawn at random.
        "position_friction" => Hidden::PositionFriction {
            k_n_per_m: rng.random_range(400.0..1200.0),
            x0_m: 0.5 * nominal.travel_m + rng.random_range(-0.03..0.03),
        },
        "cubic_spring" => Hidden::CubicSpring {
            k_n_per_m3: rng.random_range(3e5..1.5e6),
            x0_m: 0.5 * nominal.travel_m + rng.random_range(-0.02..0.02),
        },
        "pressure_offset" => Hidden::PressureOffset {
            chamber_b: rng.random_bool(0.5),
            offset_pa: sign(rng) * rng.random_range(1000.0..5000.0),
        },
        "pressure_gain" => Hidden::PressureGain {
            chamber_b: rng.random_bool(0.5),
            gain: 1.0 + sign(rng) * rng.random_range(0.015..0.06),
        },
        "force_offset" => Hidden::ForceOffset {
            slave: rng.random_bool(0.5),
            offset_n: sign(rng) * rng.random_range(15.0..60.0),
        },
        "force_gain" => Hidden::ForceGain {
            slave: rng.random_bool(0.5),
            gain: 1.0 + sign(rng) * rng.random_range(0.03..0.10),
        },
        _ => Hidden::HeatTransfer {
            ua_w_per_k: rng.random_range(1.0..20.0),
        },
    }
}

/// Draws a case hiding `effects` (empty: a null case).
pub fn draw_case(seed: u64, effects: &[&str]) -> Case {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0005_eed0_fa11);
    let nominal = Nominal::draw(&mut rng);
    let rate_hz = [5_000.0, 10_000.0, 20_000.0][rng.random_range(0..3usize)];
    let mut chambers = if rng.random_bool(0.5) {
        Chambers::Vented
    } else {
        Chambers::Sealed
    };
    let mut trajectory = [
        Trajectory::Sine,
        Trajectory::Trapezoid,
        Trajectory::HoldsAndMoves,
    ][rng.random_range(0..3usize)];
    // A lag shows in proportion to the force's rate: a log of holds and creeping moves can
    // leave it below what the drives resolve, so lags get brisk strokes unless another
    // effect needs the holds.
    // So do quadratic drag (it lives at speed: on a log of holds and creeping moves, 5 N·s²/m²
    // changes the force by less than the drives resolve) and a force-constant error (where
    // the force is mostly friction, `e·f_motor` is a Coulomb and a mass error to within the
    // noise: 71.6 % against 71.7 % explained on seed 7300; the log cannot tell them apart).
    let brisk =
        |e: &&str| e.ends_with("_lag") || matches!(*e, "quadratic_drag" | "force_constant_error");
    if effects.iter().any(brisk) && trajectory == Trajectory::HoldsAndMoves {
        trajectory = Trajectory::Trapezoid;
    }
    for e in effects {
        let (c, t) = needs(e);
        if let Some(c) = c {
            chambers = c;
        }
        if let Some(t) = t {
            trajectory = t;
        }
    }
    // The drives and the logger share the log's grid: a delay is a whole number of periods
    // (as the field logs' are: 1.0 ms at 10 kHz).
    let on_grid = |d: f64| (d * rate_hz).round().max(1.0) / rate_hz;
    let hidden = effects
        .iter()
        .map(|e| match draw_effect(e, &nominal, &mut rng) {
            Hidden::ActuatorLag { delay_s } => Hidden::ActuatorLag {
                delay_s: on_grid(delay_s),
            },
            Hidden::SlaveLag { delay_s } => Hidden::SlaveLag {
                delay_s: on_grid(delay_s),
            },
            h => h,
        })
        .collect();
    Case {
        seed,
        rate_hz,
        trajectory,
        chambers,
        nominal,
        hidden,
    }
}

/// A generated log.
#[derive(Clone, Debug)]
pub struct Generated {
    /// The run log, `docs/formats.md` §1.
    pub csv: String,
    /// The nominal model file.
    pub model_toml: String,
}

/// The true machine: nominal with the hidden effects applied.
#[derive(Clone, Copy, Debug, Default)]
struct Truth {
    mass: f64,
    coulomb: f64,
    viscous: f64,
    stribeck: Option<(f64, f64, f64)>,
    cogging: Option<(f64, f64, f64)>,
    actuator_lag: f64,
    slave_lag: f64,
    pitch: Option<(f64, f64, f64, f64)>,
    leak_gap: f64,
    ua: f64,
    spring: Option<(f64, f64)>,
    bias: f64,
    drag: f64,
    motor_gain: f64,
    drift: f64,
    position_friction: Option<(f64, f64)>,
    cubic: Option<(f64, f64)>,
    /// Chamber A's and B's transducers: (gain, offset Pa).
    transducers: [(f64, f64); 2],
    /// The master's and the slave's force readings: (gain, offset N).
    readings: [(f64, f64); 2],
}

impl Truth {
    fn of(case: &Case) -> Self {
        let n = &case.nominal;
        let mut t = Truth {
            mass: n.mass_kg,
            coulomb: n.coulomb_n,
            viscous: n.viscous,
            motor_gain: 1.0,
            transducers: [(1.0, 0.0); 2],
            readings: [(1.0, 0.0); 2],
            ..Truth::default()
        };
        for h in &case.hidden {
            match *h {
                Hidden::Mass { factor } => t.mass = n.mass_kg * factor,
                Hidden::Coulomb { delta_n } => t.coulomb = n.coulomb_n + delta_n,
                Hidden::Viscous { delta } => t.viscous = (n.viscous + delta).max(0.0),
                Hidden::Stribeck {
                    excess_n,
                    velocity_mps,
                    exponent,
                } => t.stribeck = Some((excess_n, velocity_mps, exponent)),
                Hidden::Cogging {
                    amplitude_n,
                    period_m,
                    phase_rad,
                } => t.cogging = Some((amplitude_n, period_m, phase_rad)),
                Hidden::ActuatorLag { delay_s } => t.actuator_lag = delay_s,
                Hidden::SlaveLag { delay_s } => t.slave_lag = delay_s,
                Hidden::PitchError {
                    amplitude_m,
                    period_m,
                    phase_rad,
                    scale,
                } => t.pitch = Some((amplitude_m, period_m, phase_rad, scale)),
                Hidden::Leakage { gap_m } => t.leak_gap = gap_m,
                Hidden::HeatTransfer { ua_w_per_k } => t.ua = ua_w_per_k,
                Hidden::Spring { k_n_per_m, x0_m } => t.spring = Some((k_n_per_m, x0_m)),
                Hidden::Bias { force_n } => t.bias = force_n,
                Hidden::QuadraticDrag { c_ns2_per_m2 } => t.drag = c_ns2_per_m2,
                Hidden::ForceConstant { error } => t.motor_gain = 1.0 + error,
                Hidden::DriftingFriction { rate_n_per_s } => t.drift = rate_n_per_s,
                Hidden::PositionFriction { k_n_per_m, x0_m } => {
                    t.position_friction = Some((k_n_per_m, x0_m));
                }
                Hidden::CubicSpring { k_n_per_m3, x0_m } => t.cubic = Some((k_n_per_m3, x0_m)),
                Hidden::PressureOffset {
                    chamber_b,
                    offset_pa,
                } => t.transducers[usize::from(chamber_b)].1 = offset_pa,
                Hidden::PressureGain { chamber_b, gain } => {
                    t.transducers[usize::from(chamber_b)].0 = gain;
                }
                Hidden::ForceOffset { slave, offset_n } => {
                    t.readings[usize::from(slave)].1 = offset_n;
                }
                Hidden::ForceGain { slave, gain } => t.readings[usize::from(slave)].0 = gain,
            }
        }
        t
    }

    /// Friction against the motion at `x` m and `t` s into the run.
    fn friction(&self, x: f64, v: f64, t: f64) -> f64 {
        let s = (v / SIGN_SMOOTHING).tanh();
        let level = self.coulomb
            + self.drift * t
            + self
                .position_friction
                .map_or(0.0, |(k, x0)| k * (x - x0).abs());
        let mut f = level * s + self.viscous * v + self.drag * v * v.abs();
        if let Some((excess, vs, z)) = self.stribeck {
            f += excess * (-(v.abs() / vs).powf(z)).exp() * s;
        }
        f
    }
}

/// A reference path: position, velocity and acceleration at `t`, as a list of pieces.
#[derive(Clone, Debug)]
struct Path {
    pieces: Vec<Piece>,
}

#[derive(Clone, Copy, Debug)]
enum Piece {
    /// `c + a·sin(ω(t − t0))` for `[t0, t0 + len)`.
    Sine {
        t0: f64,
        len: f64,
        c: f64,
        a: f64,
        w: f64,
    },
    /// From `x0` to `x1` with peak speed `v` and acceleration `acc` (trapezoid), then hold.
    Move {
        t0: f64,
        len: f64,
        x0: f64,
        x1: f64,
        v: f64,
        acc: f64,
    },
}

impl Path {
    fn duration(&self) -> f64 {
        self.pieces.last().map_or(0.0, |p| match *p {
            Piece::Sine { t0, len, .. } | Piece::Move { t0, len, .. } => t0 + len,
        })
    }

    fn at(&self, t: f64) -> (f64, f64, f64) {
        let piece = self
            .pieces
            .iter()
            .rev()
            .find(|p| match **p {
                Piece::Sine { t0, .. } | Piece::Move { t0, .. } => t >= t0,
            })
            .or(self.pieces.first());
        match piece {
            Some(&Piece::Sine { t0, c, a, w, len }) => {
                let u = (t - t0).clamp(0.0, len);
                let ph = w * u;
                (c + a * ph.sin(), a * w * ph.cos(), -a * w * w * ph.sin())
            }
            Some(&Piece::Move {
                t0, x0, x1, v, acc, ..
            }) => {
                let d = (x1 - x0).abs();
                let dir = (x1 - x0).signum();
                let ta = v / acc;
                let (ta, vp) = if acc * ta * ta > d {
                    let ta = (d / acc).sqrt();
                    (ta, acc * ta)
                } else {
                    (ta, v)
                };
                let tc = (d - acc * ta * ta) / vp;
                let u = (t - t0).max(0.0);
                let (s, sv, sa) = if u < ta {
                    (0.5 * acc * u * u, acc * u, acc)
                } else if u < ta + tc {
                    (0.5 * acc * ta * ta + vp * (u - ta), vp, 0.0)
                } else if u < 2.0 * ta + tc {
                    let r = 2.0 * ta + tc - u;
                    (d - 0.5 * acc * r * r, acc * r, -acc)
                } else {
                    (d, 0.0, 0.0)
                };
                (x0 + dir * s, dir * sv, dir * sa)
            }
            None => (0.1, 0.0, 0.0),
        }
    }

    fn draw(case: &Case, rng: &mut ChaCha8Rng) -> Path {
        let mid = 0.5 * case.nominal.travel_m;
        // Sealed chambers: a narrower span keeps the pressures within a few bar.
        let span = match case.chambers {
            Chambers::Vented => 0.085,
            Chambers::Sealed => 0.045,
        };
        let mut pieces = Vec::new();
        let mut t = 0.0;
        // Start at rest at mid travel.
        pieces.push(Piece::Move {
            t0: 0.0,
            len: 0.1,
            x0: mid,
            x1: mid,
            v: 1.0,
            acc: 10.0,
        });
        t += 0.1;
        match case.trajectory {
            Trajectory::Sine => {
                while t < 3.0 {
                    let a = rng.random_range(0.6..1.0) * span;
                    let v =
                        rng.random_range(0.25..2.5f64)
                            .min(if case.chambers == Chambers::Sealed {
                                1.8
                            } else {
                                2.5
                            });
                    let w = v / a;
                    let len = 2.0 * TAU / w;
                    pieces.push(Piece::Sine {
                        t0: t,
                        len,
                        c: mid,
                        a,
                        w,
                    });
                    t += len;
                }
            }
            Trajectory::Trapezoid => {
                let mut x = mid;
                while t < 3.0 {
                    let target = mid + rng.random_range(-1.0..1.0) * span;
                    let v: f64 = rng.random_range(0.3..2.2);
                    let acc: f64 = rng.random_range(20.0..60.0);
                    let d = (target - x).abs();
                    let ta = (v / acc).min((d / acc).sqrt());
                    let len = 2.0 * ta
                        + (d - acc * ta * ta).max(0.0) / v.max(1e-9)
                        + rng.random_range(0.02..0.06);
                    pieces.push(Piece::Move {
                        t0: t,
                        len,
                        x0: x,
                        x1: target,
                        v,
                        acc,
                    });
                    t += len;
                    x = target;
                }
            }
            Trajectory::HoldsAndMoves => {
                let mut x = mid;
                while t < 4.0 {
                    // Creeping moves (where Stribeck friction lives: 4–15 mm) and brisk ones.
                    let creep = rng.random_bool(0.4);
                    let target = if creep {
                        let step = rng.random_range(0.004..0.015);
                        if x + step <= mid + span && (x - step < mid - span || rng.random_bool(0.5))
                        {
                            x + step
                        } else {
                            x - step
                        }
                    } else {
                        mid + rng.random_range(-1.0..1.0) * span
                    };
                    let v: f64 = if creep {
                        rng.random_range(0.008..0.06)
                    } else {
                        rng.random_range(0.3..1.8)
                    };
                    let acc: f64 = if creep {
                        rng.random_range(0.5..3.0)
                    } else {
                        rng.random_range(5.0..30.0)
                    };
                    let d = (target - x).abs();
                    let ta = (v / acc).min((d / acc).sqrt());
                    let len =
                        2.0 * ta + (d - acc * ta * ta).max(0.0) / v + rng.random_range(0.15..0.4);
                    pieces.push(Piece::Move {
                        t0: t,
                        len,
                        x0: x,
                        x1: target,
                        v,
                        acc,
                    });
                    t += len;
                    x = target;
                }
            }
        }
        Path { pieces }
    }
}

/// White Gaussian noise of a standard deviation (Box–Muller).
#[derive(Clone, Copy, Debug)]
struct Gauss(f64);

impl Gauss {
    fn sample(&self, rng: &mut ChaCha8Rng) -> f64 {
        let u1: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
        let u2: f64 = rng.random_range(0.0..1.0);
        self.0 * (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
    }
}

/// State: x, v, then per chamber mass and temperature (sealed only).
type State = [f64; 6];

/// The plant's derivative at `t` with the acting motor force `f_motor` (as commanded: the
/// drives push `motor_gain` times it).
fn derivative(s: &State, f_motor: f64, t: f64, truth: &Truth, case: &Case) -> State {
    let n = &case.nominal;
    let area = n.area_m2();
    let (x, v) = (s[0], s[1]);
    let mut d = [0.0; 6];
    d[0] = v;
    let (pa, pb) = pressures(s, case);
    let mut f =
        truth.motor_gain * f_motor + (pa - pb) * area - truth.friction(x, v, t) + truth.bias;
    if let Some((k, x0)) = truth.spring {
        f -= k * (x - x0);
    }
    if let Some((k3, x0)) = truth.cubic {
        f -= k3 * (x - x0).powi(3);
    }
    if let Some((a, p, ph)) = truth.cogging {
        f += a * (TAU * x / p + ph).sin();
    }
    d[1] = f / truth.mass;
    if case.chambers == Chambers::Sealed {
        let (dva, dvb) = (area * v, -area * v);
        // Laminar annulus leak A→B (upstream temperature).
        let t_up = if pa >= pb { s[3] } else { s[5] };
        let mdot = if truth.leak_gap > 0.0 {
            PI * n.bore_m * truth.leak_gap.powi(3)
                / (24.0 * AIR_VISCOSITY * R_GAS * t_up * SEAL_LENGTH)
                * (pa * pa - pb * pb)
        } else {
            0.0
        };
        let cv = R_GAS / (GAMMA - 1.0);
        let cp = cv + R_GAS;
        let chamber = |m: f64, temp: f64, p: f64, dvol: f64, m_in: f64, h_in: f64| {
            // Energy: d(m·cv·T) = −p·dV + h_in·ṁ_in (ṁ_in < 0 leaves at the own enthalpy) + Q̇.
            let q = truth.ua * (T_AMBIENT - temp);
            let h = if m_in >= 0.0 { h_in } else { cp * temp };
            let du = -p * dvol + h * m_in + q;
            let dt = (du - cv * temp * m_in) / (m * cv);
            (m_in, dt)
        };
        let (dma, dta) = chamber(s[2], s[3], pa, dva, -mdot, cp * s[5]);
        let (dmb, dtb) = chamber(s[4], s[5], pb, dvb, mdot, cp * s[3]);
        d[2] = dma;
        d[3] = dta;
        d[4] = dmb;
        d[5] = dtb;
    }
    d
}

/// Chamber pressures of a state, Pa.
fn pressures(s: &State, case: &Case) -> (f64, f64) {
    let n = &case.nominal;
    let area = n.area_m2();
    match case.chambers {
        Chambers::Vented => {
            // Shrinking A (v < 0) pushes air out through A's orifice: A above ambient.
            let loss = VENT_LOSS * s[1] * s[1].abs();
            (P_AMBIENT - loss, P_AMBIENT + loss)
        }
        Chambers::Sealed => {
            let va = area * (s[0] + n.dead_m);
            let vb = area * (n.travel_m - s[0] + n.dead_m);
            (s[2] * R_GAS * s[3] / va, s[4] * R_GAS * s[5] / vb)
        }
    }
}

/// Runs the case and writes its log.
pub fn generate(case: &Case) -> Generated {
    let mut rng = ChaCha8Rng::seed_from_u64(case.seed);
    let path = Path::draw(case, &mut rng);
    let truth = Truth::of(case);
    let n = &case.nominal;
    let dt = 1.0 / case.rate_hz;
    let sub = ((dt / 25e-6).ceil() as usize).max(1);
    let h = dt / sub as f64;
    let steps = (path.duration() / dt) as usize;
    let (x0, _, _) = path.at(0.0);
    let area = n.area_m2();
    let mut s: State = [x0, 0.0, 0.0, T_AMBIENT, 0.0, T_AMBIENT];
    s[2] = P_AMBIENT * area * (x0 + n.dead_m) / (R_GAS * T_AMBIENT);
    s[4] = P_AMBIENT * area * (n.travel_m - x0 + n.dead_m) / (R_GAS * T_AMBIENT);
    let pos_noise = Gauss(1e-6);
    let f_noise = Gauss(3.0);
    let p_noise = Gauss(400.0);
    // Controller: PD on a first-order-filtered difference velocity, feed-forward of the
    // nominal mass, Coulomb friction and the measured gas force.
    let wn = TAU * 25.0;
    let (kp, kd) = (n.mass_kg * wn * wn, 2.0 * 0.8 * wn * n.mass_kg);
    let alpha = (-dt * TAU * 400.0).exp();
    let mut v_filt = 0.0;
    let mut x_prev = x0;
    // The commanded total force at each sample (held until the next).
    let mut cmd: Vec<f64> = Vec::with_capacity(steps + 1);
    let held = |cmd: &[f64], t: f64| -> f64 {
        if t < 0.0 {
            return 0.0;
        }
        // The grid's own index: a time on the grid must not round down to the sample before.
        let k = (t / dt + 1e-6).floor() as usize;
        cmd.get(k).or(cmd.last()).copied().unwrap_or(0.0)
    };
    let mut csv = String::with_capacity(steps * 80);
    csv.push_str("# source = independent test plant\n");
    if case.chambers == Chambers::Sealed {
        csv.push_str("# ports = closed\n");
    }
    csv.push_str("t_s,x_m,x_slave_m,theta_rad,f_master_n,f_slave_n,p_a_pa,p_b_pa\n");
    for k in 0..=steps {
        let t = k as f64 * dt;
        // Sense.
        let x_meas = s[0] + pos_noise.sample(&mut rng);
        let (pa, pb) = pressures(&s, case);
        // Each chamber read through its transducer (`gain·p + offset`), as the controller
        // and the logger see it.
        let [(ga, oa), (gb, ob)] = truth.transducers;
        let (pa_m, pb_m) = (
            ga * pa + oa + p_noise.sample(&mut rng),
            gb * pb + ob + p_noise.sample(&mut rng),
        );
        let raw_v = if k == 0 { 0.0 } else { (x_meas - x_prev) / dt };
        v_filt = alpha * v_filt + (1.0 - alpha) * raw_v;
        x_prev = x_meas;
        // Control.
        let (xr, vr, ar) = path.at(t);
        let u = n.mass_kg * ar
            + kp * (xr - x_meas)
            + kd * (vr - v_filt)
            + n.coulomb_n * (vr / 0.01).tanh()
            + n.viscous * vr
            - (pa_m - pb_m) * area;
        cmd.push(u.clamp(-10_000.0, 10_000.0));
        // Log: both drives report their command; the slave's is the master's, late.
        // Each through its reading, `gain·F + offset`.
        let [(gm, om), (gs, os)] = truth.readings;
        let master = gm * 0.5 * held(&cmd, t) + om;
        let slave = gs * 0.5 * held(&cmd, t - truth.slave_lag) + os;
        let x_slave = match truth.pitch {
            Some((a, p, ph, scale)) => s[0] + a * (TAU * s[0] / p + ph).sin() + scale * s[0],
            None => s[0],
        } + pos_noise.sample(&mut rng);
        let _ = writeln!(
            csv,
            "{t:.7},{x_meas:.7},{x_slave:.7},0.0,{:.2},{:.2},{pa_m:.1},{pb_m:.1}",
            master + f_noise.sample(&mut rng),
            slave + f_noise.sample(&mut rng)
        );
        // Integrate to the next sample (RK4 on sub-steps; the drives' force is piecewise
        // constant, evaluated at each stage's time).
        for j in 0..sub {
            let ts = t + j as f64 * h;
            let force = |tt: f64| {
                let late = tt - truth.actuator_lag;
                0.5 * held(&cmd, late) + 0.5 * held(&cmd, late - truth.slave_lag)
            };
            let add = |a: &State, b: &State, w: f64| -> State {
                let mut o = *a;
                for (oi, bi) in o.iter_mut().zip(b) {
                    *oi += w * bi;
                }
                o
            };
            let (tm, te) = (ts + 0.5 * h, ts + h);
            let k1 = derivative(&s, force(ts), ts, &truth, case);
            let k2 = derivative(&add(&s, &k1, 0.5 * h), force(tm), tm, &truth, case);
            let k3 = derivative(&add(&s, &k2, 0.5 * h), force(tm), tm, &truth, case);
            let k4 = derivative(&add(&s, &k3, h), force(te), te, &truth, case);
            for i in 0..6 {
                s[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        }
    }
    Generated {
        csv,
        model_toml: n.model_toml(),
    }
}
