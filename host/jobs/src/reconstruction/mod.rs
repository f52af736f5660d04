//! EPRY on a dataset: frame normalisation and order, the passes, and the outputs.
//! The algorithm itself is `fpm_physics::reconstruct`.

pub mod batch;
pub mod height;
pub mod job;
pub mod refocus;
mod warnings;

pub use warnings::{checks, warnings, Check, Warning};

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use fpm_physics::background::{Correction, FrameBackground};
use fpm_physics::calibrate::boundary::{BlockReader, BoundaryHeight, PupilFromBoundary};
use fpm_physics::frame::LitFrame;
use fpm_physics::reconstruct::tiled::{self, Banded, TiledOutcome};
use fpm_physics::reconstruct::{ContrastFit, Flattening, Settings};
use fpm_physics::tiles::Tile;
use fpm_physics::{LedGeometry, LedIndex, System};
use ndarray::Array2;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use serde::Serialize;

use crate::calibration::GeometrySource;
use crate::dataset::image_io::{self, TiffOptions};
use crate::dataset::{Dataset, DatasetOnDisk, Pixels};
use crate::refinement::RefinedLedsReport;
pub use job::{CameraGamma, Finished, GammaScanReason, GeometryChoice, Job, JobEvent, Refocus};
pub use refocus::{RefocusChoice, RefocusReport};

/// What a reconstruction produced.
#[derive(Clone)]
pub struct Reconstruction {
    /// HR complex object.
    pub object: Array2<Complex32>,
    /// Pupil, centred.
    pub pupil: Array2<Complex32>,
    /// The report.
    pub report: Report,
}

impl Reconstruction {
    /// The images of `outcome` with their report.
    pub fn from_outcome(outcome: TiledOutcome, report: Report) -> Self {
        Self {
            object: outcome.object,
            pupil: outcome.pupil,
            report,
        }
    }
}

/// `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Dataset directory.
    pub dataset: String,
    /// The microscope (wavelength, NA, magnification, camera pixel).
    pub system: System,
    /// Geometry used for the wave vectors.
    pub geometry: LedGeometry,
    /// Where it came from.
    pub geometry_source: GeometrySource,
    /// HR pixels per camera pixel.
    pub upsample: usize,
    /// The reconstruction's pixel in the sample plane, µm (the camera pixel over the
    /// magnification, over `upsample`).
    pub pixel_um: f64,
    /// Passes over all frames.
    pub passes: usize,
    /// Frames used (in focus).
    pub frames: usize,
    /// Camera frame, pixels (width, height).
    pub frame_size: [usize; 2],
    /// Tile side and overlap, camera pixels (one tile: the whole field).
    pub tile_size: usize,
    /// Overlap between neighbouring tiles, camera pixels.
    pub tile_overlap: usize,
    /// Border of each tile, on sides facing another tile, where the measurement is not
    /// imposed (absorbs the FFT's wrap-around), camera pixels.
    pub tile_free_border: usize,
    /// Border of each tile, on sides facing another tile, that gets no weight in the
    /// blend (where a tile is least sure of its object), camera pixels.
    pub tile_unblended_border: usize,
    /// Per tile: where it is, its centre and its convergence.
    pub tiles: Vec<TileReport>,
    /// Mean over tiles of the relative amplitude error of the frames, per pass.
    pub error_per_pass: Vec<f64>,
    /// Wall-clock time per pass over all tiles, ms (total / passes; tiles run in
    /// parallel).
    pub ms_per_pass: f64,
    /// Total time (without loading), ms.
    pub total_ms: f64,
    /// Worker threads used for tiles.
    pub threads: usize,
    /// How the disc position is handled.
    pub disc_placement: &'static str,
    /// What was taken off the frames before they were imposed.
    pub background: BackgroundReport,
    /// The clear background's low-order phase taken off the object (docs/dataset.md).
    pub background_phase: BackgroundPhaseReport,
    /// Against the simulation's ground truth, when the dataset has one (docs/dataset.md §6).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub versus_truth: Option<fpm_physics::metrics::Scores>,
    /// h read from the bright/dark-field boundary of the frames, which does not depend
    /// on the stage's z, against the geometry's (when the frames bracket it).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub height_from_boundary: Option<BoundaryCheck>,
    /// The edge's height weighed against the dataset's on the frames, when they were
    /// [`height::WEIGH_SIGMA`] apart and the geometry was the dataset's own.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub height_choice: Option<height::HeightChoice>,
    /// The LED positions refined inside the passes (`--refine-leds`), and the board
    /// fitted to them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refined_leds: Option<RefinedLedsReport>,
    /// The dataset's `[camera] gamma`: its frames were decoded from a display encoding.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_gamma: Option<f64>,
    /// How `--camera-gamma auto` read the gamma from the frames: each candidate's
    /// error and bright-field fit over the central square.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_gamma_scan: Option<fpm_physics::reconstruct::GammaScan>,
    /// Why the scan ran: asked for (`--camera-gamma auto`), or by default on 8-bit
    /// frames whose dataset states no gamma (then decoded only where the scan is
    /// clear).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_gamma_scan_reason: Option<job::GammaScanReason>,
    /// The bright-field frames regressed on the intensities the result predicts for
    /// them: an offset share well above 0 is light no object explains.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bright_field_fit: Option<ContrastFit>,
    /// How far the frames were refocused, and what their shifts show.
    pub refocus: RefocusReport,
    /// Bits per stored sample of the frames (8 or 16 bits; 32: floats), which decides
    /// what advice applies to them (floats carry no display gamma).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sample_bits: Option<u32>,
    /// Frames lit by more than one LED (a multiplexed acquisition): advice that needs
    /// frames of one LED each (`--refine-leds`) does not apply to them.
    #[serde(skip_serializing_if = "is_zero")]
    pub multiplexed_frames: usize,
    /// How long each step of the job took, in the order they ran (a job's run
    /// fills it: [`job::Job::run`]); what the automatic checks cost beside EPRY.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub steps_ms: Vec<StepTime>,
}

/// How long one step of a reconstruction job took.
#[derive(Debug, Clone, Serialize)]
pub struct StepTime {
    /// The step, in words.
    pub step: &'static str,
    /// Wall-clock time, ms.
    pub ms: f64,
    /// A check the job made by itself (the gamma scan, the refocus estimate and the
    /// edge's height weighed), as against EPRY, loading and scoring.
    pub automatic: bool,
}

impl Report {
    /// The share of the job's time its automatic checks took (None before a job has
    /// timed its steps).
    pub fn automatic_share(&self) -> Option<f64> {
        let total: f64 = self.steps_ms.iter().map(|s| s.ms).sum();
        let automatic: f64 = self
            .steps_ms
            .iter()
            .filter(|s| s.automatic)
            .map(|s| s.ms)
            .sum();
        (total > 0.0).then(|| automatic / total)
    }
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// h from the bright/dark-field boundary, beside the geometry's h.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct BoundaryCheck {
    /// The estimate.
    #[serde(flatten)]
    pub estimate: BoundaryHeight,
    /// The geometry's h, mm.
    pub geometry_height_mm: f64,
    /// The NA's relative 1σ assumed: h from the edge scales as √(1 − NA²)/NA.
    pub na_relative_sigma: f64,
    /// The estimate's 1σ with the NA's added, mm.
    pub sigma_with_na_mm: f64,
    /// (boundary − geometry) over `sigma_with_na_mm`.
    pub difference_sigma: f64,
    /// The entrance pupil distance the edges fit best (an objective that is not
    /// telecentric), with its h and the blocks it and the system as given get wrong.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub entrance_pupil: Option<PupilFromBoundary>,
}

/// How well an objective's NA is known, relative: the label is nominal, and the NA
/// the illumination meets may differ by a few per cent.
pub const NA_RELATIVE_SIGMA: f64 = 0.02;

/// How many σ apart the edge's h and the geometry's must be for the report to warn.
/// Not 3: the edge's estimate moves in steps as blocks flip between bright and dark
/// field, which its σ does not carry. Measured by `fpm bench warnings` on 96 good
/// simulated 128² sets (true h 92 mm): estimates of 90.0–90.2, 94.7 and 99.1 mm, the
/// last (one sample layout of eight) 3.55σ off; an h stated 8 mm off reads 5.4σ
/// where the edge bounds h (cells, stained).
pub const DISAGREE_SIGMA: f64 = 4.0;

impl BoundaryCheck {
    /// Whether the two disagree: beyond [`DISAGREE_SIGMA`] of the boundary's estimate
    /// (the NA's uncertainty included).
    pub fn disagrees(&self) -> bool {
        self.difference_sigma.abs() > DISAGREE_SIGMA
    }
}

/// Blocks the boundary is read in, camera pixels.
const BOUNDARY_BLOCK_PX: usize = 8;

/// h from the bright/dark-field boundary of `frames` (in focus), with the lateral
/// placement of `geometry`, searched from 0.75× to 1.33× its h, beside its h. `None`
/// when the frames do not bracket it (too few LEDs near the edge, no centre frame).
pub fn boundary_check(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'_>],
) -> Option<BoundaryCheck> {
    let reader = BlockReader::from_frames(system, frames, geometry.center, BOUNDARY_BLOCK_PX)?;
    BoundaryCheck::read(system, geometry, &reader)
}

/// Where h is searched from the edges: 0.75× to 1.33× the geometry's `h`.
fn boundary_search(h: f64) -> (f64, f64) {
    (0.75 * h, 1.33 * h)
}

impl BoundaryCheck {
    /// The check from the frames `reader` has read, with `geometry`'s lateral
    /// placement; and the entrance pupil they fit best.
    fn read(system: &System, geometry: &LedGeometry, reader: &BlockReader) -> Option<Self> {
        let h = geometry.height_mm;
        let estimate = reader.estimate(system, geometry, boundary_search(h))?;
        Some(Self {
            entrance_pupil: reader.fit_entrance_pupil(
                system,
                geometry,
                boundary_search(h),
                &estimate,
            ),
            ..Self::new(system, h, estimate)
        })
    }

    /// `estimate` beside the geometry's `h`, the NA's uncertainty added.
    fn new(system: &System, h: f64, estimate: BoundaryHeight) -> Self {
        let na_share = estimate.height_mm * NA_RELATIVE_SIGMA / (1.0 - system.na * system.na);
        let sigma_with_na_mm = estimate.sigma_mm.hypot(na_share);
        Self {
            estimate,
            geometry_height_mm: h,
            na_relative_sigma: NA_RELATIVE_SIGMA,
            sigma_with_na_mm,
            difference_sigma: (estimate.height_mm - h) / sigma_with_na_mm.max(1e-9),
            entrance_pupil: None,
        }
    }
}

/// What one reconstruction of a dataset is asked to do: the LED geometry and where it
/// came from, EPRY's settings, the passes, and the tile side (None: from the physics).
#[derive(Debug, Clone, Copy)]
pub struct Request<'a> {
    /// The LED geometry.
    pub geometry: &'a LedGeometry,
    /// Where it came from.
    pub source: &'a GeometrySource,
    /// EPRY's settings.
    pub settings: Settings,
    /// Passes over all frames.
    pub passes: usize,
    /// Tile side, camera pixels.
    pub tile: Option<usize>,
}

impl Report {
    /// The report of `outcome`, a reconstruction of `frames` frames of the dataset in
    /// `dataset` as `request` asked (offline or streamed: the same tiles, the same
    /// finish), `total_ms` long.
    pub fn new(
        dataset: &Path,
        system: &System,
        request: &Request<'_>,
        frames: usize,
        outcome: &TiledOutcome,
        total_ms: f64,
    ) -> Self {
        let Request {
            geometry,
            source,
            settings,
            passes,
            ..
        } = *request;
        let tiles: Vec<TileReport> = outcome
            .tiles
            .iter()
            .map(|t| TileReport {
                tile: t.tile,
                centre_um: [t.centre_um.0, t.centre_um.1],
                initial_led: t.initial_led,
                error_per_pass: t.errors.clone(),
                ms: t.ms,
                background_phase: t.flattening.clone(),
            })
            .collect();
        let error_per_pass = (0..passes)
            .map(|p| {
                tiles
                    .iter()
                    .filter_map(|t| t.error_per_pass.get(p))
                    .sum::<f64>()
                    / tiles.len().max(1) as f64
            })
            .collect();
        let layout = &outcome.layout;
        Self {
            dataset: dataset.display().to_string(),
            system: *system,
            geometry: *geometry,
            geometry_source: source.clone(),
            upsample: settings.upsample.max(1),
            pixel_um: system.sample_pixel_um() / settings.upsample.max(1) as f64,
            passes,
            frames,
            frame_size: [layout.width, layout.height],
            tile_size: layout.size,
            tile_overlap: layout.overlap,
            tile_free_border: layout.free,
            tile_unblended_border: layout.unblended,
            tiles,
            error_per_pass,
            ms_per_pass: total_ms / passes.max(1) as f64,
            total_ms,
            threads: rayon::current_num_threads().min(layout.tiles.len()),
            disc_placement: DISC_PLACEMENT,
            background: BackgroundReport::new(
                settings.background,
                &outcome.backgrounds,
                outcome.axis_clear_share,
            ),
            background_phase: BackgroundPhaseReport::new(system, geometry, settings, outcome),
            versus_truth: None,
            height_from_boundary: None,
            height_choice: None,
            refined_leds: outcome.refined_leds.as_ref().map(RefinedLedsReport::new),
            camera_gamma: None,
            camera_gamma_scan: None,
            camera_gamma_scan_reason: None,
            bright_field_fit: outcome.bright_field,
            refocus: RefocusReport::given(settings.defocus_um),
            sample_bits: None,
            multiplexed_frames: 0,
            steps_ms: vec![],
        }
    }
}

/// `background` in `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct BackgroundReport {
    /// "dark level" (the dataset's only) or "per frame" (each dark-field frame's own
    /// background too).
    pub correction: &'static str,
    /// With "per frame": the floor, in standard deviations of the background's noise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub floor_sigma: Option<f32>,
    /// With "per frame": "soft" (light near the floor shrunk) or "hard" (cut).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub floor: Option<&'static str>,
    /// With "per frame": the noise band, in standard deviations of the background's
    /// noise (0: none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise_band_sigma: Option<f32>,
    /// Per frame that is dark-field over the whole field: its LED and the background
    /// measured in its darkest blocks, counts above the dataset's dark level, and
    /// whether it was taken off (only a flat one is: mostly white noise, not the
    /// sample's dim light).
    pub dark_field_frames: Vec<FrameBackgroundReport>,
    /// The share of the frame nearest the axis that is clear glass (its blocks holding
    /// only noise). With none, the sample fills the field, and its dark-field frames'
    /// darkest blocks hold its own light: left on as they should be, and not a sign of
    /// stray light (which cannot be told from it there).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub axis_clear_share: Option<f32>,
}

/// One dark-field frame's background.
#[derive(Debug, Clone, Serialize)]
pub struct FrameBackgroundReport {
    /// The LED.
    pub led: LedIndex,
    /// Level measured, counts.
    pub level_counts: f32,
    /// White pixel noise of the background, counts.
    pub noise_counts: f32,
    /// The share of the darkest blocks' variance that is white noise.
    pub white_share: f32,
    /// The brightest block's mean above the level, counts.
    pub brightest_block_counts: f32,
    /// Whether the level was taken off.
    pub taken_off: bool,
}

impl BackgroundReport {
    fn new(
        correction: Correction,
        backgrounds: &[(LedIndex, FrameBackground)],
        axis_clear_share: Option<f32>,
    ) -> Self {
        let (correction, floor_sigma, floor, noise_band_sigma, axis_clear_share) = match correction
        {
            Correction::DarkLevel => ("dark level", None, None, None, None),
            Correction::PerFrame {
                floor_sigma,
                soft,
                band_sigma,
            } => (
                "per frame",
                Some(floor_sigma),
                Some(if soft { "soft" } else { "hard" }),
                Some(band_sigma),
                axis_clear_share,
            ),
        };
        Self {
            correction,
            floor_sigma,
            floor,
            noise_band_sigma,
            dark_field_frames: backgrounds
                .iter()
                .map(|&(led, b)| FrameBackgroundReport {
                    led,
                    level_counts: b.level,
                    noise_counts: b.noise,
                    white_share: b.white_share,
                    brightest_block_counts: b.brightest,
                    taken_off: b.is_flat(),
                })
                .collect(),
            axis_clear_share,
        }
    }
}

const DISC_PLACEMENT: &str = "object read at the nearest whole HR bin; the pupil disc shifted by the sub-bin remainder (an exact phase ramp on the exit wave)";

/// One tile in `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct TileReport {
    /// Position and size, camera pixels.
    pub tile: Tile,
    /// Sample-plane centre, µm (its wave vectors are taken there).
    pub centre_um: [f64; 2],
    /// The frame used for the initial guess (nearest the axis from this tile).
    pub initial_led: LedIndex,
    /// Mean relative amplitude error of the frames, per pass.
    pub error_per_pass: Vec<f64>,
    /// Time this tile took, ms.
    pub ms: f64,
    /// The low-order phase taken off its clear background (absent when kept).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub background_phase: Option<Flattening>,
}

/// `background_phase` in `report.json`: whether the clear background's low-order
/// phase (offset, ramps, defocus, astigmatism: what the frames hardly determine) was
/// fitted over blocks and taken off, and how much.
#[derive(Debug, Clone, Serialize)]
pub struct BackgroundPhaseReport {
    /// "flattened" or "kept".
    pub treatment: &'static str,
    /// Block side, µm (absent when kept).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub block_um: Option<f64>,
    /// Over all tiles: blocks, blocks fitted, largest phase taken off, residual.
    #[serde(flatten)]
    pub totals: Flattening,
}

impl BackgroundPhaseReport {
    fn new(
        system: &System,
        geometry: &LedGeometry,
        settings: Settings,
        outcome: &TiledOutcome,
    ) -> Self {
        let block_um = settings.flatten.block_um(geometry, system.wavelength_um);
        Self {
            treatment: if block_um.is_some() {
                "flattened"
            } else {
                "kept"
            },
            block_um,
            totals: Flattening::combined(
                outcome.tiles.iter().filter_map(|t| t.flattening.as_ref()),
            ),
        }
    }
}

/// Reconstruct the in-focus frames of `ds` with `geometry`, tile by tile (`tile`: side
/// in camera pixels, see [`tiled::TileLayout::new`]), tiles in parallel. `progress(done,
/// total)` counts frame updates over all tiles.
pub fn reconstruct(
    ds: &Dataset,
    request: &Request<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Reconstruction> {
    reconstruct_with_system(ds, &ds.manifest.system(), request, progress)
}

/// The error for a dataset in `dir` without in-focus frames.
fn no_in_focus_frames(dir: &Path) -> anyhow::Error {
    anyhow::anyhow!(
        "{}: no in-focus frames (defocus_um = 0) to reconstruct",
        dir.display()
    )
}

/// [`reconstruct`] through `system` instead of the manifest's (an objective whose
/// entrance pupil the dataset cannot state, for a dataset borrowed as it is).
pub fn reconstruct_with_system(
    ds: &Dataset,
    system: &System,
    request: &Request<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Reconstruction> {
    let frames = ds.in_focus();
    if frames.is_empty() {
        return Err(no_in_focus_frames(&ds.dir));
    }
    refuse_refinement_of_multiplexed(&ds.dir, request, frames.iter().any(|f| f.is_multiplexed()))?;
    let Request {
        geometry,
        settings,
        passes,
        tile,
        ..
    } = *request;
    // The edges' check needs only the frames: it runs beside EPRY, which leaves a core
    // idle on a field of one tile (on more, the two share the cores as they would in
    // turn).
    let (outcome, height_from_boundary) = rayon::join(
        || {
            let start = Instant::now();
            tiled::reconstruct(system, geometry, &frames, settings, passes, tile, progress)
                .map(|outcome| (outcome, start.elapsed()))
        },
        || {
            let began = Instant::now();
            let check = boundary_check(system, geometry, &frames);
            tracing::debug!(
                "the bright/dark-field edges' check took {:.0} ms beside EPRY",
                began.elapsed().as_secs_f64() * 1e3
            );
            check
        },
    );
    let (outcome, epry_time) =
        outcome.with_context(|| format!("reconstructing {}", ds.dir.display()))?;
    let total_ms = epry_time.as_secs_f64() * 1e3;
    let mut report = Report::new(&ds.dir, system, request, frames.len(), &outcome, total_ms);
    report.height_from_boundary = height_from_boundary;
    report.camera_gamma = ds.manifest.camera.gamma;
    report.sample_bits = ds.frames.first().map(|f| f.raw.bits());
    report.multiplexed_frames = frames.iter().filter(|f| f.is_multiplexed()).count();
    Ok(Reconstruction::from_outcome(outcome, report))
}

/// LED refinement moves each frame's one LED to fit its frame: a frame lit by several
/// cannot say which of them is off.
fn refuse_refinement_of_multiplexed(
    dir: &Path,
    request: &Request<'_>,
    multiplexed: bool,
) -> Result<()> {
    if multiplexed && request.settings.refine_leds.is_some() {
        anyhow::bail!(
            "{}: --refine-leds needs frames lit by one LED each, and this dataset has frames lit by several (leds = [...]): leave --refine-leds out, or calibrate the array (fpm calibrate) and reconstruct with --calibration",
            dir.display()
        );
    }
    Ok(())
}

/// Frame `k` of `ds` as lit, from `pixels` (all or some of its rows).
fn lit<'a>(ds: &'a DatasetOnDisk, k: usize, pixels: &'a Pixels) -> LitFrame<'a> {
    LitFrame {
        led: ds.manifest.frames[k].led,
        also: &ds.manifest.frames[k].also,
        measured: ds.measured(k, pixels),
    }
}

/// [`reconstruct`] for a dataset left on disk: each frame is read whole once (its size
/// and values checked, the clear level, dark-field backgrounds and the bright/dark-field
/// edges measured), then each band of tile rows is read from every frame, solved and
/// blended before the next. Memory holds one band of the frames, not all of them; the
/// result equals [`reconstruct`]'s bit for bit.
pub fn reconstruct_on_disk(
    ds: &DatasetOnDisk,
    request: &Request<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Reconstruction> {
    let system = ds.manifest.system();
    let indices = ds.in_focus();
    if indices.is_empty() {
        return Err(no_in_focus_frames(&ds.dir));
    }
    let multiplexed = indices
        .iter()
        .any(|&k| ds.manifest.frames[k].is_multiplexed());
    refuse_refinement_of_multiplexed(&ds.dir, request, multiplexed)?;
    let Request {
        geometry,
        settings,
        passes,
        tile,
        ..
    } = *request;
    let context = || format!("reconstructing {}", ds.dir.display());
    let start = Instant::now();
    let lit_by = indices
        .iter()
        .map(|&k| ds.manifest.frames[k].leds().collect())
        .collect();
    let mut run = Banded::new(system, *geometry, settings, passes, ds.dim(), tile, lit_by)
        .with_context(context)?;
    let mut edges = match indices.iter().find(|&&k| {
        let f = &ds.manifest.frames[k];
        f.led == geometry.center && !f.is_multiplexed()
    }) {
        Some(&k) => {
            let pixels = ds.frame(k)?;
            Some(BlockReader::new(
                &system,
                &lit(ds, k, &pixels),
                BOUNDARY_BLOCK_PX,
            ))
        }
        None => None,
    };
    tracing::info!(
        frames = indices.len(),
        "{}: reading each frame once, then by bands of tile rows",
        ds.dir.display()
    );
    for (i, &k) in indices.iter().enumerate() {
        let pixels = ds.frame(k)?;
        let frame = lit(ds, k, &pixels);
        run.observe(i, &frame).with_context(context)?;
        if let Some(e) = edges.as_mut() {
            e.read(&frame);
        }
    }
    for band in run.bands() {
        let pixels: Vec<Pixels> = indices
            .par_iter()
            .map(|&k| ds.rows(k, band.rows.clone()))
            .collect::<Result<_, _>>()?;
        let frames: Vec<_> = indices
            .iter()
            .zip(&pixels)
            .map(|(&k, p)| lit(ds, k, p))
            .collect();
        run.solve_band(&band, &frames, progress)
            .with_context(context)?;
    }
    let outcome = run.finish().with_context(context)?;
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    let mut report = Report::new(&ds.dir, &system, request, indices.len(), &outcome, total_ms);
    report.height_from_boundary = edges.and_then(|e| BoundaryCheck::read(&system, geometry, &e));
    report.camera_gamma = ds.manifest.camera.gamma;
    report.sample_bits = Some(ds.sample_bits());
    report.multiplexed_frames = indices
        .iter()
        .filter(|&&k| ds.manifest.frames[k].is_multiplexed())
        .count();
    Ok(Reconstruction::from_outcome(outcome, report))
}

/// The OME-Zarr group a run writes with [`ImageFormat::OmeZarr`].
pub const ZARR_NAME: &str = "image.ome.zarr";

/// How the object (amplitude and phase) is stored.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum ImageFormat {
    /// `amplitude.tif` and `phase.tif`, OME-TIFF.
    #[default]
    Tiff,
    /// [`ZARR_NAME`]: both as channels of one OME-Zarr multiscale image.
    OmeZarr,
}

/// How the outputs are written.
#[derive(Debug, Clone, Copy, Default)]
pub struct OutputOptions {
    /// The object's format.
    pub format: ImageFormat,
    /// The TIFFs' options.
    pub tiff: TiffOptions,
}

/// `report.json`: the report and, beside its numbers, what they mean for the user
/// (`warnings`: each [`Warning`]'s check and message).
pub fn report_json(report: &Report) -> Result<serde_json::Value> {
    let mut json = serde_json::to_value(report)?;
    if let Some(object) = json.as_object_mut() {
        object.insert("warnings".into(), serde_json::to_value(checks(report))?);
    }
    Ok(json)
}

/// Write amplitude/phase TIFFs (float32), the pupil's and `report.json` into `out`
/// (the PNG previews and the page are the report crate's, `fpm_report`).
pub fn write_outputs(r: &Reconstruction, out: &Path) -> Result<()> {
    write_outputs_with(r, out, OutputOptions::default())
}

/// [`write_outputs`], the object written as `options` say: OME-TIFFs (their OME-XML
/// gives the pixel size in µm, the channel and the microscope) or an OME-Zarr
/// pyramid (docs/dataset.md §5).
pub fn write_outputs_with(r: &Reconstruction, out: &Path, options: OutputOptions) -> Result<()> {
    let tiff = options.tiff;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let amp = r.object.mapv(|c| c.norm());
    let phase = r.object.mapv(|c| c.arg());
    let pamp = r.pupil.mapv(|c| c.norm());
    let pphase = r.pupil.mapv(|c| c.arg());
    let system = &r.report.system;
    let ome = |name: &str, description: &str, a: &Array2<f32>| {
        let xml = crate::ome::ome_xml(&crate::ome::OmeImage {
            name,
            description,
            size: (a.ncols(), a.nrows()),
            pixel_um: r.report.pixel_um,
            wavelength_um: system.wavelength_um,
            na: system.na,
            magnification: system.magnification,
        });
        let path = out.join(format!("{name}.tif"));
        image_io::write_tiff_f32_described(&path, a, &xml, r.report.pixel_um, tiff)
    };
    match options.format {
        ImageFormat::Tiff => {
            ome(
                "amplitude",
                "FPM reconstruction (EPRY): amplitude of the sample's complex transmission, relative to clear glass",
                &amp,
            )?;
            ome(
                "phase",
                "FPM reconstruction (EPRY): phase of the sample's complex transmission, radians in [-pi, pi]",
                &phase,
            )?;
        }
        ImageFormat::OmeZarr => {
            crate::ome_zarr::write(&out.join(ZARR_NAME), &r.object, r.report.pixel_um)?
        }
    }
    let tif = |name: &str, a: &Array2<f32>| image_io::write_tiff_f32(&out.join(name), a);
    tif("pupil_amplitude.tif", &pamp)?;
    tif("pupil_phase.tif", &pphase)?;
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&report_json(&r.report)?)?,
    )?;
    if let Some(board) = r
        .report
        .refined_leds
        .as_ref()
        .and_then(|x| x.board.as_ref())
    {
        crate::refinement::write_board(board, &r.report.geometry, out)?;
    }
    Ok(())
}

/// Read a reconstruction's complex object back from `amplitude.tif` and `phase.tif`.
pub fn read_object(dir: &Path) -> Result<Array2<Complex32>> {
    Ok(image_io::read_complex(
        &dir.join("amplitude.tif"),
        &dir.join("phase.tif"),
    )?)
}
