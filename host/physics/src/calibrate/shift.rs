//! Where the feature is in a defocused frame: the first moment of the
//! background-removed intensity in a window that follows the feature.
//!
//! The full first moment (not a thresholded centroid) is what moves exactly with the
//! mean direction of the light that reaches the camera; what remains of its bias comes
//! from the pupil clipping the feature's spectrum, and [`super::model`] removes it.

use super::noise;
use super::window::{signed_moment, Polarity, Roi};
use crate::image::{median, row_slice, Image};

/// The feature's position in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Moment {
    /// First moment, (col, row) pixels.
    pub center_px: (f64, f64),
    /// Background-removed signal summed over the window.
    pub signal: f64,
    /// The final window.
    pub window: Roi,
    /// Whether the window had to be cut by the frame's edge.
    pub clipped: bool,
    /// 1σ of `center_px` from the frame's pixel noise (the frame's own noise law,
    /// propagated through the moment and its background), pixels; zero until
    /// [`Moment::with_pixel_noise`] measures it.
    pub sigma_px: (f64, f64),
    /// Pixels the background's median was taken from.
    pub background_pixels: usize,
}

impl Moment {
    /// The same moment with its 1σ from `img`'s own pixel noise (a measured frame; a
    /// model's noiseless image has none to measure).
    pub fn with_pixel_noise(mut self, img: &Image) -> Self {
        let model = noise::measure(img, self.window);
        self.sigma_px = noise::moment_sigma(
            img,
            &model,
            self.window,
            self.center_px,
            self.signal,
            self.background_pixels,
        );
        self
    }
}

/// Width of the band around the window that the background is taken from, pixels.
pub const RING_BAND: usize = 6;

/// Background: the median of a band around the window, and how many pixels it took.
fn ring_background(
    img: &Image,
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
    band: usize,
) -> (f32, usize) {
    let (h, w) = img.dim();
    let (bx0, by0) = (x0.saturating_sub(band), y0.saturating_sub(band));
    let (bx1, by1) = ((x1 + band).min(w), (y1 + band).min(h));
    let mut ring: Vec<f32> = Vec::with_capacity(2 * band * (bx1 - bx0 + by1 - by0));
    for r in by0..by1 {
        let row = row_slice(img, r);
        if r < y0 || r >= y1 {
            ring.extend_from_slice(&row[bx0..bx1]);
        } else {
            ring.extend_from_slice(&row[bx0..x0]);
            ring.extend_from_slice(&row[x1..bx1]);
        }
    }
    let n = ring.len();
    (median(ring), n)
}

/// The first moment of `polarity`-signed, background-removed intensity in a square
/// window of half-size `half` that is re-centred on the moment `iterations` times,
/// starting at `start` (col, row).
pub fn first_moment(
    img: &Image,
    polarity: Polarity,
    start: (f64, f64),
    half: usize,
    iterations: usize,
) -> Option<Moment> {
    let (h, w) = img.dim();
    let sign = if polarity == Polarity::Bright {
        1.0
    } else {
        -1.0
    };
    let mut center = start;
    let mut result: Option<Moment> = None;
    let mut last_window = None;
    for _ in 0..iterations.max(1) {
        let (cx, cy) = (center.0.round() as i64, center.1.round() as i64);
        // The same window gives the same moment: converged.
        if last_window == Some((cx, cy)) {
            break;
        }
        last_window = Some((cx, cy));
        let x0 = (cx - half as i64).max(0) as usize;
        let y0 = (cy - half as i64).max(0) as usize;
        let x1 = ((cx + half as i64 + 1).max(0) as usize).min(w);
        let y1 = ((cy + half as i64 + 1).max(0) as usize).min(h);
        if x1 <= x0 + 2 || y1 <= y0 + 2 {
            return None;
        }
        let clipped = cx - (half as i64) < 0
            || cy - (half as i64) < 0
            || cx + half as i64 + 1 > w as i64
            || cy + half as i64 + 1 > h as i64;
        let (bg, ring) = ring_background(img, x0, y0, x1, y1, RING_BAND);
        let (c, sw) = signed_moment(img, sign, bg, (x0, x1), (y0, y1))?;
        center = c;
        result = Some(Moment {
            center_px: center,
            signal: sw,
            window: Roi {
                x: x0,
                y: y0,
                w: x1 - x0,
                h: y1 - y0,
            },
            clipped,
            sigma_px: (0.0, 0.0),
            background_pixels: ring,
        });
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_displaced_blob_is_found_to_sub_pixel_precision_despite_background() {
        let (cx, cy) = (61.37, 40.81);
        let img = Image::from_shape_fn((100, 120), |(r, c)| {
            let d2 = (c as f64 - cx).powi(2) + (r as f64 - cy).powi(2);
            (50.0 + 300.0 * (-d2 / 30.0).exp()) as f32
        });
        let m = first_moment(&img, Polarity::Bright, (55.0, 45.0), 20, 3).unwrap();
        assert!(
            (m.center_px.0 - cx).abs() < 1e-3 && (m.center_px.1 - cy).abs() < 1e-3,
            "{m:?}"
        );
        assert!(!m.clipped);
    }

    #[test]
    fn a_window_at_the_edge_is_flagged() {
        let img = Image::from_shape_fn((50, 50), |(r, c)| if r < 4 && c < 4 { 100.0 } else { 0.0 });
        let m = first_moment(&img, Polarity::Bright, (2.0, 2.0), 10, 2).unwrap();
        assert!(m.clipped);
    }
}
