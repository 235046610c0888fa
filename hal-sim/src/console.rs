//! Printing that fails like everything else, instead of the panic `println!` gives
//! (`docs/faults.md` row 23): a full device (`> /dev/full`) ends the command with exit 1 and one
//! line; a pipe its reader closed (`fpc-sim derive … | head -1`) ends it quietly, exit 0.
//!
//! [`outln!`](crate::outln) writes a line to stdout and [`errln!`](crate::errln) to stderr; both
//! return `Result<(), Failure>` for `?`. [`stdout`] is a writer for bulk output. Tests that
//! drive the tool in-process take what it prints with [`captured`].

use std::cell::RefCell;
use std::io::Write;

use crate::failure::Failure;

thread_local! {
    /// Where this thread's output goes instead of stdout/stderr, while [`captured`] runs.
    static SINK: RefCell<Option<Vec<u8>>> = const { RefCell::new(None) };
}

/// Runs `f` with everything this thread prints through this module collected, and returns
/// its result with the text.
pub fn captured<R>(f: impl FnOnce() -> R) -> (R, String) {
    let previous = SINK.with(|s| s.replace(Some(Vec::new())));
    let result = f();
    let text = SINK.with(|s| s.replace(previous)).unwrap_or_default();
    (result, String::from_utf8_lossy(&text).into_owned())
}

/// Appends to the capture sink if one is set; `false` when none is.
fn to_sink(bytes: &[u8]) -> bool {
    SINK.with(|s| match s.borrow_mut().as_mut() {
        Some(buf) => {
            buf.extend_from_slice(bytes);
            true
        }
        None => false,
    })
}

/// Standard output, or the capture sink in [`captured`].
pub struct Stdout(Option<std::io::StdoutLock<'static>>);

/// The writer for bulk output on stdout (wrap it in a `BufWriter`).
pub fn stdout() -> Stdout {
    if SINK.with(|s| s.borrow().is_some()) {
        Stdout(None)
    } else {
        Stdout(Some(std::io::stdout().lock()))
    }
}

impl Write for Stdout {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match &mut self.0 {
            Some(out) => out.write(buf),
            None => {
                to_sink(buf);
                Ok(buf.len())
            }
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        match &mut self.0 {
            Some(out) => out.flush(),
            None => Ok(()),
        }
    }
}

/// Writes one formatted line to stdout; an error is a runtime failure.
pub fn out_line(args: std::fmt::Arguments<'_>) -> Result<(), Failure> {
    if to_sink(format!("{args}\n").as_bytes()) {
        return Ok(());
    }
    let mut out = std::io::stdout().lock();
    out.write_fmt(args)
        .and_then(|()| out.write_all(b"\n"))
        .and_then(|()| out.flush())
        .map_err(|e| Failure::stdout_error(&e))
}

/// Writes one formatted line to stderr; an error is a runtime failure.
pub fn err_line(args: std::fmt::Arguments<'_>) -> Result<(), Failure> {
    if to_sink(format!("{args}\n").as_bytes()) {
        return Ok(());
    }
    let mut err = std::io::stderr().lock();
    err.write_fmt(args)
        .and_then(|()| err.write_all(b"\n"))
        .map_err(|e| Failure::runtime(format!("cannot write to standard error: {e}")))
}

/// `println!` that returns `Result<(), Failure>` instead of panicking.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => { $crate::console::out_line(format_args!($($arg)*)) };
}

/// `eprintln!` that returns `Result<(), Failure>` instead of panicking.
#[macro_export]
macro_rules! errln {
    ($($arg:tt)*) => { $crate::console::err_line(format_args!($($arg)*)) };
}

/// A number for a table: printed as `f64` with the format's width and precision when finite,
/// as `n/a` when not (an empty window, a constant signal) — never `NaN` or `inf`.
#[derive(Clone, Copy, Debug)]
pub struct Num(pub f64);

/// `n/a` in the format's width and alignment (its precision is the number's, not a cut).
fn not_available(f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
    let w = f.width().unwrap_or(0);
    match f.align() {
        Some(std::fmt::Alignment::Left) => write!(f, "{:<w$}", "n/a"),
        Some(std::fmt::Alignment::Center) => write!(f, "{:^w$}", "n/a"),
        _ => write!(f, "{:>w$}", "n/a"),
    }
}

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.0.is_finite() {
            std::fmt::Display::fmt(&self.0, f)
        } else {
            not_available(f)
        }
    }
}

impl std::fmt::LowerExp for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.0.is_finite() {
            std::fmt::LowerExp::fmt(&self.0, f)
        } else {
            not_available(f)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Num;

    #[test]
    fn undefined_numbers_print_as_n_a() {
        assert_eq!(
            format!("{:>8.2}|{:.3e}", Num(1.234), Num(12.5)),
            "    1.23|1.250e1"
        );
        assert_eq!(
            format!("{:>8.2}|{:.3e}", Num(f64::NAN), Num(f64::INFINITY)),
            "     n/a|n/a"
        );
    }
}
