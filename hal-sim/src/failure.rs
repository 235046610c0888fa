//! The failure every fallible entry point of `fpc-sim` returns: the exit code and the one
//! line to print.
//!
//! Exit codes (`formats.md` §3): 0 success, 1 runtime failure, 2 bad usage or bad input, with
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
}

/// Result of a subcommand.
pub type CmdResult = Result<(), Failure>;
