//! The physical plant: the piston (one moving mass between two heads), the two motor
//! sections, the rotation, and the gas in both chambers, configured by the machine model.
//!
//! `m·ẍ = F_master + F_slave + (p_A − p_B)·A_eff + F_cog(x) − F_fr + F_stop` (`docs/machine.md`;
//! the balance is the library's, [`fpc::physics::balance`]). State is `f64`; every law is
//! the library's own, evaluated in `f64`. The plant advances in fixed sub-steps inside each
//! 50 µs control period with the PWM duties held, as the averaged inverter applies them:
//! currents (explicit), piston (semi-implicit Euler, friction implicit through its secant
//! coefficient), rotation, then the chambers with the new volumes ([`crate::plant::chambers`]).
//!
//! **Friction of a rotating, translating piston**: the sliding surface (radius `bore/2`) moves
//! with the velocity vector `(ẋ, ω·r)`; the friction law's force, of magnitude `F(|u|)`, acts
//! against that vector. Its axial part `F·ẋ/|u|` brakes the translation, its tangential part
//! times `r` loads the servo. While the piston turns, the axial friction no longer sticks at a
//! reversal: it becomes viscous-like, `F(|u|)/|u|·ẋ`.
//!
//! **Sub-steps.** One per control period is accurate for this machine: over 50 µs the
//! electrical pole moves R·dt/L = 0.5 %, the electrical angle at 4.5 m/s 0.06 rad, the stiffest
//! mechanical mode (end-stop contact, √(k/m) ≈ 2000 rad/s) ω·dt = 0.1, and the stiff gas flows are
//! integrated implicitly; `[simulation] substeps_per_period` raises it for checks.
//!
//! Line pressures and the port mode are inputs: [`Plant::lines`] (set during a run with
//! [`Lines::set_pressure_ratio`] and friends) and [`Plant::port_mode`].

use fpc::angle::wrap_rad;
use fpc::drive::foc::phase_voltages;
use fpc::physics::balance::{implicit_velocity, PistonForces};
use fpc::physics::cogging::CoggingParams;
use fpc::physics::friction::FrictionParams;
use fpc::physics::motor::{clarke, AlphaBeta, Dq};
use fpc::units::{PerSection, PhaseDuties, Section, CONTROL_PERIOD_S};

use crate::plant::bridge::{BridgeParams, ElectricalTotals, SectionState};
use crate::plant::chambers::{ChamberParams, Chambers, Lines, PortMode};
use crate::plant::model::extra_force::{ExtraForce, ExtraState, Term};
use crate::plant::model::MachineModel;
use crate::plant::motor::{SectionParams, Sections};
use crate::plant::servo::{Rotation, ServoParams};
use crate::plant::supply::{Link, SupplyParams};

/// Parameters of the plant, SI.
#[derive(Clone, Debug, PartialEq)]
pub struct PlantParams {
    /// Moving mass, kg.
    pub mass_kg: f64,
    /// Head-to-head travel, m.
    pub travel_m: f64,
    /// Friction law of the sliding surface.
    pub friction: FrictionParams<f64>,
    /// Radius at which the sliding friction acts on the rotation, m.
    pub friction_radius_m: f64,
    /// End-stop contact stiffness, N/m.
    pub stop_stiffness_n_per_m: f64,
    /// End-stop contact damping, N·s/m.
    pub stop_damping_ns_per_m: f64,
    /// Motor sections.
    pub sections: SectionParams,
    /// Cogging, if present.
    pub cogging: Option<CoggingParams<f64>>,
    /// A force no named effect describes (`[effects.extra_force]`), if present.
    pub extra_force: Option<ExtraForce>,
    /// Chambers, ports, leaks, heat transfer.
    pub chambers: ChamberParams,
    /// Rotation.
    pub servo: ServoParams,
    /// Suction pressure, Pa, and pressure ratio at the start.
    pub lines: (f64, f64),
    /// Suction temperature, K.
    pub suction_temperature_k: f64,
    /// Sub-steps per control period.
    pub substeps: u32,
    /// The drive board's supply (DC link, chopper, logic supply).
    pub supply: SupplyParams,
    /// The sections' bridges' loss model and the servo drive's efficiency.
    pub bridge: BridgeParams,
}

impl PlantParams {
    /// The plant a model describes.
    pub fn from_model(model: &MachineModel) -> Self {
        let (piston_leak, rod_leak) = model.leaks();
        let ht = model.effects.heat_transfer.as_ref();
        PlantParams {
            mass_kg: model.piston.mass_kg,
            travel_m: model.piston.travel_m,
            friction: model.friction(),
            friction_radius_m: model.friction_radius_m(),
            stop_stiffness_n_per_m: model.piston.stop_stiffness_n_per_m,
            stop_damping_ns_per_m: model.piston.stop_damping_ns_per_m,
            sections: SectionParams {
                motor: model.motor_sections(),
                slave_offset_m: model
                    .effects
                    .section_misalignment
                    .as_ref()
                    .map_or(0.0, |m| m.offset_m),
                slave_lag_s: model.slave_lag_s(),
                actuator_lag_s: model.effects.actuator_lag.as_ref().map(|l| l.delay_s),
            },
            cogging: model.cogging(),
            extra_force: model.effects.extra_force.as_ref().map(ExtraForce::from),
            chambers: ChamberParams {
                cylinder: model.cylinder(),
                gas: model.gas_properties(),
                ports: model.port_geometry(),
                port_area_scale: model.port_area_scale(),
                piston_leak,
                rod_leak,
                ua_w_per_k: ht.map_or(0.0, |h| h.ua_w_per_k),
                wall_temperature_k: ht
                    .and_then(|h| h.wall_temperature_k)
                    .unwrap_or(model.gas.temperature_k),
                ambient_pa: model.gas.ambient_pa,
                ambient_temperature_k: model.gas.temperature_k,
            },
            servo: ServoParams::from_model(&model.servo),
            lines: (model.lines.suction_pa, model.lines.pressure_ratio),
            suction_temperature_k: model.gas.temperature_k,
            substeps: model.simulation.substeps_per_period,
            supply: SupplyParams::from_model(model),
            bridge: BridgeParams {
                forward_voltage_v: model.supply.bridge_forward_voltage_v,
                on_resistance_ohm: model.supply.bridge_on_resistance_ohm,
                switching_energy_j_per_va: model.supply.bridge_switching_energy_j_per_va,
                // The bridges switch once per control period (centred PWM at the control rate).
                switching_frequency_hz: 1.0 / f64::from(CONTROL_PERIOD_S),
                servo_efficiency: model.supply.servo_efficiency,
            },
        }
    }

    /// The reference machine (the embedded model file).
    pub fn reference() -> Self {
        Self::from_model(&MachineModel::reference())
    }
}

/// What the controller applies to the plant during one period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Drive {
    /// Duties of each section, or `None` for a section whose outputs are off.
    pub duties: PerSection<Option<PhaseDuties>>,
    /// Servo torque command, N·m.
    pub servo_torque_nm: f64,
}

/// The plant's state.
#[derive(Clone, Debug, PartialEq)]
pub struct Plant {
    /// Parameters.
    pub params: PlantParams,
    /// Piston position, m (0 = head A).
    pub x_m: f64,
    /// Piston velocity, m/s.
    pub v_mps: f64,
    /// Piston acceleration of the last sub-step, m/s².
    pub a_mps2: f64,
    /// The rotation (servo side and piston side).
    pub rotation: Rotation,
    /// The motor sections.
    pub motors: Sections,
    /// d/q currents of each section (copy of `motors.current`), A.
    pub current: PerSection<Dq<f64>>,
    /// Force of each section in the last sub-step (copy of `motors.force_n`), N.
    pub force_n: PerSection<f64>,
    /// Force of the end stops in the last sub-step, N.
    pub stop_force_n: f64,
    /// Axial friction force in the last sub-step (opposing +x motion when positive), N.
    pub friction_force_n: f64,
    /// Cogging force in the last sub-step, toward +x, N.
    pub cogging_force_n: f64,
    /// Extra force (`[effects.extra_force]`) at the last sub-step, N.
    pub extra_force_n: f64,
    /// Time since the plant was made, s (the `t` of the extra force's terms).
    pub elapsed_s: f64,
    /// The two chambers.
    pub chambers: Chambers,
    /// Suction and discharge lines (an input: set them during a run).
    pub lines: Lines,
    /// How the chambers connect to the lines (an input).
    pub port_mode: PortMode,
    /// Faults injected into the machine (`fpc-sim run --fault`; none by default).
    pub injected: PlantFaults,
    /// The drive board's DC link (held at its nominal voltage while the mains is present).
    pub supply: Link,
    /// The electrical energies since the plant was made ([`crate::plant::bridge`]).
    pub electrical: ElectricalTotals,
    /// Stator-frame voltages of the period being simulated (`None`: that bridge is off).
    voltages: PerSection<Option<AlphaBeta<f64>>>,
}

impl Plant {
    /// A plant at rest at `x_m`, chambers at ambient pressure, ports timed by the rotation.
    pub fn new(params: PlantParams, x_m: f64) -> Self {
        let dt = CONTROL_PERIOD_S as f64 / f64::from(params.substeps.max(1));
        let (suction_pa, pr) = params.lines;
        let c = &params.chambers;
        let lines = Lines::new(suction_pa, params.suction_temperature_k, pr, c.gas.gamma);
        let chambers = Chambers::new(c.clone(), x_m, c.ambient_pa, c.ambient_temperature_k);
        let motors = Sections::new(params.sections.clone(), x_m, dt);
        Plant {
            x_m,
            v_mps: 0.0,
            a_mps2: 0.0,
            rotation: Rotation::default(),
            current: motors.current,
            force_n: motors.force_n,
            motors,
            stop_force_n: 0.0,
            friction_force_n: 0.0,
            cogging_force_n: 0.0,
            extra_force_n: 0.0,
            elapsed_s: 0.0,
            chambers,
            lines,
            port_mode: PortMode::Timed,
            injected: Default::default(),
            supply: Link::new(params.supply),
            electrical: ElectricalTotals::default(),
            voltages: PerSection::default(),
            params,
        }
    }

    /// Electrical angle of the master section at the current position, rad.
    pub fn electrical_angle(&self) -> f64 {
        std::f64::consts::TAU * self.x_m / self.motors.electrical_period_m()
    }

    /// The larger force-producing (q) current of the two sections, magnitude, A.
    pub fn largest_q_current_a(&self) -> f64 {
        self.current.master.q.abs().max(self.current.slave.q.abs())
    }

    /// Phase currents of `section`, A.
    pub fn phase_currents(&self, section: Section) -> [f64; 3] {
        self.motors.phase_currents(section)
    }

    /// Rotation phase of the piston, φ = θ mod 2π, rad (what times the ports).
    pub fn port_phase_rad(&self) -> f64 {
        wrap_rad(self.rotation.piston_angle_rad)
    }

    /// Advances the plant by `period_s` with `drive` held.
    pub fn advance(&mut self, drive: &Drive, period_s: f64) {
        let n = self.params.substeps.max(1);
        let dt = period_s / f64::from(n);
        // The duties are held over the period: their stator-frame voltages once (none for a
        // section whose bridge is off), on the link's voltage at the start of the period.
        let scale = self.supply.bus_scale();
        let ab = |s: Section| {
            let bus = self.params.sections.motor.get(s).bus_voltage_v * scale;
            drive
                .duties
                .get(s)
                .as_ref()
                .map(|d| clarke(phase_voltages(d, bus)))
        };
        self.voltages = PerSection {
            master: ab(Section::Master),
            slave: ab(Section::Slave),
        };
        for _ in 0..n {
            self.substep(drive.servo_torque_nm, dt);
        }
    }

    fn substep(&mut self, servo_torque_nm: f64, dt: f64) {
        let voltages = self.voltages;
        if !self.supply.mains {
            // What the bridges deliver over this sub-step (the currents at its start, as the
            // explicit current step uses them) and the servo's shaft power, from the link.
            let sections_w = self.bridge_power_w();
            let servo_w = self.rotation.torque_nm * self.rotation.servo_speed_rad_s;
            self.supply.discharge(sections_w, servo_w, dt);
        }
        let start = self.motors.current;
        self.motors.step(&voltages, self.v_mps, dt);
        self.account_electrical(start, dt);
        if self.injected.any_section_dead() {
            self.injected.kill_sections(&mut self.motors);
        }
        self.current = self.motors.current;
        self.force_n = self.motors.force_n;

        let p = &self.params;
        let stop = self.stop_force();
        self.stop_force_n = stop;
        self.cogging_force_n = match &p.cogging {
            Some(c) => cogging_force_n(c, &self.motors, self.x_m),
            None => 0.0,
        };
        // The extra force at this sub-step's state; its term in the acceleration (`a`) acts
        // as a change of the moving mass, `(m − c_a)·a = ΣF`, so it is implicit.
        let motor_n = self.force_n.master + self.force_n.slave;
        let (extra_n, mass_kg) = match &p.extra_force {
            Some(e) => {
                let state = ExtraState {
                    x_m: self.x_m,
                    v_mps: self.v_mps,
                    a_mps2: 0.0,
                    f_motor_n: motor_n,
                    dp_pa: self.chambers.a.pressure_pa - self.chambers.b.pressure_pa,
                    t_s: self.elapsed_s,
                };
                let c_a = e.coefficient(Term::A).unwrap_or(0.0);
                (e.force_n(&state), p.mass_kg - c_a)
            }
            None => (0.0, p.mass_kg),
        };
        self.extra_force_n = extra_n;
        self.elapsed_s += dt;
        let r = p.friction_radius_m;
        let tangential = self.rotation.piston_speed_rad_s * r;
        let secant = p.friction.sliding_secant(self.v_mps, tangential);
        // The balance's forces but friction, which acts implicitly through its secant.
        let forces = PistonForces {
            motor_n,
            gas_n: self.chambers.gas_force_n(),
            cogging_n: self.cogging_force_n,
            external_n: stop + self.injected.external_force_n + extra_n,
            friction_n: 0.0,
        };
        let dt_over_m = dt / mass_kg;
        let v_new = implicit_velocity(self.v_mps, forces.driving_n(), secant, dt_over_m);
        self.friction_force_n = secant * v_new;
        self.a_mps2 = (v_new - self.v_mps) / dt;
        self.v_mps = v_new;
        self.x_m += v_new * dt;

        if self.injected.rotation_blocked {
            self.rotation.servo_speed_rad_s = 0.0;
            self.rotation.piston_speed_rad_s = 0.0;
        } else {
            self.rotation
                .step(&p.servo, servo_torque_nm, secant * r * r, dt);
        }
        self.motors.set_position(self.x_m);
        let phase = self.port_phase_rad();
        self.chambers
            .step(self.x_m, phase, &self.lines, self.port_mode, dt);
        if self.injected.any_vented() {
            self.injected.vent(&mut self.chambers);
        }
    }

    /// Adds this sub-step's electrical energies to [`Plant::electrical`]: the period's
    /// voltages, the currents from `start` to where the step took them.
    fn account_electrical(&mut self, start: PerSection<Dq<f64>>, dt: f64) {
        let bus_v = self.params.sections.motor.master.bus_voltage_v * self.supply.bus_scale();
        let state = |s: Section| SectionState {
            motor: self.params.sections.motor.get(s),
            voltage: *self.voltages.get(s),
            current: (*start.get(s), *self.motors.current.get(s)),
            angle: self.motors.angle(s),
        };
        let sections = PerSection {
            master: state(Section::Master),
            slave: state(Section::Slave),
        };
        let servo_w = self.rotation.torque_nm * self.rotation.servo_speed_rad_s;
        let mut totals = self.electrical;
        totals.add(&self.params.bridge, sections, bus_v, servo_w, dt);
        self.electrical = totals;
    }

    /// Electrical power the two bridges deliver to the sections now, W (negative: the
    /// sections regenerate): `3/2·(v_α·i_α + v_β·i_β)` with the period's voltages.
    pub fn bridge_power_w(&self) -> f64 {
        Section::ALL
            .into_iter()
            .map(|s| match self.voltages.get(s) {
                Some(v) => {
                    let (sin, cos) = self.motors.angle(s);
                    let vdq = fpc::physics::motor::park(*v, sin, cos);
                    let i = self.motors.current.get(s);
                    1.5 * (vdq.d * i.d + vdq.q * i.q)
                }
                None => 0.0,
            })
            .sum()
    }

    /// Moves the piston along a prescribed path (kinematic drive, for physics checks): the
    /// piston goes to `x_m` and turns to `piston_angle_rad` over `dt_s`, the gas follows. The
    /// motors, servo and end stops are bypassed.
    pub fn advance_kinematic(&mut self, x_m: f64, piston_angle_rad: f64, dt_s: f64) {
        let v = (x_m - self.x_m) / dt_s;
        self.a_mps2 = (v - self.v_mps) / dt_s;
        self.v_mps = v;
        self.x_m = x_m;
        let r = &mut self.rotation;
        r.piston_speed_rad_s = (piston_angle_rad - r.piston_angle_rad) / dt_s;
        r.servo_speed_rad_s = r.piston_speed_rad_s;
        r.piston_angle_rad = piston_angle_rad;
        r.servo_angle_rad = piston_angle_rad;
        self.motors.set_position(x_m);
        let phase = self.port_phase_rad();
        self.chambers
            .step(self.x_m, phase, &self.lines, self.port_mode, dt_s);
    }

    /// Contact force of the heads (penalty: spring and damper while penetrating), N.
    fn stop_force(&self) -> f64 {
        let p = &self.params;
        if self.x_m < 0.0 {
            -p.stop_stiffness_n_per_m * self.x_m - p.stop_damping_ns_per_m * self.v_mps.min(0.0)
        } else if self.x_m > p.travel_m {
            -p.stop_stiffness_n_per_m * (self.x_m - p.travel_m)
                - p.stop_damping_ns_per_m * self.v_mps.max(0.0)
        } else {
            0.0
        }
    }

    /// Distance to the nearer head, m (negative when in contact).
    pub fn head_clearance_m(&self) -> f64 {
        self.x_m.min(self.params.travel_m - self.x_m)
    }
}

/// The cogging law [`CoggingParams::force_n`], `A·sin(2π·x/p + φ)`, at `x_m`. Without a
/// phase and at the motor's electrical period, `sin(2π·x/p)` is the motors' electrical angle
/// at this position, already computed: no trigonometry here.
#[inline]
fn cogging_force_n(c: &CoggingParams<f64>, motors: &Sections, x_m: f64) -> f64 {
    if c.phase_rad == 0.0 && c.period_m == motors.electrical_period_m() {
        if let Some((sin, _)) = motors.master_angle_at(x_m) {
            return c.amplitude_n * sin;
        }
    }
    c.force_n(x_m)
}

/// Faults of the machine itself, read by the plant every sub-step (all off by default).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlantFaults {
    /// Sections whose drive stage is dead: no current flows, no force.
    pub dead: PerSection<bool>,
    /// An external axial force on the piston, toward +x (head B), N.
    pub external_force_n: f64,
    /// The rotation is blocked where it stands.
    pub rotation_blocked: bool,
    /// Chambers A and B vented to ambient (a burst seal or an open valve: a hole far larger
    /// than any port, so the chamber is at ambient pressure and temperature every sub-step).
    pub vented: [bool; 2],
}

impl PlantFaults {
    /// Whether a section is dead (one test per sub-step on the plant's hot path).
    #[inline]
    pub fn any_section_dead(&self) -> bool {
        self.dead.master || self.dead.slave
    }

    /// Whether a chamber is vented (one test per sub-step).
    #[inline]
    pub fn any_vented(&self) -> bool {
        self.vented != [false; 2]
    }

    /// Vents the chambers that are: ambient pressure and temperature, the mass that goes
    /// with them.
    pub fn vent(&self, chambers: &mut crate::plant::chambers::Chambers) {
        let p = &chambers.params;
        let (ambient_pa, ambient_k) = (p.ambient_pa, p.ambient_temperature_k);
        let r = p.gas.gas_constant_j_per_kg_k;
        for (chamber, vented) in [&mut chambers.a, &mut chambers.b]
            .into_iter()
            .zip(self.vented)
        {
            if vented {
                chamber.pressure_pa = ambient_pa;
                chamber.temperature_k = ambient_k;
                chamber.mass_kg = ambient_pa * chamber.volume_m3 / (r * ambient_k);
            }
        }
    }

    /// Zeroes the current and force of every dead section after the sections' step.
    pub fn kill_sections(&self, motors: &mut Sections) {
        for section in Section::ALL {
            if *self.dead.get(section) {
                *motors.current.get_mut(section) = Default::default();
                *motors.force_n.get_mut(section) = 0.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::model::extra_force::ExtraForceEffect;

    /// One sub-step from rest of a frictionless plant with the drives off: `v = dt·F/m`.
    fn first_velocity(extra: Option<ExtraForceEffect>) -> (f64, f64) {
        let mut model = MachineModel::reference();
        model.friction.coulomb_n = 0.0;
        model.friction.viscous_ns_per_m = 0.0;
        model.friction.static_n = None;
        model.effects.stribeck_friction = None;
        model.effects.cogging = None;
        model.effects.extra_force = extra;
        let mut plant = Plant::new(PlantParams::from_model(&model), 0.1);
        let gas_n = plant.chambers.gas_force_n();
        let drive = Drive {
            duties: PerSection {
                master: None,
                slave: None,
            },
            servo_torque_nm: 0.0,
        };
        plant.advance(&drive, CONTROL_PERIOD_S as f64);
        (plant.v_mps, gas_n)
    }

    #[test]
    fn the_extra_force_pushes_the_piston_and_its_a_term_changes_the_moving_mass() {
        let m = MachineModel::reference().piston.mass_kg;
        let dt = CONTROL_PERIOD_S as f64
            / f64::from(MachineModel::reference().simulation.substeps_per_period);
        let (v0, gas_n) = first_velocity(None);
        assert!((v0 - dt * gas_n / m).abs() <= 1e-9 * v0.abs().max(1e-9));
        // A spring of 1000 N/m about x = 0.15 m, seen at x = 0.1 m: +150 − 100 = +50 N, with
        // 2 kg of the moving mass taken off by the `a` term.
        let extra = ExtraForceEffect {
            terms: [("1", 150.0), ("x", -1000.0), ("a", 2.0)]
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect(),
            period_m: None,
        };
        let (v1, _) = first_velocity(Some(extra));
        let want = dt * (gas_n + 50.0) / (m - 2.0);
        assert!(
            (v1 - want).abs() <= 1e-9 * want.abs(),
            "{v1} against {want}"
        );
    }

    #[test]
    fn the_cogging_from_the_motor_angle_is_the_law() {
        let params = PlantParams::reference();
        let law = params.cogging.expect("the reference machine cogs");
        let mut plant = Plant::new(params, 0.0);
        for i in 0..2000 {
            let x = -0.01 + i as f64 * 1.13e-4;
            plant.motors.set_position(x);
            let f = cogging_force_n(&law, &plant.motors, x);
            assert!((f - law.force_n(x)).abs() < 1e-9 * law.amplitude_n, "x={x}");
        }
    }
}
