//! Motion: what the piston and the rotation should do next.
//!
//! Setpoints and point-to-point moves ([`trajectory`]), the periodic stroke and dead-point
//! control ([`stroke`]), where the discharge should open ([`volume_ratio`]), and the rotation
//! slaved to the measured stroke ([`synchroniser`]).

pub mod stroke;
pub mod synchroniser;
pub mod trajectory;
pub mod volume_ratio;
