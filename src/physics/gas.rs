//! The gas in the two working chambers: volumes, gas force, the energy equation, port and
//! leak flow, heat transfer (`docs/machine.md`, "Equations").
//!
//! One set of laws for the firmware (`f32`: gas-force feed-forward, the isentropic
//! discharge-opening volume of the volume-ratio control), the simulator's plant (`f64`) and
//! the model-gap workflow's pressure replay. Ideal gas, enthalpy carried from upstream, flows
//! positive *into* the chamber unless a function says otherwise.
//!
//! - Volumes: `V_A = A_eff·(x + l_dead,A)`, `V_B = A_eff·(L − x + l_dead,B)`.
//! - Energy equation: `dp/dt = (γ/V)·R·(Σ ṁ_in·T_up − Σ ṁ_out·T) − γ·(p/V)·dV/dt + ((γ−1)/V)·Q̇`.
//! - Port flow: compressible nozzle `ṁ = C_d·A·p_up/√(R·T_up)·ψ(p_dn/p_up)`, choked below the
//!   critical ratio (0.528 for γ = 1.4), made linear in the ratio above 0.995 so that its slope
//!   stays finite as the pressures equalise (the plant's implicit step needs that slope).
//! - Clearance leak (laminar flow in an annulus): `ṁ = π·D·h³/(24·μ·R·T·L_seal)·(p_hi² − p_lo²)`.
//! - Heat transfer to the wall: `Q̇ = UA·(T_wall − T)`.

use crate::real::Real;

/// Pressure ratio p_dn/p_up above which the nozzle law is linear in the ratio (`docs/machine.md`).
pub const LINEAR_PRESSURE_RATIO: f32 = 0.995;

/// Shortest gas column a chamber volume is floored at, m (1 µm of bore): keeps `V > 0` even
/// when the end-stop penalty lets the piston a few µm into a head with zero dead length.
pub const MIN_COLUMN_M: f32 = 1e-6;

/// Properties of the working gas, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GasProperties<T> {
    /// Heat-capacity ratio γ (> 1).
    pub gamma: T,
    /// Specific gas constant R, J/(kg·K).
    pub gas_constant_j_per_kg_k: T,
    /// Dynamic viscosity μ, Pa·s (clearance leakage).
    pub viscosity_pa_s: T,
}

impl<T: Real> GasProperties<T> {
    /// Air: γ 1.4, R 287 J/(kg·K), μ 1.8e-5 Pa·s (`docs/machine.md`).
    pub fn air() -> Self {
        GasProperties {
            gamma: T::of(crate::reference::gas::GAMMA as f32),
            gas_constant_j_per_kg_k: T::of(crate::reference::gas::GAS_CONSTANT_J_PER_KG_K as f32),
            viscosity_pa_s: T::of(crate::reference::gas::VISCOSITY_PA_S as f32),
        }
    }

    /// Specific heat at constant pressure c_p = γR/(γ−1), J/(kg·K).
    #[inline]
    pub fn cp_j_per_kg_k(&self) -> T {
        self.gamma * self.gas_constant_j_per_kg_k / (self.gamma - T::ONE)
    }

    /// Specific heat at constant volume c_v = R/(γ−1), J/(kg·K).
    #[inline]
    pub fn cv_j_per_kg_k(&self) -> T {
        self.gas_constant_j_per_kg_k / (self.gamma - T::ONE)
    }

    /// Critical (choking) pressure ratio `(2/(γ+1))^(γ/(γ−1))` (0.528 for γ = 1.4).
    pub fn critical_pressure_ratio(&self) -> T {
        let g = self.gamma;
        (T::of(2.0) / (g + T::ONE)).powf(g / (g - T::ONE))
    }

    /// Density at `pressure_pa` and `temperature_k`, kg/m³.
    #[inline]
    pub fn density_kg_per_m3(&self, pressure_pa: T, temperature_k: T) -> T {
        pressure_pa / (self.gas_constant_j_per_kg_k * temperature_k)
    }

    /// Temperature of `mass_kg` of gas at `pressure_pa` in `volume_m3`, K.
    #[inline]
    pub fn temperature_k(&self, pressure_pa: T, volume_m3: T, mass_kg: T) -> T {
        pressure_pa * volume_m3 / (mass_kg * self.gas_constant_j_per_kg_k)
    }

    /// Internal energy of the gas in a volume, `p·V/(γ−1)`, J.
    #[inline]
    pub fn internal_energy_j(&self, pressure_pa: T, volume_m3: T) -> T {
        pressure_pa * volume_m3 / (self.gamma - T::ONE)
    }

    /// The chamber energy equation of `docs/machine.md`: dp/dt, Pa/s.
    ///
    /// `inflow_kg_k_per_s` is Σ ṁ_in·T_up over the inflows (kg·K/s), `outflow_kg_per_s` is
    /// Σ ṁ_out (≥ 0, leaving at the chamber temperature `temperature_k`), `heat_w` is the heat
    /// flowing *into* the gas.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub fn pressure_rate_pa_per_s(
        &self,
        volume_m3: T,
        volume_rate_m3_per_s: T,
        pressure_pa: T,
        temperature_k: T,
        inflow_kg_k_per_s: T,
        outflow_kg_per_s: T,
        heat_w: T,
    ) -> T {
        let g = self.gamma;
        (g * self.gas_constant_j_per_kg_k * (inflow_kg_k_per_s - outflow_kg_per_s * temperature_k)
            - g * pressure_pa * volume_rate_m3_per_s
            + (g - T::ONE) * heat_w)
            / volume_m3
    }

    /// One step of the closed, adiabatic volume change `V_old → V_new` of the energy
    /// equation, integrated with the trapezoidal work `−½(p + p_new)·ΔV`: returns p_new, Pa.
    ///
    /// It conserves energy exactly (the work the piston does on the gas in this discretisation
    /// is the change of `p·V/(γ−1)`), is second-order accurate in ΔV/V, and costs one
    /// division — the plant's sub-step uses it instead of `(V_old/V_new)^γ`.
    #[inline]
    pub fn compression_step_pa(&self, pressure_pa: T, volume_old_m3: T, volume_new_m3: T) -> T {
        let g = self.gamma;
        let dv = volume_new_m3 - volume_old_m3;
        let two = T::of(2.0);
        pressure_pa * (two * volume_old_m3 - (g - T::ONE) * dv)
            / (two * volume_old_m3 + (g + T::ONE) * dv)
    }

    /// Pressure after an isentropic change from (p₀, V₀) to `volume_m3`: `p₀·(V₀/V)^γ`, Pa.
    #[inline]
    pub fn isentropic_pressure_pa(&self, pressure0_pa: T, volume0_m3: T, volume_m3: T) -> T {
        pressure0_pa * (volume0_m3 / volume_m3).powf(self.gamma)
    }

    /// Volume at which an isentropic compression from (p₀, V₀) reaches `pressure_pa`:
    /// `V₀·(p₀/p)^(1/γ)`, m³ — where the discharge must open for a given pressure ratio.
    #[inline]
    pub fn isentropic_volume_m3(&self, pressure0_pa: T, volume0_m3: T, pressure_pa: T) -> T {
        volume0_m3 * (pressure0_pa / pressure_pa).powf(T::ONE / self.gamma)
    }
}

/// Heat flowing from the wall into the gas, `UA·(T_wall − T)`, W.
#[inline]
pub fn heat_flow_w<T: Real>(ua_w_per_k: T, wall_temperature_k: T, gas_temperature_k: T) -> T {
    ua_w_per_k * (wall_temperature_k - gas_temperature_k)
}

/// The cylinder: effective piston area and the two chambers' volumes as functions of x.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cylinder<T> {
    /// Effective piston area A_eff = π(D² − d²)/4, m².
    pub area_m2: T,
    /// Head-to-head travel L, m.
    pub travel_m: T,
    /// Dead volume of chamber A as a length of bore, m.
    pub dead_length_a_m: T,
    /// Dead volume of chamber B as a length of bore, m.
    pub dead_length_b_m: T,
}

impl<T: Real> Cylinder<T> {
    /// From the bore and rod diameters (paper Eq. 2), m.
    pub fn from_bore(bore_m: T, rod_m: T, travel_m: T, dead_a_m: T, dead_b_m: T) -> Self {
        Cylinder {
            area_m2: T::PI * (bore_m * bore_m - rod_m * rod_m) * T::of(0.25),
            travel_m,
            dead_length_a_m: dead_a_m,
            dead_length_b_m: dead_b_m,
        }
    }

    /// The reference machine: bore 90 mm, rod 20 mm, travel 0.205 m, 0.5 mm dead length each
    /// side (**A**, `docs/machine.md`).
    pub fn reference() -> Self {
        use crate::reference::piston;
        Self::from_bore(
            T::of(piston::BORE_M as f32),
            T::of(piston::ROD_M as f32),
            T::of(piston::TRAVEL_M as f32),
            T::of(piston::DEAD_LENGTH_A_M as f32),
            T::of(piston::DEAD_LENGTH_B_M as f32),
        )
    }

    /// Volume of chamber A at piston position `x_m`, m³ (floored at [`MIN_COLUMN_M`]).
    #[inline]
    pub fn volume_a_m3(&self, x_m: T) -> T {
        self.area_m2 * (x_m + self.dead_length_a_m).max(T::of(MIN_COLUMN_M))
    }

    /// Volume of chamber B at piston position `x_m`, m³ (floored at [`MIN_COLUMN_M`]).
    #[inline]
    pub fn volume_b_m3(&self, x_m: T) -> T {
        self.area_m2 * (self.travel_m - x_m + self.dead_length_b_m).max(T::of(MIN_COLUMN_M))
    }

    /// Gas force on the piston, positive toward +x: `(p_A − p_B)·A_eff`, N.
    #[inline]
    pub fn gas_force_n(&self, pressure_a_pa: T, pressure_b_pa: T) -> T {
        (pressure_a_pa - pressure_b_pa) * self.area_m2
    }

    /// Piston position at which chamber A has `volume_m3`, m (inverse of
    /// [`Cylinder::volume_a_m3`]).
    #[inline]
    pub fn position_for_volume_a_m(&self, volume_m3: T) -> T {
        volume_m3 / self.area_m2 - self.dead_length_a_m
    }

    /// Piston position at which chamber B has `volume_m3`, m.
    #[inline]
    pub fn position_for_volume_b_m(&self, volume_m3: T) -> T {
        self.travel_m + self.dead_length_b_m - volume_m3 / self.area_m2
    }
}

/// A mass flow and its slopes with respect to the two pressures.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Flow<T> {
    /// Mass flow, kg/s (sign as the function that returned it says).
    pub mass_kg_per_s: T,
    /// ∂ṁ/∂p of the first (upstream or "from") pressure, kg/(s·Pa).
    pub d_dp1: T,
    /// ∂ṁ/∂p of the second (downstream or "to") pressure, kg/(s·Pa).
    pub d_dp2: T,
}

/// Intervals of the flow-function table of [`Nozzle`].
const TABLE_INTERVALS: usize = 64;

/// The compressible-nozzle law for one gas, with its constants precomputed.
///
/// Between the critical ratio and 0.995 the flow function is evaluated from a table built
/// from the exact law at construction: 64 cubic-Hermite intervals (values and slopes) in
/// `s = √(1 − r)`, in which ψ is smooth up to r = 1 (ψ ≈ √2·s there). That replaces a `powf`
/// per evaluation by a `sqrt` and a few multiply-adds; the table agrees with the exact law to
/// within 1e-8 in ψ (tested; ψ is 0…0.68), far below any other error of the model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nozzle<T> {
    gas: GasProperties<T>,
    inv_gamma: T,
    /// 2γ/(γ−1).
    k: T,
    critical_ratio: T,
    psi_critical: T,
    psi_linear: T,
    linear_ratio: T,
    /// s at the first table node (r = 0.995).
    s0: T,
    /// Node spacing in s.
    ds: T,
    /// 1/ds (the plant evaluates this law every step: a multiply, not a division).
    inv_ds: T,
    /// dψ/dr of the linear part above the linear ratio.
    slope_linear: T,
    /// ψ at the nodes.
    psi: [T; TABLE_INTERVALS + 1],
    /// dψ/ds at the nodes.
    dpsi_ds: [T; TABLE_INTERVALS + 1],
}

impl<T: Real> Nozzle<T> {
    /// The nozzle law for `gas`.
    pub fn new(gas: GasProperties<T>) -> Self {
        let g = gas.gamma;
        let k = T::of(2.0) * g / (g - T::ONE);
        let inv_gamma = T::ONE / g;
        let critical_ratio = gas.critical_pressure_ratio();
        let linear_ratio = T::of(LINEAR_PRESSURE_RATIO);
        let s0 = (T::ONE - linear_ratio).sqrt();
        let s1 = (T::ONE - critical_ratio).sqrt();
        let ds = (s1 - s0) / T::of(TABLE_INTERVALS as f32);
        let mut psi = [T::ZERO; TABLE_INTERVALS + 1];
        let mut dpsi_ds = [T::ZERO; TABLE_INTERVALS + 1];
        for (i, (p, d)) in psi.iter_mut().zip(dpsi_ds.iter_mut()).enumerate() {
            let s = s0 + ds * T::of(i as f32);
            let (value, slope_r) = exact_flow_function(k, inv_gamma, T::ONE - s * s);
            *p = value;
            // dr/ds = −2s.
            *d = slope_r * (T::of(-2.0) * s);
        }
        let psi_linear = exact_flow_function(k, inv_gamma, linear_ratio).0;
        Nozzle {
            gas,
            inv_gamma,
            k,
            critical_ratio,
            psi_critical: exact_flow_function(k, inv_gamma, critical_ratio).0,
            psi_linear,
            linear_ratio,
            s0,
            ds,
            inv_ds: T::ONE / ds,
            slope_linear: -psi_linear / (T::ONE - linear_ratio),
            psi,
            dpsi_ds,
        }
    }

    /// The gas.
    pub fn gas(&self) -> &GasProperties<T> {
        &self.gas
    }

    /// The critical pressure ratio in use.
    pub fn critical_ratio(&self) -> T {
        self.critical_ratio
    }

    /// Flow function ψ(r) and its slope dψ/dr for the pressure ratio `r = p_dn/p_up` in
    /// [0, 1]: constant (choked) up to the critical ratio, the isentropic nozzle law
    /// `√(2γ/(γ−1)·(r^{2/γ} − r^{(γ+1)/γ}))` above it (tabulated, see the type), linear to 0
    /// at r = 1 above 0.995.
    #[inline]
    pub fn flow_function(&self, r: T) -> (T, T) {
        if r <= self.critical_ratio {
            return (self.psi_critical, T::ZERO);
        }
        let slope_linear = self.slope_linear;
        if r >= T::ONE {
            return (T::ZERO, slope_linear);
        }
        if r > self.linear_ratio {
            return (slope_linear * (r - T::ONE), slope_linear);
        }
        let s = (T::ONE - r).sqrt();
        let u = ((s - self.s0) * self.inv_ds).max(T::ZERO);
        let i = (u.to_f32() as usize).min(TABLE_INTERVALS - 1);
        let t = u - T::of(i as f32);
        let node = |j: usize| {
            (
                self.psi.get(j).copied().unwrap_or(T::ZERO),
                self.dpsi_ds.get(j).copied().unwrap_or(T::ZERO),
            )
        };
        let ((p0, m0), (p1, m1)) = (node(i), node(i + 1));
        let h = self.ds;
        let (t2, t3) = (t * t, t * t * t);
        let two = T::of(2.0);
        let three = T::of(3.0);
        let psi = (two * t3 - three * t2 + T::ONE) * p0
            + (t3 - two * t2 + t) * h * m0
            + (three * t2 - two * t3) * p1
            + (t3 - t2) * h * m1;
        let six = T::of(6.0);
        let dpsi_ds = (six * t2 - six * t) * self.inv_ds * (p0 - p1)
            + (three * t2 - T::of(4.0) * t + T::ONE) * m0
            + (three * t2 - two * t) * m1;
        (psi, dpsi_ds / (T::of(-2.0) * s))
    }

    /// The exact law (what the table is built from), for checks.
    pub fn exact_flow_function(&self, r: T) -> (T, T) {
        if r <= self.critical_ratio {
            (self.psi_critical, T::ZERO)
        } else {
            exact_flow_function(self.k, self.inv_gamma, r.min(T::ONE))
        }
    }

    /// Mass flow through an orifice of effective area `cd_area_m2` (= C_d·A) from the
    /// upstream state (`p_up_pa`, `t_up_k`) to `p_dn_pa`, kg/s, ≥ 0 (zero if `p_dn ≥ p_up`),
    /// with its slopes: `d_dp1` = ∂ṁ/∂p_up, `d_dp2` = ∂ṁ/∂p_dn (temperature held).
    #[inline]
    pub fn mass_flow(&self, cd_area_m2: T, p_up_pa: T, t_up_k: T, p_dn_pa: T) -> Flow<T> {
        // Written as a positive test so that NaN inputs also give no flow.
        let valid = p_up_pa > T::ZERO && cd_area_m2 > T::ZERO;
        if !valid {
            return Flow {
                mass_kg_per_s: T::ZERO,
                d_dp1: T::ZERO,
                d_dp2: T::ZERO,
            };
        }
        let r = (p_dn_pa / p_up_pa).max(T::ZERO).min(T::ONE);
        let (psi, dpsi) = self.flow_function(r);
        let c = cd_area_m2 / (self.gas.gas_constant_j_per_kg_k * t_up_k).sqrt();
        if p_dn_pa >= p_up_pa {
            // At r = 1 only the linear slope survives (flow starts in either direction).
            return Flow {
                mass_kg_per_s: T::ZERO,
                d_dp1: -c * dpsi,
                d_dp2: c * dpsi,
            };
        }
        Flow {
            mass_kg_per_s: c * p_up_pa * psi,
            d_dp1: c * (psi - r * dpsi),
            d_dp2: c * dpsi,
        }
    }

    /// Signed nozzle flow from side 1 to side 2, kg/s (negative: from 2 to 1), each side's
    /// temperature used when it is upstream; slopes with respect to p₁ and p₂.
    #[inline]
    pub fn flow_between(&self, cd_area_m2: T, p1_pa: T, t1_k: T, p2_pa: T, t2_k: T) -> Flow<T> {
        if p1_pa >= p2_pa {
            self.mass_flow(cd_area_m2, p1_pa, t1_k, p2_pa)
        } else {
            let f = self.mass_flow(cd_area_m2, p2_pa, t2_k, p1_pa);
            Flow {
                mass_kg_per_s: -f.mass_kg_per_s,
                d_dp1: -f.d_dp2,
                d_dp2: -f.d_dp1,
            }
        }
    }
}

/// `ψ(r) = √(k·(r^{2/γ} − r^{(γ+1)/γ}))` (k = 2γ/(γ−1)) and dψ/dr, for r in (0, 1).
fn exact_flow_function<T: Real>(k: T, inv_gamma: T, r: T) -> (T, T) {
    // r^{2/γ} = y², r^{(γ+1)/γ} = r·y with y = r^{1/γ}: one powf.
    let y = r.powf(inv_gamma);
    let psi = (k * y * (y - r)).max(T::ZERO).sqrt();
    let positive = psi > T::ZERO;
    if !positive {
        return (T::ZERO, T::ZERO);
    }
    // dψ/dr = k/(2ψ)·(2/γ·y²/r − (γ+1)/γ·y).
    let d =
        k * (T::of(2.0) * inv_gamma * y * y / r - (T::ONE + inv_gamma) * y) / (T::of(2.0) * psi);
    (psi, d)
}

/// Laminar leakage through a clearance annulus (piston or rod seal).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AnnulusLeak<T> {
    /// Diameter of the sealing surface D, m.
    pub diameter_m: T,
    /// Radial clearance h, m.
    pub gap_m: T,
    /// Seal length along the flow L_seal, m.
    pub seal_length_m: T,
}

impl<T: Real> AnnulusLeak<T> {
    /// The reference piston seal: D 90 mm, h 25 µm, L_seal 50 mm (**A**, `docs/machine.md`).
    pub fn reference_piston() -> Self {
        AnnulusLeak {
            diameter_m: T::of(0.090),
            gap_m: T::of(25e-6),
            seal_length_m: T::of(0.050),
        }
    }

    /// Coefficient `π·D·h³/(24·μ·R·T·L_seal)`, kg/(s·Pa²), at gas temperature `t_k`.
    #[inline]
    pub fn coefficient(&self, gas: &GasProperties<T>, t_k: T) -> T {
        let h = self.gap_m;
        T::PI * self.diameter_m * h * h * h
            / (T::of(24.0)
                * gas.viscosity_pa_s
                * gas.gas_constant_j_per_kg_k
                * t_k
                * self.seal_length_m)
    }

    /// Signed leak from side 1 to side 2, kg/s, `coefficient·(p₁² − p₂²)` at the upstream
    /// temperature; slopes with respect to p₁ and p₂.
    #[inline]
    pub fn flow_between(
        &self,
        gas: &GasProperties<T>,
        p1_pa: T,
        t1_k: T,
        p2_pa: T,
        t2_k: T,
    ) -> Flow<T> {
        let t_up = if p1_pa >= p2_pa { t1_k } else { t2_k };
        let c = self.coefficient(gas, t_up);
        Flow {
            mass_kg_per_s: c * (p1_pa * p1_pa - p2_pa * p2_pa),
            d_dp1: T::of(2.0) * c * p1_pa,
            d_dp2: T::of(-2.0) * c * p2_pa,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn critical_ratio_of_air_is_0_528() {
        let air = GasProperties::<f64>::air();
        assert!((air.critical_pressure_ratio() - 0.5283).abs() < 1e-4);
    }

    #[test]
    fn flow_function_is_continuous_and_its_slope_matches() {
        let n = Nozzle::new(GasProperties::<f64>::air());
        let mut prev = n.flow_function(0.0).0;
        for i in 1..=10_000 {
            let r = i as f64 * 1e-4;
            let (psi, slope) = n.flow_function(r);
            assert!((psi - prev).abs() < 2e-3, "jump at r={r}");
            assert!(psi <= prev + 1e-12, "ψ must not increase with r (r={r})");
            prev = psi;
            if r > 0.53 && r < 0.994 && (r - 0.995).abs() > 1e-3 {
                let h = 1e-7;
                let numeric = (n.flow_function(r + h).0 - n.flow_function(r - h).0) / (2.0 * h);
                assert!(
                    (numeric - slope).abs() < 1e-4 * (1.0 + slope.abs()),
                    "r={r}"
                );
            }
        }
        assert_eq!(n.flow_function(1.0).0, 0.0);
        // Choked value √(γ·(2/(γ+1))^((γ+1)/(γ−1))) = 0.6847 for γ = 1.4.
        assert!((n.flow_function(0.3).0 - 0.6847).abs() < 1e-3);
    }

    #[test]
    fn the_tabulated_flow_function_matches_the_exact_law() {
        let n = Nozzle::new(GasProperties::<f64>::air());
        let (mut worst, mut worst_slope) = (0.0f64, 0.0f64);
        for i in 0..=100_000 {
            let r = 0.5 + i as f64 * 0.5e-5;
            if r > 0.995 {
                break;
            }
            let (a, da) = n.flow_function(r);
            let (b, db) = n.exact_flow_function(r);
            worst = worst.max((a - b).abs());
            worst_slope = worst_slope.max((da - db).abs() / db.abs().max(1.0));
        }
        println!("flow-function table: max |Δψ| {worst:.1e}, max slope error {worst_slope:.1e}");
        assert!(worst < 1e-8 && worst_slope < 1e-5);
    }

    #[test]
    fn nozzle_flow_is_antisymmetric_and_matches_the_choked_formula() {
        let n = Nozzle::new(GasProperties::<f64>::air());
        let f = n.flow_between(4e-4, 5e5, 300.0, 1e5, 300.0);
        let choked = 4e-4 * 5e5 / (287.0f64 * 300.0).sqrt() * 0.6847;
        assert!((f.mass_kg_per_s - choked).abs() < 1e-3 * choked);
        let g = n.flow_between(4e-4, 1e5, 300.0, 5e5, 300.0);
        assert!((f.mass_kg_per_s + g.mass_kg_per_s).abs() < 1e-12);
        assert!(f.d_dp1 > 0.0 && g.d_dp2 < 0.0);
    }

    #[test]
    fn compression_step_follows_the_adiabat_and_conserves_energy() {
        let air = GasProperties::<f64>::air();
        let (mut p, mut v) = (1e5, 1.2e-3);
        let mut work = 0.0;
        let u0 = air.internal_energy_j(p, v);
        for _ in 0..1000 {
            let v_new = v * 0.998;
            let p_new = air.compression_step_pa(p, v, v_new);
            work += -0.5 * (p + p_new) * (v_new - v);
            p = p_new;
            v = v_new;
        }
        let exact = air.isentropic_pressure_pa(1e5, 1.2e-3, v);
        assert!((p / exact - 1.0).abs() < 1e-5, "{p} vs {exact}");
        let du = air.internal_energy_j(p, v) - u0;
        assert!((du - work).abs() < 1e-9 * work);
    }

    #[test]
    fn volumes_and_gas_force_of_the_reference_cylinder() {
        let c = Cylinder::<f64>::reference();
        assert!((c.area_m2 - 6.048e-3).abs() < 1e-5);
        let swept = c.volume_a_m3(0.2) - c.volume_a_m3(0.0);
        assert!((swept - 1.21e-3).abs() < 0.01e-3);
        assert!((c.volume_a_m3(0.1) + c.volume_b_m3(0.1) - c.area_m2 * 0.206).abs() < 1e-9);
        assert!(c.volume_a_m3(-1.0) > 0.0);
        assert!((c.position_for_volume_b_m(c.volume_b_m3(0.05)) - 0.05).abs() < 1e-12);
        assert!(c.gas_force_n(2e5, 1e5) > 0.0);
    }

    #[test]
    fn leak_grows_with_the_difference_of_squares() {
        let air = GasProperties::<f64>::air();
        let leak = AnnulusLeak::<f64>::reference_piston();
        let f = leak.flow_between(&air, 5e5, 293.15, 1e5, 293.15);
        // 2.4e-15 kg/(s·Pa²) × (25 − 1)·10¹⁰ Pa² ≈ 5.8e-4 kg/s.
        assert!(
            (f.mass_kg_per_s - 5.8e-4).abs() < 0.3e-4,
            "{}",
            f.mass_kg_per_s
        );
        let back = leak.flow_between(&air, 1e5, 293.15, 5e5, 293.15);
        assert!((back.mass_kg_per_s + f.mass_kg_per_s).abs() < 1e-15);
    }

    #[test]
    fn f32_and_f64_volume_laws_agree() {
        // Only the algebraic laws: on f32, `powf`/`sqrt` go through micromath, whose
        // approximations (≈ 5 %) are too coarse for the nozzle law.
        let (c64, c32) = (Cylinder::<f64>::reference(), Cylinder::<f32>::reference());
        let (g64, g32) = (GasProperties::<f64>::air(), GasProperties::<f32>::air());
        for i in 0..=205 {
            let x = i as f64 * 1e-3;
            let a = c64.volume_a_m3(x);
            assert!((a - f64::from(c32.volume_a_m3(x as f32))).abs() < 1e-6 * a);
            let p = g64.compression_step_pa(3e5, a, a * 0.99);
            let q = g32.compression_step_pa(3e5, a as f32, a as f32 * 0.99);
            assert!((p - f64::from(q)).abs() < 1e-5 * p);
        }
    }
}
