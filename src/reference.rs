//! The reference machine of `docs/machine.md`, generated from its one source,
//! `hal-sim/src/plant/model/reference.toml` (each value's origin is written there): do
//! not edit. `FPC_BLESS_REFERENCE=1 cargo test -p hal-sim --test
//! the_reference_machine_is_written_once` regenerates it after the TOML changed. One
//! module per section, one constant per key, SI units as the keys name them.

/// `[effects]`.
pub mod effects {
    /// `[effects.cogging]`.
    pub mod cogging {
        /// `effects.cogging.amplitude_n`.
        pub const AMPLITUDE_N: f64 = 30.0;
        /// `effects.cogging.period_m`.
        pub const PERIOD_M: f64 = 0.024;
        /// `effects.cogging.phase_rad`.
        pub const PHASE_RAD: f64 = 0.0;
    }
    /// `[effects.heat_transfer]`.
    pub mod heat_transfer {
        /// `effects.heat_transfer.ua_w_per_k`.
        pub const UA_W_PER_K: f64 = 5.0;
    }
    /// `[effects.leakage]`.
    pub mod leakage {
        /// `effects.leakage.gap_m`.
        pub const GAP_M: f64 = 2.5e-5;
        /// `effects.leakage.rod_gap_m`.
        pub const ROD_GAP_M: f64 = 1e-5;
        /// `effects.leakage.rod_seal_length_m`.
        pub const ROD_SEAL_LENGTH_M: f64 = 0.03;
        /// `effects.leakage.seal_length_m`.
        pub const SEAL_LENGTH_M: f64 = 0.05;
    }
}
/// `[encoder]`.
pub mod encoder {
    /// `encoder.period_m`.
    pub const PERIOD_M: f64 = 0.024;
}
/// `[friction]`.
pub mod friction {
    /// `friction.coulomb_n`.
    pub const COULOMB_N: f64 = 40.0;
    /// `friction.static_n`.
    pub const STATIC_N: f64 = 60.0;
    /// `friction.stribeck_exponent`.
    pub const STRIBECK_EXPONENT: f64 = 1.0;
    /// `friction.stribeck_velocity_mps`.
    pub const STRIBECK_VELOCITY_MPS: f64 = 0.02;
    /// `friction.viscous_ns_per_m`.
    pub const VISCOUS_NS_PER_M: f64 = 25.0;
}
/// `[gas]`.
pub mod gas {
    /// `gas.ambient_pa`.
    pub const AMBIENT_PA: f64 = 101325.0;
    /// `gas.gamma`.
    pub const GAMMA: f64 = 1.4;
    /// `gas.gas_constant_j_per_kg_k`.
    pub const GAS_CONSTANT_J_PER_KG_K: f64 = 287.0;
    /// `gas.temperature_k`.
    pub const TEMPERATURE_K: f64 = 293.15;
    /// `gas.viscosity_pa_s`.
    pub const VISCOSITY_PA_S: f64 = 1.8e-5;
}
/// `[limits]`.
pub mod limits {
    /// `limits.force_limit_n`.
    pub const FORCE_LIMIT_N: f64 = 10000.0;
    /// `limits.max_speed_mps`.
    pub const MAX_SPEED_MPS: f64 = 4.5;
    /// `limits.min_head_clearance_m`.
    pub const MIN_HEAD_CLEARANCE_M: f64 = 0.0003;
    /// `limits.target_head_clearance_m`.
    pub const TARGET_HEAD_CLEARANCE_M: f64 = 0.001;
}
/// `[lines]`.
pub mod lines {
    /// `lines.pressure_ratio`.
    pub const PRESSURE_RATIO: f64 = 3.1;
    /// `lines.suction_pa`.
    pub const SUCTION_PA: f64 = 100000.0;
}
/// `[motor]`.
pub mod motor {
    /// `motor.bus_voltage_v`.
    pub const BUS_VOLTAGE_V: f64 = 560.0;
    /// `motor.current_limit_a`.
    pub const CURRENT_LIMIT_A: f64 = 62.5;
    /// `motor.force_constant_n_per_a`.
    pub const FORCE_CONSTANT_N_PER_A: f64 = 80.0;
    /// `motor.inductance_h`.
    pub const INDUCTANCE_H: f64 = 0.006;
    /// `motor.pole_pitch_m`.
    pub const POLE_PITCH_M: f64 = 0.012;
    /// `motor.resistance_ohm`.
    pub const RESISTANCE_OHM: f64 = 0.6;
    /// `motor.slave_follows_master`.
    pub const SLAVE_FOLLOWS_MASTER: bool = false;
}
/// `[piston]`.
pub mod piston {
    /// `piston.bore_m`.
    pub const BORE_M: f64 = 0.09;
    /// `piston.dead_length_a_m`.
    pub const DEAD_LENGTH_A_M: f64 = 0.0005;
    /// `piston.dead_length_b_m`.
    pub const DEAD_LENGTH_B_M: f64 = 0.0005;
    /// `piston.mass_kg`.
    pub const MASS_KG: f64 = 12.0;
    /// `piston.rod_m`.
    pub const ROD_M: f64 = 0.02;
    /// `piston.stop_damping_ns_per_m`.
    pub const STOP_DAMPING_NS_PER_M: f64 = 20000.0;
    /// `piston.stop_stiffness_n_per_m`.
    pub const STOP_STIFFNESS_N_PER_M: f64 = 50000000.0;
    /// `piston.travel_m`.
    pub const TRAVEL_M: f64 = 0.205;
}
/// `[ports]`.
pub mod ports {
    /// `ports.discharge_a_deg`.
    pub const DISCHARGE_A_DEG: [f64; 2] = [288.0, 360.0];
    /// `ports.discharge_area_m2`.
    pub const DISCHARGE_AREA_M2: f64 = 0.0005;
    /// `ports.discharge_b_deg`.
    pub const DISCHARGE_B_DEG: [f64; 2] = [108.0, 180.0];
    /// `ports.discharge_coefficient`.
    pub const DISCHARGE_COEFFICIENT: f64 = 0.8;
    /// `ports.intake_a_deg`.
    pub const INTAKE_A_DEG: [f64; 2] = [0.0, 180.0];
    /// `ports.intake_area_m2`.
    pub const INTAKE_AREA_M2: f64 = 0.0005;
    /// `ports.intake_b_deg`.
    pub const INTAKE_B_DEG: [f64; 2] = [180.0, 360.0];
    /// `ports.ramp_deg`.
    pub const RAMP_DEG: f64 = 6.0;
}
/// `[published]`.
pub mod published {
    /// `published.current_bandwidth_hz`.
    pub const CURRENT_BANDWIDTH_HZ: f64 = 1000.0;
    /// `published.current_limit_a`.
    pub const CURRENT_LIMIT_A: f64 = 0.0;
    /// `published.cycle_s`.
    pub const CYCLE_S: f64 = 0.0001;
    /// `published.loop_velocity_delay_s`.
    pub const LOOP_VELOCITY_DELAY_S: f64 = 0.0;
    /// `published.position_gain_per_s`.
    pub const POSITION_GAIN_PER_S: f64 = 100.0;
    /// `published.profile_ramp_fraction`.
    pub const PROFILE_RAMP_FRACTION: f64 = 0.5;
    /// `published.reported_velocity_delay_s`.
    pub const REPORTED_VELOCITY_DELAY_S: f64 = 0.0085;
    /// `published.rest_s`.
    pub const REST_S: f64 = 0.25;
    /// `published.slave_lag_s`.
    pub const SLAVE_LAG_S: f64 = 0.00075;
    /// `published.velocity_feedforward`.
    pub const VELOCITY_FEEDFORWARD: f64 = 1.0;
    /// `published.velocity_filter_s`.
    pub const VELOCITY_FILTER_S: f64 = 0.0;
    /// `published.velocity_gain_ns_per_m`.
    pub const VELOCITY_GAIN_NS_PER_M: f64 = 8000.0;
    /// `published.velocity_integral_time_s`.
    pub const VELOCITY_INTEGRAL_TIME_S: f64 = 0.01;
}
/// `[sensors]`.
pub mod sensors {
    /// `[sensors.current]`.
    pub mod current {
        /// `sensors.current.noise_a`.
        pub const NOISE_A: f64 = 0.0;
        /// `sensors.current.offset_master_a`.
        pub const OFFSET_MASTER_A: [f64; 3] = [0.0, 0.0, 0.0];
        /// `sensors.current.offset_slave_a`.
        pub const OFFSET_SLAVE_A: [f64; 3] = [0.0, 0.0, 0.0];
    }
    /// `[sensors.encoder_master]`.
    pub mod encoder_master {
        /// `sensors.encoder_master.amplitude_codes`.
        pub const AMPLITUDE_CODES: f64 = 1600.0;
        /// `sensors.encoder_master.cos_offset_codes`.
        pub const COS_OFFSET_CODES: f64 = 0.0;
        /// `sensors.encoder_master.gain_mismatch`.
        pub const GAIN_MISMATCH: f64 = 0.0;
        /// `sensors.encoder_master.noise_codes`.
        pub const NOISE_CODES: f64 = 0.35;
        /// `sensors.encoder_master.quadrature_error_rad`.
        pub const QUADRATURE_ERROR_RAD: f64 = 0.0;
        /// `sensors.encoder_master.sin_offset_codes`.
        pub const SIN_OFFSET_CODES: f64 = 0.0;
    }
    /// `[sensors.encoder_slave]`.
    pub mod encoder_slave {
        /// `sensors.encoder_slave.amplitude_codes`.
        pub const AMPLITUDE_CODES: f64 = 1600.0;
        /// `sensors.encoder_slave.cos_offset_codes`.
        pub const COS_OFFSET_CODES: f64 = 0.0;
        /// `sensors.encoder_slave.gain_mismatch`.
        pub const GAIN_MISMATCH: f64 = 0.0;
        /// `sensors.encoder_slave.noise_codes`.
        pub const NOISE_CODES: f64 = 0.35;
        /// `sensors.encoder_slave.quadrature_error_rad`.
        pub const QUADRATURE_ERROR_RAD: f64 = 0.0;
        /// `sensors.encoder_slave.sin_offset_codes`.
        pub const SIN_OFFSET_CODES: f64 = 0.0;
    }
    /// `[sensors.force]`.
    pub mod force {
        /// `sensors.force.gain_master`.
        pub const GAIN_MASTER: f64 = 1.0;
        /// `sensors.force.gain_slave`.
        pub const GAIN_SLAVE: f64 = 1.0;
        /// `sensors.force.offset_master_n`.
        pub const OFFSET_MASTER_N: f64 = 0.0;
        /// `sensors.force.offset_slave_n`.
        pub const OFFSET_SLAVE_N: f64 = 0.0;
    }
    /// `[sensors.pressure]`.
    pub mod pressure {
        /// `sensors.pressure.gain_a`.
        pub const GAIN_A: f64 = 1.0;
        /// `sensors.pressure.gain_b`.
        pub const GAIN_B: f64 = 1.0;
        /// `sensors.pressure.noise_pa`.
        pub const NOISE_PA: f64 = 500.0;
        /// `sensors.pressure.offset_a_pa`.
        pub const OFFSET_A_PA: f64 = 0.0;
        /// `sensors.pressure.offset_b_pa`.
        pub const OFFSET_B_PA: f64 = 0.0;
        /// `sensors.pressure.offset_discharge_pa`.
        pub const OFFSET_DISCHARGE_PA: f64 = 0.0;
        /// `sensors.pressure.offset_suction_pa`.
        pub const OFFSET_SUCTION_PA: f64 = 0.0;
        /// `sensors.pressure.time_constant_s`.
        pub const TIME_CONSTANT_S: f64 = 0.0001;
    }
}
/// `[servo]`.
pub mod servo {
    /// `servo.backlash_rad`.
    pub const BACKLASH_RAD: f64 = 0.002;
    /// `servo.coulomb_nm`.
    pub const COULOMB_NM: f64 = 0.05;
    /// `servo.counts_per_rev`.
    pub const COUNTS_PER_REV: u32 = 4096;
    /// `servo.inertia_kgm2`.
    pub const INERTIA_KGM2: f64 = 0.002;
    /// `servo.torque_full_scale_nm`.
    pub const TORQUE_FULL_SCALE_NM: f64 = 20.0;
    /// `servo.torque_limit_nm`.
    pub const TORQUE_LIMIT_NM: f64 = 20.0;
    /// `servo.torque_time_constant_s`.
    pub const TORQUE_TIME_CONSTANT_S: f64 = 0.0002;
    /// `servo.viscous_nms_per_rad`.
    pub const VISCOUS_NMS_PER_RAD: f64 = 0.001;
}
/// `[simulation]`.
pub mod simulation {
    /// `simulation.substeps_per_period`.
    pub const SUBSTEPS_PER_PERIOD: u32 = 1;
}
/// `[supply]`.
pub mod supply {
    /// `supply.bridge_forward_voltage_v`.
    pub const BRIDGE_FORWARD_VOLTAGE_V: f64 = 1.0;
    /// `supply.bridge_on_resistance_ohm`.
    pub const BRIDGE_ON_RESISTANCE_OHM: f64 = 0.02;
    /// `supply.bridge_switching_energy_j_per_va`.
    pub const BRIDGE_SWITCHING_ENERGY_J_PER_VA: f64 = 2e-7;
    /// `supply.chopper_voltage_v`.
    pub const CHOPPER_VOLTAGE_V: f64 = 750.0;
    /// `supply.link_capacitance_f`.
    pub const LINK_CAPACITANCE_F: f64 = 0.002;
    /// `supply.logic_dropout_voltage_v`.
    pub const LOGIC_DROPOUT_VOLTAGE_V: f64 = 150.0;
    /// `supply.logic_power_w`.
    pub const LOGIC_POWER_W: f64 = 40.0;
    /// `supply.power_good_voltage_v`.
    pub const POWER_GOOD_VOLTAGE_V: f64 = 500.0;
    /// `supply.servo_efficiency`.
    pub const SERVO_EFFICIENCY: f64 = 0.85;
}
