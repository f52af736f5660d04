//! The measuring primitives the feature finder and the shift estimator share: a pixel
//! rectangle, the feature's polarity, and the signed first moment over a window.

use crate::image::Image;

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
        let (mut row_x, mut row_w) = (0.0f32, 0.0f32);
        for (c, &p) in (x0..x1).zip(img.row(r).slice(ndarray::s![x0..x1]).iter()) {
            let v = sign * (p - background);
            row_x += v * (c - x0) as f32;
            row_w += v;
        }
        sx += row_x as f64 + row_w as f64 * x0 as f64;
        sy += row_w as f64 * r as f64;
        sw += row_w as f64;
    }
    (sw > 0.0).then(|| ((sx / sw, sy / sw), sw))
}
