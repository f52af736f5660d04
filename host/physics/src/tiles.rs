//! Full field of view: a frame too large (or not square) for one reconstruction is cut
//! into overlapping square tiles. Each tile sees the LEDs from its own position, so it
//! gets its own wave vectors (taken at its centre); tiles are reconstructed on their
//! own and blended back into one image.
//!
//! Blending: each tile's object is known only up to a global phase, so before it is
//! added it is rotated onto the tiles already placed (least squares over the overlap);
//! then tiles are weighted by a raised cosine that falls off across the overlap, so
//! seams get no hard edge and each pixel is dominated by the tile that sees it from
//! furthest inside.

use ndarray::Array2;
use rustfft::num_complex::Complex32;

use crate::optics::{LedGeometry, System};

/// How far, in phase at a tile's edge, any LED's spherical wave may depart from the one
/// curvature the tile is reconstructed with (the axial LED's, see
/// [`crate::reconstruct::Epry::apply_illumination_curvature`]), rad.
pub const CURVATURE_TOLERANCE_RAD: f64 = 0.25;

/// Automatic tiles are never larger than this (memory and parallel tiles), pixels.
pub const MAX_AUTO_TILE: usize = 512;

/// Nor smaller than this (the overlap and free border need room), pixels.
pub const MIN_AUTO_TILE: usize = 64;

/// The tile side, camera pixels, chosen from the physics: an LED at angle θ lights the
/// sample with a spherical wave whose curvature is cos³θ/h along the radius (cosθ/h
/// across it), while a tile is reconstructed with one curvature, 1/h. At a distance a
/// from the tile's centre the steepest LED's wave departs from it by
/// π·a²·(1 − cos³θ)/(λ·h); the tile is as large as keeps that within
/// [`CURVATURE_TOLERANCE_RAD`], in multiples of 32 pixels between [`MIN_AUTO_TILE`]
/// and [`MAX_AUTO_TILE`]. The same rule places where the bright-field edge moves
/// across a tile: the common curvature is the local change of every LED's angle, so
/// only the anisotropic remainder is left unmodelled.
pub fn auto_tile_side(system: &System, geometry: &LedGeometry) -> usize {
    let h = geometry.height_mm * 1e3;
    let worst = geometry
        .leds()
        .into_iter()
        .map(|led| {
            let (x, y, lh) = geometry.led_position_3d_mm(led);
            let cos = lh / x.hypot(y).hypot(lh);
            1.0 - cos.powi(3)
        })
        .fold(0.0, f64::max);
    let side_um = if worst > 0.0 && h > 0.0 {
        2.0 * (CURVATURE_TOLERANCE_RAD * system.wavelength_um * h / (std::f64::consts::PI * worst))
            .sqrt()
    } else {
        f64::INFINITY
    };
    let side = (side_um / system.sample_pixel_um()).min(MAX_AUTO_TILE as f64);
    ((side as usize) / 32 * 32).clamp(MIN_AUTO_TILE, MAX_AUTO_TILE)
}

/// One tile of a camera frame, camera pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Tile {
    /// First column.
    pub x0: usize,
    /// First row.
    pub y0: usize,
    /// Side.
    pub size: usize,
}

impl Tile {
    /// The border (left, right, top, bottom, camera pixels) to leave unconstrained: `free`
    /// on the sides that face another tile, none on the frame's own edges.
    pub fn free_border(&self, width: usize, height: usize, free: usize) -> [usize; 4] {
        [
            if self.x0 > 0 { free } else { 0 },
            if self.x0 + self.size < width { free } else { 0 },
            if self.y0 > 0 { free } else { 0 },
            if self.y0 + self.size < height {
                free
            } else {
                0
            },
        ]
    }

    /// Sample-plane position of the tile's centre pixel (size/2, size/2), µm, for a
    /// `width × height` frame whose optical axis is at (width/2, height/2) and whose
    /// pixels are `pixel_um` in the sample plane.
    pub fn centre_um(&self, width: usize, height: usize, pixel_um: f64) -> (f64, f64) {
        let cx = (self.x0 + self.size / 2) as f64 - (width / 2) as f64;
        let cy = (self.y0 + self.size / 2) as f64 - (height / 2) as f64;
        (cx * pixel_um, cy * pixel_um)
    }
}

/// Tiles of side `tile` (at most the frame's shorter side) covering a `width × height`
/// frame, neighbours overlapping by at least `overlap` pixels, evenly spread so that
/// the last one ends at the frame's edge. Row-major order.
pub fn plan(width: usize, height: usize, tile: usize, overlap: usize) -> Vec<Tile> {
    let size = tile.min(width).min(height).max(1);
    let overlap = overlap.min(size / 2);
    let starts = |len: usize| -> Vec<usize> {
        if len <= size {
            return vec![0];
        }
        let step = size - overlap;
        let count = (len - size).div_ceil(step) + 1;
        // Spread the starts evenly over [0, len − size].
        (0..count)
            .map(|i| ((len - size) as f64 * i as f64 / (count - 1) as f64).round() as usize)
            .collect()
    };
    let (xs, ys) = (starts(width), starts(height));
    ys.iter()
        .flat_map(|&y0| xs.iter().map(move |&x0| Tile { x0, y0, size }))
        .collect()
}

/// A tile's blending weight along one axis: nothing in the unblended border of a side
/// that faces another tile (its values nothing constrained), then a sin² ramp up to
/// the end of the overlap, full weight beyond; a side that faces no tile keeps full
/// weight to its edge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Taper {
    /// The unblended border, pixels.
    pub free: usize,
    /// The ramp's length, pixels (at least 1).
    pub ramp: usize,
}

impl Taper {
    /// The weight of pixel `i` of `len`, its low side facing a tile when `low_inner`,
    /// its high side when `high_inner`.
    pub fn weight(&self, i: usize, len: usize, low_inner: bool, high_inner: bool) -> f32 {
        let side = |d: usize, inner: bool| -> f32 {
            if !inner || d >= self.free + self.ramp {
                1.0
            } else if d < self.free {
                0.0
            } else {
                let t = (d - self.free) as f32 + 0.5;
                (t / self.ramp as f32 * std::f32::consts::FRAC_PI_2)
                    .sin()
                    .powi(2)
            }
        };
        side(i, low_inner) * side(len - 1 - i, high_inner)
    }
}

/// Blends tile reconstructions (on the HR grid, `upsample` × camera pixels) into one.
pub struct Mosaic {
    upsample: usize,
    width: usize,
    height: usize,
    overlap_hr: usize,
    unblended_hr: usize,
    sum: Array2<Complex32>,
    weight: Array2<f32>,
}

impl Mosaic {
    /// An empty mosaic for a `width × height` camera frame; `overlap` and the border
    /// `unblended` that gets no weight (at least the tiles' unconstrained border) in
    /// camera pixels (`unblended` < `overlap` / 2).
    pub fn new(
        width: usize,
        height: usize,
        upsample: usize,
        overlap: usize,
        unblended: usize,
    ) -> Self {
        let u = upsample.max(1);
        Self {
            upsample: u,
            width,
            height,
            overlap_hr: overlap * u,
            unblended_hr: unblended * u,
            sum: Array2::zeros((height * u, width * u)),
            weight: Array2::zeros((height * u, width * u)),
        }
    }

    /// Add the HR object of `tile`, rotated onto what is already placed.
    pub fn add(&mut self, tile: &Tile, object: &Array2<Complex32>) {
        let faces = tile.free_border(self.width, self.height, 1).map(|b| b > 0);
        self.add_at(
            tile.x0 * self.upsample,
            tile.y0 * self.upsample,
            faces,
            object.view(),
        );
    }

    /// Add `object` with its first pixel at HR (`x0`, `y0`), rotated onto what is
    /// already placed; `faces` (left, right, top, bottom) says which sides overlap a
    /// neighbour (those get the unblended border and the ramp). The part outside the
    /// mosaic is dropped.
    pub fn add_at(
        &mut self,
        x0: usize,
        y0: usize,
        faces: [bool; 4],
        object: ndarray::ArrayView2<'_, Complex32>,
    ) {
        let (full_h, full_w) = self.sum.dim();
        let (h, w) = object.dim();
        let [left, right, top, bottom] = faces.map(usize::from);
        let (h_in, w_in) = (
            h.min(full_h.saturating_sub(y0)),
            w.min(full_w.saturating_sub(x0)),
        );
        let taper = Taper {
            free: self.unblended_hr,
            ramp: self.overlap_hr.saturating_sub(2 * self.unblended_hr).max(1),
        };
        let taper =
            |i: usize, len: usize, low: usize, high: usize| taper.weight(i, len, low > 0, high > 0);
        // Global phase: c = Σ a·conj(t)·(blended so far) over the overlap, weighted by
        // where both count: the tile's own weight (zero in its free border, whose
        // values nothing constrained, rising over the ramp) times the weight placed.
        let mut c = rustfft::num_complex::Complex64::default();
        for r in 0..h_in {
            for col in 0..w_in {
                let wsum = self.weight[[y0 + r, x0 + col]];
                let a = taper(r, h, top, bottom) * taper(col, w, left, right) * wsum;
                if a > 0.0 {
                    let placed = self.sum[[y0 + r, x0 + col]] / wsum;
                    let p = object[[r, col]].conj() * placed * a;
                    c += rustfft::num_complex::Complex64::new(p.re as f64, p.im as f64);
                }
            }
        }
        let rotate = if c.norm() > 0.0 {
            Complex32::new((c.re / c.norm()) as f32, (c.im / c.norm()) as f32)
        } else {
            Complex32::new(1.0, 0.0)
        };
        for r in 0..h_in {
            for col in 0..w_in {
                let wt = taper(r, h, top, bottom) * taper(col, w, left, right);
                self.sum[[y0 + r, x0 + col]] += object[[r, col]] * rotate * wt;
                self.weight[[y0 + r, x0 + col]] += wt;
            }
        }
    }

    /// The blended object and where any tile gave it weight.
    pub fn finish_with_coverage(self) -> (Array2<Complex32>, Array2<bool>) {
        let covered = self.weight.mapv(|w| w > 0.0);
        (self.finish(), covered)
    }

    /// The blended object (zero where no tile reached).
    pub fn finish(self) -> Array2<Complex32> {
        let mut out = self.sum;
        for (v, &w) in out.iter_mut().zip(self.weight.iter()) {
            *v = if w > 0.0 {
                *v / w
            } else {
                Complex32::default()
            };
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_frame_with_the_overlap_asked_for() {
        for (w, h, t, o) in [
            (600, 400, 256, 64),
            (256, 256, 256, 64),
            (300, 100, 128, 32),
        ] {
            let tiles = plan(w, h, t, o);
            let mut covered = Array2::<u8>::zeros((h, w));
            for tile in &tiles {
                assert!(
                    tile.x0 + tile.size <= w && tile.y0 + tile.size <= h,
                    "{tile:?}"
                );
                covered
                    .slice_mut(ndarray::s![
                        tile.y0..tile.y0 + tile.size,
                        tile.x0..tile.x0 + tile.size
                    ])
                    .mapv_inplace(|v| v + 1);
            }
            assert!(covered.iter().all(|&v| v > 0), "{w}x{h}: gaps");
            // Horizontal neighbours overlap by at least o.
            for pair in tiles.windows(2) {
                if pair[0].y0 == pair[1].y0 {
                    assert!(pair[0].x0 + pair[0].size >= pair[1].x0 + o.min(pair[0].size / 2));
                }
            }
        }
        assert_eq!(plan(256, 256, 256, 64).len(), 1);
        assert_eq!(plan(600, 400, 256, 64).len(), 3 * 2);
    }

    /// The paper's array at 92 mm (corner LEDs at 21°) allows 270 µm, 448 camera
    /// pixels of 0.6 µm; the same array twice as far allows wider tiles, and a single
    /// LED on the axis any (capped).
    #[test]
    fn the_tile_side_follows_the_steepest_leds_curvature() {
        let system = System::paper();
        let near = LedGeometry::paper();
        assert_eq!(auto_tile_side(&system, &near), 448);
        let far = LedGeometry {
            height_mm: 184.0,
            ..near
        };
        assert!(auto_tile_side(&system, &far) > 448);
        let coarse = System {
            pixel_size_um: 9.6,
            ..system
        };
        assert_eq!(
            auto_tile_side(&coarse, &near),
            96,
            "the same µm in 2.4 µm pixels"
        );
        let one = LedGeometry {
            rows: 1,
            cols: 1,
            center: crate::optics::LedIndex::new(0, 0),
            ..near
        };
        assert_eq!(auto_tile_side(&system, &one), MAX_AUTO_TILE);
    }

    #[test]
    fn the_tile_centre_is_measured_from_the_optical_axis() {
        let t = Tile {
            x0: 0,
            y0: 128,
            size: 128,
        };
        assert_eq!(t.centre_um(256, 256, 0.5), (-32.0, 32.0));
    }

    #[test]
    fn blending_undoes_each_tiles_unknown_global_phase() {
        // A smooth complex field, cut into tiles that each get a different global phase.
        let (w, h, u) = (96, 64, 2);
        let truth = Array2::from_shape_fn((h * u, w * u), |(r, c)| {
            Complex32::from_polar(1.0 + 0.3 * (r as f32 * 0.05).sin(), c as f32 * 0.02)
        });
        let tiles = plan(w, h, 48, 12);
        let mut mosaic = Mosaic::new(w, h, u, 12, 3);
        for (k, t) in tiles.iter().enumerate() {
            let part = truth
                .slice(ndarray::s![
                    t.y0 * u..(t.y0 + t.size) * u,
                    t.x0 * u..(t.x0 + t.size) * u
                ])
                .mapv(|v| v * Complex32::from_polar(1.0, k as f32 * 1.3));
            mosaic.add(t, &part);
        }
        let out = mosaic.finish();
        let a: Vec<Complex32> = out.iter().copied().collect();
        let b: Vec<Complex32> = truth.iter().copied().collect();
        let e = crate::reconstruct::complex_nrmse(&a, &b);
        assert!(e < 1e-5, "blended NRMSE {e}");
    }
}
