//! What the control step knows about the machine: the configuration, in SI units, and why
//! one is refused.

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
    /// feed-forward (the step's `Estimator::observe_load`, cancelled in the actuate stage). 0 switches it off;
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
    /// The slave encoder's mapped difference from the master's, corrected in its reading
    /// (`None`: not mapped).
    pub encoder_map: Option<crate::sensing::encoder_map::EncoderMap>,
}

/// The machine as the controller is told it: the values of a machine model the
/// configuration follows (the rest is the firmware's own tuning). One mapping for every
/// machine: [`ControlConfig::for_machine`]; the reference's values come from the one
/// `reference.toml` ([`crate::reference`]), a simulated model's from the model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Machine {
    /// Moving mass, kg.
    pub moving_mass_kg: f32,
    /// Head-to-head travel, m.
    pub travel_m: f32,
    /// Cylinder geometry.
    pub cylinder: Cylinder<f32>,
    /// The friction law (its sign regularisation the firmware's own).
    pub friction: FrictionParams<f32>,
    /// Both encoders' signal period, m.
    pub encoder_period_m: f32,
    /// The motor sections (the master's values for both).
    pub motor: MotorParams<f32>,
    /// The rotation's inertia at the piston, kg·m².
    pub servo_inertia_kgm2: f32,
    /// The servo drive's torque at full scale, N·m.
    pub servo_torque_full_scale_nm: f32,
    /// The rotation encoder's counts per revolution.
    pub servo_counts_per_rev: u32,
    /// Clearance to a head that commanded positions keep, m.
    pub target_clearance_m: f32,
    /// The strokes' dead points, that clearance from head A and from head B, m.
    pub dead_points_m: (f32, f32),
    /// Total force limit of both sections, N.
    pub force_limit_n: f32,
    /// Largest commanded speed, m/s.
    pub max_speed_mps: f32,
}

impl Machine {
    /// The reference machine of `docs/machine.md`, from its one source (`reference.toml`,
    /// generated into [`crate::reference`]).
    pub fn reference() -> Self {
        use crate::reference::{encoder, limits, motor, piston, servo};
        let clearance = limits::TARGET_HEAD_CLEARANCE_M;
        Machine {
            moving_mass_kg: piston::MASS_KG as f32,
            travel_m: piston::TRAVEL_M as f32,
            cylinder: Cylinder::reference(),
            friction: FrictionParams::reference(),
            encoder_period_m: encoder::PERIOD_M as f32,
            motor: MotorParams {
                electrical_period_m: (2.0 * motor::POLE_PITCH_M) as f32,
                ..MotorParams::reference()
            },
            servo_inertia_kgm2: servo::INERTIA_KGM2 as f32,
            servo_torque_full_scale_nm: servo::TORQUE_FULL_SCALE_NM as f32,
            servo_counts_per_rev: servo::COUNTS_PER_REV,
            target_clearance_m: clearance as f32,
            dead_points_m: (clearance as f32, (piston::TRAVEL_M - clearance) as f32),
            force_limit_n: limits::FORCE_LIMIT_N as f32,
            max_speed_mps: limits::MAX_SPEED_MPS as f32,
        }
    }
}

impl ControlConfig {
    /// The reference machine of `docs/machine.md` with the firmware's tuning: what the
    /// flashed firmware runs before its calibration record is loaded.
    pub fn reference() -> Self {
        Self::for_machine(&Machine::reference())
    }

    /// The firmware's tuning for `machine`. The current loops, the allocation's section
    /// limit, the port geometry, the gas and the sensors' calibrations are the reference
    /// machine's whatever `machine` says (the firmware is tuned for it).
    pub fn for_machine(machine: &Machine) -> Self {
        let reference_motor = MotorParams::<f32>::reference();
        let encoder = EncoderConfig {
            period_m: machine.encoder_period_m,
            ..EncoderConfig::reference()
        };
        let mut stroke = StrokeConfig::reference(2.3);
        (stroke.dead_a_m, stroke.dead_b_m) = machine.dead_points_m;
        ControlConfig {
            sample_time_s: 50e-6,
            travel_m: machine.travel_m,
            target_clearance_m: machine.target_clearance_m,
            moving_mass_kg: machine.moving_mass_kg,
            friction: machine.friction,
            cylinder: machine.cylinder,
            gas: GasProperties::air(),
            port_geometry: PortGeometry::reference(),
            volume_ratio: VolumeRatioConfig::reference(),
            encoder_master: encoder,
            encoder_slave: encoder,
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
            force_limit_n: machine.force_limit_n,
            max_speed_mps: machine.max_speed_mps,
            current_gains: CurrentLoopGains::for_bandwidth(&reference_motor, 8000.0),
            allocation: AllocationConfig::reference(),
            motor: machine.motor,
            current_sense: PerSection {
                master: CurrentSense::reference(),
                slave: CurrentSense::reference(),
            },
            angle_offset: PerSection::default(),
            servo: ServoConfig {
                inertia_kgm2: machine.servo_inertia_kgm2,
                torque_full_scale_nm: machine.servo_torque_full_scale_nm,
                counts_per_rev: machine.servo_counts_per_rev,
                ..ServoConfig::reference()
            },
            pressure: PressureCalibration::reference(),
            homing: HomingConfig::reference(),
            park_position_m: 0.01,
            park_speed_mps: 0.2,
            heartbeat_timeout_s: 0.5,
            supervisor: SupervisorConfig::reference(),
            stroke,
            calibration: CalibrationConfig::reference(),
            encoder_map: None,
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

/// Parameters of the routines, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationConfig {
    /// Samples averaged per phase for the current-sense offsets (after `sense_settle_s`).
    pub sense_samples: u32,
    /// Time for the currents to decay after the outputs go off, s.
    pub sense_settle_s: f32,
    /// Largest plausible offset, codes: beyond it the sensor or its supply is broken and the
    /// offsets are not loaded.
    pub sense_max_offset_codes: f32,
    /// Residual mean phase current with the outputs off that counts as an offset, A.
    pub sense_detect_a: f32,
    /// Alignment current (d, in the forced frame), A.
    pub align_current_a: f32,
    /// Damping of the mover during alignment (q-current in the forced frame), N·s/m.
    pub align_damping_ns_per_m: f32,
    /// Angles per period at which each section is aligned (≥ 1; 8 cancel cogging harmonics
    /// 1–7).
    pub align_points: u32,
    /// How far past an angle the forced vector goes before approaching it from above,
    /// fraction of a period.
    pub align_approach_periods: f32,
    /// Speed of the forced angle, periods per s.
    pub align_rate_periods_per_s: f32,
    /// Ramp of the alignment current, s.
    pub align_ramp_s: f32,
    /// Wait after the first pull (the mover may jump half a period), s.
    pub align_first_settle_s: f32,
    /// Wait at each angle before the encoder is read, s.
    pub align_settle_s: f32,
    /// Averaging of the encoder angle at each angle, s.
    pub align_average_s: f32,
    /// Largest spread of one section's estimates around their mean, fraction of a period:
    /// more means the mover did not follow (blocked, or the section gives no force).
    pub align_max_spread_periods: f32,
    /// Cruise speed of the sweeps, m/s.
    pub sweep_speed_mps: f32,
    /// Acceleration at the ends of a sweep, m/s².
    pub sweep_accel_mps2: f32,
    /// Rest between sweeps, s.
    pub sweep_rest_s: f32,
    /// Distance kept from either head by a sweep, m.
    pub sweep_margin_m: f32,
    /// Periods covered at cruise speed by each cogging sweep.
    pub cogging_periods: u32,
    /// Periods covered at cruise speed by each misalignment sweep.
    pub misalign_periods: u32,
    /// d-current on the slave during the misalignment sweeps, A.
    pub misalign_current_a: f32,
    /// The encoder map's two sweep speeds, m/s (their difference gives the velocity
    /// coefficient).
    pub map_speeds_mps: [f32; 2],
    /// Acceleration at the ends of the encoder map's sweeps, m/s².
    pub map_accel_mps2: f32,
    /// Periods covered at cruise speed by each encoder-map sweep.
    pub map_periods: u32,
    /// Speed over which the mapped direction part blends between its two values, m/s.
    pub map_blend_mps: f32,
    /// Electrical periods the commissioning turns each section's forced vector forward and
    /// back (the alignment's current, rate and waits). The commissioning's three fields are
    /// the bench build's: in the release firmware they would move the fields after them
    /// in the step's state.
    #[cfg(feature = "bench")]
    pub commission_periods: f32,
    /// Wait after the commissioning's first pull, undamped (friction alone settles the
    /// mover), s.
    #[cfg(feature = "bench")]
    pub commission_first_settle_s: f32,
    /// Largest relative difference of the measured displacement per electrical period from
    /// the configured period that passes (static friction alone may take 2·F_s/k off a
    /// one-period turn: 0.28 mm of 24 mm, 1.2 %, at 20 A on the reference machine).
    #[cfg(feature = "bench")]
    pub commission_pitch_tolerance: f32,
}

impl CalibrationConfig {
    /// Reference parameters for the reference machine: alignment at 20 A (a spring of
    /// 4.2e5 N/m, so static friction leaves 0.14 mm = 2° and cogging 0.07 mm = 1°, both
    /// cancelled by the averaging), damping ζ ≈ 0.7 on 12 kg; sweeps at 0.1 m/s (the cogging
    /// at 4 Hz, far below the 40 Hz position loop); 15 A on the slave shifts the master's
    /// force by 2·80·15·sin ε = 42 N per degree.
    pub const fn reference() -> Self {
        CalibrationConfig {
            sense_samples: 4000,
            sense_settle_s: 2e-3,
            sense_max_offset_codes: 100.0,
            sense_detect_a: 0.5,
            align_current_a: 20.0,
            align_damping_ns_per_m: 3000.0,
            align_points: 8,
            align_approach_periods: 1.0 / 18.0,
            align_rate_periods_per_s: 2.0,
            align_ramp_s: 0.1,
            align_first_settle_s: 0.2,
            align_settle_s: 0.06,
            align_average_s: 0.02,
            align_max_spread_periods: 1.0 / 36.0,
            sweep_speed_mps: 0.1,
            sweep_accel_mps2: 1.0,
            sweep_rest_s: 0.1,
            sweep_margin_m: 0.01,
            cogging_periods: 4,
            misalign_periods: 2,
            misalign_current_a: 15.0,
            map_speeds_mps: [0.1, 0.4],
            map_accel_mps2: 10.0,
            map_periods: 4,
            map_blend_mps: 5e-3,
            #[cfg(feature = "bench")]
            commission_periods: 1.0,
            #[cfg(feature = "bench")]
            commission_first_settle_s: 0.6,
            #[cfg(feature = "bench")]
            commission_pitch_tolerance: 0.02,
        }
    }
}

impl ControlConfig {
    /// Refuses a configuration whose physical parameters are not finite and positive, or whose
    /// gains and capabilities are outside their ranges.
    pub fn check(&self) -> Result<(), ConfigError> {
        let config = self;
        for (name, v) in [
            ("sample_time_s", config.sample_time_s),
            ("travel_m", config.travel_m),
            ("moving_mass_kg", config.moving_mass_kg),
            ("force_limit_n", config.force_limit_n),
            (
                "motor.force_constant_n_per_a",
                config.motor.force_constant_n_per_a,
            ),
            ("motor.bus_voltage_v", config.motor.bus_voltage_v),
            ("max_speed_mps", config.max_speed_mps),
            (
                "supervisor.brake_deceleration_mps2",
                config.supervisor.brake_deceleration_mps2(),
            ),
            (
                "supervisor.following_error_time_s",
                config.supervisor.following_error_time_s,
            ),
            (
                "supervisor.section_time_s",
                config.supervisor.section_time_s,
            ),
            (
                "supervisor.rotation_time_s",
                config.supervisor.rotation_time_s,
            ),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ConfigError::NotPositive(name));
            }
        }
        // The observer's gains per cycle must stay within [0, 0.5] (a well damped update; NaN
        // fails too), its threshold non-negative.
        for (name, k) in [
            (
                "disturbance_bandwidth_rad_s",
                config.disturbance_bandwidth_rad_s,
            ),
            ("disturbance_slow_rad_s", config.disturbance_slow_rad_s),
        ] {
            if !(k >= 0.0 && k * config.sample_time_s <= 0.5) {
                return Err(ConfigError::OutOfRange(name));
            }
        }
        // The allocation relies on capabilities within [0, 1] (NaN fails too).
        for (name, c) in [
            (
                "allocation.capability.master",
                config.allocation.capability.master,
            ),
            (
                "allocation.capability.slave",
                config.allocation.capability.slave,
            ),
        ] {
            if !(0.0..=1.0).contains(&c) {
                return Err(ConfigError::OutOfRange(name));
            }
        }
        // The pressure channels' live band must have its ends in order (its check is one
        // compare of the distance from the bottom).
        if config.pressure.open_below > config.pressure.short_above {
            return Err(ConfigError::OutOfRange("pressure.open_below"));
        }
        let threshold = config.disturbance_threshold_n;
        if threshold.is_nan() || threshold < 0.0 {
            return Err(ConfigError::OutOfRange("disturbance_threshold_n"));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_configuration_the_step_cannot_hold_to_is_refused_by_name() {
        assert_eq!(ControlConfig::reference().check(), Ok(()));
        let mut c = ControlConfig::reference();
        c.supervisor.rotation_time_s = 0.0;
        assert_eq!(
            c.check(),
            Err(ConfigError::NotPositive("supervisor.rotation_time_s"))
        );
        let mut c = ControlConfig::reference();
        c.supervisor.following_error_time_s = f32::NAN;
        assert_eq!(
            c.check(),
            Err(ConfigError::NotPositive(
                "supervisor.following_error_time_s"
            ))
        );
        let mut c = ControlConfig::reference();
        (c.pressure.open_below, c.pressure.short_above) = (3890, 205);
        assert_eq!(
            c.check(),
            Err(ConfigError::OutOfRange("pressure.open_below"))
        );
    }
}
