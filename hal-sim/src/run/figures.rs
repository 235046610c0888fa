//! The figures that compare a controller with the published rig's problems (paper §4, §4.1,
//! §5): the section force difference at the dead points, the spectral line near 400 Hz of
//! the position error (stroking and at rest), the overshoot past the dead points, and the
//! travel, volume ratio and p–V pressure ratio they lead to.

use std::collections::VecDeque;

use fpc::units::CONTROL_PERIOD_S;

use super::spectrum::{Spectrum, LINE_BAND_HZ, MIN_SAMPLES};
use crate::plant::dynamics::Plant;

/// Half-width of the window around a dead point in which the force difference counts, s.
pub const DEAD_POINT_WINDOW_S: f64 = 5e-3;

/// Samples of position error kept for the spectra (3.3 s at 20 kHz): a bounded ring.
const SPECTRUM_SAMPLES: usize = 1 << 16;

/// The band searched for the position error's strongest line wherever it lies (a limit
/// cycle outside 340–460 Hz), Hz: above the strokes' own harmonics.
pub const WIDE_BAND_HZ: (f64, f64) = (100.0, 2000.0);

/// Cycles the figures are taken over (the last ones), as the other figures of `run`.
const LAST_CYCLES: usize = 5;

/// Extremes of one compression cycle.
#[derive(Clone, Copy, Debug)]
struct Extremes {
    x: (f64, f64),
    v_a: (f64, f64),
    v_b: (f64, f64),
    p_a: (f64, f64),
    p_b: (f64, f64),
    force: (f64, f64),
}

impl Default for Extremes {
    fn default() -> Self {
        let e = (f64::INFINITY, f64::NEG_INFINITY);
        Extremes {
            x: e,
            v_a: e,
            v_b: e,
            p_a: e,
            p_b: e,
            force: e,
        }
    }
}

fn widen(r: &mut (f64, f64), v: f64) {
    r.0 = r.0.min(v);
    r.1 = r.1.max(v);
}

/// Collects the figures while a run strokes.
#[derive(Default)]
pub(super) struct PaperFigures {
    stroke_err: VecDeque<f64>,
    rest_err: VecDeque<f64>,
    rest_done: bool,
    last_ref_m: Option<f32>,
    recent: VecDeque<(f64, f64)>,
    open: Option<(f64, f64)>,
    dead_point_diffs: Vec<f64>,
    overshoots: Vec<f64>,
    diff_sq: f64,
    total_sq: f64,
    cycles: Vec<Extremes>,
    current: Extremes,
}

fn push_bounded(q: &mut VecDeque<f64>, v: f64) {
    if q.len() == SPECTRUM_SAMPLES {
        q.pop_front();
    }
    q.push_back(v);
}

impl PaperFigures {
    /// Before the strokes: the position error counts as "at rest" while the reference stands
    /// still; the first such stretch long enough for a spectrum is kept.
    pub(super) fn before_strokes(&mut self, x_m: f64, reference_m: f32) {
        if self.rest_err.len() >= MIN_SAMPLES && self.last_ref_m != Some(reference_m) {
            self.rest_done = true;
        }
        if self.rest_done {
            return;
        }
        if self.last_ref_m == Some(reference_m) {
            push_bounded(&mut self.rest_err, x_m - f64::from(reference_m));
        } else {
            self.rest_err.clear();
        }
        self.last_ref_m = Some(reference_m);
    }

    /// One sample while stroking: the true position against the reference, the two
    /// sections' reported forces, the plant's chambers.
    pub(super) fn stroking(
        &mut self,
        t_s: f64,
        x_err_m: f64,
        f_master: f64,
        f_slave: f64,
        plant: &Plant,
    ) {
        push_bounded(&mut self.stroke_err, x_err_m);
        let diff = (f_master - f_slave).abs();
        self.diff_sq += diff * diff;
        self.total_sq += (f_master + f_slave).powi(2);
        while self
            .recent
            .front()
            .is_some_and(|(t, _)| *t < t_s - DEAD_POINT_WINDOW_S)
        {
            self.recent.pop_front();
        }
        self.recent.push_back((t_s, diff));
        if let Some((until, max)) = self.open.as_mut() {
            *max = max.max(diff);
            if t_s >= *until {
                self.dead_point_diffs.push(*max);
                self.open = None;
            }
        }
        let c = &plant.chambers;
        let e = &mut self.current;
        widen(&mut e.x, plant.x_m);
        widen(&mut e.v_a, c.a.volume_m3);
        widen(&mut e.v_b, c.b.volume_m3);
        widen(&mut e.p_a, c.a.pressure_pa);
        widen(&mut e.p_b, c.b.pressure_pa);
        widen(&mut e.force, f_master + f_slave);
    }

    /// The reference turned at a dead point at `t_s`; the piston went `overshoot_m` past the
    /// target (toward the head; negative: short of it).
    pub(super) fn dead_point(&mut self, t_s: f64, overshoot_m: f64) {
        self.overshoots.push(overshoot_m);
        let before = self.recent.iter().map(|(_, d)| *d).fold(0.0, f64::max);
        if let Some((_, max)) = self.open.take() {
            self.dead_point_diffs.push(max);
        }
        self.open = Some((t_s + DEAD_POINT_WINDOW_S, before));
    }

    /// A compression cycle ended.
    pub(super) fn cycle_done(&mut self) {
        self.cycles.push(std::mem::take(&mut self.current));
    }

    /// The figures of the run.
    pub(super) fn finish(self) -> Figures {
        let last = |v: &[f64]| -> Option<f64> {
            v.get(v.len().saturating_sub(2 * LAST_CYCLES)..)
                .and_then(|s| s.iter().copied().reduce(f64::max))
        };
        let cycles = self
            .cycles
            .get(self.cycles.len().saturating_sub(LAST_CYCLES)..)
            .unwrap_or(&[]);
        let span = |f: fn(&Extremes) -> (f64, f64)| -> Option<(f64, f64)> {
            cycles
                .iter()
                .map(f)
                .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)))
        };
        let ratio = |r: Option<(f64, f64)>| r.filter(|r| r.0 > 0.0).map(|r| r.1 / r.0);
        let mean2 = |a: Option<f64>, b: Option<f64>| Some(0.5 * (a? + b?));
        let dt = f64::from(CONTROL_PERIOD_S);
        let stroke: Vec<f64> = self.stroke_err.into_iter().collect();
        let rest: Vec<f64> = self.rest_err.into_iter().collect();
        // One spectrum of each record, searched in both bands.
        let stroke = Spectrum::of(&stroke, dt);
        let rest = Spectrum::of(&rest, dt);
        let line = stroke.as_ref().and_then(|s| s.line_in(LINE_BAND_HZ));
        let rest_line = rest.as_ref().and_then(|s| s.line_in(LINE_BAND_HZ));
        let wide = stroke.as_ref().and_then(|s| s.line_in(WIDE_BAND_HZ));
        let rest_wide = rest.as_ref().and_then(|s| s.line_in(WIDE_BAND_HZ));
        Figures {
            dead_point_force_diff_n: last(&self.dead_point_diffs),
            force_diff_rms_fraction: (self.total_sq > 0.0)
                .then(|| (self.diff_sq / self.total_sq).sqrt()),
            overshoot_m: last(&self.overshoots),
            travel_m: span(|e| e.x).map(|r| r.1 - r.0),
            volume_ratio_reached: mean2(ratio(span(|e| e.v_a)), ratio(span(|e| e.v_b))),
            pv_pressure_ratio: mean2(ratio(span(|e| e.p_a)), ratio(span(|e| e.p_b))),
            peak_motor_force_n: span(|e| e.force).map(|r| r.0.abs().max(r.1.abs())),
            line_hz: line.map(|l| l.hz),
            line_m: line.map(|l| l.amplitude),
            line_floor_m: line.map(|l| l.floor),
            rest_line_hz: rest_line.map(|l| l.hz),
            rest_line_m: rest_line.map(|l| l.amplitude),
            rest_line_floor_m: rest_line.map(|l| l.floor),
            wide_line_hz: wide.map(|l| l.hz),
            wide_line_m: wide.map(|l| l.amplitude),
            rest_wide_line_hz: rest_wide.map(|l| l.hz),
            rest_wide_line_m: rest_wide.map(|l| l.amplitude),
        }
    }
}

/// The figures [`PaperFigures`] gives (fields of the run's summary).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Figures {
    /// See [`super::Summary::dead_point_force_diff_n`].
    pub dead_point_force_diff_n: Option<f64>,
    /// See [`super::Summary::force_diff_rms_fraction`].
    pub force_diff_rms_fraction: Option<f64>,
    /// See [`super::Summary::overshoot_m`].
    pub overshoot_m: Option<f64>,
    /// See [`super::Summary::travel_m`].
    pub travel_m: Option<f64>,
    /// See [`super::Summary::volume_ratio_reached`].
    pub volume_ratio_reached: Option<f64>,
    /// See [`super::Summary::peak_motor_force_n`].
    pub peak_motor_force_n: Option<f64>,
    /// See [`super::Summary::pv_pressure_ratio`].
    pub pv_pressure_ratio: Option<f64>,
    /// See [`super::Summary::line_hz`].
    pub line_hz: Option<f64>,
    /// See [`super::Summary::line_m`].
    pub line_m: Option<f64>,
    /// See [`super::Summary::line_floor_m`].
    pub line_floor_m: Option<f64>,
    /// See [`super::Summary::rest_line_hz`].
    pub rest_line_hz: Option<f64>,
    /// See [`super::Summary::rest_line_m`].
    pub rest_line_m: Option<f64>,
    /// See [`super::Summary::rest_line_floor_m`].
    pub rest_line_floor_m: Option<f64>,
    /// See [`super::Summary::wide_line_hz`].
    pub wide_line_hz: Option<f64>,
    /// See [`super::Summary::wide_line_m`].
    pub wide_line_m: Option<f64>,
    /// See [`super::Summary::rest_wide_line_hz`].
    pub rest_wide_line_hz: Option<f64>,
    /// See [`super::Summary::rest_wide_line_m`].
    pub rest_wide_line_m: Option<f64>,
}

// The run summary's own figures (the work per cycle, the last clearances, the discharge
// opening's pressure error), computed as the run goes.

/// Largest of the last `n` values.
pub(super) fn last_max(values: &[f64], n: usize) -> Option<f64> {
    values
        .get(values.len().saturating_sub(n)..)
        .and_then(|v| v.iter().copied().reduce(f64::max))
}

/// Mean work per cycle over the last 5 cycles, from cumulative work at each cycle end, J.
pub(super) fn indicated_work(cumulative_j: &[f64]) -> Option<f64> {
    let n = cumulative_j.len();
    let k = 5.min(n.saturating_sub(1));
    if k == 0 {
        return None;
    }
    let last = cumulative_j.get(n - 1)?;
    let first = cumulative_j.get(n - 1 - k)?;
    Some((last - first) / k as f64)
}

/// Mean electrical energies per cycle over the last 5 cycles (the cycles of
/// [`indicated_work`]), from the plant's totals at each cycle end.
pub(super) fn electrical_per_cycle(
    at_cycle: &[crate::plant::bridge::ElectricalTotals],
) -> Option<crate::plant::bridge::ElectricalTotals> {
    let n = at_cycle.len();
    let k = 5.min(n.saturating_sub(1));
    if k == 0 {
        return None;
    }
    let last = at_cycle.get(n - 1)?;
    let first = at_cycle.get(n - 1 - k)?;
    Some(last.since(first).per(k as f64))
}

/// If a discharge port's half-open angle was crossed since `last_phase_rad` (forward
/// rotation: compressor), the relative pressure error of that chamber against the discharge
/// line at that instant: what a well-timed volume ratio makes zero.
pub(super) fn discharge_opening(
    plant: &crate::plant::dynamics::Plant,
    last_phase_rad: Option<f64>,
) -> Option<f64> {
    use fpc::physics::port_timing::Port;
    let last = last_phase_rad?;
    let now = plant.port_phase_rad();
    let ports = &plant.chambers.params.ports;
    let advance = fpc::angle::wrap_rad(now - last);
    // Reverse rotation (expander: the discharge port is the admission) or standstill: no
    // discharge opening to judge.
    if advance == 0.0 || advance >= std::f64::consts::PI {
        return None;
    }
    for (port, chamber) in [
        (Port::DischargeA, &plant.chambers.a),
        (Port::DischargeB, &plant.chambers.b),
    ] {
        let to_edge = fpc::angle::wrap_rad(ports.half_open_rad(port) - last);
        if to_edge > 0.0 && to_edge <= advance {
            let pd = plant.lines.discharge_pa;
            return Some((chamber.pressure_pa - pd).abs() / pd);
        }
    }
    None
}
