//! A sweep plan (`fpc-sim sweep PLAN.toml`): the axes of a study and the runs they span.
//!
//! ```toml
//! cycles = 5                              # per run (default 10)
//! model = "machine.toml"                  # relative to the plan (default: the reference)
//! [axes]
//! pressure_ratio = [2.2, 3.1, 4.5]        # a list …
//! speed_mps = { from = 1.0, to = 4.0, steps = 4 }   # … or a linear range, ends included
//! seed = { from = 1, to = 10 }            # whole numbers: every one from `from` to `to`
//! fault = ["none", "overrun@1.5:cycles=2"]
//! volume_ratio = ["adaptive", "fixed:3.1"]          # as `run --volume-ratio`
//! controller = ["ours", "published"]                # as `run --controller`
//! rotation = ["compressor", "expander"]             # as `run --rotation`
//! "model.piston.mass_kg" = [11.0, 12.0, 13.0]       # any number of the model file
//! ```
//!
//! Every combination of the axes' values is one run; run `k` takes the axes (in the names'
//! sorted order) as the digits of `k`, the last axis fastest. A run's options are built and
//! checked exactly as `fpc-sim run` checks its flags, so a value `run` refuses is refused here,
//! naming the run and its values, before anything runs.

use std::collections::BTreeMap;

use crate::faults::inject::FaultSpec;
use crate::output::clip;
use crate::plant::model::MachineModel;
use crate::run::RunOptions;

/// Most runs a plan may span (a study of 10⁷ runs is months of one core; shard it).
pub const MAX_RUNS: u64 = 10_000_000;

/// Most values one axis may list or step through.
pub const MAX_AXIS_VALUES: usize = 100_000;

/// The axes a plan may name besides `model.…` keys.
pub const KNOWN_AXES: [&str; 9] = [
    "pressure_ratio",
    "speed_mps",
    "seed",
    "cycles",
    "model_error",
    "fault",
    "volume_ratio",
    "controller",
    "rotation",
];

/// One value of an axis.
#[derive(Clone, Debug, PartialEq)]
pub enum AxisValue {
    /// A number.
    Real(f64),
    /// A whole number.
    Int(i64),
    /// A text (`fault`).
    Text(String),
}

impl std::fmt::Display for AxisValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AxisValue::Real(v) => write!(f, "{v}"),
            AxisValue::Int(v) => write!(f, "{v}"),
            AxisValue::Text(v) => f.write_str(v),
        }
    }
}

/// One axis: its name and values.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    /// `pressure_ratio`, …, or `model.<section>.<key>`.
    pub name: String,
    /// Its values, in the plan's order.
    pub values: Vec<AxisValue>,
}

/// A parsed plan.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Compression cycles of each run (unless `cycles` is an axis).
    pub cycles: u32,
    /// The base model's TOML text.
    pub model_text: String,
    /// Where the base model came from (for the run logs' metadata).
    pub model_name: String,
    /// The axes, sorted by name.
    pub axes: Vec<Axis>,
    /// A fingerprint of what the plan asks (FNV-1a over the model text, the cycles and the
    /// axes): shards of one plan share it, and `sweep-merge` joins only those.
    pub fingerprint: u64,
}

fn fnv1a(hash: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *hash ^= u64::from(*b);
        *hash = hash.wrapping_mul(0x0100_0000_01b3);
    }
}

impl Plan {
    /// Parses a plan's `text`; `model` resolves the plan's `model = "…"` to (text, name).
    pub fn parse(
        text: &str,
        mut model: impl FnMut(&str) -> Result<(String, String), String>,
    ) -> Result<Plan, String> {
        let table: toml::Table = text.parse().map_err(|e: toml::de::Error| {
            format!("not a plan: {}", e.message().lines().next().unwrap_or(""))
        })?;
        for key in table.keys() {
            if !["cycles", "model", "axes"].contains(&key.as_str()) {
                return Err(format!(
                    "key `{}`: a plan has `cycles`, `model` and `[axes]`",
                    clip(key, 40)
                ));
            }
        }
        let cycles = match table.get("cycles") {
            None => 10,
            Some(toml::Value::Integer(c)) if (1..=10_000).contains(c) => *c as u32,
            Some(other) => {
                return Err(format!(
                    "`cycles = {}`: must be a whole number 1..=10000",
                    clip(&other.to_string(), 40)
                ))
            }
        };
        let (model_text, model_name) = match table.get("model") {
            None => (
                include_str!("../plant/model/reference.toml").to_string(),
                "reference".to_string(),
            ),
            Some(toml::Value::String(path)) => model(path)?,
            Some(other) => {
                return Err(format!(
                    "`model = {}`: must be the path of a model file",
                    clip(&other.to_string(), 40)
                ))
            }
        };
        let Some(toml::Value::Table(axes_table)) = table.get("axes") else {
            return Err("section `[axes]` is missing: a plan sweeps at least one axis".into());
        };
        let mut axes = Vec::new();
        for (name, value) in axes_table {
            axes.push(Axis {
                name: name.clone(),
                values: axis_values(name, value)?,
            });
        }
        if axes.is_empty() {
            return Err("section `[axes]` is empty: a plan sweeps at least one axis".into());
        }
        let mut fingerprint = 0xcbf2_9ce4_8422_2325;
        fnv1a(&mut fingerprint, model_text.as_bytes());
        fnv1a(&mut fingerprint, &cycles.to_le_bytes());
        for a in &axes {
            fnv1a(&mut fingerprint, a.name.as_bytes());
            for v in &a.values {
                fnv1a(&mut fingerprint, format!("\u{1f}{v}").as_bytes());
            }
            fnv1a(&mut fingerprint, b"\x1e");
        }
        let plan = Plan {
            cycles,
            model_text,
            model_name,
            axes,
            fingerprint,
        };
        if plan.len() > MAX_RUNS {
            return Err(format!(
                "{} runs: a plan may span at most {MAX_RUNS} (split it into plans)",
                plan.len()
            ));
        }
        Ok(plan)
    }

    /// How many runs the plan spans.
    pub fn len(&self) -> u64 {
        self.axes
            .iter()
            .map(|a| a.values.len() as u64)
            .fold(1u64, u64::saturating_mul)
    }

    /// Whether the plan spans no run (never, once parsed).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The axes' values of run `k` (the last axis fastest).
    pub fn point(&self, k: u64) -> Vec<&AxisValue> {
        let mut rest = k;
        let mut out: Vec<&AxisValue> = Vec::with_capacity(self.axes.len());
        for a in self.axes.iter().rev() {
            let n = a.values.len().max(1) as u64;
            let i = (rest % n) as usize;
            rest /= n;
            if let Some(v) = a.values.get(i) {
                out.push(v);
            }
        }
        out.reverse();
        out
    }

    /// The base model, parsed once for every run.
    pub fn base(&self) -> Result<Base, String> {
        let table: toml::Table = self
            .model_text
            .parse()
            .map_err(|e: toml::de::Error| format!("model: {}", e.message()))?;
        let model = MachineModel::parse(&self.model_text).map_err(|e| format!("model: {}", e.0))?;
        Ok(Base { table, model })
    }

    /// Run `k`'s options, checked as `fpc-sim run` checks them; the error names the run and
    /// its values.
    pub fn options(&self, k: u64, base: &Base) -> Result<RunOptions, String> {
        let point = self.point(k);
        let named = || {
            self.axes
                .iter()
                .zip(&point)
                .map(|(a, v)| format!("{} = {}", a.name, clip(&v.to_string(), 40)))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let mut opts = RunOptions {
            cycles: self.cycles,
            model_name: self.model_name.clone(),
            ..RunOptions::reference()
        };
        let mut model_keys = Vec::new();
        let mut rotation = None;
        for (a, v) in self.axes.iter().zip(&point) {
            match (a.name.as_str(), v) {
                ("pressure_ratio", AxisValue::Real(x)) => opts.pressure_ratio = *x,
                ("speed_mps", AxisValue::Real(x)) => opts.speed_mps = Some(*x),
                ("model_error", AxisValue::Real(x)) => opts.model_error = *x,
                ("seed", AxisValue::Int(s)) => opts.seed = *s as u64,
                ("cycles", AxisValue::Int(c)) => opts.cycles = *c as u32,
                ("fault", AxisValue::Text(t)) => opts.faults = faults(t)?,
                ("controller", AxisValue::Text(t)) => {
                    opts.controller = crate::run::Controller::parse(t)
                        .map_err(|e| format!("run {k} ({}): {e}", named()))?
                }
                ("volume_ratio", AxisValue::Text(t)) => {
                    opts.volume_ratio = crate::run::parse_volume_ratio(t)
                        .map_err(|e| format!("run {k} ({}): {e}", named()))?
                }
                ("rotation", AxisValue::Text(t)) => {
                    rotation = Some(
                        crate::run::parse_rotation(t)
                            .map_err(|e| format!("run {k} ({}): {e}", named()))?,
                    )
                }
                (name, v) => model_keys.push((name.trim_start_matches("model."), *v)),
            }
        }
        if model_keys.is_empty() {
            opts.model = base.model.clone();
        } else {
            let mut t = base.table.clone();
            for (path, v) in &model_keys {
                set(&mut t, path, v);
            }
            opts.model = MachineModel::parse(&toml::to_string(&t).unwrap_or_default())
                .map_err(|e| format!("run {k} ({}): {}", named(), e.0))?;
        }
        // After the controller is known: the published drives refuse an expander.
        if let Some(r) = rotation {
            crate::run::set_rotation(&mut opts, r)
                .map_err(|e| format!("run {k} ({}): {e}", named()))?;
        }
        opts.validate()
            .map_err(|e| format!("run {k} ({}): {e}", named()))?;
        Ok(opts)
    }
}

/// The plan's base model: as text (for model axes) and parsed.
#[derive(Clone, Debug)]
pub struct Base {
    table: toml::Table,
    model: MachineModel,
}

/// The faults of a `fault` axis value: `none`, or specifications joined by `;`.
fn faults(text: &str) -> Result<Vec<FaultSpec>, String> {
    if text.trim() == "none" {
        return Ok(Vec::new());
    }
    text.split(';')
        .map(|s| crate::faults::inject::parse(s.trim()).map_err(|e| e.0))
        .collect()
}

/// Sets the dotted `path` of `table` to `v` (sections created as needed).
fn set(table: &mut toml::Table, path: &str, v: &AxisValue) {
    let mut parts: Vec<&str> = path.split('.').collect();
    let Some(last) = parts.pop() else { return };
    let mut t = table;
    for p in parts {
        let entry = t
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        if !entry.is_table() {
            *entry = toml::Value::Table(toml::Table::new());
        }
        let toml::Value::Table(inner) = entry else {
            return;
        };
        t = inner;
    }
    let value = match v {
        AxisValue::Real(x) => toml::Value::Float(*x),
        AxisValue::Int(i) => toml::Value::Integer(*i),
        AxisValue::Text(s) => toml::Value::String(s.clone()),
    };
    t.insert(last.to_string(), value);
}

/// What kind of value an axis takes.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Real,
    Int,
    Text,
    /// A model key: numbers as written (whole or not).
    Model,
}

fn kind_of(name: &str) -> Result<Kind, String> {
    Ok(match name {
        "pressure_ratio" | "speed_mps" | "model_error" => Kind::Real,
        "seed" | "cycles" => Kind::Int,
        "fault" | "volume_ratio" | "controller" | "rotation" => Kind::Text,
        n if n.starts_with("model.")
            && n.len() > 6
            && n.split('.').all(|p| {
                !p.is_empty() && p.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
            }) =>
        {
            Kind::Model
        }
        other => {
            return Err(format!(
                "axis `{}`: not an axis (known: {}, or `model.<section>.<key>` of the model \
                 file)",
                clip(other, 40),
                KNOWN_AXES.join(", ")
            ))
        }
    })
}

/// The values of axis `name` given as `value` (a list or a range table).
fn axis_values(name: &str, value: &toml::Value) -> Result<Vec<AxisValue>, String> {
    let kind = kind_of(name)?;
    let bad = |what: &str| format!("axis `{name}`: {what}");
    let one = |v: &toml::Value| -> Result<AxisValue, String> {
        match (kind, v) {
            (Kind::Real | Kind::Model, toml::Value::Float(x)) if x.is_finite() => {
                Ok(AxisValue::Real(*x))
            }
            (Kind::Real, toml::Value::Integer(i)) => Ok(AxisValue::Real(*i as f64)),
            (Kind::Model, toml::Value::Integer(i)) => Ok(AxisValue::Int(*i)),
            (Kind::Int, toml::Value::Integer(i)) if *i >= 0 => Ok(AxisValue::Int(*i)),
            (Kind::Text, toml::Value::String(s)) => Ok(AxisValue::Text(s.clone())),
            (_, other) => Err(bad(&format!(
                "value {} is not {}",
                clip(&other.to_string(), 40),
                match kind {
                    Kind::Real | Kind::Model => "a finite number",
                    Kind::Int => "a whole number ≥ 0",
                    Kind::Text => "a text",
                }
            ))),
        }
    };
    let values = match value {
        toml::Value::Array(items) => {
            if items.len() > MAX_AXIS_VALUES {
                return Err(bad(&format!("more than {MAX_AXIS_VALUES} values")));
            }
            items.iter().map(one).collect::<Result<Vec<_>, _>>()?
        }
        toml::Value::Table(range) => range_values(range, kind, &bad)?,
        other => {
            return Err(bad(&format!(
                "{} is neither a list nor {{ from, to, steps }}",
                clip(&other.to_string(), 40)
            )))
        }
    };
    if values.is_empty() {
        return Err(bad("no values"));
    }
    Ok(values)
}

/// The values of a `{ from, to, steps }` range (whole numbers: `{ from, to }`, every one).
fn range_values(
    range: &toml::Table,
    kind: Kind,
    bad: &dyn Fn(&str) -> String,
) -> Result<Vec<AxisValue>, String> {
    let keys: BTreeMap<&str, &toml::Value> = range.iter().map(|(k, v)| (k.as_str(), v)).collect();
    if let Some(k) = keys.keys().find(|k| !["from", "to", "steps"].contains(k)) {
        return Err(bad(&format!(
            "range key `{}`: a range has `from`, `to` and `steps`",
            clip(k, 40)
        )));
    }
    let num = |k: &str| -> Result<f64, String> {
        match keys.get(k) {
            Some(toml::Value::Float(x)) if x.is_finite() => Ok(*x),
            Some(toml::Value::Integer(i)) => Ok(*i as f64),
            Some(other) => Err(bad(&format!(
                "range `{k} = {}` is not a finite number",
                clip(&other.to_string(), 40)
            ))),
            None => Err(bad(&format!("range has no `{k}`"))),
        }
    };
    let (from, to) = (num("from")?, num("to")?);
    if from > to {
        return Err(bad(&format!("range from {from} to {to} runs backwards")));
    }
    match kind {
        Kind::Int => {
            if keys.contains_key("steps") {
                return Err(bad("a whole-number range takes every value: no `steps`"));
            }
            if from < 0.0 || from.fract() != 0.0 || to.fract() != 0.0 {
                return Err(bad("a whole-number range needs whole ends ≥ 0"));
            }
            if to - from >= MAX_AXIS_VALUES as f64 {
                return Err(bad(&format!("more than {MAX_AXIS_VALUES} values")));
            }
            Ok((from as i64..=to as i64).map(AxisValue::Int).collect())
        }
        Kind::Real | Kind::Model => {
            let steps = match keys.get("steps") {
                Some(toml::Value::Integer(n)) if (2..=MAX_AXIS_VALUES as i64).contains(n) => {
                    *n as usize
                }
                Some(other) => {
                    return Err(bad(&format!(
                        "range `steps = {}` must be a whole number 2..={MAX_AXIS_VALUES}",
                        clip(&other.to_string(), 40)
                    )))
                }
                None => return Err(bad("range has no `steps`")),
            };
            Ok((0..steps)
                .map(|i| {
                    let f = i as f64 / (steps - 1) as f64;
                    AxisValue::Real(if i + 1 == steps {
                        to
                    } else {
                        from + f * (to - from)
                    })
                })
                .collect())
        }
        Kind::Text => Err(bad("a text axis takes a list")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(text: &str) -> Result<Plan, String> {
        Plan::parse(text, |p| Err(format!("no model files here ({p})")))
    }

    #[test]
    fn runs_are_the_axes_digits_last_axis_fastest() {
        let p = plan(
            "cycles = 2\n[axes]\nspeed_mps = { from = 1.0, to = 2.0, steps = 3 }\nseed = { from = 4, to = 5 }\n",
        )
        .unwrap();
        // Sorted by name: seed, speed_mps.
        assert_eq!(p.axes[0].name, "seed");
        assert_eq!(p.len(), 6);
        let show = |k| {
            p.point(k)
                .iter()
                .map(|v| v.to_string())
                .collect::<Vec<_>>()
                .join(" ")
        };
        assert_eq!(show(0), "4 1");
        assert_eq!(show(1), "4 1.5");
        assert_eq!(show(2), "4 2");
        assert_eq!(show(5), "5 2");
    }

    #[test]
    fn bad_plans_are_refused_naming_what_is_wrong() {
        for (text, needle) in [
            ("[axes]\n", "is empty"),
            ("cycles = 2\n", "`[axes]` is missing"),
            ("[axes]\nspeed = [1.0]\n", "axis `speed`: not an axis"),
            ("[axes]\nseed = [-1]\n", "whole number ≥ 0"),
            (
                "[axes]\nspeed_mps = { from = 2.0, to = 1.0, steps = 3 }\n",
                "backwards",
            ),
            (
                "[axes]\nspeed_mps = { from = 1.0, to = 2.0 }\n",
                "no `steps`",
            ),
            ("[axes]\nspeed_mps = []\n", "no values"),
            ("[axes]\nseed = { from = 0, to = 1e9 }\n", "more than"),
            ("cycles = 0\n[axes]\nseed = [1]\n", "`cycles = 0`"),
            ("colour = 1\n[axes]\nseed = [1]\n", "key `colour`"),
            ("model = \"m.toml\"\n[axes]\nseed = [1]\n", "no model files"),
            ("[axes]\n\"model.piston.\" = [1.0]\n", "not an axis"),
            (
                "[axes]\nseed = {from=0,to=1000}\nspeed_mps = {from=1.0,to=2.0,steps=100000}\n",
                "at most",
            ),
        ] {
            let e = plan(text).unwrap_err();
            assert!(e.contains(needle), "{text:?}: {e}");
        }
    }

    #[test]
    fn a_run_that_run_would_refuse_is_named_with_its_values() {
        let p = plan("[axes]\npressure_ratio = [3.1, 9.0]\n").unwrap();
        let base = p.base().unwrap();
        assert!(p.options(0, &base).is_ok());
        let e = p.options(1, &base).unwrap_err();
        assert!(e.starts_with("run 1 (pressure_ratio = 9)"), "{e}");
        let p = plan("[axes]\n\"model.piston.mass_kg\" = [12.0, -1.0]\n").unwrap();
        assert_eq!(p.options(0, &base).unwrap().model.piston.mass_kg, 12.0);
        let e = p.options(1, &base).unwrap_err();
        assert!(e.contains("run 1") && e.contains("mass_kg"), "{e}");
    }
}
