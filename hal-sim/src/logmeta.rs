//! The run log's metadata (`docs/formats.md` §1, the `# key = value` lines): the keys the
//! log writers declare — the telemetry decoder, the scope, `gap`'s synthetic logs — and the
//! model-gap workflow reads, as one typed value written and read by both sides.

use crate::runlog::RunLog;

/// The largest force or ports delay a log may declare, s (`# force_delay_s`,
/// `# ports_delay_s`): ten milliseconds, two hundred control periods.
pub const MAX_FORCE_DELAY_S: f64 = 10e-3;

/// How the chambers were connected while the log was taken (`# ports`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PortsDeclared {
    /// `open`: ports timed by the logged rotation.
    Open,
    /// `closed`: both chambers sealed.
    Closed,
}

/// What the log's `theta_rad` measures (`# theta_source`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ThetaSource {
    /// `piston` (or no key): the piston's own angle, which times the ports.
    Piston,
    /// `servo_encoder`: the servo's quadrature count times its resolution (the count's
    /// lower edge), as the firmware reports it; the piston follows through the spline's
    /// play.
    ServoEncoder,
}

impl ThetaSource {
    /// Its name in the log.
    pub const fn name(self) -> &'static str {
        match self {
            ThetaSource::Piston => "piston",
            ThetaSource::ServoEncoder => "servo_encoder",
        }
    }

    /// The source named `name`, if any.
    pub fn from_name(name: &str) -> Option<ThetaSource> {
        [ThetaSource::Piston, ThetaSource::ServoEncoder]
            .into_iter()
            .find(|t| t.name() == name)
    }
}

/// A log's metadata. Written in this order (the typed keys as the fields run, then the
/// others as given); absent keys are not written.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LogMeta {
    /// `source`: the program that wrote the log.
    pub source: Option<String>,
    /// `sample_rate_hz`, Hz.
    pub sample_rate_hz: Option<f64>,
    /// `telemetry_decimation`: control cycles per telemetry frame (a decoded log).
    pub telemetry_decimation: Option<u32>,
    /// `telemetry_layout`: the telemetry frame layout (a decoded log).
    pub telemetry_layout: Option<u32>,
    /// `force_delay_s`: how late the logged forces are behind the row's position, s.
    pub force_delay_s: Option<f64>,
    /// `theta_source`: what `theta_rad` measures.
    pub theta_source: Option<ThetaSource>,
    /// `ports`: how the chambers were connected.
    pub ports: Option<PortsDeclared>,
    /// `ports_from_s`: the time the start-up bypass closed, s.
    pub ports_from_s: Option<f64>,
    /// `ports_delay_s`: how late the logger stamps its angle, s.
    pub ports_delay_s: Option<f64>,
    /// Every other key, in the order given (a writer's own: the scope's trigger, a run's
    /// seed, …).
    pub other: Vec<(String, String)>,
}

impl LogMeta {
    /// The `# key = value` pairs, in the order written.
    pub fn entries(&self) -> Vec<(String, String)> {
        let mut out: Vec<(String, String)> = Vec::new();
        let mut put = |k: &str, v: Option<String>| {
            if let Some(v) = v {
                out.push((k.to_string(), v));
            }
        };
        put("source", self.source.clone());
        put(
            "sample_rate_hz",
            self.sample_rate_hz.map(|r| format!("{r}")),
        );
        put(
            "telemetry_decimation",
            self.telemetry_decimation.map(|d| d.to_string()),
        );
        put(
            "telemetry_layout",
            self.telemetry_layout.map(|l| l.to_string()),
        );
        put(
            "force_delay_s",
            self.force_delay_s.map(|d| format!("{d:e}")),
        );
        put(
            "theta_source",
            self.theta_source.map(|t| t.name().to_string()),
        );
        put(
            "ports",
            self.ports.map(|p| {
                match p {
                    PortsDeclared::Open => "open",
                    PortsDeclared::Closed => "closed",
                }
                .to_string()
            }),
        );
        put("ports_from_s", self.ports_from_s.map(|t| format!("{t}")));
        put("ports_delay_s", self.ports_delay_s.map(|t| format!("{t}")));
        out.extend(self.other.iter().cloned());
        out
    }

    /// Writes the metadata into `log` (replacing what it held).
    pub fn write(&self, log: &mut RunLog) {
        log.meta = self.entries();
    }

    /// The metadata of `log`, its timing and port keys checked: a value that is not what its
    /// key means is refused with one line naming the key (`# ports = …` must be `open` or
    /// `closed`, the delays numbers of seconds within [`MAX_FORCE_DELAY_S`], `theta_source`
    /// `piston` or `servo_encoder`, `ports_from_s` a time). Other keys are kept as they are:
    /// a number that does not parse stays among [`LogMeta::other`].
    pub fn read(log: &RunLog) -> Result<LogMeta, String> {
        let text = |v: &str| v.chars().take(40).collect::<String>();
        let mut meta = LogMeta::default();
        for (key, value) in &log.meta {
            let v = value.trim();
            match key.as_str() {
                "source" => meta.source = Some(value.clone()),
                "sample_rate_hz" => match v.parse::<f64>() {
                    Ok(r) => meta.sample_rate_hz = Some(r),
                    Err(_) => meta.other.push((key.clone(), value.clone())),
                },
                "telemetry_decimation" | "telemetry_layout" => match v.parse::<u32>() {
                    Ok(n) if key == "telemetry_decimation" => meta.telemetry_decimation = Some(n),
                    Ok(n) => meta.telemetry_layout = Some(n),
                    Err(_) => meta.other.push((key.clone(), value.clone())),
                },
                // Read below, each checked.
                "ports" | "force_delay_s" | "ports_delay_s" | "theta_source" | "ports_from_s" => {}
                _ => meta.other.push((key.clone(), value.clone())),
            }
        }
        let find = |k: &str| log.meta(k).map(str::trim);
        meta.ports = match find("ports") {
            Some("closed") => Some(PortsDeclared::Closed),
            Some("open") => Some(PortsDeclared::Open),
            None => None,
            Some(other) => {
                return Err(format!(
                    "metadata `# ports = {other}`: must be `open` or `closed`"
                ))
            }
        };
        meta.force_delay_s = match find("force_delay_s") {
            None => None,
            Some(v) => match v.parse::<f64>() {
                Ok(d) if d.is_finite() && d.abs() <= MAX_FORCE_DELAY_S => Some(d),
                _ => {
                    return Err(format!(
                        "metadata `# force_delay_s = {}`: must be a number of seconds within \
                         ±{MAX_FORCE_DELAY_S}",
                        text(v)
                    ))
                }
            },
        };
        meta.ports_delay_s = match find("ports_delay_s") {
            None => None,
            Some(v) => match v.parse::<f64>() {
                Ok(d) if d.is_finite() && (0.0..=MAX_FORCE_DELAY_S).contains(&d) => Some(d),
                _ => {
                    return Err(format!(
                        "metadata `# ports_delay_s = {}`: must be a number of seconds within \
                         0..={MAX_FORCE_DELAY_S}",
                        text(v)
                    ))
                }
            },
        };
        meta.theta_source = match find("theta_source") {
            None => None,
            Some(v) => match ThetaSource::from_name(v) {
                Some(t) => Some(t),
                None => {
                    return Err(format!(
                        "metadata `# theta_source = {}`: must be `piston` or `servo_encoder`",
                        text(v)
                    ))
                }
            },
        };
        meta.ports_from_s = match find("ports_from_s") {
            None => None,
            Some(v) => match v.parse::<f64>() {
                Ok(t) if t.is_finite() => Some(t),
                _ => {
                    return Err(format!(
                        "metadata `# ports_from_s = {}`: must be a time in seconds",
                        text(v)
                    ))
                }
            },
        };
        Ok(meta)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metadata_written_reads_back_the_same() {
        let meta = LogMeta {
            source: Some("fpc-sim decode".into()),
            sample_rate_hz: Some(2000.0),
            telemetry_decimation: Some(10),
            telemetry_layout: Some(2),
            force_delay_s: Some(5e-5),
            theta_source: Some(ThetaSource::ServoEncoder),
            ports: Some(PortsDeclared::Open),
            ports_from_s: Some(0.93505),
            ports_delay_s: None,
            other: vec![("scope_trigger".into(), "fault".into())],
        };
        let mut log = RunLog::with_columns(&["t_s"]);
        meta.write(&mut log);
        let keys: Vec<&str> = log.meta.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(
            keys,
            [
                "source",
                "sample_rate_hz",
                "telemetry_decimation",
                "telemetry_layout",
                "force_delay_s",
                "theta_source",
                "ports",
                "ports_from_s",
                "scope_trigger"
            ]
        );
        assert_eq!(log.meta("force_delay_s"), Some("5e-5"));
        assert_eq!(log.meta("sample_rate_hz"), Some("2000"));
        assert_eq!(LogMeta::read(&log), Ok(meta));
    }

    #[test]
    fn a_bad_timing_or_ports_value_is_refused_by_name() {
        for (key, value) in [
            ("ports", "ajar"),
            ("force_delay_s", "1"),
            ("ports_delay_s", "-1e-3"),
            ("theta_source", "moon"),
            ("ports_from_s", "soon"),
        ] {
            let mut log = RunLog::with_columns(&["t_s"]);
            log.meta.push((key.into(), value.into()));
            let e = LogMeta::read(&log).unwrap_err();
            assert!(e.contains(&format!("`# {key} = {value}`")), "{e}");
        }
    }
}
