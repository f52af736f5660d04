//! Finding the calibration feature: an isolated compact object in the focused
//! reference frame.

use crate::image::{median, Image};

pub use super::window::{Polarity, Roi};

/// The feature found in the reference frame.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Feature {
    /// Intensity-weighted centre, (col, row) pixels.
    pub center_px: (f64, f64),
    /// Pixels above half contrast.
    pub area_px: usize,
    /// Bounding box of those pixels.
    pub bbox: Roi,
    /// Bright or dark.
    pub polarity: Polarity,
    /// Background level (median of the frame or ROI).
    pub background: f32,
    /// Peak contrast above (or below) the background.
    pub contrast: f32,
}

/// Why no feature was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FeatureError {
    /// The frame is flat.
    #[error("the reference frame has no contrast (flat or all dark)")]
    NoContrast,
    /// Nothing compact stands out.
    #[error("no isolated compact feature found (largest object: {area} px); pass --roi X,Y,W,H around one")]
    NotFound {
        /// Area of the largest candidate.
        area: usize,
    },
    /// The feature is cut by the frame's edge.
    #[error(
        "the feature touches the edge of the frame at {bbox:?}; move the sample or pass --roi"
    )]
    AtEdge {
        /// Its bounding box.
        bbox: Roi,
    },
    /// The ROI is outside the frame.
    #[error("the ROI {0:?} is not inside the {1}x{2} frame")]
    BadRoi(Roi, usize, usize),
}

/// Find the feature in `reference`, inside `roi` if given.
pub fn find(reference: &Image, roi: Option<Roi>) -> Result<Feature, FeatureError> {
    let (h, w) = reference.dim();
    let roi = match roi {
        Some(r) if r.w > 0 && r.h > 0 && r.x + r.w <= w && r.y + r.h <= h => r,
        Some(r) => return Err(FeatureError::BadRoi(r, w, h)),
        None => Roi { x: 0, y: 0, w, h },
    };
    let view = reference.slice(ndarray::s![roi.y..roi.y + roi.h, roi.x..roi.x + roi.w]);
    let background = median(view.iter().copied());
    let (lo, hi) = view
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    let (up, down) = (hi - background, background - lo);
    if up.max(down) <= 1e-6 * background.abs().max(1.0) {
        return Err(FeatureError::NoContrast);
    }
    let polarity = if up >= down {
        Polarity::Bright
    } else {
        Polarity::Dark
    };
    let sign = if polarity == Polarity::Bright {
        1.0
    } else {
        -1.0
    };
    let contrast = up.max(down);
    let threshold = 0.5 * contrast;

    // Connected components (4-neighbour) of pixels beyond half contrast.
    let (rh, rw) = (roi.h, roi.w);
    let above = |r: usize, c: usize| sign * (view[[r, c]] - background) > threshold;
    let mut label = vec![0u32; rh * rw];
    let mut best: Option<(usize, Roi)> = None;
    let mut next_label = 1;
    let mut stack = vec![];
    for r0 in 0..rh {
        for c0 in 0..rw {
            if label[r0 * rw + c0] != 0 || !above(r0, c0) {
                continue;
            }
            let (mut area, mut bx0, mut by0, mut bx1, mut by1) = (0usize, c0, r0, c0, r0);
            label[r0 * rw + c0] = next_label;
            stack.push((r0, c0));
            while let Some((r, c)) = stack.pop() {
                area += 1;
                (bx0, by0, bx1, by1) = (bx0.min(c), by0.min(r), bx1.max(c), by1.max(r));
                let neighbours = [
                    (r.wrapping_sub(1), c),
                    (r + 1, c),
                    (r, c.wrapping_sub(1)),
                    (r, c + 1),
                ];
                for (nr, nc) in neighbours {
                    if nr < rh && nc < rw && label[nr * rw + nc] == 0 && above(nr, nc) {
                        label[nr * rw + nc] = next_label;
                        stack.push((nr, nc));
                    }
                }
            }
            next_label += 1;
            let bbox = Roi {
                x: roi.x + bx0,
                y: roi.y + by0,
                w: bx1 - bx0 + 1,
                h: by1 - by0 + 1,
            };
            if best.is_none_or(|(a, _)| area > a) {
                best = Some((area, bbox));
            }
        }
    }
    let Some((area, bbox)) = best else {
        return Err(FeatureError::NotFound { area: 0 });
    };
    // Compact: a few pixels at least, and a small part of the searched area.
    if area < 4 || area * 4 > rw * rh {
        return Err(FeatureError::NotFound { area });
    }
    if bbox.x == 0 || bbox.y == 0 || bbox.x + bbox.w >= w || bbox.y + bbox.h >= h {
        return Err(FeatureError::AtEdge { bbox });
    }
    // Centroid of the background-removed signal over the bounding box plus a margin.
    let margin = bbox.w.max(bbox.h) / 2 + 2;
    let (x0, y0) = (bbox.x.saturating_sub(margin), bbox.y.saturating_sub(margin));
    let (x1, y1) = (
        (bbox.x + bbox.w + margin).min(w),
        (bbox.y + bbox.h + margin).min(h),
    );
    let (center_px, _) =
        super::window::signed_moment(reference, sign, background, (x0, x1), (y0, y1))
            .ok_or(FeatureError::NotFound { area })?;
    Ok(Feature {
        center_px,
        area_px: area,
        bbox,
        polarity,
        background,
        contrast,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame_with_square(w: usize, x: usize, y: usize, side: usize, bright: bool) -> Image {
        let (bg, fg) = if bright { (10.0, 200.0) } else { (200.0, 20.0) };
        Image::from_shape_fn((w, w), |(r, c)| {
            if r >= y && r < y + side && c >= x && c < x + side {
                fg
            } else {
                bg
            }
        })
    }

    #[test]
    fn finds_bright_and_dark_squares_at_their_centre() {
        for bright in [true, false] {
            let img = frame_with_square(100, 30, 50, 11, bright);
            let f = find(&img, None).unwrap();
            assert_eq!(
                f.polarity,
                if bright {
                    Polarity::Bright
                } else {
                    Polarity::Dark
                }
            );
            assert!(
                (f.center_px.0 - 35.0).abs() < 1e-9 && (f.center_px.1 - 55.0).abs() < 1e-9,
                "{f:?}"
            );
            assert_eq!(f.area_px, 121);
            assert_eq!(
                f.bbox,
                Roi {
                    x: 30,
                    y: 50,
                    w: 11,
                    h: 11
                }
            );
        }
    }

    #[test]
    fn refuses_flat_frames_edges_and_huge_objects() {
        assert_eq!(
            find(&Image::from_elem((50, 50), 3.0), None),
            Err(FeatureError::NoContrast)
        );
        assert!(matches!(
            find(&frame_with_square(100, 0, 40, 10, true), None),
            Err(FeatureError::AtEdge { .. })
        ));
        assert!(matches!(
            find(&frame_with_square(100, 10, 10, 70, true), None),
            Err(FeatureError::NotFound { .. })
        ));
    }

    #[test]
    fn an_roi_picks_one_of_two_features() {
        let mut img = frame_with_square(120, 20, 20, 8, true);
        for r in 80..90 {
            for c in 80..90 {
                img[[r, c]] = 200.0;
            }
        }
        let f = find(
            &img,
            Some(Roi {
                x: 60,
                y: 60,
                w: 50,
                h: 50,
            }),
        )
        .unwrap();
        assert!((f.center_px.0 - 84.5).abs() < 1e-9);
        assert!(find(
            &img,
            Some(Roi {
                x: 100,
                y: 100,
                w: 50,
                h: 50
            })
        )
        .is_err());
    }
}
