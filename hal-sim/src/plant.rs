//! The physical plant: piston, end stops, the two motor sections and the rotation servo.
//!
//! State is `f64`; the laws (friction, motor transforms) are the library's own, evaluated in
//! `f64`. The plant advances in fixed sub-steps inside each 50 µs control period with the
//! PWM duties held, as the averaged inverter applies them.

use fpc::foc::phase_voltages;
use fpc::friction::FrictionParams;
use fpc::motor::{clarke, inverse_clarke, inverse_park, park, Dq, MotorParams};
use fpc::units::{PerSection, PhaseDuties, Section};

/// Parameters of the plant, SI.
#[derive(Clone, Debug, PartialEq)]
pub struct PlantParams {
    /// Moving mass, kg.
    pub mass_kg: f64,
    /// Head-to-head travel, m.
    pub travel_m: f64,
    /// Friction of the translation.
    pub friction: FrictionParams<f64>,
    /// Motor sections (alike).
    pub motor: MotorParams<f64>,
    /// End-stop contact stiffness, N/m.
    pub stop_stiffness_n_per_m: f64,
    /// End-stop contact damping, N·s/m.
    pub stop_damping_ns_per_m: f64,
    /// Rotating inertia, kg·m².
    pub servo_inertia_kgm2: f64,
    /// Rotary viscous friction, N·m·s/rad.
    pub servo_viscous_nms_per_rad: f64,
    /// Servo torque at full-scale command, N·m.
    pub servo_torque_full_scale_nm: f64,
    /// Constant chamber pressures of the simple plant, Pa.
    pub chamber_pressure_pa: f64,
    /// Sub-steps per control period.
    pub substeps: u32,
}

impl PlantParams {
    /// The reference machine with ideal motor sections and no gas (the foundation plant).
    pub fn reference() -> Self {
        PlantParams {
            mass_kg: 12.0,
            travel_m: 0.205,
            friction: FrictionParams::reference(),
            motor: MotorParams::reference(),
            stop_stiffness_n_per_m: 5.0e7,
            stop_damping_ns_per_m: 2.0e4,
            servo_inertia_kgm2: 2e-3,
            servo_viscous_nms_per_rad: 1e-3,
            servo_torque_full_scale_nm: 5.0,
            chamber_pressure_pa: 101_325.0,
            substeps: 2,
        }
    }
}

/// What the controller applies to the plant during one period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Drive {
    /// Duties of both sections, or `None` when the outputs are off.
    pub duties: Option<PerSection<PhaseDuties>>,
    /// Servo torque, N·m.
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
    /// Rotation angle, rad.
    pub theta_rad: f64,
    /// Rotation speed, rad/s.
    pub omega_rad_s: f64,
    /// d/q currents of each section, A.
    pub current: PerSection<Dq<f64>>,
    /// Force of each section in the last sub-step, N.
    pub force_n: PerSection<f64>,
    /// Force of the end stops in the last sub-step, N.
    pub stop_force_n: f64,
}

impl Plant {
    /// A plant at rest at `x_m`.
    pub fn new(params: PlantParams, x_m: f64) -> Self {
        Plant {
            params,
            x_m,
            v_mps: 0.0,
            a_mps2: 0.0,
            theta_rad: 0.0,
            omega_rad_s: 0.0,
            current: PerSection::default(),
            force_n: PerSection::default(),
            stop_force_n: 0.0,
        }
    }

    /// Electrical angle of a section at the current position, rad.
    pub fn electrical_angle(&self) -> f64 {
        2.0 * core::f64::consts::PI * self.x_m / self.params.motor.electrical_period_m
    }

    /// Phase currents of `section`, A.
    pub fn phase_currents(&self, section: Section) -> [f64; 3] {
        let th = self.electrical_angle();
        inverse_clarke(inverse_park(*self.current.get(section), th.sin(), th.cos()))
    }

    /// Advances the plant by `period_s` with `drive` held.
    pub fn advance(&mut self, drive: &Drive, period_s: f64) {
        let n = self.params.substeps.max(1);
        let dt = period_s / f64::from(n);
        for _ in 0..n {
            self.substep(drive, dt);
        }
    }

    fn substep(&mut self, drive: &Drive, dt: f64) {
        let p = &self.params;
        let m = &p.motor;
        let th = self.electrical_angle();
        let (s, c) = th.sin_cos();
        let we = m.electrical_speed(self.v_mps);
        let ke = m.back_emf_v_per_mps();
        for section in Section::ALL {
            let i = *self.current.get(section);
            let next = match &drive.duties {
                Some(d) => {
                    let v = park(
                        clarke(phase_voltages(d.get(section), m.bus_voltage_v)),
                        s,
                        c,
                    );
                    // dq voltage equations with motional coupling and back-EMF on q.
                    let did =
                        (v.d - m.resistance_ohm * i.d + we * m.inductance_h * i.q) / m.inductance_h;
                    let diq = (v.q
                        - m.resistance_ohm * i.q
                        - we * m.inductance_h * i.d
                        - ke * self.v_mps)
                        / m.inductance_h;
                    Dq {
                        d: i.d + did * dt,
                        q: i.q + diq * dt,
                    }
                }
                // Outputs off: the bridge is open, the currents decay through the diodes
                // within a few µs — modelled as zero current.
                None => Dq::default(),
            };
            *self.current.get_mut(section) = next;
            *self.force_n.get_mut(section) = m.force_constant_n_per_a * next.q;
        }
        let stop = self.stop_force();
        self.stop_force_n = stop;
        let force =
            self.force_n.master + self.force_n.slave + stop - p.friction.force_n(self.v_mps);
        self.a_mps2 = force / p.mass_kg;
        // Semi-implicit Euler: stable for the stiff end stops at this step.
        self.v_mps += self.a_mps2 * dt;
        self.x_m += self.v_mps * dt;

        let torque = drive
            .servo_torque_nm
            .clamp(-p.servo_torque_full_scale_nm, p.servo_torque_full_scale_nm)
            - p.servo_viscous_nms_per_rad * self.omega_rad_s;
        self.omega_rad_s += torque / p.servo_inertia_kgm2 * dt;
        self.theta_rad += self.omega_rad_s * dt;
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
