//! Colour (Bayer) sensors: one colour channel out of the raw mosaic, as pure functions
//! over arrays. Two ways, both kept honest about what was measured:
//!
//! * [`subsample`]: the channel's own pixels, at their native positions, one value per
//!   2 × 2 cell (the two green pixels of a cell averaged): half the size, twice the
//!   pixel pitch. Nothing is interpolated.
//! * [`demosaic`]: the channel at every pixel, bilinear from its nearest sites
//!   (normalised convolution, so the borders need no special case): full size, the
//!   sensor's pitch, but the other channels' pixels are interpolated, not measured.

use ndarray::{Array2, ArrayView2};
use serde::{Deserialize, Serialize};

/// The colour filter of the 2 × 2 cell at the image's top-left corner, row by row.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum BayerPattern {
    /// R G / G B.
    #[serde(rename = "RGGB")]
    Rggb,
    /// G R / B G.
    #[serde(rename = "GRBG")]
    Grbg,
    /// G B / R G.
    #[serde(rename = "GBRG")]
    Gbrg,
    /// B G / G R.
    #[serde(rename = "BGGR")]
    Bggr,
}

/// A colour channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum BayerChannel {
    /// Red.
    R,
    /// Green.
    G,
    /// Blue.
    B,
}

impl BayerPattern {
    /// The filter at (row, col) of the image.
    pub fn filter(self, row: usize, col: usize) -> BayerChannel {
        use BayerChannel::*;
        let cell = match self {
            Self::Rggb => [[R, G], [G, B]],
            Self::Grbg => [[G, R], [B, G]],
            Self::Gbrg => [[G, B], [R, G]],
            Self::Bggr => [[B, G], [G, R]],
        };
        cell[row % 2][col % 2]
    }
}

/// The channel's pixels, one value per 2 × 2 cell (the mean of the channel's sites in
/// the cell: one for red and blue, two for green). A trailing odd row or column (half
/// a cell) is left out.
pub fn subsample(
    raw: ArrayView2<'_, f32>,
    pattern: BayerPattern,
    channel: BayerChannel,
) -> Array2<f32> {
    let (h, w) = raw.dim();
    let sites: Vec<(usize, usize)> = [(0, 0), (0, 1), (1, 0), (1, 1)]
        .into_iter()
        .filter(|&(r, c)| pattern.filter(r, c) == channel)
        .collect();
    let n = sites.len() as f32;
    Array2::from_shape_fn((h / 2, w / 2), |(i, j)| {
        sites
            .iter()
            .map(|&(r, c)| raw[[2 * i + r, 2 * j + c]])
            .sum::<f32>()
            / n
    })
}

/// The channel at every pixel: its own value where the filter is that channel, else
/// the bilinear interpolation of its nearest sites (weights 1/4 … 1 by distance,
/// normalised over the sites that exist, so borders take the sites they have).
pub fn demosaic(
    raw: ArrayView2<'_, f32>,
    pattern: BayerPattern,
    channel: BayerChannel,
) -> Array2<f32> {
    let (h, w) = raw.dim();
    // Weights over the 3 × 3 neighbourhood, counted only where the filter is the
    // channel: two orthogonal neighbours (½ each) or four diagonal ones (¼ each) for
    // red and blue, four orthogonal ones for green; exact for a linear field.
    const KERNEL: [[f32; 3]; 3] = [[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]];
    Array2::from_shape_fn((h, w), |(r, c)| {
        if pattern.filter(r, c) == channel {
            return raw[[r, c]];
        }
        let (mut sum, mut weight) = (0.0f32, 0.0f32);
        for (dr, row) in KERNEL.iter().enumerate() {
            for (dc, &k) in row.iter().enumerate() {
                let (rr, cc) = (r + dr, c + dc);
                if rr < 1 || cc < 1 || rr > h || cc > w {
                    continue;
                }
                let (rr, cc) = (rr - 1, cc - 1);
                if pattern.filter(rr, cc) == channel {
                    sum += k * raw[[rr, cc]];
                    weight += k;
                }
            }
        }
        if weight > 0.0 {
            sum / weight
        } else {
            0.0
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mosaic whose red, green and blue sites hold `red(r, c)`, `green(r, c)`,
    /// `blue(r, c)`.
    fn mosaic(
        pattern: BayerPattern,
        (h, w): (usize, usize),
        f: impl Fn(BayerChannel, usize, usize) -> f32,
    ) -> Array2<f32> {
        Array2::from_shape_fn((h, w), |(r, c)| f(pattern.filter(r, c), r, c))
    }

    const PATTERNS: [BayerPattern; 4] = [
        BayerPattern::Rggb,
        BayerPattern::Grbg,
        BayerPattern::Gbrg,
        BayerPattern::Bggr,
    ];

    #[test]
    fn every_cell_has_one_red_two_green_one_blue() {
        for p in PATTERNS {
            let count = |ch| {
                [(0, 0), (0, 1), (1, 0), (1, 1)]
                    .into_iter()
                    .filter(|&(r, c)| p.filter(r, c) == ch)
                    .count()
            };
            assert_eq!(
                (
                    count(BayerChannel::R),
                    count(BayerChannel::G),
                    count(BayerChannel::B)
                ),
                (1, 2, 1),
                "{p:?}"
            );
        }
    }

    #[test]
    fn subsampling_takes_exactly_the_channels_own_pixels() {
        for p in PATTERNS {
            // Each site holds a code of its channel and position: nothing else may leak.
            let raw = mosaic(p, (6, 8), |ch, r, c| match ch {
                BayerChannel::R => 1000.0 + (r / 2 * 10 + c / 2) as f32,
                BayerChannel::G => 2000.0 + (r * 10 + c) as f32,
                BayerChannel::B => 3000.0 + (r / 2 * 10 + c / 2) as f32,
            });
            let red = subsample(raw.view(), p, BayerChannel::R);
            let blue = subsample(raw.view(), p, BayerChannel::B);
            let green = subsample(raw.view(), p, BayerChannel::G);
            assert_eq!(red.dim(), (3, 4));
            for ((i, j), &v) in red.indexed_iter() {
                assert_eq!(v, 1000.0 + (i * 10 + j) as f32, "{p:?}");
                assert_eq!(blue[[i, j]], 3000.0 + (i * 10 + j) as f32, "{p:?}");
                // The two green sites of cell (i, j), averaged.
                let sites: Vec<f32> = [(0, 0), (0, 1), (1, 0), (1, 1)]
                    .into_iter()
                    .filter(|&(r, c)| p.filter(r, c) == BayerChannel::G)
                    .map(|(r, c)| 2000.0 + ((2 * i + r) * 10 + 2 * j + c) as f32)
                    .collect();
                assert_eq!(green[[i, j]], (sites[0] + sites[1]) / 2.0, "{p:?}");
            }
        }
    }

    #[test]
    fn demosaicing_keeps_the_sites_and_interpolates_a_plane_exactly_inside() {
        for p in PATTERNS {
            for ch in [BayerChannel::R, BayerChannel::G, BayerChannel::B] {
                // The channel sees a plane; the others something unrelated.
                let plane = |r: usize, c: usize| 100.0 + 3.0 * r as f32 + 7.0 * c as f32;
                let raw = mosaic(
                    p,
                    (10, 12),
                    |f, r, c| if f == ch { plane(r, c) } else { -5000.0 },
                );
                let out = demosaic(raw.view(), p, ch);
                assert_eq!(out.dim(), (10, 12));
                for ((r, c), &v) in out.indexed_iter() {
                    if r == 0 || c == 0 || r == 9 || c == 11 {
                        // Borders: a one-sided average of true values, never the others'.
                        assert!(v > 0.0, "{p:?} {ch:?} ({r}, {c}): {v}");
                        continue;
                    }
                    assert!(
                        (v - plane(r, c)).abs() < 1e-3,
                        "{p:?} {ch:?} ({r}, {c}): {v}"
                    );
                }
            }
        }
    }
}
