//! The seeded noise the sensors draw from, in the simulated board, the synthetic runs of the
//! model-gap workflow and the tests that roughen a log.
//!
//! Noise is cheap and deterministic: a ChaCha8 stream seeded per run, cut into 12-bit
//! indices into a 4096-entry table of the standard normal's quantiles (tails clipped at
//! ±3.5 σ). Five samples per 64-bit draw, no transcendental function per sample.

use std::sync::OnceLock;

use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Entries of the normal-quantile table (12 bits).
const TABLE_BITS: u32 = 12;
const TABLE_LEN: usize = 1 << TABLE_BITS;

fn normal_table() -> &'static [f64; TABLE_LEN] {
    static TABLE: OnceLock<[f64; TABLE_LEN]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = [0.0; TABLE_LEN];
        for (i, v) in t.iter_mut().enumerate() {
            *v = inverse_normal_cdf((i as f64 + 0.5) / TABLE_LEN as f64);
        }
        // Remove the tiny residual mean and scale to unit variance exactly.
        let n = TABLE_LEN as f64;
        let mean = t.iter().sum::<f64>() / n;
        let var = t.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        let k = 1.0 / var.sqrt();
        for v in &mut t {
            *v = (*v - mean) * k;
        }
        t
    })
}

/// Φ⁻¹(p) for p in (0, 1) (Acklam's rational approximation, relative error < 1.2e-9).
pub fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let p = p.clamp(1e-300, 1.0 - 1e-16);
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// Seeded standard-normal noise (see the module header).
#[derive(Clone, Debug)]
pub struct Noise {
    rng: ChaCha8Rng,
    bits: u64,
    left: u32,
    table: &'static [f64; TABLE_LEN],
}

impl Noise {
    /// A noise stream for `seed`.
    pub fn new(seed: u64) -> Self {
        Noise {
            rng: ChaCha8Rng::seed_from_u64(seed),
            bits: 0,
            left: 0,
            table: normal_table(),
        }
    }

    /// The next standard-normal sample.
    #[inline]
    pub fn normal(&mut self) -> f64 {
        if self.left == 0 {
            self.bits = self.rng.next_u64();
            self.left = 64 / TABLE_BITS;
        }
        let i = (self.bits as usize) & (TABLE_LEN - 1);
        self.bits >>= TABLE_BITS;
        self.left -= 1;
        self.table[i]
    }

    /// `sigma` times the next sample (no draw when `sigma` is zero, so a noiseless sensor
    /// leaves the stream of the others unchanged).
    #[inline]
    pub fn scaled(&mut self, sigma: f64) -> f64 {
        if sigma == 0.0 {
            0.0
        } else {
            sigma * self.normal()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_standard_normal_and_seeded() {
        let mut n = Noise::new(7);
        let xs: Vec<f64> = (0..200_000).map(|_| n.normal()).collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        assert!(
            mean.abs() < 0.01 && (var - 1.0).abs() < 0.01,
            "{mean} {var}"
        );
        let within_1 = xs.iter().filter(|x| x.abs() < 1.0).count() as f64 / xs.len() as f64;
        assert!((within_1 - 0.6827).abs() < 0.005);
        let mut again = Noise::new(7);
        assert!(xs.iter().take(100).all(|&x| x == again.normal()));
        assert!((inverse_normal_cdf(0.975) - 1.959_964).abs() < 1e-6);
    }
}
