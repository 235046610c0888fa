//! The model-gap workflow (`fpc-sim gap`, `docs/formats.md` §3): find where the model and a
//! measured run disagree, name the missing effect, fit it, add it to the model and show the
//! gap shrink.
//!
//! 1. **Residuals per channel** ([`residuals`]): force balance, slave against master force,
//!    slave against master encoder, chamber pressures replayed along the measured motion —
//!    each limited to the analysis band ([`band`]), velocity and acceleration from the
//!    firmware's own differentiator ([`data`]).
//! 2. **Where they disagree** ([`report`]): residual maps by position (and modulo the pole
//!    and N–N pitches), velocity, acceleration and pressure difference; lags by FFT
//!    cross-correlation ([`crate::signal::xcorr_lag`]).
//! 3. **Named candidates** ([`effects`]) fitted by least squares or small 1-D/Gauss–Newton
//!    searches ([`fit`]), **selected** forward by BIC with a practical floor ([`select`]);
//!    what no named effect describes, as terms of a fixed basis ([`discover`]).
//! 4. **Add and show**: the augmented model document ([`doc`]), the comparison re-run with
//!    it, per-channel RMS before and after, and the report.
//!
//! [`synth`] makes the measured runs the proofs, the benchmark and the docs use.

pub mod align;
pub mod band;
pub mod candidate;
pub mod channel;
pub mod ctx;
pub mod data;
pub mod discover;
pub mod doc;
pub mod effects;
pub mod fit;
pub mod judge;
pub mod loads;
pub mod offset;
pub mod page;
mod reconsider;
pub mod replay;
pub mod report;
pub mod residuals;
pub mod select;
pub mod synth;
pub mod uncertainty;
pub mod unexplained;

use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::Serialize;

use crate::failure::Failure;
use crate::plant::model::{model_key, model_section, MachineModel};
use crate::runlog::RunLog;

use candidate::EffectKind;
use channel::ChannelId;
use ctx::Ctx;
use data::Measured;
use doc::ModelDoc;
use residuals::{band_raw, full_of_raw, full_rms, rms_of_full, Band};
use select::{select, Judgements, Selection};

/// Default upper edge of the analysis band, Hz: above the cogging frequency at 4 m/s
/// (4 m/s / 24 mm = 170 Hz), below the differentiator's noise.
pub const DEFAULT_BAND_HZ: f64 = 300.0;

/// Most times the selection is run again with a refitted force alignment.
pub const MAX_ALIGNMENT_PASSES: usize = 3;

/// Stribeck's region, in Stribeck velocities: where its residual RMS is reported.
pub const STRIBECK_REGION: f64 = 3.0;

/// Settings of an analysis.
#[derive(Clone, Debug, PartialEq)]
pub struct GapOptions {
    /// Upper edge of the analysis band, Hz.
    pub band_hz: f64,
}

impl Default for GapOptions {
    fn default() -> Self {
        GapOptions {
            band_hz: DEFAULT_BAND_HZ,
        }
    }
}

/// A channel's RMS before and after (`docs/formats.md` §3).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ChannelJson {
    /// Channel name.
    pub name: String,
    /// Unit of the residual.
    pub unit: String,
    /// RMS of the band-limited residual with the input model.
    pub rms_before: f64,
    /// The same with the augmented model.
    pub rms_after: f64,
    /// What the augmented model still misses, judged ([`unexplained`]).
    pub unexplained: unexplained::UnexplainedJson,
}

/// An effect added (`docs/formats.md` §3).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct EffectJson {
    /// Effect name.
    pub name: String,
    /// The channel it shows in.
    pub channel: String,
    /// Fitted parameters, SI, the model file's keys.
    pub params: BTreeMap<String, f64>,
    /// One standard deviation of each fitted parameter, SI, by the same keys (a key set but
    /// not fitted, or one the log does not pin down, is absent).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub uncertainty: BTreeMap<String, f64>,
    /// Channel RMS before adding it.
    pub rms_before: f64,
    /// Channel RMS after adding it.
    pub rms_after: f64,
    /// BIC improvement when it was added.
    pub delta_bic: f64,
    /// Share of the residual explained where it acts.
    pub explained: f64,
    /// Stribeck only: channel RMS in its low-speed region before adding it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub region_rms_before: Option<f64>,
    /// Stribeck only: the same after.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub region_rms_after: Option<f64>,
}

/// A force no named effect describes, as terms of the discovery basis (`docs/formats.md`,
/// "Beyond the library").
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct DiscoveredJson {
    /// The channel (`force`).
    pub channel: String,
    /// Coefficient of each basis term, SI, by the term's name.
    pub terms: BTreeMap<String, f64>,
    /// Period of the periodic pair, m, if it is in.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub period_m: Option<f64>,
    /// What the terms are physically.
    pub reading: String,
    /// Channel RMS of the final model without the terms.
    pub rms_before: f64,
    /// Channel RMS with them.
    pub rms_after: f64,
    /// Share of the channel's mean square they explain.
    pub explained: f64,
}

/// The JSON `fpc-sim gap --json` prints.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct GapJson {
    /// Per-channel RMS before and after.
    pub channels: Vec<ChannelJson>,
    /// Effects added, most significant first (empty: nothing significant is missing).
    pub effects: Vec<EffectJson>,
    /// Forces no named effect describes (empty when nothing is left).
    pub discovered: Vec<DiscoveredJson>,
    /// Where the augmented model was written (empty if it was not).
    pub model_out: String,
    /// Warnings (collinear candidates, channels not formed).
    pub warnings: Vec<String>,
    /// How long the logged forces act after their row by the log's convention, s: the
    /// declared `−force_delay_s`, or the fitted alignment ([`align`]).
    pub force_align_s: f64,
    /// Whether `force_align_s` was fitted (no `# force_delay_s` in the log).
    pub force_align_fitted: bool,
}

/// Everything an analysis produced.
#[derive(Clone, Debug)]
pub struct GapOutcome {
    /// The JSON summary (`model_out` filled in by the caller that writes the model).
    pub json: GapJson,
    /// The augmented model file's text.
    pub model_text: String,
    /// The input model document.
    pub input: ModelDoc,
    /// The measured run.
    pub measured: Measured,
    /// The band.
    pub band: Band,
    /// The selection.
    pub selection: Selection,
    /// Each channel's residual with the input and the augmented model, band-filtered at
    /// every sample ([`residuals::full_of_raw`]), in the channels' order.
    pub filtered: Vec<ChannelResiduals>,
    /// Each channel's residual after the fit, judged, in the channels' order.
    pub unexplained: Vec<unexplained::Unexplained>,
}

/// One channel's band-filtered residual at every sample, with the input and the augmented
/// model (pressure: chamber A's samples then B's).
#[derive(Clone, Debug)]
pub struct ChannelResiduals {
    /// Which channel.
    pub channel: ChannelId,
    /// With the input model.
    pub before: Vec<f64>,
    /// With the augmented model.
    pub after: Vec<f64>,
}

/// Runs the workflow on a validated log and model text. Bad input (a model or a log the
/// workflow cannot use) is exit 2; the rest is exit 1.
pub fn analyse(model_text: &str, log: &RunLog, opts: &GapOptions) -> Result<GapOutcome, Failure> {
    let (input, model, measured) = checked_inputs(model_text, log, opts)?;
    analyse_measured(input, model, measured, opts)
}

/// [`analyse`] taking the log, which is dropped as soon as the measured run is made from it:
/// the analysis never holds the log's columns beside its own.
pub fn analyse_log(
    model_text: &str,
    log: RunLog,
    opts: &GapOptions,
) -> Result<GapOutcome, Failure> {
    let (input, model, measured) = checked_inputs(model_text, &log, opts)?;
    drop(log);
    analyse_measured(input, model, measured, opts)
}

/// [`analyse`] from the checked inputs ([`checked_inputs`]).
fn analyse_measured(
    input: ModelDoc,
    model: MachineModel,
    mut measured: Measured,
    opts: &GapOptions,
) -> Result<GapOutcome, Failure> {
    offset::set_position_offset(&mut measured, &model, opts.band_hz);
    let band = Band::new(&measured, opts.band_hz).map_err(Failure::runtime)?;
    let (selection, fitted_alignment) = aligned_selection(&mut measured, &band, &model, &input)?;
    let ctx = Ctx {
        data: &measured,
        band: &band,
    };
    // Each fitted value is written whole, with its uncertainty beside it as a comment.
    let sigma = uncertainty::of_selection(&ctx, &selection);
    // The searches are over: their columns (at the kept samples) are not read again.
    band.columns.clear();
    band.basis_columns.clear();
    band.search_columns.clear();
    band.pressure_searches.clear();
    band.proposals.clear();
    let model_text = augmented_text(&selection, &sigma)?;
    // Re-run the comparison with the model exactly as written.
    let after_model = MachineModel::parse(&model_text)
        .map_err(|e| Failure::runtime(format!("augmented model does not load: {e}")))?;
    let mut warnings = selection.warnings.clone();
    if measured.ports == data::PortsMeta::Unknown {
        warnings.push(
            "no `# ports = open|closed` metadata: the pressure channel is not compared".into(),
        );
    }
    let filtered = filtered_residuals(&measured, &band, &model, &after_model);
    let unexplained: Vec<unexplained::Unexplained> = filtered
        .iter()
        .map(|c| {
            unexplained::judge(
                &measured,
                &band,
                &after_model,
                c.channel,
                &c.before,
                &c.after,
            )
        })
        .collect();
    let channels: Vec<ChannelJson> = filtered
        .iter()
        .zip(&unexplained)
        .map(|(c, u)| ChannelJson {
            name: c.channel.name().into(),
            unit: c.channel.unit().into(),
            rms_before: rms_of_full(&measured, &band, c.channel, &c.before),
            rms_after: rms_of_full(&measured, &band, c.channel, &c.after),
            unexplained: u.json.clone(),
        })
        .collect();
    let effects = effect_rows(&ctx, &selection, sigma).map_err(Failure::runtime)?;
    let discovered = discovered_rows(&ctx, &selection).map_err(Failure::runtime)?;
    // Every force residual is made: the report reads the ones kept in `filtered`, so the
    // models' loads (three columns of the log's length each) go.
    band.loads.clear();
    Ok(GapOutcome {
        json: GapJson {
            channels,
            effects,
            discovered,
            model_out: String::new(),
            warnings,
            force_align_s: measured.force_align_s,
            force_align_fitted: fitted_alignment.is_some(),
        },
        model_text,
        input,
        measured,
        band,
        selection,
        filtered,
        unexplained,
    })
}

/// The input model (as a document and loaded) and the measured run, checked against each
/// other and the band `opts.band_hz` (positive, below the log's Nyquist frequency); every
/// error is bad input.
fn checked_inputs(
    model_text: &str,
    log: &RunLog,
    opts: &GapOptions,
) -> Result<(ModelDoc, MachineModel, Measured), Failure> {
    let input = ModelDoc::parse(model_text).map_err(Failure::bad_input)?;
    let model = input.model().map_err(Failure::bad_input)?;
    if !(opts.band_hz.is_finite() && opts.band_hz > 0.0) {
        return Err(Failure::bad_input(format!(
            "--band-hz {}: must be positive",
            opts.band_hz
        )));
    }
    let measured = Measured::from_log(log, model.encoder.period_m).map_err(Failure::bad_input)?;
    measured.check_against(&model).map_err(Failure::bad_input)?;
    let nyquist = 0.5 * measured.sample_rate_hz();
    if opts.band_hz >= nyquist {
        return Err(Failure::bad_input(format!(
            "--band-hz {}: must be below the log's Nyquist frequency, {nyquist} Hz",
            opts.band_hz
        )));
    }
    Ok((input, model, measured))
}

/// The selection from `input` with the force alignment the log declares, or else with the
/// one fitted ([`align`]), refitted on the augmented model until it settles; the fitted
/// alignment, if any, is set on `measured`.
fn aligned_selection(
    measured: &mut Measured,
    band: &Band,
    model: &MachineModel,
    input: &ModelDoc,
) -> Result<(Selection, Option<align::Alignment>), Failure> {
    let mut fitted_alignment = if measured.force_delay_s.is_none() {
        align::estimate(measured, band, model)
    } else {
        None
    };
    if let Some(a) = fitted_alignment {
        measured.force_align_s = a.used_s;
    }
    let mut judgements = Judgements::default();
    let mut selection = select(
        &Ctx {
            data: measured,
            band,
        },
        input,
        &mut judgements,
    )
    .map_err(Failure::runtime)?;
    // The alignment was fitted with the input model, whose missing effects bias it. Fit it
    // again with the augmented model — less any actuator lag, which is the same shift and
    // may only have been added to make up for a biased alignment — and, if it moved, select
    // again from the input model with it, until it settles (a few passes at most).
    for _ in 0..MAX_ALIGNMENT_PASSES {
        let Some(previous) = fitted_alignment else {
            break;
        };
        let augmented = selection
            .doc
            .with(&[doc::Edit::RemoveSection(model_section!(
                effects.actuator_lag
            ))])
            .model()
            .map_err(Failure::runtime)?;
        let Some(next) = align::estimate(measured, band, &augmented) else {
            break;
        };
        if (next.used_s - previous.used_s).abs() <= 0.05 * measured.dt_s {
            break;
        }
        measured.force_align_s = next.used_s;
        fitted_alignment = Some(next);
        selection = select(
            &Ctx {
                data: measured,
                band,
            },
            input,
            &mut judgements,
        )
        .map_err(Failure::runtime)?;
    }
    Ok((selection, fitted_alignment))
}

/// The augmented model file: a first comment naming what was added, then the selection's
/// model with each fitted value's uncertainty `sigma` beside it as a comment.
fn augmented_text(
    selection: &Selection,
    sigma: &BTreeMap<EffectKind, BTreeMap<String, f64>>,
) -> Result<String, Failure> {
    // What the final model holds: the named effects added, and the discovered terms if any
    // survived the pruning.
    let mut names: Vec<&str> = selection
        .added
        .iter()
        .filter(|a| a.proposal.kind.named())
        .map(|a| a.proposal.kind.name())
        .collect();
    if selection
        .doc
        .has_section(model_section!(effects.extra_force))
    {
        names.push(EffectKind::ExtraForce.name());
    }
    Ok(format!(
        "# Augmented by `fpc-sim gap`: {}\n{}",
        if names.is_empty() {
            "nothing significant was missing".to_string()
        } else {
            names.join(", ") + " added"
        },
        uncertainty::annotated(&selection.doc, selection, sigma)
            .to_text()
            .map_err(Failure::runtime)?
    ))
}

/// Each channel's band-filtered residual at every sample with the input `model` and the
/// augmented `after_model`, in the channels' order.
fn filtered_residuals(
    measured: &Measured,
    band: &Band,
    model: &MachineModel,
    after_model: &MachineModel,
) -> Vec<ChannelResiduals> {
    // The channels' replays are independent: on every core, kept in the channels' order.
    // Their band-filtered residuals are kept for the report's maps and overlays.
    ChannelId::ALL
        .par_iter()
        .filter_map(|&ch| {
            let (b, a) = rayon::join(
                || band_raw(measured, band, model, ch),
                || band_raw(measured, band, after_model, ch),
            );
            let (b, a) = (b?, a?);
            let (before, after) = rayon::join(
                || full_of_raw(measured, band, ch, &b),
                || full_of_raw(measured, band, ch, &a),
            );
            Some(ChannelResiduals {
                channel: ch,
                before,
                after,
            })
        })
        .collect()
}

/// Each added effect's channel RMS just before and just after it was added (the models of
/// the selection's steps), with its final parameters and their uncertainties `sigma`.
fn effect_rows(
    ctx: &Ctx<'_>,
    selection: &Selection,
    mut sigma: BTreeMap<EffectKind, BTreeMap<String, f64>>,
) -> Result<Vec<EffectJson>, String> {
    let mut rows = Vec::new();
    for (a, (before, after)) in selection.added.iter().zip(&selection.steps) {
        let kind = a.proposal.kind;
        if !kind.named() {
            continue;
        }
        // The channel its evidence was judged on (a sealed chamber's transducer gain: the force).
        let ch = kind.judged_on(ctx.data);
        let raw_b = band_raw(ctx.data, ctx.band, &before.model()?, ch).unwrap_or_default();
        let raw_a = band_raw(ctx.data, ctx.band, &after.model()?, ch).unwrap_or_default();
        let (region_rms_before, region_rms_after) = if kind == EffectKind::StribeckFriction {
            let vs = a
                .proposal
                .params
                .iter()
                .find(|p| p.0 == model_key!(effects.stribeck_friction / velocity_mps).name)
                .map_or(0.02, |p| p.1);
            (
                Some(low_speed_rms(ctx, &raw_b, vs)),
                Some(low_speed_rms(ctx, &raw_a, vs)),
            )
        } else {
            (None, None)
        };
        rows.push(EffectJson {
            name: kind.name().into(),
            channel: ch.name().into(),
            params: a
                .proposal
                .params
                .iter()
                .map(|(k, v)| (k.to_string(), *v))
                .collect(),
            uncertainty: sigma.remove(&kind).unwrap_or_default(),
            rms_before: full_rms(ctx.data, ctx.band, ch, &raw_b),
            rms_after: full_rms(ctx.data, ctx.band, ch, &raw_a),
            delta_bic: a.delta_bic,
            explained: a.explained,
            region_rms_before,
            region_rms_after,
        });
    }
    Ok(rows)
}

/// The discovered terms of the final model, with the force channel's RMS without and with
/// them (empty when it has none).
fn discovered_rows(ctx: &Ctx<'_>, selection: &Selection) -> Result<Vec<DiscoveredJson>, String> {
    let model = selection.doc.model()?;
    let Some(extra) = &model.effects.extra_force else {
        return Ok(Vec::new());
    };
    let terms = extra.parsed()?;
    if terms.is_empty() {
        return Ok(Vec::new());
    }
    let without = selection
        .doc
        .with(&[doc::Edit::RemoveSection(model_section!(
            effects.extra_force
        ))])
        .model()?;
    let ch = ChannelId::Force;
    let before = full_rms(
        ctx.data,
        ctx.band,
        ch,
        &band_raw(ctx.data, ctx.band, &without, ch).unwrap_or_default(),
    );
    let after = full_rms(
        ctx.data,
        ctx.band,
        ch,
        &band_raw(ctx.data, ctx.band, &model, ch).unwrap_or_default(),
    );
    Ok(vec![DiscoveredJson {
        channel: ch.name().into(),
        terms: terms
            .iter()
            .map(|(t, c)| (t.name().to_string(), *c))
            .collect(),
        period_m: extra.period_m,
        reading: discover::reading(&terms, extra.period_m),
        rms_before: before,
        rms_after: after,
        explained: if before > 0.0 {
            1.0 - (after / before).powi(2)
        } else {
            0.0
        },
    }])
}

/// RMS of the band-limited force residual where `0 < |v| < STRIBECK_REGION·v_s`, N.
pub fn low_speed_rms(ctx: &Ctx<'_>, raw: &[f64], vs_mps: f64) -> f64 {
    let full = ctx.band.full(ctx.data, ChannelId::Force, raw);
    let (s, c) = full
        .iter()
        .zip(&ctx.data.v_mps)
        .zip(&ctx.data.moving)
        .filter(|((_, v), w)| **w > 0.0 && v.abs() < STRIBECK_REGION * vs_mps)
        .fold((0.0, 0usize), |(s, c), ((r, _), _)| (s + r * r, c + 1));
    if c == 0 {
        0.0
    } else {
        (s / c as f64).sqrt()
    }
}
