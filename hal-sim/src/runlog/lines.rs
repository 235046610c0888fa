//! The text of a run log as pandas `read_csv` reads it: lines ending in `\n`, `\r\n` or
//! `\r` (each at most [`MAX_LINE_BYTES`]), UTF-8, fields split at the header's separator
//! with double quotes and `#` comments.

use std::io::BufRead;

use super::{LogError, MAX_LINE_BYTES};

/// The refusal of a line [`LineReader`] could not read.
pub(super) fn line_error(line_no: usize, e: LineError, gzipped: bool) -> LogError {
    let message = match e {
        LineError::TooLong => format!("longer than {MAX_LINE_BYTES} bytes: not a run log"),
        LineError::Io(e) if gzipped => format!("not a valid gzip stream ({e})"),
        LineError::Io(e) => format!("cannot read on ({e})"),
    };
    LogError {
        line: line_no,
        column: None,
        message,
    }
}

/// A line's bytes as text, or the refusal naming its first byte that is not UTF-8.
pub(super) fn utf8_line(raw: &[u8], line_no: usize) -> Result<&str, LogError> {
    std::str::from_utf8(raw).map_err(|e| LogError {
        line: line_no,
        column: None,
        message: format!(
            "not UTF-8 text (invalid byte at column {})",
            e.valid_up_to() + 1
        ),
    })
}

/// The separator of a log, from its header line: `,` when it has one, else `;` when it has
/// one, else a tab when it has one, else `,` (a single column).
pub(super) fn separator(header: &str) -> u8 {
    [b',', b';', b'\t']
        .into_iter()
        .find(|&c| header.as_bytes().contains(&c))
        .unwrap_or(b',')
}

/// The fields of a line without quotes: the separator's pieces up to a comment (`#`), as
/// [`split_fields`] gives them, found byte by byte (both are ASCII, so every piece is whole
/// UTF-8; the `str` searchers cost a tenth of reading a long log).
pub(super) fn plain_fields(line: &str, expected: usize, sep: u8) -> Vec<&str> {
    let body = match line.bytes().position(|b| b == b'#') {
        Some(i) => line.get(..i).unwrap_or_default(),
        None => line,
    };
    let mut out = Vec::with_capacity(expected);
    let mut start = 0;
    for (i, b) in body.bytes().enumerate() {
        if b == sep {
            out.push(body.get(start..i).unwrap_or_default());
            start = i + 1;
        }
    }
    out.push(body.get(start..).unwrap_or_default());
    out
}

/// Splits a CSV line into `fields`: `sep` outside double quotes separates; quotes are
/// removed (`""` inside quotes is one quote); `#` outside quotes starts a comment.
pub(super) fn split_fields(line: &str, sep: u8, fields: &mut Vec<String>) -> Result<(), String> {
    fields.clear();
    let sep = char::from(sep);
    if !line.contains('"') {
        // The common line: no quotes, so the fields are the separator's pieces up to a
        // comment.
        let body = line.split('#').next().unwrap_or_default();
        fields.extend(body.split(sep).map(str::to_string));
        return Ok(());
    }
    let mut field = String::new();
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                chars.next();
                field.push('"');
            }
            ('"', true) => quoted = false,
            ('"', false) => quoted = true,
            (c, false) if c == sep => fields.push(std::mem::take(&mut field)),
            ('#', false) => break,
            (c, _) => field.push(c),
        }
    }
    if quoted {
        return Err("a quoted field is not closed".into());
    }
    fields.push(field);
    Ok(())
}

/// Why [`LineReader`] stopped.
pub(super) enum LineError {
    TooLong,
    Io(std::io::Error),
}

/// Lines of a byte stream ending in `\n`, `\r\n` or `\r`, each at most [`MAX_LINE_BYTES`].
pub(super) struct LineReader<R> {
    source: R,
    line: Vec<u8>,
    /// The last line ended in `\r`: a `\n` right after it belongs to it.
    after_cr: bool,
    /// Lines returned so far.
    pub(super) line_no: usize,
}

impl<R: BufRead> LineReader<R> {
    pub(super) fn new(source: R) -> Self {
        LineReader {
            source,
            line: Vec::new(),
            after_cr: false,
            line_no: 0,
        }
    }

    /// The next line without its end, or `None` at the end of the stream.
    pub(super) fn next_line(&mut self) -> Result<Option<&[u8]>, LineError> {
        self.line.clear();
        loop {
            let buf = match self.source.fill_buf() {
                Ok(b) => b,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(LineError::Io(e)),
            };
            if buf.is_empty() {
                if self.line.is_empty() {
                    return Ok(None);
                }
                self.line_no += 1;
                return Ok(Some(&self.line));
            }
            let start = usize::from(self.after_cr && buf.first() == Some(&b'\n'));
            self.after_cr = false;
            let rest = buf.get(start..).unwrap_or_default();
            match rest.iter().position(|&b| b == b'\n' || b == b'\r') {
                Some(i) => {
                    if self.line.len() + i > MAX_LINE_BYTES {
                        return Err(LineError::TooLong);
                    }
                    self.line
                        .extend_from_slice(rest.get(..i).unwrap_or_default());
                    self.after_cr = rest.get(i) == Some(&b'\r');
                    self.source.consume(start + i + 1);
                    self.line_no += 1;
                    return Ok(Some(&self.line));
                }
                None => {
                    if self.line.len() + rest.len() > MAX_LINE_BYTES {
                        return Err(LineError::TooLong);
                    }
                    self.line.extend_from_slice(rest);
                    let n = buf.len();
                    self.source.consume(n);
                }
            }
        }
    }
}
