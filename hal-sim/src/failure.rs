//! The failure every fallible entry point of `fpc-sim` returns: the exit code and the one
//! line to print.
//!
//! Exit codes (`docs/formats.md` §3): 0 success, 1 runtime failure, 2 bad usage or bad input, with
//! one clear line on stderr naming the file, line or flag at fault. The subcommands and the
//! gap workflow share it.

/// A failed subcommand: the exit code and the one line to print.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Failure {
    /// Process exit code (1 runtime, 2 bad input).
    pub code: u8,
    /// The line for stderr.
    pub message: String,
}

impl Failure {
    /// Bad usage or bad input: exit code 2.
    pub fn bad_input(message: impl Into<String>) -> Self {
        Failure {
            code: 2,
            message: message.into(),
        }
    }

    /// A failure while running: exit code 1.
    pub fn runtime(message: impl Into<String>) -> Self {
        Failure {
            code: 1,
            message: message.into(),
        }
    }

    /// Standard output was closed by its reader (`fpc-sim derive … | head -1`): the command
    /// stops, quietly and with exit code 0, as a Unix filter does; the reader had what it
    /// wanted.
    pub fn closed_pipe() -> Self {
        Failure {
            code: 0,
            message: String::new(),
        }
    }

    /// Whether this is [`Failure::closed_pipe`].
    pub fn is_closed_pipe(&self) -> bool {
        self.code == 0 && self.message.is_empty()
    }

    /// A failed write to standard output: quiet when its reader closed the pipe, else a
    /// runtime failure naming the error.
    pub fn stdout_error(e: &std::io::Error) -> Self {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            Failure::closed_pipe()
        } else {
            Failure::runtime(format!("cannot write to standard output: {e}"))
        }
    }
}

/// Result of a subcommand.
pub type CmdResult = Result<(), Failure>;

/// Longest echo of a user's value in a message, characters.
pub const ECHO_CHARS: usize = 40;

/// `text` as echoed in a message: at most [`ECHO_CHARS`] characters, then `…`.
pub fn clip(text: &str) -> String {
    match text.char_indices().nth(ECHO_CHARS) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text.to_string(),
    }
}

/// A number as echoed in a message: as written for ordinary magnitudes, in exponent form
/// when that is shorter (`1e300`, not 301 digits).
pub fn num(v: f64) -> String {
    let plain = format!("{v}");
    let exp = format!("{v:e}");
    if plain.len() <= 12 || plain.len() <= exp.len() {
        plain
    } else {
        exp
    }
}

/// Every `` `…` ``-quoted span of `message` longer than [`ECHO_CHARS`] cut to that length.
pub fn clip_quoted(message: &str) -> String {
    let mut out = String::with_capacity(message.len().min(400));
    for (i, part) in message.split('`').enumerate() {
        if i > 0 {
            out.push('`');
        }
        if i % 2 == 1 {
            // A number toml wrote out in full (`1e300` as 301 digits) in its short form.
            match part.parse::<f64>() {
                Ok(v) if part.len() > 12 => out.push_str(&num(v)),
                _ => out.push_str(&clip(part)),
            }
        } else {
            out.push_str(part);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn echoes_are_short() {
        assert_eq!(num(1e300), "1e300");
        assert_eq!(num(0.205), "0.205");
        assert_eq!(num(-1e-300), "-1e-300");
        assert_eq!(num(f64::NAN), "NaN");
        assert_eq!(num(123456.0), "123456");
        assert_eq!(clip(&"x".repeat(100)).chars().count(), ECHO_CHARS + 1);
        assert_eq!(clip("short"), "short");
        let m = clip_quoted(&format!(
            "unknown field `{}`, expected `a`",
            "y".repeat(500)
        ));
        assert!(m.len() < 80 && m.ends_with("expected `a`"), "{m}");
        let m = clip_quoted(&format!("floating point `1{}.0`", "0".repeat(300)));
        assert_eq!(m, "floating point `1e300`");
    }
}
