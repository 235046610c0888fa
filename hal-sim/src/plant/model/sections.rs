//! The sections of the model file, one struct each, as serde reads them: the required
//! physics sections, the project's own sections with the reference machine's values as
//! defaults, and the `[effects.*]` the model-gap workflow adds. Each states the rule and
//! the physical range of its numeric keys right after it (`checks!`, `validate::Checked`):
//! a key is its field, so a renamed field renames its check.

use fpc::physics::port_timing::{PortGeometry, PortWindow};
use serde::{Deserialize, Deserializer};

use super::validate::Rule::*;
use super::validate::ADC_HALF_RANGE_CODES;

/// An array of exactly `N` numbers: a longer or shorter one is refused naming its length
/// (serde's fixed-size arrays leave extra elements unread).
fn exact_array<'de, D: Deserializer<'de>, const N: usize>(d: D) -> Result<[f64; N], D::Error> {
    let values = Vec::<f64>::deserialize(d)?;
    let len = values.len();
    values.try_into().map_err(|_| {
        serde::de::Error::invalid_length(len, &format!("an array of {N} numbers").as_str())
    })
}

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

checks!(Piston {
    mass_kg: Positive, 0.01, 1000.0, "kg";
    bore_m: Positive, 1e-3, 1.0, "m";
    rod_m: NonNegative, 0.0, 0.5, "m";
    travel_m: Positive, 1e-3, 2.0, "m";
    dead_length_a_m: NonNegative, 0.0, 0.5, "m";
    dead_length_b_m: NonNegative, 0.0, 0.5, "m";
    stop_stiffness_n_per_m: Positive, 1e3, 1e12, "N/m";
    stop_damping_ns_per_m: NonNegative, 0.0, 1e8, "N·s/m";
});

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

checks!(Friction {
    coulomb_n: NonNegative, 0.0, 1e5, "N";
    viscous_ns_per_m: NonNegative, 0.0, 1e6, "N·s/m";
    static_n: Positive, 0.0, 1e5, "N";
    stribeck_velocity_mps: Positive, 1e-5, 10.0, "m/s";
    stribeck_exponent: Positive, 0.1, 10.0, "";
});

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

checks!(Gas {
    gamma: Positive, 1.0, 1.7, "";
    gas_constant_j_per_kg_k: Positive, 10.0, 5000.0, "J/(kg·K)";
    temperature_k: Positive, 50.0, 1000.0, "K";
    ambient_pa: Positive, 1e4, 2e5, "Pa";
    viscosity_pa_s: Positive, 1e-7, 1e-2, "Pa·s";
});

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

checks!(SectionOverride {
    force_constant_n_per_a: Positive, FORCE_CONSTANT.0, FORCE_CONSTANT.1, "N/A";
    resistance_ohm: Positive, RESISTANCE.0, RESISTANCE.1, "Ω";
    inductance_h: Positive, INDUCTANCE.0, INDUCTANCE.1, "H";
});

/// Ranges a section's electrics share with its overrides, (min, max).
const FORCE_CONSTANT: (f64, f64) = (0.1, 1e4);
const RESISTANCE: (f64, f64) = (1e-4, 1e3);
const INDUCTANCE: (f64, f64) = (1e-7, 10.0);

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

checks!(Motor {
    pole_pitch_m: Positive, 1e-3, 0.5, "m";
    force_constant_n_per_a: Positive, FORCE_CONSTANT.0, FORCE_CONSTANT.1, "N/A";
    resistance_ohm: Positive, RESISTANCE.0, RESISTANCE.1, "Ω";
    inductance_h: Positive, INDUCTANCE.0, INDUCTANCE.1, "H";
    bus_voltage_v: Positive, 1.0, 2000.0, "V";
    current_limit_a: Positive, 0.1, 1000.0, "A";
});

/// `[encoder]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Encoder {
    /// Signal period λ, m.
    pub period_m: f64,
}

checks!(Encoder {
    period_m: Positive, 1e-6, 0.1, "m";
});

/// `[ports]`: the port windows in rotation phase (degrees, 0 = dead point A) and the flow
/// areas. See [`fpc::physics::port_timing`].
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Ports {
    /// Intake A window `[open, close]`, degrees.
    #[serde(deserialize_with = "exact_array")]
    pub intake_a_deg: [f64; 2],
    /// Discharge A window, degrees.
    #[serde(deserialize_with = "exact_array")]
    pub discharge_a_deg: [f64; 2],
    /// Intake B window, degrees.
    #[serde(deserialize_with = "exact_array")]
    pub intake_b_deg: [f64; 2],
    /// Discharge B window, degrees.
    #[serde(deserialize_with = "exact_array")]
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

checks!(Ports {
    intake_a_deg: Degrees, 0.0, 360.0, "°";
    discharge_a_deg: Degrees, 0.0, 360.0, "°";
    intake_b_deg: Degrees, 0.0, 360.0, "°";
    discharge_b_deg: Degrees, 0.0, 360.0, "°";
    ramp_deg: NonNegative, 0.0, 90.0, "°";
    intake_area_m2: Positive, 1e-8, 0.1, "m²";
    discharge_area_m2: Positive, 1e-8, 0.1, "m²";
    discharge_coefficient: InUnit(1.0), 0.0, 1.0, "";
});

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

checks!(Lines {
    suction_pa: Positive, 1e4, 1e6, "Pa";
    pressure_ratio: Positive, 1.0, 20.0, "";
});

impl Default for Lines {
    fn default() -> Self {
        use fpc::reference::lines;
        Lines {
            suction_pa: lines::SUCTION_PA,
            pressure_ratio: lines::PRESSURE_RATIO,
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

checks!(Servo {
    inertia_kgm2: Positive, 1e-7, 10.0, "kg·m²";
    viscous_nms_per_rad: NonNegative, 0.0, 100.0, "N·m·s/rad";
    coulomb_nm: NonNegative, 0.0, 100.0, "N·m";
    torque_full_scale_nm: Positive, 1e-3, 1000.0, "N·m";
    torque_limit_nm: Positive, 1e-3, 1000.0, "N·m";
    torque_time_constant_s: NonNegative, 0.0, 0.1, "s";
    backlash_rad: NonNegative, 0.0, 0.5, "rad";
    counts_per_rev: Count, 256.0, 1048576.0, "counts";
});

impl Default for Servo {
    fn default() -> Self {
        use fpc::reference::servo;
        Servo {
            inertia_kgm2: servo::INERTIA_KGM2,
            viscous_nms_per_rad: servo::VISCOUS_NMS_PER_RAD,
            coulomb_nm: servo::COULOMB_NM,
            torque_full_scale_nm: servo::TORQUE_FULL_SCALE_NM,
            torque_limit_nm: servo::TORQUE_LIMIT_NM,
            torque_time_constant_s: servo::TORQUE_TIME_CONSTANT_S,
            backlash_rad: servo::BACKLASH_RAD,
            counts_per_rev: servo::COUNTS_PER_REV,
        }
    }
}

/// `[supply]`: the drive board's supply — the DC link both motor sections and the servo
/// drive share, and the logic supply taken from it. The link's nominal voltage is
/// `motor.bus_voltage_v` (the mains rectifier holds it there while the mains is present).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Supply {
    /// DC-link capacitance, F.
    pub link_capacitance_f: f64,
    /// The brake chopper's threshold, V: regenerated power that would lift the link above it
    /// is burnt in the chopper's resistor (the link's voltage limit).
    pub chopper_voltage_v: f64,
    /// The power-good comparator's threshold, V: below it the board's undervoltage input
    /// (active-high power good) goes low.
    pub power_good_voltage_v: f64,
    /// The logic supply's lowest input, V: below it the MCU, the gate drivers and the
    /// sensors are off (outputs low).
    pub logic_dropout_voltage_v: f64,
    /// What the logic draws from the link, W: MCU, gate drivers, sensors, the servo drive's
    /// own electronics.
    pub logic_power_w: f64,
    /// The servo drive's efficiency: its shaft power drawn from the link divided by it
    /// (what the servo brakes is burnt in its drive, none goes back).
    pub servo_efficiency: f64,
    /// Knee voltage of a conducting switch or diode of a section's bridge, V (its loss
    /// model: `plant::bridge`).
    pub bridge_forward_voltage_v: f64,
    /// Slope resistance of a conducting switch or diode, Ω.
    pub bridge_on_resistance_ohm: f64,
    /// Turn-on plus turn-off energy of a bridge leg per volt of link and ampere switched,
    /// J/(V·A).
    pub bridge_switching_energy_j_per_va: f64,
}

checks!(Supply {
    link_capacitance_f: Positive, 1e-6, 1.0, "F";
    chopper_voltage_v: Positive, 1.0, 2000.0, "V";
    power_good_voltage_v: Positive, 1.0, 2000.0, "V";
    logic_dropout_voltage_v: Positive, 1.0, 2000.0, "V";
    logic_power_w: NonNegative, 0.0, 10_000.0, "W";
    servo_efficiency: Positive, 0.05, 1.0, "";
    bridge_forward_voltage_v: NonNegative, 0.0, 10.0, "V";
    bridge_on_resistance_ohm: NonNegative, 0.0, 10.0, "Ω";
    bridge_switching_energy_j_per_va: NonNegative, 0.0, 1e-4, "J/(V·A)";
});

impl Default for Supply {
    fn default() -> Self {
        use fpc::reference::supply;
        Supply {
            link_capacitance_f: supply::LINK_CAPACITANCE_F,
            chopper_voltage_v: supply::CHOPPER_VOLTAGE_V,
            power_good_voltage_v: supply::POWER_GOOD_VOLTAGE_V,
            logic_dropout_voltage_v: supply::LOGIC_DROPOUT_VOLTAGE_V,
            logic_power_w: supply::LOGIC_POWER_W,
            servo_efficiency: supply::SERVO_EFFICIENCY,
            bridge_forward_voltage_v: supply::BRIDGE_FORWARD_VOLTAGE_V,
            bridge_on_resistance_ohm: supply::BRIDGE_ON_RESISTANCE_OHM,
            bridge_switching_energy_j_per_va: supply::BRIDGE_SWITCHING_ENERGY_J_PER_VA,
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

checks!(EncoderSensor {
    amplitude_codes: Positive, 1.0, ADC_HALF_RANGE_CODES, "codes";
    sin_offset_codes: Finite, -2047.0, 2047.0, "codes";
    cos_offset_codes: Finite, -2047.0, 2047.0, "codes";
    gain_mismatch: Finite, -0.99, 10.0, "";
    quadrature_error_rad: Finite, -1.0, 1.0, "rad";
    noise_codes: NonNegative, 0.0, 200.0, "codes";
});

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
    #[serde(deserialize_with = "exact_array")]
    pub offset_master_a: [f64; 3],
    /// Offset per phase of the slave section, A.
    #[serde(deserialize_with = "exact_array")]
    pub offset_slave_a: [f64; 3],
}

checks!(CurrentSensor {
    noise_a: NonNegative, 0.0, 10.0, "A";
    offset_master_a: Finite, -10.0, 10.0, "A";
    offset_slave_a: Finite, -10.0, 10.0, "A";
});

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
    /// Gain of the chamber-A sensor: its reading per pascal of (lagged) pressure.
    pub gain_a: f64,
    /// Gain of the chamber-B sensor.
    pub gain_b: f64,
}

checks!(PressureSensor {
    noise_pa: NonNegative, 0.0, 1e5, "Pa";
    time_constant_s: NonNegative, 0.0, 1.0, "s";
    offset_a_pa: Finite, -1e5, 1e5, "Pa";
    offset_b_pa: Finite, -1e5, 1e5, "Pa";
    offset_suction_pa: Finite, -1e5, 1e5, "Pa";
    offset_discharge_pa: Finite, -1e5, 1e5, "Pa";
    gain_a: Positive, 0.5, 2.0, "";
    gain_b: Positive, 0.5, 2.0, "";
});

impl Default for PressureSensor {
    fn default() -> Self {
        PressureSensor {
            noise_pa: 0.0,
            time_constant_s: 0.0,
            offset_a_pa: 0.0,
            offset_b_pa: 0.0,
            offset_suction_pa: 0.0,
            offset_discharge_pa: 0.0,
            gain_a: 1.0,
            gain_b: 1.0,
        }
    }
}

/// `[sensors.force]`: the force each section reports to the log, `gain·F + offset` of the
/// force its drive makes from the measured currents (`plant::sensing`). The drives and the
/// controller act on the currents: an error of the reported value, not of the force applied.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ForceSensor {
    /// Offset of the master section's force reading, N.
    pub offset_master_n: f64,
    /// Offset of the slave section's force reading, N.
    pub offset_slave_n: f64,
    /// Gain of the master section's force reading: reported newtons per newton.
    pub gain_master: f64,
    /// Gain of the slave section's force reading.
    pub gain_slave: f64,
}

checks!(ForceSensor {
    offset_master_n: Finite, -1000.0, 1000.0, "N";
    offset_slave_n: Finite, -1000.0, 1000.0, "N";
    gain_master: Positive, 0.5, 2.0, "";
    gain_slave: Positive, 0.5, 2.0, "";
});

impl Default for ForceSensor {
    fn default() -> Self {
        ForceSensor {
            offset_master_n: 0.0,
            offset_slave_n: 0.0,
            gain_master: 1.0,
            gain_slave: 1.0,
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
    /// The sections' force readings.
    pub force: ForceSensor,
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

checks!(Limits {
    target_head_clearance_m: Positive, 1e-5, 0.05, "m";
    min_head_clearance_m: NonNegative, 0.0, 0.05, "m";
    force_limit_n: Positive, 1.0, 1e6, "N";
    max_speed_mps: Positive, 0.1, 10.0, "m/s";
});

impl Default for Limits {
    fn default() -> Self {
        use fpc::reference::limits;
        Limits {
            target_head_clearance_m: limits::TARGET_HEAD_CLEARANCE_M,
            min_head_clearance_m: limits::MIN_HEAD_CLEARANCE_M,
            force_limit_n: limits::FORCE_LIMIT_N,
            max_speed_mps: limits::MAX_SPEED_MPS,
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

checks!(Simulation {
    substeps_per_period: Count, 1.0, 64.0, "";
});

impl Default for Simulation {
    fn default() -> Self {
        Simulation {
            substeps_per_period: fpc::reference::simulation::SUBSTEPS_PER_PERIOD,
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

checks!(CoggingEffect {
    amplitude_n: Finite, -1e4, 1e4, "N";
    period_m: Positive, 1e-4, 1.0, "m";
    phase_rad: Finite, -1e3, 1e3, "rad";
});

/// `[effects.slave_lag]` (and `[effects.actuator_lag]`): a transport delay.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DelayEffect {
    /// Delay, s.
    pub delay_s: f64,
}

checks!(DelayEffect {
    delay_s: NonNegative, 0.0, 5e-3, "s";
});

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

checks!(StribeckEffect {
    static_n: NonNegative, 0.0, 1e5, "N";
    velocity_mps: Positive, 1e-5, 10.0, "m/s";
    exponent: Positive, 0.1, 10.0, "";
});

/// `[effects.encoder_pitch_error]`: the slave encoder reads
/// `x·(1 + scale) + A·sin(2π·x/p + φ) + A₂·sin(4π·x/p + φ₂) + S·(frac(x/p + φ/2π) − ½) +
/// ½·D·sgn(v)`: harmonics of the pitch, a saw with a step `S` once per pitch (the pattern
/// of the paper's Fig. 6) and a reading that differs by `D` with the direction of motion
/// (larger moving toward +x, "from left to right").
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
    /// Step S once per period (a saw of that height), m.
    #[serde(default)]
    pub step_m: f64,
    /// Difference D between the readings moving toward +x and toward −x, m.
    #[serde(default)]
    pub direction_m: f64,
}

checks!(PitchErrorEffect {
    amplitude_m: Finite, -1e-3, 1e-3, "m";
    period_m: Positive, 1e-4, 1.0, "m";
    phase_rad: Finite, -1e3, 1e3, "rad";
    scale: Finite, -0.1, 0.1, "";
    amplitude2_m: Finite, -1e-3, 1e-3, "m";
    phase2_rad: Finite, -1e3, 1e3, "rad";
    step_m: Finite, -1e-3, 1e-3, "m";
    direction_m: Finite, -1e-3, 1e-3, "m";
});

/// `[effects.heat_transfer]`: `Q̇ = UA·(T_wall − T)` in each chamber.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HeatTransferEffect {
    /// UA of each chamber, W/K.
    pub ua_w_per_k: f64,
    /// Wall temperature, K (default: `gas.temperature_k`).
    pub wall_temperature_k: Option<f64>,
}

checks!(HeatTransferEffect {
    ua_w_per_k: NonNegative, 0.0, 1e4, "W/K";
    wall_temperature_k: Positive, 50.0, 1000.0, "K";
});

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

checks!(LeakageEffect {
    gap_m: NonNegative, 0.0, 1e-3, "m";
    seal_length_m: Positive, 1e-4, 1.0, "m";
    rod_gap_m: NonNegative, 0.0, 1e-3, "m";
    rod_seal_length_m: Positive, 1e-4, 1.0, "m";
});

/// `[effects.port_restriction]`: the ports pass less than their geometry says.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PortRestrictionEffect {
    /// Factor on every port's effective area C_d·A (1 = as designed).
    pub area_scale: f64,
}

checks!(PortRestrictionEffect {
    area_scale: InUnit(10.0), 0.0, 10.0, "";
});

/// `[effects.section_misalignment]`: the slave section's magnets sit `offset_m` along x from
/// where its encoder says (paper Eq. 4), so its commutation is off by 2π·offset/λ.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MisalignmentEffect {
    /// Offset D_dif, m.
    pub offset_m: f64,
}

checks!(MisalignmentEffect {
    offset_m: Finite, -0.01, 0.01, "m";
});

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
    /// A force no named effect describes, as terms of the discovery basis.
    pub extra_force: Option<super::extra_force::ExtraForceEffect>,
}

/// `[published]`: the published rig's drives, for `fpc-sim run --controller published`
/// (the `published` module of this crate). Every key is optional; the defaults are the paper's figures (P)
/// and a drive commissioned as such drives are (A).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Published {
    /// Cycle of the drives' position and velocity loop, s (a whole number of 50 µs periods).
    pub cycle_s: f64,
    /// Delay of the slave drive's force setpoint behind the master's, s (P: 0.75 ms).
    pub slave_lag_s: f64,
    /// Position gain K_v, 1/s.
    pub position_gain_per_s: f64,
    /// Proportional gain of the velocity PI, N·s/m.
    pub velocity_gain_ns_per_m: f64,
    /// Integral time of the velocity PI, s (0 = none).
    pub velocity_integral_time_s: f64,
    /// Velocity feed-forward, fraction of the reference velocity.
    pub velocity_feedforward: f64,
    /// First-order smoothing of the velocity the loop closes on, s.
    pub velocity_filter_s: f64,
    /// Extra delay of the velocity the loop closes on, s (8.5e-3: the loop on the reading).
    pub loop_velocity_delay_s: f64,
    /// Delay of the drive's velocity reading (logged as `v_drive_mps`), s (P: 8.5 ms).
    pub reported_velocity_delay_s: f64,
    /// Bandwidth of each drive's current loop, Hz.
    pub current_bandwidth_hz: f64,
    /// Time the drives hold the piston at rest before moving to dead point A, s.
    pub rest_s: f64,
    /// Current limit of each drive, A (0 = the motor's `current_limit_a`).
    pub current_limit_a: f64,
    /// Share of each stroke spent accelerating, and again braking, at a constant rate
    /// (0.5: the paper's accelerate-then-stop triangle; less: a cruise at the peak speed
    /// between two steeper ramps).
    pub profile_ramp_fraction: f64,
}

checks!(Published {
    cycle_s: NonNegative, 5e-5, 0.01, "s";
    slave_lag_s: NonNegative, 0.0, 0.05, "s";
    position_gain_per_s: NonNegative, 0.0, 1e4, "1/s";
    velocity_gain_ns_per_m: NonNegative, 0.0, 1e7, "N·s/m";
    velocity_integral_time_s: NonNegative, 0.0, 10.0, "s";
    velocity_feedforward: NonNegative, 0.0, 2.0, "";
    velocity_filter_s: NonNegative, 0.0, 0.1, "s";
    loop_velocity_delay_s: NonNegative, 0.0, 0.1, "s";
    reported_velocity_delay_s: NonNegative, 0.0, 0.1, "s";
    current_bandwidth_hz: NonNegative, 10.0, 5000.0, "Hz";
    rest_s: NonNegative, 0.0, 60.0, "s";
    current_limit_a: NonNegative, 0.0, 1000.0, "A";
    profile_ramp_fraction: Positive, 0.02, 0.5, "";
});

impl Default for Published {
    fn default() -> Self {
        use fpc::reference::published as p;
        Published {
            cycle_s: p::CYCLE_S,
            slave_lag_s: p::SLAVE_LAG_S,
            position_gain_per_s: p::POSITION_GAIN_PER_S,
            velocity_gain_ns_per_m: p::VELOCITY_GAIN_NS_PER_M,
            velocity_integral_time_s: p::VELOCITY_INTEGRAL_TIME_S,
            velocity_feedforward: p::VELOCITY_FEEDFORWARD,
            velocity_filter_s: p::VELOCITY_FILTER_S,
            loop_velocity_delay_s: p::LOOP_VELOCITY_DELAY_S,
            reported_velocity_delay_s: p::REPORTED_VELOCITY_DELAY_S,
            current_bandwidth_hz: p::CURRENT_BANDWIDTH_HZ,
            rest_s: p::REST_S,
            current_limit_a: p::CURRENT_LIMIT_A,
            profile_ramp_fraction: p::PROFILE_RAMP_FRACTION,
        }
    }
}

/// Defaults of the optional keys in the required sections: the reference machine's
/// (`reference.toml`, generated into `fpc::reference`).
mod d {
    use fpc::reference::{effects, gas, motor, piston};
    pub fn stop_stiffness() -> f64 {
        piston::STOP_STIFFNESS_N_PER_M
    }
    pub fn stop_damping() -> f64 {
        piston::STOP_DAMPING_NS_PER_M
    }
    pub fn viscosity() -> f64 {
        gas::VISCOSITY_PA_S
    }
    pub fn force_constant() -> f64 {
        motor::FORCE_CONSTANT_N_PER_A
    }
    pub fn resistance() -> f64 {
        motor::RESISTANCE_OHM
    }
    pub fn inductance() -> f64 {
        motor::INDUCTANCE_H
    }
    pub fn bus_voltage() -> f64 {
        motor::BUS_VOLTAGE_V
    }
    pub fn current_limit() -> f64 {
        motor::CURRENT_LIMIT_A
    }
    pub fn rod_seal_length() -> f64 {
        effects::leakage::ROD_SEAL_LENGTH_M
    }
    pub fn one() -> f64 {
        1.0
    }
}
