//! How sure one first moment is: the pixel noise of a frame, measured from the frame
//! itself, propagated through the moment.
//!
//! The moment is linear in the pixels, so its variance is exact given each pixel's
//! variance: Σ (xᵢ − c)² σᵢ² / S², plus the background's own error, which every pixel
//! shares. Each pixel's variance follows the camera's law σ² = a + b·I (read noise plus
//! shot noise), with a and b read off the frame: the white part of the variance (from
//! the second difference along a row, which smooth light hardly reaches) of the
//! window's pixels in bins of intensity.

use super::window::Roi;
use crate::image::{from_order_key, median, order_key, row_slice, Image};

/// Pixels read for the noise law at most: 8 bins of ~500.
const MAX_SAMPLES: usize = 4096;

/// Pixel variance σ² = a + b·I (counts², I in counts above zero).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseModel {
    /// Variance at zero intensity.
    pub a: f64,
    /// Variance per count.
    pub b: f64,
}

impl NoiseModel {
    /// The variance of a pixel reading `value` counts (in f32: the moment's noise sums
    /// it over every pixel of a window, in vector lanes).
    pub fn variance(&self, value: f32) -> f32 {
        let floor = self.a.max(1e-6) as f32;
        (self.a as f32 + self.b as f32 * value.max(0.0)).max(floor)
    }
}

/// The noise model of `img` over `window`: robust white-noise variances of its pixels
/// in intensity bins, and the line through them (flat if the bins cannot be told
/// apart).
pub fn measure(img: &Image, window: Roi) -> NoiseModel {
    // (local intensity, second difference along the row) for every pixel with all four
    // neighbours. The intensity is that of the pixels above and below: binning by the
    // pixel's own value would pick its noise (the brightest of a population are those
    // with noise up) and bias every bin's variance.
    // A few thousand pixels pin each bin's variance to a few per cent; a large window
    // is read at a stride (every k-th pixel in reading order, so rows do not align).
    let (inner_w, inner_h) = (window.w.saturating_sub(2), window.h.saturating_sub(2));
    let interior = inner_w * inner_h;
    let stride = interior.div_ceil(MAX_SAMPLES).max(1);
    // (the intensity's order key, the second difference): the bins below select on
    // integer keys.
    let mut samples: Vec<(u32, f32)> = Vec::with_capacity(interior / stride + 1);
    for k in (stride - 1..interior).step_by(stride) {
        let (r, c) = (window.y + 1 + k / inner_w, window.x + 1 + k % inner_w);
        let (l, m, rr) = (img[[r, c - 1]], img[[r, c]], img[[r, c + 1]]);
        let level = 0.5 * (img[[r - 1, c]] + img[[r + 1, c]]);
        samples.push((order_key(level), m - 0.5 * (l + rr)));
    }
    if samples.len() < 16 {
        return NoiseModel { a: 1.0, b: 0.0 };
    }
    // The white variance in intensity bins of equal count (the second difference of
    // white noise has variance 1.5 σ²; MAD → σ for a normal), then the least-squares
    // line through them: a feature may fill only a tenth of the window, so two halves
    // would both be dark.
    const BINS: usize = 8;
    let chunk = samples.len().div_ceil(BINS);
    // Each bin needs its members, not their order: partition at the bin edges
    // (selection, ~4n comparisons) instead of sorting (~13n).
    let mut rest = &mut samples[..];
    while rest.len() > chunk {
        rest.select_nth_unstable_by_key(chunk, |s| s.0);
        rest = &mut rest[chunk..];
    }
    let bins: Vec<(f64, f64)> = samples
        .chunks(chunk)
        .map(|part| {
            let mad = median(part.iter().map(|s| s.1.abs())) as f64;
            (
                median(part.iter().map(|s| from_order_key(s.0))) as f64,
                (1.4826 * mad).powi(2) / 1.5,
            )
        })
        .collect();
    let n = bins.len() as f64;
    let (mi, mv) = (
        bins.iter().map(|b| b.0).sum::<f64>() / n,
        bins.iter().map(|b| b.1).sum::<f64>() / n,
    );
    let sxx: f64 = bins.iter().map(|b| (b.0 - mi).powi(2)).sum();
    let sxy: f64 = bins.iter().map(|b| (b.0 - mi) * (b.1 - mv)).sum();
    let b = if sxx > 1.0 { (sxy / sxx).max(0.0) } else { 0.0 };
    let darkest = bins[0].1;
    NoiseModel {
        a: (mv - b * mi).max(0.25 * darkest).max(1e-6),
        b,
    }
}

/// 1σ (col, row) of the first moment `center` of `sign·(img − background)` over
/// `window` (total `signal`), given the pixel noise and the number of pixels the
/// background's median was taken from.
pub fn moment_sigma(
    img: &Image,
    noise: &NoiseModel,
    window: Roi,
    center: (f64, f64),
    signal: f64,
    background_samples: usize,
) -> (f64, f64) {
    if signal <= 0.0 {
        return (f64::INFINITY, f64::INFINITY);
    }
    let (mut vx, mut vy, mut var_sum) = (0.0, 0.0, 0.0);
    let first_dx = (window.x as f64 - center.0) as f32;
    for r in window.y..window.y + window.h {
        let dy = r as f64 - center.1;
        let row = row_slice(img, r);
        let (row_v, row_xv) = row_variance(&row[window.x..window.x + window.w], noise, first_dx);
        vx += row_xv as f64;
        vy += dy * dy * row_v as f64;
        var_sum += row_v as f64;
    }
    // Σ dx and Σ dy over the window: how far the background's error levers the moment.
    let offsets = |first: usize, len: usize, at: f64| {
        len as f64 * (first as f64 + (len as f64 - 1.0) / 2.0 - at)
    };
    let lever_x = window.h as f64 * offsets(window.x, window.w, center.0);
    let lever_y = window.w as f64 * offsets(window.y, window.h, center.1);
    // The median of n background pixels: variance π/2 · σ²/n, σ² of the darkest pixels.
    let n = (window.w * window.h) as f64;
    let var_background = std::f64::consts::FRAC_PI_2 * (var_sum / n).min(noise.a * 4.0)
        / background_samples.max(1) as f64;
    let s2 = signal * signal;
    (
        ((vx + lever_x * lever_x * var_background) / s2).sqrt(),
        ((vy + lever_y * lever_y * var_background) / s2).sqrt(),
    )
}

/// Σ σ² and Σ dx²·σ² over one row's `pixels`, the first `first_dx` from the moment:
/// eight running f32 sums per total (a row's few hundred terms) and one total per
/// pass, so the compiler keeps them in vector registers.
fn row_variance(pixels: &[f32], noise: &NoiseModel, first_dx: f32) -> (f32, f32) {
    const LANES: usize = 8;
    let variance = |p: f32| noise.variance(p);
    let chunks = pixels.chunks_exact(LANES);
    let mut v = [0.0f32; LANES];
    for chunk in chunks.clone() {
        for (acc, &p) in v.iter_mut().zip(chunk) {
            *acc += variance(p);
        }
    }
    let mut xv = [0.0f32; LANES];
    let mut dx: [f32; LANES] = std::array::from_fn(|l| first_dx + l as f32);
    for chunk in chunks.clone() {
        for ((acc, &p), d) in xv.iter_mut().zip(chunk).zip(dx.iter_mut()) {
            *acc += *d * *d * variance(p);
            *d += LANES as f32;
        }
    }
    let (mut sum_v, mut sum_xv) = (v.iter().sum::<f32>(), xv.iter().sum::<f32>());
    let first = pixels.len() - chunks.remainder().len();
    for (j, &p) in (first..).zip(chunks.remainder()) {
        let dx = first_dx + j as f32;
        sum_v += variance(p);
        sum_xv += dx * dx * variance(p);
    }
    (sum_v, sum_xv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal, Poisson};

    /// A bright disc on a dark field with Poisson + read noise.
    fn noisy_disc(seed: u64, gain: f64) -> Image {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let read = Normal::new(0.0, 2.0).unwrap();
        Image::from_shape_fn((80, 80), |(r, c)| {
            let d2 = (c as f64 - 40.3).powi(2) + (r as f64 - 39.6).powi(2);
            let mean_e = if d2 < 800.0 { 400.0 } else { 5.0 };
            let e = Poisson::new(mean_e).unwrap().sample(&mut rng);
            (gain * e + read.sample(&mut rng)) as f32
        })
    }

    #[test]
    fn the_noise_law_is_read_off_the_frame() {
        let window = Roi {
            x: 0,
            y: 0,
            w: 80,
            h: 80,
        };
        let model = measure(&noisy_disc(1, 0.5), window);
        // Shot noise: variance = gain · counts = 0.5 per count; read noise 4 counts².
        assert!((model.b - 0.5).abs() < 0.12, "{model:?}");
        assert!(model.a > 2.0 && model.a < 8.0, "{model:?}");
    }

    /// Over many noisy frames the moment scatters as much as the formula says.
    #[test]
    fn the_predicted_spread_matches_the_scatter_of_the_moment() {
        let window = Roi {
            x: 0,
            y: 0,
            w: 80,
            h: 80,
        };
        let mut xs = vec![];
        let mut predicted = vec![];
        for seed in 0..200 {
            let img = noisy_disc(seed, 0.5);
            let ring: Vec<f32> = (0..80).map(|c| img[[0, c]]).collect();
            let bg = median(ring.iter().copied());
            let (c, s) =
                super::super::window::signed_moment(&img, 1.0, bg, (0, 80), (0, 80)).unwrap();
            xs.push(c.0);
            let noise = measure(&img, window);
            predicted.push(moment_sigma(&img, &noise, window, c, s, ring.len()).0);
        }
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let scatter =
            (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (xs.len() - 1) as f64).sqrt();
        let said = predicted.iter().sum::<f64>() / predicted.len() as f64;
        assert!(
            (said / scatter - 1.0).abs() < 0.3,
            "predicted {said:.4} px against a scatter of {scatter:.4} px"
        );
    }
}
