//! The encoder channel's candidate: the slave scale's pitch error (a spatial periodogram of
//! the slave-minus-master reading, then the harmonic and scale fit).

use rayon::prelude::*;

use crate::plant::model::{model_key, model_section};

use super::super::candidate::{kept_span, EffectKind, Proposal};
use super::super::channel::ChannelId;
use super::super::ctx::Ctx;
use super::super::doc::{Edit, ModelDoc};
use super::super::fit::{lstsq, minimise_1d_par};
use super::super::residuals::{channel_raw, kept_of_raw};
use super::harmonics;

pub(super) fn pitch_error(ctx: &Ctx<'_>, doc: &ModelDoc) -> Option<Proposal> {
    let base = doc.with(&[Edit::RemoveSection(model_section!(
        effects.encoder_pitch_error
    ))]);
    let model = base.model().ok()?;
    let d = ctx.data;
    let raw = channel_raw(d, &model, ChannelId::Encoder)?;
    let y = kept_of_raw(d, ctx.band, ChannelId::Encoder, &raw);
    let lambda = model.encoder.period_m;
    let idx = &ctx.band.idx_encoder;
    let xk: Vec<f64> = idx.iter().filter_map(|&i| d.x_m.get(i).copied()).collect();
    // The quick scan demeans its columns per motion stretch at the kept samples, as the
    // residual is demeaned per stretch at every sample.
    // Each kept sample's stretch (the last slot: samples in none), so that the sums per
    // stretch are a vector indexed by it: the scan demeans tens of thousands of columns.
    let none = d.segments.len();
    let seg_of: Vec<usize> = idx
        .iter()
        .map(|&i| {
            d.segments
                .iter()
                .position(|s| s.contains(&i))
                .unwrap_or(none)
        })
        .collect();
    let demean_kept = |col: Vec<f64>| -> Vec<f64> {
        let mut sums = vec![(0.0, 0usize); none + 1];
        for (v, s) in col.iter().zip(&seg_of) {
            if let Some(e) = sums.get_mut(*s) {
                e.0 += v;
                e.1 += 1;
            }
        }
        col.iter()
            .zip(&seg_of)
            .map(|(v, s)| v - sums.get(*s).map_or(0.0, |(t, c)| t / (*c).max(1) as f64))
            .collect()
    };
    let lin = demean_kept(xk.clone());
    let (f_lo, f_hi) = (1.0 / (2.0 * lambda), 1.0 / (0.5 * lambda));
    let df = 1.0 / (8.0 * kept_span(&xk));
    let steps = ((f_hi - f_lo) / df).ceil().min(4000.0) as usize;
    // Every frequency on every core, then scanned in order (the first of equal ones wins,
    // as one thread would find it).
    let scan: Vec<Option<(f64, f64)>> = (0..=steps)
        .into_par_iter()
        .map(|i| {
            let f = f_lo + df * i as f64;
            let mut cols = vec![lin.clone()];
            cols.extend(harmonics(&xk, f, true).into_iter().map(&demean_kept));
            lstsq(&cols, &y).map(|(_, rss)| (f, rss))
        })
        .collect();
    let mut best: Option<(f64, f64)> = None;
    for (f, rss) in scan.into_iter().flatten() {
        if best.is_none_or(|b| rss < b.1) {
            best = Some((f, rss));
        }
    }
    let f0 = best?.0;
    // Refine with the columns demeaned and filtered exactly as the residual is.
    let filt = |col: &[f64]| kept_of_raw(d, ctx.band, ChannelId::Encoder, &d.demean_segments(col));
    // The scale's column is the same at every frequency: filtered once.
    let scale_col = filt(&d.x_m);
    let fitf = |f: f64| -> Option<(Vec<f64>, f64)> {
        let mut cols = vec![scale_col.clone()];
        let hs = harmonics(&d.x_m, f, true);
        // Columns in the order sin f, cos f, sin 2f, cos 2f.
        cols.extend(hs.iter().map(|h| filt(h)));
        lstsq(&cols, &y)
    };
    let (f, _) = minimise_1d_par(f0 - df, f0 + df, 5, 16, |f| fitf(f).map(|r| r.1))?;
    let (th, _) = fitf(f)?;
    let g = |i: usize| th.get(i).copied().unwrap_or(0.0);
    let (scale, a1, b1, a2, b2) = (g(0), g(1), g(2), g(3), g(4));
    Some(Proposal::setting(
        EffectKind::EncoderPitchError,
        &[
            (
                model_key!(effects.encoder_pitch_error / amplitude_m),
                a1.hypot(b1),
            ),
            (model_key!(effects.encoder_pitch_error / period_m), 1.0 / f),
            (
                model_key!(effects.encoder_pitch_error / phase_rad),
                b1.atan2(a1),
            ),
            (model_key!(effects.encoder_pitch_error / scale), scale),
            (
                model_key!(effects.encoder_pitch_error / amplitude2_m),
                a2.hypot(b2),
            ),
            (
                model_key!(effects.encoder_pitch_error / phase2_rad),
                b2.atan2(a2),
            ),
        ],
        6,
    ))
}
