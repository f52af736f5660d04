//! The acquisition: calibrate the LED array (pdcFPM, optional) → order the LEDs
//! nearest-first under the geometry in use → capture one labelled frame per LED →
//! retake what is missing, once → write the dataset → finish the reconstruction that
//! streamed while the frames arrived.
//!
//! A frame's way: out of shared memory once ([`crate::capture`]), lent to the streaming
//! reconstruction as it arrives (each tile takes its share as amplitude, the one
//! conversion, in `fpm_physics::frame`), moved into the in-memory dataset, written to
//! disk, and lent again from there for the last passes. Calibration frames are used
//! from memory too.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use fpm_frames::ServiceNames;
use fpm_host::calibration::{calibrate_dataset, GeometrySource};
use fpm_host::dataset::{CameraSection, Dataset, FrameEntry, Manifest};
use fpm_host::reconstruction::{write_outputs, Reconstruction, Report, Request};
use fpm_physics::calibrate::Options;
use fpm_physics::reconstruct::{tiled, Flatten, Settings, TiledStreaming};
use fpm_physics::{LedGeometry, System};
use fpm_protocol::{BoardCalibration, LedIndex, Rgb, StoredCalibration};

use crate::board_geometry;
use crate::capture::{capture, Shot, ShotView};
use crate::controller::Controller;
use crate::page;
use crate::stage::{FocusStage, Slide, StagePosition};
pub use crate::summary::AcquireSummary;

/// What to acquire and how.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The camera whose frames to take.
    pub camera: ServiceNames,
    /// Output directory: dataset.toml + frames/, acquisition.json, calibration/,
    /// calibration.json, reconstruction/.
    pub out: PathBuf,
    /// Calibrate the LED array first.
    pub calibrate: bool,
    /// Store the calibration on the board (protocol ≥ 1.1), so later acquisitions
    /// without `calibrate` start from it.
    pub store_geometry: bool,
    /// Reconstruct while the frames arrive.
    pub reconstruct: bool,
    /// How long each LED stays lit, ms.
    pub step_ms: f64,
    /// Defocus for calibration, µm toward the LEDs.
    pub defocus_um: f64,
    /// 1σ of that defocus as the stage sets it, µm (h's uncertainty carries it).
    pub defocus_sigma_um: f64,
    /// LED colour.
    pub color: Rgb,
    /// The camera's dark level, counts.
    pub dark_level: f64,
    /// The optics.
    pub system: System,
    /// EPRY passes after the last frame.
    pub passes: usize,
    /// Tile side for the reconstruction, camera pixels (None: chosen by frame size).
    pub tile: Option<usize>,
    /// Whether the clear background's low-order phase is taken off the result.
    pub flatten: Flatten,
}

/// How long an acquisition waits for its camera to publish before saying none does.
pub const CAMERA_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

impl Plan {
    /// Every setting in its range, or an error naming it.
    pub fn validate(&self) -> Result<()> {
        if !(self.step_ms.is_finite() && (1.0..=60_000.0).contains(&self.step_ms)) {
            bail!("step_ms {}: must be 1-60000 ms", self.step_ms);
        }
        if !(self.defocus_um.is_finite() && self.defocus_um.abs() <= 10_000.0) {
            bail!("defocus_um {}: must be within ±10000 µm", self.defocus_um);
        }
        if !(self.defocus_sigma_um.is_finite() && self.defocus_sigma_um >= 0.0) {
            bail!(
                "defocus_sigma_um {}: must be 0 or more",
                self.defocus_sigma_um
            );
        }
        if !self.dark_level.is_finite() {
            bail!("dark_level {}: must be finite", self.dark_level);
        }
        if let Some((name, v, why)) = self.system.out_of_range() {
            bail!("{name} {v}: {why}");
        }
        if !(1..=10_000).contains(&self.passes) {
            bail!("passes {}: must be 1-10000", self.passes);
        }
        if let Some(tile) = self.tile.filter(|t| !(16..=16_384).contains(t)) {
            bail!("tile {tile}: must be 16-16384 camera pixels");
        }
        Ok(())
    }
}

/// Whether a camera publishes on `names`, waiting up to [`CAMERA_WAIT`] for one to come
/// up: a sequence over every LED with no camera would take minutes to fail.
fn wait_for_camera(names: &ServiceNames) -> Result<()> {
    let subscriber = fpm_frames::FrameSubscriber::create(names)?;
    if !subscriber.wait_for_publisher(CAMERA_WAIT) {
        bail!(
            "no camera publishes frames on {} (waited {} s): start the camera's driver (`fpm camera run`, or the virtual rig's camera) or give its name with --frames",
            names.frames,
            CAMERA_WAIT.as_secs()
        );
    }
    Ok(())
}

/// What the camera's driver says it applied, if it says (an optional extra: never an
/// error). A reported pixel pitch that disagrees with the system's is warned about.
fn camera_settings(camera: &ServiceNames, system: &System) -> Option<serde_json::Value> {
    let text = fpm_frames::read_settings(camera, std::time::Duration::from_millis(300))?;
    let value: serde_json::Value = match serde_json::from_str(&text) {
        Ok(v) => v,
        Err(e) => {
            tracing::warn!("the camera's settings are not JSON ({e}); left out");
            return None;
        }
    };
    tracing::info!("camera settings as applied: {value}");
    if let Some(pitch) = value.get("pixel_size_um").and_then(|v| v.as_f64()) {
        let binning = value
            .get("binning")
            .and_then(|b| b.get(0))
            .and_then(|b| b.as_f64())
            .unwrap_or(1.0);
        // A colour mosaic's channel is published one pixel per 2 × 2 cell.
        let factor = value
            .get("published_pixel_factor")
            .and_then(|f| f.as_f64())
            .unwrap_or(1.0);
        let effective = pitch * binning * factor;
        if (effective - system.pixel_size_um).abs() > 0.01 * system.pixel_size_um {
            tracing::warn!(
                "the camera reports {effective:.3} µm pixels ({pitch} µm × binning {binning} × {factor} for a colour channel), the system says {:.3} µm (--pixel-um)",
                system.pixel_size_um
            );
        }
    }
    Some(value)
}

/// The nominal array as the controller describes it.
pub fn nominal_geometry(dev: &Controller) -> LedGeometry {
    board_geometry::nominal(&dev.info().geometry)
}

/// The calibration stored on the board, if any. A board that cannot say (older
/// firmware, a damaged record, a link error) has none, with a note in the log.
fn stored_calibration(dev: &Controller) -> Option<BoardCalibration> {
    match dev.stored_calibration() {
        Ok(StoredCalibration::Calibrated(c)) => Some(c),
        Ok(other) => {
            tracing::info!("the board: {}", board_geometry::describe_stored(&other));
            None
        }
        Err(e) => {
            tracing::info!("no stored geometry: {e}");
            None
        }
    }
}

/// Run the acquisition of `plan` with controller `dev` and focus stage `stage`.
/// `on_frame(done, total)` after every frame of the full capture. Frames that arrived
/// are labelled and written even when the controller is lost; the error then says so.
pub fn acquire(
    dev: &Controller,
    stage: &mut dyn FocusStage,
    plan: &Plan,
    mut on_frame: impl FnMut(usize, usize),
) -> Result<AcquireSummary> {
    plan.validate()?;
    wait_for_camera(&plan.camera)?;
    let nominal = nominal_geometry(dev);
    let system = plan.system;
    std::fs::create_dir_all(&plan.out)
        .with_context(|| format!("creating {}", plan.out.display()))?;
    let camera_settings = camera_settings(&plan.camera, &system);
    let step_us = (plan.step_ms * 1e3).round().max(1_000.0) as u32;
    let camera = CameraSection {
        dark_level: plan.dark_level,
        ..CameraSection::default()
    };
    let capture_leds = |id: u32, leds: &[LedIndex], on: &mut dyn FnMut(ShotView<'_>)| {
        capture(dev, &plan.camera, id, leds, plan.color, step_us, on)
    };

    // 1. Calibration: a focused reference under the centre LED, then the 5×5 LEDs
    // around it with the calibration slide defocused.
    let mut geometry = nominal;
    let mut geometry_source = GeometrySource::Controller;
    let board_calibration = stored_calibration(dev);
    let mut calibration_reports = vec![];
    if !plan.calibrate {
        match &board_calibration {
            Some(c) => {
                geometry = board_geometry::geometry(&nominal, c);
                geometry_source = GeometrySource::Board;
                tracing::info!(
                    "starting from the geometry stored on the board: {}",
                    board_geometry::describe(c)
                );
            }
            None => tracing::warn!(
                "no calibration given and none stored on the board: using the nominal geometry (calibrate with --calibrate --store-geometry)"
            ),
        }
    }
    if plan.calibrate {
        stage.move_to(StagePosition::in_focus(Slide::CalibrationTarget))?;
        let (reference, r1) = capture_leds(101, &[nominal.center], &mut |_| {})?;
        stage.move_to(StagePosition {
            slide: Slide::CalibrationTarget,
            defocus_um: plan.defocus_um,
        })?;
        let grid =
            fpm_physics::calibrate::calibration_grid(&nominal, fpm_physics::calibrate::GRID_HALF);
        let (defocused, r2) = capture_leds(102, &grid, &mut |_| {})?;
        stage.move_to(StagePosition::in_focus(Slide::Sample))?;
        calibration_reports = vec![r1, r2];
        let shots = reference
            .into_iter()
            .map(|s| (s, 0.0))
            .chain(defocused.into_iter().map(|s| (s, plan.defocus_um)));
        let mut ds = dataset(
            plan.out.join("calibration"),
            &system,
            &nominal,
            camera,
            shots,
        )?;
        ds.save()?;
        let options = Options {
            defocus_sigma_um: plan.defocus_sigma_um.abs(),
            ..Options::default()
        };
        let cal = calibrate_dataset(&ds, &options)?;
        std::fs::write(
            plan.out.join("calibration.json"),
            serde_json::to_string_pretty(&cal)?,
        )?;
        page::calibration(&cal, &system, &options, &plan.out);
        geometry = cal.geometry();
        geometry_source = GeometrySource::CalibratedNow;
        if plan.store_geometry {
            let record = board_geometry::from_calibration_file(
                &plan.out.join("calibration.json"),
                &nominal,
            )?;
            let stored = dev
                .store_calibration(Some(record))
                .context("storing the calibration on the board")?;
            tracing::info!(
                "stored on the board: {}",
                board_geometry::describe_stored(&stored)
            );
        }
    }

    // 2. The full acquisition, nearest-first under the geometry in use, streamed into
    // the reconstruction as the frames arrive.
    let all = nominal.leds();
    let leds: Vec<LedIndex> = geometry
        .nearest_first(&all, (0.0, 0.0), &system)
        .into_iter()
        .map(|k| all[k])
        .collect();
    let settings = Settings {
        flatten: plan.flatten,
        ..Settings::default()
    };
    let dark = plan.dark_level as f32;
    let mut streaming: Option<TiledStreaming> = None;
    let mut stream_error: Option<String> = None;
    let mut update_us = vec![];
    let mut last_frame_at = Instant::now();
    let mut done = 0;
    let total = leds.len();
    let mut stream = |shot: ShotView<'_>| {
        done += 1;
        on_frame(done, total);
        last_frame_at = Instant::now();
        if !plan.reconstruct || stream_error.is_some() {
            return;
        }
        let frame = shot.lit_frame(dark);
        let (h, w) = frame.measured.dim();
        let s = streaming.get_or_insert_with(|| {
            TiledStreaming::new(system, geometry, settings, w, h, plan.tile)
        });
        let t = Instant::now();
        if let Err(e) = s.push(&frame) {
            stream_error = Some(e.to_string());
        }
        update_us.push(t.elapsed().as_secs_f64() * 1e6);
    };
    let (mut shots, report) = capture_leds(103, &leds, &mut stream)?;
    // Frames that did not arrive (or could not be labelled) are taken again, once.
    let mut retake = None;
    let mut retake_problem = None;
    if !report.failed && !report.missing.is_empty() {
        let again = report.missing.clone();
        tracing::warn!("re-acquiring {} missing frame(s)", again.len());
        // A retake that goes wrong loses nothing of the first capture.
        match capture_leds(104, &again, &mut stream) {
            Ok((more, r)) => {
                let frames_seen = r.labelled + r.extra_frames + r.ambiguous_frames;
                if frames_seen == 0 {
                    retake_problem = Some(format!(
                        "the camera delivered no frame while {} LED(s) were lit again: has it stopped?",
                        again.len()
                    ));
                }
                shots.extend(more);
                retake = Some(r);
            }
            Err(e) => retake_problem = Some(format!("the retake failed: {e:#}")),
        }
    }
    let tiles = streaming.as_ref().map(|s| s.layout().tiles.len());
    let mut ds = dataset(
        plan.out.clone(),
        &system,
        &nominal,
        camera,
        shots.into_iter().map(|s| (s, 0.0)),
    )?;
    ds.save()?;

    // 3. The rest of the reconstruction, over the frames in the dataset (in memory).
    let mut last_frame_to_final_ms = None;
    if let Some(e) = &stream_error {
        tracing::warn!("streaming reconstruction stopped: {e}");
    }
    let relabelled = report.relabelled + retake.as_ref().map_or(0, |r| r.relabelled);
    let mut reconstruction = None;
    if let (Some(s), false, None) = (streaming, report.failed, &stream_error) {
        let frames = ds.in_focus();
        reconstruction = Some(if relabelled == 0 {
            "streamed"
        } else {
            "dataset"
        });
        let outcome = if relabelled == 0 {
            s.finish(&frames, plan.passes, &|_, _| {})
                .context("finishing the streaming reconstruction")?
        } else {
            // Some frames reached the stream under a label the final pairing changed:
            // what it built is not trusted; the dataset's frames are, so start over.
            tracing::warn!(
                "{relabelled} frame(s) were relabelled after streaming; reconstructing from the dataset instead"
            );
            tiled::reconstruct(
                &system,
                &geometry,
                &frames,
                settings,
                plan.passes + 1,
                plan.tile,
                &|_, _| {},
            )
            .context("reconstructing the dataset")?
        };
        let ms = last_frame_at.elapsed().as_secs_f64() * 1e3;
        last_frame_to_final_ms = Some(ms);
        let request = Request {
            geometry: &geometry,
            source: &geometry_source,
            settings,
            passes: plan.passes,
            tile: plan.tile,
        };
        let mut report = Report::new(
            &ds.dir,
            &ds.manifest.system(),
            &request,
            frames.len(),
            &outcome,
            ms,
        );
        // A simulated rig's truth beside the dataset scores the image (an extra).
        report.versus_truth =
            fpm_host::truth::score_reconstruction(&ds, &outcome.object, settings.upsample);
        report.height_from_boundary =
            fpm_host::reconstruction::boundary_check(&system, &geometry, &frames);
        let reconstruction = Reconstruction::from_outcome(outcome, report);
        write_outputs(&reconstruction, &plan.out.join("reconstruction"))?;
        page::reconstruction(&reconstruction, &system, &nominal, &plan.out);
    }
    let still_missing = match &retake {
        Some(r) => r.missing.clone(),
        None => report.missing.clone(),
    };
    // An incomplete dataset is written, but the run fails: a script must notice.
    let failure = if report.failed {
        Some(report.outcome.clone())
    } else if !still_missing.is_empty() {
        Some(format!(
            "{} LED(s) still have no frame after a retake{}",
            still_missing.len(),
            retake_problem.map_or(String::new(), |p| format!(" ({p})"))
        ))
    } else {
        None
    };
    let summary = AcquireSummary {
        nominal,
        geometry,
        entrance_pupil_mm: system.entrance_pupil_mm,
        geometry_source,
        board_calibration,
        camera_settings,
        calibration: calibration_reports,
        capture: report,
        retake,
        frames_in_dataset: ds.frames.len(),
        still_missing,
        last_frame_to_final_ms,
        update_us_mean: (!update_us.is_empty())
            .then(|| update_us.iter().sum::<f64>() / update_us.len() as f64),
        tiles,
        reconstruction,
    };
    std::fs::write(
        plan.out.join("acquisition.json"),
        serde_json::to_string_pretty(&summary)?,
    )?;
    page::acquisition(&summary, &system, failure.as_deref(), &plan.out);
    if let Some(why) = failure {
        bail!(
            "{why}; the {} frames acquired are labelled and written to {} (acquisition.json lists the missing LEDs)",
            summary.frames_in_dataset,
            plan.out.display()
        );
    }
    Ok(summary)
}

/// Labelled shots (with their defocus) as an in-memory dataset in `dir`; the pixels
/// are moved, not copied.
fn dataset(
    dir: PathBuf,
    system: &System,
    nominal: &LedGeometry,
    camera: CameraSection,
    shots: impl Iterator<Item = (Shot, f64)>,
) -> Result<Dataset> {
    let mut entries = vec![];
    let mut images = vec![];
    let mut bit_depth = None;
    for (shot, defocus_um) in shots {
        bit_depth.get_or_insert(shot.header.bit_depth);
        entries.push(FrameEntry {
            file: String::new(),
            led: shot.led,
            defocus_um,
            exposure_ms: shot.header.exposure_us as f64 / 1e3,
        });
        images.push(shot.pixels);
    }
    let mut manifest = Manifest::new(system, nominal, camera, entries);
    manifest.camera.bit_depth = bit_depth;
    Ok(Dataset::from_frames(&dir, manifest, images)?)
}
