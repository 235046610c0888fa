//! The analysis band and the samples each channel is judged on: every residual and regressor
//! passes the same zero-phase filters ([`super::filter`]) and is judged where the whole filter
//! lies on usable samples, at a stride of about one sample per half period of the band edge.

use std::sync::Arc;

use fpc::units::Section;

use super::cache::ColumnCache;
use super::channel::ChannelId;
use super::columns::Column;
use super::data::Measured;
use super::filter::{convolve, force_kernel, lowpass, sg_weights, Kernel};

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
    /// The force balance's columns at the force channel's kept samples ([`Column`]), kept
    /// for every model the workflow judges on this log.
    pub force_columns: ColumnCache<Column, Vec<f64>>,
    /// The motor forces (by section, `None`: both) filtered at every row by `force`.
    motor_filtered: ColumnCache<Option<Section>, Vec<f64>>,
}

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
            force_columns: ColumnCache::default(),
            motor_filtered: ColumnCache::default(),
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
        let filtered = k.apply(raw);
        let mut out: Vec<f64> = (0..mask.len())
            .map(|i| match filtered.get(i) {
                Some(&v) if judged(i) => v,
                _ => 0.0,
            })
            .collect();
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

    /// `col` band-filtered at the force channel's kept samples, kept for the log.
    pub fn force_column(&self, data: &Measured, col: Column) -> Arc<Vec<f64>> {
        self.force_columns
            .get_or_make(col, || self.force_column_anew(data, col))
    }

    /// `col` at the force channel's kept samples, computed.
    fn force_column_anew(&self, data: &Measured, col: Column) -> Vec<f64> {
        match col {
            Column::Motor { section, shift } => {
                self.motor_kept(data, section, f64::from_bits(shift))
            }
            _ => self.kept(data, ChannelId::Force, &col.raw(data)),
        }
    }

    /// [`Self::combine`] with every motor column shifted `extra` samples further: the
    /// other columns kept for the log, the shifted motor columns computed and not kept (the
    /// alignment's and the actuator lag's one-off points).
    pub fn combine_motors_shifted(
        &self,
        data: &Measured,
        combination: &[(f64, Column)],
        extra: f64,
    ) -> Vec<f64> {
        let mut out = vec![0.0; self.idx_force.len()];
        for (w, col) in combination {
            if *w == 0.0 {
                continue;
            }
            let kept = match *col {
                Column::Motor { section, shift } => Arc::new(self.force_column_once(
                    data,
                    Column::motor(section, f64::from_bits(shift) + extra),
                )),
                col => self.force_column(data, col),
            };
            for (o, v) in out.iter_mut().zip(kept.iter()) {
                *o += w * v;
            }
        }
        out
    }

    /// [`Column::Motor`]: the motor forces of `section` (`None`: both) shifted later by
    /// `shift` samples, band-filtered at the force channel's kept samples.
    ///
    /// Filtering commutes with a shift: where the combined kernel's whole window lies on
    /// judged samples and, shifted, inside the log, the value is the forces filtered at every
    /// row (once per log) interpolated at the shifted place; elsewhere (near a standstill or
    /// the log's ends) it is filtered anew from the shifted forces. The same sums to rounding,
    /// at a cost per shift of the kept samples instead of the rows (the alignment and
    /// actuator-lag searches try a hundred shifts).
    fn motor_kept(&self, data: &Measured, section: Option<Section>, shift: f64) -> Vec<f64> {
        let filtered = self.motor_filtered.get_or_make(section, || {
            self.force.apply(&super::columns::motor_n(data, section))
        });
        let n = filtered.len() as isize;
        let h = self.force.half() as isize;
        if !shift.is_finite() {
            return vec![f64::NAN; self.idx_force.len()];
        }
        let whole = (-shift).floor();
        let frac = -shift - whole;
        let whole = whole as isize;
        let interior = |i: usize| self.force_interior.get(i).is_some_and(|&w| w > 0.0);
        let mut out = Vec::with_capacity(self.idx_force.len());
        let mut anew = Vec::new();
        for (k, &i) in self.idx_force.iter().enumerate() {
            let c = i as isize + whole;
            let at = |j: isize| {
                usize::try_from(j)
                    .ok()
                    .and_then(|j| filtered.get(j))
                    .copied()
            };
            match (at(c), at(c + 1)) {
                (Some(a), Some(b)) if interior(i) && c - h >= 0 && c + 1 + h < n => {
                    out.push(a + frac * (b - a));
                }
                _ => {
                    out.push(0.0);
                    anew.push(k);
                }
            }
        }
        if !anew.is_empty() {
            let raw = super::columns::shifted(&super::columns::motor_n(data, section), shift);
            let idx: Vec<usize> = anew
                .iter()
                .filter_map(|&k| self.idx_force.get(k).copied())
                .collect();
            for (k, v) in anew.iter().zip(self.force_terms(&raw, &idx)) {
                if let Some(o) = out.get_mut(*k) {
                    *o = v;
                }
            }
        }
        out
    }

    /// `col` band-filtered at the force channel's kept samples, computed anew and not kept
    /// (a search's one-off points).
    pub fn force_column_once(&self, data: &Measured, col: Column) -> Vec<f64> {
        match self.force_columns.get(&col) {
            Some(kept) => kept.to_vec(),
            None => self.force_column_anew(data, col),
        }
    }

    /// `Σ wᵢ·columnᵢ` at the force channel's kept samples, each column kept for the log.
    pub fn combine(&self, data: &Measured, combination: &[(f64, Column)]) -> Vec<f64> {
        let mut out = vec![0.0; self.idx_force.len()];
        for (w, col) in combination {
            if *w == 0.0 {
                continue;
            }
            let kept = self.force_column(data, *col);
            for (o, v) in out.iter_mut().zip(kept.iter()) {
                *o += w * v;
            }
        }
        out
    }

    /// Where the channel is judged.
    pub fn mask<'a>(&'a self, _data: &'a Measured, ch: ChannelId) -> &'a [f64] {
        self.route(ch).1
    }
}
