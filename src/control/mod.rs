//! Control: the 20 kHz control step and what drives it.
//!
//! The configuration ([`config`]), the host's command vocabulary and replies ([`command`]),
//! the calibration routines ([`calibration`]) and the step itself ([`step`]), a pure function
//! of one burst of samples that returns the duties of both sections and the servo code. It
//! sits above sensing, physics, motion, drive and safety and below the link and the tasks.

pub mod calibration;
pub mod command;
pub mod config;
pub mod step;
