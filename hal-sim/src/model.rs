//! The machine-model file (`formats.md` §2): TOML, SI units, the unit in every key.
//!
//! The required sections load into [`MachineModel`]; every key not given takes the reference
//! machine's value, an unknown key is refused by name, and non-physical values (zero or
//! negative where a positive quantity is meant) are refused by name. The reference machine is
//! embedded (`reference.toml`), so `fpc-sim run` needs no file.

use serde::Deserialize;

/// The reference machine's model file, embedded.
pub const REFERENCE_TOML: &str = include_str!("reference.toml");

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
    /// Gas (and wall) temperature, K.
    pub temperature_k: f64,
    /// Ambient pressure, Pa.
    pub ambient_pa: f64,
}

/// `[motor]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Motor {
    /// Magnet step (pole pitch), m; the electrical period is twice this.
    pub pole_pitch_m: f64,
    /// The slave section is commanded with the master's force (the published rig).
    pub slave_follows_master: bool,
}

/// `[encoder]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Encoder {
    /// Signal period λ, m.
    pub period_m: f64,
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

impl MachineModel {
    /// The embedded reference machine.
    pub fn reference() -> Self {
        // The embedded file is checked by a unit test; fall back to nothing else.
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
        let positive = [
            ("piston.mass_kg", self.piston.mass_kg),
            ("piston.bore_m", self.piston.bore_m),
            ("piston.travel_m", self.piston.travel_m),
            ("gas.gamma", self.gas.gamma),
            (
                "gas.gas_constant_j_per_kg_k",
                self.gas.gas_constant_j_per_kg_k,
            ),
            ("gas.temperature_k", self.gas.temperature_k),
            ("gas.ambient_pa", self.gas.ambient_pa),
            ("motor.pole_pitch_m", self.motor.pole_pitch_m),
            ("encoder.period_m", self.encoder.period_m),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(ModelError(format!(
                    "`{key}` must be positive and finite, got {v}"
                )));
            }
        }
        let non_negative = [
            ("piston.rod_m", self.piston.rod_m),
            ("piston.dead_length_a_m", self.piston.dead_length_a_m),
            ("piston.dead_length_b_m", self.piston.dead_length_b_m),
            ("friction.coulomb_n", self.friction.coulomb_n),
            ("friction.viscous_ns_per_m", self.friction.viscous_ns_per_m),
        ];
        for (key, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ModelError(format!(
                    "`{key}` must be zero or positive, got {v}"
                )));
            }
        }
        if self.piston.rod_m >= self.piston.bore_m {
            return Err(ModelError(
                "`piston.rod_m` must be smaller than `piston.bore_m`".into(),
            ));
        }
        if self.gas.gamma <= 1.0 {
            return Err(ModelError(format!(
                "`gas.gamma` must exceed 1, got {}",
                self.gas.gamma
            )));
        }
        for (key, v) in [
            ("friction.static_n", self.friction.static_n),
            (
                "friction.stribeck_velocity_mps",
                self.friction.stribeck_velocity_mps,
            ),
            (
                "friction.stribeck_exponent",
                self.friction.stribeck_exponent,
            ),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0) {
                    return Err(ModelError(format!(
                        "`{key}` must be positive and finite, got {v}"
                    )));
                }
            }
        }
        Ok(())
    }

    /// Effective piston area A_eff = π(D² − d²)/4, m².
    pub fn piston_area_m2(&self) -> f64 {
        std::f64::consts::PI * (self.piston.bore_m.powi(2) - self.piston.rod_m.powi(2)) / 4.0
    }

    /// The friction law of this model.
    pub fn friction(&self) -> fpc::friction::FrictionParams<f64> {
        let mut f = fpc::friction::FrictionParams::<f64>::reference();
        f.coulomb_n = self.friction.coulomb_n;
        f.viscous_ns_per_m = self.friction.viscous_ns_per_m;
        f.static_n = self.friction.static_n.unwrap_or(self.friction.coulomb_n);
        if let Some(v) = self.friction.stribeck_velocity_mps {
            f.stribeck_velocity_mps = v;
        }
        if let Some(z) = self.friction.stribeck_exponent {
            f.stribeck_exponent = z;
        }
        f
    }
}

/// One line naming the key at fault (serde names the unknown or missing field), with the
/// line it was found on.
fn describe(e: &toml::de::Error, text: &str) -> String {
    let msg = e.message().trim().replace('\n', " ");
    match e.span() {
        Some(span) => {
            let line = text
                .get(..span.start)
                .map_or(0, |t| t.lines().count().max(1));
            format!("line {line}: {msg}")
        }
        None => msg,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
[piston]
mass_kg = 12.0
bore_m = 0.090
rod_m = 0.020
travel_m = 0.205
dead_length_a_m = 0.0005
dead_length_b_m = 0.0005

[friction]
coulomb_n = 40.0
viscous_ns_per_m = 25.0

[gas]
gamma = 1.4
gas_constant_j_per_kg_k = 287.0
temperature_k = 293.15
ambient_pa = 101325.0

[motor]
pole_pitch_m = 0.012
slave_follows_master = true

[encoder]
period_m = 0.024
"#;

    #[test]
    fn the_minimal_file_loads_and_matches_the_paper_area() {
        let m = MachineModel::parse(MINIMAL).unwrap();
        assert!((m.piston_area_m2() - 6.05e-3).abs() < 0.05e-3);
        MachineModel::reference();
    }

    #[test]
    fn bad_files_are_refused_naming_the_key() {
        let unknown = MINIMAL.replace("coulomb_n = 40.0", "coulomb_n = 40.0\ncolomb_n = 1.0");
        assert!(MachineModel::parse(&unknown)
            .unwrap_err()
            .0
            .contains("colomb_n"));
        let missing = MINIMAL.replace("mass_kg = 12.0\n", "");
        assert!(MachineModel::parse(&missing)
            .unwrap_err()
            .0
            .contains("mass_kg"));
        let negative = MINIMAL.replace("mass_kg = 12.0", "mass_kg = -1.0");
        assert!(MachineModel::parse(&negative)
            .unwrap_err()
            .0
            .contains("piston.mass_kg"));
        let zero = MINIMAL.replace("period_m = 0.024", "period_m = 0.0");
        assert!(MachineModel::parse(&zero)
            .unwrap_err()
            .0
            .contains("encoder.period_m"));
    }
}
