//! The machine-model file (`formats.md` §2): TOML, SI units, the unit in every key.
//!
//! The five required sections (`[piston] [friction] [gas] [motor] [encoder]`) load into
//! [`MachineModel`]. The project's own sections (`[ports] [lines] [servo] [sensors] [limits]
//! [simulation]`) and every optional key default to the reference machine (`machine.md`),
//! key by key. Effects (`[effects.*]`) are what the model-gap workflow adds: an effect whose
//! section is absent is absent from the physics. The reference machine itself is embedded
//! (`reference.toml`, every key commented with its origin), so `fpc-sim run` needs no file.
//!
//! Refused, with one line naming the key: an unknown key or section, a missing required key,
//! a non-physical value (zero or negative where a positive quantity is meant, a port window
//! outside one turn, …).

use fpc::physics::cogging::CoggingParams;
use fpc::physics::friction::FrictionParams;
use fpc::physics::gas::{AnnulusLeak, Cylinder, GasProperties};
use fpc::physics::motor::MotorParams;
use fpc::physics::port_timing::{PortGeometry, PortWindow};
use serde::Deserialize;

/// The reference machine's model file, embedded.
pub const REFERENCE_TOML: &str = include_str!("reference.toml");

/// Delay of the published rig's slave drive behind its master, s (**P**: 0.75 ms, paper
/// Fig. 4): what `[effects.slave_lag] delay_s` is set to to simulate that rig. It is not a
/// default: `slave_follows_master = true` alone means the slave is commanded with the
/// master's force (`formats.md` §2), on time.
pub const PAPER_SLAVE_LAG_S: f64 = 0.75e-3;

/// `[piston]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Piston {
    /// Moving mass, kg.
    pub mass_kg: f64,
    /// Cylinder bore, m.
    pub bore_m: f64,
    /// Rod diameter, m.
    pub rod_m: f64,
    /// Head-to-head travel, m.
    pub travel_m: f64,
    /// Dead volume of chamber A as a length of bore, m.
    pub dead_length_a_m: f64,
    /// Dead volume of chamber B as a length of bore, m.
    pub dead_length_b_m: f64,
    /// Contact stiffness of the heads (end-stop penalty), N/m.
    #[serde(default = "d::stop_stiffness")]
    pub stop_stiffness_n_per_m: f64,
    /// Contact damping of the heads, N·s/m.
    #[serde(default = "d::stop_damping")]
    pub stop_damping_ns_per_m: f64,
}

/// `[friction]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Friction {
    /// Coulomb level, N.
    pub coulomb_n: f64,
    /// Viscous coefficient, N·s/m.
    pub viscous_ns_per_m: f64,
    /// Static level, N (optional: defaults to the Coulomb level, no Stribeck dip).
    pub static_n: Option<f64>,
    /// Stribeck velocity, m/s.
    pub stribeck_velocity_mps: Option<f64>,
    /// Stribeck exponent.
    pub stribeck_exponent: Option<f64>,
}

/// `[gas]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Gas {
    /// Heat-capacity ratio γ.
    pub gamma: f64,
    /// Specific gas constant, J/(kg·K).
    pub gas_constant_j_per_kg_k: f64,
    /// Gas temperature at the suction, and of the wall unless the heat-transfer effect names
    /// another, K.
    pub temperature_k: f64,
    /// Ambient pressure (outside the rod seals), Pa.
    pub ambient_pa: f64,
    /// Dynamic viscosity, Pa·s (clearance leakage).
    #[serde(default = "d::viscosity")]
    pub viscosity_pa_s: f64,
}

/// Optional per-section overrides of `[motor]` (`[motor.master]`, `[motor.slave]`).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SectionOverride {
    /// Force constant, N/A.
    pub force_constant_n_per_a: Option<f64>,
    /// Phase resistance, Ω.
    pub resistance_ohm: Option<f64>,
    /// Synchronous inductance, H.
    pub inductance_h: Option<f64>,
}

/// `[motor]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Motor {
    /// Magnet step (pole pitch), m; the electrical period is twice this.
    pub pole_pitch_m: f64,
    /// The slave section's drive follows the master's force (the published rig): the slave
    /// ignores this board's PWM and imposes the master's q-current, late by the slave lag.
    pub slave_follows_master: bool,
    /// Force constant of a section, N/A (q current, amplitude-invariant).
    #[serde(default = "d::force_constant")]
    pub force_constant_n_per_a: f64,
    /// Phase resistance, Ω.
    #[serde(default = "d::resistance")]
    pub resistance_ohm: f64,
    /// Synchronous inductance, H.
    #[serde(default = "d::inductance")]
    pub inductance_h: f64,
    /// DC bus voltage, V.
    #[serde(default = "d::bus_voltage")]
    pub bus_voltage_v: f64,
    /// Peak phase-current limit, A.
    #[serde(default = "d::current_limit")]
    pub current_limit_a: f64,
    /// Overrides for the master section.
    #[serde(default)]
    pub master: SectionOverride,
    /// Overrides for the slave section.
    #[serde(default)]
    pub slave: SectionOverride,
}

/// `[encoder]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Encoder {
    /// Signal period λ, m.
    pub period_m: f64,
}

/// `[ports]`: the port windows in rotation phase (degrees, 0 = dead point A) and the flow
/// areas. See [`fpc::physics::port_timing`].
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Ports {
    /// Intake A window `[open, close]`, degrees.
    pub intake_a_deg: [f64; 2],
    /// Discharge A window, degrees.
    pub discharge_a_deg: [f64; 2],
    /// Intake B window, degrees.
    pub intake_b_deg: [f64; 2],
    /// Discharge B window, degrees.
    pub discharge_b_deg: [f64; 2],
    /// Opening/closing ramp, degrees.
    pub ramp_deg: f64,
    /// Geometric area of an intake port, m².
    pub intake_area_m2: f64,
    /// Geometric area of a discharge port, m².
    pub discharge_area_m2: f64,
    /// Discharge coefficient C_d.
    pub discharge_coefficient: f64,
}

impl Default for Ports {
    fn default() -> Self {
        let g = PortGeometry::<f64>::reference();
        let deg = |w: PortWindow<f64>| [w.open_rad.to_degrees(), w.close_rad.to_degrees()];
        Ports {
            intake_a_deg: deg(g.intake_a),
            discharge_a_deg: deg(g.discharge_a),
            intake_b_deg: deg(g.intake_b),
            discharge_b_deg: deg(g.discharge_b),
            ramp_deg: g.ramp_rad.to_degrees(),
            intake_area_m2: g.intake_area_m2,
            discharge_area_m2: g.discharge_area_m2,
            discharge_coefficient: g.discharge_coefficient,
        }
    }
}

/// `[lines]`: the suction and discharge lines the ports connect to (set pressures; the
/// discharge pressure is the suction pressure times the pressure ratio, and both can be
/// changed during a run).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Lines {
    /// Suction-line pressure, Pa.
    pub suction_pa: f64,
    /// Pressure ratio discharge/suction at the start (`fpc-sim run --pressure-ratio`
    /// overrides it).
    pub pressure_ratio: f64,
}

impl Default for Lines {
    fn default() -> Self {
        Lines {
            suction_pa: 1.0e5,
            pressure_ratio: 3.1,
        }
    }
}

/// `[servo]`: the rotation drive, spline and quadrature encoder.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Servo {
    /// Rotating inertia (servo, gearbox and piston, at the piston), kg·m².
    pub inertia_kgm2: f64,
    /// Viscous friction of the drive train, N·m·s/rad.
    pub viscous_nms_per_rad: f64,
    /// Coulomb friction of the drive train, N·m.
    pub coulomb_nm: f64,
    /// Torque at the analog command's full scale, N·m.
    pub torque_full_scale_nm: f64,
    /// Torque limit of the drive, N·m.
    pub torque_limit_nm: f64,
    /// Lag of the drive's torque behind its command, s (0 = none).
    pub torque_time_constant_s: f64,
    /// Total play of the spline between servo and piston, rad.
    pub backlash_rad: f64,
    /// Quadrature counts per revolution (after ×4 decoding).
    pub counts_per_rev: u32,
}

impl Default for Servo {
    fn default() -> Self {
        Servo {
            inertia_kgm2: 2e-3,
            viscous_nms_per_rad: 1e-3,
            coulomb_nm: 0.05,
            torque_full_scale_nm: 20.0,
            torque_limit_nm: 20.0,
            torque_time_constant_s: 2e-4,
            backlash_rad: 2e-3,
            counts_per_rev: 4096,
        }
    }
}

/// `[sensors.encoder_master]`, `[sensors.encoder_slave]`: one sin/cos encoder at the ADC.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct EncoderSensor {
    /// Amplitude of the sine channel, ADC codes.
    pub amplitude_codes: f64,
    /// Offset of the sine channel from mid-scale, codes.
    pub sin_offset_codes: f64,
    /// Offset of the cosine channel from mid-scale, codes.
    pub cos_offset_codes: f64,
    /// Gain mismatch: cosine amplitude / sine amplitude − 1.
    pub gain_mismatch: f64,
    /// Quadrature (phase) error of the cosine channel, rad.
    pub quadrature_error_rad: f64,
    /// White noise on each channel, codes RMS (before the 12-bit quantisation).
    pub noise_codes: f64,
}

impl Default for EncoderSensor {
    fn default() -> Self {
        EncoderSensor {
            amplitude_codes: f64::from(fpc::sensing::encoder::NOMINAL_AMPLITUDE_CODES),
            sin_offset_codes: 0.0,
            cos_offset_codes: 0.0,
            gain_mismatch: 0.0,
            quadrature_error_rad: 0.0,
            noise_codes: 0.0,
        }
    }
}

/// `[sensors.current]`: the phase-current sensing of both sections.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct CurrentSensor {
    /// White noise per phase, A RMS.
    pub noise_a: f64,
    /// Offset per phase of the master section, A.
    pub offset_master_a: [f64; 3],
    /// Offset per phase of the slave section, A.
    pub offset_slave_a: [f64; 3],
}

impl Default for CurrentSensor {
    fn default() -> Self {
        CurrentSensor {
            noise_a: 0.0,
            offset_master_a: [0.0; 3],
            offset_slave_a: [0.0; 3],
        }
    }
}

/// `[sensors.pressure]`: the four pressure sensors (chambers A and B, suction, discharge).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct PressureSensor {
    /// White noise, Pa RMS.
    pub noise_pa: f64,
    /// First-order lag of the sensor, s (0 = none).
    pub time_constant_s: f64,
    /// Offset of the chamber-A sensor, Pa.
    pub offset_a_pa: f64,
    /// Offset of the chamber-B sensor, Pa.
    pub offset_b_pa: f64,
    /// Offset of the suction-line sensor, Pa.
    pub offset_suction_pa: f64,
    /// Offset of the discharge-line sensor, Pa.
    pub offset_discharge_pa: f64,
}

impl Default for PressureSensor {
    fn default() -> Self {
        PressureSensor {
            noise_pa: 0.0,
            time_constant_s: 0.0,
            offset_a_pa: 0.0,
            offset_b_pa: 0.0,
            offset_suction_pa: 0.0,
            offset_discharge_pa: 0.0,
        }
    }
}

/// `[sensors]`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct SensorsSection {
    /// Master-section encoder.
    pub encoder_master: EncoderSensor,
    /// Slave-section encoder.
    pub encoder_slave: EncoderSensor,
    /// Current sensing.
    pub current: CurrentSensor,
    /// Pressure sensing.
    pub pressure: PressureSensor,
}

/// `[limits]`: what the controller must respect (its configuration takes them from here).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Limits {
    /// Head clearance the dead points aim at, m.
    pub target_head_clearance_m: f64,
    /// Head clearance that must never be undercut, m.
    pub min_head_clearance_m: f64,
    /// Total force of both sections, N.
    pub force_limit_n: f64,
    /// Largest commanded speed, m/s.
    pub max_speed_mps: f64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            target_head_clearance_m: 1.0e-3,
            min_head_clearance_m: 0.3e-3,
            force_limit_n: 10_000.0,
            max_speed_mps: 4.5,
        }
    }
}

/// `[simulation]`: numerical settings of the plant.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Simulation {
    /// Plant sub-steps per 50 µs control period.
    pub substeps_per_period: u32,
}

impl Default for Simulation {
    fn default() -> Self {
        Simulation {
            substeps_per_period: 1,
        }
    }
}

/// `[effects.cogging]`: `F = A·sin(2π·x/p + φ)` on the piston, toward +x.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CoggingEffect {
    /// Amplitude A, N.
    pub amplitude_n: f64,
    /// Period p, m.
    pub period_m: f64,
    /// Phase φ, rad.
    #[serde(default)]
    pub phase_rad: f64,
}

/// `[effects.slave_lag]` (and `[effects.actuator_lag]`): a transport delay.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DelayEffect {
    /// Delay, s.
    pub delay_s: f64,
}

/// `[effects.stribeck_friction]`: replaces the Stribeck part of `[friction]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StribeckEffect {
    /// Static (breakaway) level, N.
    pub static_n: f64,
    /// Stribeck velocity, m/s.
    pub velocity_mps: f64,
    /// Stribeck exponent.
    #[serde(default = "d::one")]
    pub exponent: f64,
}

/// `[effects.encoder_pitch_error]`: the slave encoder reads
/// `x·(1 + scale) + A·sin(2π·x/p + φ) + A₂·sin(4π·x/p + φ₂)`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PitchErrorEffect {
    /// Amplitude A at the period, m.
    pub amplitude_m: f64,
    /// Period p, m (λ).
    pub period_m: f64,
    /// Phase φ, rad.
    #[serde(default)]
    pub phase_rad: f64,
    /// Scale error (slope), dimensionless.
    #[serde(default)]
    pub scale: f64,
    /// Amplitude A₂ at half the period, m.
    #[serde(default)]
    pub amplitude2_m: f64,
    /// Phase φ₂ of the half-period term, rad.
    #[serde(default)]
    pub phase2_rad: f64,
}

/// `[effects.heat_transfer]`: `Q̇ = UA·(T_wall − T)` in each chamber.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HeatTransferEffect {
    /// UA of each chamber, W/K.
    pub ua_w_per_k: f64,
    /// Wall temperature, K (default: `gas.temperature_k`).
    pub wall_temperature_k: Option<f64>,
}

/// `[effects.leakage]`: laminar clearance leaks, piston seal A↔B and rod seals to ambient.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LeakageEffect {
    /// Radial clearance of the piston seal (A↔B), m (0 = none).
    pub gap_m: f64,
    /// Length of the piston seal, m.
    pub seal_length_m: f64,
    /// Radial clearance of each rod seal (chamber ↔ ambient), m (0 = none).
    #[serde(default)]
    pub rod_gap_m: f64,
    /// Length of each rod seal, m.
    #[serde(default = "d::rod_seal_length")]
    pub rod_seal_length_m: f64,
}

/// `[effects.port_restriction]`: the ports pass less than their geometry says.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PortRestrictionEffect {
    /// Factor on every port's effective area C_d·A (1 = as designed).
    pub area_scale: f64,
}

/// `[effects.section_misalignment]`: the slave section's magnets sit `offset_m` along x from
/// where its encoder says (paper Eq. 4), so its commutation is off by 2π·offset/λ.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MisalignmentEffect {
    /// Offset D_dif, m.
    pub offset_m: f64,
}

/// `[effects]`: what the model-gap workflow adds. Absent = not in the physics.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Effects {
    /// Cogging.
    pub cogging: Option<CoggingEffect>,
    /// The slave section's force lags the master's (implies the slave follows the master).
    pub slave_lag: Option<DelayEffect>,
    /// Stribeck friction.
    pub stribeck_friction: Option<StribeckEffect>,
    /// Slave encoder pitch error.
    pub encoder_pitch_error: Option<PitchErrorEffect>,
    /// Heat transfer to the wall.
    pub heat_transfer: Option<HeatTransferEffect>,
    /// Clearance leakage.
    pub leakage: Option<LeakageEffect>,
    /// Port restriction.
    pub port_restriction: Option<PortRestrictionEffect>,
    /// Both sections' force lags their current by this delay.
    pub actuator_lag: Option<DelayEffect>,
    /// Section-to-section misalignment.
    pub section_misalignment: Option<MisalignmentEffect>,
}

/// A machine model.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MachineModel {
    /// Piston and cylinder geometry.
    pub piston: Piston,
    /// Friction of the translation.
    pub friction: Friction,
    /// The gas.
    pub gas: Gas,
    /// Linear motor.
    pub motor: Motor,
    /// Linear encoders.
    pub encoder: Encoder,
    /// Ports.
    #[serde(default)]
    pub ports: Ports,
    /// Suction and discharge lines.
    #[serde(default)]
    pub lines: Lines,
    /// Rotation servo.
    #[serde(default)]
    pub servo: Servo,
    /// Sensor models.
    #[serde(default)]
    pub sensors: SensorsSection,
    /// Controller limits.
    #[serde(default)]
    pub limits: Limits,
    /// Numerical settings.
    #[serde(default)]
    pub simulation: Simulation,
    /// Effects.
    #[serde(default)]
    pub effects: Effects,
}

/// Why a model file was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModelError(pub String);

impl std::fmt::Display for ModelError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ModelError {}

/// What a value must be.
#[derive(Clone, Copy)]
enum Rule {
    Positive,
    NonNegative,
    Finite,
    /// A fraction-like factor in (0, max].
    InUnit(f64),
}

fn check(key: &str, v: f64, rule: Rule) -> Result<(), ModelError> {
    let ok = v.is_finite()
        && match rule {
            Rule::Positive => v > 0.0,
            Rule::NonNegative => v >= 0.0,
            Rule::Finite => true,
            Rule::InUnit(max) => v > 0.0 && v <= max,
        };
    if ok {
        return Ok(());
    }
    let what = match rule {
        Rule::Positive => "positive and finite".to_string(),
        Rule::NonNegative => "zero or positive".to_string(),
        Rule::Finite => "finite".to_string(),
        Rule::InUnit(max) => format!("in (0, {max}]"),
    };
    Err(ModelError(format!("`{key}` must be {what}, got {v}")))
}

impl MachineModel {
    /// The embedded reference machine.
    pub fn reference() -> Self {
        // The embedded file is checked by a unit test; it cannot fail at run time.
        Self::parse(REFERENCE_TOML).unwrap_or_else(|e| panic!("embedded reference.toml: {e}"))
    }

    /// Parses and validates model text.
    pub fn parse(text: &str) -> Result<Self, ModelError> {
        let model: MachineModel =
            toml::from_str(text).map_err(|e| ModelError(describe(&e, text)))?;
        model.validate()?;
        Ok(model)
    }

    /// Reads and validates a model file.
    pub fn read(path: &std::path::Path) -> Result<Self, ModelError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ModelError(format!("cannot read {}: {e}", path.display())))?;
        Self::parse(&text).map_err(|e| ModelError(format!("{}: {}", path.display(), e.0)))
    }

    fn validate(&self) -> Result<(), ModelError> {
        use Rule::*;
        let p = &self.piston;
        let g = &self.gas;
        let m = &self.motor;
        let po = &self.ports;
        let sv = &self.servo;
        let s = &self.sensors;
        let l = &self.limits;
        let mut checks: Vec<(String, f64, Rule)> = vec![
            ("piston.mass_kg".into(), p.mass_kg, Positive),
            ("piston.bore_m".into(), p.bore_m, Positive),
            ("piston.rod_m".into(), p.rod_m, NonNegative),
            ("piston.travel_m".into(), p.travel_m, Positive),
            (
                "piston.dead_length_a_m".into(),
                p.dead_length_a_m,
                NonNegative,
            ),
            (
                "piston.dead_length_b_m".into(),
                p.dead_length_b_m,
                NonNegative,
            ),
            (
                "piston.stop_stiffness_n_per_m".into(),
                p.stop_stiffness_n_per_m,
                Positive,
            ),
            (
                "piston.stop_damping_ns_per_m".into(),
                p.stop_damping_ns_per_m,
                NonNegative,
            ),
            (
                "friction.coulomb_n".into(),
                self.friction.coulomb_n,
                NonNegative,
            ),
            (
                "friction.viscous_ns_per_m".into(),
                self.friction.viscous_ns_per_m,
                NonNegative,
            ),
            ("gas.gamma".into(), g.gamma, Positive),
            (
                "gas.gas_constant_j_per_kg_k".into(),
                g.gas_constant_j_per_kg_k,
                Positive,
            ),
            ("gas.temperature_k".into(), g.temperature_k, Positive),
            ("gas.ambient_pa".into(), g.ambient_pa, Positive),
            ("gas.viscosity_pa_s".into(), g.viscosity_pa_s, Positive),
            ("motor.pole_pitch_m".into(), m.pole_pitch_m, Positive),
            (
                "motor.force_constant_n_per_a".into(),
                m.force_constant_n_per_a,
                Positive,
            ),
            ("motor.resistance_ohm".into(), m.resistance_ohm, Positive),
            ("motor.inductance_h".into(), m.inductance_h, Positive),
            ("motor.bus_voltage_v".into(), m.bus_voltage_v, Positive),
            ("motor.current_limit_a".into(), m.current_limit_a, Positive),
            ("encoder.period_m".into(), self.encoder.period_m, Positive),
            ("ports.ramp_deg".into(), po.ramp_deg, NonNegative),
            ("ports.intake_area_m2".into(), po.intake_area_m2, Positive),
            (
                "ports.discharge_area_m2".into(),
                po.discharge_area_m2,
                Positive,
            ),
            (
                "ports.discharge_coefficient".into(),
                po.discharge_coefficient,
                InUnit(1.0),
            ),
            ("lines.suction_pa".into(), self.lines.suction_pa, Positive),
            (
                "lines.pressure_ratio".into(),
                self.lines.pressure_ratio,
                Positive,
            ),
            ("servo.inertia_kgm2".into(), sv.inertia_kgm2, Positive),
            (
                "servo.viscous_nms_per_rad".into(),
                sv.viscous_nms_per_rad,
                NonNegative,
            ),
            ("servo.coulomb_nm".into(), sv.coulomb_nm, NonNegative),
            (
                "servo.torque_full_scale_nm".into(),
                sv.torque_full_scale_nm,
                Positive,
            ),
            ("servo.torque_limit_nm".into(), sv.torque_limit_nm, Positive),
            (
                "servo.torque_time_constant_s".into(),
                sv.torque_time_constant_s,
                NonNegative,
            ),
            ("servo.backlash_rad".into(), sv.backlash_rad, NonNegative),
            (
                "sensors.current.noise_a".into(),
                s.current.noise_a,
                NonNegative,
            ),
            (
                "sensors.pressure.noise_pa".into(),
                s.pressure.noise_pa,
                NonNegative,
            ),
            (
                "sensors.pressure.time_constant_s".into(),
                s.pressure.time_constant_s,
                NonNegative,
            ),
            (
                "limits.target_head_clearance_m".into(),
                l.target_head_clearance_m,
                Positive,
            ),
            (
                "limits.min_head_clearance_m".into(),
                l.min_head_clearance_m,
                NonNegative,
            ),
            ("limits.force_limit_n".into(), l.force_limit_n, Positive),
            ("limits.max_speed_mps".into(), l.max_speed_mps, Positive),
        ];
        for (name, v) in [
            ("static_n", self.friction.static_n),
            ("stribeck_velocity_mps", self.friction.stribeck_velocity_mps),
            ("stribeck_exponent", self.friction.stribeck_exponent),
        ] {
            if let Some(v) = v {
                checks.push((format!("friction.{name}"), v, Positive));
            }
        }
        for (section, o) in [("master", &m.master), ("slave", &m.slave)] {
            for (name, v) in [
                ("force_constant_n_per_a", o.force_constant_n_per_a),
                ("resistance_ohm", o.resistance_ohm),
                ("inductance_h", o.inductance_h),
            ] {
                if let Some(v) = v {
                    checks.push((format!("motor.{section}.{name}"), v, Positive));
                }
            }
        }
        for (name, w) in [
            ("intake_a_deg", po.intake_a_deg),
            ("discharge_a_deg", po.discharge_a_deg),
            ("intake_b_deg", po.intake_b_deg),
            ("discharge_b_deg", po.discharge_b_deg),
        ] {
            for v in w {
                if !(v.is_finite() && (0.0..=360.0).contains(&v)) {
                    return Err(ModelError(format!(
                        "`ports.{name}` edges must lie in [0, 360] degrees, got {v}"
                    )));
                }
            }
        }
        for (name, e) in [
            ("encoder_master", &s.encoder_master),
            ("encoder_slave", &s.encoder_slave),
        ] {
            checks.push((
                format!("sensors.{name}.amplitude_codes"),
                e.amplitude_codes,
                Positive,
            ));
            checks.push((
                format!("sensors.{name}.noise_codes"),
                e.noise_codes,
                NonNegative,
            ));
            for (k, v) in [
                ("sin_offset_codes", e.sin_offset_codes),
                ("cos_offset_codes", e.cos_offset_codes),
                ("quadrature_error_rad", e.quadrature_error_rad),
            ] {
                checks.push((format!("sensors.{name}.{k}"), v, Finite));
            }
            if !(e.gain_mismatch.is_finite() && e.gain_mismatch > -1.0) {
                return Err(ModelError(format!(
                    "`sensors.{name}.gain_mismatch` must be finite and above −1, got {}",
                    e.gain_mismatch
                )));
            }
        }
        for (k, v) in [
            ("offset_a_pa", s.pressure.offset_a_pa),
            ("offset_b_pa", s.pressure.offset_b_pa),
            ("offset_suction_pa", s.pressure.offset_suction_pa),
            ("offset_discharge_pa", s.pressure.offset_discharge_pa),
        ] {
            checks.push((format!("sensors.pressure.{k}"), v, Finite));
        }
        for (k, o) in [
            ("offset_master_a", s.current.offset_master_a),
            ("offset_slave_a", s.current.offset_slave_a),
        ] {
            for v in o {
                checks.push((format!("sensors.current.{k}"), v, Finite));
            }
        }
        let e = &self.effects;
        if let Some(c) = &e.cogging {
            checks.push(("effects.cogging.amplitude_n".into(), c.amplitude_n, Finite));
            checks.push(("effects.cogging.period_m".into(), c.period_m, Positive));
            checks.push(("effects.cogging.phase_rad".into(), c.phase_rad, Finite));
        }
        if let Some(d) = &e.slave_lag {
            checks.push(("effects.slave_lag.delay_s".into(), d.delay_s, NonNegative));
        }
        if let Some(d) = &e.actuator_lag {
            checks.push((
                "effects.actuator_lag.delay_s".into(),
                d.delay_s,
                NonNegative,
            ));
        }
        if let Some(st) = &e.stribeck_friction {
            checks.push((
                "effects.stribeck_friction.static_n".into(),
                st.static_n,
                NonNegative,
            ));
            checks.push((
                "effects.stribeck_friction.velocity_mps".into(),
                st.velocity_mps,
                Positive,
            ));
            checks.push((
                "effects.stribeck_friction.exponent".into(),
                st.exponent,
                Positive,
            ));
        }
        if let Some(pe) = &e.encoder_pitch_error {
            for (k, v, r) in [
                ("amplitude_m", pe.amplitude_m, Finite),
                ("period_m", pe.period_m, Positive),
                ("phase_rad", pe.phase_rad, Finite),
                ("scale", pe.scale, Finite),
                ("amplitude2_m", pe.amplitude2_m, Finite),
                ("phase2_rad", pe.phase2_rad, Finite),
            ] {
                checks.push((format!("effects.encoder_pitch_error.{k}"), v, r));
            }
        }
        if let Some(h) = &e.heat_transfer {
            checks.push((
                "effects.heat_transfer.ua_w_per_k".into(),
                h.ua_w_per_k,
                NonNegative,
            ));
            if let Some(t) = h.wall_temperature_k {
                checks.push((
                    "effects.heat_transfer.wall_temperature_k".into(),
                    t,
                    Positive,
                ));
            }
        }
        if let Some(lk) = &e.leakage {
            checks.push(("effects.leakage.gap_m".into(), lk.gap_m, NonNegative));
            checks.push((
                "effects.leakage.seal_length_m".into(),
                lk.seal_length_m,
                Positive,
            ));
            checks.push((
                "effects.leakage.rod_gap_m".into(),
                lk.rod_gap_m,
                NonNegative,
            ));
            checks.push((
                "effects.leakage.rod_seal_length_m".into(),
                lk.rod_seal_length_m,
                Positive,
            ));
        }
        if let Some(r) = &e.port_restriction {
            checks.push((
                "effects.port_restriction.area_scale".into(),
                r.area_scale,
                InUnit(10.0),
            ));
        }
        if let Some(mis) = &e.section_misalignment {
            checks.push((
                "effects.section_misalignment.offset_m".into(),
                mis.offset_m,
                Finite,
            ));
        }
        for (key, v, rule) in &checks {
            check(key, *v, *rule)?;
        }
        if p.rod_m >= p.bore_m {
            return Err(ModelError(
                "`piston.rod_m` must be smaller than `piston.bore_m`".into(),
            ));
        }
        if g.gamma <= 1.0 {
            return Err(ModelError(format!(
                "`gas.gamma` must exceed 1, got {}",
                g.gamma
            )));
        }
        if sv.counts_per_rev == 0 {
            return Err(ModelError("`servo.counts_per_rev` must be positive".into()));
        }
        let sub = self.simulation.substeps_per_period;
        if !(1..=64).contains(&sub) {
            return Err(ModelError(format!(
                "`simulation.substeps_per_period` must be in [1, 64], got {sub}"
            )));
        }
        if l.min_head_clearance_m > l.target_head_clearance_m {
            return Err(ModelError(
                "`limits.min_head_clearance_m` must not exceed `limits.target_head_clearance_m`"
                    .into(),
            ));
        }
        Ok(())
    }

    /// Effective piston area A_eff = π(D² − d²)/4, m².
    pub fn piston_area_m2(&self) -> f64 {
        self.cylinder().area_m2
    }

    /// The cylinder geometry.
    pub fn cylinder(&self) -> Cylinder<f64> {
        let p = &self.piston;
        Cylinder::from_bore(
            p.bore_m,
            p.rod_m,
            p.travel_m,
            p.dead_length_a_m,
            p.dead_length_b_m,
        )
    }

    /// The gas properties.
    pub fn gas_properties(&self) -> GasProperties<f64> {
        GasProperties {
            gamma: self.gas.gamma,
            gas_constant_j_per_kg_k: self.gas.gas_constant_j_per_kg_k,
            viscosity_pa_s: self.gas.viscosity_pa_s,
        }
    }

    /// The friction law of this model (`[effects.stribeck_friction]`, when present, replaces
    /// the Stribeck part of `[friction]`).
    pub fn friction(&self) -> FrictionParams<f64> {
        let mut f = FrictionParams::<f64>::reference();
        f.coulomb_n = self.friction.coulomb_n;
        f.viscous_ns_per_m = self.friction.viscous_ns_per_m;
        f.static_n = self.friction.static_n.unwrap_or(self.friction.coulomb_n);
        if let Some(v) = self.friction.stribeck_velocity_mps {
            f.stribeck_velocity_mps = v;
        }
        if let Some(z) = self.friction.stribeck_exponent {
            f.stribeck_exponent = z;
        }
        if let Some(s) = &self.effects.stribeck_friction {
            f.static_n = s.static_n;
            f.stribeck_velocity_mps = s.velocity_mps;
            f.stribeck_exponent = s.exponent;
        }
        // The sign regularisation must stay well below the Stribeck velocity.
        f.sign_velocity_mps = f.sign_velocity_mps.min(0.05 * f.stribeck_velocity_mps);
        f
    }

    /// The port geometry (`[effects.port_restriction]` not included: see
    /// [`MachineModel::port_area_scale`]).
    pub fn port_geometry(&self) -> PortGeometry<f64> {
        let p = &self.ports;
        let w = |d: [f64; 2]| PortWindow::from_degrees(d[0], d[1]);
        PortGeometry {
            intake_a: w(p.intake_a_deg),
            discharge_a: w(p.discharge_a_deg),
            intake_b: w(p.intake_b_deg),
            discharge_b: w(p.discharge_b_deg),
            ramp_rad: p.ramp_deg.to_radians(),
            intake_area_m2: p.intake_area_m2,
            discharge_area_m2: p.discharge_area_m2,
            discharge_coefficient: p.discharge_coefficient,
        }
    }

    /// Factor on every port's effective area (`[effects.port_restriction]`, else 1).
    pub fn port_area_scale(&self) -> f64 {
        self.effects
            .port_restriction
            .as_ref()
            .map_or(1.0, |r| r.area_scale)
    }

    /// The motor parameters of the master and slave sections.
    pub fn motor_sections(&self) -> fpc::units::PerSection<MotorParams<f64>> {
        let m = &self.motor;
        let section = |o: &SectionOverride| MotorParams {
            force_constant_n_per_a: o.force_constant_n_per_a.unwrap_or(m.force_constant_n_per_a),
            resistance_ohm: o.resistance_ohm.unwrap_or(m.resistance_ohm),
            inductance_h: o.inductance_h.unwrap_or(m.inductance_h),
            electrical_period_m: 2.0 * m.pole_pitch_m,
            bus_voltage_v: m.bus_voltage_v,
            current_limit_a: m.current_limit_a,
        };
        fpc::units::PerSection {
            master: section(&m.master),
            slave: section(&m.slave),
        }
    }

    /// The cogging law, if the effect is present.
    pub fn cogging(&self) -> Option<CoggingParams<f64>> {
        self.effects.cogging.as_ref().map(|c| CoggingParams {
            amplitude_n: c.amplitude_n,
            period_m: c.period_m,
            phase_rad: c.phase_rad,
        })
    }

    /// Delay of the slave section's force behind the master's, if the slave follows the
    /// master (`[motor] slave_follows_master`, or `[effects.slave_lag]` present), s: the
    /// effect's `delay_s`, or 0 when the slave follows with no `[effects.slave_lag]` (the
    /// contract's nominal model: "commanded with the master's force" says nothing of a lag,
    /// so a model without the effect must not carry one).
    pub fn slave_lag_s(&self) -> Option<f64> {
        match (&self.effects.slave_lag, self.motor.slave_follows_master) {
            (Some(l), _) => Some(l.delay_s),
            (None, true) => Some(0.0),
            (None, false) => None,
        }
    }

    /// The piston seal's leak (A↔B) and the rod seals' leak (each chamber ↔ ambient), if
    /// present.
    pub fn leaks(&self) -> (Option<AnnulusLeak<f64>>, Option<AnnulusLeak<f64>>) {
        let Some(l) = &self.effects.leakage else {
            return (None, None);
        };
        let piston = (l.gap_m > 0.0).then_some(AnnulusLeak {
            diameter_m: self.piston.bore_m,
            gap_m: l.gap_m,
            seal_length_m: l.seal_length_m,
        });
        let rod = (l.rod_gap_m > 0.0 && self.piston.rod_m > 0.0).then_some(AnnulusLeak {
            diameter_m: self.piston.rod_m,
            gap_m: l.rod_gap_m,
            seal_length_m: l.rod_seal_length_m,
        });
        (piston, rod)
    }
}

/// Defaults of the optional keys in the required sections (reference machine).
mod d {
    pub fn stop_stiffness() -> f64 {
        5.0e7 // A: steel head with a polymer bumper
    }
    pub fn stop_damping() -> f64 {
        2.0e4 // A
    }
    pub fn viscosity() -> f64 {
        1.8e-5 // air at 20 °C
    }
    pub fn force_constant() -> f64 {
        80.0 // A: 5 kN peak at 62.5 A
    }
    pub fn resistance() -> f64 {
        0.6 // A
    }
    pub fn inductance() -> f64 {
        6e-3 // A
    }
    pub fn bus_voltage() -> f64 {
        560.0 // A
    }
    pub fn current_limit() -> f64 {
        62.5 // A
    }
    pub fn rod_seal_length() -> f64 {
        0.03 // A
    }
    pub fn one() -> f64 {
        1.0
    }
}

/// One line naming the key at fault (serde names the unknown or missing field), with the
/// line it was found on.
fn describe(e: &toml::de::Error, text: &str) -> String {
    let msg = e.message().trim().replace('\n', " ");
    match e.span() {
        Some(span) => {
            let before = text.get(..span.start).unwrap_or("");
            let line = before.matches('\n').count() + 1;
            // A missing key is reported on its table: name the table too.
            let table = before
                .lines()
                .chain(text.get(span.start..).unwrap_or("").lines().take(1))
                .filter(|l| l.trim_start().starts_with('['))
                .last()
                .map(|l| l.split('#').next().unwrap_or(l).trim().to_string());
            match table {
                Some(t) if msg.starts_with("missing field") => {
                    format!("line {line}: {msg} in {t}")
                }
                _ => format!("line {line}: {msg}"),
            }
        }
        None => msg,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The minimal file of `formats.md` §2.
    pub const MINIMAL: &str = include_str!("../../tests/data/minimal_model.toml");

    #[test]
    fn the_minimal_file_loads_with_reference_defaults_and_no_effects() {
        let m = MachineModel::parse(MINIMAL).unwrap();
        assert!((m.piston_area_m2() - 6.05e-3).abs() < 0.05e-3);
        assert_eq!(m.ports, Ports::default());
        assert_eq!(m.effects, Effects::default());
        assert_eq!(m.slave_lag_s(), Some(0.0));
        let r = MachineModel::reference();
        assert!(r.cogging().is_some() && r.effects.leakage.is_some());
        assert_eq!(r.slave_lag_s(), None);
    }

    fn refused(text: &str) -> String {
        MachineModel::parse(text).unwrap_err().0
    }

    #[test]
    fn bad_files_are_refused_naming_the_key() {
        let unknown = MINIMAL.replace("coulomb_n = 40.0", "coulomb_n = 40.0\ncolomb_n = 1.0");
        assert!(refused(&unknown).contains("colomb_n"));
        let missing = MINIMAL.replace("mass_kg = 12.0\n", "");
        assert!(refused(&missing).contains("mass_kg"));
        let negative = MINIMAL.replace("mass_kg = 12.0", "mass_kg = -1.0");
        assert!(refused(&negative).contains("piston.mass_kg"));
        let zero = MINIMAL.replace("period_m = 0.024", "period_m = 0.0");
        assert!(refused(&zero).contains("encoder.period_m"));
        let effect = format!("{MINIMAL}\n[effects.cogging]\namplitude_n = 30.0\nperiod_m = 0.0\n");
        assert!(refused(&effect).contains("effects.cogging.period_m"));
        let typo = format!("{MINIMAL}\n[effects.coging]\namplitude_n = 30.0\n");
        assert!(refused(&typo).contains("coging"));
        let no_amp = format!("{MINIMAL}\n[effects.cogging]\nperiod_m = 0.024\n");
        assert!(refused(&no_amp).contains("amplitude_n"));
        let window = format!("{MINIMAL}\n[ports]\ndischarge_a_deg = [288.0, 400.0]\n");
        assert!(refused(&window).contains("ports.discharge_a_deg"));
        let sensor = format!("{MINIMAL}\n[sensors.encoder_slave]\nnoise_codez = 1.0\n");
        assert!(refused(&sensor).contains("noise_codez"));
    }

    #[test]
    fn a_partial_project_section_keeps_the_other_reference_values() {
        let m = MachineModel::parse(&format!("{MINIMAL}\n[servo]\ninertia_kgm2 = 3e-3\n")).unwrap();
        assert_eq!(m.servo.inertia_kgm2, 3e-3);
        assert_eq!(m.servo.counts_per_rev, 4096);
    }

    #[test]
    fn stribeck_effect_replaces_the_friction_section_values() {
        let m = MachineModel::parse(&format!(
            "{MINIMAL}\n[effects.stribeck_friction]\nstatic_n = 80.0\nvelocity_mps = 0.01\n"
        ))
        .unwrap();
        let f = m.friction();
        assert_eq!((f.static_n, f.stribeck_velocity_mps), (80.0, 0.01));
    }
}
