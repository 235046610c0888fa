//! The machine's physical laws, written once and shared by the firmware's feed-forward, the
//! simulator's plant and the model-gap workflow: the force balance on the piston that sums
//! them ([`balance`]), friction ([`friction`]), gas in the chambers ([`gas`]), cogging
//! ([`cogging`]), the linear motor ([`motor`]) and the port windows in rotation phase
//! ([`port_timing`]). Generic over the scalar ([`crate::real`]),
//! they depend on nothing above it.

pub mod balance;
pub mod cogging;
pub mod friction;
pub mod gas;
pub mod motor;
pub mod port_timing;
