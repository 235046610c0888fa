//! The physical plant the firmware drives in the simulator, and the model file that
//! configures it.
//!
//! The machine model ([`model`], TOML), the piston, sections and rotation ([`dynamics`]),
//! the gas in both chambers ([`chambers`]), the motor sections' electrics ([`motor`]), the
//! rotation servo ([`servo`]), the drive board's DC link and logic supply ([`supply`]), the bridges and the electrical
//! energy they turn over ([`bridge`]), the laws of the sensors before their converters ([`sensing`])
//! and the seeded noise they draw from ([`noise`]), prescribed motion without the controller
//! ([`kinematic`]) and fast numerics for the hot path ([`fastmath`]). The plant knows neither
//! the simulated board around it nor the fault injector: faults of the machine are state it
//! reads ([`dynamics::PlantFaults`]).

pub mod bridge;
pub mod chambers;
pub mod dynamics;
pub mod fastmath;
pub mod kinematic;
pub mod model;
pub mod motor;
pub mod noise;
pub mod sensing;
pub mod servo;
pub mod supply;
