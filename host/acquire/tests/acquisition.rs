//! The acquisition's state machine, driven synchronously through generated runs as
//! `firmware/core` is: sequences that lose frames, break off (controller lost) or
//! cannot start, retakes that bring nothing, frames handed out in any order, a pause
//! that cuts the capture short and holds a while, and a cancel at any point. Whatever
//! happens, the machine
//!
//! * runs each sequence with the stage where its purpose needs it, and starts none
//!   after a cancel or while paused;
//! * after a pause, captures exactly the LEDs the cut capture did not label;
//! * captures every LED of the array once, and retakes exactly the LEDs the capture
//!   missed, once, only when the capture neither failed nor was cancelled;
//! * writes a dataset in which every frame sits under the LED that lit it, each LED at
//!   most once, and the summary's missing LEDs are exactly those without a frame;
//! * finishes, with success exactly when every LED has its frame and nobody cancelled.
//!
//! The frames are tiny (their pixels carry the LED that lit them) and the
//! reconstruction is off: the live suites (`tests/`) run the same machine with real
//! frames, the firmware and the reconstruction.
//!
//! 10⁴ generated runs per test run (`FPM_ACQUISITION_CASES` sets another count).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

use fpm_acquire::acquisition::{sequence_id, Acquisition, Action, Event, Phase, Plan, Rig};
use fpm_acquire::labeller::Waiting;
use fpm_acquire::{CaptureReport, Shot, Slide, StagePosition};
use fpm_frames::{FrameHeader, ServiceNames};
use fpm_host::calibration::GeometrySource;
use fpm_host::dataset::{Dataset, Pixels};
use fpm_physics::reconstruct::Flatten;
use fpm_physics::simulate::{CalibrationScene, SimFrame};
use fpm_physics::{LedGeometry, System};
use fpm_protocol::{LedIndex, Rgb};
use ndarray::Array2;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};

/// How one generated rig behaves.
#[derive(Debug, Clone)]
struct Case {
    rows: usize,
    cols: usize,
    calibrate: bool,
    store_geometry: bool,
    /// Each frame is lost with this probability.
    drop: f64,
    /// A sequence breaks off (the controller lost) with this probability.
    lost: f64,
    /// A sequence cannot start with this probability.
    refused: f64,
    /// The camera has stopped by the retake.
    camera_stops: bool,
    /// Cancel before this event (None: never).
    cancel_at: Option<usize>,
    /// Pause as the capture starts (the driver then cuts it short), holding for this
    /// many `Paused` actions before resuming (None: never).
    pause_holds: Option<usize>,
    seed: u64,
}

fn cases() -> impl Strategy<Value = Case> {
    (
        (
            3usize..16,
            3usize..16,
            prop::bool::weighted(0.1),
            any::<bool>(),
        ),
        (
            prop_oneof![Just(0.0), 0.0..0.3],
            prop_oneof![Just(0.0), 0.0..0.2],
            prop_oneof![Just(0.0), 0.0..0.1],
            any::<bool>(),
        ),
        (
            prop::option::weighted(0.4, 0usize..120),
            prop::option::weighted(0.3, 0usize..3),
            any::<u64>(),
        ),
    )
        .prop_map(
            |(
                (rows, cols, calibrate, store_geometry),
                (drop, lost, refused, camera_stops),
                (cancel_at, pause_holds, seed),
            )| Case {
                rows,
                cols,
                calibrate,
                store_geometry,
                drop,
                lost,
                refused,
                camera_stops,
                cancel_at,
                pause_holds,
                seed,
            },
        )
}

const SIDE: usize = 16;

/// How many generated runs ended each way, so that the generator is seen to reach
/// every branch: succeeded, failed with a dataset, failed without one, calibrated,
/// retook, cut short by a cancel, paused and resumed.
static ENDINGS: [AtomicUsize; 7] = [const { AtomicUsize::new(0) }; 7];

fn count(k: usize) {
    ENDINGS[k].fetch_add(1, Ordering::Relaxed);
}

/// The calibration slide under a 21×21 array off its nominal place, simulated once
/// with the full wave-optics model (the runs that calibrate use this array).
struct CalibrationSlide {
    scene: CalibrationScene,
    frames: Vec<SimFrame>,
}

fn calibration_slide() -> &'static CalibrationSlide {
    static SLIDE: OnceLock<CalibrationSlide> = OnceLock::new();
    SLIDE.get_or_init(|| {
        let truth = LedGeometry {
            dx_mm: 1.2,
            dy_mm: -0.8,
            theta_deg: 2.0,
            height_mm: 90.0,
            ..LedGeometry::paper()
        };
        let scene = CalibrationScene::paper(truth, 7);
        let frames = scene.acquire();
        CalibrationSlide { scene, frames }
    })
}

/// The simulated calibration frame of `led` at `defocus_um`.
fn calibration_shot(led: LedIndex, defocus_um: f64, frame_number: u64) -> Option<Shot> {
    let f = calibration_slide()
        .frames
        .iter()
        .find(|f| f.led == led && f.defocus_um == defocus_um)?;
    let (h, w) = f.counts.dim();
    Some(Shot {
        led,
        header: FrameHeader {
            frame_number,
            exposure_us: (f.exposure_ms * 1e3) as u32,
            width: w as u32,
            height: h as u32,
            bit_depth: 12,
            pixel_count: (w * h) as u64,
            ..FrameHeader::default()
        },
        pixels: f.counts.clone(),
    })
}

/// The frame `led` lights: its pixels say which LED it was.
fn shot(led: LedIndex, frame_number: u64) -> Shot {
    let tag = 1000 + 100 * led.row as u16 + led.col as u16;
    Shot {
        led,
        header: FrameHeader {
            frame_number,
            exposure_us: 10_000,
            width: SIDE as u32,
            height: SIDE as u32,
            bit_depth: 12,
            pixel_count: (SIDE * SIDE) as u64,
            ..FrameHeader::default()
        },
        pixels: Array2::from_elem((SIDE, SIDE), tag),
    }
}

/// Which LED a dataset frame's pixels say lit it.
fn tag(pixels: &Pixels) -> LedIndex {
    let Pixels::U16(p) = pixels else {
        panic!("the dataset holds other than the 16-bit frames it was given")
    };
    let t = p[[0, 0]] - 1000;
    LedIndex::new((t / 100) as u8, (t % 100) as u8)
}

/// The plan of `case`: a run that calibrates uses the simulated slide's optics.
fn plan(case: &Case, out: &Path) -> Plan {
    let slide = case.calibrate.then(calibration_slide);
    let plan = Plan {
        camera: ServiceNames::for_camera("never-opened"),
        out: out.to_path_buf(),
        calibrate: case.calibrate,
        capture: true,
        store_geometry: case.store_geometry,
        reconstruct: false,
        step_ms: 10.0,
        defocus_um: 60.0,
        defocus_sigma_um: 2.0,
        color: Rgb { r: 0, g: 255, b: 0 },
        dark_level: 100.0,
        system: System {
            wavelength_um: 0.52,
            na: 0.1,
            magnification: 4.0,
            pixel_size_um: 6.5,
            entrance_pupil_mm: None,
        },
        passes: 2,
        tile: None,
        flatten: Flatten::Keep,
        snapshot_every: 0,
        geometry: None,
        leds: None,
        multiplex: fpm_physics::multiplex::Multiplex::ONE,
    };
    match slide {
        Some(s) => Plan {
            system: s.scene.system,
            defocus_um: s.scene.defocus_um,
            dark_level: s.scene.camera.dark_level_dn,
            ..plan
        },
        None => plan,
    }
}

/// What a run did, as the driver saw it.
#[derive(Default)]
struct Seen {
    sequences: Vec<(u32, Vec<LedIndex>)>,
    capture_missing: Option<Vec<LedIndex>>,
    capture_failed: bool,
    delivered: BTreeSet<LedIndex>,
    dataset_leds: Option<Vec<LedIndex>>,
    summary_missing: Option<Vec<LedIndex>>,
    summaries: usize,
    stored: usize,
    cancelled: bool,
    cut: bool,
    calibrated: bool,
    /// Paused and not yet resumed.
    paused: bool,
    /// The pause was made (once per run).
    pause_made: bool,
}

/// Drive one generated run; every assertion about the actions' order is made as they
/// come, the rest at the end.
/// Whether the run succeeded.
fn run(case: &Case) -> Result<bool, TestCaseError> {
    let out = PathBuf::from("/nonexistent/acquisition");
    let nominal = if case.calibrate {
        LedGeometry::paper()
    } else {
        LedGeometry::grid(
            case.rows,
            case.cols,
            4.0,
            60.0,
            LedIndex::new((case.rows / 2) as u8, (case.cols / 2) as u8),
        )
    };
    let plan = plan(case, &out);
    let defocus_um = plan.defocus_um;
    // Half the runs with a camera that states its settings as the virtual camera
    // does (its gamma needs a bit depth even in a dataset without frames).
    let camera_settings = case
        .seed
        .is_multiple_of(2)
        .then(|| serde_json::json!({"encoding_gamma": 1.0, "bit_depth": 12}));
    let rig = Rig {
        nominal,
        stored: None,
        camera_settings,
    };
    let mut acq = Acquisition::new(plan, rig).map_err(|e| TestCaseError::fail(e.to_string()))?;
    let mut rng = StdRng::seed_from_u64(case.seed);
    let mut stage: Option<StagePosition> = None;
    let mut seen = Seen::default();
    let mut events = 0usize;
    let mut frame_number = 0u64;
    let mut holds = 0usize;
    let cancel_due = |acq: &mut Acquisition, seen: &mut Seen, events: &mut usize| {
        if Some(*events) == case.cancel_at {
            acq.handle(Event::Cancel);
            seen.cancelled = true;
        }
        *events += 1;
    };
    for _ in 0..100 {
        cancel_due(&mut acq, &mut seen, &mut events);
        let event = match acq.next_action() {
            Action::Paused => {
                prop_assert!(seen.paused, "held without a pause");
                prop_assert_eq!(acq.progress().phase, Phase::Paused);
                holds += 1;
                if holds > case.pause_holds.unwrap_or(0) {
                    acq.handle(Event::Resume);
                    seen.paused = false;
                }
                continue;
            }
            Action::MoveStage(to) => {
                prop_assert!(!seen.paused, "the stage moved while paused");
                stage = Some(to);
                Event::StageArrived
            }
            Action::RunSequence { id, leds } => {
                prop_assert!(!seen.cancelled, "sequence {id} started after a cancel");
                prop_assert!(!seen.paused, "sequence {id} started while paused");
                if id == sequence_id::CAPTURE && seen.pause_made {
                    // The capture goes on with exactly what the cut one did not label.
                    prop_assert_eq!(
                        Some(&leds),
                        seen.capture_missing.as_ref(),
                        "the capture after a pause is not the LEDs still to take"
                    );
                }
                // The pause comes as the capture starts; the driver cuts it short.
                let cut_at =
                    (id == sequence_id::CAPTURE && case.pause_holds.is_some() && !seen.pause_made)
                        .then(|| {
                            acq.handle(Event::Pause);
                            seen.paused = true;
                            seen.pause_made = true;
                            rng.gen_range(0..=leds.len())
                        });
                let needed = match id {
                    sequence_id::REFERENCE => {
                        Some(StagePosition::in_focus(Slide::CalibrationTarget))
                    }
                    sequence_id::CALIBRATION_GRID => Some(StagePosition {
                        slide: Slide::CalibrationTarget,
                        defocus_um,
                    }),
                    // Never moved: where the user left it, on the sample in focus.
                    _ if stage.is_none() => None,
                    _ => Some(StagePosition::in_focus(Slide::Sample)),
                };
                prop_assert_eq!(stage, needed, "sequence {} with the stage elsewhere", id);
                seen.sequences.push((id, leds.clone()));
                if rng.gen_bool(case.refused) {
                    // After a pause, the frames of the capture's first part are kept
                    // and the run fails.
                    seen.capture_failed |= id == sequence_id::CAPTURE;
                    Event::SequenceEnded(Err(anyhow::anyhow!(
                        "the controller refused the sequence"
                    )))
                } else {
                    let lost_at = rng
                        .gen_bool(case.lost)
                        .then(|| rng.gen_range(0..=leds.len()));
                    let silent = id == sequence_id::RETAKE && case.camera_stops;
                    let mut shots: Vec<Shot> = leds
                        .iter()
                        .enumerate()
                        .filter(|&(k, _)| lost_at.is_none_or(|at| k < at))
                        .filter(|&(k, _)| cut_at.is_none_or(|at| k < at))
                        .filter(|_| !silent && !rng.gen_bool(case.drop))
                        .filter_map(|(_, &led)| {
                            frame_number += 1;
                            match id {
                                sequence_id::REFERENCE => calibration_shot(led, 0.0, frame_number),
                                sequence_id::CALIBRATION_GRID => {
                                    calibration_shot(led, defocus_um, frame_number)
                                }
                                _ => Some(shot(led, frame_number)),
                            }
                        })
                        .collect();
                    let order: Vec<usize> = {
                        let mut o: Vec<usize> = (0..shots.len()).collect();
                        o.shuffle(&mut rng);
                        o
                    };
                    // The capture says why its frames wait for labels, while they do:
                    // the progress carries it until the sequence ends.
                    if id == sequence_id::CAPTURE {
                        acq.handle(Event::Labelling(Some(Waiting::Fingerprint)));
                        prop_assert_eq!(acq.progress().labelling, Some(Waiting::Fingerprint));
                    }
                    for k in order {
                        cancel_due(&mut acq, &mut seen, &mut events);
                        acq.handle(Event::Frame(shots[k].view()));
                        if id == sequence_id::CAPTURE || id == sequence_id::RETAKE {
                            seen.delivered.insert(shots[k].led);
                        }
                    }
                    shots.shuffle(&mut rng);
                    let got: BTreeSet<LedIndex> = shots.iter().map(|s| s.led).collect();
                    let missing: Vec<LedIndex> =
                        leds.iter().copied().filter(|l| !got.contains(l)).collect();
                    let report = CaptureReport {
                        requested: leds.len(),
                        labelled: shots.len(),
                        missing: missing.clone(),
                        extra_frames: 0,
                        ambiguous_frames: 0,
                        clock_offset_ns: 0,
                        clock_drift_ppm: 0.0,
                        stamp_spread_ms: 0.1,
                        clock_problem: None,
                        seconds: 1.0,
                        frames_per_s: shots.len() as f64,
                        outcome: if lost_at.is_some() {
                            "the LED controller was lost mid-sequence".into()
                        } else if cut_at.is_some() {
                            "Aborted".into()
                        } else {
                            "done".into()
                        },
                        failed: lost_at.is_some(),
                        relabelled: 0,
                        sequences: 1,
                        ..CaptureReport::default()
                    };
                    if id == sequence_id::CAPTURE || id == sequence_id::RETAKE {
                        // A cancel before the last sequence ended cut it short.
                        seen.cut = seen.cancelled;
                    }
                    if id == sequence_id::CAPTURE {
                        seen.capture_missing = Some(missing);
                        seen.capture_failed = report.failed;
                    }
                    Event::SequenceEnded(Ok((shots, report)))
                }
            }
            Action::WriteDataset(dataset) => {
                check_dataset(dataset, &out, &nominal, defocus_um, &mut seen)?;
                Event::Done
            }
            Action::WriteCalibration { .. } => {
                count(3);
                seen.calibrated = true;
                Event::Done
            }
            Action::StoreOnBoard { .. } => {
                seen.stored += 1;
                Event::Done
            }
            Action::WriteReconstruction { .. } => {
                return Err(TestCaseError::fail("a reconstruction with reconstruct off"))
            }
            Action::WriteSummary { summary, failure } => {
                seen.summaries += 1;
                let captures = seen
                    .sequences
                    .iter()
                    .filter(|(id, _)| *id == sequence_id::CAPTURE)
                    .count();
                prop_assert_eq!(summary.capture.sequences, captures);
                prop_assert_eq!(
                    summary.frames_in_dataset,
                    seen.dataset_leds.as_ref().map_or(0, |d| d.len())
                );
                prop_assert_eq!(
                    failure.is_none(),
                    summary.still_missing.is_empty() && !seen.cut && !seen.capture_failed
                );
                seen.summary_missing = Some(summary.still_missing.clone());
                if seen.calibrated {
                    // The capture ran under the geometry just calibrated (the slide's
                    // array is 1.2 mm, -0.8 mm, 2° and 90 mm off its nominal place).
                    let g = summary.geometry;
                    prop_assert_eq!(&summary.geometry_source, &GeometrySource::CalibratedNow);
                    prop_assert!(
                        (g.dx_mm - 1.2).abs() < 0.3
                            && (g.dy_mm + 0.8).abs() < 0.3
                            && (g.theta_deg - 2.0).abs() < 1.0
                            && (g.height_mm - 90.0).abs() < 3.0,
                        "the capture's geometry is not the calibrated one: {:?}",
                        g
                    );
                } else {
                    prop_assert_eq!(&summary.geometry_source, &GeometrySource::Controller);
                    prop_assert_eq!(summary.geometry, nominal);
                }
                Event::Done
            }
            Action::Finished(result) => return check_end(case, &nominal, &seen, *result, &acq),
        };
        let ended = matches!(event, Event::SequenceEnded(_));
        acq.handle(event);
        if ended {
            prop_assert_eq!(acq.progress().labelling, None, "after its sequence ended");
        }
    }
    Err(TestCaseError::fail(
        "the acquisition did not finish in 100 actions",
    ))
}

fn check_dataset(
    dataset: &Dataset,
    out: &Path,
    nominal: &LedGeometry,
    defocus_um: f64,
    seen: &mut Seen,
) -> Result<(), TestCaseError> {
    let leds: Vec<LedIndex> = dataset.frames.iter().map(|f| f.entry.led).collect();
    let unique: BTreeSet<LedIndex> = leds.iter().copied().collect();
    if dataset.dir == out.join("calibration") {
        // The centre LED twice: the focused reference, and in the defocused grid.
        let grid = fpm_physics::calibrate::calibration_grid(nominal, 2);
        let expected: BTreeSet<(LedIndex, bool)> = grid
            .into_iter()
            .map(|led| (led, true))
            .chain([(nominal.center, false)])
            .collect();
        let taken: Vec<(LedIndex, bool)> = dataset
            .frames
            .iter()
            .map(|f| (f.entry.led, f.entry.defocus_um == defocus_um))
            .collect();
        for frame in &dataset.frames {
            let Pixels::U16(pixels) = &frame.raw else {
                return Err(TestCaseError::fail("a calibration frame not as taken"));
            };
            let taken = calibration_shot(frame.entry.led, frame.entry.defocus_um, 0);
            prop_assert!(
                taken.is_some_and(|t| t.pixels == *pixels),
                "a calibration frame under another LED or defocus"
            );
        }
        let unique_taken: BTreeSet<(LedIndex, bool)> = taken.iter().copied().collect();
        prop_assert_eq!(unique_taken.len(), taken.len(), "a calibration frame twice");
        prop_assert!(
            unique_taken.is_subset(&expected),
            "a calibration frame off the grid or at the wrong defocus"
        );
        return Ok(());
    }
    for frame in &dataset.frames {
        prop_assert_eq!(
            tag(&frame.raw),
            frame.entry.led,
            "a frame under another LED"
        );
    }
    prop_assert_eq!(
        unique.len(),
        leds.len(),
        "an LED twice in a dataset: {:?}",
        leds
    );
    prop_assert_eq!(&dataset.dir, out);
    prop_assert!(seen.dataset_leds.is_none(), "the dataset written twice");
    prop_assert_eq!(
        &unique,
        &seen.delivered,
        "the dataset differs from the frames streamed"
    );
    seen.dataset_leds = Some(leds);
    Ok(())
}

fn check_end(
    case: &Case,
    nominal: &LedGeometry,
    seen: &Seen,
    result: anyhow::Result<fpm_acquire::AcquireSummary>,
    acq: &Acquisition,
) -> Result<bool, TestCaseError> {
    prop_assert_eq!(acq.progress().phase, Phase::Finished);
    let mut ids: Vec<u32> = seen.sequences.iter().map(|(id, _)| *id).collect();
    let captures = ids.iter().filter(|&&id| id == sequence_id::CAPTURE).count();
    // A pause splits the capture in two.
    prop_assert!(captures <= 1 + usize::from(seen.pause_made));
    if captures == 2 {
        count(6);
    }
    ids.dedup();
    let calibration: &[u32] = if case.calibrate {
        &[sequence_id::REFERENCE, sequence_id::CALIBRATION_GRID]
    } else {
        &[]
    };
    // The sequences in their order, each a prefix of the full run.
    let full: Vec<u32> = calibration
        .iter()
        .copied()
        .chain([sequence_id::CAPTURE, sequence_id::RETAKE])
        .collect();
    prop_assert!(full.starts_with(&ids), "sequences out of order: {:?}", ids);
    let captured = ids.contains(&sequence_id::CAPTURE);
    prop_assert!(seen.stored <= usize::from(case.store_geometry && case.calibrate));
    if captured && case.calibrate && case.store_geometry {
        prop_assert_eq!(
            seen.stored,
            1,
            "the calibration was not stored on the board"
        );
    }
    let capture = seen
        .sequences
        .iter()
        .find(|(id, _)| *id == sequence_id::CAPTURE);
    if let Some((_, leds)) = capture {
        let all: BTreeSet<LedIndex> = nominal.leds().into_iter().collect();
        let lit: BTreeSet<LedIndex> = leds.iter().copied().collect();
        prop_assert_eq!(lit.len(), leds.len(), "an LED twice in the capture");
        prop_assert_eq!(lit, all, "the capture is not the whole array");
    }
    let retake = seen
        .sequences
        .iter()
        .find(|(id, _)| *id == sequence_id::RETAKE);
    match (retake, &seen.capture_missing) {
        (Some((_, leds)), Some(missing)) => {
            prop_assert_eq!(
                leds,
                missing,
                "the retake is not the capture's missing LEDs"
            );
            prop_assert!(!seen.capture_failed);
        }
        (None, Some(missing)) => prop_assert!(
            missing.is_empty() || seen.capture_failed || seen.cancelled,
            "no retake of {} missing LEDs",
            missing.len()
        ),
        _ => {}
    }
    if retake.is_some() {
        count(4);
    }
    if seen.cut {
        count(5);
    }
    count(match (&result, &seen.dataset_leds) {
        (Ok(_), _) => 0,
        (Err(_), Some(_)) => 1,
        (Err(_), None) => 2,
    });
    let Some(written) = &seen.dataset_leds else {
        // Nothing captured: calibration stopped, the capture refused, or a cancel first;
        // or a capture that labelled no frame, whose summary says every LED is missing.
        prop_assert!(result.is_err(), "success without a dataset");
        if seen.summaries == 1 {
            let missing: BTreeSet<LedIndex> =
                seen.summary_missing.iter().flatten().copied().collect();
            let all: BTreeSet<LedIndex> = nominal.leds().into_iter().collect();
            prop_assert_eq!(missing, all, "a summary without a dataset misses an LED");
        } else {
            prop_assert_eq!(seen.summaries, 0);
        }
        return Ok(false);
    };
    prop_assert_eq!(seen.summaries, 1);
    let written: BTreeSet<LedIndex> = written.iter().copied().collect();
    let missing: BTreeSet<LedIndex> = seen.summary_missing.iter().flatten().copied().collect();
    prop_assert!(
        written.is_disjoint(&missing),
        "an LED both written and missing"
    );
    let all: BTreeSet<LedIndex> = nominal.leds().into_iter().collect();
    let union: BTreeSet<LedIndex> = written.union(&missing).copied().collect();
    prop_assert_eq!(union, all, "an LED neither written nor listed missing");
    let complete = missing.is_empty() && !seen.capture_failed && !seen.cut;
    let succeeded = result.is_ok();
    match result {
        Ok(summary) => {
            prop_assert!(complete, "success with LEDs missing or after a cancel");
            prop_assert_eq!(summary.frames_in_dataset, nominal.leds().len());
        }
        Err(e) => {
            prop_assert!(!complete, "failed although complete: {e:#}");
            if seen.cut && !seen.capture_failed {
                prop_assert!(
                    format!("{e:#}").contains("cancel"),
                    "a cancel not said: {e:#}"
                );
            }
        }
    }
    Ok(succeeded)
}

#[test]
fn any_run_keeps_every_frame_under_its_led_and_finishes() {
    let count = std::env::var("FPM_ACQUISITION_CASES")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(10_000);
    let mut runner = TestRunner::new(Config {
        cases: count,
        failure_persistence: None,
        ..Config::default()
    });
    if let Err(e) = runner.run(&cases(), |case| run(&case).map(|_| ())) {
        panic!("{e}");
    }
    let endings: Vec<usize> = ENDINGS.iter().map(|e| e.load(Ordering::Relaxed)).collect();
    eprintln!("succeeded, failed with a dataset, failed without, calibrated, retook, cut short, paused and resumed: {endings:?}");
    if count >= 1_000 {
        assert!(
            endings.iter().all(|&n| n > 0),
            "a branch never reached: {endings:?}"
        );
    }
}

#[test]
fn a_clean_run_captures_every_led_once_and_succeeds() {
    let clean = Case {
        rows: 9,
        cols: 9,
        calibrate: false,
        store_geometry: false,
        drop: 0.0,
        lost: 0.0,
        refused: 0.0,
        camera_stops: false,
        cancel_at: None,
        pause_holds: None,
        seed: 1,
    };
    assert!(run(&clean).unwrap());
    // Calibrated first, the calibration stored on the board and used for the capture.
    let calibrated = Case {
        calibrate: true,
        store_geometry: true,
        ..clean
    };
    assert!(run(&calibrated).unwrap());
}
