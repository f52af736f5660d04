//! The measuring primitives the feature finder and the shift estimator share: a pixel
//! rectangle, the feature's polarity, and the signed first moment over a window.

use crate::image::{row_slice, Image};

/// A rectangle of pixels: columns `x .. x + w`, rows `y .. y + h`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Roi {
    /// First column.
    pub x: usize,
    /// First row.
    pub y: usize,
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
}

/// Whether the feature is brighter or darker than its surroundings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    /// A bright object on a dark field (a pinhole, a hole in a mask).
    Bright,
    /// A dark object on a bright field (a bead, a particle).
    Dark,
}

/// First moment (col, row) and total of `sign·(img − background)` over rows `y0..y1`
/// and columns `x0..x1`; `None` if the signal does not sum to a positive value.
pub fn signed_moment(
    img: &Image,
    sign: f32,
    background: f32,
    (x0, x1): (usize, usize),
    (y0, y1): (usize, usize),
) -> Option<((f64, f64), f64)> {
    let (mut sx, mut sy, mut sw) = (0.0f64, 0.0f64, 0.0f64);
    for r in y0..y1 {
        // Per row in f32 (a row's few hundred terms), then accumulated in f64.
        let (row_w, row_x) = row_moment(&row_slice(img, r)[x0..x1], sign, background);
        sx += row_x as f64 + row_w as f64 * x0 as f64;
        sy += row_w as f64 * r as f64;
        sw += row_w as f64;
    }
    (sw > 0.0).then(|| ((sx / sw, sy / sw), sw))
}

/// Σ v and Σ j·v over `pixels` (j = 0, 1, …), v = sign·(p − background). Eight
/// running sums per total, one total per pass: so the compiler keeps each in vector
/// registers (it may not reorder a single float sum, and pairs two sums in one loop
/// badly).
fn row_moment(pixels: &[f32], sign: f32, background: f32) -> (f32, f32) {
    const LANES: usize = 8;
    let chunks = pixels.chunks_exact(LANES);
    let mut w = [0.0f32; LANES];
    for chunk in chunks.clone() {
        for (acc, &p) in w.iter_mut().zip(chunk) {
            *acc += p - background;
        }
    }
    let mut x = [0.0f32; LANES];
    let mut index: [f32; LANES] = std::array::from_fn(|l| l as f32);
    for chunk in chunks.clone() {
        for ((acc, &p), j) in x.iter_mut().zip(chunk).zip(index.iter_mut()) {
            *acc += (p - background) * *j;
            *j += LANES as f32;
        }
    }
    let (mut sum_w, mut sum_x) = (w.iter().sum::<f32>(), x.iter().sum::<f32>());
    let first = pixels.len() - chunks.remainder().len();
    for (j, &p) in (first..).zip(chunks.remainder()) {
        sum_w += p - background;
        sum_x += (p - background) * j as f32;
    }
    (sign * sum_w, sign * sum_x)
}
