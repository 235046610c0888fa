//! The built-in volume ratio: where each chamber's discharge must open so that the chamber
//! pressure has just reached the discharge pressure (no over- or under-compression).
//!
//! From the measured suction and discharge line pressures, the isentropic law
//! (`gas::GasProperties::isentropic_volume_m3`) gives the opening volume
//! `V_open = V_bdc·(p_s/p_d)^(1/γ)`, and the cylinder geometry turns it into a piston
//! position. Real compression is not isentropic (heat transfer, leakage) and the port edge
//! is crossed with some servo lag, so each chamber's opening volume carries a correction
//! factor, updated stroke by stroke from the chamber pressure measured at the opening:
//! if the chamber was short of the discharge pressure the port opened too early, and the next
//! opening moves to a smaller volume.
//!
//! In expander mode the same law gives the cut-off: admission of high-pressure gas ends at
//! `V_cut = V_end·(p_s/p_d)^(1/γ)`, so the expansion ends at the suction pressure.

use crate::physics::gas::{Cylinder, GasProperties};
use crate::real::{clamp_f32, min_f32};

/// The two chambers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Chamber {
    /// Chamber A (small x).
    A,
    /// Chamber B (large x).
    B,
}

/// How the volume ratio is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum RatioTarget {
    /// Follow the measured pressure ratio (the machine's purpose).
    FollowMeasured,
    /// A fixed built-in volume ratio, designed for this pressure ratio (a conventional
    /// compressor; for comparison). No stroke-by-stroke correction.
    Fixed {
        /// The design pressure ratio (> 1).
        pressure_ratio: f32,
    },
}

/// Volume-ratio parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumeRatioConfig {
    /// Fraction of the measured opening error corrected per stroke (0..1).
    pub correction_gain: f32,
    /// Largest correction of the opening volume, as a fraction (0.3 = ±30 %).
    pub max_correction: f32,
    /// Largest change of the correction in one stroke, as a fraction.
    pub max_step: f32,
}

impl VolumeRatioConfig {
    /// Half the error per stroke, at most 2 % per stroke and ±30 % in all.
    pub const fn reference() -> Self {
        VolumeRatioConfig {
            correction_gain: 0.5,
            max_correction: 0.3,
            max_step: 0.02,
        }
    }
}

/// Volume-ratio state: the target and the per-chamber corrections.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeRatio {
    config: VolumeRatioConfig,
    target: RatioTarget,
    /// Multiplicative corrections of the opening volume of A and B.
    correction: [f32; 2],
}

impl VolumeRatio {
    /// Following the measured pressure ratio, no correction yet.
    pub const fn new(config: VolumeRatioConfig) -> Self {
        VolumeRatio {
            config,
            target: RatioTarget::FollowMeasured,
            correction: [1.0; 2],
        }
    }

    /// The current target.
    pub fn target(&self) -> RatioTarget {
        self.target
    }

    /// Sets the target (the corrections are kept: they describe the machine, not the ratio).
    pub fn set_target(&mut self, target: RatioTarget) {
        self.target = target;
    }

    /// The correction factor of `chamber`'s opening volume.
    pub fn correction(&self, chamber: Chamber) -> f32 {
        match chamber {
            Chamber::A => self.correction[0],
            Chamber::B => self.correction[1],
        }
    }

    /// The opening volume of `chamber`, m³, when it is compressed from `start_volume_m3`
    /// (its volume at its bottom dead point) between the measured line pressures.
    /// Invalid or non-physical pressures (NaN, ≤ 0, p_d ≤ p_s) give the start volume: a
    /// discharge that opens at once never over-compresses.
    pub fn opening_volume_m3(
        &self,
        gas: &GasProperties<f32>,
        chamber: Chamber,
        start_volume_m3: f32,
        suction_pa: f32,
        discharge_pa: f32,
    ) -> f32 {
        let (ratio_ok, corrected) = match self.target {
            RatioTarget::Fixed { pressure_ratio } => (pressure_ratio > 1.0, false),
            RatioTarget::FollowMeasured => (discharge_pa > suction_pa && suction_pa > 0.0, true),
        };
        if !ratio_ok {
            return start_volume_m3;
        }
        let v = match self.target {
            RatioTarget::Fixed { pressure_ratio } => {
                gas.isentropic_volume_m3(1.0, start_volume_m3, pressure_ratio)
            }
            RatioTarget::FollowMeasured => {
                gas.isentropic_volume_m3(suction_pa, start_volume_m3, discharge_pa)
            }
        };
        let k = if corrected {
            self.correction(chamber)
        } else {
            1.0
        };
        min_f32(v * k, start_volume_m3)
    }

    /// Where `chamber`'s discharge must open, m, for a stroke that starts at `from_m` (its
    /// bottom dead point).
    pub fn opening_position_m(
        &self,
        cylinder: &Cylinder<f32>,
        gas: &GasProperties<f32>,
        chamber: Chamber,
        from_m: f32,
        suction_pa: f32,
        discharge_pa: f32,
    ) -> f32 {
        match chamber {
            Chamber::A => {
                let v0 = cylinder.volume_a_m3(from_m);
                let v = self.opening_volume_m3(gas, chamber, v0, suction_pa, discharge_pa);
                cylinder.position_for_volume_a_m(v)
            }
            Chamber::B => {
                let v0 = cylinder.volume_b_m3(from_m);
                let v = self.opening_volume_m3(gas, chamber, v0, suction_pa, discharge_pa);
                cylinder.position_for_volume_b_m(v)
            }
        }
    }

    /// Stroke-by-stroke correction from the chamber pressure measured when `chamber`'s
    /// discharge opened, against the discharge pressure the opening was *planned* for (a
    /// change of the line pressure in between is not a timing error of the machine, and must
    /// not be learned as one). One stroke moves the correction by at most
    /// [`VolumeRatioConfig::max_step`]: a single disturbed opening cannot throw the next one
    /// far off. Ignored for a fixed ratio or invalid pressures.
    pub fn observe_opening(
        &mut self,
        gas: &GasProperties<f32>,
        chamber: Chamber,
        chamber_pa: f32,
        planned_discharge_pa: f32,
    ) {
        if self.target != RatioTarget::FollowMeasured
            || !(chamber_pa > 0.0
                && planned_discharge_pa > 0.0
                && chamber_pa.is_finite()
                && planned_discharge_pa.is_finite())
        {
            return;
        }
        // p ∝ V^−γ near the opening: a relative pressure error e needs a relative volume change
        // of about −e/γ (short of p_d → open at a smaller volume).
        let e = chamber_pa / planned_discharge_pa - 1.0;
        let limit = self.config.max_step;
        let step = clamp_f32(self.config.correction_gain * e / gas.gamma, -limit, limit);
        let max = self.config.max_correction;
        let slot = match chamber {
            Chamber::A => &mut self.correction[0],
            Chamber::B => &mut self.correction[1],
        };
        *slot = clamp_f32(*slot * (1.0 + step), 1.0 - max, 1.0 + max);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isentropic_opening_matches_the_pressure_ratio() {
        let cyl = Cylinder::<f32>::reference();
        let gas = GasProperties::<f32>::air();
        let vr = VolumeRatio::new(VolumeRatioConfig::reference());
        // Chamber B compresses while x goes from 1 mm toward B.
        let x = vr.opening_position_m(&cyl, &gas, Chamber::B, 0.001, 1.0e5, 5.1e5);
        let ratio = cyl.volume_b_m3(0.001) / cyl.volume_b_m3(x);
        assert!((ratio - 5.1f32.powf(1.0 / 1.4)).abs() < 0.02, "{ratio}");
        // Chamber A, from the B end.
        let x = vr.opening_position_m(&cyl, &gas, Chamber::A, 0.204, 1.0e5, 3.1e5);
        let ratio = cyl.volume_a_m3(0.204) / cyl.volume_a_m3(x);
        assert!((ratio - 3.1f32.powf(1.0 / 1.4)).abs() < 0.02, "{ratio}");
        // Nonsense pressures: open at once.
        assert_eq!(
            vr.opening_position_m(&cyl, &gas, Chamber::A, 0.204, f32::NAN, 3e5),
            0.204
        );
    }

    #[test]
    fn a_short_chamber_pressure_moves_the_next_opening_later() {
        let cyl = Cylinder::<f32>::reference();
        let gas = GasProperties::<f32>::air();
        let mut vr = VolumeRatio::new(VolumeRatioConfig::reference());
        let before = vr.opening_position_m(&cyl, &gas, Chamber::B, 0.001, 1e5, 4e5);
        vr.observe_opening(&gas, Chamber::B, 3.8e5, 4e5);
        let after = vr.opening_position_m(&cyl, &gas, Chamber::B, 0.001, 1e5, 4e5);
        assert!(after > before, "B compresses toward +x: later = larger x");
        assert!(vr.correction(Chamber::B) < 1.0);
        assert_eq!(vr.correction(Chamber::A), 1.0);
    }
}
