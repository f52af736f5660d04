//! A scan of many fields: the stage moves from field to field over a grid, each field
//! is acquired as an ordinary dataset (`fpm_host::scan`'s layout: `fields/r*c*/` and
//! `scan.json`), and each field's reconstruction runs on a worker thread while the
//! stage moves on and the next field is acquired. A scan interrupted part-way is
//! completed by running it again: fields already acquired (and reconstructed) are
//! skipped.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use fpm_host::reconstruction::{self, Job};
use fpm_host::scan::{
    field_name, FieldFocus, ScanField, ScanManifest, StitchEvent, StitchOptions, StitchReport,
    FORMAT,
};
use fpm_physics::stitch;
use fpm_stage::{Stage, Target};
use serde::Serialize;

use crate::acquisition::Plan;
use crate::acquisition::Progress;
use crate::control::Control;
use crate::pipeline;
use crate::{Controller, FocusStage};

pub use crate::stage::ScanStage;

/// What to scan.
#[derive(Debug, Clone)]
pub struct ScanPlan {
    pub rows: usize,
    pub cols: usize,
    /// Neighbouring fields overlap by this fraction.
    pub overlap: f64,
    /// Each field's acquisition; its `out` is the scan directory, its `calibrate` is
    /// done at the first field only, its `reconstruct` means a worker thread
    /// reconstructs each field while the next is acquired.
    pub field: Plan,
    /// How each field is reconstructed (its geometry: the first field's calibration
    /// when it calibrated).
    pub job: Job,
    /// With `field.reconstruct`: how the fields are joined once all are in (the
    /// mosaic in `OUT/mosaic/`); None leaves them unjoined (`fpm stitch` joins them).
    pub stitch: Option<stitch::Settings>,
    /// Focus each field before acquiring it ([`focus_field`]; the first with the
    /// board's geometry, the rest with the scan's calibration).
    pub autofocus: bool,
}

impl ScanPlan {
    /// Check the grid and overlap (the field's plan is checked when it runs).
    pub fn validate(&self) -> Result<()> {
        if self.rows == 0 || self.cols == 0 || self.rows * self.cols > 10_000 {
            bail!(
                "fields {}×{}: give 1–10000 fields in all",
                self.rows,
                self.cols
            );
        }
        if !(0.0..0.9).contains(&self.overlap) {
            bail!("overlap {}: give a fraction 0–0.9", self.overlap);
        }
        if let Some(s) = &self.stitch {
            if !(s.stage_sigma_um.is_finite() && s.stage_sigma_um > 0.0) {
                bail!(
                    "stage_sigma_um {}: give the stage's position error, above 0",
                    s.stage_sigma_um
                );
            }
        }
        Ok(())
    }

    /// A `rows`×`cols` scan of `field`'s acquisition, each field reconstructed (when
    /// `field.reconstruct`) as the acquisition's own reconstruction would be, then
    /// stitched with the stage's error `stage_sigma_um` (1σ) as the prior.
    pub fn new(rows: usize, cols: usize, overlap: f64, field: Plan, stage_sigma_um: f64) -> Self {
        let job = Job {
            settings: fpm_physics::reconstruct::Settings {
                flatten: field.flatten,
                ..Default::default()
            },
            passes: field.passes,
            tile: field.tile,
            ..Job::default()
        };
        Self {
            rows,
            cols,
            overlap,
            field,
            job,
            stitch: Some(stitch::Settings {
                stage_sigma_um,
                ..Default::default()
            }),
            autofocus: true,
        }
    }
}

/// What a scan reports as it goes.
#[derive(Debug, Clone, Copy)]
pub enum ScanEvent {
    /// Moving to field `index` (of `total`), centre (x, y) µm.
    Moving {
        index: usize,
        total: usize,
        at_um: (f64, f64),
    },
    /// Field `index`'s acquisition, so far.
    Acquiring {
        index: usize,
        total: usize,
        progress: Progress,
    },
    /// Field `index` was focused: the defocus its focus frames showed (None: too
    /// little texture to tell; the focus kept), and whether the stage moved.
    Focused {
        index: usize,
        measured_um: Option<f64>,
        moved: bool,
    },
    /// Field `index` was acquired before: skipped.
    Skipped { index: usize },
    /// Field `index` is reconstructed.
    Reconstructed { index: usize },
    /// Joining the fields: reading back field `done` of `total`, then (`done ==
    /// total`) registering and blending them.
    Stitching { done: usize, total: usize },
}

/// `OUT/scan-summary.json`.
#[derive(Debug, Clone, Serialize)]
pub struct ScanSummary {
    pub fields: usize,
    /// Acquired in this run (the others were there).
    pub acquired: usize,
    pub reconstructed: usize,
    pub seconds: f64,
    /// Fields acquired (and reconstructed, if asked) per hour in this run.
    pub fields_per_hour: f64,
    /// The field's size on the slide, µm.
    pub field_um: (f64, f64),
    /// The stitched slide image (OME-Zarr), when the fields were reconstructed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mosaic: Option<PathBuf>,
    /// How the fields were joined: every pair, the placements, the warnings.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stitch: Option<StitchReport>,
}

/// Focus the field under the objective: at the focus the stage holds, light the
/// bright-field LEDs nearest the axis (up to 25) one at a time into `dir` (a small
/// dataset), read the defocus from the shifts between their frames, and when it is
/// clear (beyond 3σ, σ mostly what a sample's relief adds: a quarter of λ/NA²) move
/// the sample's focus by it. None when the frames hold too little texture to
/// tell (blank glass): the focus is kept.
pub fn focus_field(
    dev: &Controller,
    stage: &mut dyn ScanStage,
    field: &Plan,
    geometry_file: Option<&Path>,
    dir: &Path,
    control: &Control,
) -> Result<Option<FieldFocus>> {
    let board = pipeline::board_geometry(dev);
    let geometry = match geometry_file {
        Some(path) => fpm_host::calibration::PlacementFile::read(path)?.geometry(&board),
        None => board,
    };
    let system = field.system;
    let all = geometry.leds();
    let leds: Vec<fpm_physics::LedIndex> = geometry
        .nearest_first(&all, (0.0, 0.0), &system)
        .into_iter()
        .map(|k| all[k])
        .filter(|&led| geometry.is_bright_field(led, 0.0, 0.0, &system))
        .take(25)
        .collect();
    if leds.len() < 4 {
        return Ok(None);
    }
    if dir.exists() {
        // An earlier run's focus frames, cut short.
        std::fs::remove_dir_all(dir).with_context(|| format!("replacing {}", dir.display()))?;
    }
    let plan = Plan {
        out: dir.to_path_buf(),
        calibrate: false,
        store_geometry: false,
        reconstruct: false,
        snapshot_every: 0,
        leds: Some(leds),
        multiplex: fpm_physics::multiplex::Multiplex::ONE,
        geometry: geometry_file.map(Path::to_path_buf),
        ..field.clone()
    };
    pipeline::acquire(dev, stage, &plan, |_: &Progress| {}, control)?;
    let ds = fpm_host::dataset::DatasetOnDisk::open(dir)?;
    let Some(e) = fpm_host::reconstruction::refocus::defocus_on_disk(&ds, &system, &geometry)?
    else {
        return Ok(None);
    };
    // Only a clear defocus moves the stage: the shifts also read a sample's relief
    // (oblique light on features whose phase and absorption go together) as defocus,
    // differently field to field (σ ≈ a quarter of λ/NA², in `sigma_um`).
    let moved = e.is_clear();
    if moved {
        FocusStage::refocus_sample(stage, e.z_um)?;
        FocusStage::move_to(stage, crate::StagePosition::in_focus(crate::Slide::Sample))?;
    }
    tracing::info!(
        defocus_um = e.z_um,
        sigma_um = e.sigma_um,
        moved,
        "field focus"
    );
    Ok(Some(FieldFocus {
        measured_um: e.z_um,
        sigma_um: e.sigma_um,
        moved,
    }))
}

/// The reconstruction threads, joined however the scan ends: a scan that stops
/// part-way (cancelled, failed) leaves no thread writing a field's reconstruction that
/// a resumed scan would start again.
struct Workers(Vec<std::thread::JoinHandle<()>>);

impl Drop for Workers {
    fn drop(&mut self) {
        for w in self.0.drain(..) {
            let _ = w.join();
        }
    }
}

/// Whether a field's dataset is complete (written, no journal of a part-way run).
fn acquired(dir: &Path) -> bool {
    dir.join("dataset.toml").is_file() && !dir.join("journal").exists()
}

/// Whether a field has a reconstruction.
fn reconstructed(dir: &Path) -> bool {
    dir.join("reconstruction/report.json").is_file()
}

/// Run `scan` with the LED controller `dev` and `stage`, the grid's first field where
/// the stage is now (the scan runs over +x, +y from there, serpentine).
pub fn run(
    dev: &Controller,
    stage: &mut dyn ScanStage,
    scan: &ScanPlan,
    on: &mut dyn FnMut(ScanEvent),
    control: &Control,
) -> Result<ScanSummary> {
    scan.validate()?;
    let out = scan.field.out.clone();
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let started = Instant::now();
    let origin = Stage::position(stage)?;
    let total = scan.rows * scan.cols;
    // The order: serpentine, starting at the stage's position as field (0, 0).
    let order: Vec<(usize, usize)> = (0..scan.rows)
        .flat_map(|r| {
            (0..scan.cols).map(move |k| (r, if r % 2 == 0 { k } else { scan.cols - 1 - k }))
        })
        .collect();
    let mut manifest = match ScanManifest::read(&out) {
        Ok(m) if m.rows == scan.rows && m.cols == scan.cols => m,
        Ok(m) => bail!(
            "{} holds a {}×{} scan; this one is {}×{}: give another --out",
            out.display(),
            m.rows,
            m.cols,
            scan.rows,
            scan.cols
        ),
        Err(_) => ScanManifest {
            format: FORMAT.into(),
            rows: scan.rows,
            cols: scan.cols,
            overlap: scan.overlap,
            fields: Vec::new(),
        },
    };
    // A scan completed later keeps its grid: field (0, 0) where it was first taken,
    // wherever the stage has been since.
    let origin = match manifest.fields.iter().find(|f| f.row == 0 && f.col == 0) {
        Some(first) => fpm_stage::Position {
            x_um: first.stage_um[0],
            y_um: first.stage_um[1],
            z_um: first.z_um.unwrap_or(origin.z_um),
        },
        None => origin,
    };
    if (manifest.overlap - scan.overlap).abs() > 1e-9 && !manifest.fields.is_empty() {
        bail!(
            "{} was scanned with {} overlap; this scan asks for {}: give the same --overlap, or another --out",
            out.display(),
            manifest.overlap,
            scan.overlap
        );
    }
    let mut field_um: Option<(f64, f64)> = None;
    let (done_tx, done_rx) = mpsc::channel::<(usize, Result<()>)>();
    let mut workers = Workers(Vec::new());
    let mut acquired_now = 0;
    let mut reconstructed_now = 0;
    let mut geometry: Option<PathBuf> = None;
    for (index, &(row, col)) in order.iter().enumerate() {
        if control.is_cancelled() {
            bail!("the scan was cancelled after {index} of {total} fields; run it again to complete it");
        }
        let name = field_name(row, col);
        let dir = out.join(&name);
        let at = match field_um {
            // The first field is where the stage is; the grid follows from its size.
            None => (origin.x_um, origin.y_um),
            Some((w, h)) => (
                origin.x_um + col as f64 * w * (1.0 - scan.overlap),
                origin.y_um + row as f64 * h * (1.0 - scan.overlap),
            ),
        };
        let recorded = manifest
            .fields
            .iter()
            .find(|f| f.row == row && f.col == col)
            .cloned();
        if acquired(&dir) && recorded.is_some() {
            on(ScanEvent::Skipped { index });
        } else {
            on(ScanEvent::Moving {
                index,
                total,
                at_um: at,
            });
            Stage::move_to(stage, Target::xy(at.0, at.1))?;
            let resume = dir.join("dataset.toml").is_file() || dir.join("journal").exists();
            // A field cut short keeps the focus its first frames had.
            let focus = if scan.autofocus && !resume {
                let geometry = geometry.clone().or_else(|| scan.field.geometry.clone());
                // `focus/r<row>c<col>`, beside `fields/r<row>c<col>`.
                let focus_dir = out
                    .join("focus")
                    .join(Path::new(&name).file_name().context("a field's name")?);
                let f = focus_field(
                    dev,
                    stage,
                    &scan.field,
                    geometry.as_deref(),
                    &focus_dir,
                    control,
                )
                .with_context(|| format!("focusing field {name}"))?;
                on(ScanEvent::Focused {
                    index,
                    measured_um: f.map(|f| f.measured_um),
                    moved: f.is_some_and(|f| f.moved),
                });
                f
            } else {
                None
            };
            let plan = Plan {
                out: dir.clone(),
                calibrate: scan.field.calibrate && index == 0,
                store_geometry: scan.field.store_geometry && index == 0,
                reconstruct: false,
                // The fields after the first are acquired with its calibration.
                geometry: geometry.clone().or_else(|| scan.field.geometry.clone()),
                ..scan.field.clone()
            };
            let mut watch = |p: &Progress| {
                on(ScanEvent::Acquiring {
                    index,
                    total,
                    progress: *p,
                })
            };
            let _summary = if resume {
                pipeline::resume(dev, stage, &plan, &mut watch, control)
            } else {
                pipeline::acquire(dev, stage, &plan, &mut watch, control)
            }
            .with_context(|| format!("acquiring field {name}"))?;
            acquired_now += 1;
            manifest.fields.retain(|f| !(f.row == row && f.col == col));
            manifest.fields.push(ScanField {
                row,
                col,
                dataset: name.clone(),
                stage_um: [at.0, at.1],
                // Where the field was acquired (in focus).
                z_um: Some(Stage::position(stage)?.z_um),
                focus,
            });
            manifest.write(&out)?;
        }
        if index == 0 {
            let calibration = dir.join("calibration.json");
            geometry = calibration.is_file().then_some(calibration);
        }
        if field_um.is_none() {
            let ds = fpm_host::dataset::DatasetOnDisk::open(&dir)?;
            let (h, w) = ds.dim();
            let pixel = ds.manifest.system().sample_pixel_um();
            field_um = Some((w as f64 * pixel, h as f64 * pixel));
        }
        if scan.field.reconstruct && !reconstructed(&dir) {
            // The scan's calibration, else the placement the field was acquired with.
            let job = fpm_host::scan::field_job(&out, &manifest, &dir, &scan.job);
            let tx = done_tx.clone();
            // One field reconstructs while the next is acquired; the next waits for
            // it (two cores: more at once would starve the acquisition).
            if workers.0.len() > reconstructed_now {
                if let Ok((i, r)) = done_rx.recv() {
                    r.with_context(|| format!("reconstructing field {:?}", order[i]))?;
                    on(ScanEvent::Reconstructed { index: i });
                    reconstructed_now += 1;
                }
            }
            workers.0.push(std::thread::spawn(move || {
                let r = job.run(&dir, &|_| {}).and_then(|f| {
                    reconstruction::write_outputs(&f.reconstruction, &dir.join("reconstruction"))
                });
                let _ = tx.send((index, r));
            }));
        }
    }
    drop(done_tx);
    for (i, r) in done_rx.iter() {
        r.with_context(|| format!("reconstructing field {:?}", order[i]))?;
        on(ScanEvent::Reconstructed { index: i });
        reconstructed_now += 1;
    }
    drop(workers);
    manifest
        .fields
        .sort_by_key(|f| order.iter().position(|&o| o == (f.row, f.col)));
    manifest.write(&out)?;
    let seconds = started.elapsed().as_secs_f64();
    let mut summary = ScanSummary {
        fields: total,
        acquired: acquired_now,
        reconstructed: reconstructed_now,
        seconds,
        fields_per_hour: acquired_now as f64 / seconds.max(1e-9) * 3600.0,
        field_um: field_um.unwrap_or_default(),
        mosaic: None,
        stitch: None,
    };
    if let (true, Some(settings)) = (scan.field.reconstruct, scan.stitch) {
        if control.is_cancelled() {
            bail!("the scan was cancelled before its fields were stitched; run it again to stitch them");
        }
        let options = StitchOptions {
            // Each field's geometry as `field_job` finds it.
            job: scan.job.clone(),
            settings,
            redo: false,
            field_memory_bytes: fpm_host::scan::FIELD_MEMORY_BYTES,
        };
        let reproduce = format!("fpm stitch {}", out.display());
        let (stitched, _page) =
            fpm_report::slide::stitch(&out, &options, &out.join("mosaic"), &reproduce, &mut |e| {
                match e {
                    StitchEvent::Field { done, total, .. } => {
                        on(ScanEvent::Stitching { done, total })
                    }
                    StitchEvent::Registering { done: 0, .. } => {
                        on(ScanEvent::Stitching { done: total, total })
                    }
                    _ => {}
                }
            })
            .context("stitching the fields")?;
        summary.mosaic = Some(stitched.mosaic);
        summary.stitch = Some(stitched.report);
    }
    std::fs::write(
        out.join("scan-summary.json"),
        serde_json::to_string_pretty(&summary)?,
    )
    .with_context(|| format!("writing {}", out.join("scan-summary.json").display()))?;
    Ok(summary)
}
