//! Savitzky–Golay differentiator in exact integer arithmetic: velocity and acceleration from
//! position, at a cost independent of the window length.
//!
//! # What it computes
//! A least-squares polynomial of order K (1..=4) is fitted to the last N positions (N odd,
//! 3..=41) and differentiated at the evaluation point L samples back from the newest
//! (L = 0: causal end point, no delay for signals the polynomial represents; L = (N−1)/2:
//! centred, as scipy's `savgol_filter`). This is exactly scipy's
//! `savgol_coeffs(N, K, deriv, delta, pos=N−1−L, use='dot')` applied to the window.
//!
//! # How: orthogonal moments, updated recursively
//! Number the window by sample age j = 0 (newest) … N−1. Let P₀ … P_K be the discrete
//! orthogonal (Gram) polynomials on j = 0..N−1, each scaled to its smallest integer values
//! (computed at init in exact integer arithmetic from their closed form, the Hahn
//! polynomials; the tests check it against integer Gram–Schmidt on 1, j, j², …, the
//! least-squares definition itself; no pasted tables). The least-squares fit is
//! `f(j) = Σₚ Mₚ·Pₚ(j)/‖Pₚ‖²` with the *Gram moments* `Mₚ = Σⱼ Pₚ(j)·x₋ⱼ`, so
//!
//! `v = −(1/T)·Σₚ Mₚ·P′ₚ(L)/‖Pₚ‖²`,  `a = (1/T²)·Σₚ Mₚ·P″ₚ(L)/‖Pₚ‖²`
//!
//! (age runs against time, hence the sign of v). P₀ is constant and drops out. Each Pₚ is an
//! integer combination of binomials, `Pₚ(j) = Σ_q αₚ_q·C(j, q)`, and the *binomial moments*
//! `T_q = Σⱼ C(j, q)·x₋ⱼ` slide with Pascal's rule, `C(j+1, q) = C(j, q) + C(j, q−1)`:
//!
//! `T_q ← T_q + T_{q−1} − C(N, q)·x_oldest` (q ≥ 1), `T₀ ← T₀ + x_newest − x_oldest`.
//!
//! So one sample costs K+1 moment updates and K small integer dot products, whatever N is —
//! no history shift, no N-tap convolution: 111 instructions per sample for velocity and
//! acceleration at K = 2 on the Cortex-M4 (QEMU benchmark `bench/cm4`; budget 120).
//!
//! # Number formats
//! - Input `x`: [`PositionCounts`], `I12F20` (Q12.20 encoder periods in an i32) (LSB λ/2²⁰ ≈ 22.9 nm). It may
//!   wrap: it is unwrapped on entry, `X ← X + (x ⊖ x_prev)` with the wrapping i32 difference
//!   sign-extended, so a window that straddles the i32 wrap is differentiated correctly.
//! - `X`, the history ring, `T_q` and `Mₚ`: i64 in wrapping arithmetic, i.e. exact in the
//!   ring ℤ/2⁶⁴ (every operation is an add, subtract or multiply by an integer constant,
//!   and reduction mod 2⁶⁴ commutes with all three). |αₚ_q| ≤ 46 376 and C(N, q) ≤ 101 270
//!   are u32.
//! - Output: `Mₚ` is converted to f32 (relative error ≤ 2⁻²³) and multiplied by an f32
//!   weight (the SI scale folded in). These two roundings are the only ones anywhere.
//!
//! # Overflow proof: `Mₚ` is exact for *every* input sequence
//! Working mod 2⁶⁴, the bit pattern of `Mₚ` is its true integer value as soon as that value
//! lies in (−2⁶³, 2⁶³). For p ≥ 1, Pₚ is orthogonal to P₀ = 1, so `Σⱼ Pₚ(j) = 0` and
//! `Mₚ = Σⱼ Pₚ(j)·(X₋ⱼ − X₀)`. Each unwrapped step is a sign-extended i32, so
//! `|X₋ⱼ − X₀| ≤ j·2³¹ ≤ 40·2³¹ < 2^36.33`; and `‖Pₚ‖₁ = Σⱼ|Pₚ(j)| ≤ 617 100 < 2^19.24` over
//! every N ≤ 41, p ≤ 4 (`gram_moment_bound_holds_for_every_configuration` checks all of
//! them). Hence `|Mₚ| < 2^55.6 < 2⁶³`: no input, in the stroke or not, can overflow it. The
//! `T_q` themselves may wrap freely — only their exact residues are used. (In service the
//! decoder bounds each step by its plausibility limit, 13 107 counts, so |Mₚ| < 2³⁹.)
//! `every_input_gives_the_exact_gram_moments` compares `Mₚ` bit for bit with a direct i128
//! evaluation on arbitrary (adversarial) inputs.

use crate::real::i64_to_f32;
use crate::sensing::encoder::PositionCounts;

/// Largest supported window.
pub const MAX_WINDOW: usize = 41;

/// Largest supported polynomial order.
pub const MAX_ORDER: usize = 4;

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

/// Ring slots: the window rounded up to a power of two.
const RING: usize = 64;
const _: () = assert!(RING.is_power_of_two() && RING >= MAX_WINDOW);

/// Integer moments of K+1 orders (index q = 0..=K).
type Moments = [i64; MAX_ORDER + 1];

/// A straight line through the window ([`SavitzkyGolay::restart_on_line`]): `at_newest` and
/// `slope` in counts (per sample) relative to the raw count `base`.
#[derive(Clone, Copy, Debug)]
struct Line {
    base: i32,
    at_newest: f32,
    slope: f32,
}

impl Line {
    /// The i-th value of a window of `n` (oldest first) in the raw count's frame (wrapping),
    /// to the nearest count.
    #[inline(always)]
    fn at(self, i: usize, n: usize) -> i32 {
        let offset = self.at_newest - self.slope * (n - 1 - i) as f32;
        // To the nearest count (`as` truncates toward zero).
        let half = if offset < 0.0 { -0.5 } else { 0.5 };
        self.base.wrapping_add((offset + half) as i32)
    }
}

/// The differentiator's state: its constants and the sliding moments.
#[derive(Clone, Debug)]
pub struct SavitzkyGolay {
    window: usize,
    order: usize,
    lag: usize,
    /// C(N, q) for q = 1..=4: the weight of the sample leaving the window in Pascal's rule.
    leaving: [u32; MAX_ORDER],
    /// C(N, q+1) for q = 0..=4: the moments of a window holding one constant sample.
    constant: Moments,
    /// Row p−1: |αₚ_q|, the magnitudes of the binomial-basis coefficients of the Gram
    /// polynomial Pₚ (their signs alternate, see [`gram_moment`]).
    alpha: [[u32; MAX_ORDER + 1]; MAX_ORDER],
    /// Per Gram moment M₁..M₄: m/s per unit of Mₚ.
    weights_v: [f32; MAX_ORDER],
    /// Per Gram moment M₁..M₄: m/s² per unit of Mₚ.
    weights_a: [f32; MAX_ORDER],
    /// Binomial moments T₀..T₄ of the unwrapped window (mod 2⁶⁴).
    moments: Moments,
    /// Unwrapped positions of the window, a ring of the first `window` slots; `head` holds
    /// the oldest. Sized to a power of two so that masking the index proves it in bounds.
    ring: [i64; RING],
    head: usize,
    /// Last raw input (the count's bits) and its unwrapped value.
    last_input: i32,
    unwrapped: i64,
    started: bool,
}

impl SavitzkyGolay {
    /// Builds the differentiator: checks the configuration and derives every constant from
    /// the closed form of the Gram polynomials in exact integer arithmetic.
    pub fn new(cfg: SgConfig) -> Result<Self, SgError> {
        let n = cfg.window;
        if !(3..=MAX_WINDOW).contains(&n) || n.is_multiple_of(2) {
            return Err(SgError::Window);
        }
        if cfg.order == 0 || cfg.order > MAX_ORDER || cfg.order >= n {
            return Err(SgError::Order);
        }
        if cfg.lag >= n {
            return Err(SgError::Lag);
        }
        let dt = f64::from(cfg.sample_time_s);
        let m = f64::from(cfg.m_per_count);
        if !(dt.is_finite() && dt > 0.0 && m.is_finite() && m > 0.0) {
            return Err(SgError::Scale);
        }
        let k = cfg.order;

        let mut alpha = [[0u32; MAX_ORDER + 1]; MAX_ORDER];
        let mut weights_v = [0.0f32; MAX_ORDER];
        let mut weights_a = [0.0f32; MAX_ORDER];
        for (p, ((row, wv), wa)) in alpha
            .iter_mut()
            .zip(weights_v.iter_mut())
            .zip(weights_a.iter_mut())
            .take(k)
            .enumerate()
        {
            let degree = p + 1;
            *row = gram_binomial_coefficients(n, degree).ok_or(SgError::Order)?;
            if degree == 1 && row.get(1) != Some(&1) {
                return Err(SgError::Order);
            }
            // The signs alternate, αₚ_q = (−1)^(p−q)·|αₚ_q|, with the leading one positive.
            let mut signed = [0i32; MAX_ORDER + 1];
            for (q, (s, &a)) in signed
                .iter_mut()
                .zip(row.iter())
                .enumerate()
                .take(degree + 1)
            {
                let a = i32::try_from(a).map_err(|_| SgError::Order)?;
                *s = if (degree - q).is_multiple_of(2) {
                    a
                } else {
                    -a
                };
            }
            // Exact (below 2⁵³), in two u32 halves: a u64 → f64 conversion is one more
            // library routine.
            let norm = gram_norm(&signed, n);
            let norm = f64::from((norm >> 32) as u32) * 4_294_967_296.0 + f64::from(norm as u32);
            let [d1, d2] = derivatives_at_lag(&signed, cfg.lag).map(|d| {
                // 24·Pₚ⁽ᵐ⁾(L) is an exact integer below 2⁴²: to f64 exactly in two halves.
                let hi = (d >> 32) as i32;
                (f64::from(hi) * 4_294_967_296.0 + f64::from(d as u32)) / 24.0
            });
            *wv = (-d1 / norm * m / dt) as f32;
            *wa = (d2 / norm * m / (dt * dt)) as f32;
        }

        let mut leaving = [0u32; MAX_ORDER];
        for (q, c) in leaving.iter_mut().enumerate() {
            *c = binomial(n, q + 1);
        }
        let mut constant = [0i64; MAX_ORDER + 1];
        for (q, c) in constant.iter_mut().enumerate() {
            *c = i64::from(binomial(n, q + 1));
        }
        Ok(SavitzkyGolay {
            window: n,
            order: k,
            lag: cfg.lag,
            leaving,
            constant,
            alpha,
            weights_v,
            weights_a,
            moments: [0; MAX_ORDER + 1],
            ring: [0; RING],
            head: 0,
            last_input: 0,
            unwrapped: 0,
            started: false,
        })
    }

    /// Window length.
    pub fn window(&self) -> usize {
        self.window
    }

    /// Polynomial order.
    pub fn order(&self) -> usize {
        self.order
    }

    /// Evaluation point, samples back from the newest.
    pub fn lag(&self) -> usize {
        self.lag
    }

    /// Forgets the history (e.g. after re-homing moved the zero).
    pub fn reset(&mut self) {
        self.started = false;
    }

    /// Refills the window with the straight line fitted (least squares) to its newest
    /// `samples` positions, and returns the line's derivatives at the newest sample
    /// (velocity = its slope; acceleration 0 but for the line's rounding to whole counts).
    /// For an estimate before the window has filled after a start (after a reset, the brake
    /// cannot wait for N samples): from this call on
    /// the window holds the line, and each real sample pushed replaces one of the line's,
    /// so the estimate goes over to the full window's without a jump. The price is noise:
    /// a line through m samples of noise σ_x has a slope noise
    /// `σ_v = (σ_x/T)·√(12/(m(m²−1)))` (m = 6: 0.24·σ_x/T, against the full window's
    /// [`SavitzkyGolay::new`] figure), and a bias of `a·T·(m−1)/2` under an acceleration a.
    ///
    /// `samples` is clamped to 2..=N; before a start this is a no-op (zero output). The state
    /// it leaves is, to the bit, that of a start on the line's oldest value and N−1 pushes of
    /// the others, built in one pass over the window (N·(K+1) adds, no slides): a cold path,
    /// once, but inside a control period.
    #[cold]
    #[inline(never)]
    pub fn restart_on_line(&mut self, samples: usize) -> Derivatives {
        if !self.started {
            return Derivatives::default();
        }
        let n = self.window;
        let m = samples.clamp(2, n);
        // The k-th newest slot (k = 0: the newest; `head` holds the oldest), relative to the
        // newest, counts; the abscissa of the k-th newest is −k.
        let newest = self.unwrapped;
        let (mut sum_j, mut sum_d, mut sum_jj, mut sum_jd) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
        for k in 0..m {
            let slot = (self.head + 2 * n - 1 - k) % n;
            let x = self.ring.get(slot & (RING - 1)).copied().unwrap_or(newest);
            let d = i64_to_f32(x.wrapping_sub(newest));
            let j = -(k as f32);
            sum_j += j;
            sum_d += d;
            sum_jj += j * j;
            sum_jd += j * d;
        }
        let mf = m as f32;
        let slope = (mf * sum_jd - sum_j * sum_d) / (mf * sum_jj - sum_j * sum_j);
        let at_newest = (sum_d - slope * sum_j) / mf;
        let line = Line {
            base: self.last_input,
            at_newest,
            slope,
        };
        self.refill(line);
        match self.order {
            1 => self.derivatives::<1>(),
            2 => self.derivatives::<2>(),
            3 => self.derivatives::<3>(),
            _ => self.derivatives::<4>(),
        }
    }

    /// Fills the window with `line` ([`SavitzkyGolay::restart_on_line`]): the ring, the
    /// moments T₀..T_K, `head` and the unwrapped input as a start on the line's oldest value
    /// and N−1 slides of the others leave them. The values are unwrapped as
    /// [`SavitzkyGolay::slide`] unwraps them (from the oldest, sign-extended wrapping steps),
    /// the oldest goes to slot N−1 (where `head` then points), the i-th (i ≥ 1) to slot i−1.
    /// The moments `T_q = Σⱼ C(j, q)·X₋ⱼ` grow with the window, oldest first: each value
    /// added ages the others by one, `T_q ← T_q + T_{q−1}` (Pascal's rule, highest order
    /// first), and enters at age 0, `T₀ ← T₀ + X`; after N values they are the window's,
    /// exact mod 2⁶⁴ (adds only). The moments above K stay a constant window's of the oldest
    /// value, as a start leaves them (no slide touches them).
    fn refill(&mut self, line: Line) {
        let n = self.window;
        let k = self.order.min(MAX_ORDER);
        let oldest = line.at(0, n);
        let oldest_u = i64::from(oldest);
        let mut moments = self.constant.map(|c| c.wrapping_mul(oldest_u));
        for t in moments.iter_mut().take(k + 1) {
            *t = 0;
        }
        let (mut x_prev, mut u) = (oldest, oldest_u);
        for i in 0..n {
            let x = line.at(i, n);
            u = u.wrapping_add(i64::from(x.wrapping_sub(x_prev)));
            x_prev = x;
            let slot = if i == 0 { n - 1 } else { i - 1 };
            if let Some(s) = self.ring.get_mut(slot & (RING - 1)) {
                *s = u;
            }
            for q in (1..=k).rev() {
                let below = moments.get(q - 1).copied().unwrap_or(0);
                if let Some(t) = moments.get_mut(q) {
                    *t = t.wrapping_add(below);
                }
            }
            let [t0, ..] = &mut moments;
            *t0 = t0.wrapping_add(u);
        }
        self.moments = moments;
        self.head = n - 1;
        self.last_input = x_prev;
        self.unwrapped = u;
        self.started = true;
    }

    /// Adds the newest position and returns the derivatives at the evaluation point.
    ///
    /// The first sample after construction or [`SavitzkyGolay::reset`] fills the whole
    /// window with itself (zero output); the estimate is the true least-squares one from the
    /// N-th sample on.
    #[inline]
    pub fn push(&mut self, x: PositionCounts) -> Derivatives {
        // The core works on the raw count: exact wrapping integers from here on.
        let x = x.to_bits();
        if !self.started {
            self.start(x);
            return Derivatives::default();
        }
        // One monomorphised body per order: the loops over q unroll and the moments stay in
        // registers.
        match self.order {
            1 => self.advance::<1>(x),
            2 => self.advance::<2>(x),
            3 => self.advance::<3>(x),
            _ => self.advance::<4>(x),
        }
    }

    /// Out of line: the first sample's, once (inlined, it would take the control path's
    /// room in CCM SRAM).
    #[inline(never)]
    fn start(&mut self, x: i32) {
        let xn = i64::from(x);
        self.ring.fill(xn);
        self.head = 0;
        self.last_input = x;
        self.unwrapped = xn;
        for (t, &c) in self.moments.iter_mut().zip(&self.constant) {
            *t = c.wrapping_mul(xn);
        }
        self.started = true;
    }

    #[inline(always)]
    fn advance<const K: usize>(&mut self, x: i32) -> Derivatives {
        self.slide::<K>(x);
        self.derivatives::<K>()
    }

    /// Slides the window by one raw input `x`: the ring and the moments T₀..T_K.
    #[inline(always)]
    fn slide<const K: usize>(&mut self, x: i32) {
        let newest = self
            .unwrapped
            .wrapping_add(i64::from(x.wrapping_sub(self.last_input)));
        self.unwrapped = newest;
        self.last_input = x;
        // `head` < window ≤ 41 always; the mask only lets the compiler see it.
        let oldest = match self.ring.get_mut(self.head & (RING - 1)) {
            Some(slot) => core::mem::replace(slot, newest),
            None => newest,
        };
        let next = self.head + 1;
        self.head = if next >= self.window { 0 } else { next };

        // Pascal's rule, highest order first so each uses the previous T_{q−1}.
        let [c1, c2, c3, c4] = self.leaving;
        let leave = |c: u32| oldest.wrapping_mul(i64::from(c));
        let [t0, t1, t2, t3, t4] = &mut self.moments;
        if K >= 4 {
            *t4 = t4.wrapping_add(*t3).wrapping_sub(leave(c4));
        }
        if K >= 3 {
            *t3 = t3.wrapping_add(*t2).wrapping_sub(leave(c3));
        }
        if K >= 2 {
            *t2 = t2.wrapping_add(*t1).wrapping_sub(leave(c2));
        }
        *t1 = t1.wrapping_add(*t0).wrapping_sub(leave(c1));
        *t0 = t0.wrapping_add(newest.wrapping_sub(oldest));
    }

    /// The derivatives at the evaluation point from the moments T₀..T_K.
    #[inline(always)]
    fn derivatives<const K: usize>(&self) -> Derivatives {
        let t = &self.moments;
        let [a1, a2, a3, a4] = &self.alpha;
        let [v1, v2, v3, v4] = self.weights_v;
        let [_, w2, w3, w4] = self.weights_a;
        // P₁(j) = j − (N−1)/2: its leading coefficient is 1 (checked at init), so M₁ needs
        // one multiply.
        let [t0, t1, ..] = *t;
        let [a10, ..] = *a1;
        let m1 = i64_to_f32(t1.wrapping_sub(t0.wrapping_mul(i64::from(a10))));
        let mut velocity = v1 * m1;
        let mut acceleration = 0.0;
        if K >= 2 {
            let m2 = i64_to_f32(gram_moment(a2, t, 2));
            velocity += v2 * m2;
            acceleration += w2 * m2;
        }
        if K >= 3 {
            let m3 = i64_to_f32(gram_moment(a3, t, 3));
            velocity += v3 * m3;
            acceleration += w3 * m3;
        }
        if K >= 4 {
            let m4 = i64_to_f32(gram_moment(a4, t, 4));
            velocity += v4 * m4;
            acceleration += w4 * m4;
        }
        Derivatives {
            velocity_mps: velocity,
            acceleration_mps2: acceleration,
        }
    }

    /// The Gram moments M₁..M_K as the recursion holds them (for the exactness tests).
    #[cfg(test)]
    fn gram_moments(&self) -> [i64; MAX_ORDER] {
        let mut out = [0i64; MAX_ORDER];
        for (p, (o, a)) in out.iter_mut().zip(&self.alpha).enumerate().take(self.order) {
            *o = gram_moment(a, &self.moments, p + 1);
        }
        out
    }
}

/// `Mₚ = Σ_{q≤p} (−1)^(p−q)·|αₚ_q|·T_q`, exact mod 2⁶⁴ (see the module's overflow proof).
/// With `p` a constant after inlining, the signs are compile-time adds and subtracts.
#[inline(always)]
fn gram_moment(alpha: &[u32; MAX_ORDER + 1], t: &Moments, p: usize) -> i64 {
    alpha
        .iter()
        .zip(t)
        .enumerate()
        .take(p + 1)
        .fold(0i64, |acc, (q, (&a, &tq))| {
            let term = tq.wrapping_mul(i64::from(a));
            if (p - q).is_multiple_of(2) {
                acc.wrapping_add(term)
            } else {
                acc.wrapping_sub(term)
            }
        })
}

/// `C(n, q)` for the small arguments used here (n ≤ 41, q ≤ 5: at most 749 398; every
/// intermediate product below 3.1·10⁷). In u32, whose division the Cortex-M4 has in hardware.
#[inline(never)]
fn binomial(n: usize, q: usize) -> u32 {
    let n = u32::try_from(n).unwrap_or(u32::MAX);
    let mut c: u32 = 1;
    for i in 0..q as u32 {
        // Exact at every step: c·(n−i) is divisible by i+1 (c is then C(n, i+1)).
        c = c.saturating_mul(n.saturating_sub(i)) / (i + 1);
    }
    c
}

/// |αₚ_q|, q = 0..=p: the coefficients of the Gram polynomial Pₚ of the window j = 0..n−1 in
/// the binomial basis C(j, q), as the coprime integers with a positive leading one.
///
/// Pₚ is the Hahn polynomial Q_p(j; 0, 0, n−1) = Σ_q (−1)^q·C(p, q)·C(p+q, q)·C(j, q)/C(n−1, q)
/// (the discrete Chebyshev polynomial, orthogonal on j = 0..n−1 with unit weights), up to
/// scale. Times (−1)^p·(n−1)(n−2)…(n−p) the q-th coefficient is the integer
/// (−1)^(p−q)·C(p, q)·C(p+q, q)·q!·(n−q−1)…(n−p), at most 2 193 360 for n ≤ 41, p ≤ 4, so u32
/// holds every step; dividing by the magnitudes' gcd gives the coprime scaling. (Coprime
/// coefficients and coprime values are the same thing: each is an integer combination of
/// the other, the values by Newton's formula, the coefficients as forward differences.)
/// The tests check the result against exact Gram–Schmidt on 1, j, j², … for every window.
/// `None` if p ≥ n or p > 4.
fn gram_binomial_coefficients(n: usize, p: usize) -> Option<[u32; MAX_ORDER + 1]> {
    if p > MAX_ORDER || p >= n {
        return None;
    }
    let n32 = u32::try_from(n).ok()?;
    let mut out = [0u32; MAX_ORDER + 1];
    let mut g = 0u32;
    for (q, a) in out.iter_mut().enumerate().take(p + 1) {
        let mut v = binomial(p, q).checked_mul(binomial(p + q, q))?;
        for i in 1..=q as u32 {
            v = v.checked_mul(i)?;
        }
        for i in (q + 1) as u32..=p as u32 {
            v = v.checked_mul(n32.checked_sub(i)?)?;
        }
        *a = v;
        g = gcd(g, v);
    }
    if g == 0 {
        return None;
    }
    for a in out.iter_mut() {
        *a /= g;
    }
    Some(out)
}

/// ‖Pₚ‖² = Σⱼ Pₚ(j)² over j = 0..n−1, from its binomial-basis coefficients. Exact: below
/// 2⁵³ for every window (checked by the tests), so also exact as an f64.
fn gram_norm(alpha: &[i32; MAX_ORDER + 1], n: usize) -> u64 {
    let mut norm = 0u64;
    // C(j, q), q = 0..=MAX_ORDER, for j = 0, 1, … in turn: C(j+1, q) = C(j, q) + C(j, q−1)
    // (Pascal's rule, exact), a sum per entry where a binomial per entry took q divisions.
    let mut row = [0i64; MAX_ORDER + 1];
    if let Some(first) = row.first_mut() {
        *first = 1;
    }
    for _ in 0..n {
        let value = alpha.iter().zip(&row).fold(0i64, |s, (&a, &c)| {
            s.wrapping_add(i64::from(a).wrapping_mul(c))
        });
        norm = norm.wrapping_add(value.unsigned_abs().wrapping_mul(value.unsigned_abs()));
        let mut below = 0i64;
        for c in row.iter_mut() {
            let this = *c;
            *c = this.wrapping_add(below);
            below = this;
        }
    }
    norm
}

fn gcd(mut a: u32, mut b: u32) -> u32 {
    while b != 0 {
        // b ≠ 0: the remainder is defined.
        (a, b) = (b, a % b);
    }
    a
}

/// 24·P′(L) and 24·P″(L), exactly, for P(j) = Σ_q α_q·C(j, q) (`alpha` signed): with
/// C(j, q) = F_q(j)/q! and the falling factorial F_q(j) = j(j−1)…(j−q+1), 24/q! is an integer
/// for q ≤ 4, so both are integers. F_q and its first two derivatives at L by the product
/// rule, one factor (L − q) at a time. |α| ≤ 46 376 and L ≤ 40 keep every term below 2⁴²
/// (so the f64 conversion after it is exact too).
fn derivatives_at_lag(alpha: &[i32; MAX_ORDER + 1], lag: usize) -> [i64; 2] {
    let l = i64::try_from(lag).unwrap_or(0);
    // (F_q(L), F_q′(L), F_q″(L)), starting from F₀ = 1.
    let (mut f, mut f1, mut f2) = (1i64, 0i64, 0i64);
    let mut scale = 24i64; // 24/q!
    let (mut d1, mut d2) = (0i64, 0i64);
    for (q, &a) in alpha.iter().enumerate() {
        let q = q as i64;
        if q > 0 {
            scale /= q;
        }
        let c = i64::from(a) * scale;
        d1 += c * f1;
        d2 += c * f2;
        // F_{q+1}(j) = F_q(j)·(j − q)
        let t = l - q;
        f2 = f2 * t + 2 * f1;
        f1 = f1 * t + f;
        f *= t;
    }
    [d1, d2]
}

#[cfg(test)]
// The reference implementations below index like the textbook formulas they transcribe.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;

    /// A position of `n` raw counts.
    fn bits(n: i32) -> PositionCounts {
        PositionCounts::from_bits(n)
    }

    // The reference route: exact integer Gram–Schmidt (the least-squares definition).

    /// Values at j = 0..n−1 of the Gram polynomials P₀..P_k, each scaled to coprime integers:
    /// Gram–Schmidt on 1, j, j², … in exact integer arithmetic (each projection is removed
    /// by `v ← ‖P‖²·v − ⟨v, P⟩·P`, then the common factor is divided out). `None` if a value
    /// ever left i128 (impossible for n ≤ 41, k ≤ 4: intermediates stay below 2⁹³).
    fn gram_polynomials(n: usize, k: usize) -> Option<[[i128; MAX_WINDOW]; MAX_ORDER + 1]> {
        let mut basis = [[0i128; MAX_WINDOW]; MAX_ORDER + 1];
        for (p, poly) in basis.iter_mut().enumerate().take(k + 1) {
            let mut v = [0i128; MAX_WINDOW];
            for (j, x) in v.iter_mut().enumerate().take(n) {
                *x = (j as i128).checked_pow(p as u32)?;
            }
            *poly = v;
        }
        for p in 0..=k {
            let (done, rest) = basis.split_at_mut(p);
            let v = rest.first_mut()?;
            for q in done.iter() {
                let norm = dot(q, q, n)?;
                let proj = dot(v, q, n)?;
                for (x, &b) in v.iter_mut().zip(q.iter()).take(n) {
                    *x = x.checked_mul(norm)?.checked_sub(proj.checked_mul(b)?)?;
                }
                let g = v
                    .iter()
                    .take(n)
                    .fold(0u128, |g, x| gcd128(g, x.unsigned_abs()));
                let g = i128::try_from(g).ok().filter(|g| *g > 0)?;
                for x in v.iter_mut().take(n) {
                    *x = x.checked_div(g)?;
                }
            }
        }
        Some(basis)
    }

    fn dot(a: &[i128; MAX_WINDOW], b: &[i128; MAX_WINDOW], n: usize) -> Option<i128> {
        a.iter()
            .zip(b)
            .take(n)
            .try_fold(0i128, |s, (x, y)| s.checked_add(x.checked_mul(*y)?))
    }

    fn gcd128(mut a: u128, mut b: u128) -> u128 {
        while b != 0 {
            // b ≠ 0: the remainder is defined.
            (a, b) = (b, a % b);
        }
        a
    }

    /// The coefficients of the polynomial of `degree` through `values` (at j = 0, 1, …) in the
    /// binomial basis C(j, q): its forward differences at j = 0 (Newton's formula). `None` if
    /// one does not fit an i32 (never for n ≤ 41, k ≤ 4: |α| ≤ 46 376).
    fn binomial_coefficients(values: &[i128], degree: usize) -> Option<[i32; MAX_ORDER + 1]> {
        let mut diff = [0i128; MAX_WINDOW];
        for (d, v) in diff.iter_mut().zip(values) {
            *d = *v;
        }
        let mut out = [0i32; MAX_ORDER + 1];
        for (q, a) in out.iter_mut().enumerate().take(degree + 1) {
            *a = diff.first().and_then(|&d| i32::try_from(d).ok())?;
            for i in 0..values.len().saturating_sub(q + 1) {
                let next = diff.get(i + 1).copied().unwrap_or(0);
                if let Some(d) = diff.get_mut(i) {
                    *d = next.checked_sub(*d)?;
                }
            }
        }
        Some(out)
    }

    fn cfg(window: usize, order: usize, lag: usize) -> SgConfig {
        SgConfig {
            window,
            order,
            lag,
            sample_time_s: 50e-6,
            m_per_count: 1e-6,
        }
    }

    /// Every valid configuration (window, order, lag).
    fn all_configs() -> impl Iterator<Item = (usize, usize, usize)> {
        (3..=MAX_WINDOW).step_by(2).flat_map(|n| {
            (1..=MAX_ORDER.min(n - 1)).flat_map(move |k| (0..n).map(move |l| (n, k, l)))
        })
    }

    /// Direct least-squares weights in f64 (normal equations on the monomials, centred on
    /// the evaluation point): an independent check of the Gram route. Oldest sample first.
    fn direct_weights(n: usize, k: usize, lag: usize, deriv: usize) -> Vec<f64> {
        let origin = (n - 1 - lag) as f64;
        let m = k + 1;
        let mut g = vec![vec![0.0f64; m]; m];
        for j in 0..n {
            let tau = j as f64 - origin;
            for r in 0..m {
                for c in 0..m {
                    g[r][c] += tau.powi((r + c) as i32);
                }
            }
        }
        let mut rhs = vec![0.0; m];
        rhs[deriv] = if deriv == 2 { 2.0 } else { 1.0 };
        // Gaussian elimination (G is SPD and small).
        for col in 0..m {
            let piv = (col..m)
                .max_by(|&a, &b| g[a][col].abs().total_cmp(&g[b][col].abs()))
                .unwrap();
            g.swap(col, piv);
            rhs.swap(col, piv);
            for r in col + 1..m {
                let f = g[r][col] / g[col][col];
                for c in col..m {
                    g[r][c] -= f * g[col][c];
                }
                rhs[r] -= f * rhs[col];
            }
        }
        let mut y = vec![0.0; m];
        for r in (0..m).rev() {
            let s: f64 = rhs[r] - (r + 1..m).map(|c| g[r][c] * y[c]).sum::<f64>();
            y[r] = s / g[r][r];
        }
        (0..n)
            .map(|j| {
                let tau = j as f64 - origin;
                (0..m).map(|p| y[p] * tau.powi(p as i32)).sum()
            })
            .collect()
    }

    #[test]
    fn matches_the_least_squares_definition_for_every_configuration() {
        // Response to a unit impulse at each position of the window = the weights.
        let mut worst = 0.0f64;
        for (n, k, lag) in all_configs() {
            let hv = direct_weights(n, k, lag, 1);
            let ha = if k >= 2 {
                direct_weights(n, k, lag, 2)
            } else {
                vec![0.0; n]
            };
            let scale_v: f64 = hv.iter().map(|h| h.abs()).sum();
            let scale_a: f64 = ha.iter().map(|h| h.abs()).sum::<f64>().max(1e-300);
            let mut sg = SavitzkyGolay::new(SgConfig {
                sample_time_s: 1.0,
                m_per_count: 1.0,
                ..cfg(n, k, lag)
            })
            .unwrap();
            for at in 0..n {
                // A zero history, then the window: the impulse is 10⁶ counts tall so the
                // f32 output rounding is negligible.
                sg.reset();
                sg.push(bits(0));
                let mut d = Derivatives::default();
                for j in 0..n {
                    d = sg.push(bits(if j == at { 1_000_000 } else { 0 }));
                }
                let ev = (f64::from(d.velocity_mps) / 1e6 - hv[at]).abs() / scale_v;
                worst = worst.max(ev);
                if k >= 2 {
                    let ea = (f64::from(d.acceleration_mps2) / 1e6 - ha[at]).abs() / scale_a;
                    worst = worst.max(ea);
                }
            }
        }
        assert!(worst < 1e-6, "worst relative weight error {worst:e}");
    }

    /// Monomial coefficients (ascending powers of j) of `Σ_q α_q·C(j, q)`.
    fn monomial_coefficients(alpha: &[i32; MAX_ORDER + 1]) -> [f64; MAX_ORDER + 1] {
        let mut out = [0.0f64; MAX_ORDER + 1];
        // C(j, q) = j(j−1)…(j−q+1)/q!, built up one factor at a time.
        let mut falling = [0.0f64; MAX_ORDER + 1];
        if let Some(f) = falling.first_mut() {
            *f = 1.0;
        }
        let mut factorial = 1.0f64;
        for (q, &a) in alpha.iter().enumerate() {
            if q > 0 {
                factorial *= q as f64;
                // falling ← falling·(j − (q−1))
                let shift = (q - 1) as f64;
                let mut next = [0.0f64; MAX_ORDER + 1];
                for (m, nx) in next.iter_mut().enumerate() {
                    let lower = if m > 0 {
                        falling.get(m - 1).copied().unwrap_or(0.0)
                    } else {
                        0.0
                    };
                    *nx = lower - shift * falling.get(m).copied().unwrap_or(0.0);
                }
                falling = next;
            }
            for (o, f) in out.iter_mut().zip(falling.iter()) {
                *o += f64::from(a) * f / factorial;
            }
        }
        out
    }

    /// First and second derivative at `j` of the polynomial with ascending coefficients `c`.
    fn derivatives_at(c: &[f64; MAX_ORDER + 1], j: f64) -> (f64, f64) {
        let mut d1 = 0.0;
        let mut d2 = 0.0;
        let mut pow = 1.0; // j^(m−1) for d1, then j^(m−2) for d2 via `prev`
        let mut prev = 0.0;
        for (m, &cm) in c.iter().enumerate().skip(1) {
            let mf = m as f64;
            d1 += mf * cm * pow;
            if m >= 2 {
                d2 += mf * (mf - 1.0) * cm * prev;
            }
            prev = pow;
            pow *= j;
        }
        (d1, d2)
    }

    /// The weights by the Gram–Schmidt route, as `new` computed them before the closed form.
    fn reference_weights(c: SgConfig) -> ([f32; MAX_ORDER], [f32; MAX_ORDER]) {
        let (n, k) = (c.window, c.order);
        let gram = gram_polynomials(n, k).unwrap();
        let (dt, m) = (f64::from(c.sample_time_s), f64::from(c.m_per_count));
        let mut wv = [0.0f32; MAX_ORDER];
        let mut wa = [0.0f32; MAX_ORDER];
        for p in 1..=k {
            let values = &gram[p][..n];
            let signed = binomial_coefficients(values, p).unwrap();
            let sign = if signed[p] < 0 { -1.0 } else { 1.0 };
            let norm: f64 = values.iter().map(|&v| (v as f64) * (v as f64)).sum();
            let (d1, d2) = derivatives_at(&monomial_coefficients(&signed), c.lag as f64);
            wv[p - 1] = (-sign * d1 / norm * m / dt) as f32;
            wa[p - 1] = (sign * d2 / norm * m / (dt * dt)) as f32;
        }
        (wv, wa)
    }

    #[test]
    fn closed_form_gram_polynomials_match_gram_schmidt_for_every_window() {
        for n in (3..=MAX_WINDOW).step_by(2) {
            let k = MAX_ORDER.min(n - 1);
            let g = gram_polynomials(n, k).unwrap();
            for p in 1..=k {
                let gs = binomial_coefficients(&g[p][..n], p).unwrap();
                let flip = if gs[p] < 0 { -1 } else { 1 };
                let closed = gram_binomial_coefficients(n, p).unwrap();
                let mut signed = [0i32; MAX_ORDER + 1];
                for q in 0..=p {
                    let expected = i64::from(gs[q]) * flip;
                    let sign = if (p - q) % 2 == 0 { 1 } else { -1 };
                    assert_eq!(i64::from(closed[q]) * sign, expected, "n={n} p={p} q={q}");
                    signed[q] = gs[q] * flip as i32;
                }
                assert!(closed[p + 1..].iter().all(|&a| a == 0));
                let norm: i128 = g[p][..n].iter().map(|v| v * v).sum();
                assert_eq!(i128::from(gram_norm(&signed, n)), norm, "n={n} p={p}");
                assert!(norm < 1i128 << 53, "‖P‖² exact in f64");
                for lag in 0..n {
                    for d in derivatives_at_lag(&signed, lag) {
                        assert!(d.unsigned_abs() < 1 << 42, "n={n} p={p} lag={lag}: {d}");
                    }
                }
            }
            assert_eq!(gram_binomial_coefficients(n, n), None);
        }
    }

    /// The exact integer derivatives against the f64 route `new` used before: the same f32
    /// weights bit for bit, except where the exact weight is zero (P′ₚ(L) = 0 by symmetry:
    /// order 4 at the centred lag), which the f64 route left as rounding noise.
    #[test]
    fn weights_match_the_gram_schmidt_route_bit_for_bit_except_its_rounding_noise() {
        let firmware = crate::control::config::ControlConfig::reference();
        let scales = [
            (
                firmware.sample_time_s,
                firmware.encoder_master.m_per_count(),
            ),
            (50e-6, 1e-6),
            (1.0, 1.0),
            (1e-3, 3.0),
        ];
        for (n, k, lag) in all_configs() {
            for (dt, m) in scales {
                let c = SgConfig {
                    sample_time_s: dt,
                    m_per_count: m,
                    ..cfg(n, k, lag)
                };
                let sg = SavitzkyGolay::new(c).unwrap();
                let (wv, wa) = reference_weights(c);
                for (weights, reference) in [(sg.weights_v, wv), (sg.weights_a, wa)] {
                    let largest = reference.iter().fold(0.0f32, |a, w| a.max(w.abs()));
                    for (w, r) in weights.iter().zip(&reference) {
                        if w.to_bits() != r.to_bits() {
                            assert!(
                                *w == 0.0 && r.abs() <= 1e-12 * largest,
                                "n={n} k={k} lag={lag}: {w:e}, reference {r:e}"
                            );
                            assert_eq!((k, 2 * lag + 1), (4, n), "only where P′₄(L) = 0");
                        }
                    }
                }
                if (n, k, lag) == (firmware.sg_window, firmware.sg_order, firmware.sg_lag) {
                    assert_eq!(sg.weights_v.map(f32::to_bits), wv.map(f32::to_bits));
                    assert_eq!(sg.weights_a.map(f32::to_bits), wa.map(f32::to_bits));
                }
            }
        }
    }

    #[test]
    fn gram_moment_bound_holds_for_every_configuration() {
        let mut worst_l1 = 0u128;
        let mut worst_alpha = 0u32;
        for n in (3..=MAX_WINDOW).step_by(2) {
            let k = MAX_ORDER.min(n - 1);
            let g = gram_polynomials(n, k).unwrap();
            for poly in g.iter().take(k + 1).skip(1) {
                let sum: i128 = poly[..n].iter().sum();
                assert_eq!(sum, 0, "P_p must be orthogonal to the constant");
                let l1: u128 = poly[..n].iter().map(|v| v.unsigned_abs()).sum();
                worst_l1 = worst_l1.max(l1);
            }
            let sg = SavitzkyGolay::new(cfg(n, k, 0)).unwrap();
            for row in &sg.alpha {
                for &a in row {
                    worst_alpha = worst_alpha.max(a);
                }
            }
        }
        // The figures the module's proof uses.
        assert!(worst_l1 <= 617_100, "‖P‖₁ = {worst_l1}");
        assert!(worst_alpha <= 46_376, "|α| = {worst_alpha}");
        // |M| < ‖P‖₁ · 40 · 2³¹ < 2⁶³.
        assert!(worst_l1 * 40 * (1u128 << 31) < 1u128 << 63);
    }

    /// Σⱼ Pₚ(j)·X₋ⱼ straight from the ring, in i128.
    fn reference_moments(sg: &SavitzkyGolay) -> [i128; MAX_ORDER] {
        let n = sg.window;
        let g = gram_polynomials(n, sg.order).unwrap();
        let mut out = [0i128; MAX_ORDER];
        for p in 1..=sg.order {
            let mut s = 0i128;
            for j in 0..n {
                // Age j sits j slots before the newest, which is just before `head`.
                let slot = (sg.head + 2 * n - 1 - j) % n;
                s += g[p][j] * i128::from(sg.ring[slot]);
            }
            out[p - 1] = s;
        }
        out
    }

    #[test]
    fn every_input_gives_the_exact_gram_moments() {
        use proptest::prelude::*;
        let strategy = (
            (1usize..=20).prop_map(|h| 2 * h + 1),
            1usize..=4,
            proptest::collection::vec(any::<i32>(), 1..200),
        );
        proptest!(ProptestConfig::with_cases(200), |((n, k, xs) in strategy)| {
            let k = k.min(n - 1);
            let mut sg = SavitzkyGolay::new(cfg(n, k, 0)).unwrap();
            let mut unwrapped = 0i128;
            let mut last = None::<i32>;
            for &x in &xs {
                let d = sg.push(bits(x));
                prop_assert!(d.velocity_mps.is_finite() && d.acceleration_mps2.is_finite());
                unwrapped = match last {
                    None => i128::from(x),
                    Some(l) => unwrapped + i128::from(x.wrapping_sub(l)),
                };
                last = Some(x);
                // The ring really holds the unwrapped positions.
                prop_assert_eq!(i128::from(sg.unwrapped), unwrapped);
                let exact = reference_moments(&sg);
                let got = sg.gram_moments();
                for p in 0..k {
                    prop_assert!(exact[p].abs() < 1i128 << 63);
                    prop_assert_eq!(i128::from(got[p]), exact[p]);
                }
            }
        });
    }

    #[test]
    fn exact_on_polynomials_of_its_order_across_the_i32_wrap() {
        // x(t) = x0 + v t + a t²/2 in counts, crossing i32::MAX mid-run.
        for (k, lag) in [(2, 0), (3, 5), (4, 20)] {
            let mut sg = SavitzkyGolay::new(SgConfig {
                m_per_count: 1e-8,
                ..cfg(41, k, lag)
            })
            .unwrap();
            let (v, a) = (2.0f64, -60.0f64); // m/s, m/s², 10 nm counts
            let x0 = f64::from(i32::MAX) - 1e6;
            let mut d = Derivatives::default();
            let mut t = 0.0;
            for i in 0..200 {
                t = i as f64 * 50e-6;
                let x = x0 + (v * t + 0.5 * a * t * t) * 1e8;
                d = sg.push(bits((x.round() as i64) as i32)); // wraps past i32::MAX
            }
            let te = t - lag as f64 * 50e-6;
            assert!(
                (f64::from(d.velocity_mps) - (v + a * te)).abs() < 1e-3,
                "k={k}"
            );
            assert!((f64::from(d.acceleration_mps2) - a).abs() < 0.1, "k={k}");
        }
    }

    /// The refill's one pass leaves the state — ring, moments T₀..T₄, head, the raw and
    /// unwrapped input — and returns the output that a start on the line's oldest value and
    /// N−1 slides of the others give, to the bit, for every order and window, lines across
    /// the i32 wrap and steep ones included; the pushes after it agree too.
    #[test]
    fn the_refill_in_one_pass_is_the_start_and_slides_to_the_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(44);
        for window in [3usize, 5, 7, 21, 25, 41] {
            for order in 1..=4usize.min(window - 1) {
                for trial in 0..40 {
                    let mut sg = SavitzkyGolay::new(cfg(window, order, 0)).unwrap();
                    let step: i32 = rng.random_range(-20_000..20_000);
                    let mut x: i32 = if trial % 2 == 0 {
                        i32::MAX - 5 * step.abs()
                    } else {
                        rng.random()
                    };
                    let pushed = rng.random_range(1..2 * window);
                    for _ in 0..pushed {
                        x = x.wrapping_add(step).wrapping_add(rng.random_range(-50..50));
                        sg.push(bits(x));
                    }
                    let mut reference = sg.clone();
                    let m = rng.random_range(0..window + 3);
                    let d = sg.restart_on_line(m);
                    let d_ref = restart_by_slides(&mut reference, m);
                    let what = format!("window {window} order {order} trial {trial} m {m}");
                    assert_eq!(d, d_ref, "{what}");
                    assert_eq!(sg.moments, reference.moments, "{what}");
                    assert_eq!(sg.ring[..window], reference.ring[..window], "{what}");
                    assert_eq!(
                        (sg.head, sg.last_input, sg.unwrapped, sg.started),
                        (
                            reference.head,
                            reference.last_input,
                            reference.unwrapped,
                            reference.started
                        ),
                        "{what}"
                    );
                    for _ in 0..window + 2 {
                        x = x.wrapping_add(step);
                        assert_eq!(sg.push(bits(x)), reference.push(bits(x)), "{what}");
                    }
                }
            }
        }
    }

    /// The refill as a start on the line's oldest value and N−1 pushes of the others (their
    /// outputs unread): the reference [`SavitzkyGolay::restart_on_line`] must equal.
    fn restart_by_slides(sg: &mut SavitzkyGolay, samples: usize) -> Derivatives {
        if !sg.started {
            return Derivatives::default();
        }
        let n = sg.window;
        let m = samples.clamp(2, n);
        let newest = sg.unwrapped;
        let (mut sum_j, mut sum_d, mut sum_jj, mut sum_jd) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
        for k in 0..m {
            let x = sg.ring[(sg.head + 2 * n - 1 - k) % n];
            let d = i64_to_f32(x.wrapping_sub(newest));
            let j = -(k as f32);
            sum_j += j;
            sum_d += d;
            sum_jj += j * j;
            sum_jd += j * d;
        }
        let mf = m as f32;
        let slope = (mf * sum_jd - sum_j * sum_d) / (mf * sum_jj - sum_j * sum_j);
        let at_newest = (sum_d - slope * sum_j) / mf;
        let base = sg.last_input;
        let line = |i: usize| {
            let offset = at_newest - slope * (n - 1 - i) as f32;
            let half = if offset < 0.0 { -0.5 } else { 0.5 };
            base.wrapping_add((offset + half) as i32)
        };
        sg.start(line(0));
        let mut d = Derivatives::default();
        for i in 1..n {
            d = sg.push(bits(line(i)));
        }
        d
    }

    /// The refill slides the line in without its outputs: the moments and the output are
    /// those of a fresh filter fed the window's contents, oldest first, to the bit, for every
    /// order.
    #[test]
    fn a_restart_holds_what_pushing_the_line_would() {
        for order in 1..=4 {
            let mut sg = SavitzkyGolay::new(cfg(21, order, 0)).unwrap();
            for i in 0..9 {
                sg.push(bits(i32::MAX - 300 + 37 * i + (i * i) % 5));
            }
            let d = sg.restart_on_line(7);
            let mut fresh = SavitzkyGolay::new(cfg(21, order, 0)).unwrap();
            let mut reference = Derivatives::default();
            for k in 0..sg.window {
                let x = sg.ring[(sg.head + k) % sg.window];
                reference = fresh.push(bits(x as i32));
            }
            assert_eq!(sg.gram_moments(), fresh.gram_moments(), "order {order}");
            assert_eq!(d, reference, "order {order}");
        }
    }

    /// A start, then `m` samples of a ramp (across the i32 wrap) with Gaussian noise: the
    /// line's slope is the velocity within the stated noise (its spread over many draws
    /// matches `σ_x/T·√(12/(m(m²−1)))`), and once N real samples have followed, the
    /// estimate is the full window's on those samples alone, to the bit.
    #[test]
    fn a_restart_on_a_line_gives_the_slope_at_once_and_hands_over_to_the_window() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let (n, m) = (25usize, 6usize);
        let (v, sigma_counts) = (0.5f64, 1.0f64); // m/s; 1 µm noise at 1 µm counts
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, sigma_counts).unwrap();
        let x0 = f64::from(i32::MAX) - 200.0;
        let mut errors = Vec::new();
        for trial in 0..2000 {
            let mut sg = SavitzkyGolay::new(cfg(n, 2, 0)).unwrap();
            let mut fresh = SavitzkyGolay::new(cfg(n, 2, 0)).unwrap();
            let at = |i: usize, rng: &mut rand_chacha::ChaCha8Rng| {
                let x = x0 + v * i as f64 * 50e-6 * 1e6 + noise.sample(rng);
                bits((x.round() as i64) as i32)
            };
            for i in 0..m {
                sg.push(at(i, &mut rng));
            }
            let d = sg.restart_on_line(m);
            // The line rounded to whole counts (1 µm here, 23 nm on the machine's encoders)
            // is all the acceleration the window sees: ≈ 1 m/s² rms for this window.
            assert!(d.acceleration_mps2.abs() < 5.0, "{}", d.acceleration_mps2);
            errors.push(f64::from(d.velocity_mps) - v);
            if trial < 20 {
                let mut last = d;
                for i in m..m + n {
                    let x = at(i, &mut rng);
                    last = sg.push(x);
                    fresh.push(x);
                }
                // The window holds only real samples now: the same estimate as a window
                // that never held the line (its first sample filled it; n more replaced it).
                let mut reference = Derivatives::default();
                for i in m + n..m + 2 * n {
                    let x = at(i, &mut rng);
                    last = sg.push(x);
                    reference = fresh.push(x);
                }
                assert_eq!(last, reference);
            }
        }
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        let mf = m as f64;
        let predicted = sigma_counts * 1e-6 / 50e-6 * (12.0 / (mf * (mf * mf - 1.0))).sqrt();
        println!("slope error rms {rms:.5} m/s, predicted {predicted:.5} m/s");
        assert!(
            (rms / predicted - 1.0).abs() < 0.1,
            "rms {rms}, predicted {predicted}"
        );
    }

    #[test]
    fn reset_restarts_from_the_next_sample() {
        let mut sg = SavitzkyGolay::new(cfg(5, 2, 0)).unwrap();
        for i in 0..10 {
            sg.push(bits(i * 1000));
        }
        sg.reset();
        assert_eq!(sg.push(bits(-5)), Derivatives::default());
        assert_eq!(sg.push(bits(-5)), Derivatives::default());
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
        assert_eq!(SavitzkyGolay::new(cfg(3, 3, 0)).err(), Some(SgError::Order));
        assert_eq!(SavitzkyGolay::new(cfg(5, 2, 5)).err(), Some(SgError::Lag));
        let mut c = cfg(5, 2, 0);
        c.sample_time_s = f32::NAN;
        assert_eq!(SavitzkyGolay::new(c).err(), Some(SgError::Scale));
        c.sample_time_s = 50e-6;
        c.m_per_count = 0.0;
        assert_eq!(SavitzkyGolay::new(c).err(), Some(SgError::Scale));
    }
}
