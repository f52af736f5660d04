//! A live DPC preview on the rig (Tian & Waller 2015): the four half-circle patterns the
//! controller computes itself (`Pattern::HalfCircle` at the objective's NA), one frame
//! each, turned into phase and absorption as fast as the camera delivers four frames.
//! It is how a user finds the sample and focuses before a calibration or a scan.
//!
//! [`Preview`] is the pure part: which LEDs each pattern lights (the firmware's own
//! rule on the board's nominal grid, so host and controller agree), the solver planned
//! once, and four frames in, one weak object out. [`live`] drives the rig around it.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU32, Ordering};

use anyhow::{bail, Context, Result};
use fpm_frames::ServiceNames;
use fpm_physics::dpc::{Dpc, Half, Regularisation, Transfer, WeakObject};
use fpm_physics::{Complex32, Image, LedGeometry, System};
use fpm_protocol::{BoardGeometry, Illumination, LedIndex, Pattern, Rgb, Step};
use ndarray::{Array2, ArrayView2};
use serde::Serialize;

use crate::acquisition::{Phase, Progress, Snapshot};
use crate::capture::{capture_steps, Lighting, News};
use crate::control::{Control, Watcher};
use crate::controller::Controller;

/// Most rounds of four frames one preview takes (one controller sequence holds them).
pub const MAX_ROUNDS: usize = fpm_protocol::limits::MAX_SEQUENCE_STEPS / 4;

/// The four patterns in the order they are lit (the physics' order of halves).
const HALVES: [(Half, fpm_protocol::Half); 4] = [
    (Half::Top, fpm_protocol::Half::Top),
    (Half::Bottom, fpm_protocol::Half::Bottom),
    (Half::Left, fpm_protocol::Half::Left),
    (Half::Right, fpm_protocol::Half::Right),
];

/// The pure part of a live DPC: the patterns and the planned solver.
pub struct Preview {
    na: f32,
    /// The LEDs each pattern lights, in [`HALVES`]' order.
    lit: [Vec<LedIndex>; 4],
    transfers: Vec<Transfer>,
    reg: Regularisation,
    dark_level: f32,
    /// Planned at the first frames' size.
    solver: Option<Dpc>,
}

impl Preview {
    /// The patterns at the objective's NA on `board` (the controller's nominal grid,
    /// which decides what a pattern lights), their transfer functions from where
    /// `geometry` places those LEDs (the calibrated array, or the nominal one), for
    /// frames of `system` with `dark_level` counts of offset.
    pub fn new(
        board: &BoardGeometry,
        system: &System,
        geometry: &LedGeometry,
        reg: Regularisation,
        dark_level: f64,
        size: (usize, usize),
    ) -> Result<Self> {
        let na = system.na as f32;
        let lit = HALVES.map(|(_, half)| {
            let pattern = Pattern::HalfCircle { na, half };
            (0..board.rows)
                .flat_map(|r| (0..board.cols).map(move |c| LedIndex::new(r, c)))
                .filter(|&led| fpm_firmware::patterns::contains(board, &pattern, led))
                .collect::<Vec<_>>()
        });
        if let Some((k, _)) = lit.iter().enumerate().find(|(_, l)| l.is_empty()) {
            bail!(
                "the {} half-circle at NA {na} lights no LED on this board ({}x{}, pitch {} µm, {} mm below): DPC needs LEDs inside the objective's NA on every side of the centre LED",
                HALVES[k].0.name(),
                board.rows,
                board.cols,
                board.pitch_um,
                board.height_um as f64 / 1e3
            );
        }
        let (w, h) = size;
        let transfers = lit
            .iter()
            .map(|leds| {
                let f: Vec<(f64, f64)> = leds
                    .iter()
                    .map(|&led| geometry.pupil_frequency(led, 0.0, 0.0, system))
                    .collect();
                Transfer::new(&f, system.cutoff(), (w, h), system.sample_pixel_um())
            })
            .collect();
        Ok(Self {
            na,
            lit,
            transfers,
            reg,
            dark_level: dark_level as f32,
            solver: None,
        })
    }

    /// The four steps of one round, in `color`.
    pub fn steps(&self, color: Rgb) -> [Step; 4] {
        HALVES.map(|(_, half)| Step {
            illumination: Illumination::Pattern(Pattern::HalfCircle { na: self.na, half }),
            color,
        })
    }

    /// The LEDs each pattern lights (top, bottom, left, right).
    pub fn lit(&self) -> &[Vec<LedIndex>; 4] {
        &self.lit
    }

    /// The weak object from one round's frames (counts, exposure µs), in
    /// [`Self::steps`]' order; None if their sizes differ from the plan's.
    pub fn solve(&mut self, frames: [(ArrayView2<'_, u16>, u32); 4]) -> Option<WeakObject> {
        let (h, w) = frames[0].0.dim();
        let images: Vec<Image> = frames
            .iter()
            .map(|(counts, exposure_us)| {
                let per_ms = 1e3 / (*exposure_us).max(1) as f32;
                counts.mapv(|v| (v as f32 - self.dark_level).max(0.0) * per_ms)
            })
            .collect();
        let solver = self
            .solver
            .get_or_insert_with(|| Dpc::new(&self.transfers, (w, h), self.reg));
        solver.solve(&images.iter().collect::<Vec<_>>())
    }
}

/// A weak object as a complex field for the live view: (1 − μ)·e^{iφ}.
pub fn as_field(object: &WeakObject) -> Array2<Complex32> {
    ndarray::Zip::from(&object.absorption)
        .and(&object.phase)
        .map_collect(|&mu, &phi| Complex32::from_polar(1.0 - mu, phi))
}

/// A live DPC on the rig.
#[derive(Debug, Clone)]
pub struct LivePlan {
    /// The camera whose frames to take.
    pub camera: ServiceNames,
    /// Where the last round's phase and absorption go (OME-TIFF) with `dpc.json`.
    pub out: PathBuf,
    /// The optics.
    pub system: System,
    /// Where the LEDs are (the board's stored calibration, or its nominal grid).
    pub geometry: LedGeometry,
    /// Rounds of four frames (1 to [`MAX_ROUNDS`]).
    pub rounds: usize,
    /// How long each pattern stays lit, ms.
    pub step_ms: f64,
    /// The patterns' colour.
    pub color: Rgb,
    /// The camera's dark level, counts.
    pub dark_level: f64,
    /// Tikhonov weights.
    pub reg: Regularisation,
}

/// What a live DPC did.
#[derive(Debug, Clone, Serialize)]
pub struct LiveSummary {
    /// Rounds solved (four frames each).
    pub rounds: usize,
    /// Frames the camera delivered labelled.
    pub frames: usize,
    /// Phase images per second over the run.
    pub updates_per_s: f64,
    /// The LEDs each pattern lit: top, bottom, left, right.
    pub lit: [Vec<LedIndex>; 4],
    /// Where the last round was written.
    pub out: PathBuf,
}

/// Sequence ids of live previews (each run its own, so a stale event is never taken
/// for a new one's).
static NEXT_ID: AtomicU32 = AtomicU32::new(201);

/// Light the four patterns `plan.rounds` times, solve every round as its fourth frame
/// arrives and hand it to `watcher` as a snapshot (phase, and 1 − μ as amplitude);
/// write the last round into `plan.out`. A cancel aborts the sequence at once and
/// keeps the rounds done.
pub fn live(
    dev: &Controller,
    plan: &LivePlan,
    mut watcher: impl Watcher,
    control: &Control,
) -> Result<LiveSummary> {
    if !(1..=MAX_ROUNDS).contains(&plan.rounds) {
        bail!("rounds {}: give 1 to {MAX_ROUNDS}", plan.rounds);
    }
    crate::rig::wait_for_camera(&plan.camera)?;
    std::fs::create_dir_all(&plan.out)
        .with_context(|| format!("creating {}", plan.out.display()))?;
    let board = dev.info().geometry;
    let mut preview: Option<Preview> = None;
    let steps: Vec<Step> = {
        // The steps do not depend on the frame size: plan them on a placeholder.
        let probe = Preview::new(&board, &plan.system, &plan.geometry, plan.reg, 0.0, (4, 4))?;
        (0..plan.rounds)
            .flat_map(|_| probe.steps(plan.color))
            .collect()
    };
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
    let exposure_us = (plan.step_ms * 1e3).round().max(1_000.0) as u32;
    let started = std::time::Instant::now();
    let mut round: [Option<(Array2<u16>, u32)>; 4] = Default::default();
    let mut solved = 0usize;
    let mut last: Option<WeakObject> = None;
    let mut frames = 0usize;
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
    let (_, report) = capture_steps(
        dev,
        &plan.camera,
        id,
        Lighting::Steps(&steps),
        exposure_us,
        || control.is_cancelled(),
        |news| {
            let News::Labelled {
                step,
                header,
                pixels,
                ..
            } = news
            else {
                return;
            };
            frames += 1;
            watcher.progress(&progress(frames, Phase::Capturing));
            round[step % 4] = Some((pixels.to_owned(), header.exposure_us));
            if step % 4 != 3 || round.iter().any(Option::is_none) {
                return;
            }
            let taken = std::mem::take(&mut round).map(|f| f.unwrap_or_default());
            let pre = match preview.as_mut() {
                Some(p) => p,
                None => match Preview::new(
                    &board,
                    &plan.system,
                    &plan.geometry,
                    plan.reg,
                    plan.dark_level,
                    (taken[0].0.ncols(), taken[0].0.nrows()),
                ) {
                    Ok(p) => preview.insert(p),
                    Err(_) => return,
                },
            };
            let views = [0, 1, 2, 3].map(|k| (taken[k].0.view(), taken[k].1));
            if let Some(object) = pre.solve(views) {
                solved += 1;
                if watcher.wants_snapshots() {
                    watcher.snapshot(Snapshot {
                        frames,
                        of,
                        finished: false,
                        object: as_field(&object),
                        pixel_um: plan.system.sample_pixel_um(),
                    });
                }
                last = Some(object);
            }
        },
    )?;
    let seconds = started.elapsed().as_secs_f64();
    let Some(object) = last else {
        bail!(
            "no round of four half-circle frames came whole ({} of {} frames labelled: {}): is the camera triggered by the controller?",
            report.labelled,
            report.requested,
            report.outcome
        );
    };
    watcher.progress(&progress(frames, Phase::Writing));
    let pixel_um = plan.system.sample_pixel_um();
    fpm_host::dpc::write_object(&object, &plan.system, &plan.out)?;
    let summary = LiveSummary {
        rounds: solved,
        frames: report.labelled,
        updates_per_s: solved as f64 / seconds.max(1e-9),
        lit: preview.map(|p| p.lit.clone()).unwrap_or_default(),
        out: plan.out.clone(),
    };
    std::fs::write(
        plan.out.join("dpc.json"),
        serde_json::to_string_pretty(&summary)?,
    )
    .with_context(|| format!("writing {}", plan.out.join("dpc.json").display()))?;
    if watcher.wants_snapshots() {
        watcher.snapshot(Snapshot {
            frames,
            of,
            finished: true,
            object: as_field(&object),
            pixel_um,
        });
    }
    watcher.progress(&progress(frames, Phase::Finished));
    Ok(summary)
}
