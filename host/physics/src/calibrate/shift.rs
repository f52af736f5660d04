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

/// Background: the median of a band around the window (within `limits`), and how many
/// pixels it took.
fn ring_background(
    img: &Image,
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
    band: usize,
    limits: [usize; 4],
) -> (f32, usize) {
    let [lx0, ly0, lx1, ly1] = limits;
    let (bx0, by0) = (
        x0.saturating_sub(band).max(lx0),
        y0.saturating_sub(band).max(ly0),
    );
    let (bx1, by1) = ((x1 + band).min(lx1), (y1 + band).min(ly1));
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

/// The pixels a moment may use, [x0, x1) × [y0, y1) in the image's pixels: the
/// frame's own, which a model's larger grid must respect to see the frame's cut.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bounds {
    pub x0: i64,
    pub y0: i64,
    pub x1: i64,
    pub y1: i64,
}

impl Bounds {
    /// All of `img`.
    pub fn whole(img: &Image) -> Self {
        let (h, w) = img.dim();
        Self {
            x0: 0,
            y0: 0,
            x1: w as i64,
            y1: h as i64,
        }
    }

    /// Moved by (dx, dy) pixels.
    pub fn shifted(self, dx: i64, dy: i64) -> Self {
        Self {
            x0: self.x0 + dx,
            y0: self.y0 + dy,
            x1: self.x1 + dx,
            y1: self.y1 + dy,
        }
    }
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
    first_moment_within(img, Bounds::whole(img), polarity, start, half, iterations)
}

/// [`first_moment`] using only the pixels within `bounds` (and the image): the window
/// and its background band are cut there, and the moment says so (`clipped`).
pub fn first_moment_within(
    img: &Image,
    bounds: Bounds,
    polarity: Polarity,
    start: (f64, f64),
    half: usize,
    iterations: usize,
) -> Option<Moment> {
    let (h, w) = img.dim();
    let clamp = |v: i64, hi: usize| v.clamp(0, hi as i64) as usize;
    let limits = [
        clamp(bounds.x0, w),
        clamp(bounds.y0, h),
        clamp(bounds.x1, w),
        clamp(bounds.y1, h),
    ];
    let [lx0, ly0, lx1, ly1] = limits.map(|v| v as i64);
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
        let x0 = (cx - half as i64).clamp(lx0, lx1) as usize;
        let y0 = (cy - half as i64).clamp(ly0, ly1) as usize;
        let x1 = (cx + half as i64 + 1).clamp(lx0, lx1) as usize;
        let y1 = (cy + half as i64 + 1).clamp(ly0, ly1) as usize;
        if x1 <= x0 + 2 || y1 <= y0 + 2 {
            return None;
        }
        let clipped = cx - (half as i64) < lx0
            || cy - (half as i64) < ly0
            || cx + half as i64 + 1 > lx1
            || cy + half as i64 + 1 > ly1;
        let (bg, ring) = ring_background(img, x0, y0, x1, y1, RING_BAND, limits);
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

    /// Bounds inside a larger image cut the window and its background band exactly as
    /// the image's own edge would: the model's grid, larger than the frame, sees the
    /// frame's cut.
    #[test]
    fn bounds_cut_as_the_frame_edge_cuts() {
        let blob = |(r, c): (usize, usize)| {
            let d2 = (c as f64 - 33.0).powi(2) + (r as f64 - 30.0).powi(2);
            (20.0 + 300.0 * (-d2 / 40.0).exp() + ((r * 7 + c * 3) % 5) as f64) as f32
        };
        let frame = Image::from_shape_fn((60, 40), blob);
        let larger = Image::from_shape_fn((60, 90), blob);
        let bounds = Bounds {
            x0: 0,
            y0: 0,
            x1: 40,
            y1: 60,
        };
        let a = first_moment(&frame, Polarity::Bright, (31.0, 30.0), 12, 3).unwrap();
        let b =
            first_moment_within(&larger, bounds, Polarity::Bright, (31.0, 30.0), 12, 3).unwrap();
        assert!(a.clipped && b.clipped);
        assert_eq!(
            (a.window, a.background_pixels),
            (b.window, b.background_pixels)
        );
        assert!(
            (a.center_px.0 - b.center_px.0).abs() < 1e-9
                && (a.center_px.1 - b.center_px.1).abs() < 1e-9
        );
        // Without the bounds the larger image's window is whole, and elsewhere.
        let c = first_moment(&larger, Polarity::Bright, (31.0, 30.0), 12, 3).unwrap();
        assert!(!c.clipped && (c.center_px.0 - b.center_px.0).abs() > 0.1);
    }
}
