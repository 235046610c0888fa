//! Validation of a parsed model: every value checked for its physical kind (positive,
//! non-negative, finite, a fraction), with an error naming the key.

use super::{MachineModel, ModelError};

/// What a value must be.
#[derive(Clone, Copy)]
enum Rule {
    Positive,
    NonNegative,
    Finite,
    /// A fraction-like factor in (0, max].
    InUnit(f64),
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
        return Ok(());
    }
    let what = match rule {
        Rule::Positive => "positive and finite".to_string(),
        Rule::NonNegative => "zero or positive".to_string(),
        Rule::Finite => "finite".to_string(),
        Rule::InUnit(max) => format!("in (0, {max}]"),
    };
    Err(ModelError(format!("`{key}` must be {what}, got {v}")))
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
                        "`ports.{name}` edges must lie in [0, 360] degrees, got {v}"
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
            if !(e.gain_mismatch.is_finite() && e.gain_mismatch > -1.0) {
                return Err(ModelError(format!(
                    "`sensors.{name}.gain_mismatch` must be finite and above −1, got {}",
                    e.gain_mismatch
                )));
            }
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
        for (key, v, rule) in &checks {
            check(key, *v, *rule)?;
        }
        if p.rod_m >= p.bore_m {
            return Err(ModelError(
                "`piston.rod_m` must be smaller than `piston.bore_m`".into(),
            ));
        }
        if g.gamma <= 1.0 {
            return Err(ModelError(format!(
                "`gas.gamma` must exceed 1, got {}",
                g.gamma
            )));
        }
        if sv.counts_per_rev == 0 {
            return Err(ModelError("`servo.counts_per_rev` must be positive".into()));
        }
        let sub = self.simulation.substeps_per_period;
        if !(1..=64).contains(&sub) {
            return Err(ModelError(format!(
                "`simulation.substeps_per_period` must be in [1, 64], got {sub}"
            )));
        }
        if l.min_head_clearance_m > l.target_head_clearance_m {
            return Err(ModelError(
                "`limits.min_head_clearance_m` must not exceed `limits.target_head_clearance_m`"
                    .into(),
            ));
        }
        Ok(())
    }
}
