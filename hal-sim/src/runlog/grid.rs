//! A run log's time onto its nominal grid: what rigs' loggers write is seldom exactly
//! uniform. A logger's sample instants jitter by microseconds, and a busy one drops a row
//! now and then; the analyses need one sample every step. The reader therefore finds the
//! log's nominal step (the median step, refined over the whole log), places every row on
//! the grid, and — when some row is off it by more than [`EXACT_JITTER`] of a step, or
//! rows are missing — interpolates every column onto the grid, filling the dropped rows,
//! and says how many it filled and how far the rows were off.
//!
//! Refused, naming the row and its step against the log's: a row off the grid by more
//! than [`MAX_JITTER`] of a step (two rows on one step), more than [`MAX_MISSING_IN_A_ROW`]
//! rows missing in a row (a gap no interpolation bridges faithfully), more than
//! [`MAX_MISSING_SHARE`] of the rows missing in all.

/// Most a row's time may sit off the nominal grid, as a share of the step.
pub const MAX_JITTER: f64 = 0.25;
/// Below this share of a step off the grid and with no row missing, a log is uniform as it
/// is and is read unchanged.
pub const EXACT_JITTER: f64 = 0.01;
/// Most rows missing one after the other that the reader fills.
pub const MAX_MISSING_IN_A_ROW: u64 = 3;
/// Most rows missing in all, as a share of the rows read.
pub const MAX_MISSING_SHARE: f64 = 0.01;

/// What the reader did to a log's time column.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Resampled {
    /// The nominal step, s.
    pub step_s: f64,
    /// Data rows read.
    pub rows_read: usize,
    /// Rows missing, filled by interpolation.
    pub filled: u64,
    /// Rows off the grid by more than [`EXACT_JITTER`] of a step.
    pub off_grid: usize,
    /// The largest distance of a row from the grid, s.
    pub max_jitter_s: f64,
}

impl std::fmt::Display for Resampled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "resampled onto its nominal step of {}: {} of {} rows filled where the logger \
             dropped them, {} rows off the grid by up to {} ({:.1} % of a step)",
            crate::console::eng(self.step_s, "s"),
            self.filled,
            self.rows_read as u64 + self.filled,
            self.off_grid,
            crate::console::eng(self.max_jitter_s, "s"),
            100.0 * self.max_jitter_s / self.step_s
        )
    }
}

/// The grid the rows lie on: its start and step, and each row's place on it.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    /// Time of grid point 0, s.
    pub t0_s: f64,
    /// The step, s.
    pub step_s: f64,
    /// Each row's grid point.
    pub points: Vec<u64>,
    /// What was found.
    pub report: Resampled,
}

/// Why the rows cannot be placed on a grid: the data row (0-based) and what is wrong.
pub type GridError = (usize, String);

/// The grid of the (strictly increasing) times `t`; `None` when they are uniform as they
/// are (within [`EXACT_JITTER`], nothing missing).
pub fn place(t: &[f64]) -> Result<Option<Grid>, GridError> {
    if t.len() < 3 {
        return Ok(None);
    }
    let mut steps: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    let mid = steps.len() / 2;
    let (_, &mut median, _) = steps.select_nth_unstable_by(mid, f64::total_cmp);
    // Each row's place from the step before it (a dropped row is a double step), then the
    // grid that fits those places best (least squares): a logger whose clock runs a little
    // off its nominal rate keeps its own step, and the jitter averages out.
    let mut places = Vec::with_capacity(t.len());
    let mut place = 0u64;
    for (i, &ti) in t.iter().enumerate() {
        if let Some(&prev) = i.checked_sub(1).and_then(|j| t.get(j)) {
            place += (((ti - prev) / median).round() as u64).max(1);
        }
        places.push(place);
    }
    let n = t.len() as f64;
    let p_mean = places.iter().map(|&p| p as f64).sum::<f64>() / n;
    let t_mean = t.iter().sum::<f64>() / n;
    let (mut spp, mut spt) = (0.0, 0.0);
    for (&p, &ti) in places.iter().zip(t) {
        let dp = p as f64 - p_mean;
        spp += dp * dp;
        spt += dp * (ti - t_mean);
    }
    let step = if spp > 0.0 { spt / spp } else { median };
    let t0 = t_mean - step * p_mean;
    let off = |ti: f64| -> (u64, f64) {
        let p = ((ti - t0) / step).round().max(0.0);
        (p as u64, ti - (t0 + p * step))
    };
    let mut points = Vec::with_capacity(t.len());
    let (mut filled, mut off_grid, mut max_jitter) = (0u64, 0usize, 0.0f64);
    let mut prev: Option<(u64, f64)> = None;
    let refuse = |i: usize, prev_t: f64, ti: f64, why: String| -> GridError {
        (
            i,
            format!(
                "the step from the previous row is {} where the log's step is {} ({:.2} \
                 steps): {why} (the reader takes rows up to ±{:.0} % of a step off the grid \
                 and fills up to {MAX_MISSING_IN_A_ROW} dropped rows in a row)",
                crate::console::eng(ti - prev_t, "s"),
                crate::console::eng(step, "s"),
                (ti - prev_t) / step,
                100.0 * MAX_JITTER
            ),
        )
    };
    for (i, &ti) in t.iter().enumerate() {
        let (p, e) = off(ti.max(t0));
        let e = if ti < t0 { ti - t0 } else { e };
        if let Some((pp, pt)) = prev {
            if e.abs() > MAX_JITTER * step {
                return Err(refuse(
                    i,
                    pt,
                    ti,
                    format!(
                        "this row is {} off the grid",
                        crate::console::eng(e.abs(), "s")
                    ),
                ));
            }
            if p <= pp {
                return Err(refuse(i, pt, ti, "two rows fall on one step".into()));
            }
            let missing = p - pp - 1;
            if missing > MAX_MISSING_IN_A_ROW {
                return Err(refuse(
                    i,
                    pt,
                    ti,
                    format!("{missing} rows are missing here"),
                ));
            }
            filled += missing;
        }
        if e.abs() > EXACT_JITTER * step {
            off_grid += 1;
        }
        max_jitter = max_jitter.max(e.abs());
        points.push(p);
        prev = Some((p, ti));
    }
    if filled as f64 > MAX_MISSING_SHARE * t.len() as f64 {
        return Err((
            0,
            format!(
                "{filled} rows of {} are missing where the log's step is {} (more than the \
                 {:.0} % the reader fills)",
                t.len() as u64 + filled,
                crate::console::eng(step, "s"),
                100.0 * MAX_MISSING_SHARE
            ),
        ));
    }
    if filled == 0 && off_grid == 0 {
        return Ok(None);
    }
    Ok(Some(Grid {
        t0_s: t0,
        step_s: step,
        points,
        report: Resampled {
            step_s: step,
            rows_read: t.len(),
            filled,
            off_grid,
            max_jitter_s: max_jitter,
        },
    }))
}

/// Whether `column`'s values lie on a lattice: every change from one row to the next a
/// whole multiple (within 1 %) of the smallest change — a count or a code times its
/// resolution. A constant column is one too.
pub fn lattice(column: &[f64]) -> bool {
    let quantum = column
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    if !quantum.is_finite() {
        return true;
    }
    column.windows(2).all(|w| {
        let k = (w[1] - w[0]) / quantum;
        (k - k.round()).abs() <= 0.01
    })
}

impl Grid {
    /// `column`, sampled at the rows' times `t`, on the grid: linear between the rows
    /// around each grid point, or — for a column whose values lie on a lattice ([`lattice`]:
    /// counts and codes, a servo count's angle, an ADC's pressure, `fault`, `mode`) — the
    /// value of the row nearest in time, never one between two codes.
    pub fn resample(&self, t: &[f64], column: &[f64]) -> Vec<f64> {
        let codes = lattice(column);
        let n = self.points.last().map_or(0, |p| p + 1);
        let mut out = Vec::with_capacity(n as usize);
        let mut i = 0;
        for k in 0..n {
            let g = self.t0_s + k as f64 * self.step_s;
            while i + 1 < t.len() && t.get(i + 1).is_some_and(|&next| next <= g) {
                i += 1;
            }
            let (t_a, v_a) = (t.get(i).copied(), column.get(i).copied());
            let (t_b, v_b) = (t.get(i + 1).copied(), column.get(i + 1).copied());
            let v = match (t_a, v_a, t_b, v_b) {
                (Some(ta), Some(va), Some(tb), Some(vb)) if g > ta && tb > ta => {
                    if !codes {
                        va + (vb - va) * ((g - ta) / (tb - ta)).min(1.0)
                    } else if tb - g < g - ta {
                        vb
                    } else {
                        va
                    }
                }
                (_, Some(va), _, _) => va,
                _ => f64::NAN,
            };
            out.push(v);
        }
        out
    }

    /// The grid's times.
    pub fn times(&self) -> Vec<f64> {
        let n = self.points.last().map_or(0, |p| p + 1);
        (0..n).map(|k| self.t0_s + k as f64 * self.step_s).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn jittered(n: usize, step: f64, jitter: f64, drop: &[usize], seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .filter(|i| !drop.contains(i))
            .map(|i| 1.0 + i as f64 * step + rng.random_range(-jitter..=jitter))
            .collect()
    }

    #[test]
    fn a_uniform_log_is_left_as_it_is() {
        let t: Vec<f64> = (0..1000).map(|i| i as f64 * 1e-4).collect();
        assert_eq!(place(&t).unwrap(), None);
    }

    #[test]
    fn jitter_and_dropped_rows_are_placed_and_counted() {
        let t = jittered(10_000, 1e-4, 2e-6, &[500, 501, 7000], 3);
        let g = place(&t).unwrap().unwrap();
        assert!((g.step_s - 1e-4).abs() < 1e-9, "{}", g.step_s);
        assert_eq!(g.report.filled, 3);
        assert!(g.report.max_jitter_s <= 2.2e-6 && g.report.max_jitter_s > 1.5e-6);
        assert_eq!(g.points.last(), Some(&9999));
        // A straight line comes back exactly on the grid, the dropped rows filled.
        let v: Vec<f64> = t.iter().map(|ti| 3.0 * ti - 1.0).collect();
        let r = g.resample(&t, &v);
        assert_eq!(r.len(), 10_000);
        for (k, (gt, rv)) in g.times().iter().zip(&r).enumerate().skip(1).take(9997) {
            assert!((rv - (3.0 * gt - 1.0)).abs() < 1e-9, "grid point {k}");
        }
    }

    #[test]
    fn counts_and_codes_are_lattices_measured_signals_are_not() {
        let count: Vec<f64> = (0..500)
            .map(|i| f64::from(i / 7) * 1.533_980_787_885_641e-3)
            .collect();
        assert!(lattice(&count));
        assert!(lattice(&[0.0, 0.0, 3.0, 6.0, 3.0]));
        assert!(lattice(&[4.0; 10]));
        let signal: Vec<f64> = (0..500).map(|i| (f64::from(i) * 0.01).sin()).collect();
        assert!(!lattice(&signal));
    }

    #[test]
    fn codes_are_held_not_interpolated() {
        let t = jittered(200, 1e-3, 1e-4, &[100], 5);
        let codes: Vec<f64> = (0..t.len())
            .map(|i| if i < 100 { 0.0 } else { 6.0 })
            .collect();
        let g = place(&t).unwrap().unwrap();
        assert!(g
            .resample(&t, &codes)
            .iter()
            .all(|v| *v == 0.0 || *v == 6.0));
    }

    #[test]
    fn past_the_limits_the_refusal_names_the_row_and_both_steps() {
        let t = jittered(1000, 1e-4, 0.0, &[300, 301, 302, 303], 1);
        let (row, why) = place(&t).unwrap_err();
        assert_eq!(row, 300);
        assert!(
            why.contains("500 µs where the log's step is 100 µs"),
            "{why}"
        );
        assert!(why.contains("4 rows are missing"), "{why}");
        let mut t: Vec<f64> = (0..1000).map(|i| i as f64 * 1e-4).collect();
        t[400] += 0.4e-4;
        let (row, why) = place(&t).unwrap_err();
        assert_eq!(row, 400);
        assert!(why.contains("off the grid"), "{why}");
        let drops: Vec<usize> = (0..30).map(|k| 10 + 30 * k).collect();
        let t = jittered(1000, 1e-4, 0.0, &drops, 1);
        let (row, why) = place(&t).unwrap_err();
        assert_eq!(row, 0);
        assert!(why.contains("30 rows of 1000 are missing"), "{why}");
    }
}
