//! The numerical tools of the effect fits: linear least squares (nalgebra), a bracketing
//! 1-D minimiser for the nonlinear parameters (period, lag, velocity scale, UA, area), and
//! a damped Gauss–Newton step for the two leak coefficients.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// Least squares `y ≈ Σ θⱼ·colⱼ`: the coefficients and the residual sum of squares. `None`
/// when the columns are empty, of unequal length or singular, or when the design matrix,
/// the right-hand side or their products are not finite (values so large that their
/// squares overflow): the solvers are never handed a NaN or an infinity.
pub fn lstsq(cols: &[Vec<f64>], y: &[f64]) -> Option<(Vec<f64>, f64)> {
    let k = cols.len();
    let n = y.len();
    if k == 0 || n < k || cols.iter().any(|c| c.len() != n) {
        return None;
    }
    if !all_finite(y) || !cols.iter().all(|c| all_finite(c)) {
        return None;
    }
    let x = DMatrix::from_fn(n, k, |r, c| {
        cols.get(c).and_then(|v| v.get(r)).copied().unwrap_or(0.0)
    });
    let yv = DVector::from_column_slice(y);
    // Normal equations with Cholesky (k ≤ 7, well-scaled columns): fast for the grids; a
    // singular set falls back to the SVD.
    let xtx = x.transpose() * &x;
    let xty = x.transpose() * &yv;
    if !all_finite(xtx.as_slice()) || !all_finite(xty.as_slice()) {
        return None;
    }
    let theta = match xtx.clone().cholesky() {
        Some(ch) => ch.solve(&xty),
        None => xtx.svd(true, true).solve(&xty, 1e-12).ok()?,
    };
    if theta.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let fitted = &x * &theta;
    let rss: f64 = (yv - fitted).iter().map(|e| e * e).sum();
    rss.is_finite()
        .then(|| (theta.iter().copied().collect(), rss))
}

/// One standard deviation of each coefficient of a least-squares fit whose Jacobian columns
/// are `cols` (∂residual/∂θⱼ at the optimum) and whose residual sum of squares is `rss`
/// over samples worth `n_eff` independent ones: `√diag(s²·(JᵀJ)⁻¹)` with
/// `s² = rss / (n_eff − k)`. For white residuals (`n_eff = n`) this is the textbook
/// covariance; for a smoothed residual `rss / n_eff` is its per-sample variance inflated by
/// the `n / n_eff` samples each independent one is spread over, which is how much less the
/// fit knows than the raw count suggests. `None` when `JᵀJ` is singular or not finite, or
/// `n_eff ≤ k`.
pub fn standard_errors(cols: &[Vec<f64>], rss: f64, n_eff: f64) -> Option<Vec<f64>> {
    let k = cols.len();
    let n = cols.first().map_or(0, Vec::len);
    let enough = n_eff.is_finite() && n_eff > k as f64;
    if k == 0 || cols.iter().any(|c| c.len() != n || !all_finite(c)) || !enough {
        return None;
    }
    let jtj = DMatrix::from_fn(k, k, |a, b| dot(&cols[a], &cols[b]));
    if !all_finite(jtj.as_slice()) || !rss.is_finite() {
        return None;
    }
    let inv = jtj.cholesky()?.inverse();
    let s2 = rss / (n_eff - k as f64);
    let se: Vec<f64> = (0..k).map(|j| (s2 * inv[(j, j)]).sqrt()).collect();
    all_finite(&se).then_some(se)
}

/// Whether every value is finite.
pub fn all_finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Sum of squares.
pub fn sumsq(v: &[f64]) -> f64 {
    v.iter().map(|a| a * a).sum()
}

/// Pearson correlation of two equally long vectors (0 if either is constant).
pub fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    if n < 2 {
        return 0.0;
    }
    let ma = a.iter().take(n).sum::<f64>() / n as f64;
    let mb = b.iter().take(n).sum::<f64>() / n as f64;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b).take(n) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    if saa > 0.0 && sbb > 0.0 {
        sab / (saa * sbb).sqrt()
    } else {
        0.0
    }
}

/// Minimises `f` over `[lo, hi]`: a grid of `grid` points, then golden-section search in the
/// cells around the best point for `iters` steps. Returns (argmin, min). Points where `f` is
/// `None` count as +∞.
pub fn minimise_1d(
    lo: f64,
    hi: f64,
    grid: usize,
    iters: usize,
    mut f: impl FnMut(f64) -> Option<f64>,
) -> Option<(f64, f64)> {
    minimise_batched(lo, hi, grid, iters, |xs, _| {
        (xs.iter().map(|&x| f(x)).collect(), None)
    })
}

/// [`minimise_1d`] with the independent evaluations (the grid, the golden section's first
/// pair, the bracket ends) spread over the cores, and each golden-section step's point
/// evaluated beside the one before it ([`ahead`]); the same points are scanned in the same
/// order, so the result does not depend on the number of threads.
pub fn minimise_1d_par(
    lo: f64,
    hi: f64,
    grid: usize,
    iters: usize,
    f: impl Fn(f64) -> Option<f64> + Sync,
) -> Option<(f64, f64)> {
    minimise_batched(lo, hi, grid, iters, |xs, next| match (xs, next) {
        ([x], Some(next)) => {
            let (v, later) = ahead(&f, *x, next);
            (vec![v], later)
        }
        _ => (xs.par_iter().map(|&x| f(x)).collect(), None),
    })
}

/// `f` at `x`, and beside it `f` at the point `next` gives for the value at `x`: on another
/// core if one is free (then, not knowing that value yet, the point `next` gives for a value
/// below all others: the search goes on the way it went), and otherwise after `x`, with its
/// value. The second is `None` where `next` gives no point.
fn ahead(
    f: &(impl Fn(f64) -> Option<f64> + Sync),
    x: f64,
    next: &(dyn Fn(f64) -> Option<f64> + Sync),
) -> (Option<f64>, Option<(f64, Option<f64>)>) {
    use std::sync::atomic::{AtomicU64, Ordering};
    // The value at `x` once it is known (NaN bits until then; +∞ stands for `None`).
    let known = AtomicU64::new(f64::NAN.to_bits());
    rayon::join(
        || {
            let v = f(x);
            let seen = v.filter(|v| v.is_finite()).unwrap_or(f64::INFINITY);
            known.store(seen.to_bits(), Ordering::Release);
            v
        },
        || {
            let seen = f64::from_bits(known.load(Ordering::Acquire));
            let x2 = next(if seen.is_nan() {
                f64::NEG_INFINITY
            } else {
                seen
            })?;
            Some((x2, f(x2)))
        },
    )
}

/// The golden section's bracket `[a, b]` with its inner points `c < d` and their values.
#[derive(Clone, Copy)]
struct Golden {
    a: f64,
    b: f64,
    c: f64,
    d: f64,
    fc: f64,
    fd: f64,
}

impl Golden {
    /// The bracket narrowed away from the worse inner point, and its new inner point, whose
    /// value [`Golden::with`] sets (`true`: the new point is `c`).
    fn narrowed(self) -> (Golden, f64, bool) {
        let r = 0.5 * (5f64.sqrt() - 1.0);
        let mut g = self;
        if g.fc < g.fd {
            g.b = g.d;
            g.d = g.c;
            g.fd = g.fc;
            g.c = g.b - r * (g.b - g.a);
            (g, g.c, true)
        } else {
            g.a = g.c;
            g.c = g.d;
            g.fc = g.fd;
            g.d = g.a + r * (g.b - g.a);
            (g, g.d, false)
        }
    }

    /// The narrowed bracket with `v`, the value at its new point.
    fn with(mut self, new_is_c: bool, v: f64) -> Golden {
        if new_is_c {
            self.fc = v;
        } else {
            self.fd = v;
        }
        self
    }
}

/// What [`minimise_batched`] is handed to evaluate `f`: at the points `xs` (in their order),
/// and, for a single point, optionally a point ahead: `next` gives the point the search
/// needs after this one for the value there (`None`: none), and the evaluator may return it
/// with its value.
type Ahead<'a> = Option<&'a (dyn Fn(f64) -> Option<f64> + Sync)>;

/// The search of [`minimise_1d`], `batch` evaluating `f` at several points at once (in
/// their order), or at one point and one ahead of it.
fn minimise_batched(
    lo: f64,
    hi: f64,
    grid: usize,
    iters: usize,
    mut batch: impl FnMut(&[f64], Ahead<'_>) -> (Vec<Option<f64>>, Option<(f64, Option<f64>)>),
) -> Option<(f64, f64)> {
    let grid = grid.max(3);
    let step = (hi - lo) / (grid - 1) as f64;
    let finite = |v: Option<f64>| v.filter(|v| v.is_finite()).unwrap_or(f64::INFINITY);
    let mut evals = |xs: &[f64]| finite_at(&mut batch, xs);
    let points: Vec<f64> = (0..grid).map(|i| lo + step * i as f64).collect();
    let (mut best_i, mut best) = (0usize, f64::INFINITY);
    for (i, v) in evals(&points).into_iter().enumerate() {
        if v < best {
            best = v;
            best_i = i;
        }
    }
    if !best.is_finite() {
        return None;
    }
    let a = lo + step * best_i.saturating_sub(1) as f64;
    let b = (lo + step * (best_i + 1) as f64).min(hi);
    let mut best_x = lo + step * best_i as f64;
    let r = 0.5 * (5f64.sqrt() - 1.0);
    let c = b - r * (b - a);
    let d = a + r * (b - a);
    let (fc, fd) = pair(&mut evals, c, d);
    let mut g = Golden { a, b, c, d, fc, fd };
    // A point evaluated ahead, with its value: used if it is the one the step needs.
    let mut known: Option<(f64, f64)> = None;
    for k in 0..iters {
        let (narrowed, x, new_is_c) = g.narrowed();
        let v = match known.take() {
            Some((kx, kv)) if kx.to_bits() == x.to_bits() => kv,
            _ => {
                let next =
                    |v: f64| (k + 1 < iters).then(|| narrowed.with(new_is_c, v).narrowed().1);
                let (v, later) = batch(&[x], Some(&next));
                known = later.map(|(x2, v2)| (x2, finite(v2)));
                finite(v.into_iter().next().flatten())
            }
        };
        g = narrowed.with(new_is_c, v);
    }
    let Golden { a, b, c, d, fc, fd } = g;
    let mut evals = |xs: &[f64]| finite_at(&mut batch, xs);
    for (x, v) in [(c, fc), (d, fd)] {
        if v < best {
            best = v;
            best_x = x;
        }
    }
    // One parabolic step through the two inner points and the better bracket end: golden
    // section narrows slowly, a smooth minimum is nearly a parabola.
    let (fa, fb) = pair(&mut evals, a, b);
    let (x0, f0, x1, f1, x2, f2) = if fc < fd {
        (a, fa, c, fc, d, fd)
    } else {
        (c, fc, d, fd, b, fb)
    };
    let den = (x1 - x0) * (f1 - f2) - (x1 - x2) * (f1 - f0);
    if den.abs() > 0.0 {
        let num = (x1 - x0).powi(2) * (f1 - f2) - (x1 - x2).powi(2) * (f1 - f0);
        let xv = x1 - 0.5 * num / den;
        if xv.is_finite() && xv > x0.min(x2) && xv < x0.max(x2) {
            let fv = one(&mut evals, xv);
            if fv < best {
                best = fv;
                best_x = xv;
            }
        }
    }
    Some((best_x, best))
}

/// `batch` at the points `xs`, each value finite or +∞.
fn finite_at(
    batch: &mut impl FnMut(&[f64], Ahead<'_>) -> (Vec<Option<f64>>, Option<(f64, Option<f64>)>),
    xs: &[f64],
) -> Vec<f64> {
    let mut out: Vec<f64> = batch(xs, None)
        .0
        .into_iter()
        .map(|v| v.filter(|v| v.is_finite()).unwrap_or(f64::INFINITY))
        .collect();
    out.resize(xs.len(), f64::INFINITY);
    out
}

/// `evals` at one point.
fn one(evals: &mut impl FnMut(&[f64]) -> Vec<f64>, x: f64) -> f64 {
    evals(&[x]).first().copied().unwrap_or(f64::INFINITY)
}

/// `evals` at two points, together.
fn pair(evals: &mut impl FnMut(&[f64]) -> Vec<f64>, a: f64, b: f64) -> (f64, f64) {
    let v = evals(&[a, b]);
    let at = |i: usize| v.get(i).copied().unwrap_or(f64::INFINITY);
    (at(0), at(1))
}

/// Relative decrease of the cost below which [`gauss_newton_nonneg`] stops: the parameters
/// are then within `√(GN_TOLERANCE·n)` standard errors of the optimum for a residual of `n`
/// independent samples (0.003 at 10⁴), and a further iteration would cost an evaluation per
/// parameter and up to six trial steps, each a replay of the chambers for the pressure
/// effects, to move them by less.
pub const GN_TOLERANCE: f64 = 1e-9;

/// Damped Gauss–Newton on non-negative parameters `u` minimising ‖r(u)‖², with forward
/// differences of step `steps[j]`, for at most `iters` iterations. It ends early once a
/// step lowers the cost by less than [`GN_TOLERANCE`] of it, or once the linearised
/// residual promises no more than that of the next step (which is then not tried). A
/// parameter at zero whose cost rises as it grows is held there, and one the step would
/// take below zero is moved to zero ([`bounded_step`]); the step is solved for the others
/// with them there. (A step solved for all and then cut at zero moves the others by what
/// the cut one could not do: it is refused, and the damped steps after it crawl along the
/// bound.) `r` returns the residual vector (`None`: invalid point).
pub fn gauss_newton_nonneg(
    mut u: Vec<f64>,
    steps: &[f64],
    iters: usize,
    r: impl Fn(&[f64]) -> Option<Vec<f64>> + Sync,
) -> Option<(Vec<f64>, f64)> {
    let mut res = r(&u).filter(|v| all_finite(v))?;
    let mut cost = sumsq(&res);
    if !cost.is_finite() {
        return None;
    }
    let mut damping = 1e-3;
    for _ in 0..iters {
        // The finite differences are independent evaluations: on every core, in order.
        let cols: Vec<Vec<f64>> = steps
            .par_iter()
            .enumerate()
            .map(|(j, h)| {
                let mut up = u.clone();
                if let Some(v) = up.get_mut(j) {
                    *v += h;
                }
                let rp = r(&up)?;
                Some(
                    rp.iter()
                        .zip(&res)
                        .map(|(a, b)| (a - b) / h)
                        .collect::<Vec<f64>>(),
                )
            })
            .collect::<Option<Vec<Vec<f64>>>>()?;
        // The parameters the step moves: all but those held at zero.
        let free: Vec<(usize, &Vec<f64>)> = cols
            .iter()
            .enumerate()
            .filter(|(j, c)| u.get(*j).is_some_and(|v| *v > 0.0) || dot(c, &res) < 0.0)
            .collect();
        let k = free.len();
        if k == 0 {
            break;
        }
        let jtj = DMatrix::from_fn(k, k, |a, b| dot(free[a].1, free[b].1));
        let jtr = DVector::from_fn(k, |a, _| dot(free[a].1, &res));
        if !all_finite(jtj.as_slice()) || !all_finite(jtr.as_slice()) {
            break;
        }
        let at: Vec<f64> = free
            .iter()
            .map(|(j, _)| u.get(*j).copied().unwrap_or(0.0))
            .collect();
        // The damped tries, damping ×10 after each that gives no step or a refused one:
        // their trial points, in order, up to one whose promised decrease is below the
        // tolerance (then converged, if every trial before it is refused).
        let mut trials: Vec<(f64, Vec<f64>)> = Vec::new();
        for _ in 0..MAX_TRIES {
            if let Some(delta) = bounded_step(&jtj, &jtr, &at, damping) {
                // ‖r‖² − ‖r + J·δ‖²: the decrease the linearised residual promises.
                let promised = -(2.0 * delta.dot(&jtr) + delta.dot(&(&jtj * &delta)));
                if promised.is_nan() || promised < GN_TOLERANCE * cost {
                    break;
                }
                let mut trial = u.clone();
                for ((j, _), d) in free.iter().zip(delta.iter()) {
                    if let Some(v) = trial.get_mut(*j) {
                        *v = (*v + d).max(0.0);
                    }
                }
                trials.push((damping, trial));
            }
            damping *= 10.0;
        }
        let Some((tried, trial, rt, ct)) = first_accepted(&trials, cost, &r) else {
            break;
        };
        let converged = cost - ct < GN_TOLERANCE * cost;
        u = trial;
        res = rt;
        cost = ct;
        damping = (tried * 0.3).max(1e-6);
        if converged {
            break;
        }
    }
    Some((u, cost))
}

/// Most damped tries per Gauss–Newton iteration.
const MAX_TRIES: usize = 6;

/// The first of `trials` (damping, point), in order, whose residual `r` lowers the cost
/// below `cost`: with that damping, the point, its residual and cost. Two trials are
/// evaluated at a time: the second on another core if one is free, and otherwise after the
/// first, only if the first is refused; the result is the one the trials give one by one.
fn first_accepted(
    trials: &[(f64, Vec<f64>)],
    cost: f64,
    r: &(impl Fn(&[f64]) -> Option<Vec<f64>> + Sync),
) -> Option<(f64, Vec<f64>, Vec<f64>, f64)> {
    let accept = |point: &[f64]| -> Option<(Vec<f64>, f64)> {
        let rt = r(point)?;
        let ct = sumsq(&rt);
        (ct.is_finite() && ct < cost).then_some((rt, ct))
    };
    for pair in trials.chunks(2) {
        let first_kept = std::sync::atomic::AtomicBool::new(false);
        let (first, second) = rayon::join(
            || {
                let got = pair.first().and_then(|(_, p)| accept(p));
                first_kept.store(got.is_some(), std::sync::atomic::Ordering::Release);
                got
            },
            || {
                let kept = first_kept.load(std::sync::atomic::Ordering::Acquire);
                pair.get(1).filter(|_| !kept).and_then(|(_, p)| accept(p))
            },
        );
        for (got, (tried, point)) in [first, second].into_iter().zip(pair) {
            if let Some((rt, ct)) = got {
                return Some((*tried, point.clone(), rt, ct));
            }
        }
    }
    None
}

/// The damped Gauss–Newton step `δ` of parameters at `at` whose columns give `jtj` and
/// `jtr`, kept within `at + δ ≥ 0`: a parameter the step would take below zero is moved to
/// zero and the others solved again with it there (each pass holds at least one more, so
/// there are at most as many passes as parameters). `None` if a system is singular.
fn bounded_step(
    jtj: &DMatrix<f64>,
    jtr: &DVector<f64>,
    at: &[f64],
    damping: f64,
) -> Option<DVector<f64>> {
    let k = at.len();
    let mut delta = DVector::zeros(k);
    let mut held = vec![false; k];
    for _ in 0..k {
        let moved: Vec<usize> = (0..k).filter(|i| !held[*i]).collect();
        let n = moved.len();
        if n == 0 {
            break;
        }
        let m = DMatrix::from_fn(n, n, |a, b| {
            let d = if a == b { 1.0 + damping } else { 1.0 };
            jtj[(moved[a], moved[b])] * d
        });
        let rhs = DVector::from_fn(n, |a, _| {
            let pulled: f64 = (0..k)
                .filter(|h| held[*h])
                .map(|h| jtj[(moved[a], h)] * delta[h])
                .sum();
            -(jtr[moved[a]] + pulled)
        });
        let sol = m.lu().solve(&rhs)?;
        let mut crossed = false;
        for (i, d) in moved.iter().zip(sol.iter()) {
            delta[*i] = *d;
            if at[*i] + d < 0.0 {
                held[*i] = true;
                delta[*i] = -at[*i];
                crossed = true;
            }
        }
        if !crossed {
            break;
        }
    }
    Some(delta)
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_parallel_minimiser_evaluates_the_same_points_in_the_same_order() {
        // A bumpy function with several cells of near-equal depth and holes (`None`): the
        // parallel search must land on exactly the same point, bit for bit, on any number
        // of threads.
        let f = |x: f64| {
            if (x * 7.0).fract() < 0.1 {
                None
            } else {
                Some((3.0 * x).sin() * (x - 4.2).powi(2) + 0.1 * (17.0 * x).cos())
            }
        };
        let serial = minimise_1d(0.0, 10.0, 37, 20, f).unwrap();
        let parallel = minimise_1d_par(0.0, 10.0, 37, 20, f).unwrap();
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| minimise_1d_par(0.0, 10.0, 37, 20, f).unwrap());
        assert_eq!(serial.0.to_bits(), parallel.0.to_bits());
        assert_eq!(serial.1.to_bits(), parallel.1.to_bits());
        assert_eq!(serial.0.to_bits(), one.0.to_bits());
        // A function that is nowhere defined has no minimum on either path.
        assert!(minimise_1d_par(0.0, 1.0, 5, 4, |_| None).is_none());
    }

    #[test]
    fn least_squares_recovers_a_line_and_the_minimiser_a_parabola() {
        let x: Vec<f64> = (0..50).map(f64::from).collect();
        let y: Vec<f64> = x.iter().map(|v| 2.0 + 0.5 * v).collect();
        let (th, rss) = lstsq(&[vec![1.0; 50], x.clone()], &y).unwrap();
        assert!((th[0] - 2.0).abs() < 1e-9 && (th[1] - 0.5).abs() < 1e-9 && rss < 1e-12);
        let (xm, _) = minimise_1d(0.0, 10.0, 11, 40, |x| Some((x - 3.3).powi(2))).unwrap();
        assert!((xm - 3.3).abs() < 1e-6);
        assert!((correlation(&x, &y) - 1.0).abs() < 1e-12);
        let (u, _) = gauss_newton_nonneg(vec![0.0], &[0.1], 20, |u| {
            Some(
                x.iter()
                    .map(|v| (1.0 + u[0] * 2.5).ln() * v - 1.2f64.ln() * v)
                    .collect(),
            )
        })
        .unwrap();
        assert!((u[0] - 0.08).abs() < 1e-6, "{u:?}");
    }

    /// `f` on a pool of one thread: the evaluations a search makes one by one, without
    /// those a free core makes ahead ([`first_accepted`]).
    fn on_one_thread<T: Send>(f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(f)
    }

    #[test]
    fn the_first_trial_that_lowers_the_cost_is_taken_in_order() {
        // Costs 9, 2.25, 1, 0.25 against 4: the second is the first below, whether the
        // trials are evaluated on one core (then exactly two are) or ahead on another.
        let trials: Vec<(f64, Vec<f64>)> = [3.0f64, 1.5, 1.0, 0.5]
            .iter()
            .enumerate()
            .map(|(i, c)| (10f64.powi(i as i32), vec![*c]))
            .collect();
        let calls = std::sync::atomic::AtomicUsize::new(0);
        let r = |u: &[f64]| {
            calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            Some(vec![u[0]])
        };
        let (damping, point, _, cost) = on_one_thread(|| first_accepted(&trials, 4.0, &r)).unwrap();
        assert_eq!((damping, point, cost), (10.0, vec![1.5], 2.25));
        assert_eq!(calls.load(std::sync::atomic::Ordering::Relaxed), 2);
        // The first taken: on one core its pair's second is not evaluated.
        calls.store(0, std::sync::atomic::Ordering::Relaxed);
        let got = on_one_thread(|| first_accepted(trials.get(1..).unwrap(), 4.0, &r));
        assert_eq!(got.map(|g| g.0), Some(10.0));
        assert_eq!(calls.load(std::sync::atomic::Ordering::Relaxed), 1);
        let (damping, _, _, cost) = first_accepted(&trials, 4.0, &r).unwrap();
        assert_eq!((damping, cost), (10.0, 2.25));
        // None below: none taken.
        assert!(first_accepted(&trials, 0.2, &r).is_none());
    }

    #[test]
    fn gauss_newton_stops_once_a_step_gains_less_than_its_tolerance() {
        // A straight line with noise left at its optimum. The damped first step lands within
        // 1e-3 of it and the steps after gain ever less: the fourth gains less than the
        // tolerance, and the search stops there instead of spending its 20 iterations (the
        // last ending in six refused trials) on digits no fit resolves.
        let x: Vec<f64> = (0..200).map(|i| f64::from(i) / 200.0).collect();
        let noise = |i: usize| if i.is_multiple_of(3) { 0.01 } else { -0.005 };
        let y: Vec<f64> = x
            .iter()
            .enumerate()
            .map(|(i, v)| 2.0 * v + 0.5 + noise(i))
            .collect();
        let calls = std::sync::atomic::AtomicUsize::new(0);
        let r = |u: &[f64]| {
            calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            Some(
                x.iter()
                    .zip(&y)
                    .map(|(v, y)| u[0] * v + u[1] - y)
                    .collect::<Vec<f64>>(),
            )
        };
        let (u, cost) =
            on_one_thread(|| gauss_newton_nonneg(vec![1.0, 1.0], &[1e-3, 1e-3], 20, r)).unwrap();
        // The start, then per iteration a difference per parameter and one accepted trial:
        // four iterations.
        let n = calls.load(std::sync::atomic::Ordering::Relaxed);
        assert!(n <= 1 + 4 * 3, "{n} evaluations");
        let (best, rss) = lstsq(&[x.clone(), vec![1.0; 200]], &y).unwrap();
        assert!(cost <= rss * (1.0 + GN_TOLERANCE), "{cost} against {rss}");
        assert!(
            (u[0] - best[0]).abs() < 1e-4 && (u[1] - best[1]).abs() < 1e-4,
            "{u:?}"
        );
    }

    #[test]
    fn gauss_newton_holds_a_parameter_at_its_bound_and_solves_for_the_other() {
        // Two nearly parallel columns, the second's unconstrained optimum negative: the
        // optimum over u ≥ 0 holds it at zero and fits the first alone. A step solved for both
        // and cut at zero moves the first by what the second could not do, is refused, and
        // the damped steps that follow crawl along the bound.
        let x: Vec<f64> = (0..100).map(|i| f64::from(i) / 50.0).collect();
        let a: Vec<f64> = x.iter().map(|v| 1.0 + v).collect();
        let b: Vec<f64> = x.iter().map(|v| 1.0 + 0.8 * v).collect();
        let y: Vec<f64> = a.iter().zip(&b).map(|(a, b)| 2.0 * a - 0.5 * b).collect();
        let calls = std::sync::atomic::AtomicUsize::new(0);
        let r = |u: &[f64]| {
            calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            Some(
                (0..y.len())
                    .map(|i| u[0] * a[i] + u[1] * b[i] - y[i])
                    .collect::<Vec<f64>>(),
            )
        };
        let (u, cost) =
            on_one_thread(|| gauss_newton_nonneg(vec![1.0, 1.0], &[1e-3, 1e-3], 20, r)).unwrap();
        let (best, rss) = lstsq(std::slice::from_ref(&a), &y).unwrap();
        assert_eq!(u[1], 0.0, "{u:?}");
        assert!(
            (u[0] - best[0]).abs() < 1e-6 * best[0],
            "{u:?} against {best:?}"
        );
        assert!(cost <= rss * (1.0 + GN_TOLERANCE), "{cost} against {rss}");
        let n = calls.load(std::sync::atomic::Ordering::Relaxed);
        assert!(n <= 1 + 4 * 3, "{n} evaluations");
    }

    #[test]
    fn standard_errors_match_the_textbook_line_fit() {
        // y = a + b·x + e, e = ±1 alternating: s² = rss/(n−2), and the slope's variance is
        // s² / Σ(x − x̄)², the intercept's s²·Σx² / (n·Σ(x − x̄)²).
        let n = 40;
        let x: Vec<f64> = (0..n).map(f64::from).collect();
        let e: Vec<f64> = (0..n)
            .map(|i| if i % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        let y: Vec<f64> = x.iter().zip(&e).map(|(x, e)| 3.0 + 0.2 * x + e).collect();
        let cols = [vec![1.0; n as usize], x.clone()];
        let (_, rss) = lstsq(&cols, &y).unwrap();
        let se = standard_errors(&cols, rss, f64::from(n)).unwrap();
        let mean = x.iter().sum::<f64>() / f64::from(n);
        let sxx: f64 = x.iter().map(|x| (x - mean).powi(2)).sum();
        let s2 = rss / f64::from(n - 2);
        assert!((se[1] - (s2 / sxx).sqrt()).abs() < 1e-12 * se[1], "{se:?}");
        let sx2: f64 = x.iter().map(|x| x * x).sum();
        assert!((se[0] - (s2 * sx2 / (f64::from(n) * sxx)).sqrt()).abs() < 1e-12 * se[0]);
        // Fewer independent samples, wider: a quarter of them doubles the error.
        let se4 = standard_errors(&cols, rss, f64::from(n - 2) / 4.0 + 2.0).unwrap();
        assert!((se4[1] / se[1] - 2.0).abs() < 1e-9, "{se4:?}");
        // A column that moves nothing has no error to give.
        assert!(standard_errors(&[vec![0.0; 40]], rss, 40.0).is_none());
    }
}
