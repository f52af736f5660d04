//! The acquisition as a sans-IO state machine, as `firmware/core` is for the controller
//! and quinn-proto for QUIC: [`Acquisition`] takes [`Event`]s (the stage arrived, a
//! labelled frame, a sequence ended, a write is done, cancel) and answers with the
//! next [`Action`] (move the stage, run this sequence, write this, finished). It never
//! touches a port, a camera, a stage or a file; [`crate::pipeline::acquire`] drives it
//! on a live rig, and `tests/acquisition.rs` drives it synchronously through arbitrary
//! runs.
//!
//! calibrate (pdcFPM, optional) → order the LEDs nearest-first under the geometry in
//! use → capture one labelled frame per LED, streaming each into the reconstruction →
//! retake what is missing, once → write the dataset → finish the reconstruction → write
//! the summary. Cancelling stops before the next sequence (the driver aborts the one
//! running); what was captured is still written, and the run ends as failed. Pausing
//! holds the rig between LEDs (the driver aborts the capture sequence running; the LEDs
//! it had not lit wait, and are lit when the run resumes). [`Acquisition::resume`]
//! starts from the frames an earlier run of the same plan left, and lights only the
//! LEDs they lack.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Error, Result};
use fpm_frames::ServiceNames;
use fpm_host::calibration::{calibrate_dataset, CalibrationFile, GeometrySource};
use fpm_host::dataset::{CameraSection, Dataset, FrameEntry, Manifest};
use fpm_host::reconstruction::{Reconstruction, Report, Request};
use fpm_physics::calibrate::{calibration_grid, Options, GRID_HALF};
use fpm_physics::reconstruct::{limits, tiled, Flatten, Settings, TiledStreaming};
use fpm_physics::{LedGeometry, System};
use fpm_protocol::{BoardCalibration, LedIndex, Rgb};
use serde::Serialize;

use crate::board_geometry;
use crate::capture::{CaptureReport, Shot, ShotView};
use crate::labeller::{SequenceSteps, Waiting};
use crate::stage::{Slide, StagePosition};
use crate::stream::StreamWorker;
use crate::summary::AcquireSummary;

/// Most LEDs lit together: a set fits one request (`fpm/light/set/define`).
pub const MAX_MULTIPLEX: usize = fpm_protocol::limits::MAX_LEDS_PER_LIST;

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
    /// Capture the dataset (false: calibrate only, and store the result on the board
    /// with `store_geometry`).
    pub capture: bool,
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
    /// Frames between live [`Snapshot`]s of the streaming reconstruction (0: none but
    /// the finished reconstruction's, which a reconstructing run always has).
    pub snapshot_every: usize,
    /// Light only these LEDs, in this order (a raw sequence); None: every LED of the
    /// array, nearest the axis first.
    pub leds: Option<Vec<LedIndex>>,
    /// LEDs lit together in each frame, dark field and bright field (one each: one
    /// LED per frame; more: a multiplexed acquisition, [`crate::multiplexed`], through
    /// the controller's LED sets).
    pub multiplex: fpm_physics::multiplex::Multiplex,
    /// Acquire with the placement in this file (a calibration.json: a scan's first
    /// field's, for the fields after it) instead of the board's stored one or the
    /// nominal. Ignored when the run calibrates.
    pub geometry: Option<PathBuf>,
}

/// What an acquisition does when nothing else is said: `fpm acquire`'s flags and the
/// service's requests both start from these.
pub mod defaults {
    use fpm_protocol::Rgb;

    /// How long each LED stays lit, ms.
    pub const STEP_MS: f64 = 40.0;
    /// Defocus for calibration, µm toward the LEDs.
    pub const DEFOCUS_UM: f64 = 200.0;
    /// 1σ of that defocus, µm.
    pub const DEFOCUS_SIGMA_UM: f64 = fpm_physics::calibrate::DEFAULT_DEFOCUS_SIGMA_UM;
    /// LED colour.
    pub const COLOR: Rgb = Rgb { r: 0, g: 0, b: 255 };
    /// The camera's dark level, counts.
    pub const DARK_LEVEL: f64 = 100.0;
    /// Illumination wavelength, µm (blue).
    pub const WAVELENGTH_UM: f64 = 0.47;
    /// Objective NA.
    pub const NA: f64 = 0.1;
    /// Objective magnification.
    pub const MAGNIFICATION: f64 = 4.0;
    /// Camera pixel, µm.
    pub const PIXEL_UM: f64 = 2.4;
    /// EPRY passes after the last frame.
    pub const PASSES: usize = 5;
    /// Frames between live snapshots, where something shows them (the service).
    pub const SNAPSHOT_EVERY: usize = 25;
}

impl Plan {
    /// Every setting in its range, or an error naming it.
    pub fn validate(&self) -> Result<()> {
        if !self.capture && !self.calibrate {
            bail!("a plan that neither calibrates nor captures has nothing to do");
        }
        if let Some(leds) = &self.leds {
            if leds.is_empty() {
                bail!("leds: empty; give at least one LED, or none to take them all");
            }
            let mut seen = std::collections::BTreeSet::new();
            if let Some(twice) = leds.iter().find(|l| !seen.insert((l.row, l.col))) {
                bail!("leds: LED [{}, {}] twice", twice.row, twice.col);
            }
        }
        self.multiplex.check(MAX_MULTIPLEX)?;
        if !self.multiplex.is_one() {
            if self.calibrate {
                bail!("multiplex with calibrate: a calibration takes one LED per frame; calibrate first and store it on the board (calibrate with store_geometry), then acquire multiplexed from it");
            }
            if self.leds.is_some() {
                bail!("multiplex with leds: a multiplexed acquisition lights every LED, in sets it chooses");
            }
        }
        if !self.capture && self.reconstruct {
            bail!(
                "reconstruct needs a capture (a calibration alone has no dataset to reconstruct)"
            );
        }
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
        limits::check_run(self.passes, self.tile)?;
        Ok(streaming_settings(self).validate()?)
    }

    /// How long each LED stays lit, µs, as the controller takes it.
    pub fn step_us(&self) -> u32 {
        (self.step_ms * 1e3).round().max(1_000.0) as u32
    }
}

/// What the rig said before the acquisition began.
#[derive(Debug, Clone)]
pub struct Rig {
    /// The array as the controller describes it.
    pub nominal: LedGeometry,
    /// The calibration the board stores, if any.
    pub stored: Option<BoardCalibration>,
    /// The settings the camera's driver says it applied, if it says.
    pub camera_settings: Option<serde_json::Value>,
}

/// The sequence ids the acquisition uploads, one per purpose.
pub mod sequence_id {
    /// The focused reference under the centre LED.
    pub const REFERENCE: u32 = 101;
    /// The defocused calibration grid.
    pub const CALIBRATION_GRID: u32 = 102;
    /// Every LED, nearest-first.
    pub const CAPTURE: u32 = 103;
    /// The LEDs the capture missed.
    pub const RETAKE: u32 = 104;
}

/// What happened on the rig, for [`Acquisition::handle`].
pub enum Event<'a> {
    /// The stage reached the position [`Action::MoveStage`] asked for.
    StageArrived,
    /// A labelled frame of the sequence running now (every labelled frame exactly once,
    /// perhaps before its final label is certain: see [`CaptureReport::relabelled`]).
    Frame(ShotView<'a>),
    /// The sequence running now ended: its shots under their final labels and what it
    /// did, or why it could not run.
    SequenceEnded(Result<(Vec<Shot>, CaptureReport)>),
    /// The write or board request asked for is done.
    Done,
    /// The user asked to stop: no new sequence starts.
    Cancel,
    /// The user asked to pause: the rig holds before its next sequence or stage move
    /// (a capture sequence running is to be aborted by the driver, the LEDs it did not
    /// reach are lit after [`Event::Resume`]).
    Pause,
    /// The user asked to go on after a pause.
    Resume,
    /// Why the running sequence's frames wait for their labels (None: they no longer
    /// do), as [`crate::capture::Live::Labelling`] says.
    Labelling(Option<Waiting>),
    /// How far the controller is through the running sequence.
    Steps(SequenceSteps),
}

/// What the driver must do next, from [`Acquisition::next_action`]. Each action but
/// `Finished` is answered with one event: `MoveStage` with `StageArrived`,
/// `RunSequence` with `Frame`s and then `SequenceEnded`, the rest with `Done`.
pub enum Action<'a> {
    /// Move the focus stage.
    MoveStage(StagePosition),
    /// Run one capture sequence lighting `leds` in order, one frame each.
    RunSequence { id: u32, leds: Vec<LedIndex> },
    /// Write `out/calibration.json` and its page.
    WriteCalibration {
        calibration: &'a CalibrationFile,
        options: &'a Options,
    },
    /// Store the calibration in `out/calibration.json` on the board.
    StoreOnBoard { nominal: &'a LedGeometry },
    /// Save a dataset: the calibration frames (in `out/calibration`), then the
    /// acquisition's (in `out`).
    WriteDataset(&'a mut Dataset),
    /// Write the reconstruction of `dataset` (its images and page); score it against a
    /// simulated rig's truth beside the dataset first, if there is one (an extra).
    WriteReconstruction {
        reconstruction: &'a mut Reconstruction,
        dataset: &'a Dataset,
        upsample: usize,
    },
    /// Write `acquisition.json` and its page; `failure` says why the run failed.
    WriteSummary {
        summary: &'a AcquireSummary,
        failure: Option<&'a str>,
    },
    /// Hold: the user paused (no LED lit, the stage where it is). Answered by
    /// [`Event::Resume`] or [`Event::Cancel`].
    Paused,
    /// Over: the summary, or why the acquisition failed. Asked again, the error says the
    /// acquisition has finished.
    Finished(Box<Result<AcquireSummary>>),
}

/// Where the acquisition is, for a progress display.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    Calibrating,
    Capturing,
    Retaking,
    Writing,
    Reconstructing,
    /// Holding between LEDs until the user resumes.
    Paused,
    Finished,
}

/// How far the acquisition is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Progress {
    pub phase: Phase,
    /// Frames of the full capture (and its retake) labelled so far.
    pub frames: usize,
    /// While frames of the running capture wait for their labels: why (as text).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub labelling: Option<Waiting>,
    /// How far the controller is through the running capture or retake sequence.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steps: Option<SequenceSteps>,
    /// LEDs in the full capture (0 until it is ordered).
    pub of: usize,
    /// The user asked to stop.
    pub cancelled: bool,
    /// The user asked to pause (the phase is `paused` once the rig holds).
    pub paused: bool,
}

/// The reconstruction as it stands, for a live view: taken from the stream every
/// [`Plan::snapshot_every`] frames, and the finished reconstruction once.
#[derive(Debug, Clone)]
pub struct Snapshot {
    /// Frames streamed into it.
    pub frames: usize,
    /// LEDs in the full capture.
    pub of: usize,
    /// The finished reconstruction, not the stream's state.
    pub finished: bool,
    /// The sample's complex field.
    pub object: ndarray::Array2<fpm_physics::Complex32>,
    /// Its pixel in the sample plane, µm.
    pub pixel_um: f64,
}

/// The step the machine is in; each waits for the one event that ends it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    FocusReference,
    Reference,
    Defocus,
    CalibrationGrid,
    BackToSample,
    WriteCalibrationFrames,
    WriteCalibration,
    StoreOnBoard,
    Capture,
    Retake,
    WriteDataset,
    WriteReconstruction,
    WriteSummary,
    Finished,
}

impl Step {
    /// The phase the step belongs to.
    fn phase(self) -> Phase {
        match self {
            Step::FocusReference
            | Step::Reference
            | Step::Defocus
            | Step::CalibrationGrid
            | Step::BackToSample
            | Step::WriteCalibrationFrames
            | Step::WriteCalibration
            | Step::StoreOnBoard => Phase::Calibrating,
            Step::Capture => Phase::Capturing,
            Step::Retake => Phase::Retaking,
            Step::WriteDataset | Step::WriteSummary => Phase::Writing,
            Step::WriteReconstruction => Phase::Reconstructing,
            Step::Finished => Phase::Finished,
        }
    }

    /// Whether the step moves the stage or lights LEDs (a pause holds before it).
    fn uses_rig(self) -> bool {
        matches!(
            self,
            Step::FocusReference
                | Step::Reference
                | Step::Defocus
                | Step::CalibrationGrid
                | Step::BackToSample
                | Step::Capture
                | Step::Retake
        )
    }
}

/// What a cancel cut short.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cut {
    Capture,
    Reconstruction,
}

/// The acquisition's state machine.
pub struct Acquisition {
    plan: Plan,
    rig: Rig,
    step: Step,
    /// The action for `step` was handed out; its event has not come yet.
    waiting: bool,
    cancelled: bool,
    /// The user asked to pause.
    pause: bool,
    /// Holding for the pause now (the last action handed out was `Paused`).
    holding: bool,
    /// What the cancel cut short (None: nothing, it came after the last sequence and
    /// with no reconstruction to skip; the run then succeeds).
    cut: Option<Cut>,
    geometry: LedGeometry,
    geometry_source: GeometrySource,
    calibration_shots: Vec<(Shot, f64)>,
    calibration_reports: Vec<CaptureReport>,
    calibration_frames: Option<Dataset>,
    calibration: Option<(CalibrationFile, Options)>,
    order: Vec<LedIndex>,
    /// The LEDs of `order` the capture has still to light (all of them at first; after a
    /// pause those it did not reach; on resuming a run, those its frames lack).
    pending: Vec<LedIndex>,
    /// Frames an earlier run left, taken over by [`Acquisition::resume`].
    frames_before: usize,
    shots: Vec<Shot>,
    capture: Option<CaptureReport>,
    retake: Option<CaptureReport>,
    retake_problem: Option<String>,
    /// The streaming reconstruction, on its own thread.
    streaming: Option<StreamWorker>,
    stream_error: Option<String>,
    /// Why the running sequence's frames wait for their labels, if they do.
    labelling: Option<Waiting>,
    /// How far the controller is through the running sequence.
    steps: Option<SequenceSteps>,
    /// The finished reconstruction is to be shown once.
    finished_snapshot_due: bool,
    update_us: Vec<f64>,
    tiles: Option<usize>,
    frames: usize,
    last_frame_at: Option<Instant>,
    dataset: Option<Dataset>,
    reconstruction: Option<Reconstruction>,
    reconstruction_source: Option<&'static str>,
    last_frame_to_final_ms: Option<f64>,
    summary: Option<AcquireSummary>,
    failure: Option<String>,
    result: Option<Result<AcquireSummary>>,
}

impl Acquisition {
    /// The acquisition of `plan` on a rig that said `rig`; the plan is checked first.
    pub fn new(plan: Plan, rig: Rig) -> Result<Self> {
        plan.validate()?;
        if let Some(leds) = &plan.leds {
            let all = rig.nominal.leds();
            if let Some(off) = leds.iter().find(|l| !all.contains(l)) {
                bail!(
                    "leds: LED [{}, {}] is not on the board ({}×{})",
                    off.row,
                    off.col,
                    rig.nominal.rows,
                    rig.nominal.cols
                );
            }
        }
        let given = match (&plan.geometry, plan.calibrate) {
            (Some(path), false) => Some((
                fpm_host::calibration::PlacementFile::read(path)
                    .with_context(|| format!("the placement to acquire with, {}", path.display()))?
                    .geometry(&rig.nominal),
                path.clone(),
            )),
            _ => None,
        };
        let (geometry, geometry_source) = match (&rig.stored, plan.calibrate) {
            _ if given.is_some() => given
                .clone()
                .map(|(g, p)| (g, GeometrySource::File(p)))
                .unwrap_or((rig.nominal, GeometrySource::Controller)),
            (_, true) | (None, false) => (rig.nominal, GeometrySource::Controller),
            (Some(c), false) => (
                board_geometry::geometry(&rig.nominal, c),
                GeometrySource::Board,
            ),
        };
        if let Some((_, path)) = &given {
            tracing::info!("acquiring with the placement in {}", path.display());
        } else if !plan.calibrate {
            match &rig.stored {
                Some(c) => tracing::info!(
                    "starting from the geometry stored on the board: {}",
                    board_geometry::describe(c)
                ),
                // Chosen LEDs (a scan's focus frames before its calibration, a raw
                // sequence) are not the array a reconstruction needs placed: said only.
                None if plan.leds.is_some() => tracing::info!(
                    "no calibration given and none stored on the board: the chosen LEDs are labelled with the nominal geometry"
                ),
                None => tracing::warn!(
                    "no calibration given and none stored on the board: using the nominal geometry (calibrate with --calibrate --store-geometry)"
                ),
            }
        }
        let mut machine = Self {
            step: Step::FocusReference,
            waiting: false,
            cancelled: false,
            pause: false,
            holding: false,
            cut: None,
            geometry,
            geometry_source,
            calibration_shots: vec![],
            calibration_reports: vec![],
            calibration_frames: None,
            calibration: None,
            order: vec![],
            pending: vec![],
            frames_before: 0,
            shots: vec![],
            capture: None,
            retake: None,
            retake_problem: None,
            streaming: None,
            stream_error: None,
            labelling: None,
            steps: None,
            finished_snapshot_due: false,
            update_us: vec![],
            tiles: None,
            frames: 0,
            last_frame_at: None,
            dataset: None,
            reconstruction: None,
            reconstruction_source: None,
            last_frame_to_final_ms: None,
            summary: None,
            failure: None,
            result: None,
            plan,
            rig,
        };
        if !machine.plan.calibrate {
            // The stage stays where the user left it: on the sample, in focus.
            machine.start_capture();
            machine.step = Step::Capture;
        }
        Ok(machine)
    }

    /// How far the acquisition is.
    pub fn progress(&self) -> Progress {
        let phase = match self.holding {
            true => Phase::Paused,
            false => self.step.phase(),
        };
        Progress {
            phase,
            frames: self.frames,
            labelling: self
                .labelling
                .filter(|_| matches!(self.step, Step::Capture | Step::Retake)),
            steps: self
                .steps
                .filter(|_| matches!(self.step, Step::Capture | Step::Retake)),
            of: self.order.len(),
            cancelled: self.cancelled,
            paused: self.pause,
        }
    }

    /// The acquisition of `plan` (which must not calibrate) continued from `before`,
    /// the labelled frames an earlier run of it left (an interrupted or cancelled one):
    /// they are kept, streamed into the reconstruction first, and only the LEDs they
    /// lack are lit. `geometry` is the placement that run used, when it was not the
    /// rig's (its own calibration).
    pub fn resume(
        plan: Plan,
        rig: Rig,
        before: Vec<Shot>,
        geometry: Option<(LedGeometry, GeometrySource)>,
    ) -> Result<Self> {
        if plan.calibrate {
            bail!("a resumed acquisition does not calibrate again (its first run did)");
        }
        let mut machine = Self::new(plan, rig)?;
        if let Some((g, source)) = geometry {
            machine.geometry = g;
            machine.geometry_source = source;
            machine.start_capture();
        }
        let (known, unknown): (Vec<Shot>, Vec<Shot>) = before
            .into_iter()
            .partition(|s| machine.order.contains(&s.led));
        if let Some(s) = unknown.first() {
            bail!(
                "{} of the frames to resume from are lit by LEDs this board does not have (LED {:?} first): is it the same rig?",
                unknown.len(),
                (s.led.row, s.led.col)
            );
        }
        machine
            .pending
            .retain(|led| !known.iter().any(|s| s.led == *led));
        if machine.pending.is_empty() {
            bail!(
                "nothing to resume: every LED already has its frame ({} frames); reconstruct the dataset instead",
                known.len()
            );
        }
        machine.frames_before = known.len();
        for shot in &known {
            machine.stream(shot.view());
        }
        machine.shots = known;
        Ok(machine)
    }

    /// The snapshot due now, if one is: the finished reconstruction once, before it the
    /// newest one the stream's thread took (the driver asks after each event, when it
    /// has a viewer to give it to).
    pub fn snapshot(&mut self) -> Option<Snapshot> {
        let of = self.order.len();
        if std::mem::take(&mut self.finished_snapshot_due) {
            return self.reconstruction.as_ref().map(|r| Snapshot {
                frames: self.frames,
                of,
                finished: true,
                object: r.object.clone(),
                pixel_um: r.report.pixel_um,
            });
        }
        let (frames, object) = self.streaming.as_ref()?.take_snapshot()?;
        let upsample = streaming_settings(&self.plan).upsample.max(1) as f64;
        let system = self.plan.system;
        Some(Snapshot {
            frames,
            of,
            finished: false,
            object,
            pixel_um: system.pixel_size_um / system.magnification / upsample,
        })
    }

    /// The action to carry out now. Calling it again before the action's event was
    /// handled hands out the same action again (a sequence's LEDs and the like anew).
    pub fn next_action(&mut self) -> Action<'_> {
        self.holding = self.pause && !self.cancelled && self.step.uses_rig();
        if self.holding {
            return Action::Paused;
        }
        self.waiting = true;
        let plan = &self.plan;
        match self.step {
            Step::FocusReference => {
                Action::MoveStage(StagePosition::in_focus(Slide::CalibrationTarget))
            }
            Step::Reference => Action::RunSequence {
                id: sequence_id::REFERENCE,
                leds: vec![self.rig.nominal.center],
            },
            Step::Defocus => Action::MoveStage(StagePosition {
                slide: Slide::CalibrationTarget,
                defocus_um: plan.defocus_um,
            }),
            Step::CalibrationGrid => Action::RunSequence {
                id: sequence_id::CALIBRATION_GRID,
                leds: calibration_grid(&self.rig.nominal, GRID_HALF),
            },
            Step::BackToSample => Action::MoveStage(StagePosition::in_focus(Slide::Sample)),
            Step::WriteCalibrationFrames => match &mut self.calibration_frames {
                Some(d) => Action::WriteDataset(d),
                None => unreachable_step("calibration frames"),
            },
            Step::WriteCalibration => match &self.calibration {
                Some((calibration, options)) => Action::WriteCalibration {
                    calibration,
                    options,
                },
                None => unreachable_step("calibration"),
            },
            Step::StoreOnBoard => Action::StoreOnBoard {
                nominal: &self.rig.nominal,
            },
            Step::Capture => Action::RunSequence {
                id: sequence_id::CAPTURE,
                leds: self.pending.clone(),
            },
            Step::Retake => Action::RunSequence {
                id: sequence_id::RETAKE,
                leds: self.capture.as_ref().map_or(vec![], |r| r.missing.clone()),
            },
            Step::WriteDataset => match &mut self.dataset {
                Some(d) => Action::WriteDataset(d),
                None => unreachable_step("dataset"),
            },
            Step::WriteReconstruction => match (&mut self.reconstruction, &self.dataset) {
                (Some(reconstruction), Some(dataset)) => Action::WriteReconstruction {
                    reconstruction,
                    dataset,
                    upsample: streaming_settings(plan).upsample,
                },
                _ => unreachable_step("reconstruction"),
            },
            Step::WriteSummary => match &self.summary {
                Some(summary) => Action::WriteSummary {
                    summary,
                    failure: self.failure.as_deref(),
                },
                None => unreachable_step("summary"),
            },
            Step::Finished => {
                self.waiting = false;
                Action::Finished(Box::new(
                    self.result
                        .take()
                        .unwrap_or_else(|| Err(anyhow!("the acquisition has finished"))),
                ))
            }
        }
    }

    /// Take in what happened. An event the current step does not wait for is ignored
    /// with a note in the log (a stray frame after its sequence ended, say).
    pub fn handle(&mut self, event: Event<'_>) {
        match event {
            Event::Cancel => {
                if !self.cancelled && self.step != Step::Finished {
                    tracing::warn!(
                        "cancelled: no new sequence starts; what was captured is written"
                    );
                }
                if !self.cancelled {
                    self.cut = match self.step {
                        Step::Capture | Step::Retake => Some(Cut::Capture),
                        Step::WriteDataset if self.streaming.is_some() => Some(Cut::Reconstruction),
                        _ => None,
                    };
                    if self.cut.is_some() {
                        // Nothing cut short is reconstructed: the stream's thread stops
                        // now rather than compete with writing what was captured.
                        self.stop_stream();
                    }
                }
                self.cancelled = true;
                if !self.waiting {
                    self.after_cancel();
                }
            }
            Event::Pause => {
                if !self.pause && self.step != Step::Finished {
                    tracing::info!("paused: the rig holds before its next LED");
                }
                self.pause = true;
            }
            Event::Resume => {
                if self.pause && self.step != Step::Finished {
                    tracing::info!("resumed");
                }
                self.pause = false;
                self.holding = false;
            }
            Event::Frame(shot) => {
                if matches!(self.step, Step::Capture | Step::Retake) && self.waiting {
                    self.stream(shot);
                }
            }
            Event::Labelling(waiting) => self.labelling = waiting,
            Event::Steps(steps) => self.steps = Some(steps),
            Event::StageArrived if self.waiting => self.advance(None),
            Event::Done if self.waiting => self.advance(None),
            Event::SequenceEnded(result) if self.waiting => {
                self.labelling = None;
                self.steps = None;
                self.advance(Some(result))
            }
            Event::StageArrived | Event::Done | Event::SequenceEnded(_) => {
                tracing::debug!("an event no step waits for ({:?}): ignored", self.step)
            }
        }
    }

    /// The current step's event came: on to the next step.
    fn advance(&mut self, sequence: Option<Result<(Vec<Shot>, CaptureReport)>>) {
        self.waiting = false;
        let ended = |s: Option<Result<_>>| s.unwrap_or_else(|| Err(anyhow!("no sequence ran")));
        let next = match self.step {
            Step::FocusReference => Ok(Step::Reference),
            Step::Reference => ended(sequence).map(|(shots, report)| {
                self.calibration_shots
                    .extend(shots.into_iter().map(|s| (s, 0.0)));
                self.calibration_reports.push(report);
                Step::Defocus
            }),
            Step::Defocus => Ok(Step::CalibrationGrid),
            Step::CalibrationGrid => ended(sequence).map(|(shots, report)| {
                let defocus = self.plan.defocus_um;
                self.calibration_shots
                    .extend(shots.into_iter().map(|s| (s, defocus)));
                self.calibration_reports.push(report);
                Step::BackToSample
            }),
            Step::BackToSample => self
                .calibration_frames()
                .map(|()| Step::WriteCalibrationFrames),
            Step::WriteCalibrationFrames => self.calibrate().map(|()| Step::WriteCalibration),
            Step::WriteCalibration => {
                if let Some((calibration, _)) = &self.calibration {
                    self.geometry = calibration.geometry();
                    self.geometry_source = GeometrySource::CalibratedNow;
                }
                Ok(if self.plan.store_geometry {
                    Step::StoreOnBoard
                } else {
                    self.after_calibration()
                })
            }
            Step::StoreOnBoard => Ok(self.after_calibration()),
            // The capture went on after a pause and could not: what came first is kept.
            Step::Capture if self.capture.is_some() && matches!(sequence, Some(Err(_))) => {
                if let (Some(Err(e)), Some(c)) = (sequence, self.capture.as_mut()) {
                    c.outcome = format!("the capture could not go on after the pause: {e:#}");
                    c.failed = true;
                    c.sequences += 1;
                }
                Ok(self.build_dataset())
            }
            Step::Capture => ended(sequence).map(|(shots, report)| {
                self.shots.extend(shots);
                let report = match self.capture.take() {
                    Some(mut before) => {
                        before.then(report);
                        before
                    }
                    None => report,
                };
                // Paused part-way: the LEDs it did not reach wait for the resume.
                if self.pause && !self.cancelled && !report.failed && !report.missing.is_empty() {
                    self.pending = report.missing.clone();
                    self.capture = Some(report);
                    return Step::Capture;
                }
                let retake = !report.failed && !report.missing.is_empty() && !self.cancelled;
                if retake {
                    tracing::warn!("re-acquiring {} missing frame(s)", report.missing.len());
                }
                self.capture = Some(report);
                if retake {
                    Step::Retake
                } else {
                    self.build_dataset()
                }
            }),
            Step::Retake => {
                // A retake that goes wrong loses nothing of the first capture.
                match ended(sequence) {
                    Ok((more, r)) => {
                        if r.labelled + r.extra_frames + r.ambiguous_frames == 0 {
                            self.retake_problem = Some(format!(
                                "the camera delivered no frame while {} LED(s) were lit again: has it stopped?",
                                r.requested
                            ));
                        }
                        self.shots.extend(more);
                        self.retake = Some(r);
                    }
                    Err(e) => self.retake_problem = Some(format!("the retake failed: {e:#}")),
                }
                Ok(self.build_dataset())
            }
            Step::WriteDataset => Ok(self.reconstruct()),
            Step::WriteReconstruction => Ok(self.summarise()),
            Step::WriteSummary => {
                self.result = Some(match (self.summary.take(), self.failure.take()) {
                    (Some(s), None) => Ok(s),
                    (Some(s), Some(why)) => Err(anyhow!(
                        "{why}; the {} frames acquired are labelled and written to {} (acquisition.json lists the missing LEDs)",
                        s.frames_in_dataset,
                        self.plan.out.display()
                    )),
                    (None, _) => Err(anyhow!("the acquisition lost its summary")),
                });
                Ok(Step::Finished)
            }
            Step::Finished => Ok(Step::Finished),
        };
        match next {
            Ok(step) => {
                self.step = step;
                if self.cancelled {
                    self.after_cancel();
                }
            }
            Err(e) => self.fail(e),
        }
    }

    /// Cancelled, with no action outstanding: calibration stops with nothing written;
    /// a capture's frames are written (no retake, no reconstruction).
    fn after_cancel(&mut self) {
        match self.step {
            s if s.phase() == Phase::Calibrating => {
                self.fail(anyhow!(
                    "cancelled during the calibration; no frame was acquired"
                ));
            }
            // Cancelled while paused part-way: what was captured is written.
            Step::Capture if self.capture.is_some() || !self.shots.is_empty() => {
                self.cut = Some(Cut::Capture);
                self.step = self.build_dataset();
            }
            Step::Capture => {
                // Cancelled before the capture started: an empty dataset is no use.
                self.fail(anyhow!(
                    "cancelled before the capture; no frame was acquired"
                ));
            }
            Step::Retake => self.step = self.build_dataset(),
            // Later steps have nothing to stop: the reconstruction is computed (or was
            // skipped, see `cut`) and writing is quick.
            _ => {}
        }
    }

    /// Over, with `error`.
    fn fail(&mut self, error: Error) {
        self.step = Step::Finished;
        self.result = Some(Err(error));
    }

    /// The calibration frames as a dataset, written before the calibration runs (a
    /// calibration that fails leaves its frames to look at).
    fn calibration_frames(&mut self) -> Result<()> {
        let shots = std::mem::take(&mut self.calibration_shots);
        self.calibration_frames = Some(dataset(
            self.plan.out.join("calibration"),
            &self.plan.system,
            &self.rig.nominal,
            self.camera_section(),
            shots.into_iter(),
        )?);
        Ok(())
    }

    /// Run the calibration on its frames (in memory).
    fn calibrate(&mut self) -> Result<()> {
        let dataset = self
            .calibration_frames
            .take()
            .context("the calibration frames are gone")?;
        let options = Options {
            defocus_sigma_um: self.plan.defocus_sigma_um.abs(),
            ..Options::default()
        };
        let calibration = calibrate_dataset(&dataset, &options)?;
        self.calibration = Some((calibration, options));
        Ok(())
    }

    /// Calibrated: on to the capture, or, for a plan that only calibrates, finished.
    fn after_calibration(&mut self) -> Step {
        if self.plan.capture {
            self.start_capture();
            return Step::Capture;
        }
        let none = CaptureReport {
            outcome: "none: the plan only calibrates".into(),
            sequences: 0,
            ..CaptureReport::default()
        };
        self.result = Some(Ok(self.summary(none, 0, vec![])));
        Step::Finished
    }

    /// Order the full capture nearest-first under the geometry now in use.
    fn start_capture(&mut self) {
        let all = self.rig.nominal.leds();
        if let Some(leds) = &self.plan.leds {
            self.order = leds.clone();
            self.pending = self.order.clone();
            return;
        }
        self.order = self
            .geometry
            .nearest_first(&all, (0.0, 0.0), &self.plan.system)
            .into_iter()
            .map(|k| all[k])
            .collect();
        self.pending = self.order.clone();
    }

    /// A labelled frame of the full capture or its retake, into the stream.
    fn stream(&mut self, shot: ShotView<'_>) {
        self.frames += 1;
        self.last_frame_at = Some(Instant::now());
        if !self.plan.reconstruct || self.stream_error.is_some() || self.cut.is_some() {
            return;
        }
        if self.streaming.is_none() {
            let (h, w) = shot.pixels.dim();
            let stream = TiledStreaming::new(
                self.plan.system,
                self.geometry,
                streaming_settings(&self.plan),
                w,
                h,
                self.plan.tile,
            );
            let dark = self.plan.dark_level as f32;
            match StreamWorker::start(stream, dark, self.plan.snapshot_every) {
                Ok(worker) => self.streaming = Some(worker),
                Err(e) => {
                    tracing::warn!("no streaming reconstruction: {e:#}");
                    self.stream_error = Some(format!("{e:#}"));
                    return;
                }
            }
        }
        if let Some(worker) = self.streaming.as_mut() {
            worker.offer(shot);
        }
    }

    /// The stream's thread stopped, what it queued dropped; its tiles and update times
    /// kept for the summary.
    fn stop_stream(&mut self) {
        if let Some(worker) = self.streaming.take() {
            self.tiles = Some(worker.tiles());
            self.update_us = worker.update_us();
        }
    }

    /// The datasets' `[camera]` block (its bit depth comes with the frames).
    fn camera_section(&self) -> CameraSection {
        camera_section(self.plan.dark_level, self.rig.camera_settings.as_ref())
    }

    /// The labelled shots as the dataset to write.
    fn build_dataset(&mut self) -> Step {
        if let Some(worker) = &self.streaming {
            self.tiles = Some(worker.tiles());
        }
        let shots = std::mem::take(&mut self.shots);
        if shots.is_empty() {
            // Cancelled (or cut off) before any frame was labelled: no dataset (one has
            // frames), only the summary saying every LED is missing.
            tracing::info!("no frame was labelled: no dataset is written");
            return self.reconstruct();
        }
        match dataset(
            self.plan.out.clone(),
            &self.plan.system,
            &self.rig.nominal,
            self.camera_section(),
            shots.into_iter().map(|s| (s, 0.0)),
        ) {
            Ok(d) => {
                self.dataset = Some(d);
                Step::WriteDataset
            }
            Err(e) => {
                self.fail(e);
                Step::Finished
            }
        }
    }

    /// Finish the reconstruction over the dataset's frames (in memory): the stream's
    /// own, or from the dataset when frames reached the stream under a label the final
    /// pairing changed.
    fn reconstruct(&mut self) -> Step {
        let capture_failed = self.capture.as_ref().is_none_or(|r| r.failed);
        if capture_failed || self.stream_error.is_some() || self.cut.is_some() {
            self.stop_stream();
        }
        let (Some(worker), Some(ds)) = (self.streaming.take(), &self.dataset) else {
            return self.summarise();
        };
        let relabelled = self.relabelled();
        let left_out = worker.left_out();
        // The stream's thread takes in what it still has queued.
        let (stream, update_us) = worker.finish();
        self.update_us = update_us;
        let stream = match stream {
            Ok(s) => s,
            Err(e) => {
                self.stream_error = Some(e);
                return self.summarise();
            }
        };
        let settings = streaming_settings(&self.plan);
        let frames = ds.in_focus();
        let outcome = if (relabelled, left_out) == (0, 0) {
            self.reconstruction_source = Some("streamed");
            stream
                .finish(&frames, self.plan.passes, &|_, _| {})
                .context("finishing the streaming reconstruction")
        } else {
            if relabelled > 0 {
                tracing::warn!(
                    "{relabelled} frame(s) were relabelled after streaming; reconstructing from the dataset instead"
                );
            }
            self.reconstruction_source = Some("dataset");
            tiled::reconstruct(
                &self.plan.system,
                &self.geometry,
                &frames,
                settings,
                self.plan.passes + 1,
                self.plan.tile,
                &|_, _| {},
            )
            .context("reconstructing the dataset")
        };
        let outcome = match outcome {
            Ok(o) => o,
            Err(e) => {
                self.fail(e);
                return Step::Finished;
            }
        };
        // The one clock read besides the frames': how long the final image took after
        // the last frame arrived.
        let ms = self
            .last_frame_at
            .map_or(0.0, |t| t.elapsed().as_secs_f64() * 1e3);
        self.last_frame_to_final_ms = Some(ms);
        let request = Request {
            geometry: &self.geometry,
            source: &self.geometry_source,
            settings,
            passes: self.plan.passes,
            tile: self.plan.tile,
        };
        let mut report = Report::new(
            &ds.dir,
            &ds.manifest.system(),
            &request,
            frames.len(),
            &outcome,
            ms,
        );
        report.height_from_boundary =
            fpm_host::reconstruction::boundary_check(&self.plan.system, &self.geometry, &frames);
        self.reconstruction = Some(Reconstruction::from_outcome(outcome, report));
        self.finished_snapshot_due = true;
        Step::WriteReconstruction
    }

    fn relabelled(&self) -> usize {
        self.capture.as_ref().map_or(0, |r| r.relabelled)
            + self.retake.as_ref().map_or(0, |r| r.relabelled)
    }

    /// The summary, and whether the run failed.
    fn summarise(&mut self) -> Step {
        let Some(capture) = self.capture.clone() else {
            self.fail(anyhow!("the acquisition has no capture to summarise"));
            return Step::Finished;
        };
        let still_missing = match &self.retake {
            Some(r) => r.missing.clone(),
            None => capture.missing.clone(),
        };
        let frames_in_dataset = self.dataset.as_ref().map_or(0, |d| d.frames.len());
        // An incomplete dataset is written, but the run fails: a script must notice.
        self.failure = if capture.failed {
            Some(capture.outcome.clone())
        } else if let Some(cut) = self.cut {
            Some(match cut {
                Cut::Capture => format!(
                    "cancelled by the user after {frames_in_dataset} of {} frames",
                    self.order.len()
                ),
                Cut::Reconstruction => "cancelled by the user before the reconstruction (the dataset is complete: `fpm reconstruct` makes the image)".into(),
            })
        } else if !still_missing.is_empty() {
            Some(format!(
                "{} LED(s) still have no frame after a retake{}",
                still_missing.len(),
                self.retake_problem
                    .as_ref()
                    .map_or(String::new(), |p| format!(" ({p})"))
            ))
        } else {
            None
        };
        self.summary = Some(self.summary(capture, frames_in_dataset, still_missing));
        Step::WriteSummary
    }

    /// What the run did, with this capture, dataset size and missing LEDs.
    fn summary(
        &self,
        capture: CaptureReport,
        frames_in_dataset: usize,
        still_missing: Vec<LedIndex>,
    ) -> AcquireSummary {
        AcquireSummary {
            nominal: self.rig.nominal,
            geometry: self.geometry,
            entrance_pupil_mm: self.plan.system.entrance_pupil_mm,
            geometry_source: self.geometry_source.clone(),
            board_calibration: self.rig.stored,
            camera_settings: self.rig.camera_settings.clone(),
            calibration: self.calibration_reports.clone(),
            capture,
            retake: self.retake.clone(),
            frames_in_dataset,
            frames_before: self.frames_before,
            still_missing,
            last_frame_to_final_ms: self.last_frame_to_final_ms,
            update_us_mean: (!self.update_us.is_empty())
                .then(|| self.update_us.iter().sum::<f64>() / self.update_us.len() as f64),
            tiles: self.tiles,
            reconstruction: self.reconstruction.as_ref().and(self.reconstruction_source),
        }
    }
}

/// A step was reached without what it writes: a bug, reported as the run's error.
fn unreachable_step<'a>(what: &str) -> Action<'a> {
    Action::Finished(Box::new(Err(anyhow!(
        "the acquisition reached its {what} step without one"
    ))))
}

/// The reconstruction's settings during an acquisition.
fn streaming_settings(plan: &Plan) -> Settings {
    Settings {
        flatten: plan.flatten,
        ..Settings::default()
    }
}

/// A dataset's `[camera]` block: the dark level, and the gamma the camera's driver
/// reported its frames decode with (`encoding_gamma` in its settings: 1 for raw
/// counts, so nothing is read from the frames later). A camera that did not say
/// leaves it unstated, and `fpm reconstruct` may read one from the frames.
pub(crate) fn camera_section(
    dark_level: f64,
    camera_settings: Option<&serde_json::Value>,
) -> CameraSection {
    let gamma = camera_settings
        .and_then(|s| s.get("encoding_gamma"))
        .and_then(serde_json::Value::as_f64)
        .filter(|g| CameraSection::is_valid_gamma(*g));
    CameraSection {
        dark_level,
        gamma,
        ..CameraSection::default()
    }
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
            also: vec![],
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
