//! The slave encoder's correction by the encoder-difference map (paper §4.2, Fig. 6): the
//! difference `d(x, v) = S·(frac(u − u₀) − ½) + D_dir + k_v·v` the map predicts from the
//! master's phase `u` within its period and the velocity `v`, taken out of the slave's
//! reading and its commutation angle each cycle. The calibration routine that maps it is
//! `control::calibration::encoder_map`.

use crate::real::clamp_f32;

/// One encoder period as a wrapping phase (2³²), the unit of the decoders' angles.
const TURN: f32 = 4_294_967_296.0;

/// The slave encoder's difference from the master's, as mapped (the calibration routine's
/// module header derives each term).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncoderMap {
    /// The encoders' period λ, m.
    pub period_m: f32,
    /// Saw height S, m (negative: a falling saw).
    pub saw_m: f32,
    /// Where in the master's period the saw steps, fraction of a period in [0, 1).
    pub step_phase: f32,
    /// Mean difference moving toward +x, m (the velocity part removed).
    pub toward_plus_m: f32,
    /// Mean difference moving toward −x, m.
    pub toward_minus_m: f32,
    /// Velocity coefficient k_v, m per m/s.
    pub velocity_s: f32,
    /// Speed over which the direction part blends between its two values, m/s.
    pub blend_mps: f32,
    /// RMS of what the fit left in the bins, m (what the map cannot explain).
    pub residual_m: f32,
}

impl EncoderMap {
    /// The difference the map predicts, m, with the master encoder at `master_phase`
    /// (wrapping, 2³² = one period, in its own frame) and the piston at `velocity_mps`.
    pub fn difference_m(&self, master_phase: u32, velocity_mps: f32) -> f32 {
        let u = master_phase as f32 / TURN;
        let s = u - self.step_phase;
        let frac = s - libm::floorf(s);
        let w = if self.blend_mps > 0.0 {
            clamp_f32(velocity_mps / self.blend_mps, -1.0, 1.0)
        } else {
            0.0
        };
        let mean = 0.5 * (self.toward_plus_m + self.toward_minus_m);
        let half = 0.5 * (self.toward_plus_m - self.toward_minus_m);
        self.saw_m * (frac - 0.5) + mean + w * half + self.velocity_s * velocity_mps
    }

    /// Takes the difference the map predicts ([`Self::difference_m`]) out of the slave's
    /// reading `slave_m` (m) and out of its commutation angle `slave_angle` (wrapping,
    /// 2³² = one period).
    ///
    /// Out of line (`memory.x` puts it in CCM SRAM with the control path): a machine without
    /// a map pays only the test of `ControlConfig::encoder_map` in its control step.
    #[inline(never)]
    pub fn correct(
        &self,
        master_phase: u32,
        velocity_mps: f32,
        slave_m: &mut f32,
        slave_angle: &mut u32,
    ) {
        let d = self.difference_m(master_phase, velocity_mps);
        *slave_m -= d;
        *slave_angle = slave_angle.wrapping_sub(crate::angle::turns(d / self.period_m));
    }
}
