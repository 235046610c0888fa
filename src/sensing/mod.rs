//! Sensing: from raw sensor codes to trusted measurements.
//!
//! Everything the control step learns about the machine enters here: the sin/cos encoders
//! interpolated and counted ([`encoder`]), the servo's wrapping quadrature count extended
//! ([`quadrature`]), the master position differentiated ([`differentiator`]), the chamber
//! pressure codes converted and supervised ([`pressure`]), and the zero found at head A
//! ([`homing`]). Depends only on the units, the scalar helpers and the port types.

pub mod differentiator;
pub mod encoder;
pub mod encoder_map;
pub mod homing;
pub mod pressure;
pub mod quadrature;
