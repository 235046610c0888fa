//! The machine-model file (`docs/formats.md` §2): TOML, SI units, the unit in every key.
//!
//! The five required sections (`[piston] [friction] [gas] [motor] [encoder]`) load into
//! [`MachineModel`]. The project's own sections (`[ports] [lines] [servo] [sensors] [limits]
//! [simulation]`) and every optional key default to the reference machine (`docs/machine.md`),
//! key by key. Effects (`[effects.*]`) are what the model-gap workflow adds: an effect whose
//! section is absent is absent from the physics. The reference machine itself is embedded
//! (`reference.toml`, every key commented with its origin), so `fpc-sim run` needs no file.
//!
//! Refused, with one line naming the key: an unknown key or section, a missing required key,
//! a non-physical value (zero or negative where a positive quantity is meant, a port window
//! outside one turn, …).

use fpc::control::config::Machine;
use fpc::physics::balance::PistonLaws;
use fpc::physics::cogging::CoggingParams;
use fpc::physics::friction::FrictionParams;
use fpc::physics::gas::{AnnulusLeak, Cylinder, GasProperties};
use fpc::physics::motor::MotorParams;
use fpc::physics::port_timing::{PortGeometry, PortWindow};
use serde::Deserialize;

use crate::failure::{clip_quoted, num};

/// The reference machine's model file, embedded.
pub const REFERENCE_TOML: &str = include_str!("reference.toml");

/// Delay of the published rig's slave drive behind its master, s (**P**: 0.75 ms, paper
/// Fig. 4): what `[effects.slave_lag] delay_s` is set to to simulate that rig. It is not a
/// default: `slave_follows_master = true` alone means the slave is commanded with the
/// master's force (`docs/formats.md` §2), on time.
pub const PAPER_SLAVE_LAG_S: f64 = 0.75e-3;

#[macro_use]
pub mod validate;
pub mod extra_force;
mod sections;

pub use sections::*;

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
    /// The drive board's supply: DC link, brake chopper, logic supply.
    #[serde(default)]
    pub supply: Supply,
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
    /// The published rig's drives (`fpc-sim run --controller published`).
    #[serde(default)]
    pub published: Published,
}

/// A key of the model file, `section.name` (the section a dotted path such as
/// `effects.cogging`): made by [`model_key!`](validate::model_key) from the model's own fields, so that a
/// renamed field fails to compile where its key is used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Key {
    /// The section's dotted path.
    pub section: &'static str,
    /// The key in it.
    pub name: &'static str,
}

/// A section of the model file, its dotted path: made by [`model_section!`](validate::model_section) from the
/// model's own fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SectionKey(pub &'static str);

pub(crate) use validate::{model_key, model_section};

/// The largest model file read, bytes (the reference file is about 6 KB).
pub const MAX_MODEL_BYTES: u64 = 1 << 20;

/// Why a model file was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModelError(pub String);

impl std::fmt::Display for ModelError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ModelError {}

impl MachineModel {
    /// The embedded reference machine.
    pub fn reference() -> Self {
        // The embedded file is checked by a unit test; it cannot fail at run time.
        Self::parse(REFERENCE_TOML).unwrap_or_else(|e| panic!("embedded reference.toml: {e}"))
    }

    /// Parses and validates model text.
    pub fn parse(text: &str) -> Result<Self, ModelError> {
        let model: MachineModel =
            toml::from_str(text).map_err(|e| ModelError(describe_toml(&e, text)))?;
        model.validate()?;
        Ok(model)
    }

    /// Reads and validates a model file. At most [`MAX_MODEL_BYTES`] are read: a larger or
    /// endless input (`/dev/zero`) is refused, not read into memory.
    pub fn read(path: &std::path::Path) -> Result<Self, ModelError> {
        use std::io::Read;
        let fail = |what: String| ModelError(format!("cannot read {}: {what}", path.display()));
        let file = std::fs::File::open(path).map_err(|e| fail(e.to_string()))?;
        let mut bytes = Vec::new();
        file.take(MAX_MODEL_BYTES + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| fail(e.to_string()))?;
        if bytes.len() as u64 > MAX_MODEL_BYTES {
            return Err(fail(format!(
                "larger than {MAX_MODEL_BYTES} bytes, which no model file is"
            )));
        }
        let text = String::from_utf8(bytes).map_err(|e| {
            fail(format!(
                "not UTF-8 text (byte {})",
                e.utf8_error().valid_up_to()
            ))
        })?;
        Self::parse(&text).map_err(|e| ModelError(format!("{}: {}", path.display(), e.0)))
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

    /// The machine as the controller is told it ([`fpc::control::config::Machine`]): the
    /// values of this model the firmware's configuration follows
    /// (`fpc::control::config::ControlConfig::for_machine`), rounded to `f32`; the friction's
    /// sign regularisation stays the firmware's own.
    pub fn machine(&self) -> Machine {
        let p = &self.piston;
        let f = self.friction();
        let m = self.motor_sections().master;
        let clearance = self.limits.target_head_clearance_m;
        Machine {
            moving_mass_kg: p.mass_kg as f32,
            travel_m: p.travel_m as f32,
            cylinder: Cylinder::from_bore(
                p.bore_m as f32,
                p.rod_m as f32,
                p.travel_m as f32,
                p.dead_length_a_m as f32,
                p.dead_length_b_m as f32,
            ),
            friction: FrictionParams {
                coulomb_n: f.coulomb_n as f32,
                static_n: f.static_n as f32,
                viscous_ns_per_m: f.viscous_ns_per_m as f32,
                stribeck_velocity_mps: f.stribeck_velocity_mps as f32,
                stribeck_exponent: f.stribeck_exponent as f32,
                ..FrictionParams::<f32>::reference()
            },
            encoder_period_m: self.encoder.period_m as f32,
            motor: MotorParams {
                force_constant_n_per_a: m.force_constant_n_per_a as f32,
                resistance_ohm: m.resistance_ohm as f32,
                inductance_h: m.inductance_h as f32,
                electrical_period_m: (2.0 * self.motor.pole_pitch_m) as f32,
                bus_voltage_v: m.bus_voltage_v as f32,
                current_limit_a: m.current_limit_a as f32,
            },
            servo_inertia_kgm2: self.servo.inertia_kgm2 as f32,
            servo_torque_full_scale_nm: self.servo.torque_full_scale_nm as f32,
            servo_counts_per_rev: self.servo.counts_per_rev,
            target_clearance_m: clearance as f32,
            // The dead points at the target clearance from each head of this model's travel.
            dead_points_m: (clearance as f32, (p.travel_m - clearance) as f32),
            force_limit_n: self.limits.force_limit_n as f32,
            max_speed_mps: self.limits.max_speed_mps as f32,
        }
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

    /// Radius at which the sliding friction acts on the rotation, m (the bore's).
    pub fn friction_radius_m(&self) -> f64 {
        0.5 * self.piston.bore_m
    }

    /// The laws of the force balance on the piston ([`fpc::physics::balance`]).
    pub fn piston_laws(&self) -> PistonLaws<f64> {
        PistonLaws {
            mass_kg: self.piston.mass_kg,
            cylinder: self.cylinder(),
            friction: self.friction(),
            cogging: self.cogging(),
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

/// The sections a model file must have.
const REQUIRED_SECTIONS: [&str; 5] = ["piston", "friction", "gas", "motor", "encoder"];

/// One line naming the key (or section) at fault and the line it was found on, every echoed
/// value cut to [`crate::failure::ECHO_CHARS`] characters; no type's debug dump.
pub(crate) fn describe_toml(e: &toml::de::Error, text: &str) -> String {
    // serde's words for types, in the file's words.
    let msg = e
        .message()
        .trim()
        .replace('\n', " ")
        .replace("expected f64", "expected a number")
        .replace("expected u32", "expected a whole number")
        .replace("type: sequence", "type: array")
        .replace("type: map", "type: table");
    // A missing required section is reported by serde as a missing field of the file.
    if let Some(section) = REQUIRED_SECTIONS
        .iter()
        .find(|s| msg.starts_with(&format!("missing field `{s}`")))
    {
        return format!(
            "missing section [{section}] (required: [piston] [friction] [gas] [motor] [encoder])"
        );
    }
    let Some(span) = e.span() else {
        return clip_quoted(&msg);
    };
    let before = text.get(..span.start).unwrap_or("");
    let line = before.matches('\n').count() + 1;
    // toml names neither a duplicate key nor the key of a bad value: the text does.
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let code = |l: &str| l.split('#').next().unwrap_or("").trim().to_string();
    let here = code(
        text.get(line_start..)
            .and_then(|t| t.lines().next())
            .unwrap_or(""),
    );
    let here = here.as_str();
    // The table the error is in (a missing key is reported on its table): the last header
    // line (`[name]`, no `=`) up to and including this one.
    let table = text
        .get(..line_start)
        .unwrap_or("")
        .lines()
        .map(code)
        .chain(std::iter::once(here.to_string()))
        .rev()
        .find(|l| l.starts_with('[') && !l.contains('='));
    let key = (!here.starts_with('['))
        .then(|| here.split_once('=').map(|(k, _)| k.trim()))
        .flatten()
        .filter(|k| !k.is_empty());
    let section = table
        .as_deref()
        .map(|t| t.trim_matches(|c| c == '[' || c == ']').trim());
    let full_key = |k: &str| match section {
        Some(s) => format!("{s}.{k}"),
        None => k.to_string(),
    };
    let text = if msg.contains("duplicate key") || msg.contains("duplicate table") {
        if here.starts_with('[') {
            format!("section `{here}` is given twice")
        } else {
            let k = key.unwrap_or(here);
            format!("key `{}` is given twice", full_key(k))
        }
    } else if let Some(field) = msg.strip_prefix("missing field ") {
        let field = field.trim_matches('`');
        match &table {
            Some(t) => format!("missing key `{}` in {t}", full_key(field)),
            None => format!("missing key `{field}`"),
        }
    } else if let Some(k) = key.filter(|_| !msg.starts_with("unknown field")) {
        let k = full_key(k);
        match validate::range_of(&k) {
            Some((lo, hi, unit)) => format!(
                "`{k}`: {msg} (range {} ..= {}{}{unit})",
                num(lo),
                num(hi),
                if unit.is_empty() { "" } else { " " }
            ),
            None => format!("`{k}`: {msg}"),
        }
    } else {
        msg
    };
    format!("line {line}: {}", clip_quoted(&text))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The minimal file of `docs/formats.md` §2.
    pub const MINIMAL: &str = include_str!("../../../tests/data/minimal_model.toml");

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
        let term = format!(
            "{MINIMAL}\n[effects.extra_force]\nterms = {{ \"x\" = -1800.0, \"xx\" = 1.0 }}\n"
        );
        assert!(refused(&term).contains("\"xx\""));
        let mass = format!("{MINIMAL}\n[effects.extra_force]\nterms = {{ \"a\" = 6.0 }}\n");
        assert!(refused(&mass).contains("extra_force.terms.\"a\""));
        let spring = format!(
            "{MINIMAL}\n[effects.extra_force]\nterms = {{ \"x\" = -1800.0, \"1\" = 162.0 }}\n"
        );
        let m = MachineModel::parse(&spring).unwrap();
        let e = m
            .effects
            .extra_force
            .expect("the inline table of docs/formats.md loads");
        assert_eq!(e.terms.get("x"), Some(&-1800.0));
    }

    #[test]
    fn a_force_reading_out_of_its_range_is_refused_naming_its_key() {
        let read = |body: &str| format!("{MINIMAL}\n[sensors.force]\n{body}\n");
        let m = MachineModel::parse(&read("offset_slave_n = -30.0\ngain_master = 1.05")).unwrap();
        let f = m.sensors.force;
        assert_eq!((f.offset_master_n, f.offset_slave_n), (0.0, -30.0));
        assert_eq!((f.gain_master, f.gain_slave), (1.05, 1.0));
        assert!(
            refused(&read("offset_master_n = 1500.0")).contains("sensors.force.offset_master_n")
        );
        assert!(refused(&read("gain_slave = 0.0")).contains("sensors.force.gain_slave"));
        assert!(refused(&read("gain_slave = 2.5")).contains("sensors.force.gain_slave"));
        assert!(refused(&read("offset_n = 1.0")).contains("offset_n"));
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
