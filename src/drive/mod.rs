//! Drive: from a force and a rotation demand to switching duties and a servo code.
//!
//! One total force split over the two linear-motor sections with cogging cancelled
//! ([`allocation`]), the current loops and modulation of each section ([`foc`]), and the
//! rotation servo loop ([`servo`]). Below the control step; knows nothing of modes.

pub mod allocation;
pub mod foc;
pub mod servo;
