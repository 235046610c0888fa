//! The drives' bridges and the electrical energy they turn over: what each section's bridge
//! delivers to its windings, what it loses itself, what the windings lose, and what the
//! rotation's servo drive draws — integrated along the run, so a cycle's electrical input and
//! the compressor's efficiency (indicated work ÷ electrical input) can be read off.
//!
//! Per section (amplitude-invariant dq, the section's own frame):
//! - **delivered** `P = 3/2·(v_d·i_d + v_q·i_q)`: the mechanical power `K_f·i_q·v`, the copper
//!   loss and the change of the windings' magnetic energy (negative while the section brakes:
//!   it regenerates);
//! - **copper loss** `3/2·R·|i|²` ([`fpc::physics::motor::MotorParams::copper_loss_w`]);
//! - **bridge loss**, a stated model of a two-level three-phase bridge (every part of it an
//!   assumption, `[supply]` in the model): in each leg one switch or diode carries the phase
//!   current at any instant, so conduction costs `V_0·|i_k| + r·i_k²`; each PWM period the leg
//!   switches its current once on and once off against the link, costing `E·V_dc·|i_k|` with
//!   `E` the switching energy per volt and ampere switched; the PWM frequency is the
//!   control rate (20 kHz). Summed over the three phases.
//!
//! The servo draws its shaft power `τ·ω` at `1/η` while it drives (what it brakes is burnt in
//! its own drive), as the DC link's model has it ([`crate::plant::supply`]).
//!
//! **Electrical input** of an interval = both sections' delivered energy + both bridges'
//! losses + the servo's draw. Regenerated energy counts against it: the DC link stores it and
//! the next acceleration uses it again (the link's 2 mF hold ≈ 250 J between the nominal
//! 560 V and the chopper's 750 V; what a stroke returns is reported beside it,
//! [`ElectricalTotals::regenerated_j`]). The logic supply's constant draw is left out: no
//! controller changes it.
//!
//! **The sections' fight**: two sections that make the same total force lose least when they
//! carry equal currents; `|i_m|² + |i_s|² = 2·|ī|² + ½·|i_m − i_s|²`. What the I²-losses
//! (copper and the bridges' `r`) would have been with both carrying the mean current `ī`,
//! subtracted from what they were, is the fight's cost ([`ElectricalTotals::fight_j`]); the
//! losses linear in `|i|` are not split.

use fpc::physics::motor::{inverse_clarke, inverse_park, park, AlphaBeta, Dq, MotorParams};
use fpc::units::{PerSection, Section};

/// The bridge-loss model's parameters (one bridge per section, alike), SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BridgeParams {
    /// Knee voltage of a conducting switch or diode, V.
    pub forward_voltage_v: f64,
    /// Slope resistance of a conducting switch or diode, Ω.
    pub on_resistance_ohm: f64,
    /// Turn-on plus turn-off energy per volt of link and ampere switched, J/(V·A).
    pub switching_energy_j_per_va: f64,
    /// PWM frequency, Hz.
    pub switching_frequency_hz: f64,
    /// The servo drive's efficiency (its shaft power is drawn at 1/η).
    pub servo_efficiency: f64,
}

impl BridgeParams {
    /// Loss of one bridge carrying phase currents `phases_a` from a link at `bus_v`, W.
    pub fn loss_w(&self, phases_a: [f64; 3], bus_v: f64) -> f64 {
        let per_amp = self.forward_voltage_v
            + self.switching_frequency_hz * self.switching_energy_j_per_va * bus_v;
        phases_a
            .iter()
            .map(|i| per_amp * i.abs() + self.on_resistance_ohm * i * i)
            .sum()
    }
}

/// Energies since the plant was made, J (cumulative: a cycle's is the difference of two
/// snapshots).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ElectricalTotals {
    /// Delivered by each bridge to its section (regeneration counted negative).
    pub delivered_j: PerSection<f64>,
    /// Lost in each section's windings.
    pub copper_j: PerSection<f64>,
    /// Lost in each section's bridge.
    pub bridge_loss_j: PerSection<f64>,
    /// Drawn by the servo drive.
    pub servo_j: f64,
    /// Returned to the link by the two sections together while they brake.
    pub regenerated_j: f64,
    /// The I²-losses the sections' unequal currents added (the fight's cost).
    pub fight_j: f64,
}

impl ElectricalTotals {
    /// What the link gave: both sections' delivered energy, both bridges' losses and the
    /// servo's draw.
    pub fn input_j(&self) -> f64 {
        self.delivered_j.master
            + self.delivered_j.slave
            + self.bridge_loss_j.master
            + self.bridge_loss_j.slave
            + self.servo_j
    }

    /// Both sections' copper loss.
    pub fn copper_total_j(&self) -> f64 {
        self.copper_j.master + self.copper_j.slave
    }

    /// Both bridges' loss.
    pub fn bridge_loss_total_j(&self) -> f64 {
        self.bridge_loss_j.master + self.bridge_loss_j.slave
    }

    /// `self − earlier`: the energies of the interval between two snapshots.
    pub fn since(&self, earlier: &ElectricalTotals) -> ElectricalTotals {
        let d = |a: PerSection<f64>, b: PerSection<f64>| PerSection {
            master: a.master - b.master,
            slave: a.slave - b.slave,
        };
        ElectricalTotals {
            delivered_j: d(self.delivered_j, earlier.delivered_j),
            copper_j: d(self.copper_j, earlier.copper_j),
            bridge_loss_j: d(self.bridge_loss_j, earlier.bridge_loss_j),
            servo_j: self.servo_j - earlier.servo_j,
            regenerated_j: self.regenerated_j - earlier.regenerated_j,
            fight_j: self.fight_j - earlier.fight_j,
        }
    }

    /// The mean of `(later − earlier)/count`: an interval's energies per cycle.
    pub fn per(&self, count: f64) -> ElectricalTotals {
        let s = |p: PerSection<f64>| PerSection {
            master: p.master / count,
            slave: p.slave / count,
        };
        ElectricalTotals {
            delivered_j: s(self.delivered_j),
            copper_j: s(self.copper_j),
            bridge_loss_j: s(self.bridge_loss_j),
            servo_j: self.servo_j / count,
            regenerated_j: self.regenerated_j / count,
            fight_j: self.fight_j / count,
        }
    }
}

/// One section as the accounting sees it over a step.
#[derive(Clone, Copy, Debug)]
pub struct SectionState<'a> {
    /// Its electrical parameters.
    pub motor: &'a MotorParams<f64>,
    /// Its stator-frame voltage over the step (`None`: bridge off).
    pub voltage: Option<AlphaBeta<f64>>,
    /// Its current in its own frame at the step's start and at its end, A (the explicit
    /// current step makes it linear in between).
    pub current: (Dq<f64>, Dq<f64>),
    /// (sin, cos) of its electrical angle over the step.
    pub angle: (f64, f64),
}

/// The mean of `x²` over a step on which `x` goes linearly from `a` to `b`.
fn mean_sq(a: f64, b: f64) -> f64 {
    (a * a + a * b + b * b) / 3.0
}

/// The mean of `|i|²` over a step on which the dq current goes linearly from `a` to `b`.
fn mean_sq_dq(a: Dq<f64>, b: Dq<f64>) -> f64 {
    mean_sq(a.d, b.d) + mean_sq(a.q, b.q)
}

fn mid(a: Dq<f64>, b: Dq<f64>) -> Dq<f64> {
    Dq {
        d: 0.5 * (a.d + b.d),
        q: 0.5 * (a.q + b.q),
    }
}

impl ElectricalTotals {
    /// Adds a step of `dt_s` with the sections as `sections` say, the link at `bus_v` and
    /// the servo's shaft power `servo_w`. The voltage is held over the step and the current
    /// moves linearly, so the delivered energy is the voltage times the mean current and
    /// the I²-losses take the mean of the square (a current chattering from step to step
    /// then costs what it really does).
    pub fn add(
        &mut self,
        bridge: &BridgeParams,
        sections: PerSection<SectionState<'_>>,
        bus_v: f64,
        servo_w: f64,
        dt_s: f64,
    ) {
        let mut delivered_w = 0.0;
        for s in Section::ALL {
            let st = sections.get(s);
            let Some(v) = st.voltage else { continue };
            let (sin, cos) = st.angle;
            let vdq = park(v, sin, cos);
            let (i0, i1) = st.current;
            let i = mid(i0, i1);
            let p = 1.5 * (vdq.d * i.d + vdq.q * i.q);
            delivered_w += p;
            *self.delivered_j.get_mut(s) += p * dt_s;
            *self.copper_j.get_mut(s) += 1.5 * st.motor.resistance_ohm * mean_sq_dq(i0, i1) * dt_s;
            let phases = inverse_clarke(inverse_park(i, sin, cos));
            // The knee and switching parts at the mean current; the slope resistance's at the
            // mean square (3/2·r·|i|² over the three phases).
            let linear = bridge.loss_w(phases, bus_v)
                - bridge.on_resistance_ohm * 1.5 * (i.d * i.d + i.q * i.q);
            *self.bridge_loss_j.get_mut(s) +=
                (linear + 1.5 * bridge.on_resistance_ohm * mean_sq_dq(i0, i1)) * dt_s;
        }
        self.regenerated_j += (-delivered_w).max(0.0) * dt_s;
        self.servo_j += servo_w.max(0.0) / bridge.servo_efficiency * dt_s;
        // The fight: the I²-losses over what the mean current would have cost.
        let (m, sl) = (sections.master, sections.slave);
        if m.voltage.is_some() && sl.voltage.is_some() {
            let r = |st: &SectionState| 1.5 * (st.motor.resistance_ohm + bridge.on_resistance_ohm);
            let shared = (
                mid(m.current.0, sl.current.0),
                mid(m.current.1, sl.current.1),
            );
            let actual = r(&m) * mean_sq_dq(m.current.0, m.current.1)
                + r(&sl) * mean_sq_dq(sl.current.0, sl.current.1);
            let even = (r(&m) + r(&sl)) * mean_sq_dq(shared.0, shared.1);
            self.fight_j += (actual - even) * dt_s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bridge() -> BridgeParams {
        BridgeParams {
            forward_voltage_v: 1.0,
            on_resistance_ohm: 0.02,
            switching_energy_j_per_va: 2e-7,
            switching_frequency_hz: 20_000.0,
            servo_efficiency: 0.85,
        }
    }

    #[test]
    fn the_bridge_loses_conduction_and_switching_per_phase() {
        // 10 A in one phase returning through the other two (5 A each), 560 V link:
        // per ampere 1 V + 20 kHz·2e-7·560 = 3.24 V; 3.24·20 + 0.02·(100 + 25 + 25).
        let loss = bridge().loss_w([10.0, -5.0, -5.0], 560.0);
        assert!((loss - (3.24 * 20.0 + 0.02 * 150.0)).abs() < 1e-9, "{loss}");
    }

    #[test]
    fn equal_sections_cost_no_fight_and_unequal_ones_the_difference_squared() {
        let motor = MotorParams::<f64>::reference();
        let angle = (0.3f64.sin(), 0.3f64.cos());
        let at = |q: f64| SectionState {
            motor: &motor,
            voltage: Some(AlphaBeta::default()),
            current: (Dq { d: 0.0, q }, Dq { d: 0.0, q }),
            angle,
        };
        let mut e = ElectricalTotals::default();
        e.add(
            &bridge(),
            PerSection {
                master: at(10.0),
                slave: at(10.0),
            },
            560.0,
            0.0,
            1.0,
        );
        assert!(e.fight_j.abs() < 1e-9);
        let mut f = ElectricalTotals::default();
        f.add(
            &bridge(),
            PerSection {
                master: at(14.0),
                slave: at(6.0),
            },
            560.0,
            0.0,
            1.0,
        );
        // 3/2·(R + r)·½·Δ² with Δ = 8 A: 1.5·0.62·32.
        assert!(
            (f.fight_j - 1.5 * 0.62 * 32.0).abs() < 1e-5,
            "{}",
            f.fight_j
        );
        assert!(f.copper_total_j() > e.copper_total_j());
    }

    #[test]
    fn delivered_power_is_what_the_windings_take() {
        // A voltage along q at rest: P = 3/2·v_q·i_q, regeneration when they oppose.
        let motor = MotorParams::<f64>::reference();
        let angle = (0.0, 1.0);
        let st = |vq: f64, iq: f64| SectionState {
            motor: &motor,
            voltage: Some(AlphaBeta {
                alpha: 0.0,
                beta: vq,
            }),
            current: (Dq { d: 0.0, q: iq }, Dq { d: 0.0, q: iq }),
            angle,
        };
        let mut e = ElectricalTotals::default();
        e.add(
            &bridge(),
            PerSection {
                master: st(100.0, 5.0),
                slave: st(-100.0, 5.0),
            },
            560.0,
            50.0,
            0.5,
        );
        assert!((e.delivered_j.master - 375.0).abs() < 1e-9);
        assert!((e.delivered_j.slave + 375.0).abs() < 1e-9);
        assert_eq!(e.regenerated_j, 0.0); // the two cancel in the shared link
        assert!((e.servo_j - 50.0 / 0.85 * 0.5).abs() < 1e-9);
        let input = e.input_j();
        assert!((input - e.bridge_loss_total_j() - e.servo_j).abs() < 1e-9);
    }

    #[test]
    fn a_current_chattering_about_zero_takes_no_energy_but_its_copper_loss() {
        // A voltage alternating every step drives the current from −I to +I and back: the
        // voltage meets the mean current (zero) — no energy delivered — while the windings
        // lose R·I²/3 on average.
        let motor = MotorParams::<f64>::reference();
        let st = |vq: f64, i0: f64, i1: f64| SectionState {
            motor: &motor,
            voltage: Some(AlphaBeta {
                alpha: 0.0,
                beta: vq,
            }),
            current: (Dq { d: 0.0, q: i0 }, Dq { d: 0.0, q: i1 }),
            angle: (0.0, 1.0),
        };
        let mut e = ElectricalTotals::default();
        for k in 0..10 {
            let (v, i0, i1) = if k % 2 == 0 {
                (300.0, -2.0, 2.0)
            } else {
                (-300.0, 2.0, -2.0)
            };
            let off = SectionState {
                voltage: None,
                ..st(0.0, 0.0, 0.0)
            };
            e.add(
                &bridge(),
                PerSection {
                    master: st(v, i0, i1),
                    slave: off,
                },
                560.0,
                0.0,
                50e-6,
            );
        }
        assert!(e.delivered_j.master.abs() < 1e-12);
        let copper = 1.5 * motor.resistance_ohm * 4.0 / 3.0 * 10.0 * 50e-6;
        assert!((e.copper_j.master - copper).abs() < 1e-9 * copper.max(1.0));
    }
}
