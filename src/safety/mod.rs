//! Safety: the fault vocabulary and the per-cycle supervision.
//!
//! The faults, the reaction each asks for and the latched set ([`faults`]); the checks run every cycle, the braking
//! envelope and the limit flags ([`supervisor`]). Depends only on the scalar helpers, so
//! every layer above may report into it.

pub mod absent;
pub mod faults;
pub mod supervisor;
