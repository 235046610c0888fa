//! Validation of a parsed model: every key checked for its physical kind (positive,
//! non-negative, finite, a fraction) and against its physical range — each section states
//! its keys' rules and ranges next to its struct ([`Checked`], the `checks!` tables of
//! `sections.rs`: what a free-piston compressor of a few grams to a tonne could have) — then
//! the model as a whole for consistency (the stroke fits between the clearances, the dead
//! lengths, cogging below the force limit, …), with an error naming the key and the range.

use std::sync::LazyLock;

use super::{MachineModel, ModelError};
use crate::failure::num;

/// What a value must be.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rule {
    /// Above zero.
    Positive,
    /// Zero or above.
    NonNegative,
    /// Any finite number.
    Finite,
    /// A fraction-like factor in (0, max].
    InUnit(f64),
    /// A whole number (the file's integer keys): its range alone.
    Count,
    /// The edges of a port window, degrees in [0, 360].
    Degrees,
}

/// A key of a section: its rule and its physical range, inclusive, with its unit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldSpec {
    /// The key in its section.
    pub name: &'static str,
    /// What its value must be.
    pub rule: Rule,
    /// Smallest physical value.
    pub lo: f64,
    /// Largest physical value.
    pub hi: f64,
    /// Unit ("" for none).
    pub unit: &'static str,
}

/// A key's value as the checks see it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value<'a> {
    /// A number.
    One(f64),
    /// An optional number (absent: nothing to check).
    Maybe(Option<f64>),
    /// An array of numbers, each checked.
    Many(&'a [f64]),
    /// A whole number.
    Count(u32),
}

/// A field type the checks read.
pub trait IntoValue {
    /// The value as the checks see it.
    fn value(&self) -> Value<'_>;
}

impl IntoValue for f64 {
    fn value(&self) -> Value<'_> {
        Value::One(*self)
    }
}

impl IntoValue for Option<f64> {
    fn value(&self) -> Value<'_> {
        Value::Maybe(*self)
    }
}

impl<const N: usize> IntoValue for [f64; N] {
    fn value(&self) -> Value<'_> {
        Value::Many(self)
    }
}

impl IntoValue for u32 {
    fn value(&self) -> Value<'_> {
        Value::Count(*self)
    }
}

/// A section of the model file that checks its own keys.
pub trait Checked {
    /// Its numeric keys' rules and ranges.
    const FIELDS: &'static [FieldSpec];
    /// Its values, in the order of [`Checked::FIELDS`].
    fn values(&self) -> Vec<Value<'_>>;
    /// Checks every key; the first out of its rule or range is named as `path.key`.
    fn check(&self, path: &str) -> Result<(), ModelError> {
        for (f, v) in Self::FIELDS.iter().zip(self.values()) {
            let key = || format!("{path}.{}", f.name);
            match v {
                Value::One(x) | Value::Maybe(Some(x)) => check(&key(), x, f)?,
                Value::Maybe(None) => {}
                Value::Many(xs) => {
                    for &x in xs {
                        check(&key(), x, f)?;
                    }
                }
                Value::Count(n) => in_range(&key(), f64::from(n), f)?,
            }
        }
        Ok(())
    }
}

/// Where a section sits in the model: present (the section itself) or optional (an
/// `Option` of it). What the registry of sections ([`MachineModel::sections`]) and the
/// typed keys (`model_key!`) read through.
pub trait SectionSlot {
    /// The section.
    type Section: Checked;
    /// The section, if present.
    fn section(&self) -> Option<&Self::Section>;
}

impl<T: Checked> SectionSlot for Option<T> {
    type Section = T;
    fn section(&self) -> Option<&T> {
        self.as_ref()
    }
}

/// The typed key of the model's field at `section.path / field`: `model_key!(effects.cogging
/// / amplitude_n)` is `effects.cogging.amplitude_n`, checked at compile time against
/// [`MachineModel`]'s fields (through an optional section too).
macro_rules! model_key {
    ($($part:ident).+ / $field:ident) => {{
        #[allow(dead_code)]
        fn exists(m: &$crate::plant::model::MachineModel) {
            use $crate::plant::model::validate::SectionSlot;
            let _ = m.$($part).+.section().map(|s| &s.$field);
        }
        $crate::plant::model::Key {
            section: stringify!($($part).+),
            name: stringify!($field),
        }
    }};
}
pub(crate) use model_key;

/// The typed path of the model's section at `section.path`, checked at compile time.
macro_rules! model_section {
    ($($part:ident).+) => {{
        #[allow(dead_code)]
        fn exists(m: &$crate::plant::model::MachineModel) {
            use $crate::plant::model::validate::SectionSlot;
            let _ = m.$($part).+.section();
        }
        $crate::plant::model::SectionKey(stringify!($($part).+))
    }};
}
pub(crate) use model_section;

/// A section's rules and ranges next to its struct: `checks!(Type { key: rule, lo, hi,
/// "unit"; … })`. The keys are the struct's fields (a renamed field fails to compile).
macro_rules! checks {
    ($ty:ty { $($field:ident : $rule:expr, $lo:expr, $hi:expr, $unit:expr;)* }) => {
        impl $crate::plant::model::validate::Checked for $ty {
            const FIELDS: &'static [$crate::plant::model::validate::FieldSpec] = &[$(
                $crate::plant::model::validate::FieldSpec {
                    name: stringify!($field),
                    rule: $rule,
                    lo: $lo,
                    hi: $hi,
                    unit: $unit,
                }
            ),*];
            fn values(&self) -> Vec<$crate::plant::model::validate::Value<'_>> {
                use $crate::plant::model::validate::IntoValue;
                vec![$(self.$field.value()),*]
            }
        }
        impl $crate::plant::model::validate::SectionSlot for $ty {
            type Section = $ty;
            fn section(&self) -> Option<&$ty> {
                Some(self)
            }
        }
    };
}

/// One section of the model file: its path, its keys and, in this model, its values
/// (`None`: an absent optional section).
pub struct SectionEntry<'a> {
    /// Dotted path of the section (`effects.cogging`).
    pub path: &'static str,
    /// Its keys' rules and ranges.
    pub fields: &'static [FieldSpec],
    /// Its values, if present.
    pub values: Option<Vec<Value<'a>>>,
    check: Option<&'a dyn CheckAt>,
}

/// A present section, checked at its path.
trait CheckAt {
    fn check_at(&self, path: &str) -> Result<(), ModelError>;
}

impl<T: Checked> CheckAt for T {
    fn check_at(&self, path: &str) -> Result<(), ModelError> {
        self.check(path)
    }
}

/// The entry of the section at `path` held in `slot`.
pub fn section_entry<'a, S: SectionSlot>(path: &'static str, slot: &'a S) -> SectionEntry<'a> {
    let present = slot.section();
    SectionEntry {
        path,
        fields: S::Section::FIELDS,
        values: present.map(Checked::values),
        check: present.map(|s| s as &dyn CheckAt),
    }
}

/// The entry of a section of the model, its path written as the fields that lead to it.
macro_rules! section {
    ($model:ident, $($part:ident).+) => {
        $crate::plant::model::validate::section_entry(stringify!($($part).+), &$model.$($part).+)
    };
}

impl MachineModel {
    /// Every section of the model file in file order, with its path: what validation walks
    /// and [`range_of`] reads. The only place a section's path is written.
    pub fn sections(&self) -> Vec<SectionEntry<'_>> {
        let m = self;
        vec![
            section!(m, piston),
            section!(m, friction),
            section!(m, gas),
            section!(m, motor),
            section!(m, motor.master),
            section!(m, motor.slave),
            section!(m, encoder),
            section!(m, ports),
            section!(m, lines),
            section!(m, servo),
            section!(m, supply),
            section!(m, sensors.encoder_master),
            section!(m, sensors.encoder_slave),
            section!(m, sensors.current),
            section!(m, sensors.pressure),
            section!(m, sensors.force),
            section!(m, limits),
            section!(m, simulation),
            section!(m, effects.cogging),
            section!(m, effects.slave_lag),
            section!(m, effects.actuator_lag),
            section!(m, effects.stribeck_friction),
            section!(m, effects.encoder_pitch_error),
            section!(m, effects.heat_transfer),
            section!(m, effects.leakage),
            section!(m, effects.port_restriction),
            section!(m, effects.section_misalignment),
            section!(m, effects.extra_force),
            section!(m, published),
        ]
    }
}

/// The physical range of every numeric key, inclusive, with its unit: `(key, min, max,
/// unit)`, from the sections' own tables.
pub static RANGES: LazyLock<Vec<(String, f64, f64, &'static str)>> = LazyLock::new(|| {
    MachineModel::reference()
        .sections()
        .iter()
        .flat_map(|s| {
            s.fields
                .iter()
                .map(|f| (format!("{}.{}", s.path, f.name), f.lo, f.hi, f.unit))
        })
        .collect()
});

/// What the 12-bit ADC can carry either side of its mid-scale, codes: an encoder signal's
/// amplitude plus its offset must fit.
pub const ADC_HALF_RANGE_CODES: f64 = 2047.0;

/// Full scale of the pressure sensors, Pa (0–10 bar absolute, `docs/machine.md`): the discharge
/// line (suction × pressure ratio) must be readable.
pub const PRESSURE_FULL_SCALE_PA: f64 = 1.0e6;

/// The range of `key` (`None` for keys without one).
pub fn range_of(key: &str) -> Option<(f64, f64, &'static str)> {
    RANGES
        .iter()
        .find(|(k, ..)| k == key)
        .map(|&(_, lo, hi, unit)| (lo, hi, unit))
}

/// `key` = `v` within the range of `f`.
fn in_range(key: &str, v: f64, f: &FieldSpec) -> Result<(), ModelError> {
    if (f.lo..=f.hi).contains(&v) {
        return Ok(());
    }
    Err(ModelError(format!(
        "`{key}` = {} is outside its physical range {} ..= {}{}{}",
        num(v),
        num(f.lo),
        num(f.hi),
        if f.unit.is_empty() { "" } else { " " },
        f.unit
    )))
}

/// `key` = `v` by the rule and within the range of `f`.
fn check(key: &str, v: f64, f: &FieldSpec) -> Result<(), ModelError> {
    let ok = v.is_finite()
        && match f.rule {
            Rule::Positive => v > 0.0,
            Rule::NonNegative | Rule::Count => v >= 0.0,
            Rule::Finite => true,
            Rule::InUnit(max) => v > 0.0 && v <= max,
            Rule::Degrees => (0.0..=360.0).contains(&v),
        };
    if ok {
        return in_range(key, v, f);
    }
    let what = match f.rule {
        Rule::Positive => "positive and finite".to_string(),
        Rule::NonNegative | Rule::Count => "zero or positive".to_string(),
        Rule::Finite => "finite".to_string(),
        Rule::InUnit(max) => format!("in (0, {max}]"),
        Rule::Degrees => {
            return Err(ModelError(format!(
                "`{key}` edges must lie in [0, 360] degrees, got {}",
                num(v)
            )))
        }
    };
    Err(ModelError(format!(
        "`{key}` must be {what}, got {}",
        num(v)
    )))
}

impl MachineModel {
    /// Checks every value of the model, section by section (each by its own rules and
    /// ranges), then the rules across sections; the first value at fault is named.
    pub(super) fn validate(&self) -> Result<(), ModelError> {
        for s in self.sections() {
            if let Some(c) = s.check {
                c.check_at(s.path)?;
            }
        }
        if let Some(e) = &self.effects.extra_force {
            e.parsed().map_err(ModelError)?;
            // The `a` term changes the moving mass (`(m − c_a)·a`): it must leave a mass.
            let c_a = e.mass_term_kg().unwrap_or(0.0);
            if c_a >= 0.5 * self.piston.mass_kg {
                return Err(ModelError(format!(
                    "`effects.extra_force.terms.\"a\"` = {} kg leaves less than half of \
                     `piston.mass_kg` = {} kg moving (below {} kg)",
                    num(c_a),
                    num(self.piston.mass_kg),
                    num(0.5 * self.piston.mass_kg)
                )));
            }
        }
        let pu = &self.published;
        let periods = pu.cycle_s / f64::from(fpc::units::CONTROL_PERIOD_S);
        if (periods - periods.round()).abs() > 1e-6 {
            return Err(ModelError(format!(
                "`published.cycle_s` = {} s must be a whole number of the simulator's 50 µs \
                 periods (e.g. 1e-4, 1.5e-4, 2.5e-4)",
                num(pu.cycle_s)
            )));
        }
        let g = &self.gas;
        if g.gamma <= 1.0 {
            return Err(ModelError(format!(
                "`gas.gamma` must exceed 1 (range above 1 ..= 1.7), got {}",
                num(g.gamma)
            )));
        }
        let l = &self.limits;
        if l.min_head_clearance_m > l.target_head_clearance_m {
            return Err(ModelError(
                "`limits.min_head_clearance_m` must not exceed `limits.target_head_clearance_m`"
                    .into(),
            ));
        }
        self.check_consistency()
    }

    /// The model as a whole: values that are each in range but make no machine together.
    /// The rules are listed in [`CONSISTENCY_RULES`].
    fn check_consistency(&self) -> Result<(), ModelError> {
        self.check_geometry()?;
        self.check_supply()?;
        let p = &self.piston;
        if self.encoder.period_m > p.travel_m {
            return Err(ModelError(format!(
                "`encoder.period_m` = {} m is longer than `piston.travel_m` = {} m",
                num(self.encoder.period_m),
                num(p.travel_m)
            )));
        }
        self.check_motor_force()?;
        self.check_ports()?;
        self.check_sensor_ranges()
    }

    /// The piston: its rod thinner than its bore, each dead length shorter than the travel,
    /// and a stroke left at least as long as the dead lengths and clearances take.
    fn check_geometry(&self) -> Result<(), ModelError> {
        let p = &self.piston;
        let l = &self.limits;
        let fail = |m: String| Err(ModelError(m));
        if p.rod_m >= p.bore_m {
            return fail(format!(
                "`piston.rod_m` = {} m must be smaller than `piston.bore_m` = {} m",
                num(p.rod_m),
                num(p.bore_m)
            ));
        }
        for (name, dead) in [("a", p.dead_length_a_m), ("b", p.dead_length_b_m)] {
            if dead >= p.travel_m {
                return fail(format!(
                    "`piston.dead_length_{name}_m` = {} m is not shorter than \
                     `piston.travel_m` = {} m: the chamber could not compress",
                    num(dead),
                    num(p.travel_m)
                ));
            }
        }
        let reserved = p.dead_length_a_m + p.dead_length_b_m + 2.0 * l.target_head_clearance_m;
        if p.travel_m <= 2.0 * reserved {
            return fail(format!(
                "`piston.travel_m` = {} m leaves no stroke: the dead lengths and twice \
                 `limits.target_head_clearance_m` take {} m, and the stroke must be at \
                 least as long again (travel above {} m)",
                num(p.travel_m),
                num(reserved),
                num(2.0 * reserved)
            ));
        }
        Ok(())
    }

    /// The DC link's thresholds in order: logic dropout < power good < bus < chopper, V.
    fn check_supply(&self) -> Result<(), ModelError> {
        let fail = |m: String| Err(ModelError(m));
        let su = &self.supply;
        let bus_v = self.motor.bus_voltage_v;
        if !(su.logic_dropout_voltage_v < su.power_good_voltage_v
            && su.power_good_voltage_v < bus_v
            && bus_v < su.chopper_voltage_v)
        {
            return fail(format!(
                "`supply.logic_dropout_voltage_v` = {} V < `supply.power_good_voltage_v` = {} V \
                 < `motor.bus_voltage_v` = {} V < `supply.chopper_voltage_v` = {} V does not \
                 hold: the link's thresholds must be in that order",
                num(su.logic_dropout_voltage_v),
                num(su.power_good_voltage_v),
                num(bus_v),
                num(su.chopper_voltage_v)
            ));
        }
        Ok(())
    }

    /// One section's peak force, N, above what it must overcome: twice the cogging amplitude
    /// (and the force limit too), and every friction force.
    fn check_motor_force(&self) -> Result<(), ModelError> {
        let l = &self.limits;
        let fail = |m: String| Err(ModelError(m));
        // One section's peak force: what the motor can hold against friction and cogging.
        let m = &self.motor;
        let peak_force = m.force_constant_n_per_a * m.current_limit_a;
        let peak = || {
            format!(
                "the motor's peak force (`motor.force_constant_n_per_a` × \
                 `motor.current_limit_a` = {} N)",
                num(peak_force)
            )
        };
        if let Some(c) = &self.effects.cogging {
            let half = 0.5 * l.force_limit_n.min(peak_force);
            if c.amplitude_n.abs() >= half {
                return fail(format!(
                    "`effects.cogging.amplitude_n` = {} N is not below half of \
                     `limits.force_limit_n` = {} N and of {}: the motor could not move \
                     the piston (|amplitude| below {} N)",
                    num(c.amplitude_n),
                    num(l.force_limit_n),
                    peak(),
                    num(half)
                ));
            }
        }
        let frictions = [
            ("friction.coulomb_n", Some(self.friction.coulomb_n)),
            ("friction.static_n", self.friction.static_n),
            (
                "effects.stribeck_friction.static_n",
                self.effects.stribeck_friction.as_ref().map(|s| s.static_n),
            ),
        ];
        for (key, f) in frictions {
            if let Some(f) = f.filter(|f| *f >= peak_force) {
                return fail(format!(
                    "`{key}` = {} N is not below {}: the piston could not move",
                    num(f),
                    peak()
                ));
            }
        }
        Ok(())
    }

    /// The sensors' ranges: each encoder's swing within the 12-bit ADC, the discharge
    /// pressure within the pressure sensors' full scale.
    fn check_sensor_ranges(&self) -> Result<(), ModelError> {
        let fail = |m: String| Err(ModelError(m));
        for (name, e) in [
            ("encoder_master", &self.sensors.encoder_master),
            ("encoder_slave", &self.sensors.encoder_slave),
        ] {
            let swing = e.amplitude_codes * (1.0 + e.gain_mismatch.max(0.0))
                + e.sin_offset_codes.abs().max(e.cos_offset_codes.abs());
            if swing > ADC_HALF_RANGE_CODES {
                return fail(format!(
                    "`sensors.{name}.amplitude_codes` = {} with its gain mismatch and \
                     offsets swings {} codes from mid-scale: the 12-bit ADC carries \
                     {} ..= {}",
                    num(e.amplitude_codes),
                    num(swing),
                    num(-ADC_HALF_RANGE_CODES),
                    num(ADC_HALF_RANGE_CODES)
                ));
            }
        }
        let discharge = self.lines.suction_pa * self.lines.pressure_ratio;
        if discharge > PRESSURE_FULL_SCALE_PA {
            return fail(format!(
                "`lines.suction_pa` = {} Pa × `lines.pressure_ratio` = {} is {} Pa, beyond \
                 the pressure sensors' full scale {} Pa",
                num(self.lines.suction_pa),
                num(self.lines.pressure_ratio),
                num(discharge),
                num(PRESSURE_FULL_SCALE_PA)
            ));
        }
        Ok(())
    }

    /// Each port window has a length, and no chamber is open to suction and discharge at
    /// once (the intake and discharge windows of a chamber do not overlap).
    fn check_ports(&self) -> Result<(), ModelError> {
        let po = &self.ports;
        let windows = [
            ("intake_a_deg", po.intake_a_deg),
            ("discharge_a_deg", po.discharge_a_deg),
            ("intake_b_deg", po.intake_b_deg),
            ("discharge_b_deg", po.discharge_b_deg),
        ];
        for (name, [open, close]) in windows {
            let length = (close - open).rem_euclid(360.0);
            if length < 1e-9 {
                return Err(ModelError(format!(
                    "`ports.{name}` = [{}, {}] has no length: a window opens at one edge and \
                     closes at another",
                    num(open),
                    num(close)
                )));
            }
            if 2.0 * po.ramp_deg >= length {
                return Err(ModelError(format!(
                    "`ports.ramp_deg` = {} is not below half of `ports.{name}`'s {} degrees: \
                     the window would never open fully",
                    num(po.ramp_deg),
                    num(length)
                )));
            }
        }
        for (intake, discharge) in [(windows[0], windows[1]), (windows[2], windows[3])] {
            let overlap = arc_overlap_deg(intake.1, discharge.1);
            if overlap > 1e-9 {
                return Err(ModelError(format!(
                    "`ports.{}` and `ports.{}` overlap by {} degrees: the chamber would be \
                     open to suction and discharge at once",
                    intake.0,
                    discharge.0,
                    num(overlap)
                )));
            }
        }
        Ok(())
    }
}

/// Degrees two windows `[open, close]` (edges in [0, 360], a window running forward from
/// `open` to `close` through 360 if need be) share.
fn arc_overlap_deg(a: [f64; 2], b: [f64; 2]) -> f64 {
    let span = |w: [f64; 2]| (w[1] - w[0]).rem_euclid(360.0);
    let (a0, a1) = (a[0], a[0] + span(a));
    [-360.0, 0.0, 360.0]
        .iter()
        .map(|shift| {
            let (b0, b1) = (b[0] + shift, b[0] + shift + span(b));
            (a1.min(b1) - a0.max(b0)).max(0.0)
        })
        .sum()
}

/// The whole-model rules of [`MachineModel`]'s validation, for the documentation.
pub const CONSISTENCY_RULES: &[&str] = &[
    "`piston.rod_m` < `piston.bore_m`",
    "each `piston.dead_length_*_m` < `piston.travel_m`",
    "`piston.travel_m` > 2 × (both dead lengths + 2 × `limits.target_head_clearance_m`)",
    "`limits.min_head_clearance_m` ≤ `limits.target_head_clearance_m`",
    "`encoder.period_m` ≤ `piston.travel_m`",
    "|`effects.cogging.amplitude_n`| < ½ × min(`limits.force_limit_n`, peak force)",
    "`friction.coulomb_n`, `friction.static_n`, `effects.stribeck_friction.static_n` < peak \
     force = `motor.force_constant_n_per_a` × `motor.current_limit_a`",
    "each port window has a length above 2 × `ports.ramp_deg`; a chamber's intake and \
     discharge windows do not overlap",
    "each encoder's amplitude × (1 + max(0, gain_mismatch)) + its largest offset ≤ 2047 codes",
    "`lines.suction_pa` × `lines.pressure_ratio` ≤ 1e6 Pa (the pressure sensors' full scale)",
    "`gas.gamma` > 1",
    "`supply.logic_dropout_voltage_v` < `supply.power_good_voltage_v` < `motor.bus_voltage_v` \
     < `supply.chopper_voltage_v`",
];
