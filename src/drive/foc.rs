//! Field-oriented current control of one motor section.
//!
//! Per section and per cycle: phase currents (codes → A), Clarke/Park with the electrical
//! angle, PI loops on d and q with anti-windup by conditional integration, the voltage vector
//! limited to the space-vector hexagon's inscribed circle, inverse Park and space-vector
//! (min–max injection) modulation to three duties.
//!
//! Arithmetic is `f32` on the FPU: the M4F does a multiply-add in one instruction, so the
//! fixed-point alternative would only cost range bookkeeping (figures in the M4 benchmark).

use crate::physics::motor::{clarke, inverse_clarke, inverse_park, park, Dq, MotorParams};
use crate::ports::PhaseCurrentCodes;
use crate::real::{max_f32, min_f32, sqrt_f32};
use crate::units::{Duty, PhaseDuties};

/// Current-sense calibration of one section.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentSense {
    /// Amps per code (sign: positive current into the motor).
    pub a_per_code: f32,
    /// Zero-current code offsets from mid-scale, per phase.
    pub offset_codes: [f32; 3],
}

impl CurrentSense {
    /// Reference: ±100 A over the 12-bit range, no offset.
    pub const fn reference() -> Self {
        CurrentSense {
            a_per_code: 100.0 / 2048.0,
            offset_codes: [0.0; 3],
        }
    }

    /// Phase currents in amperes.
    #[inline]
    pub fn amps(&self, codes: &PhaseCurrentCodes) -> [f32; 3] {
        let [a, b, c] = *codes;
        let [oa, ob, oc] = self.offset_codes;
        [
            (f32::from(a.centered()) - oa) * self.a_per_code,
            (f32::from(b.centered()) - ob) * self.a_per_code,
            (f32::from(c.centered()) - oc) * self.a_per_code,
        ]
    }
}

/// Gains of the current loops (same on d and q).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentLoopGains {
    /// Proportional gain, V/A (≈ L·ω_c).
    pub kp_v_per_a: f32,
    /// Integral gain, V/(A·s) (≈ R·ω_c, cancelling the electrical pole).
    pub ki_v_per_as: f32,
}

impl CurrentLoopGains {
    /// Pole-cancelling gains for a closed-loop bandwidth `bandwidth_rad_s`.
    pub fn for_bandwidth(motor: &MotorParams<f32>, bandwidth_rad_s: f32) -> Self {
        CurrentLoopGains {
            kp_v_per_a: motor.inductance_h * bandwidth_rad_s,
            ki_v_per_as: motor.resistance_ohm * bandwidth_rad_s,
        }
    }
}

/// Measured state of one section after a FOC step (for telemetry and supervision).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FocState {
    /// Measured d/q currents, A.
    pub current: Dq<f32>,
    /// Applied d/q voltage, V.
    pub voltage: Dq<f32>,
    /// Largest measured phase current magnitude, A.
    pub peak_phase_a: f32,
    /// The voltage limit was active this cycle.
    pub voltage_limited: bool,
}

/// The PI current controller of one section.
#[derive(Clone, Debug)]
pub struct CurrentController {
    gains: CurrentLoopGains,
    motor: MotorParams<f32>,
    /// The integral gain times the sample time, V/A, and the back-EMF constant, V·s/m:
    /// products the step would otherwise form every cycle, taken once (the same values).
    ki_dt_v_per_a: f32,
    back_emf_v_per_mps: f32,
    /// The motional cross-coupling per unit velocity, `ω_e·L/v = 2π·L/λ`, Ω·s/m (V per A
    /// per m/s; no division per cycle).
    coupling_h_per_m: f32,
    voltage_limit_v: f32,
    /// The voltage limit squared, V² (the step compares squares).
    voltage_limit_sq_v2: f32,
    /// Duty codes per volt of phase voltage, 65535/V_dc, precomputed (a division per cycle
    /// saved).
    codes_per_volt: f32,
    integral: Dq<f32>,
    state: FocState,
}

impl CurrentController {
    /// A controller for `motor` at `sample_time_s`.
    pub fn new(motor: &MotorParams<f32>, gains: CurrentLoopGains, sample_time_s: f32) -> Self {
        CurrentController {
            gains,
            motor: *motor,
            ki_dt_v_per_a: gains.ki_v_per_as * sample_time_s,
            back_emf_v_per_mps: motor.back_emf_v_per_mps(),
            coupling_h_per_m: motor.electrical_speed(1.0) * motor.inductance_h,
            voltage_limit_v: motor.voltage_limit_v(),
            voltage_limit_sq_v2: motor.voltage_limit_v() * motor.voltage_limit_v(),
            codes_per_volt: 65_535.0 / motor.bus_voltage_v,
            integral: Dq::default(),
            state: FocState::default(),
        }
    }

    /// Clears the integrators (when the outputs are switched off).
    pub fn reset(&mut self) {
        self.integral = Dq::default();
    }

    /// State of the last step.
    pub fn state(&self) -> &FocState {
        &self.state
    }

    /// One current-loop step: measured phase currents, electrical angle (wrapping, 2³² = one
    /// period), the d/q current references and the velocity (for the decoupling and back-EMF
    /// feed-forward) → the three duties.
    ///
    /// The PI zero cancels the electrical pole, which leaves that slow pole (L/R = 10 ms) in
    /// the response to any integrator mismatch; the model feed-forward (`R·i_ref`, the
    /// motional cross-coupling `ω_e·L·i` and the back-EMF `K_e·v`) puts the steady-state
    /// voltage in directly, so the integrator only trims model error and a saturated step
    /// settles at the fast closed-loop pole instead.
    #[inline(always)]
    pub fn step(
        &mut self,
        phase_a: [f32; 3],
        angle: u32,
        reference: Dq<f32>,
        velocity_mps: f32,
    ) -> PhaseDuties {
        let (sin, cos) = angle_sin_cos(angle);
        let i = park(clarke(phase_a), sin, cos);
        let err = Dq {
            d: reference.d - i.d,
            q: reference.q - i.q,
        };
        let m = &self.motor;
        let we_l = self.coupling_h_per_m * velocity_mps;
        let ff = Dq {
            d: m.resistance_ohm * reference.d - we_l * reference.q,
            q: m.resistance_ohm * reference.q
                + we_l * reference.d
                + self.back_emf_v_per_mps * velocity_mps,
        };
        let kp = self.gains.kp_v_per_a;
        let ki_dt = self.ki_dt_v_per_a;
        let integral = Dq {
            d: self.integral.d + ki_dt * err.d,
            q: self.integral.q + ki_dt * err.q,
        };
        let mut v = Dq {
            d: ff.d + kp * err.d + integral.d,
            q: ff.q + kp * err.q + integral.q,
        };
        // Compare squares: the square root is only needed when the limit is hit.
        let mag_sq = v.d * v.d + v.q * v.q;
        let limited = mag_sq > self.voltage_limit_sq_v2;
        if limited {
            // Scale back onto the circle and hold the integrators (anti-windup).
            let k = self.voltage_limit_v / sqrt_f32(mag_sq);
            v.d *= k;
            v.q *= k;
        } else {
            self.integral = integral;
        }
        let [a, b, c] = phase_a;
        self.state = FocState {
            current: i,
            voltage: v,
            peak_phase_a: max_f32(max_f32(a.abs(), b.abs()), c.abs()),
            voltage_limited: limited,
        };
        // One NaN test for the three duties: the vector is finite or NaN here (finite below
        // the limit; scaled by k < 1 above it) and the table's sin/cos are finite, so a phase
        // voltage is NaN only if the vector is. A NaN vector gives 50 % on every phase.
        if (v.d + v.q).is_nan() {
            return [Duty::HALF; 3];
        }
        modulate_codes(
            inverse_clarke(inverse_park(v, sin, cos)),
            self.codes_per_volt,
        )
    }
}

/// sin and cos of a wrapping angle (2³² = 2π).
#[inline]
pub fn angle_sin_cos(angle: u32) -> (f32, f32) {
    crate::angle::sin_cos_turns(angle)
}

/// Space-vector modulation by min–max injection: phase voltages (V) → duties on a bus of
/// `bus_v`. Saturates at 0 and 100 %.
#[inline]
pub fn modulate(v: [f32; 3], bus_v: f32) -> PhaseDuties {
    let inv = 1.0 / bus_v;
    let offset = common_mode_offset(v);
    v.map(|phase| Duty::from_fraction(0.5 + (phase + offset) * inv))
}

/// The min–max injection's common-mode voltage added to every phase of `v`, V: centres the
/// largest and the smallest phase on the bus.
#[inline(always)]
fn common_mode_offset([a, b, c]: [f32; 3]) -> f32 {
    -0.5 * (max_f32(max_f32(a, b), c) + min_f32(min_f32(a, b), c))
}

/// [`modulate`] of finite phase voltages `v` (V) with `codes_per_volt` = 65535/V_dc given,
/// straight to duty codes: the fraction `0.5 + (v + offset)/V_dc` as a code, rounded to
/// nearest, is `(v + offset)·codes_per_volt + 32768` truncated (the same duties to within
/// one code where the two roundings straddle a code boundary): the common-mode offset's
/// share `32768 + offset·codes_per_volt` taken once for the three phases, each phase one
/// multiply-add. Saturates at 0 and 100 %.
#[inline(always)]
fn modulate_codes(v: [f32; 3], codes_per_volt: f32) -> PhaseDuties {
    let base = 32_768.0 + common_mode_offset(v) * codes_per_volt;
    v.map(|phase| Duty::from_code_number(base + phase * codes_per_volt))
}

/// The average phase voltages (V, zero common mode) the duties apply on a bus of `bus_v`:
/// the inverse of [`modulate`] inside the linear range.
#[inline]
pub fn phase_voltages<T: crate::real::Real>(duties: &PhaseDuties, bus_v: T) -> [T; 3] {
    let [a, b, c] = duties.map(|d| T::of(d.fraction()));
    let mean = (a + b + c) * T::of(1.0 / 3.0);
    [(a - mean) * bus_v, (b - mean) * bus_v, (c - mean) * bus_v]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_nan_current_gives_half_duty_on_every_phase_and_a_finite_one_a_duty_in_range() {
        let motor = MotorParams::reference();
        let gains = CurrentLoopGains::for_bandwidth(&motor, 2000.0);
        let mut c = CurrentController::new(&motor, gains, 50e-6);
        let nan = c.step([f32::NAN, 1.0, -1.0], 0, Dq { d: 0.0, q: 10.0 }, 0.0);
        assert_eq!(nan, [Duty::HALF; 3]);
        let mut c = CurrentController::new(&motor, gains, 50e-6);
        // Far past the voltage limit: scaled back onto it, a vector that is not zero.
        let big = c.step([0.0; 3], 0x4000_0000, Dq { d: 0.0, q: 1e5 }, 3.0);
        assert!(c.state().voltage_limited);
        assert!(big.iter().any(|d| d.0 != Duty::HALF.0), "{big:?}");
        let mut c = CurrentController::new(&motor, gains, 50e-6);
        // An infinite reference: the vector is NaN (∞·0), and a NaN vector gives 50 %.
        let inf = c.step(
            [0.0; 3],
            0,
            Dq {
                d: f32::INFINITY,
                q: 0.0,
            },
            0.0,
        );
        assert_eq!(inf, [Duty::HALF; 3]);
    }

    #[test]
    fn modulation_reproduces_the_voltage_vector() {
        let v = [100.0, -30.0, -70.0];
        let d = modulate(v, 560.0);
        let back: [f32; 3] = phase_voltages(&d, 560.0);
        for (x, y) in back.iter().zip(v) {
            assert!((x - y).abs() < 0.05, "{back:?}");
        }
    }

    #[test]
    fn the_current_loops_codes_are_the_modulations_duties_within_one_code() {
        // Every phase voltage vector within the bus and beyond it (saturating), on a grid
        // fine enough to land next to code boundaries.
        let bus = 560.0f32;
        let per_volt = 65_535.0 / bus;
        let (mut worst, mut differ) = (0i32, 0u32);
        for i in -400..=400 {
            for j in -60..=60 {
                let v = [i as f32 * 0.73, j as f32 * 3.1 - 0.013 * i as f32, 0.0];
                let v = [v[0], v[1], -v[0] - v[1]];
                let by_fraction = modulate(v, bus);
                let by_code = modulate_codes(v, per_volt);
                for (f, c) in by_fraction.iter().zip(&by_code) {
                    let d = i32::from(f.0) - i32::from(c.0);
                    worst = worst.max(d.abs());
                    differ += u32::from(d != 0);
                }
            }
        }
        assert!(worst <= 1, "{worst} codes apart");
        // Rare: only where the two roundings straddle a code boundary.
        assert!(differ < 3 * 801 * 121 / 50, "{differ} duties differ");
    }
}
