//! A multiplexed acquisition (`fpm acquire --multiplex K`): every LED lit once, K
//! dark-field LEDs at a time (the bright field as `--multiplex-bright` says, one by
//! default), in the sets [`fpm_physics::multiplex::sets`] chooses, through the
//! controller's LED set table (protocol ≥ 1.2) — about K times fewer dark-field frames
//! than one LED each (Tian et al. 2014). The dataset lists each frame's LEDs (`leds = [...]`); the
//! reconstruction runs once the frames are in (the streaming one takes one LED per
//! frame).

use std::time::Instant;

use anyhow::{bail, Context, Result};
use fpm_host::calibration::GeometrySource;
use fpm_host::dataset::{CameraSection, Dataset, FrameEntry, Manifest};
use fpm_host::reconstruction::{reconstruct_with_system, Request};
use fpm_physics::reconstruct::Settings;
use fpm_protocol::SetStep;

use crate::acquisition::{sequence_id, Phase, Plan, Progress, Snapshot};
use crate::capture::{capture_steps, Lighting, News};
use crate::control::{Control, Watcher};
use crate::controller::Controller;
use crate::rig;
use crate::summary::AcquireSummary;

pub use crate::acquisition::MAX_MULTIPLEX;

/// Acquire `plan` (its `multiplex` > 1) into `plan.out`: the sets defined on the board,
/// one sequence lighting each once, the frames written as a dataset, reconstructed if
/// the plan says so, `acquisition.json` written.
pub fn acquire(
    dev: &Controller,
    plan: &Plan,
    mut watcher: impl Watcher,
    control: &Control,
) -> Result<AcquireSummary> {
    plan.validate()?;
    rig::wait_for_camera(&plan.camera)?;
    std::fs::create_dir_all(&plan.out)
        .with_context(|| format!("creating {}", plan.out.display()))?;
    let nominal = rig::nominal_geometry(dev);
    let camera_settings = rig::camera_settings(&plan.camera, &plan.system);
    let board_calibration = rig::stored_board_calibration(dev);
    let (geometry, geometry_source) = match &board_calibration {
        Some(c) => (
            crate::board_geometry::geometry(&nominal, c),
            GeometrySource::Board,
        ),
        None => (nominal, GeometrySource::Controller),
    };
    let sets = fpm_physics::multiplex::sets(&geometry, &plan.system, plan.multiplex, 1);
    dev.define_led_sets(&sets)
        .context("defining the LED sets on the controller")?;
    let steps: Vec<SetStep> = (0..sets.len())
        .map(|set| SetStep {
            set: set as u16,
            color: plan.color,
        })
        .collect();
    let of = steps.len();
    let progress = |frames: usize, phase: Phase| Progress {
        phase,
        frames,
        of,
        labelling: None,
        steps: None,
        cancelled: control.is_cancelled(),
        paused: false,
    };
    watcher.progress(&progress(0, Phase::Capturing));
    let mut arrived = 0usize;
    let (frames, capture) = capture_steps(
        dev,
        &plan.camera,
        sequence_id::CAPTURE,
        Lighting::Sets(&steps),
        plan.step_us(),
        || control.is_cancelled(),
        |news| {
            if let News::Labelled { .. } = news {
                arrived += 1;
                watcher.progress(&progress(arrived, Phase::Capturing));
            }
        },
    )?;
    let last_frame = Instant::now();
    watcher.progress(&progress(arrived, Phase::Writing));
    let mut entries = vec![];
    let mut images = vec![];
    let mut bit_depth = None;
    let mut still_missing = vec![];
    for (set, frame) in sets.iter().zip(frames) {
        let Some((header, pixels)) = frame else {
            still_missing.extend_from_slice(set);
            continue;
        };
        bit_depth.get_or_insert(header.bit_depth);
        entries.push(FrameEntry {
            file: String::new(),
            led: set[0],
            also: set[1..].to_vec(),
            defocus_um: 0.0,
            exposure_ms: header.exposure_us as f64 / 1e3,
        });
        images.push(pixels);
    }
    if entries.is_empty() {
        bail!(
            "no frame of the {of} multiplexed steps came labelled ({}): is the camera triggered by the controller?",
            capture.outcome
        );
    }
    let camera = CameraSection {
        bit_depth,
        ..crate::acquisition::camera_section(plan.dark_level, camera_settings.as_ref())
    };
    let manifest = Manifest::new(&plan.system, &nominal, camera, entries);
    let mut ds = Dataset::from_frames(&plan.out, manifest, images)?;
    ds.save()?;
    let frames_in_dataset = ds.frames.len();
    let mut last_frame_to_final_ms = None;
    let mut reconstruction = None;
    if plan.reconstruct && !control.is_cancelled() {
        watcher.progress(&progress(arrived, Phase::Reconstructing));
        let request = Request {
            geometry: &geometry,
            source: &geometry_source,
            settings: Settings {
                flatten: plan.flatten,
                ..Settings::default()
            },
            passes: plan.passes,
            tile: plan.tile,
        };
        let mut r = reconstruct_with_system(&ds, &plan.system, &request, &|_, _| {})?;
        r.report.versus_truth =
            fpm_host::truth::score_reconstruction(&ds, &r.object, r.report.upsample);
        let dir = plan.out.join("reconstruction");
        fpm_host::reconstruction::write_outputs(&r, &dir)?;
        fpm_report::preview::reconstruction(&r, &dir)?;
        crate::page::reconstruction(&r, &plan.system, &nominal, &plan.out);
        last_frame_to_final_ms = Some(last_frame.elapsed().as_secs_f64() * 1e3);
        reconstruction = Some("dataset");
        if watcher.wants_snapshots() {
            watcher.snapshot(Snapshot {
                frames: frames_in_dataset,
                of,
                finished: true,
                object: r.object.clone(),
                pixel_um: r.report.pixel_um,
            });
        }
    }
    let summary = AcquireSummary {
        nominal,
        geometry,
        entrance_pupil_mm: plan.system.entrance_pupil_mm,
        geometry_source,
        board_calibration,
        camera_settings,
        calibration: vec![],
        capture,
        retake: None,
        frames_in_dataset,
        frames_before: 0,
        still_missing,
        last_frame_to_final_ms,
        update_us_mean: None,
        tiles: None,
        reconstruction,
    };
    std::fs::write(
        plan.out.join("acquisition.json"),
        serde_json::to_string_pretty(&summary)?,
    )
    .with_context(|| format!("writing {}", plan.out.join("acquisition.json").display()))?;
    watcher.progress(&progress(arrived, Phase::Finished));
    if summary.capture.failed || !summary.still_missing.is_empty() {
        bail!(
            "{} of {of} multiplexed frames labelled ({}); the dataset in {} holds those",
            frames_in_dataset,
            summary.capture.outcome,
            plan.out.display()
        );
    }
    Ok(summary)
}
