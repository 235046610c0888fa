//! The run log (`docs/formats.md` §1): the CSV the rig logs and the simulator writes.
//!
//! Writing is plain formatted text (deterministic: the same values give the same bytes).
//! Reading takes logs as rigs write them — `,`, `;` or tab between the fields (a `;` or tab
//! log may write decimal commas), sample times that jitter and rows a logger dropped,
//! resampled onto the nominal grid with the counts reported ([`grid`]) — and refuses with
//! the line and column at fault: a column the command needs that is missing, non-numeric or
//! non-finite values, time not increasing or too far off its grid, fewer than 100 rows.

pub mod grid;
mod lines;

use lines::{line_error, plain_fields, separator, split_fields, utf8_line, LineReader};

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::{BufRead, BufReader};
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
    /// What the reader did to put the rows on the nominal time grid (`None`: they were).
    pub resampled: Option<grid::Resampled>,
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
            resampled: None,
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
        self.head_to_csv(&mut out);
        self.rows_to_csv(&mut out);
        out
    }

    /// Appends the metadata lines and the header line of the CSV to `out`.
    pub fn head_to_csv(&self, out: &mut String) {
        for (k, v) in &self.meta {
            let _ = writeln!(out, "# {k} = {v}");
        }
        out.push_str(&self.names.join(","));
        out.push('\n');
    }

    /// Appends the data rows of the CSV to `out` (so a long log can be written in chunks that
    /// join to exactly [`RunLog::to_csv`]).
    pub fn rows_to_csv(&self, out: &mut String) {
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
    }

    /// Writes the CSV to `path`.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        std::fs::write(path, self.to_csv())
    }

    /// Reads and validates a run log from `path`, gzipped or not (recognised by the gzip
    /// magic bytes, whatever the file is called). The file is read as a stream: memory
    /// grows with the values accepted, and a file that is not a run log (no line breaks,
    /// binary, endless) is refused at its first bad line.
    pub fn read(path: &Path) -> Result<RunLog, LogError> {
        Self::read_needing(path, &REQUIRED)
    }

    /// [`RunLog::read`] for a command that needs only the columns `needs` (`t_s` always):
    /// a log without the others is read.
    pub fn read_needing(path: &Path, needs: &[&str]) -> Result<RunLog, LogError> {
        let fail = |what: String| LogError {
            line: 0,
            column: None,
            message: format!("cannot read {}: {what}", path.display()),
        };
        if path.is_dir() {
            return Err(fail("it is a directory".into()));
        }
        let file = std::fs::File::open(path).map_err(|e| fail(e.to_string()))?;
        let mut reader = BufReader::with_capacity(1 << 16, file);
        let gzipped = reader
            .fill_buf()
            .map_err(|e| fail(e.to_string()))?
            .starts_with(&GZIP_MAGIC);
        if gzipped {
            let gz = BufReader::with_capacity(1 << 16, flate2::read::MultiGzDecoder::new(reader));
            Self::parse_stream(gz, true, needs)
        } else {
            Self::parse_stream(reader, false, needs)
        }
    }

    /// Parses and validates run-log text.
    pub fn parse(text: &str) -> Result<RunLog, LogError> {
        Self::parse_stream(text.as_bytes(), false, &REQUIRED)
    }

    /// [`RunLog::parse`] needing only the columns `needs` (and `t_s`).
    pub fn parse_needing(text: &str, needs: &[&str]) -> Result<RunLog, LogError> {
        Self::parse_stream(text.as_bytes(), false, needs)
    }

    /// Parses and validates a run log line by line, as pandas `read_csv(comment='#')` reads
    /// it: `\n`, `\r\n` or `\r` line ends, an optional UTF-8 byte-order mark, fields in
    /// double quotes, `#` starting a comment anywhere; the fields separated by the header's
    /// separator (`,`, else `;`, else tab). Refused, naming the line (and column): lines
    /// longer than [`MAX_LINE_BYTES`], text that is not UTF-8, a column of `needs` missing or
    /// a column duplicated, metadata keys given twice with different values, a
    /// `sample_rate_hz` the time column contradicts, values that are not numbers, not finite
    /// or outside [`physical_range`], time not increasing, a step outside
    /// [`SAMPLE_TIME_RANGE_S`], rows too far off the grid or too many missing ([`grid`]),
    /// fewer than [`MIN_ROWS`] or more than [`MAX_VALUES`] values.
    fn parse_stream(
        source: impl BufRead,
        gzipped: bool,
        needs: &[&str],
    ) -> Result<RunLog, LogError> {
        let mut lines = LineReader::new(source);
        let Head {
            meta,
            meta_lines,
            header,
            sep,
        } = read_head(&mut lines, gzipped, needs)?;
        let Some((_, names)) = header else {
            return Err(log_error(0, None, "no header line".into()));
        };
        let mut columns: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
        let mut time = TimeCheck::default();
        read_rows(&mut lines, gzipped, &names, sep, &mut columns, &mut time)?;
        let time_col = names.iter().position(|n| n == "t_s");
        let mut log = RunLog {
            meta,
            names,
            columns,
            resampled: None,
        };
        if let Some(i) = time_col {
            log.place_on_grid(i, &time.lines)?;
        }
        if log.len() < MIN_ROWS {
            return Err(log_error(
                0,
                None,
                format!("{} data rows, at least {MIN_ROWS} needed", log.len()),
            ));
        }
        check_sample_rate(&log, &meta_lines)?;
        Ok(log)
    }
}

/// A refusal of a run log at `line` (0: the whole log), in `column` if one is named.
fn log_error(line: usize, column: Option<&str>, message: String) -> LogError {
    LogError {
        line,
        column: column.map(str::to_string),
        message,
    }
}

/// What a run log's lines up to its header give: the metadata (`# key = value`, with the
/// line each was first given on), the header (its line and column names; `None` when the
/// log ends before one) and its field separator.
struct Head {
    meta: Vec<(String, String)>,
    meta_lines: Vec<usize>,
    header: Option<(usize, Vec<String>)>,
    sep: u8,
}

/// Reads the lines up to and including the header: comment lines are metadata where they
/// hold `key = value` (a key given twice with different values is refused), blank lines
/// are skipped, and the header must name `t_s` and every column of `needs`, each once.
fn read_head<R: BufRead>(
    lines: &mut LineReader<R>,
    gzipped: bool,
    needs: &[&str],
) -> Result<Head, LogError> {
    let mut head = Head {
        meta: Vec::new(),
        meta_lines: Vec::new(),
        header: None,
        sep: b',',
    };
    let mut fields: Vec<String> = Vec::new();
    while head.header.is_none() {
        let line_no = lines.line_no + 1;
        let raw = match lines.next_line() {
            Ok(Some(raw)) => raw,
            Ok(None) => break,
            Err(e) => return Err(line_error(line_no, e, gzipped)),
        };
        let mut line = utf8_line(raw, line_no)?;
        if line_no == 1 {
            line = line.strip_prefix('\u{feff}').unwrap_or(line);
        }
        if let Some(rest) = line.trim_start().strip_prefix('#') {
            head.meta_line(rest, line_no)?;
            continue;
        }
        head.sep = separator(line);
        split_fields(line, head.sep, &mut fields).map_err(|m| log_error(line_no, None, m))?;
        if fields.len() == 1 && fields.first().is_some_and(|f| f.trim().is_empty()) {
            continue; // a blank line, or one that is all comment
        }
        let names: Vec<String> = fields.iter().map(|f| f.trim().to_string()).collect();
        check_header(&names, needs, line_no)?;
        head.header = Some((line_no, names));
    }
    Ok(head)
}

impl Head {
    /// A comment line before the header, `rest` after its `#`, on line `line_no`: a
    /// `key = value` is kept (once; again with another value is refused).
    fn meta_line(&mut self, rest: &str, line_no: usize) -> Result<(), LogError> {
        let Some((k, v)) = rest.split_once('=') else {
            return Ok(());
        };
        let (k, v) = (k.trim(), v.trim());
        if let Some(i) = self.meta.iter().position(|(mk, _)| mk == k) {
            let first = self.meta_lines.get(i).copied().unwrap_or(0);
            let value = self.meta.get(i).map_or("", |(_, mv)| mv.as_str());
            if value != v {
                return Err(log_error(
                    line_no,
                    None,
                    format!(
                        "`# {}` given twice with different values (line {first}: `{}`, here: \
                         `{}`)",
                        echo(k),
                        echo(value),
                        echo(v)
                    ),
                ));
            }
        } else {
            self.meta.push((k.to_string(), v.to_string()));
            self.meta_lines.push(line_no);
        }
        Ok(())
    }
}

/// The header's column `names` on line `line_no`: each once, `t_s` and every column of
/// `needs` among them.
fn check_header(names: &[String], needs: &[&str], line_no: usize) -> Result<(), LogError> {
    for (i, name) in names.iter().enumerate() {
        if let Some(j) = names.iter().skip(i + 1).position(|n| n == name) {
            return Err(log_error(
                line_no,
                Some(&echo(name)),
                format!("column given twice (fields {} and {})", i + 1, i + j + 2),
            ));
        }
    }
    for req in std::iter::once(&"t_s").chain(needs) {
        if !names.iter().any(|n| n == req) {
            let mut wanted: Vec<&str> = vec!["t_s"];
            wanted.extend(needs.iter().filter(|n| **n != "t_s"));
            return Err(log_error(
                line_no,
                Some(req),
                format!(
                    "required column is missing (this command reads {}; the header has: {})",
                    wanted.join(", "),
                    echo(&names.join(","))
                ),
            ));
        }
    }
    Ok(())
}

/// Reads the data rows after the header (columns `names`, fields separated by `sep`) into
/// `columns`, the time column checked by `time`.
fn read_rows<R: BufRead>(
    lines: &mut LineReader<R>,
    gzipped: bool,
    names: &[String],
    sep: u8,
    columns: &mut [Vec<f64>],
    time: &mut TimeCheck,
) -> Result<(), LogError> {
    let ranges: Vec<(f64, f64)> = names.iter().map(|n| physical_range(n)).collect();
    let time_col = names.iter().position(|n| n == "t_s");
    let mut rows = RowBatch::default();
    // The data rows, a batch at a time: each batch is parsed on every core while the
    // next one is read (reading is one thread's work, a third of the whole); then its
    // values are taken in file order, so the result and the first error named are those
    // of reading the rows one at a time.
    let mut stop = read_batch(lines, gzipped, &mut rows);
    // Two batches take turns (their buffers reused: no fresh memory per batch).
    let mut next = RowBatch::default();
    loop {
        next.text.clear();
        next.lines.clear();
        let mut parsed = Vec::new();
        let mut next_stop = None;
        if stop.is_none() {
            // The stream stays on this thread (it need not be `Send`).
            rayon::in_place_scope(|scope| {
                scope.spawn(|_| parsed = rows.parse(names, &ranges, sep));
                next_stop = read_batch(&mut *lines, gzipped, &mut next);
            });
        } else {
            parsed = rows.parse(names, &ranges, sep);
        }
        rows.take(parsed, names, columns, time, time_col)?;
        if let Some(end) = stop {
            return end;
        }
        std::mem::swap(&mut rows, &mut next);
        stop = next_stop;
    }
}

/// A `# sample_rate_hz` of `log` (stated on the line `meta_lines` gives) must be a
/// positive number within 1 % of the rate its time column steps at.
fn check_sample_rate(log: &RunLog, meta_lines: &[usize]) -> Result<(), LogError> {
    if let Some(i) = log.meta.iter().position(|(k, _)| k == "sample_rate_hz") {
        let rate = log.meta.get(i).map_or("", |(_, v)| v.as_str());
        let line = meta_lines.get(i).copied().unwrap_or(0);
        let stated: f64 = rate.parse().map_err(|_| {
            log_error(
                line,
                None,
                format!("`# sample_rate_hz = {}` is not a number", echo(rate)),
            )
        })?;
        let step_s = log.sample_time_s().unwrap_or(f64::NAN);
        let from_t = 1.0 / step_s;
        if !(stated.is_finite() && stated > 0.0) || (stated - from_t).abs() > 0.01 * from_t {
            return Err(log_error(
                line,
                Some("t_s"),
                format!(
                    "`# sample_rate_hz = {}` contradicts the time column (step {:e} s = \
                         {from_t:.6} Hz)",
                    echo(rate),
                    step_s
                ),
            ));
        }
    }
    Ok(())
}

/// Longest line a run log may have, bytes (a header of hundreds of columns fits).
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Most values (rows × columns) a reader accepts: 1.6 GB of `f64`, e.g. 10⁷ rows of 20
/// columns (8 minutes at 20 kHz).
pub const MAX_VALUES: usize = 200_000_000;

/// Sample times a run log may have, s: 10 MHz down to 10 Hz. Outside, it is not a log of a
/// machine that strokes at 5–50 Hz, and the analyses' cost would follow its duration.
pub const SAMPLE_TIME_RANGE_S: (f64, f64) = (1e-7, 0.1);

/// The values a column can physically hold, by its name (the required columns and the
/// optional ones of `docs/formats.md` by unit; any other column within ±1e15, so that squares and
/// sums of a whole log stay finite).
pub fn physical_range(column: &str) -> (f64, f64) {
    match column {
        // A week of logging.
        "t_s" => (-1e6, 1e6),
        // Metres: a machine of this kind is well under a metre; 10 m leaves room for offsets.
        "x_m" | "x_slave_m" | "x_ref_m" => (-10.0, 10.0),
        // Unwrapped turns: a week at 100 Hz.
        "theta_rad" | "theta_ref_rad" => (-1e9, 1e9),
        // Newtons: ten times the largest linear motors made.
        "f_master_n" | "f_slave_n" => (-1e7, 1e7),
        // Absolute pascals: vacuum (a little below, for sensor offsets) to 10 kbar.
        "p_a_pa" | "p_b_pa" | "p_suction_pa" | "p_discharge_pa" => (-1e5, 1e9),
        "v_drive_mps" => (-1e3, 1e3),
        _ => (-1e15, 1e15),
    }
}

/// A value echoed in a message, cut to 40 characters.
fn echo(text: &str) -> String {
    crate::output::clip(text, 40)
}

/// The time column's check, one value at a time: increasing, the first step within
/// [`SAMPLE_TIME_RANGE_S`]; each row's line kept for [`RunLog::place_on_grid`]'s refusals.
#[derive(Default)]
struct TimeCheck {
    prev: Option<f64>,
    /// The line of each data row.
    lines: Vec<u32>,
}

impl TimeCheck {
    fn next(&mut self, t: f64, line: usize) -> Result<(), String> {
        self.lines.push(u32::try_from(line).unwrap_or(u32::MAX));
        let Some(prev) = self.prev.replace(t) else {
            return Ok(());
        };
        let dt = t - prev;
        if dt <= 0.0 {
            return Err("time does not increase".into());
        }
        if self.lines.len() == 2 {
            let (lo, hi) = SAMPLE_TIME_RANGE_S;
            if !(lo..=hi).contains(&dt) {
                return Err(format!(
                    "time step {dt:e} s is outside the range a run log may have \
                     ({lo:e}..={hi:e} s)"
                ));
            }
        }
        Ok(())
    }
}

impl RunLog {
    /// Puts the rows on the log's nominal time grid ([`grid::place`]): unchanged when they
    /// are on it, else every column resampled and [`RunLog::resampled`] saying how.
    fn place_on_grid(&mut self, time_col: usize, lines: &[u32]) -> Result<(), LogError> {
        let t = self.columns.get(time_col).cloned().unwrap_or_default();
        let placed = grid::place(&t).map_err(|(row, message)| LogError {
            line: if row == 0 {
                0
            } else {
                lines.get(row).map_or(0, |&l| l as usize)
            },
            column: Some("t_s".into()),
            message,
        })?;
        let Some(g) = placed else {
            return Ok(());
        };
        for (i, col) in self.columns.iter_mut().enumerate() {
            *col = if i == time_col {
                g.times()
            } else {
                g.resample(&t, col)
            };
        }
        self.resampled = Some(g.report);
        Ok(())
    }
}

/// Data rows read but not parsed yet: their text, one after the other, and each row's line
/// number and span. Parsing (splitting, number conversion, range checks) is most of the cost
/// of reading a long log and is independent from row to row, so a batch is parsed on every
/// core; what depends on the order (the time check, the value count, which error comes
/// first) is then done row by row, so the result and the first error named are those of
/// reading the rows one at a time.
#[derive(Default)]
struct RowBatch {
    text: String,
    lines: Vec<(usize, std::ops::Range<usize>)>,
}

/// A data row parsed: blank (skipped), or its values (or the first bad one, which is named
/// only after the value count is checked, as one-at-a-time reading does).
enum ParsedRow {
    Blank,
    Values(Result<Vec<f64>, LogError>),
}

impl RowBatch {
    /// Rows per batch.
    const ROWS: usize = 16_384;

    fn push(&mut self, line_no: usize, line: &str) {
        let start = self.text.len();
        self.text.push_str(line);
        self.lines.push((line_no, start..self.text.len()));
    }

    /// Parses the batch's rows (fields separated by `sep`), on every core.
    fn parse(
        &self,
        names: &[String],
        ranges: &[(f64, f64)],
        sep: u8,
    ) -> Vec<Result<ParsedRow, LogError>> {
        use rayon::prelude::*;
        self.lines
            .par_iter()
            .map(|(line_no, span)| {
                parse_row(
                    self.text.get(span.clone()).unwrap_or_default(),
                    *line_no,
                    names,
                    ranges,
                    sep,
                )
            })
            .collect()
    }

    /// Appends the batch's rows as [`RowBatch::parse`] gave them to `columns` in order; the
    /// first refusal in file order is returned.
    fn take(
        &self,
        parsed: Vec<Result<ParsedRow, LogError>>,
        names: &[String],
        columns: &mut [Vec<f64>],
        time: &mut TimeCheck,
        time_col: Option<usize>,
    ) -> Result<(), LogError> {
        for ((line_no, _), row) in self.lines.iter().zip(parsed) {
            let values = match row? {
                ParsedRow::Blank => continue,
                ParsedRow::Values(v) => v,
            };
            if columns.first().map_or(0, Vec::len) * names.len() >= MAX_VALUES {
                return Err(LogError {
                    line: *line_no,
                    column: None,
                    message: format!(
                        "more than {MAX_VALUES} values: too large to analyse at once \
                         (cut the log into parts)"
                    ),
                });
            }
            for (col, v) in columns.iter_mut().zip(values?) {
                col.push(v);
            }
            // The time after the whole row read: a bad value names its own column.
            if let Some(&t) = time_col.and_then(|i| columns.get(i)).and_then(|c| c.last()) {
                time.next(t, *line_no).map_err(|message| LogError {
                    line: *line_no,
                    column: Some("t_s".into()),
                    message,
                })?;
            }
        }
        Ok(())
    }
}

/// Reads data lines into `batch` until it holds [`RowBatch::ROWS`] (`None`: there may be
/// more), or to the end of the stream (`Some(Ok)`) or a line that cannot be read
/// (`Some(Err)`, after the rows before it). Comment lines are skipped: after the header
/// they carry nothing.
fn read_batch<R: BufRead>(
    lines: &mut LineReader<R>,
    gzipped: bool,
    batch: &mut RowBatch,
) -> Option<Result<(), LogError>> {
    while batch.lines.len() < RowBatch::ROWS {
        let line_no = lines.line_no + 1;
        let raw = match lines.next_line() {
            Ok(Some(raw)) => raw,
            Ok(None) => return Some(Ok(())),
            Err(e) => return Some(Err(line_error(line_no, e, gzipped))),
        };
        let line = match utf8_line(raw, line_no) {
            Ok(line) => line,
            Err(e) => return Some(Err(e)),
        };
        if line.trim_start().starts_with('#') {
            continue;
        }
        batch.push(line_no, line);
    }
    None
}

/// One data row's fields as numbers, checked against the columns' physical ranges.
fn parse_row(
    line: &str,
    line_no: usize,
    names: &[String],
    ranges: &[(f64, f64)],
    sep: u8,
) -> Result<ParsedRow, LogError> {
    let err = |column: Option<&str>, message: String| LogError {
        line: line_no,
        column: column.map(str::to_string),
        message,
    };
    // The common row has no quotes: its fields are slices of the line (no copy per field,
    // which was a third of the reading's cost on a long log); a quoted one is unquoted first.
    let mut unquoted = Vec::new();
    let fields: Vec<&str> = if line.as_bytes().contains(&b'"') {
        split_fields(line, sep, &mut unquoted).map_err(|m| err(None, m))?;
        unquoted.iter().map(String::as_str).collect()
    } else {
        plain_fields(line, names.len(), sep)
    };
    if fields.len() == 1 && fields.first().is_some_and(|f| f.trim().is_empty()) {
        return Ok(ParsedRow::Blank); // a blank line, or one that is all comment
    }
    if fields.len() != names.len() {
        return Err(err(
            None,
            format!("expected {} fields, found {}", names.len(), fields.len()),
        ));
    }
    let values = fields
        .iter()
        .zip(names)
        .zip(ranges)
        .map(|((field, name), &(lo, hi))| {
            let text = field.trim();
            // A log separated by `;` or tabs may write a decimal comma (`0,25`).
            let decimal;
            let text = if sep != b',' && text.contains(',') {
                decimal = text.replace(',', ".");
                decimal.as_str()
            } else {
                text
            };
            let v: f64 = text
                .parse()
                .map_err(|_| err(Some(name), format!("`{}` is not a number", echo(text))))?;
            if !v.is_finite() {
                return Err(err(Some(name), format!("`{}` is not finite", echo(text))));
            }
            if !(lo..=hi).contains(&v) {
                return Err(err(
                    Some(name),
                    format!("{v:e} is outside the physical range {lo:e}..={hi:e}"),
                ));
            }
            Ok(v)
        })
        .collect();
    Ok(ParsedRow::Values(values))
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

#[cfg(test)]
mod contract_tests {
    use super::*;

    fn sample(rows: usize, end: &str) -> String {
        let mut text = String::from("# source = test\n# sample_rate_hz = 10000\n");
        text.push_str(&REQUIRED.join(","));
        text.push('\n');
        for i in 0..rows {
            let t = i as f64 * 1e-4;
            text.push_str(&format!("{t},0.1,0.1,0,1,1,1e5,1e5"));
            text.push_str(end);
        }
        text
    }

    #[test]
    fn reads_what_pandas_reads() {
        let plain = RunLog::parse(&sample(120, "\n")).unwrap();
        for variant in [
            format!("\u{feff}{}", sample(120, "\n")),
            sample(120, "\r"),
            sample(120, "\r\n"),
            sample(120, "\n").replacen("t_s,x_m", "\"t_s\",\"x_m\"", 1),
            sample(120, "\n").replace(",0.1,0.1,", ",\"0.1\",0.1,"),
            sample(120, " # a note\n"),
            sample(120, "\n\n"),
        ] {
            let log = RunLog::parse(&variant).unwrap_or_else(|e| panic!("{e}: {variant:.200}"));
            assert_eq!(log.columns, plain.columns);
            assert_eq!(log.names, plain.names);
        }
    }

    #[test]
    fn refuses_naming_the_real_cause() {
        let ok = sample(120, "\n");
        let cases: [(String, &str); 9] = [
            (
                ok.replacen("p_a_pa,p_b_pa", "p_a_pa,p_a_pa", 1),
                "given twice",
            ),
            (format!("# ports = open\n# ports = closed\n{ok}"), "line 1"),
            (ok.replacen("10000", "20000", 1), "contradicts"),
            (
                ok.replacen("0.0001,0.1", "0.0001,1e20", 1),
                "physical range",
            ),
            (
                ok.replacen("\n0.0001,", "\n0.0000000000001,", 1),
                "outside the range",
            ),
            (ok.replacen("0.0001,0.1", "0.0001,\"0.1", 1), "quoted field"),
            (
                format!("{}\n", "1".repeat(MAX_LINE_BYTES + 10)),
                "longer than",
            ),
            (
                ok.replacen("0.0002,0.1", "0.0002,0.1\u{0}", 1),
                "not a number",
            ),
            (
                ok.replacen("theta_rad", "theta_rad,theta_rad", 1),
                "given twice",
            ),
        ];
        for (text, expected) in cases {
            let e = RunLog::parse(&text).unwrap_err();
            assert!(
                e.to_string().contains(expected),
                "{e} (wanted `{expected}`)"
            );
        }
        let mut bytes = ok.clone().into_bytes();
        let at = ok.find("0.0003").unwrap();
        bytes[at] = 0xff;
        let scratch = tempfile::tempdir().unwrap();
        let path = scratch.path().join("not-utf8.csv");
        std::fs::write(&path, &bytes).unwrap();
        let e = RunLog::read(&path).unwrap_err();
        assert!(e.line > 3 && e.message.contains("UTF-8"), "{e}");
    }

    /// The data lines of `text` with `f` applied (metadata lines as they are).
    fn rows_mapped(text: &str, f: impl Fn(&str) -> String) -> String {
        text.lines()
            .map(|l| {
                if l.starts_with('#') {
                    format!("{l}\n")
                } else {
                    format!("{}\n", f(l))
                }
            })
            .collect()
    }

    #[test]
    fn reads_semicolons_tabs_and_decimal_commas() {
        let text = sample(120, "\n");
        let plain = RunLog::parse(&text).unwrap();
        for (what, variant) in [
            ("`;`", rows_mapped(&text, |l| l.replace(',', ";"))),
            (
                "`;` with decimal commas",
                rows_mapped(&text, |l| l.replace(',', ";").replace('.', ",")),
            ),
            ("tab", rows_mapped(&text, |l| l.replace(',', "\t"))),
        ] {
            let log = RunLog::parse(&variant).unwrap_or_else(|e| panic!("{what}: {e}"));
            assert_eq!(log.names, plain.names, "{what}");
            assert_eq!(log.columns, plain.columns, "{what}");
        }
    }

    #[test]
    fn a_command_reads_a_log_holding_only_the_columns_it_needs() {
        let mut text = String::from("t_s,f_master_n,f_slave_n\n");
        for i in 0..150 {
            text.push_str(&format!("{},{},{}\n", i as f64 * 1e-4, i, i + 1));
        }
        let log = RunLog::parse_needing(&text, &["f_master_n", "f_slave_n"]).unwrap();
        assert_eq!(log.len(), 150);
        let e = RunLog::parse(&text).unwrap_err();
        assert_eq!(e.column.as_deref(), Some("x_m"));
        assert!(e.message.contains("this command reads t_s, x_m"), "{e}");
    }

    #[test]
    fn jitter_and_dropped_rows_are_put_on_the_grid_and_counted() {
        let mut text = String::from("# sample_rate_hz = 10000\n");
        text.push_str(&REQUIRED.join(","));
        text.push('\n');
        for i in 0..1000 {
            if [200, 500, 501].contains(&i) {
                continue;
            }
            // ±2 µs of jitter on a 100 µs step; x = 1 m/s × t, so the grid's x is its t.
            let t = i as f64 * 1e-4 + if i % 2 == 0 { 2e-6 } else { -2e-6 };
            text.push_str(&format!("{t},{t},{t},0,{},1,1e5,1e5\n", i % 3));
        }
        let log = RunLog::parse(&text).unwrap();
        let r = log.resampled.expect("resampled");
        assert_eq!((log.len(), r.filled, r.rows_read), (1000, 3, 997));
        let (t, x) = (log.column("t_s").unwrap(), log.column("x_m").unwrap());
        for (k, (t, x)) in t.iter().zip(x).enumerate().skip(1).take(997) {
            assert!((t - x).abs() < 1e-9, "row {k}: t {t} x {x}");
        }
        // A code column is held, never a fraction.
        assert!(log
            .column("f_master_n")
            .unwrap()
            .iter()
            .all(|v| v.fract() == 0.0));
        // Past the limit: the refusal names the line and both steps.
        let mut gap = String::from(&REQUIRED.join(","));
        gap.push('\n');
        for i in (0..300).filter(|i| !(100..105).contains(i)) {
            gap.push_str(&format!("{},0,0,0,0,0,1e5,1e5\n", i as f64 * 1e-4));
        }
        let e = RunLog::parse(&gap).unwrap_err();
        assert_eq!((e.line, e.column.as_deref()), (102, Some("t_s")), "{e}");
        assert!(
            e.message.contains("600 µs where the log's step is 100 µs"),
            "{e}"
        );
    }

    #[test]
    fn an_endless_stream_without_line_breaks_is_refused_at_line_1() {
        let e = RunLog::read(Path::new("/dev/zero")).unwrap_err();
        assert_eq!(e.line, 1, "{e}");
        assert!(e.message.contains("longer than"), "{e}");
    }
}
