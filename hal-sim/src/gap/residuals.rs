//! Residuals per channel: what the measured run shows minus what the model predicts from the
//! same measured inputs, limited to the analysis band ([`super::band`]).
//!
//! | channel | residual (sample-wise, before the band filter) |
//! |---|---|
//! | `force` | `m·Δ²x − (F_master + F_slave [behind their readings, realigned to the row's time, delayed by the actuator lag] + (p_A − p_B)·A_eff − F_fr(v, ω) + F_cog(x))`, smoothed by the force kernel: the force no model term explains, toward +x |
//! | `slave_force` | `F_slave − F_master` delayed by the model's slave lag (none: not delayed), judged while moving |
//! | `encoder` | `x_slave − x_master` minus the model's pitch error, judged while moving, mean removed per stretch of motion (a constant offset between the encoders is a zero, not an effect, and homing may set it anew at each standstill) |
//! | `pressure` | `p_A, p_B` minus the chambers replayed along the measured x(t) (and rotation, with open ports) through the model's chambers and pressure sensors |
//!
//! The force balance is the library's ([`fpc::physics::balance`]), as in the plant: friction
//! acts against the sliding velocity `(ẋ, ω·r)` of the turning piston, its axial part is
//! `F_fr(|u|)·ẋ/|u|`.

use fpc::physics::balance::{PistonForces, PistonState};
use fpc::units::Section;

use crate::plant::model::extra_force::{ExtraForce, ExtraState, Term};
use crate::plant::model::{ForceSensor, MachineModel};
use crate::signal::delayed;

use super::band::{force_kernel, lowpass, sg_weights, ColumnCache, Kernel};
use super::candidate::{EffectKind, Proposal};
use super::channel::ChannelId;
use super::data::Measured;
use super::loads::{LoadCache, Loads};
use super::replay::kept_replay;

/// The analysis band and the sample sets the statistics use.
///
/// The plain channels are filtered unmasked and judged only where the whole low-pass lies on
/// samples the channel may be judged on (the mask eroded by the kernel's half length). The
/// force channel is filtered in two stages: the acceleration kernel, which turns a raw second
/// difference (kN of noise per sample) into an acceleration only over its whole window, is
/// applied unmasked and judged where it lies on moving samples; its output is then masked to
/// those samples before the low-pass. A standstill never leaks into the band, yet the force
/// channel is judged up to the edge of a stop, where breakaway and creep friction act.
#[derive(Clone, Debug)]
pub struct Band {
    /// Upper edge of the band, Hz.
    pub band_hz: f64,
    /// Low-pass then force kernel: what the force channel's terms pass through.
    pub force: Kernel,
    /// The low-pass alone: what the other channels pass through.
    pub plain: Kernel,
    /// The force kernel alone (the differentiator's acceleration smoothing).
    pub accel: Kernel,
    /// Where the whole low-pass of a force term lies on judged samples (1): there the
    /// two stages are one kernel, `force`.
    pub force_interior: Vec<f64>,
    /// Decimation stride: about one sample per half period at the band edge, so that the
    /// residual noise left in the band is roughly independent from one kept sample to the
    /// next (the statistics count these samples).
    pub stride: usize,
    /// Where the force channel is judged (1) or not (0).
    pub mask_force: Vec<f64>,
    /// Where the encoder and slave-force channels are judged (while moving, like the force
    /// channel).
    pub mask_encoder: Vec<f64>,
    /// Where the pressure channel is judged: away from the log's ends and where its replay
    /// does not hinge on a port angle the log does not resolve
    /// ([`Measured::pressure_judged`]).
    pub mask_inner: Vec<f64>,
    /// Kept samples of the force channel.
    pub idx_force: Vec<usize>,
    /// Kept samples of the encoder channel.
    pub idx_encoder: Vec<usize>,
    /// Kept samples of the pressure channel.
    pub idx_inner: Vec<usize>,
    /// Columns of this band's searches, kept for the next selection step.
    pub columns: ColumnCache,
    /// The discovery basis's plain columns at the force channel's kept samples, by term and
    /// by what they depend on beyond the log ([`basis_key`]).
    pub basis_columns: ColumnCache<BasisKey>,
    /// The force balance's loads of the models of this log's analysis ([`LoadCache`]).
    pub loads: LoadCache,
    /// The named force candidates' band-filtered regressors at the kept samples, by search
    /// and the bits of what they depend on ([`super::effects`]): their grids are visited
    /// again at every selection step.
    pub search_columns: ColumnCache<(u8, u64, u64, u64)>,
    /// The pressure searches' stretches with their bands (`effects::pressure`), kept with
    /// their replays by first row, length and the bits of the position offset; read on the
    /// pressure channel only, so a stretch keeps the force alignment it was cut with.
    pub pressure_searches: ColumnCache<(usize, usize, u64), Option<(Measured, Band)>>,
    /// The other candidates' search stretch with its band (`effects::search_stretch`), kept
    /// by length and the bits of the position offset and of the force alignment.
    pub force_searches: ColumnCache<(usize, u64, u64), Option<(Measured, Band)>>,
    /// The pressure candidates' fits (`effects::propose`), by effect, the model's text and
    /// the bits of the position offset and of the force alignment: each replays the chambers
    /// 15–25 times, and a joint judgement fits a candidate again on a model an earlier step
    /// fitted it on.
    pub proposals: ProposalCache,
}

/// [`Band::proposals`]: a fit by effect, model text and the bits of the position offset and
/// of the force alignment.
pub type ProposalCache = ColumnCache<(EffectKind, String, u64, u64), Option<Proposal>>;

/// `mask` eroded by `half` samples on each side: 1 only where every sample within `half`
/// is 1.
pub fn erode(mask: &[f64], half: usize) -> Vec<f64> {
    let n = mask.len();
    let mut bad = vec![0usize; n + 1];
    for (i, w) in mask.iter().enumerate() {
        bad[i + 1] = bad[i] + usize::from(*w <= 0.0);
    }
    (0..n)
        .map(|i| {
            let lo = i.saturating_sub(half);
            let hi = (i + half + 1).min(n);
            let ok = i >= half && i + half < n && bad.get(hi) == bad.get(lo);
            f64::from(u8::from(ok))
        })
        .collect()
}

impl Band {
    /// The band of `band_hz` for `data`.
    pub fn new(data: &Measured, band_hz: f64) -> Result<Self, String> {
        let dt = data.dt_s;
        let h2 = sg_weights(data.sg_window, 2, 2, dt).ok_or("differentiator weights")?;
        let g = force_kernel(&h2, dt);
        let lp = lowpass(band_hz, data.sample_rate_hz());
        let force = Kernel::new(super::band::convolve(&lp, &g));
        let plain = Kernel::new(lp);
        let accel = Kernel::new(g);
        let stride = ((data.sample_rate_hz() / (2.0 * band_hz)).round() as usize).max(1);
        // Judged wherever the acceleration kernel lies on moving samples; where the low-pass
        // still reaches a standstill, the force terms are masked between the two stages.
        let mask_force = erode(&data.moving, accel.half());
        let force_interior = erode(&mask_force, plain.half());
        let judged: Vec<f64> = data
            .inner
            .iter()
            .zip(data.pressure_judged.iter().chain(std::iter::repeat(&1.0)))
            .map(|(a, b)| a.min(*b))
            .collect();
        let mask_inner = erode(&judged, plain.half());
        let mask_encoder = erode(&data.moving, plain.half());
        let pick = |mask: &[f64]| -> Vec<usize> {
            (0..mask.len())
                .step_by(stride)
                .filter(|&i| mask.get(i).is_some_and(|&w| w > 0.0))
                .collect()
        };
        Ok(Band {
            band_hz,
            idx_force: pick(&mask_force),
            idx_inner: pick(&mask_inner),
            idx_encoder: pick(&mask_encoder),
            mask_encoder,
            force,
            plain,
            accel,
            force_interior,
            stride,
            mask_force,
            mask_inner,
            columns: ColumnCache::default(),
            basis_columns: ColumnCache::default(),
            loads: LoadCache::default(),
            search_columns: ColumnCache::default(),
            pressure_searches: ColumnCache::default(),
            force_searches: ColumnCache::default(),
            proposals: ColumnCache::default(),
        })
    }

    /// The kernel, judging mask and kept samples of a channel.
    fn route(&self, ch: ChannelId) -> (&Kernel, &[f64], &[usize]) {
        match ch {
            ChannelId::Force => (&self.force, &self.mask_force, &self.idx_force),
            // The slave force says something of a lag only while the force changes: in a
            // hold both sections push alike and only dilute it with noise.
            ChannelId::Encoder | ChannelId::SlaveForce => {
                (&self.plain, &self.mask_encoder, &self.idx_encoder)
            }
            ChannelId::Pressure => (&self.plain, &self.mask_inner, &self.idx_inner),
        }
    }

    /// Force terms at samples `idx`: the acceleration kernel, zero off the judged samples,
    /// then the low-pass. A standstill's raw terms (stiction holds any force) never leak into
    /// the band, so the force channel is judged right up to where the differentiator window
    /// reaches a stop, where breakaway and creep friction live. Away from stops the two
    /// stages are the one combined kernel; near them the masked acceleration is computed
    /// once for every sample the low-pass reaches.
    fn force_terms(&self, raw: &[f64], idx: &[usize]) -> Vec<f64> {
        let n = raw.len();
        let h = self.plain.half();
        let interior = |i: usize| self.force_interior.get(i).is_some_and(|&w| w > 0.0);
        // Near an edge, the acceleration-filtered term (masked) on the span of samples the
        // low-passes of the edge samples reach, `seg` = samples `lo..lo + seg.len()`: kept
        // samples come in order, so a span grows until the next window no longer touches it.
        // Outside the span the term counts as zero, as the low-pass counts outside the log.
        let mut seg: Vec<f64> = Vec::new();
        let mut lo = 0usize;
        idx.iter()
            .map(|&i| {
                if interior(i) {
                    return self.force.at(raw, i);
                }
                let (from, to) = (i.saturating_sub(h), (i + h + 1).min(n));
                if from < lo || from > lo + seg.len() {
                    seg.clear();
                    lo = from;
                }
                for k in lo + seg.len()..to {
                    let judged = self.mask_force.get(k).is_some_and(|&m| m > 0.0);
                    seg.push(if judged { self.accel.at(raw, k) } else { 0.0 });
                }
                self.plain.at(&seg, i - lo)
            })
            .collect()
    }

    /// A raw per-sample term of channel `ch`, band-filtered, at the kept samples.
    pub fn kept(&self, _data: &Measured, ch: ChannelId, raw: &[f64]) -> Vec<f64> {
        let (k, _, idx) = self.route(ch);
        if ch == ChannelId::Force {
            return self.force_terms(raw, idx);
        }
        k.apply_at(raw, idx)
    }

    /// The same at every sample (zero where the channel is not judged).
    pub fn full(&self, _data: &Measured, ch: ChannelId, raw: &[f64]) -> Vec<f64> {
        let (k, mask, _) = self.route(ch);
        let judged = |i: usize| mask.get(i).is_some_and(|&w| w > 0.0);
        // Filtered in place: zero where not judged (or beyond `raw`).
        let mut out = k.apply(raw);
        out.resize(mask.len(), 0.0);
        for (i, o) in out.iter_mut().enumerate() {
            if !judged(i) {
                *o = 0.0;
            }
        }
        if ch == ChannelId::Force {
            // Near a standstill the force terms pass the two stages with the mask between.
            let edges: Vec<usize> = (0..mask.len())
                .filter(|&i| judged(i) && self.force_interior.get(i).is_none_or(|&w| w <= 0.0))
                .collect();
            for (i, v) in edges.iter().zip(self.force_terms(raw, &edges)) {
                if let Some(o) = out.get_mut(*i) {
                    *o = v;
                }
            }
        }
        out
    }

    /// Where the channel is judged.
    pub fn mask<'a>(&'a self, _data: &'a Measured, ch: ChannelId) -> &'a [f64] {
        self.route(ch).1
    }
}

/// One channel's residual for one model, at the kept samples only (the raw residual at
/// every row is dropped once filtered: [`band_raw`] makes it again).
#[derive(Clone, Debug)]
pub struct Residual {
    /// Which channel.
    pub channel: ChannelId,
    /// Band-filtered at the kept samples (for `pressure`: A's then B's).
    pub kept: Vec<f64>,
}

impl Residual {
    /// Sum of squares over the kept samples.
    pub fn rss(&self) -> f64 {
        self.kept.iter().map(|v| v * v).sum()
    }

    /// RMS over the kept samples.
    pub fn rms(&self) -> f64 {
        if self.kept.is_empty() {
            0.0
        } else {
            (self.rss() / self.kept.len() as f64).sqrt()
        }
    }
}

/// `x` shifted later by `samples` (fractional: linear interpolation; negative: earlier),
/// holding the end values beyond the ends.
pub fn shifted(x: &[f64], samples: f64) -> Vec<f64> {
    let n = x.len();
    let (first, last) = match (x.first(), x.last()) {
        (Some(&f), Some(&l)) => (f, l),
        _ => return Vec::new(),
    };
    if !samples.is_finite() {
        return vec![f64::NAN; n];
    }
    // `x` at `i − samples` = `x` at `j + f` with one whole shift `j − i` and one fraction
    // `f` for every sample.
    let whole = (-samples).floor();
    let f = -samples - whole;
    let whole = whole as isize;
    let last_index = n as isize - 1;
    (0..n)
        .map(|i| {
            let j = i as isize + whole;
            if j < 0 {
                return first;
            }
            if j >= last_index {
                return last;
            }
            let k = j as usize;
            match (x.get(k), x.get(k + 1)) {
                (Some(a), Some(b)) => a + f * (b - a),
                _ => last,
            }
        })
        .collect()
}

/// The key of the discovery basis's plain column of `term` on `data` with `model` in
/// [`Band::basis_columns`]: the term, and for `f_motor` (the motor forces as they act) the
/// model's actuator lag, the log's force alignment and the force readings' offsets and gains,
/// bit for bit; every other term is the log's alone.
pub fn basis_key(term: Term, data: &Measured, model: &MachineModel) -> BasisKey {
    match term {
        Term::FMotor => {
            let f = &model.sensors.force;
            let sensor = [
                f.offset_master_n,
                f.offset_slave_n,
                f.gain_master,
                f.gain_slave,
            ];
            (
                term,
                actuator_delay_s(model).to_bits(),
                data.force_align_s.to_bits(),
                sensor.map(f64::to_bits),
            )
        }
        _ => (term, 0, 0, [0; 4]),
    }
}

/// What a discovery basis column depends on ([`basis_key`]).
pub type BasisKey = (Term, u64, u64, [u64; 4]);

/// The model's actuator lag, s (0 without `[effects.actuator_lag]`).
fn actuator_delay_s(model: &MachineModel) -> f64 {
    model
        .effects
        .actuator_lag
        .as_ref()
        .map_or(0.0, |l| l.delay_s)
}

/// The motor forces as they act on the piston at each row, N: the forces behind the
/// readings (`sensor`), `late_s` after their rows (the log's alignment, `force_align_s`, plus
/// the model's actuator lag).
pub fn acting_motor_force_n(data: &Measured, sensor: &ForceSensor, late_s: f64) -> Vec<f64> {
    shifted(&motor_sum_n(data, sensor), late_s / data.dt_s)
}

/// Both sections' forces behind their readings through `sensor` summed at each row, N (not
/// realigned).
pub fn motor_sum_n(data: &Measured, sensor: &ForceSensor) -> Vec<f64> {
    let exact = sensor.exact();
    let force = |s: Section, r: f64| if exact { r } else { sensor.force_n(s, r) };
    let both = data.f_master_n.iter().zip(&data.f_slave_n);
    both.map(|(a, b)| force(Section::Master, *a) + force(Section::Slave, *b))
        .collect()
}

/// The tangential sliding speed ω·r at every sample, m/s.
pub fn tangential_mps(data: &Measured, model: &MachineModel) -> Vec<f64> {
    let r = model.friction_radius_m();
    data.omega_rad_s.iter().map(|w| w * r).collect()
}

/// The forces of the balance on the piston at every sample, by the model's laws
/// ([`fpc::physics::balance`]): the motor forces as they act (realigned and late by the
/// model's actuator lag), the gas force of the chambers' true pressures, cogging at x and
/// friction along the sliding velocity `(ẋ, ω·r)`.
pub fn force_terms(data: &Measured, model: &MachineModel) -> Vec<PistonForces<f64>> {
    force_terms_each(data, model).collect()
}

/// [`force_terms`] one row at a time, so a caller that keeps only a few of them (or a sum)
/// never holds the forces of every row at once.
pub fn force_terms_each<'a>(
    data: &'a Measured,
    model: &'a MachineModel,
) -> impl ExactSizeIterator<Item = PistonForces<f64>> + 'a {
    let n = data.len();
    let late_s = actuator_delay_s(model) + data.force_align_s;
    let acting = acting_motor_force_n(data, &model.sensors.force, late_s);
    let laws = model.piston_laws();
    let tang = tangential_mps(data, model);
    // The gas force acts with the chambers' true pressures: the readings through the model's
    // sensor offsets and gains, the sensors' first-order lag undone
    // (p = (p_read − offset + τ·ṗ_read)/gain).
    // Left in, the lag reads as friction (it follows the stroke direction) or as an actuator
    // lag (it follows the force's rate).
    let sensor = &model.sensors.pressure;
    (0..n).map(move |i| {
        let g = |v: &[f64]| v.get(i).copied().unwrap_or(0.0);
        laws.forces(&PistonState {
            x_m: g(&data.x_m),
            v_mps: g(&data.v_mps),
            tangential_mps: g(&tang),
            pressure_a_pa: sensor.true_pressure_pa(
                g(&data.p_a_pa),
                g(&data.dp_a_pa_per_s),
                sensor.chamber_a(),
            ),
            pressure_b_pa: sensor.true_pressure_pa(
                g(&data.p_b_pa),
                g(&data.dp_b_pa_per_s),
                sensor.chamber_b(),
            ),
            motor_n: g(&acting),
        })
    })
}

/// Everything the model's force terms add up to at every sample, toward +x (motor forces as
/// they act, gas, cogging, minus friction, and the extra force), N.
pub fn model_force_n(data: &Measured, model: &MachineModel) -> Vec<f64> {
    let extra = extra_force_n(data, model, data.force_align_s);
    force_terms_each(data, model)
        .enumerate()
        .map(|(i, f)| f.net_n() + extra.as_ref().and_then(|e| e.get(i)).unwrap_or(&0.0))
        .collect()
}

/// The raw force-balance residual `m·Δ²x − ΣF_model`, N: the force the model does not
/// explain ([`PistonForces::unexplained_n`]), less the model's extra force.
pub fn force_raw(data: &Measured, model: &MachineModel) -> Vec<f64> {
    let m = model.piston.mass_kg;
    let extra = extra_force_n(data, model, data.force_align_s);
    force_terms_each(data, model)
        .zip(&data.d2x_mps2)
        .enumerate()
        .map(|(i, (f, a))| {
            f.unexplained_n(m, *a) - extra.as_ref().and_then(|e| e.get(i)).unwrap_or(&0.0)
        })
        .collect()
}

/// The states the discovery basis is evaluated at, one per row as it is read: measured x, the
/// differentiator's velocity, the raw second difference (as the mass term of the balance),
/// the motor forces as they act (aligned by `align_s`, late by the model's actuator lag; with
/// `None` they are not read and count as 0), the logged pressure difference and the time from
/// the first row.
pub fn extra_states<'a>(
    data: &'a Measured,
    model: &MachineModel,
    align_s: Option<f64>,
) -> impl Iterator<Item = ExtraState> + 'a {
    let late_s = align_s.map(|a| actuator_delay_s(model) + a);
    let acting = late_s.map_or_else(Vec::new, |l| {
        acting_motor_force_n(data, &model.sensors.force, l)
    });
    let t0 = data.t_s.first().copied().unwrap_or(0.0);
    (0..data.len()).map(move |i| {
        let g = |v: &[f64]| v.get(i).copied().unwrap_or(0.0);
        ExtraState {
            x_m: g(&data.x_m),
            v_mps: g(&data.v_mps),
            a_mps2: g(&data.d2x_mps2),
            f_motor_n: g(&acting),
            dp_pa: g(&data.p_a_pa) - g(&data.p_b_pa),
            t_s: g(&data.t_s) - t0,
        }
    })
}

/// The model's `[effects.extra_force]` at every row, N, with the forces aligned by `align_s`
/// (`None`: the model has none).
pub fn extra_force_n(data: &Measured, model: &MachineModel, align_s: f64) -> Option<Vec<f64>> {
    let e = ExtraForce::from(model.effects.extra_force.as_ref()?);
    let align_s = e.reads_motor().then_some(align_s);
    Some(e.forces_n(extra_states(data, model, align_s)))
}

/// The slave force reading the model predicts from the master's, N: the master's force
/// behind its reading, late by the model's slave lag, read through the slave's reading.
pub fn slave_force_prediction(data: &Measured, model: &MachineModel) -> Vec<f64> {
    let sensor = &model.sensors.force;
    let master = sensor.forces_n(Section::Master, data.f_master_n.clone());
    let slave = match model.slave_lag_s() {
        Some(d) if d > 0.0 => delayed(&master, d / data.dt_s),
        _ => master,
    };
    sensor.readings_n(Section::Slave, slave)
}

/// What the model says the slave encoder reads minus the master's, m.
pub fn encoder_prediction(data: &Measured, model: &MachineModel) -> Vec<f64> {
    match &model.effects.encoder_pitch_error {
        Some(e) => data
            .x_m
            .iter()
            .map(|&x| e.reading_at_rest_m(x) - x)
            .collect(),
        None => vec![0.0; data.len()],
    }
}

/// The raw residual of `ch` for `model` (`None`: the channel cannot be formed from this log).
pub fn channel_raw(data: &Measured, model: &MachineModel, ch: ChannelId) -> Option<Vec<f64>> {
    match ch {
        ChannelId::Force => Some(force_raw(data, model)),
        ChannelId::SlaveForce => Some(
            slave_force_prediction(data, model)
                .iter()
                .zip(&data.f_slave_n)
                .map(|(p, s)| s - p)
                .collect(),
        ),
        ChannelId::Encoder => {
            let pred = encoder_prediction(data, model);
            let diff: Vec<f64> = data
                .x_slave_m
                .iter()
                .zip(&data.x_m)
                .zip(&pred)
                .map(|((s, m), p)| s - m - p)
                .collect();
            Some(data.demean_segments(&diff))
        }
        ChannelId::Pressure => {
            let kept = kept_replay(data, model)?;
            let [pa, pb] = kept.as_slice() else {
                return None;
            };
            let ra = data.p_a_pa.iter().zip(pa).map(|(m, p)| m - p);
            let rb = data.p_b_pa.iter().zip(pb).map(|(m, p)| m - p);
            Some(ra.chain(rb).collect())
        }
    }
}

/// [`force_raw`] on the log of `band`, with the loads it keeps ([`Band::loads`]): the same,
/// bit for bit.
pub fn band_force_raw(data: &Measured, band: &Band, model: &MachineModel) -> Vec<f64> {
    band_force_raw_aligned(data, band, model, data.force_align_s)
}

/// [`band_force_raw`] with the forces aligned by `align_s` instead of the log's alignment.
pub fn band_force_raw_aligned(
    data: &Measured,
    band: &Band,
    model: &MachineModel,
    align_s: f64,
) -> Vec<f64> {
    let loads = band
        .loads
        .of(model, || Loads::of_terms(force_terms_each(data, model)));
    let delay_s = actuator_delay_s(model);
    let acting = acting_motor_force_n(data, &model.sensors.force, delay_s + align_s);
    let extra = model.effects.extra_force.as_ref().map(|e| {
        band.loads
            .extra(e, (delay_s, align_s), &model.sensors.force, || {
                extra_force_n(data, model, align_s).unwrap_or_default()
            })
    });
    loads.force_raw(
        model.piston.mass_kg,
        &data.d2x_mps2,
        &acting,
        extra.as_deref().map(Vec::as_slice),
    )
}

/// The motor force that closes the balance of `model` at every row, N
/// ([`PistonForces::motor_needed_n`]), with the loads `band` keeps.
pub fn band_motor_needed_n(data: &Measured, band: &Band, model: &MachineModel) -> Vec<f64> {
    band.loads
        .of(model, || Loads::of_terms(force_terms_each(data, model)))
        .motor_needed_n(model.piston.mass_kg, &data.d2x_mps2)
}

/// [`channel_raw`] on the log of `band`, the force channel from the loads it keeps
/// ([`Band::loads`]).
pub fn band_raw(
    data: &Measured,
    band: &Band,
    model: &MachineModel,
    ch: ChannelId,
) -> Option<Vec<f64>> {
    match ch {
        ChannelId::Force => Some(band_force_raw(data, band, model)),
        _ => channel_raw(data, model, ch),
    }
}

/// The residual of `ch` for `model`.
pub fn residual(
    data: &Measured,
    band: &Band,
    model: &MachineModel,
    ch: ChannelId,
) -> Option<Residual> {
    let raw = band_raw(data, band, model, ch)?;
    let kept = kept_of_raw(data, band, ch, &raw);
    Some(Residual { channel: ch, kept })
}

/// Band-filters a raw residual (or regressor) of `ch` at the kept samples; the pressure
/// channel's two halves are filtered separately and concatenated.
pub fn kept_of_raw(data: &Measured, band: &Band, ch: ChannelId, raw: &[f64]) -> Vec<f64> {
    let n = data.len();
    if ch == ChannelId::Pressure {
        let (a, b) = raw.split_at(n.min(raw.len()));
        let mut out = band.kept(data, ch, a);
        out.extend(band.kept(data, ch, b));
        out
    } else {
        band.kept(data, ch, raw)
    }
}

/// Band-filters a raw residual of `ch` at every sample (pressure: A's then B's).
pub fn full_of_raw(data: &Measured, band: &Band, ch: ChannelId, raw: &[f64]) -> Vec<f64> {
    let n = data.len();
    if ch == ChannelId::Pressure {
        let (a, b) = raw.split_at(n.min(raw.len()));
        let mut out = band.full(data, ch, a);
        out.extend(band.full(data, ch, b));
        out
    } else {
        band.full(data, ch, raw)
    }
}

/// RMS of the band-filtered residual over every sample the channel is judged on.
pub fn full_rms(data: &Measured, band: &Band, ch: ChannelId, raw: &[f64]) -> f64 {
    rms_of_full(data, band, ch, &full_of_raw(data, band, ch, raw))
}

/// [`full_rms`] of a residual already band-filtered at every sample ([`full_of_raw`]).
pub fn rms_of_full(data: &Measured, band: &Band, ch: ChannelId, full: &[f64]) -> f64 {
    let mask = band.mask(data, ch);
    let (s, c) = full
        .iter()
        .zip(mask.iter().cycle())
        .filter(|(_, w)| **w > 0.0)
        .fold((0.0, 0usize), |(s, c), (v, _)| (s + v * v, c + 1));
    if c == 0 {
        0.0
    } else {
        (s / c as f64).sqrt()
    }
}
