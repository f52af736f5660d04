//! How a frame is cut into tiles, and the margins each tile needs.

use super::*;

/// How a `width × height` frame is cut.
#[derive(Debug, Clone, PartialEq)]
pub struct TileLayout {
    /// Frame width, pixels.
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// Tile side, pixels.
    pub size: usize,
    /// Overlap between neighbours, pixels (0 for one tile).
    pub overlap: usize,
    /// Border on the sides facing another tile where the measurement is not imposed
    /// (absorbs the FFT's wrap-around), pixels (0 for one tile).
    pub free: usize,
    /// Border on the sides facing another tile that the blend gives no weight, pixels
    /// (0 for one tile).
    pub unblended: usize,
    /// The tiles, row-major.
    pub tiles: Vec<Tile>,
}

impl TileLayout {
    /// `tile` = None picks the side from the physics ([`auto_tile_side`]): the whole
    /// field when it is square and no larger. The overlap and the borders are
    /// [`TileMargins`].
    pub fn new(
        width: usize,
        height: usize,
        tile: Option<usize>,
        system: &System,
        geometry: &LedGeometry,
    ) -> Self {
        let auto = auto_tile_side(system, geometry);
        let size = match tile {
            Some(t) => t.max(16),
            None if width == height && width <= auto => width,
            None => auto,
        };
        let size = size.min(width).min(height);
        let margins = TileMargins::new(size, system);
        let tiles = plan(width, height, size, margins.overlap);
        let margins = if tiles.len() > 1 {
            margins
        } else {
            TileMargins {
                overlap: 0,
                free: 0,
                unblended: 0,
            }
        };
        Self {
            width,
            height,
            size,
            overlap: margins.overlap,
            free: margins.free,
            unblended: margins.unblended,
            tiles,
        }
    }

    /// The field of tile `k`: its centre (wave vectors are taken there), its free
    /// border, and the shared clear level.
    pub fn field(&self, k: usize, pixel_um: f64, clear_level: Option<f32>) -> Field {
        let t = &self.tiles[k];
        Field {
            centre_um: t.centre_um(self.width, self.height, pixel_um),
            clear_level,
            free_border: t.free_border(self.width, self.height, self.free),
        }
    }

    /// The tile whose centre is nearest the optical axis (its pupil is reported).
    pub fn central_tile(&self) -> usize {
        (0..self.tiles.len())
            .min_by(|&a, &b| {
                let d = |k: usize| {
                    let c = self.tiles[k].centre_um(self.width, self.height, 1.0);
                    c.0.hypot(c.1)
                };
                d(a).total_cmp(&d(b))
            })
            .unwrap_or(0)
    }
}

/// A tile's object is worst near its inner edges: the frames there hold light from
/// the sample beyond the tile, which its periodic model cannot have. Measured on a
/// simulated 384² field in tiles of 160 (NRMSE against the truth by distance from the
/// nearest inner edge): 0.23 within one PSF width (λ/NA), 0.15, 0.11, 0.09 over the
/// next three, 0.08 further in. So the blend gives a tile no weight within
/// [`UNBLENDED_PSF_WIDTHS`] PSF widths of its inner edges, and the overlap is at
/// least [`OVERLAP_PSF_WIDTHS`], leaving the blend's ramp where both tiles are good.
/// With a quarter tile's overlap and a sixteenth unblended (40 and 10 px), tiles of
/// 160 stitched to 1.69× their own NRMSE (`host/physics/tests/stitching.rs`); with
/// these (63 and 24 px), to 1.29×.
pub const UNBLENDED_PSF_WIDTHS: f64 = 3.0;

/// See [`UNBLENDED_PSF_WIDTHS`].
pub const OVERLAP_PSF_WIDTHS: f64 = 8.0;

/// How far tiles reach into each other, camera pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileMargins {
    /// Overlap between neighbours: a quarter tile, but at least
    /// [`OVERLAP_PSF_WIDTHS`] PSF widths, and at most half a tile.
    pub overlap: usize,
    /// Border on the inner sides where the frames are not imposed (the FFT's
    /// wrap-around has no counterpart in the data): a sixteenth of the tile. Wider
    /// costs the tile more than it saves: on a simulated 256² field in tiles of 128,
    /// 8, 16 and 23 px gave NRMSE 0.090, 0.095 and 0.101.
    pub free: usize,
    /// Border on the inner sides that the blend gives no weight:
    /// [`UNBLENDED_PSF_WIDTHS`] PSF widths, at least the free border, and leaving a
    /// quarter of the overlap to blend over.
    pub unblended: usize,
}

impl TileMargins {
    /// The margins for tiles of side `size` under `system`'s PSF.
    pub fn new(size: usize, system: &System) -> Self {
        let psf_px = system.wavelength_um / (system.na * system.sample_pixel_um());
        let overlap = ((OVERLAP_PSF_WIDTHS * psf_px).ceil() as usize)
            .max(size / 4)
            .min(size / 2);
        let free = size / 16;
        let unblended = ((UNBLENDED_PSF_WIDTHS * psf_px).ceil() as usize)
            .min(overlap * 3 / 8)
            .max(free);
        Self {
            overlap,
            free,
            unblended,
        }
    }
}
