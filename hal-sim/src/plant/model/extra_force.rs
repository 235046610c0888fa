//! `[effects.extra_force]`: a force on the piston along +x that no named effect describes,
//! written as coefficients of a fixed basis (`docs/formats.md`, "Beyond the library"). The model
//! gap workflow discovers it; the plant and the workflow's force replay both evaluate it
//! through [`ExtraForceEffect::force_n`], so a discovered force is simulated exactly as it
//! was fitted.

use std::collections::BTreeMap;
use std::f64::consts::TAU;

use serde::Deserialize;

use super::validate::Rule::Positive;

/// One term of the basis: what it multiplies, in SI.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Term {
    /// `1`: a constant force, N.
    One,
    /// `x`: linear in position (a spring), N/m.
    X,
    /// `x^2`, N/m².
    X2,
    /// `x^3`: a hardening (or softening) spring's cubic part, N/m³.
    X3,
    /// `v`: linear in velocity, N·s/m.
    V,
    /// `v|v|`: quadratic drag, N·s²/m².
    VAbsV,
    /// `sgn(v)`: a constant force along the motion, N.
    SgnV,
    /// `x*sgn(v)`: a force along the motion growing linearly with position, N/m.
    XSgnV,
    /// `a`: proportional to the acceleration, kg.
    A,
    /// `f_motor`: proportional to the logged motor force of both sections (dimensionless).
    FMotor,
    /// `p_a-p_b`: proportional to the chamber pressure difference, m².
    DeltaP,
    /// `t`: a force drifting in time, N/s.
    T,
    /// `t*sgn(v)`: a force along the motion changing in time (drifting friction), N/s.
    TSgnV,
    /// `sin(2πx/p)`, N (period `period_m`).
    Sin,
    /// `cos(2πx/p)`, N (period `period_m`).
    Cos,
}

impl Term {
    /// Every term, in the order of `docs/formats.md`.
    pub const ALL: [Term; 15] = [
        Term::One,
        Term::X,
        Term::X2,
        Term::X3,
        Term::V,
        Term::VAbsV,
        Term::SgnV,
        Term::XSgnV,
        Term::A,
        Term::FMotor,
        Term::DeltaP,
        Term::T,
        Term::TSgnV,
        Term::Sin,
        Term::Cos,
    ];

    /// The term's name in the model file and the JSON.
    pub fn name(self) -> &'static str {
        match self {
            Term::One => "1",
            Term::X => "x",
            Term::X2 => "x^2",
            Term::X3 => "x^3",
            Term::V => "v",
            Term::VAbsV => "v|v|",
            Term::SgnV => "sgn(v)",
            Term::XSgnV => "x*sgn(v)",
            Term::A => "a",
            Term::FMotor => "f_motor",
            Term::DeltaP => "p_a-p_b",
            Term::T => "t",
            Term::TSgnV => "t*sgn(v)",
            Term::Sin => "sin(2πx/p)",
            Term::Cos => "cos(2πx/p)",
        }
    }

    /// The term named `name` (`None`: not a term of the basis).
    pub fn parse(name: &str) -> Option<Term> {
        Term::ALL.into_iter().find(|t| t.name() == name)
    }

    /// Whether it needs the fitted period `period_m`.
    pub fn periodic(self) -> bool {
        matches!(self, Term::Sin | Term::Cos)
    }

    /// The term's value at one state (`period_m` is used by the periodic terms only).
    pub fn value(self, s: &ExtraState, period_m: f64) -> f64 {
        let sgn = if s.v_mps > 0.0 {
            1.0
        } else if s.v_mps < 0.0 {
            -1.0
        } else {
            0.0
        };
        let angle = || TAU * s.x_m / period_m;
        match self {
            Term::One => 1.0,
            Term::X => s.x_m,
            Term::X2 => s.x_m * s.x_m,
            Term::X3 => s.x_m * s.x_m * s.x_m,
            Term::V => s.v_mps,
            Term::VAbsV => s.v_mps * s.v_mps.abs(),
            Term::SgnV => sgn,
            Term::XSgnV => s.x_m * sgn,
            Term::A => s.a_mps2,
            Term::FMotor => s.f_motor_n,
            Term::DeltaP => s.dp_pa,
            Term::T => s.t_s,
            Term::TSgnV => s.t_s * sgn,
            Term::Sin => angle().sin(),
            Term::Cos => angle().cos(),
        }
    }
}

/// What the basis terms are evaluated at: the piston's state and the forces on it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExtraState {
    /// Position, m.
    pub x_m: f64,
    /// Velocity, m/s.
    pub v_mps: f64,
    /// Acceleration, m/s².
    pub a_mps2: f64,
    /// Motor force of both sections, N.
    pub f_motor_n: f64,
    /// Chamber pressure difference `p_A − p_B`, Pa.
    pub dp_pa: f64,
    /// Time from the start of the run (the log's first row), s.
    pub t_s: f64,
}

/// `[effects.extra_force]`: `F = Σ cᵢ·termᵢ` on the piston, toward +x.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ExtraForceEffect {
    /// Coefficient of each term, by the term's name (`"x" = -1800.0`), SI.
    pub terms: BTreeMap<String, f64>,
    /// Period p of the `sin(2πx/p)` and `cos(2πx/p)` terms, m.
    #[serde(default)]
    pub period_m: Option<f64>,
}

checks!(ExtraForceEffect {
    period_m: Positive, 1e-4, 1.0, "m";
});

/// Largest magnitude of a coefficient accepted (SI of its term).
pub const MAX_COEFFICIENT: f64 = 1e9;

impl ExtraForceEffect {
    /// The terms with their coefficients, or an error naming the first term at fault
    /// (unknown name, a value not finite or out of range, a periodic term without
    /// `period_m`).
    pub fn parsed(&self) -> Result<Vec<(Term, f64)>, String> {
        let mut out = Vec::new();
        for (name, &c) in &self.terms {
            let Some(t) = Term::parse(name) else {
                let known: Vec<String> = Term::ALL
                    .iter()
                    .map(|t| format!("\"{}\"", t.name()))
                    .collect();
                return Err(format!(
                    "`effects.extra_force.terms` has an unknown term \"{}\" (the basis is {})",
                    name.chars().take(40).collect::<String>(),
                    known.join(", ")
                ));
            };
            if !(c.is_finite() && c.abs() <= MAX_COEFFICIENT) {
                return Err(format!(
                    "`effects.extra_force.terms.\"{name}\"` must be finite and within ±{MAX_COEFFICIENT:e}, got {}",
                    crate::failure::num(c)
                ));
            }
            if t.periodic() && self.period_m.is_none() {
                return Err(format!(
                    "`effects.extra_force.terms.\"{name}\"` needs `effects.extra_force.period_m`"
                ));
            }
            out.push((t, c));
        }
        Ok(out)
    }

    /// The coefficient of `term`, if present.
    pub fn coefficient(&self, term: Term) -> Option<f64> {
        self.terms.get(term.name()).copied()
    }

    /// The `a` term's coefficient, kg (it changes the moving mass: `(m − c_a)·a`), if
    /// present.
    pub fn mass_term_kg(&self) -> Option<f64> {
        self.coefficient(Term::A)
    }
}

/// An extra force with its terms read by name once: what the plant evaluates at every step
/// and `gap` at every row.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtraForce {
    /// The terms whose names parse, with their coefficients (SI), in the order of the names.
    terms: Vec<(Term, f64)>,
    /// Period of the periodic terms, m.
    period_m: f64,
}

impl ExtraForce {
    /// `Σ c·term(s)`, N, term by term in the order of the terms' names.
    pub fn force_n(&self, s: &ExtraState) -> f64 {
        self.terms
            .iter()
            .map(|(t, c)| c * t.value(s, self.period_m))
            .sum()
    }

    /// Whether a term reads the motor forces (`f_motor`): without one the force does not
    /// depend on the force readings, their alignment or the actuator lag.
    pub fn reads_motor(&self) -> bool {
        self.terms.iter().any(|(t, _)| *t == Term::FMotor)
    }

    /// [`Self::force_n`] at each of `states`, N.
    pub fn forces_n(&self, states: impl Iterator<Item = ExtraState>) -> Vec<f64> {
        states.map(|s| self.force_n(&s)).collect()
    }

    /// The coefficient of `term`, if present.
    pub fn coefficient(&self, term: Term) -> Option<f64> {
        self.terms.iter().find(|(t, _)| *t == term).map(|(_, c)| *c)
    }
}

/// Terms whose names do not parse count as nothing: the model was validated with
/// [`ExtraForceEffect::parsed`].
impl From<&ExtraForceEffect> for ExtraForce {
    fn from(e: &ExtraForceEffect) -> Self {
        ExtraForce {
            terms: e
                .terms
                .iter()
                .filter_map(|(name, c)| Some((Term::parse(name)?, *c)))
                .collect(),
            period_m: e.period_m.unwrap_or(1.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_term_round_trips_by_name_and_an_unknown_one_is_named() {
        for t in Term::ALL {
            assert_eq!(Term::parse(t.name()), Some(t));
        }
        let e = ExtraForceEffect {
            terms: [("x".to_string(), -1800.0), ("spring".to_string(), 1.0)]
                .into_iter()
                .collect(),
            period_m: None,
        };
        let err = e.parsed().unwrap_err();
        assert!(err.contains("\"spring\""), "{err}");
        let no_p = ExtraForceEffect {
            terms: [("sin(2πx/p)".to_string(), 3.0)].into_iter().collect(),
            period_m: None,
        };
        assert!(no_p.parsed().unwrap_err().contains("period_m"));
    }

    #[test]
    fn the_forces_at_many_states_are_the_force_at_each() {
        let e = ExtraForceEffect {
            terms: Term::ALL
                .iter()
                .enumerate()
                .map(|(i, t)| (t.name().to_string(), 1.5 - 0.37 * i as f64))
                .chain([("unknown".to_string(), 9.0)])
                .collect(),
            period_m: Some(0.031),
        };
        let states: Vec<ExtraState> = (0..200)
            .map(|i| {
                let k = f64::from(i);
                ExtraState {
                    x_m: 0.01 + 1e-3 * k,
                    v_mps: (0.1 * k).sin(),
                    a_mps2: 30.0 * (0.05 * k).cos(),
                    f_motor_n: 5.0 * k - 300.0,
                    dp_pa: 1e3 * (0.2 * k).sin(),
                    t_s: 1e-4 * k,
                }
            })
            .collect();
        let f = ExtraForce::from(&e);
        let many = f.forces_n(states.iter().copied());
        let each: Vec<f64> = states.iter().map(|s| f.force_n(s)).collect();
        assert_eq!(
            many.iter().map(|f| f.to_bits()).collect::<Vec<_>>(),
            each.iter().map(|f| f.to_bits()).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_spring_about_x0_is_its_two_terms() {
        let e = ExtraForceEffect {
            terms: [("x".to_string(), -1800.0), ("1".to_string(), 162.0)]
                .into_iter()
                .collect(),
            period_m: None,
        };
        let s = ExtraState {
            x_m: 0.1,
            ..ExtraState::default()
        };
        // −k·(x − x0) with k = 1800 N/m, x0 = 0.09 m.
        assert!((ExtraForce::from(&e).force_n(&s) - (-1800.0 * (0.1 - 0.09))).abs() < 1e-9);
    }
}
