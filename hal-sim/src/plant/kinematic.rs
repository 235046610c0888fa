//! Prescribed motion of the piston and its rotation — the plant driven open-loop, without the
//! controller: for physics checks (p–V loops, energy balance) and synthetic data.
//!
//! The stroke is sinusoidal between two dead points, `x = x_mid − a·cos ψ` with
//! `ψ = v_max·t/a`. The rotation is the stroke phase bent piecewise-linearly so that each
//! discharge window is half open exactly when its chamber reaches the planned opening volume —
//! what the firmware's rotary synchroniser does in closed loop. By default the opening volume
//! is the isentropic one for the pressure ratio, `V_open = V_max·PR^(−1/γ)`.

use std::f64::consts::{PI, TAU};

use fpc::angle::wrap_rad;
use fpc::physics::port_timing::Port;

use crate::plant::dynamics::Plant;
use crate::plant::model::MachineModel;

/// A periodic compressor cycle, prescribed.
#[derive(Clone, Debug, PartialEq)]
pub struct CycleDrive {
    /// Middle of the stroke, m.
    pub x_mid_m: f64,
    /// Half stroke, m.
    pub amplitude_m: f64,
    /// Angular frequency of the stroke, rad/s.
    pub omega_rad_s: f64,
    /// Stroke phase at which chamber B's discharge is half open (in [0, π]).
    pub open_b_phase_rad: f64,
    /// Stroke phase at which chamber A's discharge is half open (in [π, 2π]).
    pub open_a_phase_rad: f64,
    /// Rotation phase at which B's discharge is half open.
    pub edge_b_rad: f64,
    /// Rotation phase at which A's discharge is half open.
    pub edge_a_rad: f64,
}

impl CycleDrive {
    /// A cycle between dead points `clearance_m` from each head at peak speed `v_max_mps`,
    /// with the discharges opening at the isentropic volume for `pressure_ratio`.
    pub fn new(
        model: &MachineModel,
        clearance_m: f64,
        v_max_mps: f64,
        pressure_ratio: f64,
    ) -> Self {
        // V_open/V_max of an isentropic compression to the pressure ratio (the gas law's).
        let open_share =
            model
                .gas_properties()
                .isentropic_volume_m3(1.0, 1.0, pressure_ratio.max(1.0));
        Self::with_volume_ratio(model, clearance_m, v_max_mps, 1.0 / open_share)
    }

    /// As [`CycleDrive::new`] with a fixed built-in volume ratio `V_max/V_open`.
    pub fn with_volume_ratio(
        model: &MachineModel,
        clearance_m: f64,
        v_max_mps: f64,
        volume_ratio: f64,
    ) -> Self {
        let cyl = model.cylinder();
        let (lo, hi) = (clearance_m, model.piston.travel_m - clearance_m);
        let x_mid_m = 0.5 * (lo + hi);
        let amplitude_m = 0.5 * (hi - lo);
        let x_open_b = cyl.position_for_volume_b_m(cyl.volume_b_m3(lo) / volume_ratio);
        let x_open_a = cyl.position_for_volume_a_m(cyl.volume_a_m3(hi) / volume_ratio);
        let phase_of = |x: f64| ((x_mid_m - x) / amplitude_m).clamp(-1.0, 1.0).acos();
        let ports = model.port_geometry();
        CycleDrive {
            x_mid_m,
            amplitude_m,
            omega_rad_s: v_max_mps / amplitude_m,
            open_b_phase_rad: phase_of(x_open_b),
            open_a_phase_rad: TAU - phase_of(x_open_a),
            edge_b_rad: ports.half_open_rad(Port::DischargeB),
            edge_a_rad: ports.half_open_rad(Port::DischargeA),
        }
    }

    /// Duration of one cycle (A → B → A), s.
    pub fn period_s(&self) -> f64 {
        TAU / self.omega_rad_s
    }

    /// Piston position (m) and rotation angle (rad, unwrapped) at time `t_s`.
    pub fn at(&self, t_s: f64) -> (f64, f64) {
        let total = self.omega_rad_s * t_s;
        let psi = wrap_rad(total);
        let x = self.x_mid_m - self.amplitude_m * psi.cos();
        let bend = |psi: f64, from: f64, knee_in: f64, knee_out: f64, to: f64| {
            // Maps [from, knee_in] → [from, knee_out] and [knee_in, to] → [knee_out, to].
            if psi <= knee_in {
                from + (psi - from) * (knee_out - from) / (knee_in - from).max(1e-9)
            } else {
                knee_out + (psi - knee_in) * (to - knee_out) / (to - knee_in).max(1e-9)
            }
        };
        let theta = if psi < PI {
            bend(psi, 0.0, self.open_b_phase_rad, self.edge_b_rad, PI)
        } else {
            bend(psi, PI, self.open_a_phase_rad, self.edge_a_rad, TAU)
        };
        // The whole turns done, and the bent phase within this one.
        (x, (total - psi) + theta)
    }

    /// Drives `plant` from `t0_s` to `t1_s` in steps of `dt_s`, calling `each` after every step
    /// with the plant and the time.
    pub fn drive(
        &self,
        plant: &mut Plant,
        t0_s: f64,
        t1_s: f64,
        dt_s: f64,
        mut each: impl FnMut(&Plant, f64),
    ) {
        let steps = ((t1_s - t0_s) / dt_s).round().max(0.0) as u64;
        for k in 1..=steps {
            let t = t0_s + k as f64 * dt_s;
            let (x, theta) = self.at(t);
            plant.advance_kinematic(x, theta, dt_s);
            each(plant, t);
        }
    }
}
