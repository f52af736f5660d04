//! EPRY on a dataset: frame normalisation and order, the passes, and the outputs.
//! The algorithm itself is `fpm_physics::reconstruct`.

use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use fpm_physics::reconstruct::{run, Settings, Shot};
use fpm_physics::{Image, LedGeometry};
use ndarray::Array2;
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
    /// Frame used for the initial guess (nearest the axis).
    pub initial_led: [usize; 2],
    /// Mean relative amplitude error of the frames, per pass.
    pub error_per_pass: Vec<f64>,
    /// Time per pass, ms.
    pub pass_ms: Vec<f64>,
    /// Total time (without loading), ms.
    pub total_ms: f64,
    /// How the disc position is handled.
    pub disc_placement: &'static str,
}

/// Reconstruct the in-focus frames of `ds` with `geometry`.
pub fn reconstruct(
    ds: &Dataset,
    geometry: &LedGeometry,
    source: &str,
    settings: Settings,
    passes: usize,
    mut progress: impl FnMut(usize, usize),
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
    let (h, w) = ds.frames[frames[0]].raw.dim();
    if h != w {
        bail!("{}: frames are {w}x{h}; the reconstructor takes square fields (crop them, or wait for tiling)", ds.dir.display());
    }
    // Each frame as intensity per ms.
    let images: Vec<Image> = frames
        .iter()
        .map(|&k| {
            ds.corrected(k)
                .mapv(|v| v.max(0.0) / ds.frames[k].entry.exposure_ms as f32)
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
    let start = Instant::now();
    let mut pass_start = Instant::now();
    let mut pass_ms = vec![];
    let per_pass = shots.len();
    let outcome = run(
        &system,
        geometry,
        &shots,
        settings,
        passes,
        |done, total| {
            progress(done, total);
            if done % per_pass == 0 {
                pass_ms.push(pass_start.elapsed().as_secs_f64() * 1e3);
                pass_start = Instant::now();
            }
        },
    )
    .context("the frame nearest the axis is black")?;
    let (mut epry, errors) = (outcome.epry, outcome.errors);
    let object = epry.object();
    let pupil = epry.pupil_centered();
    let initial = ds.frames[frames[outcome.initial]].entry.led;
    Ok(Reconstruction {
        object,
        pupil,
        report: Report {
            dataset: ds.dir.display().to_string(),
            geometry: *geometry,
            geometry_source: source.into(),
            upsample: epry.settings().upsample,
            passes,
            frames: shots.len(),
            initial_led: initial,
            error_per_pass: errors,
            pass_ms,
            total_ms: start.elapsed().as_secs_f64() * 1e3,
            disc_placement: "nearest HR frequency bin (error ≤ half a bin, 1/(2·W·Δ))",
        },
    })
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
