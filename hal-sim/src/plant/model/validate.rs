//! Validation of a parsed model: every value checked for its physical kind (positive,
//! non-negative, finite, a fraction) and against the physical range of its key
//! ([`RANGES`]: what a free-piston compressor of a few grams to a tonne could have), then
//! the model as a whole for consistency (the stroke fits between the clearances, the dead
//! lengths, cogging below the force limit, …), with an error naming the key and the range.

use super::{MachineModel, ModelError};
use crate::failure::num;

/// What a value must be.
#[derive(Clone, Copy)]
enum Rule {
    Positive,
    NonNegative,
    Finite,
    /// A fraction-like factor in (0, max].
    InUnit(f64),
}

/// The physical range of every numeric key, inclusive, with its unit: `(key, min, max, unit)`.
/// The per-section overrides (`motor.master.*`) and both encoders (`sensors.encoder_*`) share
/// the ranges of their plain keys.
pub const RANGES: &[(&str, f64, f64, &str)] = &[
    ("piston.mass_kg", 0.01, 1000.0, "kg"),
    ("piston.bore_m", 1e-3, 1.0, "m"),
    ("piston.rod_m", 0.0, 0.5, "m"),
    ("piston.travel_m", 1e-3, 2.0, "m"),
    ("piston.dead_length_a_m", 0.0, 0.5, "m"),
    ("piston.dead_length_b_m", 0.0, 0.5, "m"),
    ("piston.stop_stiffness_n_per_m", 1e3, 1e12, "N/m"),
    ("piston.stop_damping_ns_per_m", 0.0, 1e8, "N·s/m"),
    ("friction.coulomb_n", 0.0, 1e5, "N"),
    ("friction.viscous_ns_per_m", 0.0, 1e6, "N·s/m"),
    ("friction.static_n", 0.0, 1e5, "N"),
    ("friction.stribeck_velocity_mps", 1e-5, 10.0, "m/s"),
    ("friction.stribeck_exponent", 0.1, 10.0, ""),
    ("gas.gamma", 1.0, 1.7, ""),
    ("gas.gas_constant_j_per_kg_k", 10.0, 5000.0, "J/(kg·K)"),
    ("gas.temperature_k", 50.0, 1000.0, "K"),
    ("gas.ambient_pa", 1e4, 2e5, "Pa"),
    ("gas.viscosity_pa_s", 1e-7, 1e-2, "Pa·s"),
    ("motor.pole_pitch_m", 1e-3, 0.5, "m"),
    ("motor.force_constant_n_per_a", 0.1, 1e4, "N/A"),
    ("motor.resistance_ohm", 1e-4, 1e3, "Ω"),
    ("motor.inductance_h", 1e-7, 10.0, "H"),
    ("motor.bus_voltage_v", 1.0, 2000.0, "V"),
    ("motor.current_limit_a", 0.1, 1000.0, "A"),
    ("encoder.period_m", 1e-6, 0.1, "m"),
    ("ports.ramp_deg", 0.0, 90.0, "°"),
    ("ports.intake_area_m2", 1e-8, 0.1, "m²"),
    ("ports.discharge_area_m2", 1e-8, 0.1, "m²"),
    ("ports.discharge_coefficient", 0.0, 1.0, ""),
    ("lines.suction_pa", 1e4, 1e6, "Pa"),
    ("lines.pressure_ratio", 1.0, 20.0, ""),
    ("servo.inertia_kgm2", 1e-7, 10.0, "kg·m²"),
    ("servo.viscous_nms_per_rad", 0.0, 100.0, "N·m·s/rad"),
    ("servo.coulomb_nm", 0.0, 100.0, "N·m"),
    ("servo.torque_full_scale_nm", 1e-3, 1000.0, "N·m"),
    ("servo.torque_limit_nm", 1e-3, 1000.0, "N·m"),
    ("servo.torque_time_constant_s", 0.0, 0.1, "s"),
    ("servo.backlash_rad", 0.0, 0.5, "rad"),
    ("servo.counts_per_rev", 256.0, 1048576.0, "counts"),
    ("sensors.current.noise_a", 0.0, 10.0, "A"),
    ("sensors.current.offset_master_a", -10.0, 10.0, "A"),
    ("sensors.current.offset_slave_a", -10.0, 10.0, "A"),
    ("sensors.pressure.noise_pa", 0.0, 1e5, "Pa"),
    ("sensors.pressure.time_constant_s", 0.0, 1.0, "s"),
    ("sensors.pressure.offset_a_pa", -1e5, 1e5, "Pa"),
    ("sensors.pressure.offset_b_pa", -1e5, 1e5, "Pa"),
    ("sensors.pressure.offset_suction_pa", -1e5, 1e5, "Pa"),
    ("sensors.pressure.offset_discharge_pa", -1e5, 1e5, "Pa"),
    (
        "sensors.encoder.amplitude_codes",
        1.0,
        ADC_HALF_RANGE_CODES,
        "codes",
    ),
    ("sensors.encoder.noise_codes", 0.0, 200.0, "codes"),
    ("sensors.encoder.sin_offset_codes", -2047.0, 2047.0, "codes"),
    ("sensors.encoder.cos_offset_codes", -2047.0, 2047.0, "codes"),
    ("sensors.encoder.quadrature_error_rad", -1.0, 1.0, "rad"),
    ("sensors.encoder.gain_mismatch", -0.99, 10.0, ""),
    ("limits.target_head_clearance_m", 1e-5, 0.05, "m"),
    ("limits.min_head_clearance_m", 0.0, 0.05, "m"),
    ("limits.force_limit_n", 1.0, 1e6, "N"),
    ("limits.max_speed_mps", 0.1, 10.0, "m/s"),
    ("effects.cogging.amplitude_n", -1e4, 1e4, "N"),
    ("effects.cogging.period_m", 1e-4, 1.0, "m"),
    ("effects.cogging.phase_rad", -1e3, 1e3, "rad"),
    ("effects.slave_lag.delay_s", 0.0, 5e-3, "s"),
    ("effects.actuator_lag.delay_s", 0.0, 5e-3, "s"),
    ("effects.stribeck_friction.static_n", 0.0, 1e5, "N"),
    ("effects.stribeck_friction.velocity_mps", 1e-5, 10.0, "m/s"),
    ("effects.stribeck_friction.exponent", 0.1, 10.0, ""),
    ("effects.encoder_pitch_error.amplitude_m", -1e-3, 1e-3, "m"),
    ("effects.encoder_pitch_error.period_m", 1e-4, 1.0, "m"),
    ("effects.encoder_pitch_error.phase_rad", -1e3, 1e3, "rad"),
    ("effects.encoder_pitch_error.scale", -0.1, 0.1, ""),
    ("effects.encoder_pitch_error.amplitude2_m", -1e-3, 1e-3, "m"),
    ("effects.encoder_pitch_error.phase2_rad", -1e3, 1e3, "rad"),
    ("effects.encoder_pitch_error.step_m", -1e-3, 1e-3, "m"),
    ("effects.encoder_pitch_error.direction_m", -1e-3, 1e-3, "m"),
    ("effects.heat_transfer.ua_w_per_k", 0.0, 1e4, "W/K"),
    (
        "effects.heat_transfer.wall_temperature_k",
        50.0,
        1000.0,
        "K",
    ),
    ("effects.leakage.gap_m", 0.0, 1e-3, "m"),
    ("effects.leakage.seal_length_m", 1e-4, 1.0, "m"),
    ("effects.leakage.rod_gap_m", 0.0, 1e-3, "m"),
    ("effects.leakage.rod_seal_length_m", 1e-4, 1.0, "m"),
    ("effects.port_restriction.area_scale", 0.0, 10.0, ""),
    ("effects.section_misalignment.offset_m", -0.01, 0.01, "m"),
    ("simulation.substeps_per_period", 1.0, 64.0, ""),
    ("published.cycle_s", 5e-5, 0.01, "s"),
    ("published.slave_lag_s", 0.0, 0.05, "s"),
    ("published.position_gain_per_s", 0.0, 1e4, "1/s"),
    ("published.velocity_gain_ns_per_m", 0.0, 1e7, "N·s/m"),
    ("published.velocity_integral_time_s", 0.0, 10.0, "s"),
    ("published.velocity_feedforward", 0.0, 2.0, ""),
    ("published.velocity_filter_s", 0.0, 0.1, "s"),
    ("published.loop_velocity_delay_s", 0.0, 0.1, "s"),
    ("published.reported_velocity_delay_s", 0.0, 0.1, "s"),
    ("published.current_bandwidth_hz", 10.0, 5000.0, "Hz"),
    ("published.rest_s", 0.0, 60.0, "s"),
    ("published.current_limit_a", 0.0, 1000.0, "A"),
];

/// What the 12-bit ADC can carry either side of its mid-scale, codes: an encoder signal's
/// amplitude plus its offset must fit.
pub const ADC_HALF_RANGE_CODES: f64 = 2047.0;

/// Full scale of the pressure sensors, Pa (0–10 bar absolute, `machine.md`): the discharge
/// line (suction × pressure ratio) must be readable.
pub const PRESSURE_FULL_SCALE_PA: f64 = 1.0e6;

/// The range of `key` in [`RANGES`] (`None` for keys without one).
pub fn range_of(key: &str) -> Option<(f64, f64, &'static str)> {
    let plain = key
        .replace("motor.master.", "motor.")
        .replace("motor.slave.", "motor.")
        .replace("sensors.encoder_master.", "sensors.encoder.")
        .replace("sensors.encoder_slave.", "sensors.encoder.");
    RANGES
        .iter()
        .find(|(k, ..)| *k == plain)
        .map(|&(_, lo, hi, unit)| (lo, hi, unit))
}

/// `key` = `v` within its physical range.
fn in_range(key: &str, v: f64) -> Result<(), ModelError> {
    match range_of(key) {
        Some((lo, hi, unit)) if !(lo..=hi).contains(&v) => Err(ModelError(format!(
            "`{key}` = {} is outside its physical range {} ..= {}{}{unit}",
            num(v),
            num(lo),
            num(hi),
            if unit.is_empty() { "" } else { " " }
        ))),
        _ => Ok(()),
    }
}

fn check(key: &str, v: f64, rule: Rule) -> Result<(), ModelError> {
    let ok = v.is_finite()
        && match rule {
            Rule::Positive => v > 0.0,
            Rule::NonNegative => v >= 0.0,
            Rule::Finite => true,
            Rule::InUnit(max) => v > 0.0 && v <= max,
        };
    if ok {
        return in_range(key, v);
    }
    let what = match rule {
        Rule::Positive => "positive and finite".to_string(),
        Rule::NonNegative => "zero or positive".to_string(),
        Rule::Finite => "finite".to_string(),
        Rule::InUnit(max) => format!("in (0, {max}]"),
    };
    Err(ModelError(format!(
        "`{key}` must be {what}, got {}",
        num(v)
    )))
}

impl MachineModel {
    /// Checks every value of the model; the first one out of its range is named.
    pub(super) fn validate(&self) -> Result<(), ModelError> {
        use Rule::*;
        let p = &self.piston;
        let g = &self.gas;
        let m = &self.motor;
        let po = &self.ports;
        let sv = &self.servo;
        let s = &self.sensors;
        let l = &self.limits;
        let mut checks: Vec<(String, f64, Rule)> = vec![
            ("piston.mass_kg".into(), p.mass_kg, Positive),
            ("piston.bore_m".into(), p.bore_m, Positive),
            ("piston.rod_m".into(), p.rod_m, NonNegative),
            ("piston.travel_m".into(), p.travel_m, Positive),
            (
                "piston.dead_length_a_m".into(),
                p.dead_length_a_m,
                NonNegative,
            ),
            (
                "piston.dead_length_b_m".into(),
                p.dead_length_b_m,
                NonNegative,
            ),
            (
                "piston.stop_stiffness_n_per_m".into(),
                p.stop_stiffness_n_per_m,
                Positive,
            ),
            (
                "piston.stop_damping_ns_per_m".into(),
                p.stop_damping_ns_per_m,
                NonNegative,
            ),
            (
                "friction.coulomb_n".into(),
                self.friction.coulomb_n,
                NonNegative,
            ),
            (
                "friction.viscous_ns_per_m".into(),
                self.friction.viscous_ns_per_m,
                NonNegative,
            ),
            ("gas.gamma".into(), g.gamma, Positive),
            (
                "gas.gas_constant_j_per_kg_k".into(),
                g.gas_constant_j_per_kg_k,
                Positive,
            ),
            ("gas.temperature_k".into(), g.temperature_k, Positive),
            ("gas.ambient_pa".into(), g.ambient_pa, Positive),
            ("gas.viscosity_pa_s".into(), g.viscosity_pa_s, Positive),
            ("motor.pole_pitch_m".into(), m.pole_pitch_m, Positive),
            (
                "motor.force_constant_n_per_a".into(),
                m.force_constant_n_per_a,
                Positive,
            ),
            ("motor.resistance_ohm".into(), m.resistance_ohm, Positive),
            ("motor.inductance_h".into(), m.inductance_h, Positive),
            ("motor.bus_voltage_v".into(), m.bus_voltage_v, Positive),
            ("motor.current_limit_a".into(), m.current_limit_a, Positive),
            ("encoder.period_m".into(), self.encoder.period_m, Positive),
            ("ports.ramp_deg".into(), po.ramp_deg, NonNegative),
            ("ports.intake_area_m2".into(), po.intake_area_m2, Positive),
            (
                "ports.discharge_area_m2".into(),
                po.discharge_area_m2,
                Positive,
            ),
            (
                "ports.discharge_coefficient".into(),
                po.discharge_coefficient,
                InUnit(1.0),
            ),
            ("lines.suction_pa".into(), self.lines.suction_pa, Positive),
            (
                "lines.pressure_ratio".into(),
                self.lines.pressure_ratio,
                Positive,
            ),
            ("servo.inertia_kgm2".into(), sv.inertia_kgm2, Positive),
            (
                "servo.viscous_nms_per_rad".into(),
                sv.viscous_nms_per_rad,
                NonNegative,
            ),
            ("servo.coulomb_nm".into(), sv.coulomb_nm, NonNegative),
            (
                "servo.torque_full_scale_nm".into(),
                sv.torque_full_scale_nm,
                Positive,
            ),
            ("servo.torque_limit_nm".into(), sv.torque_limit_nm, Positive),
            (
                "servo.torque_time_constant_s".into(),
                sv.torque_time_constant_s,
                NonNegative,
            ),
            ("servo.backlash_rad".into(), sv.backlash_rad, NonNegative),
            (
                "sensors.current.noise_a".into(),
                s.current.noise_a,
                NonNegative,
            ),
            (
                "sensors.pressure.noise_pa".into(),
                s.pressure.noise_pa,
                NonNegative,
            ),
            (
                "sensors.pressure.time_constant_s".into(),
                s.pressure.time_constant_s,
                NonNegative,
            ),
            (
                "limits.target_head_clearance_m".into(),
                l.target_head_clearance_m,
                Positive,
            ),
            (
                "limits.min_head_clearance_m".into(),
                l.min_head_clearance_m,
                NonNegative,
            ),
            ("limits.force_limit_n".into(), l.force_limit_n, Positive),
            ("limits.max_speed_mps".into(), l.max_speed_mps, Positive),
        ];
        for (name, v) in [
            ("static_n", self.friction.static_n),
            ("stribeck_velocity_mps", self.friction.stribeck_velocity_mps),
            ("stribeck_exponent", self.friction.stribeck_exponent),
        ] {
            if let Some(v) = v {
                checks.push((format!("friction.{name}"), v, Positive));
            }
        }
        for (section, o) in [("master", &m.master), ("slave", &m.slave)] {
            for (name, v) in [
                ("force_constant_n_per_a", o.force_constant_n_per_a),
                ("resistance_ohm", o.resistance_ohm),
                ("inductance_h", o.inductance_h),
            ] {
                if let Some(v) = v {
                    checks.push((format!("motor.{section}.{name}"), v, Positive));
                }
            }
        }
        for (name, w) in [
            ("intake_a_deg", po.intake_a_deg),
            ("discharge_a_deg", po.discharge_a_deg),
            ("intake_b_deg", po.intake_b_deg),
            ("discharge_b_deg", po.discharge_b_deg),
        ] {
            for v in w {
                if !(v.is_finite() && (0.0..=360.0).contains(&v)) {
                    return Err(ModelError(format!(
                        "`ports.{name}` edges must lie in [0, 360] degrees, got {}",
                        num(v)
                    )));
                }
            }
        }
        for (name, e) in [
            ("encoder_master", &s.encoder_master),
            ("encoder_slave", &s.encoder_slave),
        ] {
            checks.push((
                format!("sensors.{name}.amplitude_codes"),
                e.amplitude_codes,
                Positive,
            ));
            checks.push((
                format!("sensors.{name}.noise_codes"),
                e.noise_codes,
                NonNegative,
            ));
            for (k, v) in [
                ("sin_offset_codes", e.sin_offset_codes),
                ("cos_offset_codes", e.cos_offset_codes),
                ("quadrature_error_rad", e.quadrature_error_rad),
            ] {
                checks.push((format!("sensors.{name}.{k}"), v, Finite));
            }
            checks.push((
                format!("sensors.{name}.gain_mismatch"),
                e.gain_mismatch,
                Finite,
            ));
        }
        for (k, v) in [
            ("offset_a_pa", s.pressure.offset_a_pa),
            ("offset_b_pa", s.pressure.offset_b_pa),
            ("offset_suction_pa", s.pressure.offset_suction_pa),
            ("offset_discharge_pa", s.pressure.offset_discharge_pa),
        ] {
            checks.push((format!("sensors.pressure.{k}"), v, Finite));
        }
        for (k, o) in [
            ("offset_master_a", s.current.offset_master_a),
            ("offset_slave_a", s.current.offset_slave_a),
        ] {
            for v in o {
                checks.push((format!("sensors.current.{k}"), v, Finite));
            }
        }
        let e = &self.effects;
        if let Some(c) = &e.cogging {
            checks.push(("effects.cogging.amplitude_n".into(), c.amplitude_n, Finite));
            checks.push(("effects.cogging.period_m".into(), c.period_m, Positive));
            checks.push(("effects.cogging.phase_rad".into(), c.phase_rad, Finite));
        }
        if let Some(d) = &e.slave_lag {
            checks.push(("effects.slave_lag.delay_s".into(), d.delay_s, NonNegative));
        }
        if let Some(d) = &e.actuator_lag {
            checks.push((
                "effects.actuator_lag.delay_s".into(),
                d.delay_s,
                NonNegative,
            ));
        }
        if let Some(st) = &e.stribeck_friction {
            checks.push((
                "effects.stribeck_friction.static_n".into(),
                st.static_n,
                NonNegative,
            ));
            checks.push((
                "effects.stribeck_friction.velocity_mps".into(),
                st.velocity_mps,
                Positive,
            ));
            checks.push((
                "effects.stribeck_friction.exponent".into(),
                st.exponent,
                Positive,
            ));
        }
        if let Some(pe) = &e.encoder_pitch_error {
            for (k, v, r) in [
                ("amplitude_m", pe.amplitude_m, Finite),
                ("period_m", pe.period_m, Positive),
                ("phase_rad", pe.phase_rad, Finite),
                ("scale", pe.scale, Finite),
                ("amplitude2_m", pe.amplitude2_m, Finite),
                ("phase2_rad", pe.phase2_rad, Finite),
                ("step_m", pe.step_m, Finite),
                ("direction_m", pe.direction_m, Finite),
            ] {
                checks.push((format!("effects.encoder_pitch_error.{k}"), v, r));
            }
        }
        if let Some(h) = &e.heat_transfer {
            checks.push((
                "effects.heat_transfer.ua_w_per_k".into(),
                h.ua_w_per_k,
                NonNegative,
            ));
            if let Some(t) = h.wall_temperature_k {
                checks.push((
                    "effects.heat_transfer.wall_temperature_k".into(),
                    t,
                    Positive,
                ));
            }
        }
        if let Some(lk) = &e.leakage {
            checks.push(("effects.leakage.gap_m".into(), lk.gap_m, NonNegative));
            checks.push((
                "effects.leakage.seal_length_m".into(),
                lk.seal_length_m,
                Positive,
            ));
            checks.push((
                "effects.leakage.rod_gap_m".into(),
                lk.rod_gap_m,
                NonNegative,
            ));
            checks.push((
                "effects.leakage.rod_seal_length_m".into(),
                lk.rod_seal_length_m,
                Positive,
            ));
        }
        if let Some(r) = &e.port_restriction {
            checks.push((
                "effects.port_restriction.area_scale".into(),
                r.area_scale,
                InUnit(10.0),
            ));
        }
        if let Some(mis) = &e.section_misalignment {
            checks.push((
                "effects.section_misalignment.offset_m".into(),
                mis.offset_m,
                Finite,
            ));
        }
        let pu = &self.published;
        for (k, v) in [
            ("cycle_s", pu.cycle_s),
            ("slave_lag_s", pu.slave_lag_s),
            ("position_gain_per_s", pu.position_gain_per_s),
            ("velocity_gain_ns_per_m", pu.velocity_gain_ns_per_m),
            ("velocity_integral_time_s", pu.velocity_integral_time_s),
            ("velocity_feedforward", pu.velocity_feedforward),
            ("velocity_filter_s", pu.velocity_filter_s),
            ("loop_velocity_delay_s", pu.loop_velocity_delay_s),
            ("reported_velocity_delay_s", pu.reported_velocity_delay_s),
            ("current_bandwidth_hz", pu.current_bandwidth_hz),
            ("rest_s", pu.rest_s),
            ("current_limit_a", pu.current_limit_a),
        ] {
            checks.push((format!("published.{k}"), v, NonNegative));
        }
        for (key, v, rule) in &checks {
            check(key, *v, *rule)?;
        }
        let periods = pu.cycle_s / f64::from(fpc::units::CONTROL_PERIOD_S);
        if (periods - periods.round()).abs() > 1e-6 {
            return Err(ModelError(format!(
                "`published.cycle_s` = {} s must be a whole number of the simulator's 50 µs \
                 periods (e.g. 1e-4, 1.5e-4, 2.5e-4)",
                num(pu.cycle_s)
            )));
        }
        if g.gamma <= 1.0 {
            return Err(ModelError(format!(
                "`gas.gamma` must exceed 1 (range above 1 ..= 1.7), got {}",
                num(g.gamma)
            )));
        }
        in_range("servo.counts_per_rev", f64::from(sv.counts_per_rev))?;
        in_range(
            "simulation.substeps_per_period",
            f64::from(self.simulation.substeps_per_period),
        )?;
        if l.min_head_clearance_m > l.target_head_clearance_m {
            return Err(ModelError(
                "`limits.min_head_clearance_m` must not exceed `limits.target_head_clearance_m`"
                    .into(),
            ));
        }
        self.check_consistency()
    }

    /// The model as a whole: values that are each in range but make no machine together.
    /// The rules are listed in [`CONSISTENCY_RULES`].
    fn check_consistency(&self) -> Result<(), ModelError> {
        let p = &self.piston;
        let l = &self.limits;
        let fail = |m: String| Err(ModelError(m));
        if p.rod_m >= p.bore_m {
            return fail(format!(
                "`piston.rod_m` = {} m must be smaller than `piston.bore_m` = {} m",
                num(p.rod_m),
                num(p.bore_m)
            ));
        }
        for (name, dead) in [("a", p.dead_length_a_m), ("b", p.dead_length_b_m)] {
            if dead >= p.travel_m {
                return fail(format!(
                    "`piston.dead_length_{name}_m` = {} m is not shorter than \
                     `piston.travel_m` = {} m: the chamber could not compress",
                    num(dead),
                    num(p.travel_m)
                ));
            }
        }
        let reserved = p.dead_length_a_m + p.dead_length_b_m + 2.0 * l.target_head_clearance_m;
        if p.travel_m <= 2.0 * reserved {
            return fail(format!(
                "`piston.travel_m` = {} m leaves no stroke: the dead lengths and twice \
                 `limits.target_head_clearance_m` take {} m, and the stroke must be at \
                 least as long again (travel above {} m)",
                num(p.travel_m),
                num(reserved),
                num(2.0 * reserved)
            ));
        }
        if self.encoder.period_m > p.travel_m {
            return fail(format!(
                "`encoder.period_m` = {} m is longer than `piston.travel_m` = {} m",
                num(self.encoder.period_m),
                num(p.travel_m)
            ));
        }
        // One section's peak force: what the motor can hold against friction and cogging.
        let m = &self.motor;
        let peak_force = m.force_constant_n_per_a * m.current_limit_a;
        let peak = || {
            format!(
                "the motor's peak force (`motor.force_constant_n_per_a` × \
                 `motor.current_limit_a` = {} N)",
                num(peak_force)
            )
        };
        if let Some(c) = &self.effects.cogging {
            let half = 0.5 * l.force_limit_n.min(peak_force);
            if c.amplitude_n.abs() >= half {
                return fail(format!(
                    "`effects.cogging.amplitude_n` = {} N is not below half of \
                     `limits.force_limit_n` = {} N and of {}: the motor could not move \
                     the piston (|amplitude| below {} N)",
                    num(c.amplitude_n),
                    num(l.force_limit_n),
                    peak(),
                    num(half)
                ));
            }
        }
        let frictions = [
            ("friction.coulomb_n", Some(self.friction.coulomb_n)),
            ("friction.static_n", self.friction.static_n),
            (
                "effects.stribeck_friction.static_n",
                self.effects.stribeck_friction.as_ref().map(|s| s.static_n),
            ),
        ];
        for (key, f) in frictions {
            if let Some(f) = f.filter(|f| *f >= peak_force) {
                return fail(format!(
                    "`{key}` = {} N is not below {}: the piston could not move",
                    num(f),
                    peak()
                ));
            }
        }
        self.check_ports()?;
        for (name, e) in [
            ("encoder_master", &self.sensors.encoder_master),
            ("encoder_slave", &self.sensors.encoder_slave),
        ] {
            let swing = e.amplitude_codes * (1.0 + e.gain_mismatch.max(0.0))
                + e.sin_offset_codes.abs().max(e.cos_offset_codes.abs());
            if swing > ADC_HALF_RANGE_CODES {
                return fail(format!(
                    "`sensors.{name}.amplitude_codes` = {} with its gain mismatch and \
                     offsets swings {} codes from mid-scale: the 12-bit ADC carries \
                     {} ..= {}",
                    num(e.amplitude_codes),
                    num(swing),
                    num(-ADC_HALF_RANGE_CODES),
                    num(ADC_HALF_RANGE_CODES)
                ));
            }
        }
        let discharge = self.lines.suction_pa * self.lines.pressure_ratio;
        if discharge > PRESSURE_FULL_SCALE_PA {
            return fail(format!(
                "`lines.suction_pa` = {} Pa × `lines.pressure_ratio` = {} is {} Pa, beyond \
                 the pressure sensors' full scale {} Pa",
                num(self.lines.suction_pa),
                num(self.lines.pressure_ratio),
                num(discharge),
                num(PRESSURE_FULL_SCALE_PA)
            ));
        }
        Ok(())
    }

    /// Each port window has a length, and no chamber is open to suction and discharge at
    /// once (the intake and discharge windows of a chamber do not overlap).
    fn check_ports(&self) -> Result<(), ModelError> {
        let po = &self.ports;
        let windows = [
            ("intake_a_deg", po.intake_a_deg),
            ("discharge_a_deg", po.discharge_a_deg),
            ("intake_b_deg", po.intake_b_deg),
            ("discharge_b_deg", po.discharge_b_deg),
        ];
        for (name, [open, close]) in windows {
            let length = (close - open).rem_euclid(360.0);
            if length < 1e-9 {
                return Err(ModelError(format!(
                    "`ports.{name}` = [{}, {}] has no length: a window opens at one edge and \
                     closes at another",
                    num(open),
                    num(close)
                )));
            }
            if 2.0 * po.ramp_deg >= length {
                return Err(ModelError(format!(
                    "`ports.ramp_deg` = {} is not below half of `ports.{name}`'s {} degrees: \
                     the window would never open fully",
                    num(po.ramp_deg),
                    num(length)
                )));
            }
        }
        for (intake, discharge) in [(windows[0], windows[1]), (windows[2], windows[3])] {
            let overlap = arc_overlap_deg(intake.1, discharge.1);
            if overlap > 1e-9 {
                return Err(ModelError(format!(
                    "`ports.{}` and `ports.{}` overlap by {} degrees: the chamber would be \
                     open to suction and discharge at once",
                    intake.0,
                    discharge.0,
                    num(overlap)
                )));
            }
        }
        Ok(())
    }
}

/// Degrees two windows `[open, close]` (edges in [0, 360], a window running forward from
/// `open` to `close` through 360 if need be) share.
fn arc_overlap_deg(a: [f64; 2], b: [f64; 2]) -> f64 {
    let span = |w: [f64; 2]| (w[1] - w[0]).rem_euclid(360.0);
    let (a0, a1) = (a[0], a[0] + span(a));
    [-360.0, 0.0, 360.0]
        .iter()
        .map(|shift| {
            let (b0, b1) = (b[0] + shift, b[0] + shift + span(b));
            (a1.min(b1) - a0.max(b0)).max(0.0)
        })
        .sum()
}

/// The whole-model rules of [`MachineModel`]'s validation, for the documentation.
pub const CONSISTENCY_RULES: &[&str] = &[
    "`piston.rod_m` < `piston.bore_m`",
    "each `piston.dead_length_*_m` < `piston.travel_m`",
    "`piston.travel_m` > 2 × (both dead lengths + 2 × `limits.target_head_clearance_m`)",
    "`limits.min_head_clearance_m` ≤ `limits.target_head_clearance_m`",
    "`encoder.period_m` ≤ `piston.travel_m`",
    "|`effects.cogging.amplitude_n`| < ½ × min(`limits.force_limit_n`, peak force)",
    "`friction.coulomb_n`, `friction.static_n`, `effects.stribeck_friction.static_n` < peak \
     force = `motor.force_constant_n_per_a` × `motor.current_limit_a`",
    "each port window has a length above 2 × `ports.ramp_deg`; a chamber's intake and \
     discharge windows do not overlap",
    "each encoder's amplitude × (1 + max(0, gain_mismatch)) + its largest offset ≤ 2047 codes",
    "`lines.suction_pa` × `lines.pressure_ratio` ≤ 1e6 Pa (the pressure sensors' full scale)",
    "`gas.gamma` > 1",
];
