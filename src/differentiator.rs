//! Savitzky–Golay differentiator in fixed point: velocity and acceleration from position.
//!
//! A least-squares polynomial of order K is fitted to the last N positions (N odd, ≤ 41) and
//! differentiated at an evaluation point L samples back from the newest (L = 0: causal end
//! point, smallest delay; L = (N−1)/2: centred, as scipy's `savgol_filter`). Both derivatives
//! are linear in the samples, `d = Σ hⱼ·xⱼ`, with weights computed at init from the
//! least-squares definition (no pasted tables).
//!
//! Fixed point: positions are [`PositionCounts`]; each output is accumulated as
//! `Σ cⱼ·(xⱼ − x_newest)` in `i64`, with integer weights `cⱼ = round(hⱼ·2^S)`. Because
//! `Σ hⱼ = 0` for every derivative, subtracting the newest sample changes nothing in exact
//! arithmetic and removes the absolute position from the sum, so the range of the accumulator
//! depends only on how far the piston moves inside one window.
//!
//! Overflow proof (checked by `accumulator_bound_holds` below and by the constructor):
//! `|xⱼ − x_newest| < 2³¹` (i32 difference, computed in i64), `|cⱼ| < 2³¹` (asserted at init
//! by choosing S), N ≤ 41 < 2⁶ ⇒ `|Σ| < 2³¹·2³¹·2⁶ = 2⁶⁸`… which is too loose, so S is chosen
//! per window such that `max|cⱼ|·Σ|…|` fits: the constructor picks `S` so that
//! `Σⱼ|cⱼ| ≤ 2³¹`, hence `|Σ cⱼ·Δxⱼ| ≤ 2³¹·max|Δx| < 2³¹·2³¹ = 2⁶²` for any positions at all —
//! the accumulator cannot overflow for any input, in or out of the stroke.

use crate::encoder::PositionCounts;

/// Largest supported window.
pub const MAX_WINDOW: usize = 41;

/// Configuration of the differentiator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SgConfig {
    /// Window length N, odd, 3..=41.
    pub window: usize,
    /// Polynomial order K, 1..=4, K < N (acceleration needs K ≥ 2).
    pub order: usize,
    /// Evaluation point counted back from the newest sample, 0..=N−1.
    pub lag: usize,
    /// Sample time, s (> 0).
    pub sample_time_s: f32,
    /// Metres per position count.
    pub m_per_count: f32,
}

/// Why a configuration was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SgError {
    /// Window even, < 3 or > 41.
    Window,
    /// Order 0, > 4 or ≥ window.
    Order,
    /// Lag ≥ window.
    Lag,
    /// Sample time or scale not finite and positive.
    Scale,
}

/// Velocity and acceleration at the evaluation point.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Derivatives {
    /// Velocity, m/s.
    pub velocity_mps: f32,
    /// Acceleration, m/s² (0 when the order is 1).
    pub acceleration_mps2: f32,
}

/// The differentiator's state: configuration, integer weights and the sample history.
#[derive(Clone, Debug)]
pub struct SavitzkyGolay {
    window: usize,
    lag: usize,
    /// Integer weights for d/dt and d²/dt², oldest sample first.
    weights_v: [i32; MAX_WINDOW],
    weights_a: [i32; MAX_WINDOW],
    /// Output scale: counts·2^−S per sample^d → SI.
    scale_v: f32,
    scale_a: f32,
    /// History, oldest first once full (shifted; small N keeps this cheap enough — the
    /// optimised ring form is measured in the Cortex-M4 benchmark).
    history: [PositionCounts; MAX_WINDOW],
    filled: usize,
}

impl SavitzkyGolay {
    /// Builds the differentiator, computing the least-squares weights.
    pub fn new(cfg: SgConfig) -> Result<Self, SgError> {
        let n = cfg.window;
        if !(3..=MAX_WINDOW).contains(&n) || n.is_multiple_of(2) {
            return Err(SgError::Window);
        }
        if cfg.order == 0 || cfg.order > 4 || cfg.order >= n {
            return Err(SgError::Order);
        }
        if cfg.lag >= n {
            return Err(SgError::Lag);
        }
        if !(cfg.sample_time_s.is_finite()
            && cfg.sample_time_s > 0.0
            && cfg.m_per_count.is_finite()
            && cfg.m_per_count > 0.0)
        {
            return Err(SgError::Scale);
        }
        let mut hv = [0.0f64; MAX_WINDOW];
        let mut ha = [0.0f64; MAX_WINDOW];
        weights(n, cfg.order, cfg.lag, 1, &mut hv);
        if cfg.order >= 2 {
            weights(n, cfg.order, cfg.lag, 2, &mut ha);
        }
        let (weights_v, shift_v) = quantise(&hv[..n]);
        let (weights_a, shift_a) = quantise(&ha[..n]);
        let dt = f64::from(cfg.sample_time_s);
        let m = f64::from(cfg.m_per_count);
        Ok(SavitzkyGolay {
            window: n,
            lag: cfg.lag,
            weights_v,
            weights_a,
            scale_v: (m / dt / pow2(shift_v)) as f32,
            scale_a: (m / (dt * dt) / pow2(shift_a)) as f32,
            history: [0; MAX_WINDOW],
            filled: 0,
        })
    }

    /// Window length.
    pub fn window(&self) -> usize {
        self.window
    }

    /// Evaluation point, samples back from the newest.
    pub fn lag(&self) -> usize {
        self.lag
    }

    /// Forgets the history (e.g. after re-homing moved the zero).
    pub fn reset(&mut self) {
        self.filled = 0;
    }

    /// Adds the newest position and returns the derivatives at the evaluation point.
    /// Until the window is full the history is padded with the first sample (zero output).
    pub fn push(&mut self, x: PositionCounts) -> Derivatives {
        let n = self.window;
        if self.filled == 0 {
            self.history[..n].fill(x);
        }
        self.filled = (self.filled + 1).min(n);
        self.history.copy_within(1..n, 0);
        if let Some(slot) = self.history.get_mut(n - 1) {
            *slot = x;
        }
        let mut acc_v: i64 = 0;
        let mut acc_a: i64 = 0;
        for ((&xj, &cv), &ca) in self.history[..n]
            .iter()
            .zip(&self.weights_v[..n])
            .zip(&self.weights_a[..n])
        {
            let dx = i64::from(xj) - i64::from(x);
            acc_v += i64::from(cv) * dx;
            acc_a += i64::from(ca) * dx;
        }
        Derivatives {
            velocity_mps: acc_v as f32 * self.scale_v,
            acceleration_mps2: acc_a as f32 * self.scale_a,
        }
    }
}

fn pow2(s: u32) -> f64 {
    (1u64 << s) as f64
}

/// Quantises weights to integers with the largest S such that Σ|c| ≤ 2³¹ (see module doc).
fn quantise(h: &[f64]) -> ([i32; MAX_WINDOW], u32) {
    let l1: f64 = h.iter().map(|v| v.abs()).sum();
    let mut out = [0i32; MAX_WINDOW];
    if l1 == 0.0 {
        return (out, 0);
    }
    let mut shift = 0u32;
    // 2^31 − a margin of N for the rounding of each weight.
    while shift < 40 && l1 * pow2(shift + 1) <= 2_147_483_000.0 {
        shift += 1;
    }
    for (o, &v) in out.iter_mut().zip(h) {
        *o = libm::round(v * pow2(shift)) as i32;
    }
    (out, shift)
}

/// Least-squares weights of the `deriv`-th derivative (per sample^deriv) at the point `lag`
/// samples back from the newest, for window `n` and order `k`; oldest sample first.
fn weights(n: usize, k: usize, lag: usize, deriv: usize, out: &mut [f64; MAX_WINDOW]) {
    // Sample j (0 = oldest) sits at τ = j − (n − 1 − lag) relative to the evaluation point.
    let m = k + 1;
    let origin = (n - 1 - lag) as f64;
    // Gram matrix G = AᵀA with A[j][p] = τⱼ^p.
    let mut g = [[0.0f64; 5]; 5];
    for j in 0..n {
        let tau = j as f64 - origin;
        let mut pows = [1.0f64; 9];
        for p in 1..9 {
            pows[p] = pows[p - 1] * tau;
        }
        for (r, row) in g.iter_mut().enumerate().take(m) {
            for (c, cell) in row.iter_mut().enumerate().take(m) {
                *cell += pows[r + c];
            }
        }
    }
    // Solve G·y = e_deriv; the weights are hⱼ = deriv!·Σ_p y_p·τⱼ^p.
    let mut rhs = [0.0f64; 5];
    rhs[deriv] = 1.0;
    let y = solve(g, rhs, m);
    let fact = if deriv == 2 { 2.0 } else { 1.0 };
    for (j, o) in out.iter_mut().enumerate().take(n) {
        let tau = j as f64 - origin;
        let mut t = 1.0;
        let mut v = 0.0;
        for yp in y.iter().take(m) {
            v += yp * t;
            t *= tau;
        }
        *o = fact * v;
    }
}

/// Gaussian elimination with partial pivoting on the leading m×m block (G is SPD).
fn solve(mut a: [[f64; 5]; 5], mut b: [f64; 5], m: usize) -> [f64; 5] {
    for col in 0..m {
        let mut piv = col;
        for r in col + 1..m {
            if a[r][col].abs() > a[piv][col].abs() {
                piv = r;
            }
        }
        a.swap(col, piv);
        b.swap(col, piv);
        let d = a[col][col];
        if d == 0.0 {
            continue;
        }
        let pivot_row = a[col];
        let pivot_b = b[col];
        for (row, rb) in a.iter_mut().zip(b.iter_mut()).take(m).skip(col + 1) {
            let f = row[col] / d;
            for (x, p) in row.iter_mut().zip(pivot_row.iter()).take(m).skip(col) {
                *x -= f * p;
            }
            *rb -= f * pivot_b;
        }
    }
    let mut x = [0.0f64; 5];
    for r in (0..m).rev() {
        let mut s = b[r];
        for c in r + 1..m {
            s -= a[r][c] * x[c];
        }
        x[r] = if a[r][r] == 0.0 { 0.0 } else { s / a[r][r] };
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(window: usize, order: usize, lag: usize) -> SgConfig {
        SgConfig {
            window,
            order,
            lag,
            sample_time_s: 50e-6,
            m_per_count: 1e-6,
        }
    }

    #[test]
    fn exact_on_polynomials_of_its_order() {
        // x(t) = 0.1 + 2t − 30t² in µm counts; v = 2 − 60t, a = −60.
        let mut sg = SavitzkyGolay::new(cfg(21, 2, 0)).unwrap();
        let mut d = Derivatives::default();
        let mut t = 0.0;
        for i in 0..100 {
            t = i as f64 * 50e-6;
            let x = 0.1 + 2.0 * t - 30.0 * t * t;
            d = sg.push((x * 1e6).round() as i32);
        }
        assert!((f64::from(d.velocity_mps) - (2.0 - 60.0 * t)).abs() < 0.02);
        assert!((f64::from(d.acceleration_mps2) + 60.0).abs() < 3.0);
    }

    #[test]
    fn centred_weights_match_the_closed_form() {
        // Centred, order 2, first derivative: h_j = j / Σ j² (classic formula).
        let mut h = [0.0; MAX_WINDOW];
        weights(5, 2, 2, 1, &mut h);
        let expect = [-0.2, -0.1, 0.0, 0.1, 0.2];
        for (a, b) in h.iter().zip(expect) {
            assert!((a - b).abs() < 1e-12);
        }
    }

    #[test]
    fn accumulator_bound_holds() {
        for n in (3..=MAX_WINDOW).step_by(2) {
            for k in 1..=4.min(n - 1) {
                for lag in [0, (n - 1) / 2, n - 1] {
                    let sg = SavitzkyGolay::new(cfg(n, k, lag)).unwrap();
                    for w in [&sg.weights_v, &sg.weights_a] {
                        let l1: i64 = w.iter().map(|c| i64::from(*c).abs()).sum();
                        assert!(l1 <= 1 << 31, "n={n} k={k} lag={lag}");
                    }
                }
            }
        }
    }

    #[test]
    fn refuses_bad_configurations() {
        assert_eq!(
            SavitzkyGolay::new(cfg(4, 2, 0)).err(),
            Some(SgError::Window)
        );
        assert_eq!(
            SavitzkyGolay::new(cfg(43, 2, 0)).err(),
            Some(SgError::Window)
        );
        assert_eq!(SavitzkyGolay::new(cfg(5, 5, 0)).err(), Some(SgError::Order));
        assert_eq!(SavitzkyGolay::new(cfg(5, 2, 5)).err(), Some(SgError::Lag));
        let mut c = cfg(5, 2, 0);
        c.sample_time_s = f32::NAN;
        assert_eq!(SavitzkyGolay::new(c).err(), Some(SgError::Scale));
    }
}
