//! The run log (`formats.md` §1): the CSV the rig logs and the simulator writes.
//!
//! Writing is plain formatted text (deterministic: the same values give the same bytes).
//! Reading validates everything the contract names and refuses with the line and column at
//! fault: missing required columns, non-numeric or non-finite values, time not increasing
//! uniformly (1 % tolerance), fewer than 100 rows.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// Required columns, in order.
pub const REQUIRED: [&str; 8] = [
    "t_s",
    "x_m",
    "x_slave_m",
    "theta_rad",
    "f_master_n",
    "f_slave_n",
    "p_a_pa",
    "p_b_pa",
];

/// Fewest data rows a reader accepts.
pub const MIN_ROWS: usize = 100;

/// The first two bytes of a gzip stream (RFC 1952).
const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];

/// A run log in memory: metadata and named columns of equal length.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunLog {
    /// `# key = value` metadata, in file order.
    pub meta: Vec<(String, String)>,
    /// Column names, in file order.
    pub names: Vec<String>,
    /// Column data, in the order of `names`.
    pub columns: Vec<Vec<f64>>,
}

/// Why a run log was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LogError {
    /// 1-based line in the file (0 when it concerns the whole file).
    pub line: usize,
    /// Column name, when one is at fault.
    pub column: Option<String>,
    /// What is wrong.
    pub message: String,
}

impl std::fmt::Display for LogError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.column, self.line) {
            (Some(c), 0) => write!(f, "column `{c}`: {}", self.message),
            (Some(c), l) => write!(f, "line {l}, column `{c}`: {}", self.message),
            (None, 0) => write!(f, "{}", self.message),
            (None, l) => write!(f, "line {l}: {}", self.message),
        }
    }
}

impl std::error::Error for LogError {}

impl RunLog {
    /// An empty log with these columns.
    pub fn with_columns(names: &[&str]) -> Self {
        RunLog {
            meta: Vec::new(),
            names: names.iter().map(|s| s.to_string()).collect(),
            columns: vec![Vec::new(); names.len()],
        }
    }

    /// Appends a row (one value per column, in column order; extra values are ignored and
    /// missing ones are NaN).
    pub fn push_row(&mut self, row: &[f64]) {
        let padded = row.iter().chain(std::iter::repeat(&f64::NAN));
        for (col, v) in self.columns.iter_mut().zip(padded) {
            col.push(*v);
        }
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.columns.first().map_or(0, Vec::len)
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The column called `name`.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.names
            .iter()
            .position(|n| n == name)
            .and_then(|i| self.columns.get(i))
            .map(Vec::as_slice)
    }

    /// A metadata value.
    pub fn meta(&self, key: &str) -> Option<&str> {
        self.meta
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// Sample time, s (from the first two rows).
    pub fn sample_time_s(&self) -> Option<f64> {
        let t = self.column("t_s")?;
        Some(t.get(1)? - t.first()?)
    }

    /// The CSV text. Every value is written in the shortest digits that read back as the same
    /// number at the precision it was computed in (`f64`, or `f32` for what the firmware
    /// reports; see `format_value`), so a file read and written again is the same text.
    pub fn to_csv(&self) -> String {
        let mut out = String::with_capacity(self.len() * self.names.len() * 16 + 256);
        for (k, v) in &self.meta {
            let _ = writeln!(out, "# {k} = {v}");
        }
        out.push_str(&self.names.join(","));
        out.push('\n');
        let mut float = ryu::Buffer::new();
        let mut int = itoa::Buffer::new();
        for r in 0..self.len() {
            for (i, col) in self.columns.iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                out.push_str(format_value(
                    col.get(r).copied().unwrap_or(f64::NAN),
                    &mut float,
                    &mut int,
                ));
            }
            out.push('\n');
        }
        out
    }

    /// Writes the CSV to `path`.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        std::fs::write(path, self.to_csv())
    }

    /// Reads and validates a run log from `path`, gzipped or not (recognised by the gzip
    /// magic bytes, whatever the file is called).
    pub fn read(path: &Path) -> Result<RunLog, LogError> {
        let fail = |what: String| LogError {
            line: 0,
            column: None,
            message: format!("cannot read {}: {what}", path.display()),
        };
        let bytes = std::fs::read(path).map_err(|e| fail(e.to_string()))?;
        let bytes = if bytes.starts_with(&GZIP_MAGIC) {
            let mut out = Vec::new();
            std::io::Read::read_to_end(
                &mut flate2::read::MultiGzDecoder::new(&bytes[..]),
                &mut out,
            )
            .map_err(|e| fail(format!("not a valid gzip stream ({e})")))?;
            out
        } else {
            bytes
        };
        let text = String::from_utf8(bytes).map_err(|e| {
            fail(format!(
                "not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ))
        })?;
        Self::parse(&text)
    }

    /// Parses and validates run-log text.
    pub fn parse(text: &str) -> Result<RunLog, LogError> {
        let err = |line: usize, column: Option<&str>, message: String| LogError {
            line,
            column: column.map(str::to_string),
            message,
        };
        let mut meta = Vec::new();
        let mut header: Option<(usize, Vec<String>)> = None;
        let mut columns: Vec<Vec<f64>> = Vec::new();
        for (idx, raw) in text.lines().enumerate() {
            let line_no = idx + 1;
            let line = raw.trim_end_matches('\r');
            if let Some(rest) = line.strip_prefix('#') {
                if header.is_none() {
                    if let Some((k, v)) = rest.split_once('=') {
                        meta.push((k.trim().to_string(), v.trim().to_string()));
                    }
                }
                continue;
            }
            if line.trim().is_empty() {
                continue;
            }
            match &header {
                None => {
                    let names: Vec<String> =
                        line.split(',').map(|s| s.trim().to_string()).collect();
                    for req in REQUIRED {
                        if !names.iter().any(|n| n == req) {
                            return Err(err(
                                line_no,
                                Some(req),
                                "required column is missing".into(),
                            ));
                        }
                    }
                    columns = vec![Vec::new(); names.len()];
                    header = Some((line_no, names));
                }
                Some((_, names)) => {
                    let fields: Vec<&str> = line.split(',').collect();
                    if fields.len() != names.len() {
                        return Err(err(
                            line_no,
                            None,
                            format!("expected {} fields, found {}", names.len(), fields.len()),
                        ));
                    }
                    for ((field, name), col) in fields.iter().zip(names).zip(columns.iter_mut()) {
                        let v: f64 = field.trim().parse().map_err(|_| {
                            err(
                                line_no,
                                Some(name),
                                format!("`{}` is not a number", field.trim()),
                            )
                        })?;
                        if !v.is_finite() {
                            return Err(err(
                                line_no,
                                Some(name),
                                format!("`{}` is not finite", field.trim()),
                            ));
                        }
                        col.push(v);
                    }
                }
            }
        }
        let Some((header_line, names)) = header else {
            return Err(err(0, None, "no header line".into()));
        };
        let log = RunLog {
            meta,
            names,
            columns,
        };
        if log.len() < MIN_ROWS {
            return Err(err(
                0,
                None,
                format!("{} data rows, at least {MIN_ROWS} needed", log.len()),
            ));
        }
        // Uniform, increasing time within 1 % of the first step.
        let t = log.column("t_s").unwrap_or_default();
        let dt0 = t.get(1).copied().unwrap_or(0.0) - t.first().copied().unwrap_or(0.0);
        if dt0 <= 0.0 {
            return Err(err(
                header_line + 2,
                Some("t_s"),
                "time does not increase".into(),
            ));
        }
        for (i, w) in t.windows(2).enumerate() {
            let dt = w[1] - w[0];
            if (dt - dt0).abs() > 0.01 * dt0 {
                let what = if dt <= 0.0 {
                    "time does not increase"
                } else {
                    "time step is not uniform"
                };
                // Data row i+1 (0-based) is at this file line, skipping comment lines is not
                // needed: data rows follow the header without interruption in valid files.
                return Err(err(
                    data_line(text, header_line, i + 1),
                    Some("t_s"),
                    what.into(),
                ));
            }
        }
        Ok(log)
    }
}

/// File line of the `row`-th data row (0-based) after the header.
fn data_line(text: &str, header_line: usize, row: usize) -> usize {
    text.lines()
        .enumerate()
        .skip(header_line)
        .filter(|(_, l)| !l.starts_with('#') && !l.trim().is_empty())
        .nth(row)
        .map_or(0, |(i, _)| i + 1)
}

/// A map of metadata for quick lookup.
pub fn meta_map(log: &RunLog) -> BTreeMap<&str, &str> {
    log.meta
        .iter()
        .map(|(k, v)| (k.as_str(), v.as_str()))
        .collect()
}

/// One CSV value in its shortest round-trip form: a whole number below 2⁵³ as an integer (a
/// fault code reads `3`, not `3.0`); a value that is exactly an `f32` (what the firmware
/// computes: positions, forces, measured pressures) in the shortest digits that give back
/// that `f32` (`0.1`, not `0.10000000149011612`); anything else in the shortest digits that
/// give back the `f64`. Magnitudes far from 1 take exponent form, which every CSV reader
/// (and pandas) reads. `ryu`/`itoa` do the digits, an order of magnitude faster than
/// `Display` with the same shortest-digit guarantee.
fn format_value<'b>(v: f64, float: &'b mut ryu::Buffer, int: &'b mut itoa::Buffer) -> &'b str {
    const EXACT: f64 = 9_007_199_254_740_992.0; // 2⁵³
                                                // Range first: the conversion below is then exact for whole numbers.
    if v.abs() < EXACT && v == (v as i64) as f64 && !(v == 0.0 && v.is_sign_negative()) {
        int.format(v as i64)
    } else if f64::from(v as f32) == v {
        float.format(v as f32)
    } else {
        float.format(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngCore, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn csv_values_read_back_bit_for_bit() {
        let (mut float, mut int) = (ryu::Buffer::new(), itoa::Buffer::new());
        let mut rng = ChaCha8Rng::seed_from_u64(0x9E37_79B9_7F4A_7C15);
        let mut values = vec![0.0, 3.0, -2.0, 0.1, 1e-7, 2.5e-5, 123_456.789, 1e300, -0.0];
        for _ in 0..10_000 {
            let v = f64::from_bits(rng.next_u64());
            if v.is_finite() {
                values.push(v);
            }
        }
        for v in values {
            let text = format_value(v, &mut float, &mut int).to_string();
            let back: f64 = text.parse().unwrap();
            if f64::from(v as f32) == v {
                // Written to the precision it was computed in: the same f32 comes back.
                assert_eq!(
                    (back as f32).to_bits(),
                    (v as f32).to_bits(),
                    "{v} wrote {text}"
                );
            } else {
                assert_eq!(back.to_bits(), v.to_bits(), "{v} wrote {text}");
            }
            // Writing what was read gives the same text (a file survives a round trip).
            assert_eq!(format_value(back, &mut float, &mut int), text);
        }
        assert_eq!(format_value(f64::from(0.1f32), &mut float, &mut int), "0.1");
        assert_eq!(format_value(3.0, &mut float, &mut int), "3");
        assert_eq!(format_value(0.25, &mut float, &mut int), "0.25");
    }

    fn sample(rows: usize) -> String {
        let mut log = RunLog::with_columns(&REQUIRED);
        log.meta.push(("source".into(), "test".into()));
        for i in 0..rows {
            let t = i as f64 * 1e-4;
            log.push_row(&[t, 0.1, 0.1, 0.0, 1.0, 1.0, 1e5, 1e5]);
        }
        log.to_csv()
    }

    #[test]
    fn round_trips() {
        let text = sample(150);
        let log = RunLog::parse(&text).unwrap();
        assert_eq!(log.len(), 150);
        assert_eq!(log.meta("source"), Some("test"));
        assert_eq!(log.to_csv(), text);
    }

    #[test]
    fn refuses_what_the_contract_names() {
        let text = sample(150);
        let short = sample(50);
        assert!(RunLog::parse(&short)
            .unwrap_err()
            .message
            .contains("at least 100"));
        let no_col = text.replacen("p_b_pa", "p_x", 1);
        let e = RunLog::parse(&no_col).unwrap_err();
        assert_eq!(e.column.as_deref(), Some("p_b_pa"));
        let lines: Vec<&str> = text.lines().collect();
        let mut bad = lines.clone();
        bad[10] = "0.0009,abc,0.1,0,1,1,1e5,1e5";
        let e = RunLog::parse(&bad.join("\n")).unwrap_err();
        assert_eq!((e.line, e.column.as_deref()), (11, Some("x_m")));
        let mut nan = lines.clone();
        nan[10] = "0.0009,NaN,0.1,0,1,1,1e5,1e5";
        assert!(RunLog::parse(&nan.join("\n"))
            .unwrap_err()
            .message
            .contains("not finite"));
        let mut back = lines.clone();
        back[20] = "0.0001,0.1,0.1,0,1,1,1e5,1e5";
        let e = RunLog::parse(&back.join("\n")).unwrap_err();
        assert_eq!((e.line, e.column.as_deref()), (21, Some("t_s")));
        let mut trunc = lines.clone();
        trunc[30] = "0.0029,0.1";
        assert_eq!(RunLog::parse(&trunc.join("\n")).unwrap_err().line, 31);
    }
}
