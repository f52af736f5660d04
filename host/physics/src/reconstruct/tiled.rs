//! The full field of view, offline and streaming alike: a frame is cut into square
//! tiles ([`TileLayout`]), each tile is reconstructed with its own wave vectors and a
//! free border on its inner sides, all tiles share one clear level (the whole frame
//! under the LED nearest the axis), and the tiles are blended into one image
//! ([`Mosaic`]). Offline runs and streams differ only in where each tile's estimate
//! starts: fresh, or from the updates made while the frames arrived.

use crate::optics::LedIndex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use ndarray::Array2;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;

use super::contrast::{ContrastFit, ContrastSums};
use super::flatten::{flatten_background_phase, Flattening};
use super::offline::{run_amplitudes, Field, Outcome};
use super::refine::{FieldFrequencies, RefinedLeds};
use super::streaming::Streaming;
use super::Settings;
use crate::background::{correct, FrameBackground};
use crate::frame::{LitFrame, Measured, Region};
use crate::optics::{LedGeometry, System};
use crate::tiles::{auto_tile_side, plan, Mosaic, Tile};
use crate::Image;

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

/// One tile's result.
#[derive(Debug, Clone)]
pub struct TileResult {
    /// Where it is.
    pub tile: Tile,
    /// Sample-plane centre, µm.
    pub centre_um: (f64, f64),
    /// The LED of the initial guess (nearest the axis from this tile).
    pub initial_led: LedIndex,
    /// Mean relative amplitude error per pass.
    pub errors: Vec<f64>,
    /// Time this tile took, ms.
    pub ms: f64,
    /// Each frame's illumination frequency at the tile's centre at the end (cycles/µm,
    /// frames' order): refined when the settings ask for it.
    pub frequencies: Vec<(f64, f64)>,
    /// The clear background's low-order phase taken off before blending (None when the
    /// settings keep it).
    pub flattening: Option<Flattening>,
    /// The tile's bright-field frames against the intensities its result predicts.
    pub bright_field: ContrastSums,
}

/// A reconstruction of the full field.
pub struct TiledOutcome {
    /// How the frame was cut.
    pub layout: TileLayout,
    /// The sample's HR transmission, blended, illumination curvature removed.
    pub object: Array2<Complex32>,
    /// The pupil of the tile nearest the axis, centred.
    pub pupil: Array2<Complex32>,
    /// Per tile.
    pub tiles: Vec<TileResult>,
    /// The clear level the frames were normalised by (intensity per ms).
    pub clear_level: f32,
    /// The background measured in each frame that is dark-field over the whole field,
    /// by LED (taken off where [`FrameBackground::is_flat`]; empty when the settings take
    /// off the dark level only).
    pub backgrounds: Vec<(LedIndex, FrameBackground)>,
    /// The LED positions refined inside the passes, over all tiles (when the settings
    /// ask for it).
    pub refined_leds: Option<RefinedLeds>,
    /// The bright-field frames against the intensities the result predicts, over all
    /// tiles ([`super::contrast`]; None when no tile had a bright-field frame).
    pub bright_field: Option<ContrastFit>,
}

/// Why a tiled reconstruction could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TiledError {
    /// No frames.
    #[error("no frames to reconstruct")]
    NoFrames,
    /// The reference frame is black.
    #[error("frame {index} (LED {led:?}, nearest the axis) is black: cannot normalise")]
    BlackReference {
        /// Its index among the frames given.
        index: usize,
        /// Its LED.
        led: LedIndex,
    },
    /// Frames of different sizes.
    #[error("frame {index} (LED {led:?}) is {got:?} (rows, cols), the others {expected:?}")]
    Size {
        /// Its index among the frames given.
        index: usize,
        /// Its LED.
        led: LedIndex,
        /// Its size.
        got: (usize, usize),
        /// The size of the first.
        expected: (usize, usize),
    },
    /// A band's frames do not fit the run (see [`Banded::solve_band`]).
    #[error("band of rows {start}..{end}: {why}")]
    Band {
        /// Its first row.
        start: usize,
        /// One past its last row.
        end: usize,
        /// What is wrong.
        why: String,
    },
    /// A tile had no usable frame.
    #[error("tile at ({x0}, {y0}): no bright-field frame to start from")]
    Tile {
        /// Its first column.
        x0: usize,
        /// Its first row.
        y0: usize,
    },
}

/// The clear level all tiles share: the whole frame's mean intensity under the LED
/// nearest the axis. Returns (index of that frame, level).
pub fn clear_level(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'_>],
) -> Result<(usize, f32), TiledError> {
    let leds: Vec<LedIndex> = frames.iter().map(|f| f.led).collect();
    let nearest = nearest_to_axis(system, geometry, &leds)?;
    Ok((nearest, reference_level(nearest, &frames[nearest])?))
}

/// The index of the LED nearest the axis among `leds`: the frame the clear level is
/// read from.
fn nearest_to_axis(
    system: &System,
    geometry: &LedGeometry,
    leds: &[LedIndex],
) -> Result<usize, TiledError> {
    geometry
        .nearest_first(leds, (0.0, 0.0), system)
        .first()
        .copied()
        .ok_or(TiledError::NoFrames)
}

/// The clear level from frame `index`, the one nearest the axis: its whole-frame mean
/// intensity, which must be positive.
fn reference_level(index: usize, frame: &LitFrame<'_>) -> Result<f32, TiledError> {
    let level = frame.measured.mean_intensity();
    if level.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return Err(TiledError::BlackReference {
            index,
            led: frame.led,
        });
    }
    Ok(level)
}

/// The frames' common (rows, cols), or which frame differs.
pub(crate) fn check_sizes(frames: &[LitFrame<'_>]) -> Result<(usize, usize), TiledError> {
    let expected = frames.first().ok_or(TiledError::NoFrames)?.measured.dim();
    for (index, f) in frames.iter().enumerate() {
        if f.measured.dim() != expected {
            return Err(TiledError::Size {
                index,
                led: f.led,
                got: f.measured.dim(),
                expected,
            });
        }
    }
    Ok(expected)
}

/// Reconstruct `frames` (in focus) with `geometry` in tiles (`tile`: side in pixels,
/// see [`TileLayout::new`]), tiles in parallel. `progress(done, total)` counts frame
/// updates over all tiles.
pub fn reconstruct(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'_>],
    settings: Settings,
    passes: usize,
    tile: Option<usize>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<TiledOutcome, TiledError> {
    let (height, width) = check_sizes(frames)?;
    let layout = TileLayout::new(width, height, tile, system, geometry);
    let (_, level) = clear_level(system, geometry, frames)?;
    let starts = (0..layout.tiles.len()).map(|_| None).collect();
    solve(
        system, geometry, frames, settings, passes, layout, level, starts, progress,
    )
}

/// Each frame with its own background taken off where the settings ask (measured over
/// the whole frame), and the backgrounds measured, by LED.
fn corrected<'a>(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'a>],
    settings: Settings,
) -> (Vec<LitFrame<'a>>, Vec<(LedIndex, FrameBackground)>) {
    let mut backgrounds = vec![];
    let frames = frames
        .iter()
        .map(|f| {
            let (frame, background) = correct(*f, system, geometry, settings.background);
            backgrounds.extend(background.map(|b| (f.led, b)));
            frame
        })
        .collect();
    (frames, backgrounds)
}

/// What the tiles share while they run: the layout, the settings, the frames' LEDs, the
/// clear level, and the progress over all tiles.
struct TileJob<'a> {
    system: &'a System,
    geometry: &'a LedGeometry,
    settings: Settings,
    layout: &'a TileLayout,
    leds: &'a [LedIndex],
    clear_level: f32,
    passes: usize,
    tick: &'a (dyn Fn(usize, usize) + Sync),
}

impl TileJob<'_> {
    /// Tiles `ks` (each from its start: None is fresh) in parallel, from `frames`
    /// (corrected), whose first row is row `row0` of the full frame.
    fn run(
        &self,
        ks: &[usize],
        starts: Vec<Option<Streaming>>,
        frames: &[LitFrame<'_>],
        row0: usize,
    ) -> Result<Vec<(TileResult, Outcome)>, TiledError> {
        let pixel_um = self.system.sample_pixel_um();
        let jobs: Vec<(usize, Option<Streaming>)> = ks.iter().copied().zip(starts).collect();
        jobs.into_par_iter()
            .map(|(k, start)| {
                let began = Instant::now();
                let t = self.layout.tiles[k];
                let region = Region {
                    y0: t.y0 - row0,
                    ..Region::from(t)
                };
                // This tile's share of each frame, as amplitude: the only conversion of
                // the counts, made here and dropped with the tile.
                let amplitudes: Vec<Image> = frames
                    .iter()
                    .map(|f| f.measured.amplitude(region, self.clear_level))
                    .collect();
                let field = self.layout.field(k, pixel_um, Some(self.clear_level));
                let mut outcome = match start {
                    Some(s) => s.finish_amplitudes(self.leds, &amplitudes, self.passes, self.tick),
                    None => run_amplitudes(
                        self.system,
                        self.geometry,
                        field,
                        self.leds,
                        &amplitudes,
                        self.settings,
                        self.passes,
                        self.tick,
                    ),
                }
                .ok_or(TiledError::Tile { x0: t.x0, y0: t.y0 })?;
                let (cx, cy) = field.centre_um;
                let mut bright_field = ContrastSums::default();
                for (k, amplitude) in amplitudes.iter().enumerate() {
                    if self
                        .geometry
                        .is_bright_field(self.leds[k], cx, cy, self.system)
                    {
                        outcome.epry.add_contrast(
                            amplitude,
                            outcome.frequencies[k],
                            &mut bright_field,
                        );
                    }
                }
                let result = TileResult {
                    tile: t,
                    centre_um: field.centre_um,
                    initial_led: self.leds[outcome.initial],
                    errors: outcome.errors.clone(),
                    ms: began.elapsed().as_secs_f64() * 1e3,
                    frequencies: outcome.frequencies.clone(),
                    flattening: None,
                    bright_field,
                };
                Ok((result, outcome))
            })
            .collect()
    }
}

/// The settings' background block ([`Settings::flatten`]) in HR pixels.
fn flatten_block(system: &System, geometry: &LedGeometry, settings: Settings) -> Option<usize> {
    let hr_pixel_um = system.sample_pixel_um() / settings.upsample.max(1) as f64;
    let um = settings.flatten.block_um(geometry, system.wavelength_um)?;
    Some((um / hr_pixel_um).round().min(usize::MAX as f64 / 4.0) as usize)
}

/// The tiles blended as they finish, in tile order, each tile's state dropped once it
/// is placed (only the central tile's pupil is kept).
struct Assembly {
    mosaic: Mosaic,
    /// Block side of the background flattening, HR pixels (None: keep the phase).
    flatten: Option<usize>,
    central: usize,
    pupil: Option<Array2<Complex32>>,
    tiles: Vec<TileResult>,
}

impl Assembly {
    fn new(
        system: &System,
        geometry: &LedGeometry,
        layout: &TileLayout,
        settings: Settings,
    ) -> Self {
        Self {
            mosaic: Mosaic::new(
                layout.width,
                layout.height,
                settings.upsample.max(1),
                layout.overlap,
                layout.unblended,
            ),
            flatten: flatten_block(system, geometry, settings),
            central: layout.central_tile(),
            pupil: None,
            tiles: Vec::with_capacity(layout.tiles.len()),
        }
    }

    /// Tile `k`, the next in order.
    fn add(&mut self, k: usize, mut result: TileResult, mut outcome: Outcome) {
        let mut sample = outcome.sample();
        if let Some(block) = self.flatten {
            result.flattening = Some(flatten_background_phase(&mut sample, block));
        }
        self.mosaic.add(&result.tile, &sample);
        if k == self.central {
            self.pupil = Some(outcome.epry.pupil_centered());
        }
        self.tiles.push(result);
    }

    #[allow(clippy::too_many_arguments)]
    fn finish(
        self,
        system: &System,
        geometry: &LedGeometry,
        settings: Settings,
        layout: TileLayout,
        leds: &[LedIndex],
        clear_level: f32,
        backgrounds: Vec<(LedIndex, FrameBackground)>,
    ) -> Result<TiledOutcome, TiledError> {
        let pixel_um = system.sample_pixel_um();
        let tiles = self.tiles;
        let refined_leds = settings.refine_leds.map(|_| {
            // The passes refine frequencies relative to the pupil's centre; the board
            // is fitted to the illumination's own.
            let illumination: Vec<Vec<(f64, f64)>> = tiles
                .iter()
                .map(|t| {
                    let c = system.chief_ray_frequency(t.centre_um.0, t.centre_um.1);
                    t.frequencies
                        .iter()
                        .map(|f| (f.0 + c.0, f.1 + c.1))
                        .collect()
                })
                .collect();
            let fields: Vec<FieldFrequencies> = tiles
                .iter()
                .zip(&illumination)
                .map(|(t, frequencies)| FieldFrequencies {
                    centre_um: t.centre_um,
                    frequencies,
                })
                .collect();
            let bin_step = 1.0 / (layout.size as f64 * pixel_um);
            RefinedLeds::from_fields(geometry, leds, &fields, system.wavelength_um, bin_step)
        });
        let mut bright_field = ContrastSums::default();
        for t in &tiles {
            bright_field.merge(&t.bright_field);
        }
        Ok(TiledOutcome {
            refined_leds,
            bright_field: bright_field.fit(),
            object: self.mosaic.finish(),
            pupil: self.pupil.ok_or(TiledError::NoFrames)?,
            tiles,
            layout,
            clear_level,
            backgrounds,
        })
    }
}

/// Each tile from its start (None: fresh, nearest-first from the frames), then blended.
#[allow(clippy::too_many_arguments)]
fn solve(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'_>],
    settings: Settings,
    passes: usize,
    layout: TileLayout,
    clear_level: f32,
    starts: Vec<Option<Streaming>>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<TiledOutcome, TiledError> {
    let (frames, backgrounds) = corrected(system, geometry, frames, settings);
    let leds: Vec<LedIndex> = frames.iter().map(|f| f.led).collect();
    let total = layout.tiles.len() * passes * frames.len();
    let done = AtomicUsize::new(0);
    let tick = |_: usize, _: usize| progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
    let job = TileJob {
        system,
        geometry,
        settings,
        layout: &layout,
        leds: &leds,
        clear_level,
        passes,
        tick: &tick,
    };
    let all: Vec<usize> = (0..layout.tiles.len()).collect();
    let results = job.run(&all, starts, &frames, 0)?;
    let mut assembly = Assembly::new(system, geometry, &layout, settings);
    for (k, (result, outcome)) in results.into_iter().enumerate() {
        assembly.add(k, result, outcome);
    }
    assembly.finish(
        system,
        geometry,
        settings,
        layout,
        &leds,
        clear_level,
        backgrounds,
    )
}

/// One band of a [`Banded`] run: the rows every frame must give, and its tiles (one
/// row of tiles).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Band {
    /// Frame rows `rows.start..rows.end`.
    pub rows: std::ops::Range<usize>,
    /// Its tiles' indices in the layout.
    pub tiles: Vec<usize>,
}

/// A tiled reconstruction fed band by band, for frames too many or too large to hold
/// at once (441 frames of 20 MP are 17.6 GB as 16-bit counts). What needs whole frames
/// is gathered first, one frame at a time ([`Self::observe`]: the clear level, each
/// dark-field frame's background); then each band of tile rows is solved from just
/// those rows of every frame ([`Self::solve_band`]) and blended at once, so neither
/// the frames nor the tiles' states are ever all in memory. The result equals
/// [`reconstruct`]'s bit for bit.
pub struct Banded {
    system: System,
    geometry: LedGeometry,
    settings: Settings,
    passes: usize,
    layout: TileLayout,
    leds: Vec<LedIndex>,
    nearest: usize,
    /// Per frame once observed: its dark level and floor after its background.
    corrections: Vec<Option<(f32, f32)>>,
    backgrounds: Vec<(LedIndex, FrameBackground)>,
    clear_level: Option<f32>,
    assembly: Assembly,
    next_tile: usize,
    done: AtomicUsize,
}

impl Banded {
    /// A run over frames of `width × height` lit by `leds` (in the order they will be
    /// given), cut as `tile` says ([`TileLayout::new`]).
    pub fn new(
        system: System,
        geometry: LedGeometry,
        settings: Settings,
        passes: usize,
        (height, width): (usize, usize),
        tile: Option<usize>,
        leds: Vec<LedIndex>,
    ) -> Result<Self, TiledError> {
        let nearest = nearest_to_axis(&system, &geometry, &leds)?;
        let layout = TileLayout::new(width, height, tile, &system, &geometry);
        let assembly = Assembly::new(&system, &geometry, &layout, settings);
        Ok(Self {
            corrections: vec![None; leds.len()],
            system,
            geometry,
            settings,
            passes,
            layout,
            leds,
            nearest,
            backgrounds: vec![],
            clear_level: None,
            assembly,
            next_tile: 0,
            done: AtomicUsize::new(0),
        })
    }

    /// How the frame is cut.
    pub fn layout(&self) -> &TileLayout {
        &self.layout
    }

    /// The bands, top to bottom: one per row of tiles.
    pub fn bands(&self) -> Vec<Band> {
        let mut bands: Vec<Band> = vec![];
        for (k, t) in self.layout.tiles.iter().enumerate() {
            match bands.last_mut() {
                Some(b) if b.rows.start == t.y0 => b.tiles.push(k),
                _ => bands.push(Band {
                    rows: t.y0..t.y0 + t.size,
                    tiles: vec![k],
                }),
            }
        }
        bands
    }

    /// Frame `k` whole (in any order, each once, before any band): its size checked,
    /// its background measured, the clear level read if it is the frame nearest the
    /// axis.
    pub fn observe(&mut self, k: usize, frame: &LitFrame<'_>) -> Result<(), TiledError> {
        let expected = (self.layout.height, self.layout.width);
        if frame.measured.dim() != expected {
            return Err(TiledError::Size {
                index: k,
                led: frame.led,
                got: frame.measured.dim(),
                expected,
            });
        }
        if k == self.nearest {
            self.clear_level = Some(reference_level(k, frame)?);
        }
        let (corrected, background) = correct(
            *frame,
            &self.system,
            &self.geometry,
            self.settings.background,
        );
        self.backgrounds.extend(background.map(|b| (frame.led, b)));
        if let Some(c) = self.corrections.get_mut(k) {
            *c = Some((corrected.measured.dark_level, corrected.measured.floor));
        }
        Ok(())
    }

    /// Solve `band` (the next in [`Self::bands`]' order) from `rows`: rows
    /// `band.rows` of every frame, in the order of the LEDs given to [`Self::new`], as
    /// measured (each frame's correction is applied here). `progress(done, total)`
    /// counts frame updates over the whole run.
    pub fn solve_band(
        &mut self,
        band: &Band,
        rows: &[LitFrame<'_>],
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<(), TiledError> {
        let clear_level = self.clear_level.ok_or(TiledError::BlackReference {
            index: self.nearest,
            led: self.leds[self.nearest],
        })?;
        let bad = |why: String| TiledError::Band {
            start: band.rows.start,
            end: band.rows.end,
            why,
        };
        if band.tiles.first() != Some(&self.next_tile) {
            return Err(bad(format!(
                "bands must come in order; tile {} is next",
                self.next_tile
            )));
        }
        if rows.len() != self.leds.len() {
            return Err(bad(format!(
                "{} frames given, the run has {}",
                rows.len(),
                self.leds.len()
            )));
        }
        let wanted = (band.rows.len(), self.layout.width);
        let mut frames = Vec::with_capacity(rows.len());
        for (index, (f, &led)) in rows.iter().zip(&self.leds).enumerate() {
            if f.led != led {
                return Err(bad(format!(
                    "frame {index} is lit by LED {:?}, the run has LED {led:?} there",
                    f.led
                )));
            }
            if f.measured.dim() != wanted {
                return Err(bad(format!(
                    "frame {index} (LED {led:?}) is {:?} (rows, cols), the band {wanted:?}",
                    f.measured.dim()
                )));
            }
            let (dark_level, floor) = self.corrections[index]
                .ok_or_else(|| bad(format!("frame {index} (LED {led:?}) was not observed")))?;
            frames.push(LitFrame {
                led,
                measured: Measured {
                    dark_level,
                    floor,
                    ..f.measured
                },
            });
        }
        let total = self.layout.tiles.len() * self.passes * self.leds.len();
        let done = &self.done;
        let tick = |_: usize, _: usize| progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
        let job = TileJob {
            system: &self.system,
            geometry: &self.geometry,
            settings: self.settings,
            layout: &self.layout,
            leds: &self.leds,
            clear_level,
            passes: self.passes,
            tick: &tick,
        };
        let starts = band.tiles.iter().map(|_| None).collect();
        let results = job.run(&band.tiles, starts, &frames, band.rows.start)?;
        for (&k, (result, outcome)) in band.tiles.iter().zip(results) {
            self.assembly.add(k, result, outcome);
        }
        self.next_tile = band.tiles.last().map_or(self.next_tile, |k| k + 1);
        Ok(())
    }

    /// Blend what the bands gave (every band must have been solved).
    pub fn finish(self) -> Result<TiledOutcome, TiledError> {
        if self.next_tile != self.layout.tiles.len() {
            let t = self.layout.tiles[self.next_tile];
            return Err(TiledError::Tile { x0: t.x0, y0: t.y0 });
        }
        let clear_level = self.clear_level.ok_or(TiledError::NoFrames)?;
        self.assembly.finish(
            &self.system,
            &self.geometry,
            self.settings,
            self.layout,
            &self.leds,
            clear_level,
            self.backgrounds,
        )
    }
}

/// Streaming EPRY over the full field: one [`Streaming`] per tile of the same
/// [`TileLayout`] an offline run uses, so frames of any size (a 20 MP sensor, a
/// non-square one) stream. The clear level comes from the first frame that is
/// bright-field on the axis (in a nearest-first acquisition, the axial LED's).
pub struct TiledStreaming {
    system: System,
    geometry: LedGeometry,
    settings: Settings,
    layout: TileLayout,
    tiles: Vec<Streaming>,
    clear_level: Option<f32>,
}

impl TiledStreaming {
    /// Nothing received yet, for `width × height` frames cut as `tile` says.
    pub fn new(
        system: System,
        geometry: LedGeometry,
        settings: Settings,
        width: usize,
        height: usize,
        tile: Option<usize>,
    ) -> Self {
        let layout = TileLayout::new(width, height, tile, &system, &geometry);
        let pixel_um = system.sample_pixel_um();
        let tiles = (0..layout.tiles.len())
            .map(|k| {
                Streaming::for_field(system, geometry, settings, layout.field(k, pixel_um, None))
            })
            .collect();
        Self {
            system,
            geometry,
            settings,
            layout,
            tiles,
            clear_level: None,
        }
    }

    /// How the frame is cut.
    pub fn layout(&self) -> &TileLayout {
        &self.layout
    }

    /// A frame arrived: every tile is updated with its share (or keeps it until it can
    /// be seeded). A frame of the wrong size is refused.
    pub fn push(&mut self, frame: &LitFrame<'_>) -> Result<(), TiledError> {
        let expected = (self.layout.height, self.layout.width);
        if frame.measured.dim() != expected {
            return Err(TiledError::Size {
                index: self.received(),
                led: frame.led,
                got: frame.measured.dim(),
                expected,
            });
        }
        if self.clear_level.is_none()
            && self
                .geometry
                .is_bright_field(frame.led, 0.0, 0.0, &self.system)
        {
            let level = frame.measured.mean_intensity();
            if level > 0.0 {
                self.clear_level = Some(level);
                for t in &mut self.tiles {
                    t.set_clear_level(level);
                }
            }
        }
        let (frame, _) = correct(
            *frame,
            &self.system,
            &self.geometry,
            self.settings.background,
        );
        for (t, tile) in self.tiles.iter_mut().zip(&self.layout.tiles) {
            t.push_measured(frame.led, &frame.measured, Region::from(*tile));
        }
        Ok(())
    }

    /// Frames received.
    pub fn received(&self) -> usize {
        self.tiles.first().map_or(0, Streaming::received)
    }

    /// The sample as it stands, blended over the tiles as the finish blends them (None
    /// until every tile has been seeded).
    pub fn snapshot(&mut self) -> Option<Array2<Complex32>> {
        let mut mosaic = Mosaic::new(
            self.layout.width,
            self.layout.height,
            self.settings.upsample.max(1),
            self.layout.overlap,
            self.layout.unblended,
        );
        let flatten = flatten_block(&self.system, &self.geometry, self.settings);
        for (t, tile) in self.tiles.iter_mut().zip(&self.layout.tiles) {
            let mut sample = t.snapshot_sample()?;
            if let Some(block) = flatten {
                flatten_background_phase(&mut sample, block);
            }
            mosaic.add(tile, &sample);
        }
        Some(mosaic.finish())
    }

    /// Run `passes` more passes over `frames` (every frame received, handed back) in
    /// each tile, and blend: the same finish as an offline run.
    pub fn finish(
        self,
        frames: &[LitFrame<'_>],
        passes: usize,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<TiledOutcome, TiledError> {
        check_sizes(frames)?;
        let level = self.clear_level.ok_or(TiledError::NoFrames)?;
        if let Some(k) = self.tiles.iter().position(|t| t.clear_level().is_none()) {
            let t = self.layout.tiles[k];
            return Err(TiledError::Tile { x0: t.x0, y0: t.y0 });
        }
        let starts = self.tiles.into_iter().map(Some).collect();
        solve(
            &self.system,
            &self.geometry,
            frames,
            self.settings,
            passes,
            self.layout,
            level,
            starts,
            progress,
        )
    }
}
