//! `fpm acquire`: calibrate (pdcFPM) and acquire a full dataset from a live rig, with
//! streaming reconstruction while the frames arrive.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use fpm_frames::bench::{Stage, StageControl};
use fpm_frames::ServiceNames;
use fpm_physics::calibrate::Options;
use fpm_physics::reconstruct::{Settings, Streaming};
use fpm_physics::{LedGeometry, System};
use fpm_protocol::{LedIndex, Rgb};
use serde::Serialize;

use crate::acquire::{capture, CaptureReport, Shot, ShotView, StageMover};
use crate::calibration::calibrate_dataset;
use crate::controller::Controller;
use crate::dataset::{CameraSection, Dataset, FrameEntry, Manifest};

/// How the focus stage moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum StageKind {
    /// Ask the user to move it and wait for Enter.
    Manual,
    /// A virtual motorised stage on the bench (`--bench`).
    Virtual,
}

/// Acquire an FPM dataset: every LED of the array, one frame each, labelled.
#[derive(Args, Debug, Clone)]
pub struct AcquireArgs {
    /// The LED controller's serial port (a board, or `fpm emulator --link`).
    #[arg(long)]
    pub port: String,
    /// The camera whose frames to take (`fpm/camera/<NAME>/frames` on iceoryx2).
    #[arg(long, default_value = "0")]
    pub frames: String,
    /// Output directory: dataset.toml + frames/, acquisition.json, calibration/,
    /// calibration.json, reconstruction/.
    #[arg(long)]
    pub out: PathBuf,
    /// Calibrate the LED array first (pdcFPM: a focused reference, then the bright-field
    /// LEDs with the sample defocused).
    #[arg(long)]
    pub calibrate: bool,
    /// Reconstruct while the frames arrive (streaming EPRY).
    #[arg(long)]
    pub reconstruct: bool,
    /// How to move the focus stage for calibration.
    #[arg(long, value_enum, default_value_t = StageKind::Manual)]
    pub stage: StageKind,
    /// The virtual bench whose stage to move (with `--stage virtual`).
    #[arg(long)]
    pub bench: Option<String>,
    /// How long each LED stays lit, ms (the camera exposes within it).
    #[arg(long, default_value_t = 40.0)]
    pub step_ms: f64,
    /// Defocus for calibration, µm toward the LEDs.
    #[arg(long, default_value_t = 200.0)]
    pub defocus_um: f64,
    /// LED colour, `R,G,B` (0–255).
    #[arg(long, default_value = "0,0,255")]
    pub color: String,
    /// The camera's dark level, counts.
    #[arg(long, default_value_t = 100.0)]
    pub dark_level: f64,
    /// Illumination wavelength, µm.
    #[arg(long, default_value_t = 0.47)]
    pub wavelength_um: f64,
    /// Objective NA.
    #[arg(long, default_value_t = 0.1)]
    pub na: f64,
    /// Objective magnification.
    #[arg(long, default_value_t = 4.0)]
    pub magnification: f64,
    /// Camera pixel, µm.
    #[arg(long, default_value_t = 2.4)]
    pub pixel_um: f64,
    /// EPRY passes after the last frame.
    #[arg(long, default_value_t = 5)]
    pub passes: usize,
}

/// What `fpm acquire` did, also written as `acquisition.json`.
#[derive(Debug, Clone, Serialize)]
pub struct AcquireSummary {
    /// The nominal array (from the controller).
    pub nominal: LedGeometry,
    /// The geometry used for the acquisition order and the reconstruction.
    pub geometry: LedGeometry,
    /// Calibration captures.
    pub calibration: Vec<CaptureReport>,
    /// The full capture.
    pub capture: CaptureReport,
    /// The second capture of the frames the first one missed, if any.
    pub retake: Option<CaptureReport>,
    /// Frames written to the dataset.
    pub frames_in_dataset: usize,
    /// LEDs without a frame after the retake.
    pub still_missing: Vec<[usize; 2]>,
    /// Last frame → final image, ms (with `--reconstruct`).
    pub last_frame_to_final_ms: Option<f64>,
    /// Streaming updates per frame, µs (mean).
    pub update_us_mean: Option<f64>,
}

fn parse_color(s: &str) -> Result<Rgb> {
    let v: Vec<u8> = s
        .split(',')
        .map(|p| p.trim().parse::<u8>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--color {s}: expected R,G,B with 0–255 each"))?;
    match v.as_slice() {
        [r, g, b] => Ok(Rgb::new(*r, *g, *b)),
        _ => anyhow::bail!("--color {s}: expected three values R,G,B"),
    }
}

/// Run `fpm acquire`.
pub fn run(a: AcquireArgs) -> Result<()> {
    let summary = acquire(&a)?;
    print_summary(&summary, &a.out);
    Ok(())
}

/// The acquisition, returning its summary (used by `fpm demo` too).
pub fn acquire(a: &AcquireArgs) -> Result<AcquireSummary> {
    let color = parse_color(&a.color)?;
    let dev = Controller::open(&a.port, Duration::from_secs(2))
        .with_context(|| format!("connecting to the LED controller on {}", a.port))?;
    let g = dev.info().geometry;
    let nominal = LedGeometry {
        rows: g.rows as usize,
        cols: g.cols as usize,
        pitch_mm: g.pitch_um as f64 / 1e3,
        height_mm: g.height_um as f64 / 1e3,
        center: (g.center.row as usize, g.center.col as usize),
        dx_mm: 0.0,
        dy_mm: 0.0,
        theta_deg: 0.0,
    };
    let system = System {
        wavelength_um: a.wavelength_um,
        na: a.na,
        magnification: a.magnification,
        pixel_size_um: a.pixel_um,
    };
    let frames = ServiceNames::for_camera(&a.frames);
    // Shared memory of crashed runs (ours or a camera's) is removed before we start.
    match fpm_frames::cleanup_stale() {
        Ok(0) => {}
        Ok(n) => tracing::info!("removed the shared memory of {n} crashed process(es)"),
        Err(e) => tracing::warn!("could not check for stale shared memory: {e}"),
    }
    let stage = match a.stage {
        StageKind::Manual => StageMover::Manual,
        StageKind::Virtual => StageMover::Virtual(StageControl::create(
            a.bench
                .as_deref()
                .context("--stage virtual needs --bench NAME")?,
        )?),
    };
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let step_us = (a.step_ms * 1e3).round().max(1_000.0) as u32;
    let manifest = |frames: Vec<FrameEntry>| {
        let camera = CameraSection {
            dark_level: a.dark_level,
            ..CameraSection::default()
        };
        Manifest::new(&system, &nominal, camera, frames)
    };

    // 1. Calibration.
    let mut geometry = nominal;
    let mut calibration_reports = vec![];
    if a.calibrate {
        let centre = LedIndex::new(nominal.center.0 as u8, nominal.center.1 as u8);
        stage.move_to(Stage {
            slide: Stage::CALIBRATION_TARGET,
            ..Stage::default()
        })?;
        let (reference, r1) = capture(&dev, &frames, 101, &[centre], color, step_us, |_| {})?;
        stage.move_to(Stage {
            slide: Stage::CALIBRATION_TARGET,
            defocus_um: a.defocus_um,
            ..Stage::default()
        })?;
        let grid: Vec<LedIndex> = (-2i32..=2)
            .flat_map(|dr| (-2i32..=2).map(move |dc| (dr, dc)))
            .map(|(dr, dc)| {
                LedIndex::new(
                    (nominal.center.0 as i32 + dr) as u8,
                    (nominal.center.1 as i32 + dc) as u8,
                )
            })
            .collect();
        let (defocused, r2) = capture(&dev, &frames, 102, &grid, color, step_us, |_| {})?;
        stage.move_to(Stage::default())?;
        calibration_reports = vec![r1, r2];
        let dir = a.out.join("calibration");
        let mut shots: Vec<(&Shot, f64)> = reference.iter().map(|s| (s, 0.0)).collect();
        shots.extend(defocused.iter().map(|s| (s, a.defocus_um)));
        write_dataset(&dir, &manifest, &shots)?;
        let ds = Dataset::load(&dir)?;
        let cal = calibrate_dataset(&ds, &Options::default())?;
        std::fs::write(
            a.out.join("calibration.json"),
            serde_json::to_string_pretty(&cal)?,
        )?;
        geometry = cal.geometry();
    }

    // 2. The full acquisition, nearest-first under the geometry in use.
    let radius = |l: &LedIndex| {
        let f = geometry.illumination_frequency(
            l.row as usize,
            l.col as usize,
            0.0,
            0.0,
            system.wavelength_um,
        );
        f.0.hypot(f.1)
    };
    let mut leds: Vec<LedIndex> = (0..nominal.rows)
        .flat_map(|r| (0..nominal.cols).map(move |c| LedIndex::new(r as u8, c as u8)))
        .collect();
    leds.sort_by(|x, y| radius(x).total_cmp(&radius(y)));
    let settings = Settings::default();
    let mut streaming = a
        .reconstruct
        .then(|| Streaming::new(system, geometry, settings));
    let bar = indicatif::ProgressBar::new(leds.len() as u64).with_style(
        indicatif::ProgressStyle::with_template(
            "acquiring [{bar:40}] {pos}/{len} frames ({per_sec}, {eta} left)",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let dark = a.dark_level as f32;
    let mut update_us = vec![];
    let mut last_frame_at = Instant::now();
    let mut on_frame = |shot: ShotView<'_>| {
        bar.inc(1);
        last_frame_at = Instant::now();
        if let Some(s) = streaming.as_mut() {
            let (w, h) = (shot.header.width as usize, shot.header.height as usize);
            let ms = shot.header.exposure_us.max(1) as f32 / 1e3;
            let image = ndarray::Array2::from_shape_fn((h, w), |(r, c)| {
                ((shot.pixels[r * w + c] as f32 - dark) / ms).max(0.0)
            });
            let t = Instant::now();
            s.push(shot.led, image);
            update_us.push(t.elapsed().as_secs_f64() * 1e6);
        }
    };
    let (mut shots, report) = capture(&dev, &frames, 103, &leds, color, step_us, &mut on_frame)?;
    // Frames that did not arrive (or could not be labelled) are taken again, once.
    let mut retake = None;
    if !report.failed && !report.missing.is_empty() {
        let again: Vec<LedIndex> = report
            .missing
            .iter()
            .map(|&[r, c]| LedIndex::new(r as u8, c as u8))
            .collect();
        tracing::warn!("re-acquiring {} missing frame(s)", again.len());
        let (more, r) = capture(&dev, &frames, 104, &again, color, step_us, &mut on_frame)?;
        shots.extend(more);
        retake = Some(r);
    }
    let shot_refs: Vec<(&Shot, f64)> = shots.iter().map(|s| (s, 0.0)).collect();
    write_dataset(&a.out, &manifest, &shot_refs)?;

    // 3. The rest of the reconstruction.
    let mut last_frame_to_final_ms = None;
    if let (Some(s), false) = (streaming, report.failed) {
        let mut done = s
            .finish(a.passes)
            .context("no bright-field frame arrived")?;
        let object = done.sample();
        last_frame_to_final_ms = Some(last_frame_at.elapsed().as_secs_f64() * 1e3);
        let ds = Dataset::load(&a.out)?;
        let rec = crate::reconstruction::Reconstruction {
            pupil: done.epry.pupil_centered(),
            report: crate::reconstruction::Report::streamed(
                &ds,
                &geometry,
                if a.calibrate {
                    "calibration.json"
                } else {
                    "nominal (controller)"
                },
                settings,
                a.passes,
                done.errors.clone(),
                last_frame_to_final_ms.unwrap_or(0.0),
            ),
            object,
        };
        crate::reconstruction::write_outputs(&rec, &a.out.join("reconstruction"))?;
    }
    let failure = report.failed.then(|| report.outcome.clone());
    let still_missing: Vec<[usize; 2]> = match &retake {
        Some(r) => r.missing.clone(),
        None => report.missing.clone(),
    };
    let summary = AcquireSummary {
        nominal,
        geometry,
        calibration: calibration_reports,
        capture: report,
        retake,
        frames_in_dataset: shots.len(),
        still_missing,
        last_frame_to_final_ms,
        update_us_mean: (!update_us.is_empty())
            .then(|| update_us.iter().sum::<f64>() / update_us.len() as f64),
    };
    std::fs::write(
        a.out.join("acquisition.json"),
        serde_json::to_string_pretty(&summary)?,
    )?;
    if let Some(why) = failure {
        anyhow::bail!(
            "{why}; the {} frames acquired before are labelled and written to {} (acquisition.json lists the missing LEDs)",
            summary.frames_in_dataset,
            a.out.display()
        );
    }
    Ok(summary)
}

/// Write labelled shots as a dataset (PHYSICS.md §5) in `dir`.
fn write_dataset(
    dir: &Path,
    manifest: &dyn Fn(Vec<FrameEntry>) -> Manifest,
    shots: &[(&Shot, f64)],
) -> Result<()> {
    let entries = shots
        .iter()
        .map(|(s, z)| FrameEntry {
            file: String::new(),
            led: [s.led.0, s.led.1],
            defocus_um: *z,
            exposure_ms: s.header.exposure_us as f64 / 1e3,
        })
        .collect();
    let images: Vec<ndarray::Array2<u16>> = shots
        .iter()
        .map(|(s, _)| {
            ndarray::Array2::from_shape_vec(
                (s.header.height as usize, s.header.width as usize),
                s.pixels.clone(),
            )
            .context("frame size")
        })
        .collect::<Result<_>>()?;
    let mut m = manifest(entries);
    m.camera.bit_depth = shots.first().map(|(s, _)| s.header.bit_depth);
    Dataset::write(dir, &m, &images)?;
    Ok(())
}

fn print_summary(s: &AcquireSummary, out: &Path) {
    let c = &s.capture;
    println!(
        "acquired {}/{} frames in {:.1} s ({:.1} frames/s); missing {}, extra {}, ambiguous {}",
        c.labelled,
        c.requested,
        c.seconds,
        c.frames_per_s,
        c.missing.len(),
        c.extra_frames,
        c.ambiguous_frames
    );
    if let Some(r) = &s.retake {
        println!(
            "  re-acquired {}/{} missing frame(s)",
            r.labelled, r.requested
        );
    }
    if !s.still_missing.is_empty() {
        println!("  missing LEDs (not in the dataset): {:?}", s.still_missing);
    }
    let g = &s.geometry;
    println!(
        "geometry used: Δx {:.3} mm, Δy {:.3} mm, θ {:.3}°, h {:.2} mm",
        g.dx_mm, g.dy_mm, g.theta_deg, g.height_mm
    );
    if let Some(ms) = s.last_frame_to_final_ms {
        println!("last frame → final image: {ms:.0} ms");
    }
    println!(
        "wrote the dataset and acquisition.json to {}",
        out.display()
    );
}
