//! `fpc-sim`: one module per subcommand, and the plumbing the log tools share
//! ([`analysis`]: reading the log and the model, columns, output directory, progress).
//! Failures and their exit codes are [`crate::failure`]'s; plots are [`crate::plot`]'s.

pub mod analysis;
pub mod decode;
pub mod derive;
pub mod energy;
pub mod filters;
pub mod forces;
pub mod gap;
pub mod lag;
pub mod pv;
pub mod run;
