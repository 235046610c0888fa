//! The drive board's supply: the DC link both motor sections and the servo drive share, its
//! brake chopper, and the logic supply taken from it (`[supply]` in the machine model).
//!
//! While the mains is present its rectifier holds the link at the nominal voltage
//! (`motor.bus_voltage_v`; ripple and regeneration pulses within a cycle are neglected, so a
//! run without a power cut is the fixed-bus plant it always was). Once the mains stops the
//! link is on its own, and each sub-step its energy `½·C·V²` changes by
//!
//! `−(P_master + P_slave + P_servo + P_logic)·dt`
//!
//! where `P_section = 3/2·(v_d·i_d + v_q·i_q)` is the electrical power the bridge delivers to
//! the section (amplitude-invariant dq: copper losses, the mechanical power `K_f·i_q·v` and
//! the change of the magnetic energy; negative while it brakes, which charges the link),
//! `P_servo = max(0, τ·ω)/η` the servo drive's draw (what it brakes it burns itself) and
//! `P_logic` the logic's constant draw. Above the chopper's threshold the surplus is burnt in
//! the chopper's resistor (counted in [`Link::chopped_j`]): the link's voltage limit is the
//! hardware's, the firmware never has to hold regeneration back. Below the logic supply's
//! dropout the MCU is off ([`Link::logic_powered`]); below the power-good threshold the
//! board's undervoltage input reads low ([`Link::power_good`]).
//!
//! Neglected, both on the safe side: the magnetic energy a section's windings return through
//! the diodes when its bridge switches off (≈ 3/2·L·i² ≤ 35 J at the current limit), and the
//! rectifier's own capacitance.

use crate::plant::model::MachineModel;

/// The supply's parameters, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SupplyParams {
    /// DC-link capacitance, F.
    pub capacitance_f: f64,
    /// Nominal link voltage (the mains rectifier's), V.
    pub nominal_v: f64,
    /// Brake chopper threshold (the link's voltage limit), V.
    pub chopper_v: f64,
    /// Power-good comparator threshold, V.
    pub power_good_v: f64,
    /// The logic supply's lowest input, V.
    pub logic_dropout_v: f64,
    /// The logic's draw, W.
    pub logic_power_w: f64,
    /// The servo drive's efficiency.
    pub servo_efficiency: f64,
}

impl SupplyParams {
    /// The supply a model describes.
    pub fn from_model(model: &MachineModel) -> Self {
        let s = &model.supply;
        SupplyParams {
            capacitance_f: s.link_capacitance_f,
            nominal_v: model.motor.bus_voltage_v,
            chopper_v: s.chopper_voltage_v,
            power_good_v: s.power_good_voltage_v,
            logic_dropout_v: s.logic_dropout_voltage_v,
            logic_power_w: s.logic_power_w,
            servo_efficiency: s.servo_efficiency,
        }
    }

    /// Energy the link holds at `v`, J.
    pub fn energy_j(&self, v: f64) -> f64 {
        0.5 * self.capacitance_f * v * v
    }
}

/// The DC link's state.
#[derive(Clone, Debug, PartialEq)]
pub struct Link {
    /// Parameters.
    pub params: SupplyParams,
    /// Link voltage, V.
    pub voltage_v: f64,
    /// The mains is present (the rectifier holds the nominal voltage).
    pub mains: bool,
    /// Energy the brake chopper has burnt since the mains stopped, J.
    pub chopped_j: f64,
    /// Highest link voltage since the mains stopped, V.
    pub peak_v: f64,
    /// Lowest link voltage since the mains stopped, V.
    pub lowest_v: f64,
}

impl Link {
    /// A link at its nominal voltage, the mains present.
    pub fn new(params: SupplyParams) -> Self {
        Link {
            voltage_v: params.nominal_v,
            mains: true,
            chopped_j: 0.0,
            peak_v: params.nominal_v,
            lowest_v: params.nominal_v,
            params,
        }
    }

    /// The mains stops: from now the link runs on its own energy.
    pub fn cut(&mut self) {
        self.mains = false;
        self.chopped_j = 0.0;
        self.peak_v = self.voltage_v;
        self.lowest_v = self.voltage_v;
    }

    /// The mains is back: the rectifier recharges the link to its nominal voltage.
    pub fn restore(&mut self) {
        self.mains = true;
        self.voltage_v = self.params.nominal_v;
    }

    /// Energy the link holds now, J.
    pub fn energy_j(&self) -> f64 {
        self.params.energy_j(self.voltage_v)
    }

    /// The factor on every section's bus voltage: the link's voltage over its nominal one
    /// (exactly 1 while the mains holds it).
    #[inline]
    pub fn bus_scale(&self) -> f64 {
        if self.mains {
            1.0
        } else {
            self.voltage_v / self.params.nominal_v
        }
    }

    /// Whether the logic supply (MCU, gate drivers, sensors) still runs.
    pub fn logic_powered(&self) -> bool {
        self.voltage_v >= self.params.logic_dropout_v
    }

    /// What the board's power-good input reads: the link at or above the comparator's
    /// threshold.
    pub fn power_good(&self) -> bool {
        self.voltage_v >= self.params.power_good_v
    }

    /// One sub-step of `dt` s without the mains: `sections_w` drawn by the motor sections
    /// (negative: regenerated), the servo's shaft power `servo_w` (drawn at 1/η when
    /// positive); the logic's draw while it runs. The chopper clamps the top; an empty link
    /// stays at 0 V.
    pub fn discharge(&mut self, sections_w: f64, servo_w: f64, dt: f64) {
        let p = &self.params;
        let logic_w = if self.logic_powered() {
            p.logic_power_w
        } else {
            0.0
        };
        let drawn_w = sections_w + servo_w.max(0.0) / p.servo_efficiency + logic_w;
        let mut e = self.energy_j() - drawn_w * dt;
        let limit_j = p.energy_j(p.chopper_v);
        if e > limit_j {
            self.chopped_j += e - limit_j;
            e = limit_j;
        }
        self.voltage_v = (2.0 * e.max(0.0) / p.capacitance_f).sqrt();
        self.peak_v = self.peak_v.max(self.voltage_v);
        self.lowest_v = self.lowest_v.min(self.voltage_v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn link() -> Link {
        Link::new(SupplyParams::from_model(&MachineModel::reference()))
    }

    #[test]
    fn the_link_loses_what_is_drawn_and_the_chopper_clamps_what_comes_back() {
        let mut l = link();
        l.cut();
        let e0 = l.energy_j();
        // 1 kW drawn by the sections for 10 ms, the servo idle: 10 J plus the logic's.
        for _ in 0..200 {
            l.discharge(1000.0, 0.0, 50e-6);
        }
        let logic_j = l.params.logic_power_w * 0.01;
        assert!((e0 - l.energy_j() - 10.0 - logic_j).abs() < 1e-9);
        // 100 kW regenerated for 10 ms: far beyond the chopper's limit.
        for _ in 0..200 {
            l.discharge(-100_000.0, 0.0, 50e-6);
        }
        assert!((l.voltage_v - l.params.chopper_v).abs() < 1e-9);
        assert!(l.chopped_j > 0.0);
        assert!(l.power_good() && l.logic_powered());
        // The servo braking draws nothing; driving, its shaft power over η.
        let before = l.energy_j();
        l.discharge(0.0, -500.0, 1e-3);
        let logic_j = l.params.logic_power_w * 1e-3;
        assert!((before - l.energy_j() - logic_j).abs() < 1e-9);
        let before = l.energy_j();
        l.discharge(0.0, 85.0, 1e-3);
        assert!((before - l.energy_j() - 0.1 - logic_j).abs() < 1e-9);
    }

    #[test]
    fn an_empty_link_turns_the_logic_off_and_the_mains_brings_it_back() {
        let mut l = link();
        assert_eq!(l.bus_scale(), 1.0);
        l.cut();
        while l.logic_powered() {
            l.discharge(5000.0, 0.0, 1e-3);
        }
        assert!(!l.power_good());
        assert!(l.bus_scale() < 0.3);
        l.restore();
        assert_eq!(l.voltage_v, l.params.nominal_v);
        assert_eq!(l.bus_scale(), 1.0);
    }
}
