//! The acquisition on a live rig: the I/O loop that drives the sans-IO
//! [`Acquisition`](crate::acquisition::Acquisition) — the controller's sequences, the
//! camera's frames, the stage, the files and the pages.
//!
//! A frame's way: out of shared memory once ([`crate::capture`]), lent to the streaming
//! reconstruction as it arrives (each tile takes its share as amplitude, the one
//! conversion, in `fpm_physics::frame`), moved into the in-memory dataset, written to
//! disk, and lent again from there for the last passes. Calibration frames are used
//! from memory too.

use std::cell::Cell;

use anyhow::{bail, Context, Result};
use fpm_physics::{LedGeometry, System};

use crate::acquisition::sequence_id;
pub use crate::acquisition::Plan;
use crate::acquisition::{Acquisition, Action, Event, Rig};
use crate::board_geometry;
use crate::capture::{capture, News, Sequence};
pub use crate::control::{Control, Watcher};
use crate::controller::Controller;
use crate::journal::Journal;
use crate::page;
pub use crate::rig::{board_geometry, nominal_geometry, stored_board_calibration, CAMERA_WAIT};
use crate::rig::{camera_settings, wait_for_camera};
use crate::stage::FocusStage;
pub use crate::summary::AcquireSummary;

/// Run the acquisition of `plan` with controller `dev` and focus stage `stage`.
/// `watcher` sees its progress after every event; `control` pauses, resumes or
/// cancels it (a cancel aborts the running sequence and writes what was captured; the
/// run then fails, saying so). Frames that arrived are labelled and written even when
/// the controller is lost; the error then says so.
pub fn acquire(
    dev: &Controller,
    stage: &mut dyn FocusStage,
    plan: &Plan,
    watcher: impl Watcher,
    control: &Control,
) -> Result<AcquireSummary> {
    if !plan.multiplex.is_one() {
        return crate::multiplexed::acquire(dev, plan, watcher, control);
    }
    run(dev, stage, plan, None, watcher, control)
}

/// Complete the acquisition an earlier run of `plan` left in `plan.out` (interrupted,
/// cancelled, failed part-way): its frames are kept (a journal a kill left is made a
/// dataset first) and only the LEDs they lack are lit, with the geometry it used (its
/// `calibration.json` when it calibrated). `plan.calibrate` is ignored: the first run
/// calibrated, or did not.
pub fn resume(
    dev: &Controller,
    stage: &mut dyn FocusStage,
    plan: &Plan,
    watcher: impl Watcher,
    control: &Control,
) -> Result<AcquireSummary> {
    let out = &plan.out;
    if !plan.multiplex.is_one() {
        bail!(
            "{}: a multiplexed acquisition cannot be resumed (its frames are not journalled yet): acquire again",
            out.display()
        );
    }
    crate::journal::recover(out)?;
    if !out.join("dataset.toml").is_file() {
        bail!(
            "{}: no frames to resume from (no dataset.toml, no journal): acquire again",
            out.display()
        );
    }
    let before = fpm_host::dataset::Dataset::load(out)
        .with_context(|| format!("the partial dataset in {}", out.display()))?;
    let system = before.manifest.system();
    if let Some(what) = differs(&system, &plan.system) {
        bail!(
            "{}: its dataset was acquired with {what}; resume with the plan it was acquired with",
            out.display()
        );
    }
    let geometry = match out.join("calibration.json") {
        file if file.is_file() => {
            let g = fpm_host::calibration::PlacementFile::read(&file)?
                .geometry(&before.manifest.geometry());
            Some((g, fpm_host::calibration::GeometrySource::File(file)))
        }
        _ => None,
    };
    let plan = Plan {
        calibrate: false,
        store_geometry: false,
        ..plan.clone()
    };
    run(
        dev,
        stage,
        &plan,
        Some((shots_of(before)?, geometry)),
        watcher,
        control,
    )
}

/// The first optical setting in which `a` and `b` differ, named as a request names it.
fn differs(a: &System, b: &System) -> Option<String> {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-6 * x.abs().max(y.abs()).max(1e-9);
    [
        ("wavelength_um", a.wavelength_um, b.wavelength_um),
        ("na", a.na, b.na),
        ("magnification", a.magnification, b.magnification),
        ("pixel_um", a.pixel_size_um, b.pixel_size_um),
    ]
    .into_iter()
    .find(|(_, x, y)| !close(*x, *y))
    .map(|(name, x, y)| format!("{name} {x}, not {y}"))
}

/// A dataset's frames as labelled shots (their headers rebuilt from the manifest:
/// exposure, size, bit depth).
fn shots_of(dataset: fpm_host::dataset::Dataset) -> Result<Vec<crate::capture::Shot>> {
    let bit_depth = dataset.manifest.camera.bit_depth.unwrap_or(16);
    dataset
        .frames
        .into_iter()
        .map(|f| {
            let fpm_physics::frame::Pixels::U16(pixels) = f.raw else {
                bail!(
                    "{}: not 16-bit counts; only an acquisition's own frames can be resumed",
                    f.entry.file
                );
            };
            let (h, w) = pixels.dim();
            let header = fpm_frames::FrameHeader {
                frame_number: 0,
                timestamp_ns: 0,
                exposure_us: (f.entry.exposure_ms * 1e3).round() as u32,
                width: w as u32,
                height: h as u32,
                bit_depth,
                pixel_count: (w * h) as u64,
                camera_id: 0,
                flags: 0,
            };
            Ok(crate::capture::Shot {
                led: f.entry.led,
                header,
                pixels,
            })
        })
        .collect()
}

/// The labelled frames and placement of a run being resumed.
type Before = (
    Vec<crate::capture::Shot>,
    Option<(LedGeometry, fpm_host::calibration::GeometrySource)>,
);

fn run(
    dev: &Controller,
    stage: &mut dyn FocusStage,
    plan: &Plan,
    before: Option<Before>,
    mut watcher: impl Watcher,
    control: &Control,
) -> Result<AcquireSummary> {
    plan.validate()?;
    wait_for_camera(&plan.camera)?;
    std::fs::create_dir_all(&plan.out)
        .with_context(|| format!("creating {}", plan.out.display()))?;
    let rig = Rig {
        nominal: nominal_geometry(dev),
        stored: stored_board_calibration(dev),
        camera_settings: camera_settings(&plan.camera, &plan.system),
    };
    let nominal = rig.nominal;
    let camera = crate::acquisition::camera_section(plan.dark_level, rig.camera_settings.as_ref());
    // The frames an earlier run wrote, which a new journal must carry on.
    let mut adopted = vec![];
    let mut acq = match before {
        None => Acquisition::new(plan.clone(), rig)?,
        Some((shots, geometry)) => {
            adopted = shots
                .iter()
                .map(|s| Adopted {
                    led: s.led,
                    exposure_us: s.header.exposure_us,
                    bit_depth: s.header.bit_depth,
                    checksum: crate::journal::checksum(s.pixels.iter()),
                })
                .collect();
            Acquisition::resume(plan.clone(), rig, shots, geometry)?
        }
    };
    // The capture's frames go to disk as they are labelled (what a kill leaves).
    let mut journal: Option<Journal> = None;
    // A cancel or a pause reaches the machine before the next action, and before the
    // outcome of the action it interrupted (a sequence aborted by it is not then
    // retaken). `pause_seen` latches a pause the capture obeyed, however briefly it
    // lasted.
    let pause_seen = Cell::new(false);
    let deliver = |acq: &mut Acquisition| {
        let p = acq.progress();
        if control.is_cancelled() && !p.cancelled {
            acq.handle(Event::Cancel);
        }
        let pause = control.is_paused() || pause_seen.replace(false);
        if pause != p.paused {
            acq.handle(if pause { Event::Pause } else { Event::Resume });
        }
    };
    let watch = |acq: &mut Acquisition, watcher: &mut dyn Watcher| {
        watcher.progress(&acq.progress());
        if watcher.wants_snapshots() {
            if let Some(snapshot) = acq.snapshot() {
                watcher.snapshot(snapshot);
            }
        }
    };
    loop {
        deliver(&mut acq);
        watch(&mut acq, &mut watcher);
        let event = match acq.next_action() {
            Action::Paused => {
                watch(&mut acq, &mut watcher);
                while control.is_paused() && !control.is_cancelled() {
                    std::thread::sleep(std::time::Duration::from_millis(5));
                }
                continue;
            }
            Action::MoveStage(to) => {
                stage.move_to(to)?;
                Event::StageArrived
            }
            Action::RunSequence { id, leds } => {
                let captures = matches!(id, sequence_id::CAPTURE | sequence_id::RETAKE);
                if captures && journal.is_none() {
                    journal = start_journal(plan, &nominal, camera, &adopted);
                }
                let mut on_news = |news: News<'_>| {
                    // Journal trouble is an optional extra's: warned once, then the
                    // frames are written when the capture ends, as ever.
                    if let Some(j) = journal.as_mut().filter(|_| captures) {
                        if let Err(e) = j.record(&news, &leds) {
                            tracing::warn!("frames are no longer written as they arrive ({e:#}); they are written when the capture ends");
                            journal = None;
                        }
                    }
                    match news {
                        News::Labelling(waiting) => acq.handle(Event::Labelling(waiting)),
                        News::Steps(steps) => acq.handle(Event::Steps(steps)),
                        News::Labelled { .. } => {
                            if let Some(shot) = news.shot(&leds) {
                                watcher.frame(&shot);
                                acq.handle(Event::Frame(shot));
                            }
                        }
                        // The raw record: the journal's alone.
                        News::Started { .. } | News::Step { .. } | News::Arrived { .. } => return,
                    }
                    watch(&mut acq, &mut watcher);
                };
                let sequence = Sequence {
                    id,
                    leds: &leds,
                    color: plan.color,
                    exposure_us: plan.step_us(),
                };
                // A pause cuts the capture short (the LEDs it did not reach wait); the
                // calibration's sequences and a retake are short, and finish first.
                let stop = || {
                    let pause = id == sequence_id::CAPTURE && control.is_paused();
                    if pause {
                        pause_seen.set(true);
                    }
                    control.is_cancelled() || pause
                };
                let mut captured = capture(dev, &plan.camera, &sequence, stop, &mut on_news);
                if let (Ok((_, report)), Some(asked)) = (&mut captured, control.cancelled_at()) {
                    report.cancel_to_leds_off_ms = report
                        .leds_off_at
                        .map(|off| off.saturating_duration_since(asked).as_secs_f64() * 1e3);
                }
                Event::SequenceEnded(captured)
            }
            Action::Finished(result) => {
                // A run that ended without a dataset of its own (no frame labelled: a
                // cancel before the first) is over too: its journal has served.
                if result.is_ok() {
                    if let Some(j) = journal.take() {
                        j.finish();
                    }
                }
                return *result;
            }
            write => {
                write_out(write, dev, plan, &nominal, &mut journal)?;
                Event::Done
            }
        };
        deliver(&mut acq);
        acq.handle(event);
    }
}

/// Carry out one of the machine's writes (and its one board request) in `plan.out`.
fn write_out(
    action: Action<'_>,
    dev: &Controller,
    plan: &Plan,
    nominal: &LedGeometry,
    journal: &mut Option<Journal>,
) -> Result<()> {
    let (out, system) = (&plan.out, &plan.system);
    match action {
        // The capture's dataset: frames the journal wrote with these pixels stay.
        Action::WriteDataset(dataset) if dataset.dir == *out => match journal.take() {
            Some(j) => {
                dataset.save_reusing(|path, pixels| j.holds(path, pixels))?;
                j.finish();
            }
            None => dataset.save()?,
        },
        Action::WriteDataset(dataset) => dataset.save()?,
        Action::WriteCalibration {
            calibration,
            options,
        } => {
            let json = serde_json::to_string_pretty(calibration)?;
            std::fs::write(out.join("calibration.json"), json)?;
            page::calibration(calibration, system, options, out);
        }
        Action::StoreOnBoard { nominal } => {
            let file = out.join("calibration.json");
            let record = board_geometry::from_calibration_file(&file, nominal)?;
            let stored = dev
                .store_calibration(Some(record))
                .context("storing the calibration on the board")?;
            let stored = board_geometry::describe_stored(&stored);
            tracing::info!("stored on the board: {stored}");
        }
        Action::WriteReconstruction {
            reconstruction: r,
            dataset,
            upsample,
        } => {
            // A simulated rig's truth beside the dataset scores the image (an extra).
            r.report.versus_truth =
                fpm_host::truth::score_reconstruction(dataset, &r.object, upsample);
            let dir = out.join("reconstruction");
            fpm_host::reconstruction::write_outputs(r, &dir)?;
            fpm_report::preview::reconstruction(r, &dir)?;
            page::reconstruction(r, system, nominal, out);
        }
        Action::WriteSummary { summary, failure } => {
            let json = serde_json::to_string_pretty(summary)?;
            std::fs::write(out.join("acquisition.json"), json)?;
            page::acquisition(summary, system, failure, out);
        }
        Action::MoveStage(_)
        | Action::RunSequence { .. }
        | Action::Paused
        | Action::Finished(_) => {
            bail!("the acquisition asked for a write that is not one")
        }
    }
    Ok(())
}

/// A frame an earlier run wrote, carried on by a resumed run's journal.
struct Adopted {
    led: fpm_protocol::LedIndex,
    exposure_us: u32,
    bit_depth: u32,
    checksum: u64,
}

/// The capture's journal in `plan.out` (an optional extra: without it the frames are
/// written when the capture ends, as ever), carrying on the frames of the run resumed.
/// Its dataset.toml is then removed: the journal holds all it said, and a kill makes a
/// dataset of the journal only where there is no dataset.toml.
fn start_journal(
    plan: &Plan,
    nominal: &LedGeometry,
    camera: fpm_host::dataset::CameraSection,
    adopted: &[Adopted],
) -> Option<Journal> {
    let manifest = fpm_host::dataset::Manifest::new(&plan.system, nominal, camera, vec![]);
    let started = Journal::start(&plan.out, &manifest).and_then(|mut j| {
        for a in adopted {
            j.adopt(a.led, a.exposure_us, a.bit_depth, a.checksum)?;
        }
        if !adopted.is_empty() {
            let toml = plan.out.join("dataset.toml");
            std::fs::remove_file(&toml)
                .with_context(|| format!("removing {} (the journal holds it)", toml.display()))?;
        }
        Ok(j)
    });
    started
        .map_err(|e| {
            tracing::warn!(
                "frames will be written when the capture ends, not as they arrive: {e:#}"
            )
        })
        .ok()
}
