//! Fault injection: the scenarios of `docs/faults.md` parsed from `--fault` ([`inject`]) and
//! applied to a running simulation, with a report of what the firmware made of them
//! ([`apply`]). Sits above the plant and the simulated board, which only hold the state it
//! sets.

pub mod apply;
pub mod inject;
