//! What the control step knows about the machine: the configuration, in SI units, and why
//! one is refused.

use crate::control::calibration::CalibrationConfig;
use crate::drive::allocation::AllocationConfig;
use crate::drive::foc::{CurrentLoopGains, CurrentSense};
use crate::drive::servo::ServoConfig;
use crate::motion::stroke::StrokeConfig;
use crate::motion::volume_ratio::VolumeRatioConfig;
use crate::physics::friction::FrictionParams;
use crate::physics::gas::{Cylinder, GasProperties};
use crate::physics::motor::MotorParams;
use crate::physics::port_timing::PortGeometry;
use crate::safety::supervisor::SupervisorConfig;
use crate::sensing::differentiator::SgError;
use crate::sensing::encoder::EncoderConfig;
use crate::sensing::homing::HomingConfig;
use crate::sensing::pressure::PressureCalibration;
use crate::units::PerSection;

/// Everything the control step needs to know about the machine, in SI units.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlConfig {
    /// Control period, s.
    pub sample_time_s: f32,
    /// Head-to-head travel, m.
    pub travel_m: f32,
    /// Clearance to a head that commanded positions must keep, m (target 1 mm).
    pub target_clearance_m: f32,
    /// Moving mass, m (feed-forward).
    pub moving_mass_kg: f32,
    /// Friction law (feed-forward).
    pub friction: FrictionParams<f32>,
    /// Cylinder geometry: area and chamber volumes (gas force, volume ratio).
    pub cylinder: Cylinder<f32>,
    /// The working gas.
    pub gas: GasProperties<f32>,
    /// Port windows of the rotation.
    pub port_geometry: PortGeometry<f32>,
    /// Stroke-by-stroke volume-ratio correction.
    pub volume_ratio: VolumeRatioConfig,
    /// Master-section encoder.
    pub encoder_master: EncoderConfig,
    /// Slave-section encoder.
    pub encoder_slave: EncoderConfig,
    /// Differentiator window (odd, ≤ 41).
    pub sg_window: usize,
    /// Differentiator polynomial order.
    pub sg_order: usize,
    /// Differentiator evaluation point, samples back from the newest.
    pub sg_lag: usize,
    /// Model feed-forward (m·a + friction − gas force) on; off only to measure what it is
    /// worth.
    pub feed_forward: bool,
    /// Position-loop stiffness, N/m.
    pub position_kp_n_per_m: f32,
    /// Position-loop damping, N·s/m.
    pub position_kd_ns_per_m: f32,
    /// Bandwidth of the running strokes' disturbance observer, rad/s (the inverse of its
    /// time constant): the force on the piston that the model does not explain (an external
    /// load, a mass or gas-force error) is estimated from the measured motor force, the
    /// model's friction and gas force and the velocity estimate, and cancelled through the
    /// feed-forward (`ControlStep`'s actuate stage, `observe_load`). 0 switches it off;
    /// accepted 0 ≤ K ≤ 0.5 / `sample_time_s` (10,000 rad/s at 20 kHz).
    pub disturbance_bandwidth_rad_s: f32,
    /// The observer's estimate is cancelled at its full bandwidth while it differs from
    /// what is being cancelled by more than this, N (≥ 0), and at
    /// [`ControlConfig::disturbance_slow_rad_s`] below it.
    pub disturbance_threshold_n: f32,
    /// How fast the cancelled estimate follows differences below the threshold, rad/s
    /// (0 ≤ K ≤ 0.5 / `sample_time_s`): slow, so the observer's noise and the force ripple
    /// it sees do not reach the force reference.
    pub disturbance_slow_rad_s: f32,
    /// Total force limit of both sections, N.
    pub force_limit_n: f32,
    /// Largest commanded speed, m/s.
    pub max_speed_mps: f32,
    /// Motor section parameters (both sections alike).
    pub motor: MotorParams<f32>,
    /// Split of the force over the sections, cogging compensation.
    pub allocation: AllocationConfig,
    /// Current-loop gains.
    pub current_gains: CurrentLoopGains,
    /// Current-sense calibration per section.
    pub current_sense: PerSection<CurrentSense>,
    /// Electrical-angle offset per section (wrapping, 2³² = one period), from alignment.
    pub angle_offset: PerSection<u32>,
    /// Rotation servo.
    pub servo: ServoConfig,
    /// Pressure-sensor calibration (all four channels alike).
    pub pressure: PressureCalibration,
    /// Homing.
    pub homing: HomingConfig,
    /// Where the piston parks after homing or when the host is lost, m.
    pub park_position_m: f32,
    /// Peak speed of a park move, m/s.
    pub park_speed_mps: f32,
    /// Time without a heartbeat after which the piston parks (once heartbeats were seen), s.
    pub heartbeat_timeout_s: f32,
    /// Supervision limits.
    pub supervisor: SupervisorConfig,
    /// The periodic stroke (its peak speed is set by the start command).
    pub stroke: StrokeConfig,
    /// The calibration routines.
    pub calibration: CalibrationConfig,
}

impl ControlConfig {
    /// The reference machine of `machine.md`.
    pub fn reference() -> Self {
        let motor = MotorParams::<f32>::reference();
        ControlConfig {
            sample_time_s: 50e-6,
            travel_m: 0.205,
            target_clearance_m: 1.0e-3,
            moving_mass_kg: 12.0,
            friction: FrictionParams::reference(),
            cylinder: Cylinder::reference(),
            gas: GasProperties::air(),
            port_geometry: PortGeometry::reference(),
            volume_ratio: VolumeRatioConfig::reference(),
            encoder_master: EncoderConfig::reference(),
            encoder_slave: EncoderConfig::reference(),
            // 25, not 21: acceleration error 3.8 % vs 4.5 % of peak on a 4 m/s stroke at
            // σx = 1 µm, same cost (tests/velocity_estimate_quality.rs).
            sg_window: 25,
            sg_order: 2,
            sg_lag: 0,
            feed_forward: true,
            // ≈ 40 Hz position bandwidth on 12 kg, damping 0.8.
            position_kp_n_per_m: 7.5e5,
            position_kd_ns_per_m: 4.8e3,
            // τ = 0.25 ms, followed to within 300 N at once, then at 250 rad/s: a ±3 kN load
            // step at any phase leaves ≥ 0.76 mm to the heads, and the force reference moves
            // from cycle to cycle as it did without the observer
            // (tests/a_load_step_at_any_phase_keeps_the_head_clearance.rs).
            disturbance_bandwidth_rad_s: 4000.0,
            disturbance_threshold_n: 300.0,
            disturbance_slow_rad_s: 250.0,
            force_limit_n: 10_000.0,
            max_speed_mps: 4.5,
            current_gains: CurrentLoopGains::for_bandwidth(&motor, 8000.0),
            allocation: AllocationConfig::reference(),
            motor,
            current_sense: PerSection {
                master: CurrentSense::reference(),
                slave: CurrentSense::reference(),
            },
            angle_offset: PerSection::default(),
            servo: ServoConfig::reference(),
            pressure: PressureCalibration::reference(),
            homing: HomingConfig::reference(),
            park_position_m: 0.01,
            park_speed_mps: 0.2,
            heartbeat_timeout_s: 0.5,
            supervisor: SupervisorConfig::reference(),
            stroke: StrokeConfig::reference(2.3),
            calibration: CalibrationConfig::reference(),
        }
    }
}

/// Why a configuration was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConfigError {
    /// The differentiator configuration is invalid.
    Differentiator(SgError),
    /// A physical parameter is not finite and positive (names the field).
    NotPositive(&'static str),
    /// A parameter is outside its documented range (names the field).
    OutOfRange(&'static str),
}
