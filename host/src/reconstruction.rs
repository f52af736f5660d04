//! EPRY on a dataset: frame normalisation and order, the passes, and the outputs.
//! The algorithm itself is `fpm_physics::reconstruct`.

use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use std::sync::atomic::{AtomicUsize, Ordering};

use fpm_physics::reconstruct::{run, Field, Settings, Shot};
use fpm_physics::tiles::{plan, Mosaic, Tile};
use fpm_physics::{Image, LedGeometry};
use ndarray::Array2;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use serde::Serialize;

use crate::dataset::{image_io, Dataset};

/// What a reconstruction produced.
pub struct Reconstruction {
    /// HR complex object.
    pub object: Array2<Complex32>,
    /// Pupil, centred.
    pub pupil: Array2<Complex32>,
    /// The report.
    pub report: Report,
}

/// `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Dataset directory.
    pub dataset: String,
    /// Geometry used for the wave vectors.
    pub geometry: LedGeometry,
    /// Where it came from: "nominal" or a calibration file.
    pub geometry_source: String,
    /// HR pixels per camera pixel.
    pub upsample: usize,
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
    /// Against the simulation's ground truth, when the dataset has one (PHYSICS.md §6).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub versus_truth: Option<fpm_physics::metrics::Scores>,
}

impl Report {
    /// The report of a streamed reconstruction of `ds` (one field, the whole frame).
    pub fn streamed(
        ds: &Dataset,
        geometry: &LedGeometry,
        source: &str,
        settings: Settings,
        passes: usize,
        errors: Vec<f64>,
        total_ms: f64,
    ) -> Self {
        let (h, w) = ds.frames.first().map(|f| f.raw.dim()).unwrap_or((0, 0));
        Self {
            dataset: ds.dir.display().to_string(),
            geometry: *geometry,
            geometry_source: source.into(),
            upsample: settings.upsample.max(1),
            passes,
            frames: ds.frames.len(),
            frame_size: [w, h],
            tile_size: w.min(h),
            tile_overlap: 0,
            tile_free_border: 0,
            tiles: vec![],
            error_per_pass: errors,
            ms_per_pass: total_ms / passes.max(1) as f64,
            total_ms,
            threads: 1,
            disc_placement: DISC_PLACEMENT,
            versus_truth: None,
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
    pub initial_led: [usize; 2],
    /// Mean relative amplitude error of the frames, per pass.
    pub error_per_pass: Vec<f64>,
    /// Time this tile took, ms.
    pub ms: f64,
}

/// Tiling for a `width × height` frame: `tile` = None picks the whole field when it is
/// square and at most 512 pixels, else 256-pixel tiles; the overlap is a quarter tile.
pub fn tiling(width: usize, height: usize, tile: Option<usize>) -> (usize, usize) {
    let size = match tile {
        Some(t) => t.max(16),
        None if width == height && width <= 512 => width,
        None => 256,
    };
    let size = size.min(width).min(height);
    (size, size / 4)
}

/// Reconstruct the in-focus frames of `ds` with `geometry`, tile by tile (`tile`: side
/// in camera pixels, see [`tiling`]), tiles in parallel. `progress(done, total)` counts
/// frame updates over all tiles.
pub fn reconstruct(
    ds: &Dataset,
    geometry: &LedGeometry,
    source: &str,
    settings: Settings,
    passes: usize,
    tile: Option<usize>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Reconstruction> {
    let system = ds.manifest.system();
    let frames: Vec<usize> = (0..ds.frames.len())
        .filter(|&k| ds.frames[k].entry.defocus_um == 0.0)
        .collect();
    if frames.is_empty() {
        bail!(
            "{}: no in-focus frames (defocus_um = 0) to reconstruct",
            ds.dir.display()
        );
    }
    let (height, width) = ds.frames[frames[0]].raw.dim();
    let (size, overlap) = tiling(width, height, tile);
    let free = overlap / 4;
    let tiles = plan(width, height, size, overlap);
    let exposure = |k: usize| ds.frames[k].entry.exposure_ms as f32;
    // One clear level for all tiles: the whole frame under the LED nearest the axis.
    let nearest = *frames
        .iter()
        .min_by(|&&a, &&b| {
            let f = |k: usize| {
                let led = ds.frames[k].entry.led;
                let f =
                    geometry.illumination_frequency(led[0], led[1], 0.0, 0.0, system.wavelength_um);
                f.0.hypot(f.1)
            };
            f(a).total_cmp(&f(b))
        })
        .context("no frames")?;
    let clear_level = ds
        .corrected(nearest)
        .mapv(|v| v.max(0.0))
        .mean()
        .unwrap_or(0.0)
        / exposure(nearest);
    if clear_level.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        bail!(
            "{}: frame {} (LED {:?}, nearest the axis) is black; cannot normalise",
            ds.dir.display(),
            ds.frames[nearest].entry.file,
            ds.frames[nearest].entry.led
        );
    }
    let pixel_um = system.sample_pixel_um();
    let total = tiles.len() * passes * frames.len();
    let done = AtomicUsize::new(0);
    let start = Instant::now();
    let solve = |t: &Tile| -> Result<(Array2<Complex32>, Array2<Complex32>, TileReport)> {
        let tile_start = Instant::now();
        // This tile's share of each frame, as intensity per ms (u16 frames stay u16;
        // only the tile is converted).
        let images: Vec<Image> = frames
            .iter()
            .map(|&k| {
                ds.corrected_region(k, t.y0, t.x0, t.size, t.size)
                    .mapv(|v| v.max(0.0) / exposure(k))
            })
            .collect();
        let shots: Vec<Shot> = frames
            .iter()
            .zip(&images)
            .map(|(&k, image)| Shot {
                led: (ds.frames[k].entry.led[0], ds.frames[k].entry.led[1]),
                image,
            })
            .collect();
        let centre = t.centre_um(width, height, pixel_um);
        let field = Field {
            centre_um: centre,
            clear_level: Some(clear_level),
            free_border: t.free_border(width, height, free),
        };

        let mut outcome = run(
            &system,
            geometry,
            field,
            &shots,
            settings,
            passes,
            |_, _| {
                progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            },
        )
        .with_context(|| format!("tile at ({}, {}): no usable frame", t.x0, t.y0))?;
        drop(images);
        let report = TileReport {
            tile: *t,
            centre_um: [centre.0, centre.1],
            initial_led: ds.frames[frames[outcome.initial]].entry.led,
            error_per_pass: outcome.errors.clone(),
            ms: tile_start.elapsed().as_secs_f64() * 1e3,
        };
        let object = outcome.sample();
        let pupil = outcome.epry.pupil_centered();
        Ok((object, pupil, report))
    };
    let results: Vec<_> = tiles.par_iter().map(solve).collect::<Result<Vec<_>>>()?;
    let mut mosaic = Mosaic::new(width, height, settings.upsample.max(1), overlap, free);
    let mut reports = vec![];
    let mut pupil = None;
    let centre_tile = nearest_to_centre(&tiles, width, height);
    for (k, (object, p, report)) in results.into_iter().enumerate() {
        mosaic.add(&tiles[k], &object);
        if k == centre_tile {
            pupil = Some(p);
        }
        reports.push(report);
    }
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    let error_per_pass = (0..passes)
        .map(|p| reports.iter().map(|r| r.error_per_pass[p]).sum::<f64>() / reports.len() as f64)
        .collect();
    Ok(Reconstruction {
        object: mosaic.finish(),
        pupil: pupil.context("no tiles")?,
        report: Report {
            dataset: ds.dir.display().to_string(),
            geometry: *geometry,
            geometry_source: source.into(),
            upsample: settings.upsample.max(1),
            passes,
            frames: frames.len(),
            frame_size: [width, height],
            tile_size: size,
            tile_overlap: if tiles.len() > 1 { overlap } else { 0 },
            tile_free_border: if tiles.len() > 1 { free } else { 0 },
            tiles: reports,
            error_per_pass,
            ms_per_pass: total_ms / passes.max(1) as f64,
            total_ms,
            threads: rayon::current_num_threads().min(tiles.len()),
            versus_truth: None,
            disc_placement: DISC_PLACEMENT,
        },
    })
}

/// The tile whose centre is nearest the optical axis (its pupil is reported).
fn nearest_to_centre(tiles: &[Tile], width: usize, height: usize) -> usize {
    (0..tiles.len())
        .min_by(|&a, &b| {
            let d = |k: usize| {
                let c = tiles[k].centre_um(width, height, 1.0);
                c.0.hypot(c.1)
            };
            d(a).total_cmp(&d(b))
        })
        .unwrap_or(0)
}

/// Write amplitude/phase TIFFs (float32), PNG previews and `report.json` into `out`.
pub fn write_outputs(r: &Reconstruction, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let amp = r.object.mapv(|c| c.norm());
    let phase = r.object.mapv(|c| c.arg());
    let pamp = r.pupil.mapv(|c| c.norm());
    let pphase = r.pupil.mapv(|c| c.arg());
    let tif = |name: &str, a: &Array2<f32>| {
        image_io::write_tiff_f32(&out.join(name), a).map_err(anyhow::Error::msg)
    };
    tif("amplitude.tif", &amp)?;
    tif("phase.tif", &phase)?;
    tif("pupil_amplitude.tif", &pamp)?;
    tif("pupil_phase.tif", &pphase)?;
    let pct = |a: &Array2<f32>, q: f64| {
        let mut v: Vec<f32> = a.iter().copied().collect();
        v.sort_by(|x, y| x.total_cmp(y));
        v[((v.len() - 1) as f64 * q) as usize]
    };
    let png = |name: &str, a: &Array2<f32>, lo: f32, hi: f32| {
        image_io::write_png_preview(&out.join(name), a, lo, hi).map_err(anyhow::Error::msg)
    };
    png("amplitude.png", &amp, pct(&amp, 0.005), pct(&amp, 0.995))?;
    png(
        "phase.png",
        &phase,
        -std::f32::consts::PI,
        std::f32::consts::PI,
    )?;
    png("pupil_amplitude.png", &pamp, 0.0, pct(&pamp, 1.0))?;
    png(
        "pupil_phase.png",
        &pphase,
        -std::f32::consts::PI,
        std::f32::consts::PI,
    )?;
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&r.report)?,
    )?;
    Ok(())
}

/// Read a reconstruction's complex object back from `amplitude.tif` and `phase.tif`.
pub fn read_object(dir: &Path) -> Result<Array2<Complex32>> {
    let read = |name: &str| -> Result<Array2<f32>> {
        let path = dir.join(name);
        match image_io::read(&path).map_err(anyhow::Error::msg)? {
            image_io::Pixels::F32(a) => Ok(a),
            _ => bail!("{}: expected float32", path.display()),
        }
    };
    let (amp, phase) = (read("amplitude.tif")?, read("phase.tif")?);
    if amp.dim() != phase.dim() {
        bail!("{}: amplitude and phase differ in size", dir.display());
    }
    Ok(Array2::from_shape_fn(amp.dim(), |i| {
        Complex32::from_polar(amp[i], phase[i])
    }))
}
