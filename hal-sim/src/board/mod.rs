//! The simulated board: what the firmware's task bodies run against on the host.
//!
//! Simulated time, the sampling burst and the latched outputs behind the port traits
//! ([`world`]), the sensor models ([`sensors`]) and their faults ([`corruption`]), the
//! executor that polls the firmware's tasks in lock-step with simulated time ([`exec`]), the
//! RTT channels the tasks write and read ([`channels`]), the telemetry capture
//! ([`capture`]), the calibration's NOR flash with an injectable power cut
//! ([`flash`]), the RAM a probe reads, with the firmware's RTT channels ([`ram`]), and
//! in-memory ports for running one task body alone ([`loopback`]), and the wiring faults
//! between the board and the machine ([`wiring`]). It drives the
//! [`crate::plant::dynamics`]; it knows neither the fault injector nor the runner.

pub mod capture;
pub mod channels;
pub mod corruption;
pub mod exec;
pub mod flash;
pub mod loopback;
pub mod ram;
pub mod sensors;
pub mod wiring;
pub mod world;
