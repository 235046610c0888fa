//! Fault injection: the `--fault NAME@T[:k=v,…]` specifications of `docs/faults.md`.
//!
//! A specification names a scenario, the simulated time it starts at and optional
//! parameters. Parsing is strict: an unknown name, a malformed time, an unknown parameter or
//! a value out of its range is refused with a message naming it (exit code 2), so a typo
//! can never silently run a fault-free simulation. Applying a parsed specification to a
//! running simulation is [`crate::faults::apply`].

use std::fmt;

use crate::failure::{clip, num};

/// The injectable scenarios (`docs/faults.md` #1–15, #20 and #22; #16–19 are bad input, tested
/// through the command, model and log readers).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FaultKind {
    /// #1: sin/cos amplitude scaled (`gain`, default 0.2) on one encoder or both (`encoder`
    /// = master|slave|both, default master).
    EncoderAmplitude,
    /// #2: one channel (`channel` = sin|cos, default sin) frozen at mid-scale.
    EncoderStuck,
    /// #3: one sample with a phase jump (`jump_rad`, default 2.0).
    EncoderGlitch,
    /// #4: a fraction (`fraction`, default 0.1) of samples corrupt for `duration_s` (0.02).
    EncoderNoiseBurst,
    /// #5: a chamber pressure sensor at 0 V.
    PressureOpen,
    /// #5: a chamber pressure sensor at the rail.
    PressureShort,
    /// #6: a chamber pressure reading frozen.
    PressureStuck,
    /// #7: one motor section (`section` = master|slave, default slave) produces no force.
    SectionLoss,
    /// #8: the rotation blocked.
    ServoStall,
    /// #9: one chamber (`chamber` = a|b, default a) vented to ambient.
    GasLoss,
    /// #10: an external force step (`force_n`, default 3000).
    LoadStep,
    /// #11: the control step takes `cycles` (3) periods once.
    Overrun,
    /// #12: a task (`task` = control|supervision, default control) stops forever.
    TaskHang,
    /// #13: the host heartbeat stops.
    CommandLoss,
    /// #14: homing with no end stop (the stop is beyond the search distance).
    HomingNoStop,
    /// #15: homing with a brief friction spike (`force_n` 300, `duration_s` 0.005) mid-travel.
    HomingSpike,
    /// #20: counters start just before their wrap (time base, quadrature).
    CounterWrap,
    /// #21, #24: the mains is lost for `off_s` (0.1 s): the board runs on the DC link until
    /// its logic supply drops out, is then off (outputs low) for the rest of the outage, then
    /// boots again from power-on, reading its calibration flash (`--calibration`) afresh.
    PowerCut,
    /// #22: both encoders lost together: sin/cos amplitude scaled (`gain`, default 0.2) on
    /// the master and the slave (the same as `encoder_amplitude` with `encoder=both`).
    BothEncoders,
}

impl FaultKind {
    /// Every kind, with its command-line name.
    pub const ALL: [(FaultKind, &'static str); 19] = [
        (FaultKind::EncoderAmplitude, "encoder_amplitude"),
        (FaultKind::EncoderStuck, "encoder_stuck"),
        (FaultKind::EncoderGlitch, "encoder_glitch"),
        (FaultKind::EncoderNoiseBurst, "encoder_noise_burst"),
        (FaultKind::PressureOpen, "pressure_open"),
        (FaultKind::PressureShort, "pressure_short"),
        (FaultKind::PressureStuck, "pressure_stuck"),
        (FaultKind::SectionLoss, "section_loss"),
        (FaultKind::ServoStall, "servo_stall"),
        (FaultKind::GasLoss, "gas_loss"),
        (FaultKind::LoadStep, "load_step"),
        (FaultKind::Overrun, "overrun"),
        (FaultKind::TaskHang, "task_hang"),
        (FaultKind::CommandLoss, "command_loss"),
        (FaultKind::HomingNoStop, "homing_no_stop"),
        (FaultKind::HomingSpike, "homing_spike"),
        (FaultKind::CounterWrap, "counter_wrap"),
        (FaultKind::PowerCut, "power_cut"),
        (FaultKind::BothEncoders, "both_encoders"),
    ];

    /// The command-line name.
    pub fn name(self) -> &'static str {
        FaultKind::ALL
            .iter()
            .find(|(k, _)| *k == self)
            .map_or("?", |(_, n)| n)
    }

    /// What the fault does, for `--help` and the file-format reference (`docs/formats.md`
    /// §3): the `docs/faults.md` row and the parameters with their defaults.
    pub fn description(self) -> &'static str {
        match self {
            FaultKind::EncoderAmplitude => {
                "#1: sin/cos amplitude scaled (`gain`, default 0.2) on one encoder or both (`encoder` = master|slave|both, default master)."
            }
            FaultKind::EncoderStuck => {
                "#2: one channel (`channel` = sin|cos, default sin) frozen at mid-scale."
            }
            FaultKind::EncoderGlitch => {
                "#3: one sample with a phase jump (`jump_rad`, default 2.0)."
            }
            FaultKind::EncoderNoiseBurst => {
                "#4: a fraction (`fraction`, default 0.1) of samples corrupt for `duration_s` (0.02)."
            }
            FaultKind::PressureOpen => {
                "#5: a chamber pressure sensor at 0 V."
            }
            FaultKind::PressureShort => {
                "#5: a chamber pressure sensor at the rail."
            }
            FaultKind::PressureStuck => {
                "#6: a chamber pressure reading frozen."
            }
            FaultKind::SectionLoss => {
                "#7: one motor section (`section` = master|slave, default slave) produces no force."
            }
            FaultKind::ServoStall => {
                "#8: the rotation blocked."
            }
            FaultKind::GasLoss => {
                "#9: one chamber (`chamber` = a|b, default a) vented to ambient."
            }
            FaultKind::LoadStep => {
                "#10: an external force step (`force_n`, default 3000)."
            }
            FaultKind::Overrun => {
                "#11: the control step takes `cycles` (3) periods once."
            }
            FaultKind::TaskHang => {
                "#12: a task (`task` = control|supervision, default control) stops forever."
            }
            FaultKind::CommandLoss => {
                "#13: the host heartbeat stops."
            }
            FaultKind::HomingNoStop => {
                "#14: homing with no end stop (the stop is beyond the search distance)."
            }
            FaultKind::HomingSpike => {
                "#15: homing with a brief friction spike (`force_n` 300, `duration_s` 0.005) mid-travel."
            }
            FaultKind::CounterWrap => {
                "#20: counters start just before their wrap (time base, quadrature)."
            }
            FaultKind::PowerCut => {
                "#21, #24: the mains is lost for `off_s` (0.1 s): the board runs on the DC link (`[supply]`) until its logic supply drops out, is then off (outputs low) for the rest of `off_s`, then boots again from power-on, reading its calibration flash (`--calibration`) afresh."
            }
            FaultKind::BothEncoders => {
                "#22: both encoders lost together: sin/cos amplitude scaled (`gain`, default 0.2) on the master and the slave (the same as `encoder_amplitude` with `encoder=both`)."
            }
        }
    }

    /// Parameters this kind accepts: (name, default, lowest, highest). Text-valued
    /// parameters (`channel`, `section`, `chamber`) are encoded as 0/1.
    pub fn parameters(self) -> &'static [(&'static str, f64, f64, f64)] {
        match self {
            FaultKind::EncoderAmplitude => &[("gain", 0.2, 0.0, 10.0), ("encoder", 0.0, 0.0, 2.0)],
            FaultKind::BothEncoders => &[("gain", 0.2, 0.0, 10.0)],
            FaultKind::EncoderStuck => &[("channel", 0.0, 0.0, 1.0)],
            FaultKind::EncoderGlitch => {
                &[("jump_rad", 2.0, -std::f64::consts::PI, std::f64::consts::PI)]
            }
            FaultKind::EncoderNoiseBurst => {
                &[("fraction", 0.1, 0.0, 1.0), ("duration_s", 0.02, 0.0, 10.0)]
            }
            FaultKind::PressureOpen | FaultKind::PressureShort | FaultKind::PressureStuck => {
                &[("chamber", 0.0, 0.0, 1.0)]
            }
            FaultKind::SectionLoss => &[("section", 1.0, 0.0, 1.0)],
            FaultKind::GasLoss => &[("chamber", 0.0, 0.0, 1.0)],
            FaultKind::LoadStep => &[("force_n", 3000.0, -20_000.0, 20_000.0)],
            FaultKind::Overrun => &[("cycles", 3.0, 2.0, 1000.0)],
            FaultKind::HomingSpike => &[
                ("force_n", 300.0, 0.0, 5000.0),
                ("duration_s", 0.005, 0.0, 1.0),
            ],
            FaultKind::TaskHang => &[("task", 0.0, 0.0, 1.0)],
            FaultKind::PowerCut => &[("off_s", 0.1, 0.0, 10.0)],
            FaultKind::ServoStall
            | FaultKind::CommandLoss
            | FaultKind::HomingNoStop
            | FaultKind::CounterWrap => &[],
        }
    }
}

/// Parameters that count or pick something (an encoder, a chamber, a section, a task, control
/// cycles): whole numbers only.
const INTEGER_PARAMETERS: [&str; 6] =
    ["encoder", "channel", "chamber", "section", "cycles", "task"];

/// One parsed `--fault` specification.
#[derive(Clone, Debug, PartialEq)]
pub struct FaultSpec {
    /// The scenario.
    pub kind: FaultKind,
    /// When it starts, s of simulated time.
    pub at_s: f64,
    /// Every parameter of the kind, given or defaulted, in the order of
    /// [`FaultKind::parameters`].
    pub params: Vec<(&'static str, f64)>,
}

impl FaultSpec {
    /// The value of parameter `name` (its default if not given; 0 if the kind has none).
    pub fn param(&self, name: &str) -> f64 {
        self.params
            .iter()
            .find(|(n, _)| *n == name)
            .map_or(0.0, |(_, v)| *v)
    }
}

/// Why a specification was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SpecError(pub String);

impl fmt::Display for SpecError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for SpecError {}

/// Text values some parameters take, and their numeric code: (parameter, word, code).
pub const WORDS: [(&str, &str, f64); 11] = [
    ("channel", "sin", 0.0),
    ("channel", "cos", 1.0),
    ("section", "master", 0.0),
    ("section", "slave", 1.0),
    ("chamber", "a", 0.0),
    ("chamber", "b", 1.0),
    ("task", "control", 0.0),
    ("task", "supervision", 1.0),
    ("encoder", "master", 0.0),
    ("encoder", "slave", 1.0),
    ("encoder", "both", 2.0),
];

/// Parses `NAME@T[:k=v,…]`.
pub fn parse(spec: &str) -> Result<FaultSpec, SpecError> {
    // Every echo of the user's text is cut to a readable length.
    let err = |m: String| SpecError(format!("--fault `{}`: {m}", clip(spec)));
    let (name, rest) = spec
        .split_once('@')
        .ok_or_else(|| err("expected NAME@T[:k=v,…] (missing `@`)".into()))?;
    let kind = FaultKind::ALL
        .iter()
        .find(|(_, n)| *n == name)
        .map(|(k, _)| *k)
        .ok_or_else(|| {
            let known: Vec<&str> = FaultKind::ALL.iter().map(|(_, n)| *n).collect();
            err(format!(
                "unknown fault `{}` (known: {})",
                clip(name),
                known.join(", ")
            ))
        })?;
    let (time, params) = match rest.split_once(':') {
        Some((t, p)) => (t, Some(p)),
        None => (rest, None),
    };
    let at_s: f64 = time
        .parse()
        .map_err(|_| err(format!("time `{}` is not a number of seconds", clip(time))))?;
    if !(at_s.is_finite() && at_s >= 0.0) {
        return Err(err(format!(
            "time `{}` must be a finite, non-negative number of seconds",
            clip(time)
        )));
    }
    let allowed = kind.parameters();
    let mut given: Vec<&str> = Vec::new();
    let mut values: Vec<(&'static str, f64)> =
        allowed.iter().map(|(n, d, _, _)| (*n, *d)).collect();
    for pair in params
        .into_iter()
        .flat_map(|p| p.split(','))
        .filter(|p| !p.is_empty())
    {
        let (k, v) = pair
            .split_once('=')
            .ok_or_else(|| err(format!("parameter `{}` is not k=v", clip(pair))))?;
        let (pname, _, lo, hi) = allowed.iter().find(|(n, ..)| *n == k).ok_or_else(|| {
            let names: Vec<&str> = allowed.iter().map(|(n, ..)| *n).collect();
            err(format!(
                "`{name}` has no parameter `{}` (it takes: {})",
                clip(k),
                if names.is_empty() {
                    "none".to_string()
                } else {
                    names.join(", ")
                }
            ))
        })?;
        let value = match WORDS.iter().find(|(p, w, _)| p == pname && *w == v) {
            Some((_, _, code)) => *code,
            None if WORDS.iter().any(|(p, ..)| p == pname) => {
                let words: Vec<&str> = WORDS
                    .iter()
                    .filter(|(p, ..)| p == pname)
                    .map(|(_, w, _)| *w)
                    .collect();
                return Err(err(format!("`{k}` must be one of {}", words.join("|"))));
            }
            None => v
                .parse::<f64>()
                .map_err(|_| err(format!("`{k}={}` is not a number", clip(v))))?,
        };
        if !(value.is_finite() && (*lo..=*hi).contains(&value)) {
            return Err(err(format!(
                "`{k}={}` is outside [{}, {}]",
                clip(v),
                num(*lo),
                num(*hi)
            )));
        }
        if INTEGER_PARAMETERS.contains(pname) && value.fract() != 0.0 {
            return Err(err(format!(
                "`{k}={}` must be a whole number in [{}, {}]",
                clip(v),
                num(*lo),
                num(*hi)
            )));
        }
        if given.contains(pname) {
            return Err(err(format!("parameter `{k}` is given twice")));
        }
        given.push(pname);
        if let Some(slot) = values.iter_mut().find(|(n, _)| n == pname) {
            slot.1 = value;
        }
    }
    Ok(FaultSpec {
        kind,
        at_s,
        params: values,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_names_times_and_parameters() {
        let s = parse("encoder_amplitude@0.5:gain=1.5").unwrap();
        assert_eq!(
            (s.kind, s.at_s, s.param("gain")),
            (FaultKind::EncoderAmplitude, 0.5, 1.5)
        );
        let s = parse("section_loss@1").unwrap();
        assert_eq!(s.param("section"), 1.0);
        let s = parse("section_loss@1:section=master").unwrap();
        assert_eq!(s.param("section"), 0.0);
        for (_, name) in FaultKind::ALL {
            assert!(parse(&format!("{name}@0.1")).is_ok(), "{name}");
        }
    }

    #[test]
    fn counts_are_whole_and_parameters_given_once() {
        let e = parse("overrun@1:cycles=2.5").unwrap_err().0;
        assert!(e.contains("whole number"), "{e}");
        let e = parse("overrun@1:cycles=3,cycles=4").unwrap_err().0;
        assert!(e.contains("given twice"), "{e}");
        assert_eq!(parse("overrun@1:cycles=4").unwrap().param("cycles"), 4.0);
    }

    #[test]
    fn refuses_bad_specs_naming_what_is_wrong() {
        let e = parse("encoder_amplitud@0.5").unwrap_err().0;
        assert!(e.contains("unknown fault `encoder_amplitud`"), "{e}");
        assert!(parse("encoder_amplitude")
            .unwrap_err()
            .0
            .contains("missing `@`"));
        assert!(parse("encoder_amplitude@soon")
            .unwrap_err()
            .0
            .contains("time `soon`"));
        assert!(parse("encoder_amplitude@-1")
            .unwrap_err()
            .0
            .contains("non-negative"));
        assert!(parse("encoder_amplitude@1:gian=2")
            .unwrap_err()
            .0
            .contains("no parameter `gian`"));
        assert!(parse("encoder_amplitude@1:gain")
            .unwrap_err()
            .0
            .contains("not k=v"));
        assert!(parse("encoder_amplitude@1:gain=x")
            .unwrap_err()
            .0
            .contains("not a number"));
        assert!(parse("encoder_amplitude@1:gain=NaN")
            .unwrap_err()
            .0
            .contains("outside"));
        assert!(parse("section_loss@1:section=left")
            .unwrap_err()
            .0
            .contains("master|slave"));
    }
}
