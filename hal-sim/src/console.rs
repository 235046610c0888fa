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

/// `value` in engineering notation with its unit: a mantissa of 1 to 999 with four
/// significant digits (trailing zeros dropped) and an SI prefix, `998.7 µs`, `3.227 N`,
/// `1 kHz`, `-12.5 kPa`; `n/a` when not finite. A unit written with a prefix of its own
/// (`mm`, `kPa`) is not re-prefixed: give it in the base unit.
pub fn eng(value: f64, unit: &str) -> String {
    eng_digits(value, unit, 4)
}

/// [`eng`] with `digits` significant digits (1–17).
pub fn eng_digits(value: f64, unit: &str, digits: usize) -> String {
    const PREFIXES: [(i32, &str); 11] = [
        (-18, "a"),
        (-15, "f"),
        (-12, "p"),
        (-9, "n"),
        (-6, "µ"),
        (-3, "m"),
        (0, ""),
        (3, "k"),
        (6, "M"),
        (9, "G"),
        (12, "T"),
    ];
    if !value.is_finite() {
        return "n/a".to_string();
    }
    let space = if unit.is_empty() { "" } else { " " };
    if value == 0.0 {
        return format!("0{space}{unit}");
    }
    let digits = digits.clamp(1, 17);
    // Rounded to its digits first: 999.96 becomes 1 k, not 1000.
    let exp10 = value.abs().log10().floor() as i32;
    let scale = 10f64.powi(digits as i32 - 1 - exp10);
    let rounded = (value * scale).round() / scale;
    let exp10 = rounded.abs().log10().floor() as i32;
    let exp3 = (exp10.div_euclid(3) * 3).clamp(-18, 12);
    let prefix = PREFIXES
        .iter()
        .find(|(e, _)| *e == exp3)
        .map_or("", |(_, p)| *p);
    let mantissa = rounded / 10f64.powi(exp3);
    let decimals = (digits as i32 - 1 - (exp10 - exp3)).max(0) as usize;
    let mut text = format!("{mantissa:.decimals$}");
    if text.contains('.') {
        text = text.trim_end_matches('0').trim_end_matches('.').to_string();
    }
    format!("{text}{space}{prefix}{unit}")
}

/// `value ± sigma` in engineering notation with its unit, both written to the digit the
/// uncertainty supports: `sigma` to one significant digit (two when that digit would be a 1:
/// `0.14`, not `0.1`), `value` rounded to the same decimal place, one SI prefix for both —
/// `79.4 ± 0.3 N`, `750.07 ± 0.02 µs`, `1.23 ± 0.03 kN`. Without a usable `sigma` (not
/// finite or not positive) the value alone, as [`eng`].
pub fn eng_pm(value: f64, sigma: f64, unit: &str) -> String {
    if !value.is_finite() || !sigma.is_finite() || sigma <= 0.0 {
        return eng(value, unit);
    }
    let place = |s: f64| {
        let e = s.log10().floor() as i32;
        let lead = s / 10f64.powi(e);
        // The last kept digit's power of ten.
        if lead < 1.95 {
            e - 1
        } else {
            e
        }
    };
    let mut q = place(sigma);
    let mut sig = (sigma / 10f64.powi(q)).round() * 10f64.powi(q);
    // Rounding may carry into a new leading digit (0.96 → 1.0): take the rule again.
    if place(sig) != q {
        q = place(sig);
        sig = (sigma / 10f64.powi(q)).round() * 10f64.powi(q);
    }
    let val = (value / 10f64.powi(q)).round() * 10f64.powi(q);
    let top = val.abs().max(sig);
    let exp3 = ((top.log10().floor() as i32).div_euclid(3) * 3).clamp(-18, 12);
    let prefix = match exp3 {
        -18 => "a",
        -15 => "f",
        -12 => "p",
        -9 => "n",
        -6 => "µ",
        -3 => "m",
        3 => "k",
        6 => "M",
        9 => "G",
        12 => "T",
        _ => "",
    };
    let decimals = (exp3 - q).max(0) as usize;
    let k = 10f64.powi(exp3);
    let space = if unit.is_empty() && prefix.is_empty() {
        ""
    } else {
        " "
    };
    // `-0.0` prints as `0`.
    let v = val / k + 0.0;
    format!(
        "{v:.decimals$} ± {:.decimals$}{space}{prefix}{unit}",
        sig / k
    )
}

#[cfg(test)]
mod tests {
    use super::{eng, eng_digits, eng_pm, Num};

    #[test]
    fn a_value_is_written_to_the_digit_its_uncertainty_supports() {
        // The same value, three uncertainties: three precisions.
        assert_eq!(eng_pm(79.4321, 0.31, "N"), "79.4 ± 0.3 N");
        assert_eq!(eng_pm(79.4321, 0.0031, "N"), "79.432 ± 0.003 N");
        assert_eq!(eng_pm(79.4321, 3.1, "N"), "79 ± 3 N");
        // A leading 1 keeps a second digit.
        assert_eq!(eng_pm(79.4321, 0.14, "N"), "79.43 ± 0.14 N");
        // Carry: 0.96 rounds to 1.0, which keeps two digits.
        assert_eq!(eng_pm(79.4321, 0.96, "N"), "79.4 ± 1.0 N");
        assert_eq!(eng_pm(0.000750071, 2.3e-8, "s"), "750.07 ± 0.02 µs");
        assert_eq!(eng_pm(1234.5, 31.0, "N"), "1.23 ± 0.03 kN");
        assert_eq!(eng_pm(-0.69312, 0.0042, "rad"), "-693 ± 4 mrad");
        // An uncertainty larger than the value: the value rounds to its digit.
        assert_eq!(eng_pm(45.0, 300.0, "N"), "0 ± 300 N");
        assert_eq!(eng_pm(2.5, 0.25, ""), "2.5 ± 0.3");
        assert_eq!(eng_pm(2.5, f64::NAN, "N"), "2.5 N");
        assert_eq!(eng_pm(2.5, 0.0, "N"), "2.5 N");
    }

    #[test]
    fn engineering_notation_has_a_prefix_and_the_digits_asked() {
        assert_eq!(eng(0.000998693095552472, "s"), "998.7 µs");
        assert_eq!(eng(3.227, "N"), "3.227 N");
        assert_eq!(eng(1000.0, "Hz"), "1 kHz");
        assert_eq!(eng(-12_500.0, "Pa"), "-12.5 kPa");
        assert_eq!(eng(999.96, "V"), "1 kV");
        assert_eq!(eng(3.392e-7, "m"), "339.2 nm");
        assert_eq!(eng(0.0, "m"), "0 m");
        assert_eq!(eng(f64::NAN, "m"), "n/a");
        assert_eq!(eng(2.5, ""), "2.5");
        assert_eq!(eng_digits(0.024013, "m", 3), "24 mm");
        assert_eq!(eng_digits(1e-4, "s", 2), "100 µs");
    }

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
