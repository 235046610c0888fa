//! The two working chambers: their gas, the ports and leaks that connect them to the lines,
//! to each other and to ambient, and heat transfer to the wall — one plant sub-step at a time.
//!
//! The laws are the library's ([`fpc::physics::gas`], [`fpc::physics::port_timing`]); this module only
//! integrates them. State per chamber: pressure and mass (temperature follows from the ideal
//! gas law). One sub-step, with the piston's new position and the ports' open fractions:
//!
//! 1. **Volume change**, closed and adiabatic, with the trapezoidal work
//!    ([`GasProperties::compression_step_pa`]): energy-exact, second order — half of it
//!    before steps 2–4 and half after (Strang splitting, so the work the piston does while
//!    a port is open is second-order accurate too).
//! 2. **Port flow and rod-seal leak**, *linearly implicit* (Rosenbrock–Euler) in the chamber
//!    pressure: `Δp = dt·g/(1 − dt·∂g/∂p)` with g the energy equation's right-hand side at
//!    constant volume, then clamped so the chamber never passes the pressure of the line it is
//!    filling from or emptying into. Near the dead volume a port equalises in a few µs (the
//!    linearised nozzle's time constant is ≈ 3 µs at 1.5 mm of gas column) — far below the
//!    25 µs sub-step — and this step is stable there: it lands on the line pressure instead of
//!    oscillating. Each path's mass is scaled by the same factor, so mass and energy are
//!    conserved exactly between chamber and lines (enthalpy from upstream; the chamber's
//!    temperature is held over the step for outflow).
//! 3. **Piston-seal leak A↔B**, explicit (its rate is ≈ 30 /s at the dead volume), limited so
//!    the two pressures never cross.
//! 4. **Heat transfer**, backward Euler at constant volume and mass (unconditionally stable).
//!
//! Every joule and kilogram that crosses a chamber's boundary is added up in
//! [`ChamberTotals`], so the first law can be checked from outside.

use fpc::physics::gas::{AnnulusLeak, Cylinder, Flow, GasProperties, Nozzle};
use fpc::physics::port_timing::{Port, PortGeometry, PortOpenings};

/// What connects the chambers to the lines.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PortMode {
    /// The ports open and close with the piston's rotation (normal operation).
    #[default]
    Timed,
    /// Both chambers open to the suction line through their intake ports, whatever the
    /// rotation (start-up unloader / bypass: homing and motion tests without compression).
    Unloaded,
    /// Every port sealed (the paper's first campaign: pressure build-up and leak-down).
    Closed,
}

/// The suction and discharge lines: set pressures, reservoirs of fixed state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lines {
    /// Suction-line pressure, Pa.
    pub suction_pa: f64,
    /// Suction-line temperature, K.
    pub suction_temperature_k: f64,
    /// Discharge-line pressure, Pa.
    pub discharge_pa: f64,
    /// Discharge-line temperature (isentropic from the suction state), K: what flows back
    /// into a chamber that opens below the discharge pressure.
    pub discharge_temperature_k: f64,
    gamma: f64,
}

impl Lines {
    /// Lines at `suction_pa` and `suction_temperature_k`, discharge at `pressure_ratio` times
    /// the suction pressure.
    pub fn new(
        suction_pa: f64,
        suction_temperature_k: f64,
        pressure_ratio: f64,
        gamma: f64,
    ) -> Self {
        let mut l = Lines {
            suction_pa,
            suction_temperature_k,
            discharge_pa: suction_pa,
            discharge_temperature_k: suction_temperature_k,
            gamma,
        };
        l.set_pressure_ratio(pressure_ratio);
        l
    }

    /// Sets the discharge pressure, Pa (its temperature follows).
    pub fn set_discharge_pa(&mut self, discharge_pa: f64) {
        self.discharge_pa = discharge_pa;
        let ratio = (discharge_pa / self.suction_pa).max(1e-6);
        self.discharge_temperature_k =
            self.suction_temperature_k * ratio.powf((self.gamma - 1.0) / self.gamma);
    }

    /// Sets the suction pressure, Pa, keeping the pressure ratio.
    pub fn set_suction_pa(&mut self, suction_pa: f64) {
        let pr = self.pressure_ratio();
        self.suction_pa = suction_pa;
        self.set_pressure_ratio(pr);
    }

    /// Sets the discharge pressure to `pressure_ratio` times the suction pressure.
    pub fn set_pressure_ratio(&mut self, pressure_ratio: f64) {
        self.set_discharge_pa(self.suction_pa * pressure_ratio);
    }

    /// Discharge / suction pressure.
    pub fn pressure_ratio(&self) -> f64 {
        self.discharge_pa / self.suction_pa
    }
}

/// Everything that crossed one chamber's boundary since the start (signed as named).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ChamberTotals {
    /// Work done by the piston on the gas, `−∫p dV`, J.
    pub work_on_gas_j: f64,
    /// Heat from the wall into the gas, J.
    pub heat_in_j: f64,
    /// Mass in through the intake port (net), kg.
    pub intake_kg: f64,
    /// Enthalpy in through the intake port (net), J.
    pub intake_j: f64,
    /// Mass out through the discharge port (net), kg.
    pub discharge_kg: f64,
    /// Enthalpy out through the discharge port (net), J.
    pub discharge_j: f64,
    /// Mass out through the seals (net, to the other chamber and to ambient), kg.
    pub leak_kg: f64,
    /// Enthalpy out through the seals (net), J.
    pub leak_j: f64,
}

/// One chamber's gas.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chamber {
    /// Pressure, Pa.
    pub pressure_pa: f64,
    /// Mass of gas, kg.
    pub mass_kg: f64,
    /// Volume, m³.
    pub volume_m3: f64,
    /// Temperature, K (ideal gas: `p·V/(m·R)`).
    pub temperature_k: f64,
    /// What crossed the boundary.
    pub totals: ChamberTotals,
    /// `(m, 1/(m·R))` for the mass last seen: the temperature update is then a product (the
    /// mass changes only when gas flows; divisions dominate the chamber step's cost).
    inverse: (f64, f64),
}

impl Chamber {
    fn new(gas: &GasProperties<f64>, pressure_pa: f64, temperature_k: f64, volume_m3: f64) -> Self {
        Chamber {
            pressure_pa,
            mass_kg: pressure_pa * volume_m3 / (gas.gas_constant_j_per_kg_k * temperature_k),
            volume_m3,
            temperature_k,
            totals: ChamberTotals::default(),
            inverse: (0.0, 0.0),
        }
    }

    /// Internal energy `p·V/(γ−1)`, J.
    pub fn internal_energy_j(&self, gas: &GasProperties<f64>) -> f64 {
        gas.internal_energy_j(self.pressure_pa, self.volume_m3)
    }

    /// `1/(m·R)` for the current mass.
    #[inline]
    fn inverse_mass_r(&mut self, r: f64) -> f64 {
        if self.inverse.0 != self.mass_kg {
            self.inverse = (self.mass_kg, 1.0 / (self.mass_kg * r));
        }
        self.inverse.1
    }

    #[inline]
    fn update_temperature(&mut self, r: f64) {
        self.temperature_k = self.pressure_pa * self.volume_m3 * self.inverse_mass_r(r);
    }
}

/// Updates both temperatures after the gas moved. When both masses changed, their `1/(m·R)`
/// come from one division, `D = 1/(m_A·m_B·R)`: `1/(m_A·R) = m_B·D`, `1/(m_B·R) = m_A·D`.
#[inline]
fn update_temperatures(a: &mut Chamber, b: &mut Chamber, r: f64) {
    let (ma, mb) = (a.mass_kg, b.mass_kg);
    if a.inverse.0 != ma && b.inverse.0 != mb {
        let product = ma * mb * r;
        if product > 0.0 && product.is_finite() {
            let d = 1.0 / product;
            a.inverse = (ma, mb * d);
            b.inverse = (mb, ma * d);
        }
    }
    a.update_temperature(r);
    b.update_temperature(r);
}

/// Parameters of the chambers and what connects them.
#[derive(Clone, Debug, PartialEq)]
pub struct ChamberParams {
    /// Geometry.
    pub cylinder: Cylinder<f64>,
    /// The gas.
    pub gas: GasProperties<f64>,
    /// Port timing and areas.
    pub ports: PortGeometry<f64>,
    /// Factor on every port's effective area (port restriction; 1 = as designed).
    pub port_area_scale: f64,
    /// Piston seal (A↔B), if it leaks.
    pub piston_leak: Option<AnnulusLeak<f64>>,
    /// Each rod seal (chamber ↔ ambient), if it leaks.
    pub rod_leak: Option<AnnulusLeak<f64>>,
    /// UA of each chamber to its wall, W/K (0 = adiabatic).
    pub ua_w_per_k: f64,
    /// Wall temperature, K.
    pub wall_temperature_k: f64,
    /// Ambient pressure, Pa.
    pub ambient_pa: f64,
    /// Ambient temperature, K.
    pub ambient_temperature_k: f64,
}

/// Both chambers.
#[derive(Clone, Debug, PartialEq)]
pub struct Chambers {
    /// Parameters.
    pub params: ChamberParams,
    /// Chamber A (small x).
    pub a: Chamber,
    /// Chamber B (large x).
    pub b: Chamber,
    /// Open fractions of the ports in the last step (as the mode applied them).
    pub openings: PortOpenings<f64>,
    nozzle: Nozzle<f64>,
    cp: f64,
    /// 1/(γ − 1).
    inv_gm1: f64,
}

impl Chambers {
    /// Both chambers at rest with the piston at `x_m`, filled at `pressure_pa` and
    /// `temperature_k`.
    pub fn new(params: ChamberParams, x_m: f64, pressure_pa: f64, temperature_k: f64) -> Self {
        let g = params.gas;
        let a = Chamber::new(
            &g,
            pressure_pa,
            temperature_k,
            params.cylinder.volume_a_m3(x_m),
        );
        let b = Chamber::new(
            &g,
            pressure_pa,
            temperature_k,
            params.cylinder.volume_b_m3(x_m),
        );
        Chambers {
            nozzle: Nozzle::new(g),
            cp: g.cp_j_per_kg_k(),
            inv_gm1: 1.0 / (g.gamma - 1.0),
            params,
            a,
            b,
            openings: PortOpenings::default(),
        }
    }

    /// Gas force on the piston, toward +x, N.
    #[inline]
    pub fn gas_force_n(&self) -> f64 {
        self.params
            .cylinder
            .gas_force_n(self.a.pressure_pa, self.b.pressure_pa)
    }

    /// Advances both chambers by `dt_s` as the piston moves to `x_m` with the rotation at
    /// phase `phase_rad` ∈ [0, 2π).
    pub fn step(&mut self, x_m: f64, phase_rad: f64, lines: &Lines, mode: PortMode, dt_s: f64) {
        let g = self.params.gas;
        let cyl = self.params.cylinder;
        let (va, vb) = (cyl.volume_a_m3(x_m), cyl.volume_b_m3(x_m));
        // Strang splitting: half the volume change, the flows, the other half (second order;
        // compressing first and then letting the ports act leaves an O(dt) error in the
        // work, ≈ 0.3 % of a cycle's at 50 µs).
        let (mid_a, mid_b) = (0.5 * (self.a.volume_m3 + va), 0.5 * (self.b.volume_m3 + vb));
        compress(&mut self.a, &g, mid_a);
        compress(&mut self.b, &g, mid_b);
        // Steps 2–4 act at these volumes: their reciprocals once (divisions dominate the cost).
        let (inv_va, inv_vb) = (1.0 / mid_a, 1.0 / mid_b);

        self.openings = match mode {
            PortMode::Timed => self.params.ports.openings(phase_rad),
            PortMode::Unloaded => PortOpenings {
                intake_a: 1.0,
                intake_b: 1.0,
                ..PortOpenings::default()
            },
            PortMode::Closed => PortOpenings::default(),
        };
        let area = |port: Port, o: &PortOpenings<f64>| {
            self.params.port_area_scale * self.params.ports.effective_area_m2(port, o.get(port))
        };
        let o = self.openings;
        let (ia, da, ib, db) = (
            area(Port::IntakeA, &o),
            area(Port::DischargeA, &o),
            area(Port::IntakeB, &o),
            area(Port::DischargeB, &o),
        );
        let ctx = FlowContext {
            nozzle: &self.nozzle,
            gas: &g,
            cp: self.cp,
            lines,
            rod_leak: self.params.rod_leak.as_ref(),
            ambient_pa: self.params.ambient_pa,
            ambient_temperature_k: self.params.ambient_temperature_k,
            dt_s,
        };
        ctx.flow_step(&mut self.a, ia, da, inv_va);
        ctx.flow_step(&mut self.b, ib, db, inv_vb);
        let r = g.gas_constant_j_per_kg_k;
        update_temperatures(&mut self.a, &mut self.b, r);

        if let Some(leak) = &self.params.piston_leak {
            let inv_v = (inv_va, inv_vb);
            piston_leak(&mut self.a, &mut self.b, leak, &g, self.cp, dt_s, inv_v);
            update_temperatures(&mut self.a, &mut self.b, r);
        }
        if self.params.ua_w_per_k > 0.0 {
            let wall = Wall {
                ua_w_per_k: self.params.ua_w_per_k,
                temperature_k: self.params.wall_temperature_k,
                inv_gm1: self.inv_gm1,
            };
            wall.heat(&mut self.a, &g, dt_s, inv_va);
            wall.heat(&mut self.b, &g, dt_s, inv_vb);
        }
        compress(&mut self.a, &g, va);
        compress(&mut self.b, &g, vb);
    }
}

fn compress(c: &mut Chamber, g: &GasProperties<f64>, volume_m3: f64) {
    let p0 = c.pressure_pa;
    let v0 = c.volume_m3;
    let p = g.compression_step_pa(p0, v0, volume_m3);
    c.totals.work_on_gas_j -= 0.5 * (p0 + p) * (volume_m3 - v0);
    c.pressure_pa = p;
    c.volume_m3 = volume_m3;
    c.update_temperature(g.gas_constant_j_per_kg_k);
}

struct FlowContext<'a> {
    nozzle: &'a Nozzle<f64>,
    gas: &'a GasProperties<f64>,
    cp: f64,
    lines: &'a Lines,
    rod_leak: Option<&'a AnnulusLeak<f64>>,
    ambient_pa: f64,
    ambient_temperature_k: f64,
    dt_s: f64,
}

impl FlowContext<'_> {
    /// The linearly implicit port-and-rod-leak step of one chamber (module header, step 2),
    /// at the volume whose reciprocal is `inv_v`. The temperature is left to the caller.
    fn flow_step(&self, c: &mut Chamber, intake_area_m2: f64, discharge_area_m2: f64, inv_v: f64) {
        let (p, t) = (c.pressure_pa, c.temperature_k);
        let l = self.lines;
        let closed = Flow::default();
        // Flows into the chamber (negative: out) from each reservoir, with their slopes in
        // the chamber pressure; a shut path contributes nothing.
        let intake = if intake_area_m2 > 0.0 {
            let (lp, lt) = (l.suction_pa, l.suction_temperature_k);
            self.nozzle.flow_between(intake_area_m2, lp, lt, p, t)
        } else {
            closed
        };
        let discharge = if discharge_area_m2 > 0.0 {
            let (lp, lt) = (l.discharge_pa, l.discharge_temperature_k);
            self.nozzle.flow_between(discharge_area_m2, lp, lt, p, t)
        } else {
            closed
        };
        let leak = match self.rod_leak {
            Some(leak) => {
                leak.flow_between(self.gas, self.ambient_pa, self.ambient_temperature_k, p, t)
            }
            None => closed,
        };
        let paths = [
            (intake, l.suction_pa, l.suction_temperature_k),
            (discharge, l.discharge_pa, l.discharge_temperature_k),
            (leak, self.ambient_pa, self.ambient_temperature_k),
        ];
        let (mut in_kg_k, mut out_kg, mut slope) = (0.0, 0.0, 0.0);
        let (mut fill_to, mut empty_to) = (f64::NEG_INFINITY, f64::INFINITY);
        let mut t_up = [t; 3];
        for ((f, line_pa, line_k), tu) in paths.iter().zip(t_up.iter_mut()) {
            let m = f.mass_kg_per_s;
            if m > 0.0 {
                *tu = *line_k;
                in_kg_k += m * line_k;
                fill_to = fill_to.max(*line_pa);
            } else if m < 0.0 {
                out_kg -= m;
                empty_to = empty_to.min(*line_pa);
            }
            slope += f.d_dp2 * *tu;
        }
        if in_kg_k == 0.0 && out_kg == 0.0 {
            return;
        }
        // The energy equation per unit volume, times 1/V.
        let g = self
            .gas
            .pressure_rate_pa_per_s(1.0, 0.0, p, t, in_kg_k, out_kg, 0.0)
            * inv_v;
        // ∂g/∂p with the upstream temperatures held; ≤ 0 for every law used here.
        let dg_dp = self.gas.gamma * self.gas.gas_constant_j_per_kg_k * slope * inv_v;
        let dt = self.dt_s;
        let implicit_dt = dt / (1.0 - dt * dg_dp).max(1.0);
        let step = implicit_dt * g;
        let p_new = if step > 0.0 {
            (p + step).min(fill_to.max(p))
        } else {
            (p + step).max(empty_to.min(p))
        };
        // Every path's flow scaled alike, so that mass and energy match the pressure change.
        // Unclamped, the step is exactly `implicit_dt·g`: no division needed.
        let scale = if p_new == p + step || g == 0.0 {
            implicit_dt
        } else {
            (p_new - p) / g
        };
        let [ti, td, tl] = t_up;
        let (dmi, dmd, dml) = (
            scale * intake.mass_kg_per_s,
            scale * discharge.mass_kg_per_s,
            scale * leak.mass_kg_per_s,
        );
        let cp = self.cp;
        let tot = &mut c.totals;
        tot.intake_kg += dmi;
        tot.intake_j += cp * ti * dmi;
        tot.discharge_kg -= dmd;
        tot.discharge_j -= cp * td * dmd;
        tot.leak_kg -= dml;
        tot.leak_j -= cp * tl * dml;
        c.mass_kg += dmi + dmd + dml;
        c.pressure_pa = p_new;
    }
}

/// The explicit piston-seal leak between the chambers (module header, step 3); `inv_v` are
/// the reciprocal volumes. The temperatures are left to the caller.
fn piston_leak(
    a: &mut Chamber,
    b: &mut Chamber,
    leak: &AnnulusLeak<f64>,
    g: &GasProperties<f64>,
    cp: f64,
    dt_s: f64,
    inv_v: (f64, f64),
) {
    let f = leak.flow_between(
        g,
        a.pressure_pa,
        a.temperature_k,
        b.pressure_pa,
        b.temperature_k,
    );
    let m = f.mass_kg_per_s;
    if m == 0.0 {
        return;
    }
    let t_up = if m > 0.0 {
        a.temperature_k
    } else {
        b.temperature_k
    };
    let k = g.gamma * g.gas_constant_j_per_kg_k * t_up;
    let (ka, kb) = (k * inv_v.0, k * inv_v.1);
    let mut dm = m * dt_s;
    let diff = a.pressure_pa - b.pressure_pa;
    if (diff - (ka + kb) * dm) * diff < 0.0 {
        // It would overshoot: move only the mass that equalises the pressures.
        dm = diff / (ka + kb);
    }
    let dh = cp * t_up * dm;
    a.mass_kg -= dm;
    a.pressure_pa -= ka * dm;
    a.totals.leak_kg += dm;
    a.totals.leak_j += dh;
    b.mass_kg += dm;
    b.pressure_pa += kb * dm;
    b.totals.leak_kg -= dm;
    b.totals.leak_j -= dh;
}

/// The chambers' wall (heat transfer).
struct Wall {
    ua_w_per_k: f64,
    temperature_k: f64,
    /// 1/(γ − 1).
    inv_gm1: f64,
}

impl Wall {
    /// Heat transfer to the wall at constant volume and mass, backward Euler (step 4), at the
    /// volume whose reciprocal is `inv_v`.
    fn heat(&self, c: &mut Chamber, g: &GasProperties<f64>, dt_s: f64, inv_v: f64) {
        let gm1 = g.gamma - 1.0;
        let ua = self.ua_w_per_k;
        // dp/dt = (γ−1)/V·UA·(T_w − p·V/(m·R)) = c1 − c2·p, backward Euler.
        let c2 = gm1 * ua * c.inverse_mass_r(g.gas_constant_j_per_kg_k);
        let c1 = gm1 * ua * self.temperature_k * inv_v;
        let p = (c.pressure_pa + dt_s * c1) / (1.0 + dt_s * c2);
        c.totals.heat_in_j += (p - c.pressure_pa) * c.volume_m3 * self.inv_gm1;
        c.pressure_pa = p;
        c.update_temperature(g.gas_constant_j_per_kg_k);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> ChamberParams {
        ChamberParams {
            cylinder: Cylinder::reference(),
            gas: GasProperties::air(),
            ports: PortGeometry::reference(),
            port_area_scale: 1.0,
            piston_leak: None,
            rod_leak: None,
            ua_w_per_k: 0.0,
            wall_temperature_k: 293.15,
            ambient_pa: 101_325.0,
            ambient_temperature_k: 293.15,
        }
    }

    #[test]
    fn an_open_port_at_the_dead_volume_equalises_without_ringing() {
        // Chamber A at 1.5 mm of gas column, 1 bar, discharge line at 5 bar opens fully.
        let mut ch = Chambers::new(params(), 0.001, 1e5, 293.15);
        let lines = Lines::new(1e5, 293.15, 5.0, 1.4);
        let phase = ch.params.ports.discharge_a.open_rad + 0.5;
        let mut last = ch.a.pressure_pa;
        for _ in 0..40 {
            ch.step(0.001, phase, &lines, PortMode::Timed, 25e-6);
            assert!(
                ch.a.pressure_pa >= last - 1e-6,
                "pressure must rise monotonically"
            );
            assert!(
                ch.a.pressure_pa <= lines.discharge_pa + 1e-6,
                "no overshoot"
            );
            last = ch.a.pressure_pa;
        }
        assert!((last - 5e5).abs() < 1.0, "{last}");
        // Mass and energy conservation between the chamber and the line.
        let g = ch.params.gas;
        let t = &ch.a.totals;
        let du = ch.a.internal_energy_j(&g) - g.internal_energy_j(1e5, ch.a.volume_m3);
        assert!((du - (-t.discharge_j)).abs() < 1e-9 * du.abs().max(1.0));
        // Gas that came in from the hot discharge line and was compressed is hot.
        assert!(ch.a.temperature_k > lines.discharge_temperature_k);
    }

    #[test]
    fn the_piston_leak_moves_mass_from_high_to_low_without_crossing() {
        let mut p = params();
        p.piston_leak = Some(AnnulusLeak {
            diameter_m: 0.09,
            gap_m: 200e-6, // absurdly large: the limiter must hold
            seal_length_m: 0.01,
        });
        let mut ch = Chambers::new(p, 0.001, 1e5, 293.15);
        ch.a.pressure_pa = 6e5;
        ch.a.update_temperature(287.0);
        let total = ch.a.mass_kg + ch.b.mass_kg;
        for _ in 0..1000 {
            ch.step(
                0.001,
                4.0,
                &Lines::new(1e5, 293.15, 3.0, 1.4),
                PortMode::Closed,
                25e-6,
            );
            assert!(ch.a.pressure_pa >= ch.b.pressure_pa - 1e-6);
        }
        assert!((ch.a.mass_kg + ch.b.mass_kg - total).abs() < 1e-12 * total);
        assert!((ch.a.pressure_pa - ch.b.pressure_pa).abs() < 10.0);
    }
}
