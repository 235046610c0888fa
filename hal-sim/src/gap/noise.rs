//! The noise a channel's analysis band lets through ([`super::unexplained`]'s floor): from
//! the data's high band ([`floor_from_data`]) and from the model's sensors
//! ([`floor_from_model`]).
//!
//! A channel's raw residual carries the sensors' noise in one of two shapes (in per-sample
//! variance per unit of normalised frequency ω): white, `b` — a force, pressure or position
//! reading's own noise — and, on the force channel, the position noise through the second
//! difference of `m·Δ²x`, `a·(2 − 2·cos ω)²`. Each white level is measured where the signal
//! is smooth and the noise is not: in the fourth difference of the reading itself
//! ([`white_sigma`]), the highest band there is; the levels are then carried through the
//! channel's own filter, `floor² = ∫|K(ω)|²·S(ω) dω/2π`. (Fitting both shapes to the
//! residual's spectrum just above the band does not work on the force channel: there the
//! second difference's noise is a hundred times the force sensors', and the white level
//! fitted beside it was noise of the fit, several newtons in the band.)

use crate::plant::model::MachineModel;

use super::band::Band;
use super::channel::ChannelId;
use super::data::Measured;
use super::filter::Kernel;

/// Points of the frequency grid the filter's response is integrated on.
const GRID: usize = 2048;

/// The channel's kernel.
fn kernel(band: &Band, ch: ChannelId) -> &Kernel {
    match ch {
        ChannelId::Force => &band.force,
        _ => &band.plain,
    }
}

/// The second difference's noise shape `(2 − 2·cos ω)²`.
fn blue(w: f64) -> f64 {
    let d = 2.0 - 2.0 * w.cos();
    d * d
}

/// `∫|K(ω)|²·shape(ω) dω/2π` over the kernel's response (symmetric taps: real).
fn through(k: &Kernel, shape: impl Fn(f64) -> f64) -> f64 {
    let taps = k.taps();
    let h = k.half() as f64;
    let mut sum = 0.0;
    for g in 0..GRID {
        let w = std::f64::consts::PI * (g as f64 + 0.5) / GRID as f64;
        let resp: f64 = taps
            .iter()
            .enumerate()
            .map(|(j, t)| t * (w * (j as f64 - h)).cos())
            .sum();
        sum += resp * resp * shape(w);
    }
    sum / GRID as f64
}

/// The floor `sqrt(b·∫|K|² + a·∫|K|²·blue)` of white level `b` and blue level `a`.
fn floor(k: &Kernel, white: f64, second_difference: f64) -> f64 {
    let mut var = white.max(0.0) * through(k, |_| 1.0);
    if second_difference > 0.0 {
        var += second_difference * through(k, blue);
    }
    var.max(0.0).sqrt()
}

/// The white noise of `signal` on the rows `mask` judges, robustly: its fourth difference
/// (`1, −4, 6, −4, 1`: variance 70·σ² of white noise, and nearly nothing of a signal that
/// is smooth over five rows) through the median absolute deviation (a step of the signal
/// in a few rows does not count), as a standard deviation.
pub fn white_sigma(signal: &[f64], mask: &[f64]) -> f64 {
    let mut d: Vec<f64> = signal
        .windows(5)
        .enumerate()
        .filter(|(i, _)| (*i..*i + 5).all(|k| mask.get(k).is_some_and(|m| *m > 0.0)))
        .map(|(_, w)| w[0] - 4.0 * w[1] + 6.0 * w[2] - 4.0 * w[3] + w[4])
        .collect();
    if d.len() < 16 {
        return 0.0;
    }
    d.sort_by(f64::total_cmp);
    let median = d[d.len() / 2];
    let mut dev: Vec<f64> = d.iter().map(|v| (v - median).abs()).collect();
    dev.sort_by(f64::total_cmp);
    1.4826 * dev[dev.len() / 2] / 70f64.sqrt()
}

/// The noise floor of channel `ch` from the data: module header. The force channel's two
/// sources are measured where they are white — the logged position's own noise, carried
/// through `m·Δ²x`, and the forces' in the slave's reading against the master's — the other
/// channels' in their raw residual `raw` (every row; pressure: A's rows then B's), where the
/// replay or prediction is smooth.
pub fn floor_from_data(
    data: &Measured,
    band: &Band,
    model: &MachineModel,
    ch: ChannelId,
    raw: &[f64],
) -> f64 {
    let n = data.len();
    let mask = band.mask(data, ch);
    match ch {
        ChannelId::Force => {
            // The forces' noise from the slave's against the master's (the sum's noise is
            // theirs together, and the command both follow, whose high band the piston
            // follows too, cancels there).
            let sx = white_sigma(&data.x_m, mask);
            let slave = super::residuals::channel_raw(data, model, ChannelId::SlaveForce)
                .unwrap_or_default();
            let sf = white_sigma(&slave, band.mask(data, ChannelId::SlaveForce));
            let m = model.piston.mass_kg;
            let dt2 = data.dt_s * data.dt_s;
            floor(kernel(band, ch), sf * sf, (m * sx / dt2).powi(2))
        }
        ChannelId::Pressure => {
            let (a, b) = raw.split_at(n.min(raw.len()));
            let (sa, sb) = (white_sigma(a, mask), white_sigma(b, mask));
            floor(kernel(band, ch), 0.5 * (sa * sa + sb * sb), 0.0)
        }
        ChannelId::SlaveForce | ChannelId::Encoder => {
            let s = white_sigma(raw, mask);
            floor(kernel(band, ch), s * s, 0.0)
        }
    }
}

/// The noise floor of channel `ch` the model's `[sensors]` noise would give: the current
/// sensors' per-phase noise as each section's force noise (`K_t·σ·√(2/3)` through the
/// Clarke transform), the encoders' as position noise (`λ·σ_codes/(2π·amplitude)`), the
/// pressure sensors' as it is.
pub fn floor_from_model(data: &Measured, band: &Band, model: &MachineModel, ch: ChannelId) -> f64 {
    let s = &model.sensors;
    let force = model.motor.force_constant_n_per_a * s.current.noise_a * (2.0f64 / 3.0).sqrt();
    let position = |e: &crate::plant::model::EncoderSensor| {
        model.encoder.period_m * e.noise_codes / (std::f64::consts::TAU * e.amplitude_codes)
    };
    let (xm, xs) = (position(&s.encoder_master), position(&s.encoder_slave));
    let k = kernel(band, ch);
    match ch {
        ChannelId::Force => {
            let m = model.piston.mass_kg;
            floor(
                k,
                2.0 * force * force,
                (m * xm / (data.dt_s * data.dt_s)).powi(2),
            )
        }
        ChannelId::SlaveForce => floor(k, 2.0 * force * force, 0.0),
        ChannelId::Encoder => floor(k, xm * xm + xs * xs, 0.0),
        ChannelId::Pressure => floor(k, s.pressure.noise_pa.powi(2), 0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_noise_through_a_kernel_is_its_taps_sum_of_squares() {
        let k = Kernel::new(super::super::filter::lowpass(300.0, 10_000.0));
        let want: f64 = k.taps().iter().map(|t| t * t).sum();
        assert!((through(&k, |_| 1.0) / want - 1.0).abs() < 1e-6);
        // The second difference of white noise has variance 6σ² (1, −2, 1).
        let one = Kernel::new(vec![1.0]);
        assert!((through(&one, blue) - 6.0).abs() < 1e-9);
    }

    #[test]
    fn the_fourth_difference_finds_white_noise_under_a_smooth_signal() {
        let mut state = 12345u64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        // σ = 3 (Box–Muller) on a slow sine of amplitude 500 sampled at 10 kHz.
        let s: Vec<f64> = (0..20_000)
            .map(|i| {
                let (u1, u2) = (uniform().max(1e-300), uniform());
                500.0 * (i as f64 * 1e-3).sin()
                    + 3.0 * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
            })
            .collect();
        let sigma = white_sigma(&s, &vec![1.0; s.len()]);
        assert!((sigma - 3.0).abs() < 0.15, "{sigma}");
    }
}
