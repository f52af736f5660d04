//! The full field of view, offline and streaming alike: a frame is cut into square
//! tiles ([`TileLayout`]), each tile is reconstructed with its own wave vectors and a
//! free border on its inner sides, all tiles share one clear level (the whole frame
//! under the LED nearest the axis), and the tiles are blended into one image
//! ([`Mosaic`]). Offline runs and streams differ only in where each tile's estimate
//! starts: fresh, or from the updates made while the frames arrived.
//!
//! Here the shared core (the tiles run in parallel and blended, [`reconstruct`] the
//! offline driver); [`layout`] cuts the frame; [`banded`] feeds frames band by band
//! from disk; [`streaming`] updates the tiles as frames arrive.

mod banded;
mod layout;
mod streaming;

pub use banded::{Band, Banded};
pub use layout::{TileLayout, TileMargins, OVERLAP_PSF_WIDTHS, UNBLENDED_PSF_WIDTHS};
pub use streaming::TiledStreaming;

use crate::optics::LedIndex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use ndarray::Array2;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;

use super::contrast::{ContrastFit, ContrastSums};
use super::flatten::{flatten_background_phase, Flattening};
use super::offline::{run_amplitudes, Amplitudes, Field, Lit, Outcome};
use super::refine::{FieldFrequencies, RefinedLeds};
use super::streaming::Streaming;
use super::Settings;
use crate::background::{clear_share, correct, FrameBackground};
use crate::frame::{LitFrame, Measured, Region};
use crate::optics::{LedGeometry, System};
use crate::tiles::{auto_tile_side, plan, Mosaic, Tile};
use crate::Image;

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
    /// How far the refinement found LEDs off its board model, cycles/µm (None
    /// unrefined).
    pub led_scatter: Option<f64>,
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
    /// The share of the clear glass the sample leaves in the frame nearest the axis
    /// ([`crate::background::clear_share`]; None for a frame too small for blocks):
    /// where there is none, dark-field backgrounds that are not flat are the sample's
    /// own light.
    pub axis_clear_share: Option<f32>,
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
    let (nearest, count) = axial_frame(system, geometry, frames).ok_or(TiledError::NoFrames)?;
    Ok((
        nearest,
        reference_level(nearest, &frames[nearest])? / count as f32,
    ))
}

/// The frame nearest the axis (its index) and how many bright-field LEDs light it: a
/// multiplexed frame over clear glass is as bright as those together, and the clear
/// level is one LED's. None without frames.
fn axial_frame(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'_>],
) -> Option<(usize, usize)> {
    let leds: Vec<LedIndex> = frames.iter().map(|f| f.led).collect();
    let also: Vec<Vec<LedIndex>> = frames.iter().map(|f| f.also.to_vec()).collect();
    let lit = Lit {
        leds: &leds,
        also: &also,
    };
    let nearest = *lit.nearest_first(geometry, (0.0, 0.0), system).first()?;
    Some((
        nearest,
        lit.bright_field_count(nearest, geometry, (0.0, 0.0), system),
    ))
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
    let fixed = Fixed {
        system,
        geometry,
        settings,
        clear_level: level,
    };
    solve(fixed, frames, passes, layout, starts, progress)
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
    also: &'a [Vec<LedIndex>],
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
                let bands: Vec<f32> = frames
                    .iter()
                    .map(|f| f.measured.intensity_band(self.clear_level))
                    .collect();
                let field = self.layout.field(k, pixel_um, Some(self.clear_level));
                let frames = Amplitudes {
                    leds: self.leds,
                    also: self.also,
                    images: &amplitudes,
                    bands: &bands,
                };
                let mut outcome = match start {
                    Some(s) => s.finish_amplitudes(frames, self.passes, self.tick),
                    None => {
                        let (system, geometry) = (self.system, self.geometry);
                        run_amplitudes(
                            system,
                            geometry,
                            field,
                            frames,
                            self.settings,
                            self.passes,
                            self.tick,
                        )
                    }
                }
                .ok_or(TiledError::Tile { x0: t.x0, y0: t.y0 })?;
                let (cx, cy) = field.centre_um;
                let mut bright_field = ContrastSums::default();
                for (k, amplitude) in amplitudes.iter().enumerate() {
                    // One LED's frames only: the contrast fit models one exit wave.
                    let single = self.also.get(k).is_none_or(Vec::is_empty);
                    if single
                        && self
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
                    initial_led: Lit {
                        leds: self.leds,
                        also: self.also,
                    }
                    .nearest(
                        outcome.initial,
                        self.geometry,
                        field.centre_um,
                        self.system,
                    ),
                    errors: outcome.errors.clone(),
                    ms: began.elapsed().as_secs_f64() * 1e3,
                    frequencies: outcome.frequencies.clone(),
                    led_scatter: outcome.led_scatter,
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

    fn finish(
        self,
        fixed: Fixed<'_>,
        layout: TileLayout,
        leds: &[LedIndex],
        backgrounds: Vec<(LedIndex, FrameBackground)>,
        axis_clear_share: Option<f32>,
    ) -> Result<TiledOutcome, TiledError> {
        let Fixed {
            system,
            geometry,
            settings,
            clear_level,
        } = fixed;
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
                    led_scatter: t.led_scatter,
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
            axis_clear_share,
        })
    }
}

/// What a run fixes before its tiles start: the optics, the settings, and the clear
/// level all tiles share.
#[derive(Clone, Copy)]
struct Fixed<'a> {
    system: &'a System,
    geometry: &'a LedGeometry,
    settings: Settings,
    clear_level: f32,
}

/// Each tile from its start (None: fresh, nearest-first from the frames), then blended.
fn solve(
    fixed: Fixed<'_>,
    frames: &[LitFrame<'_>],
    passes: usize,
    layout: TileLayout,
    starts: Vec<Option<Streaming>>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<TiledOutcome, TiledError> {
    let Fixed {
        system,
        geometry,
        settings,
        clear_level,
    } = fixed;
    let (frames, backgrounds) = corrected(system, geometry, frames, settings);
    let leds: Vec<LedIndex> = frames.iter().map(|f| f.led).collect();
    let also: Vec<Vec<LedIndex>> = frames.iter().map(|f| f.also.to_vec()).collect();
    let total = layout.tiles.len() * passes * frames.len();
    let done = AtomicUsize::new(0);
    let tick = |_: usize, _: usize| progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
    let job = TileJob {
        system,
        geometry,
        settings,
        layout: &layout,
        leds: &leds,
        also: &also,
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
    let axis_clear_share = axial_frame(system, geometry, &frames)
        .and_then(|(nearest, _)| clear_share(&frames[nearest].measured));
    assembly.finish(fixed, layout, &leds, backgrounds, axis_clear_share)
}
