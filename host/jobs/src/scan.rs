//! Whole slides: a scan is a grid of fields, each an ordinary dataset in
//! `fields/<name>/`, and `scan.json` saying where the stage put each (docs/dataset.md
//! §5.10). [`stitch`] reconstructs the fields (skipping those already done) and joins
//! them into one slide image ([`fpm_physics::stitch`]), written as an OME-Zarr pyramid
//! in the slide's coordinates. [`simulate`] makes a scan of one larger hidden slide
//! with the full wave-optics model, the stage off its commanded positions, and keeps
//! the slide's truth for scoring.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use fpm_physics::metrics::Scores;
use fpm_physics::simulate::{ObjectField, SampleKind};
use fpm_physics::stitch::{self, Canvas, Layout};
use fpm_physics::System;
use ndarray::Array2;
use rand::{Rng, SeedableRng};
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};

use crate::dataset::image_io;
use crate::reconstruction::{self, Job, JobEvent};
use crate::simulation::{write_acquisition_of, Scene};

/// The scan's manifest file in a scan directory.
pub const MANIFEST: &str = "scan.json";
/// What `format` says.
pub const FORMAT: &str = "fpm-scan/1";

/// `scan.json`: the fields and where the stage put them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanManifest {
    /// [`FORMAT`].
    pub format: String,
    /// Grid rows and columns.
    pub rows: usize,
    pub cols: usize,
    /// Neighbouring fields overlap by this fraction of a field.
    pub overlap: f64,
    /// The fields, in the order they were taken.
    pub fields: Vec<ScanField>,
}

/// One field of a scan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanField {
    pub row: usize,
    pub col: usize,
    /// The field's dataset, relative to the scan directory.
    pub dataset: String,
    /// Where the stage was told to put the field's centre, µm (stage coordinates,
    /// image columns along +x and rows along +y).
    pub stage_um: [f64; 2],
    /// The stage's Z for this field, µm, if a focus was set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub z_um: Option<f64>,
    /// How the field was focused before it was acquired (a scan with autofocus).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focus: Option<FieldFocus>,
}

/// A field's focus, measured before it was acquired: the shifts between a few
/// bright-field frames at the focus the stage held
/// ([`fpm_physics::reconstruct::refocus`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FieldFocus {
    /// The defocus the frames showed, µm toward the LEDs.
    pub measured_um: f64,
    /// Its 1σ, µm: the shifts' scatter and what a sample's relief reads as defocus
    /// (a quarter of λ/NA², varying field to field).
    pub sigma_um: f64,
    /// Whether the stage moved to take it out (beyond 3σ).
    pub moved: bool,
}

impl ScanManifest {
    /// Read `dir/scan.json`, checked.
    pub fn read(dir: &Path) -> Result<Self> {
        let path = dir.join(MANIFEST);
        let text = std::fs::read_to_string(&path).with_context(|| {
            format!(
                "reading {} (is {} a scan directory?)",
                path.display(),
                dir.display()
            )
        })?;
        let m: Self =
            serde_json::from_str(&text).with_context(|| format!("reading {}", path.display()))?;
        if m.format != FORMAT {
            bail!(
                "{}: format `{}`, this fpm reads `{FORMAT}`",
                path.display(),
                m.format
            );
        }
        if m.fields.is_empty() {
            bail!("{}: no fields", path.display());
        }
        if !(0.0..0.9).contains(&m.overlap) {
            bail!(
                "{}: overlap {} must be a fraction 0–0.9",
                path.display(),
                m.overlap
            );
        }
        for f in &m.fields {
            if f.row >= m.rows || f.col >= m.cols {
                bail!(
                    "{}: field {} at row {}, column {} is outside the {}×{} grid",
                    path.display(),
                    f.dataset,
                    f.row,
                    f.col,
                    m.rows,
                    m.cols
                );
            }
            let p = Path::new(&f.dataset);
            if p.is_absolute()
                || p.components()
                    .any(|c| matches!(c, std::path::Component::ParentDir))
            {
                bail!(
                    "{}: field dataset `{}` must be a directory inside the scan",
                    path.display(),
                    f.dataset
                );
            }
            if !f.stage_um.iter().all(|v| v.is_finite()) {
                bail!(
                    "{}: field {} has a stage position that is not a number",
                    path.display(),
                    f.dataset
                );
            }
        }
        Ok(m)
    }

    /// Write `dir/scan.json`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        let path = dir.join(MANIFEST);
        std::fs::write(&path, serde_json::to_string_pretty(self)?)
            .with_context(|| format!("writing {}", path.display()))
    }
}

/// A `rows × cols` grid of fields `field_um` (width, height) wide overlapping by
/// `overlap`, centred on `centre_um`, in serpentine order (each row the way the last
/// ended, so the stage never runs back across the slide): (row, col, centre µm).
pub fn grid(
    rows: usize,
    cols: usize,
    field_um: (f64, f64),
    overlap: f64,
    centre_um: (f64, f64),
) -> Vec<(usize, usize, (f64, f64))> {
    let step = (field_um.0 * (1.0 - overlap), field_um.1 * (1.0 - overlap));
    let mut out = Vec::with_capacity(rows * cols);
    for r in 0..rows {
        for k in 0..cols {
            let c = if r % 2 == 0 { k } else { cols - 1 - k };
            let x = centre_um.0 + (c as f64 - (cols as f64 - 1.0) / 2.0) * step.0;
            let y = centre_um.1 + (r as f64 - (rows as f64 - 1.0) / 2.0) * step.1;
            out.push((r, c, (x, y)));
        }
    }
    out
}

/// The directory name of field (row, col).
pub fn field_name(row: usize, col: usize) -> String {
    format!("fields/r{row}c{col}")
}

/// A simulated scan.
#[derive(Debug, Clone)]
pub struct SimulatedScan {
    pub rows: usize,
    pub cols: usize,
    pub overlap: f64,
    /// The array, the camera noise, the sensor side (each field) and the seed.
    pub scene: Scene,
    /// The optics (a lower magnification gives a wider field for the same pixels).
    pub system: System,
    /// Simulation pixels per camera pixel.
    pub upsample: usize,
    /// The stage misses each commanded position by up to this much (uniform in a
    /// disc), µm.
    pub stage_error_um: f64,
    pub sample: SampleKind,
}

impl SimulatedScan {
    /// The scene with only the central `side × side` LEDs of its board (odd `side`):
    /// fewer frames per field where the resolution gain may be smaller.
    pub fn central_leds(mut self, side: usize) -> Self {
        let g = &mut self.scene.truth;
        let side = side.clamp(1, g.rows.min(g.cols)) | 1;
        g.center = fpm_physics::LedIndex::new((side / 2) as u8, (side / 2) as u8);
        g.rows = side;
        g.cols = side;
        self
    }
}

/// The slide's truth, `truth/slide.json` beside `truth/slide_amplitude.tif` and
/// `truth/slide_phase.tif`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SlideTruth {
    /// The truth images' pixel, µm.
    pub pixel_um: f64,
    /// Slide position of the truth images' first pixel, µm.
    pub origin_um: [f64; 2],
    /// Where each field's centre really was, µm, in `scan.json`'s order.
    pub true_um: Vec<[f64; 2]>,
}

/// Simulate `s` into `out`: `scan.json`, `fields/r*c*/` (each a dataset with its own
/// truth), `truth/` (the slide and where the fields really were).
pub fn simulate(
    s: &SimulatedScan,
    out: &Path,
    on_field: &dyn Fn(usize, usize),
) -> Result<ScanManifest> {
    if s.rows == 0 || s.cols == 0 || s.rows * s.cols > 400 {
        bail!("a {}×{} scan: give 1–400 fields", s.rows, s.cols);
    }
    if !(0.05..0.9).contains(&s.overlap) {
        bail!("overlap {}: give a fraction 0.05–0.9", s.overlap);
    }
    if !(s.stage_error_um.is_finite() && s.stage_error_um >= 0.0) {
        bail!("stage error {} µm: give a distance ≥ 0", s.stage_error_um);
    }
    let pixel = s.system.sample_pixel_um();
    let side = s.scene.size;
    let field_um = side as f64 * pixel;
    let centres = grid(s.rows, s.cols, (field_um, field_um), s.overlap, (0.0, 0.0));
    let mut rng = rand::rngs::StdRng::seed_from_u64(s.scene.seed ^ 0x57A6E);
    let truth_at: Vec<(f64, f64)> = centres
        .iter()
        .map(|&(_, _, (x, y))| {
            let (r, a) = (
                s.stage_error_um * rng.gen::<f64>().sqrt(),
                rng.gen_range(0.0..std::f64::consts::TAU),
            );
            (x + r * a.cos(), y + r * a.sin())
        })
        .collect();
    // The slide: every field with its margin, whatever the stage's error.
    let pad = 48;
    let span =
        |n: usize| field_um * (1.0 + (n as f64 - 1.0) * (1.0 - s.overlap)) + 2.0 * s.stage_error_um;
    let slide_side =
        ((span(s.rows.max(s.cols)) / pixel).ceil() as usize + 2 * pad + 8).next_multiple_of(2);
    let slide = ObjectField::slide(
        &s.system,
        slide_side,
        pad,
        s.upsample,
        s.scene.seed,
        s.sample,
    );
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut fields = Vec::new();
    let mut used = Vec::new();
    for (k, (&(row, col, commanded), &real)) in centres.iter().zip(&truth_at).enumerate() {
        on_field(k, centres.len());
        let (object, at) = slide
            .window(real, side, pad)
            .context("a field leaves the simulated slide")?;
        let name = field_name(row, col);
        let dir = out.join(&name);
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let scene = Scene {
            seed: s.scene.seed.wrapping_add(1 + k as u64),
            ..s.scene
        };
        write_acquisition_of(&scene, &s.system, &object, &dir)?;
        used.push([at.0, at.1]);
        fields.push(ScanField {
            row,
            col,
            dataset: name,
            stage_um: [commanded.0, commanded.1],
            z_um: None,
            focus: None,
        });
    }
    let manifest = ScanManifest {
        format: FORMAT.into(),
        rows: s.rows,
        cols: s.cols,
        overlap: s.overlap,
        fields,
    };
    manifest.write(out)?;
    // The slide's truth over every field.
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in &used {
        x0 = x0.min(p[0] - field_um / 2.0);
        y0 = y0.min(p[1] - field_um / 2.0);
        x1 = x1.max(p[0] + field_um / 2.0);
        y1 = y1.max(p[1] + field_um / 2.0);
    }
    let d = slide.pitch_um();
    // A margin: a mosaic placed a little off (within its errors) still lies on it.
    let margin = 16.0 * d;
    let (x0, y0, x1, y1) = (x0 - margin, y0 - margin, x1 + margin, y1 + margin);
    let (w, h) = (
        ((x1 - x0) / d).ceil() as usize,
        ((y1 - y0) / d).ceil() as usize,
    );
    let region = slide
        .region(x0, y0, w, h)
        .context("the truth leaves the simulated slide")?;
    let truth_dir = out.join("truth");
    std::fs::create_dir_all(&truth_dir)
        .with_context(|| format!("creating {}", truth_dir.display()))?;
    image_io::write_tiff_f32(
        &truth_dir.join("slide_amplitude.tif"),
        &region.mapv(|c| c.norm()),
    )?;
    image_io::write_tiff_f32(
        &truth_dir.join("slide_phase.tif"),
        &region.mapv(|c| c.arg()),
    )?;
    // The region starts at the grid pixel nearest x0, y0.
    let origin = [(x0 / d).round() * d, (y0 / d).round() * d];
    let truth = SlideTruth {
        pixel_um: d,
        origin_um: origin,
        true_um: used,
    };
    std::fs::write(
        truth_dir.join("slide.json"),
        serde_json::to_string_pretty(&truth)?,
    )?;
    Ok(manifest)
}

/// How to stitch a scan.
#[derive(Debug, Clone)]
pub struct StitchOptions {
    /// How each field is reconstructed (fields reconstructed before are read back).
    pub job: Job,
    /// Registration and blending.
    pub settings: stitch::Settings,
    /// Reconstruct every field again even if it has a reconstruction.
    pub redo: bool,
    /// Field reconstructions kept in memory at most, bytes (those evicted are read
    /// again from disk); never fewer than two rows of fields.
    pub field_memory_bytes: usize,
}

/// One field in the stitch report.
#[derive(Debug, Clone, Serialize)]
pub struct FieldReport {
    pub row: usize,
    pub col: usize,
    pub dataset: String,
    pub stage_um: [f64; 2],
    /// Where the images put it, µm.
    pub placed_um: [f64; 2],
    /// placed − stage, µm.
    pub correction_um: [f64; 2],
    /// The field's reconstruction against its truth (simulations).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub versus_truth: Option<Scores>,
}

/// The mosaic against a simulated slide's truth.
#[derive(Debug, Clone, Serialize)]
pub struct MosaicTruth {
    /// The mosaic's complex NRMSE (one global phase), scored as each field is.
    pub complex_nrmse: f64,
    /// The fields' own, their mean.
    pub fields_complex_nrmse: f64,
    /// Mosaic over fields.
    pub ratio: f64,
    /// The largest error of a placed field against where it really was (after the one
    /// translation the images cannot know), µm.
    pub max_position_error_um: f64,
    /// The same, RMS.
    pub rms_position_error_um: f64,
    /// The stage's own error, RMS, µm (what stitching on the stage alone would keep).
    pub rms_stage_error_um: f64,
    /// RMS phase step across the seams, rad ((mosaic·conj(truth)) between bands either
    /// side of each seam).
    pub seam_step_rad: f64,
    /// The same step across the middle of each field: what the sample and noise give.
    pub within_step_rad: f64,
}

/// `stitch.json`.
#[derive(Debug, Clone, Serialize)]
pub struct StitchReport {
    pub scan: String,
    pub fields: Vec<FieldReport>,
    pub pairs: Vec<stitch::Pair>,
    /// RMS of the used pairs' disagreement with the solved positions, µm.
    pub residual_rms_um: f64,
    pub canvas: Canvas,
    pub settings: stitch::Settings,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub versus_truth: Option<MosaicTruth>,
    /// What to look at, each with what to do.
    pub warnings: Vec<String>,
}

/// What stitching reports as it goes.
#[derive(Debug, Clone, Copy)]
pub enum StitchEvent {
    /// Field `done` of `total` is being reconstructed (or read back).
    Field {
        done: usize,
        total: usize,
        reused: bool,
    },
    /// Registering pair `done` of `total`.
    Registering { done: usize, total: usize },
    /// Blending and writing the mosaic: `done` of `total` rows.
    Writing { done: usize, total: usize },
}

/// How many bytes of field reconstructions stitching keeps in memory by default (the
/// rest are read again from disk as needed).
pub const FIELD_MEMORY_BYTES: usize = 4 << 30;

/// Fields' reconstructions, read from disk when asked and kept while there is room
/// (least recently used go first).
struct FieldCache<'a> {
    dirs: Vec<PathBuf>,
    capacity: usize,
    kept: Vec<(usize, std::sync::Arc<Array2<Complex32>>)>,
    /// What a field becomes once read (the blend's shift onto the canvas).
    prepare: Box<dyn Fn(usize, Array2<Complex32>) -> Array2<Complex32> + 'a>,
    reads: usize,
}

impl<'a> FieldCache<'a> {
    fn new(dirs: Vec<PathBuf>, capacity: usize) -> Self {
        Self {
            dirs,
            capacity: capacity.max(1),
            kept: Vec::new(),
            prepare: Box::new(|_, o| o),
            reads: 0,
        }
    }

    fn put(&mut self, k: usize, object: Array2<Complex32>) -> std::sync::Arc<Array2<Complex32>> {
        let object = std::sync::Arc::new((self.prepare)(k, object));
        self.kept.retain(|(i, _)| *i != k);
        self.kept.insert(0, (k, object.clone()));
        self.kept.truncate(self.capacity);
        object
    }

    fn get(&mut self, k: usize) -> Result<std::sync::Arc<Array2<Complex32>>> {
        if let Some(at) = self.kept.iter().position(|(i, _)| *i == k) {
            let hit = self.kept.remove(at);
            self.kept.insert(0, hit.clone());
            return Ok(hit.1);
        }
        let dir = self.dirs[k].join("reconstruction");
        let object = reconstruction::read_object(&dir)
            .with_context(|| format!("reading {}", dir.display()))?;
        self.reads += 1;
        Ok(self.put(k, object))
    }

    /// From now on `prepare` each field read; those kept are prepared now.
    fn reset(&mut self, prepare: Box<dyn Fn(usize, Array2<Complex32>) -> Array2<Complex32> + 'a>) {
        self.prepare = prepare;
        for (k, object) in std::mem::take(&mut self.kept).into_iter().rev() {
            let object = std::sync::Arc::try_unwrap(object).unwrap_or_else(|o| (*o).clone());
            self.put(k, object);
        }
    }
}

/// A stitched scan: where the mosaic went, how it was joined, and its preview.
pub struct Stitched {
    /// `mosaic.zarr`.
    pub mosaic: PathBuf,
    pub report: StitchReport,
    /// Its smallest pyramid level at most [`crate::ome_zarr::PREVIEW_SIDE`] a side.
    pub preview: crate::ome_zarr::Preview,
}

/// Reconstruct `dir`'s fields (each into `<field>/reconstruction/`, skipped where one
/// is there already unless `redo`), then join them into `out`: `mosaic.zarr` (OME-Zarr,
/// amplitude and phase, a pyramid, the slide's coordinates as its translation) and
/// `stitch.json`. The mosaic is blended and written a band of rows at a time, fields
/// read back from disk as the band needs them: a slide larger than memory is fine.
pub fn stitch(
    dir: &Path,
    options: &StitchOptions,
    out: &Path,
    on: &mut dyn FnMut(StitchEvent),
) -> Result<Stitched> {
    let manifest = ScanManifest::read(dir)?;
    let total = manifest.fields.len();
    if total == 0 {
        bail!("{}: no fields yet", dir.join(MANIFEST).display());
    }
    let field_dirs: Vec<PathBuf> = manifest
        .fields
        .iter()
        .map(|f| dir.join(&f.dataset))
        .collect();
    let mut footprints = Vec::with_capacity(total);
    let mut scores = Vec::with_capacity(total);
    let mut pitch: Option<f64> = None;
    // Sized once the first field's size is known.
    let mut cache = FieldCache::new(field_dirs.clone(), total);
    for (k, f) in manifest.fields.iter().enumerate() {
        let field_dir = &field_dirs[k];
        let recon = field_dir.join("reconstruction");
        let report_path = recon.join("report.json");
        let reused = !options.redo && report_path.exists();
        on(StitchEvent::Field {
            done: k,
            total,
            reused,
        });
        let (object, p, score) = if reused {
            let object = reconstruction::read_object(&recon).with_context(|| {
                format!(
                    "reading field {}'s reconstruction (delete {} to redo it)",
                    f.dataset,
                    recon.display()
                )
            })?;
            let report: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&report_path)?)
                    .with_context(|| format!("reading {}", report_path.display()))?;
            let p = report["pixel_um"]
                .as_f64()
                .with_context(|| format!("{}: no pixel_um", report_path.display()))?;
            // Scored when it was reconstructed, or now if its truth came later (a
            // virtual rig's, written once the field's true place was known).
            let score = serde_json::from_value(report["versus_truth"].clone())
                .ok()
                .or_else(|| {
                    let upsample = report["upsample"].as_u64()? as usize;
                    let ds = crate::dataset::DatasetOnDisk::open(field_dir).ok()?;
                    crate::truth::score_reconstruction(&ds, &object, upsample)
                });
            (object, p, score)
        } else {
            let job = field_job(dir, &manifest, field_dir, &options.job);
            let finished = job
                .run(field_dir, &|_: JobEvent| {})
                .with_context(|| format!("reconstructing field {}", f.dataset))?;
            reconstruction::write_outputs(&finished.reconstruction, &recon)?;
            let r = finished.reconstruction;
            // As written (amplitude and phase, float32) and as a later stitch reads it
            // back: the same mosaic whether a field was just reconstructed or not.
            let object = r.object.mapv(|z| Complex32::from_polar(z.norm(), z.arg()));
            (object, r.report.pixel_um, r.report.versus_truth)
        };
        match pitch {
            Some(q) if (q - p).abs() > 1e-9 * q => bail!("field {} was reconstructed at {p} µm pixels, the others at {q}: reconstruct them alike (--redo)", f.dataset),
            _ => pitch = Some(p),
        }
        if k == 0 {
            let bytes = object.len() * std::mem::size_of::<Complex32>();
            // Never fewer than two rows of fields: what a band of the mosaic needs.
            cache.capacity = (options.field_memory_bytes / bytes.max(1)).max(2 * manifest.cols + 2);
        }
        footprints.push(stitch::Footprint {
            dim: object.dim(),
            stage_um: (f.stage_um[0], f.stage_um[1]),
        });
        scores.push(score);
        cache.put(k, object);
    }
    let pitch = pitch.unwrap_or(1.0);
    // Registration, a pair at a time, in the order of the fields' grid (row by row),
    // so that the fields a pair needs are mostly those just used.
    let mut plans = stitch::plan_pairs(&footprints, pitch, &options.settings);
    let grid = |k: usize| (manifest.fields[k].row, manifest.fields[k].col);
    plans.sort_by_key(|p| grid(p.a).max(grid(p.b)));
    let mut pairs = Vec::with_capacity(plans.len());
    for (i, plan) in plans.iter().enumerate() {
        on(StitchEvent::Registering {
            done: i,
            total: plans.len(),
        });
        let (a, b) = (cache.get(plan.a)?, cache.get(plan.b)?);
        pairs.extend(stitch::register(
            plan,
            plan.window_a.of(a.view()),
            plan.window_b.of(b.view()),
            pitch,
            &options.settings,
        ));
    }
    let layout = stitch::solve(&footprints, pairs, pitch, &options.settings);
    let canvas = Canvas::covering(&footprints, &layout.positions_um, pitch);
    let placements: Vec<((usize, usize), (f64, f64))> = footprints
        .iter()
        .zip(&layout.positions_um)
        .map(|(f, &p)| canvas.placement(f, p))
        .collect();
    // From here the cache holds fields shifted onto the canvas's grid.
    let fractions: Vec<(f64, f64)> = placements.iter().map(|p| p.1).collect();
    cache.reset(Box::new(move |k, object| {
        stitch::shifted_onto_canvas(object.view(), fractions[k])
    }));
    let side = footprints[0].dim.1;
    let overlap_px = (manifest.overlap * side as f64).round() as usize;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let zarr = out.join("mosaic.zarr");
    let mut writer = crate::ome_zarr::Writer::create(
        &zarr,
        &[""],
        (canvas.height, canvas.width),
        pitch,
        canvas.origin_um,
    )?
    .with_preview();
    // A simulation's mosaic is scored against its truth: kept whole (they are small).
    let truth = dir.join("truth").join("slide.json").exists();
    let mut whole = truth.then(|| {
        (
            Array2::<Complex32>::zeros((canvas.height, canvas.width)),
            Array2::<bool>::from_elem((canvas.height, canvas.width), false),
        )
    });
    let band = crate::ome_zarr::CHUNK;
    for y0 in (0..canvas.height).step_by(band) {
        on(StitchEvent::Writing {
            done: y0,
            total: canvas.height,
        });
        let rows = y0..(y0 + band).min(canvas.height);
        let here: Vec<usize> = (0..total)
            .filter(|&k| {
                let (y, h) = (placements[k].0 .1, footprints[k].dim.0);
                y < rows.end && y + h > rows.start
            })
            .collect();
        let objects = here
            .iter()
            .map(|&k| cache.get(k))
            .collect::<Result<Vec<_>>>()?;
        let placed: Vec<stitch::Placed<'_>> = here
            .iter()
            .zip(&objects)
            .map(|(&k, o)| stitch::Placed {
                object: o.view(),
                at: placements[k].0,
                phase_rad: layout.phases_rad[k],
            })
            .collect();
        let (mut object, weight) = stitch::blend_rows(
            &placed,
            canvas.width,
            rows.clone(),
            overlap_px,
            &options.settings,
        );
        if let Some((m, c)) = whole.as_mut() {
            m.slice_mut(ndarray::s![rows.clone(), ..]).assign(&object);
            c.slice_mut(ndarray::s![rows.clone(), ..])
                .assign(&weight.mapv(|w| w > 0.0));
        }
        // Uncovered pixels are NaN (the OME-Zarr's fill value): no data, not black.
        ndarray::Zip::from(&mut object)
            .and(&weight)
            .for_each(|v, &w| {
                if w <= 0.0 {
                    *v = Complex32::new(f32::NAN, f32::NAN);
                }
            });
        writer.push(&[object.view()])?;
    }
    let preview = writer.finish()?.context("the mosaic's preview")?;
    tracing::info!(
        reads = cache.reads,
        kept = cache.capacity,
        "fields read again from disk while stitching"
    );
    let field_reports: Vec<FieldReport> = manifest
        .fields
        .iter()
        .zip(&layout.positions_um)
        .zip(scores)
        .map(|((f, p), score)| FieldReport {
            row: f.row,
            col: f.col,
            dataset: f.dataset.clone(),
            stage_um: f.stage_um,
            placed_um: [p.0, p.1],
            correction_um: [p.0 - f.stage_um[0], p.1 - f.stage_um[1]],
            versus_truth: score,
        })
        .collect();
    let warnings = warnings(&layout, &manifest, &options.settings);
    let mut report = StitchReport {
        scan: dir.display().to_string(),
        fields: field_reports,
        pairs: layout.pairs.clone(),
        residual_rms_um: layout.residual_rms_um,
        canvas,
        settings: options.settings,
        versus_truth: None,
        warnings,
    };
    if let Some((object, covered)) = &whole {
        report.versus_truth =
            match versus_truth(dir, object, covered, &report, &layout, &footprints) {
                Ok(t) => t,
                Err(e) => {
                    tracing::warn!("the mosaic was not scored against the slide's truth: {e:#}");
                    None
                }
            };
    }
    std::fs::write(
        out.join("stitch.json"),
        serde_json::to_string_pretty(&report)?,
    )
    .with_context(|| format!("writing {}", out.join("stitch.json").display()))?;
    Ok(Stitched {
        mosaic: zarr,
        report,
        preview,
    })
}

/// How a field without a geometry of its own is reconstructed: with the scan's
/// calibration (its own calibration.json, else the first field's: a scan calibrates
/// once), else as `job` says (by default, as the field was acquired: the calibration
/// stored on the controller board when its acquisition.json says so).
pub fn field_job(dir: &Path, manifest: &ScanManifest, field_dir: &Path, job: &Job) -> Job {
    if job.geometry != reconstruction::GeometryChoice::AsAcquired {
        return job.clone();
    }
    let own = field_dir.join("calibration.json");
    let first = manifest
        .fields
        .first()
        .map(|f| dir.join(&f.dataset).join("calibration.json"));
    match [Some(own), first]
        .into_iter()
        .flatten()
        .find(|p| p.is_file())
    {
        Some(path) => Job {
            geometry: reconstruction::GeometryChoice::File(path),
            ..job.clone()
        },
        None => job.clone(),
    }
}

fn warnings(layout: &Layout, manifest: &ScanManifest, s: &stitch::Settings) -> Vec<String> {
    let mut out = Vec::new();
    // A field none of whose overlaps registered keeps the stage's position (and its
    // error); one with at least one is placed by the images.
    let alone: Vec<&str> = manifest
        .fields
        .iter()
        .enumerate()
        .filter(|&(k, _)| {
            manifest.fields.len() > 1
                && !layout
                    .pairs
                    .iter()
                    .any(|p| p.used && (p.a == k || p.b == k))
        })
        .map(|(_, f)| f.dataset.as_str())
        .collect();
    if !alone.is_empty() {
        out.push(format!(
            "{} kept the stage's position (±{:.0} µm): none of its overlaps could be registered (blank glass, too little overlap, or a stage error beyond {:.0} µm); scan with more overlap (--overlap), or give the stage's error (--stage-sigma-um) if it is larger",
            alone.join(", "),
            s.stage_sigma_um,
            4.0 * s.stage_sigma_um
        ));
    }
    let expected = manifest.rows * manifest.cols.saturating_sub(1)
        + manifest.cols * manifest.rows.saturating_sub(1);
    if layout.pairs.len() < expected {
        out.push(format!(
            "only {} of the grid's {expected} neighbouring fields overlap as the stage placed them: scan with more overlap (--overlap)",
            layout.pairs.len()
        ));
    }
    out
}

/// Score the mosaic against `dir/truth/` if the scan is a simulation's.
fn versus_truth(
    dir: &Path,
    object: &Array2<Complex32>,
    covered: &Array2<bool>,
    report: &StitchReport,
    layout: &Layout,
    fields: &[stitch::Footprint],
) -> Result<Option<MosaicTruth>> {
    let truth_dir = dir.join("truth");
    let path = truth_dir.join("slide.json");
    if !path.exists() {
        return Ok(None);
    }
    let truth: SlideTruth = serde_json::from_str(&std::fs::read_to_string(&path)?)
        .with_context(|| format!("reading {}", path.display()))?;
    if truth.true_um.len() != fields.len() {
        bail!(
            "{}: {} fields, the scan has {}",
            path.display(),
            truth.true_um.len(),
            fields.len()
        );
    }
    let slide = image_io::read_complex(
        &truth_dir.join("slide_amplitude.tif"),
        &truth_dir.join("slide_phase.tif"),
    )?;
    // The one translation images cannot know: the mean of true − placed.
    let n = fields.len() as f64;
    let shift = truth
        .true_um
        .iter()
        .zip(&layout.positions_um)
        .fold((0.0, 0.0), |a, (t, p)| {
            (a.0 + (t[0] - p.0) / n, a.1 + (t[1] - p.1) / n)
        });
    let errors: Vec<f64> = truth
        .true_um
        .iter()
        .zip(&layout.positions_um)
        .map(|(t, p)| ((p.0 + shift.0 - t[0]).powi(2) + (p.1 + shift.1 - t[1]).powi(2)).sqrt())
        .collect();
    let stage_shift = truth
        .true_um
        .iter()
        .zip(fields)
        .fold((0.0, 0.0), |a, (t, f)| {
            (
                a.0 + (t[0] - f.stage_um.0) / n,
                a.1 + (t[1] - f.stage_um.1) / n,
            )
        });
    let stage_errors: Vec<f64> = truth
        .true_um
        .iter()
        .zip(fields)
        .map(|(t, f)| {
            ((f.stage_um.0 + stage_shift.0 - t[0]).powi(2)
                + (f.stage_um.1 + stage_shift.1 - t[1]).powi(2))
            .sqrt()
        })
        .collect();
    let rms = |v: &[f64]| (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt();
    // The truth under the canvas: the canvas's origin moved by the shift, on the truth's
    // grid (integer part cut, fraction shifted).
    let c = &report.canvas;
    let t_pitch = truth.pixel_um;
    let fx = (c.origin_um.0 + shift.0 - truth.origin_um[0]) / t_pitch;
    let fy = (c.origin_um.1 + shift.1 - truth.origin_um[1]) / t_pitch;
    let scale = c.pitch_um / t_pitch;
    let (tw, th) = (
        ((c.width as f64) * scale).round() as usize,
        ((c.height as f64) * scale).round() as usize,
    );
    let (ix, iy) = (fx.floor(), fy.floor());
    if ix < 0.0 || iy < 0.0 || ix as usize + tw > slide.ncols() || iy as usize + th > slide.nrows()
    {
        bail!("the mosaic reaches beyond the slide's truth");
    }
    let cut = slide
        .slice(ndarray::s![
            iy as usize..iy as usize + th,
            ix as usize..ix as usize + tw
        ])
        .to_owned();
    let under = fpm_physics::color::shifted_back(&cut, fx - ix, fy - iy);
    // Scored as each field is ([`crate::truth`]): the truth band-limited to the
    // fields' synthetic aperture, the central part, pixels no field covered masked.
    let mut mosaic = object.clone();
    // On the mosaic's grid (resampled if the truth's pixel differs), and both zero
    // where no field reached.
    let mut masked_truth = if (scale - 1.0).abs() > 1e-6 {
        fpm_physics::metrics::resample_to(&under, t_pitch, object.dim(), |_, _| true)
    } else {
        under
    };
    for ((m, t), &k) in mosaic.iter_mut().zip(masked_truth.iter_mut()).zip(covered) {
        if !k {
            *m = Complex32::default();
            *t = Complex32::default();
        }
    }
    let fields_nrmse: Vec<f64> = report
        .fields
        .iter()
        .filter_map(|f| f.versus_truth.map(|s| s.complex_nrmse))
        .collect();
    let fields_mean = fields_nrmse.iter().sum::<f64>() / fields_nrmse.len().max(1) as f64;
    // The band the fields were scored in: their LEDs' synthetic aperture.
    let first = dir.join(&report.fields[0].dataset);
    let discs = crate::truth::aperture_discs(&first)?;
    let cutoff = crate::dataset::DatasetOnDisk::open(&first)?
        .manifest
        .system()
        .cutoff();
    let band = fpm_physics::metrics::synthetic_aperture(&discs, cutoff);
    let mosaic_score =
        fpm_physics::metrics::score(&mosaic, c.pitch_um, &masked_truth, c.pitch_um, band);
    let (seam, within) = seam_steps(
        &mosaic,
        &masked_truth,
        covered,
        fields,
        &layout.positions_um,
        c,
    );
    Ok(Some(MosaicTruth {
        complex_nrmse: mosaic_score.complex_nrmse,
        fields_complex_nrmse: fields_mean,
        ratio: mosaic_score.complex_nrmse / fields_mean.max(1e-12),
        max_position_error_um: errors.iter().copied().fold(0.0, f64::max),
        rms_position_error_um: rms(&errors),
        rms_stage_error_um: rms(&stage_errors),
        seam_step_rad: seam,
        within_step_rad: within,
    }))
}

/// RMS phase step of mosaic·conj(truth) between two bands either side of each seam
/// (the midline of each overlap between horizontal or vertical neighbours), and the
/// same across the middle of each field.
fn seam_steps(
    mosaic: &Array2<Complex32>,
    truth: &Array2<Complex32>,
    covered: &Array2<bool>,
    fields: &[stitch::Footprint],
    positions: &[(f64, f64)],
    c: &Canvas,
) -> (f64, f64) {
    let band = 6usize;
    let (h, w) = mosaic.dim();
    let mean_phase = |r0: usize, r1: usize, c0: usize, c1: usize| -> Option<f64> {
        let mut acc = Complex32::default();
        for r in r0.min(h)..r1.min(h) {
            for k in c0.min(w)..c1.min(w) {
                if covered[[r, k]] {
                    acc += mosaic[[r, k]] * truth[[r, k]].conj();
                }
            }
        }
        (acc.norm() > 0.0).then(|| acc.arg() as f64)
    };
    let wrap = |d: f64| {
        (d + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
    };
    // Pixel of slide position (x, y) on the canvas.
    let px = |x: f64| ((x - c.origin_um.0) / c.pitch_um).round().max(0.0) as usize;
    let py = |y: f64| ((y - c.origin_um.1) / c.pitch_um).round().max(0.0) as usize;
    let (mut seams, mut within) = (Vec::new(), Vec::new());
    for (i, a) in fields.iter().enumerate() {
        let (fh, fw) = a.dim;
        let half = (fw as f64 * c.pitch_um / 2.0, fh as f64 * c.pitch_um / 2.0);
        let pa = positions[i];
        // Rows (or columns) across the field's middle half, for a step along x (or y).
        let (ry0, ry1) = (py(pa.1 - half.1 / 2.0), py(pa.1 + half.1 / 2.0));
        let (rx0, rx1) = (px(pa.0 - half.0 / 2.0), px(pa.0 + half.0 / 2.0));
        let step_x = |at: usize, gap: usize| -> Option<f64> {
            let left = mean_phase(
                ry0,
                ry1,
                at.checked_sub(gap / 2 + band)?,
                at.checked_sub(gap / 2)?,
            )?;
            let right = mean_phase(ry0, ry1, at + gap / 2, at + gap / 2 + band)?;
            Some(wrap(right - left))
        };
        let step_y = |at: usize, gap: usize| -> Option<f64> {
            let top = mean_phase(
                at.checked_sub(gap / 2 + band)?,
                at.checked_sub(gap / 2)?,
                rx0,
                rx1,
            )?;
            let bottom = mean_phase(at + gap / 2, at + gap / 2 + band, rx0, rx1)?;
            Some(wrap(bottom - top))
        };
        for (j, b) in fields.iter().enumerate().skip(i + 1) {
            let _ = b;
            let pb = positions[j];
            let (dx, dy) = ((pb.0 - pa.0).abs(), (pb.1 - pa.1).abs());
            if dy < half.1 / 2.0 && dx < 2.0 * half.0 && dx > half.0 {
                // Side by side: the seam at the midline of the overlap.
                let mid = px((pa.0 + pb.0) / 2.0);
                if let Some(s) = step_x(mid, 2 * band) {
                    seams.push(s);
                }
            } else if dx < half.0 / 2.0 && dy < 2.0 * half.1 && dy > half.1 {
                let mid = py((pa.1 + pb.1) / 2.0);
                if let Some(s) = step_y(mid, 2 * band) {
                    seams.push(s);
                }
            }
        }
        if let Some(s) = step_x(px(pa.0), 2 * band) {
            within.push(s);
        }
        if let Some(s) = step_y(py(pa.1), 2 * band) {
            within.push(s);
        }
    }
    let rms = |v: &[f64]| (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt();
    (rms(&seams), rms(&within))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_field_acquired_with_the_boards_calibration_is_reconstructed_with_it() {
        let dir = std::env::temp_dir().join(format!("fpm-scan-field-job-{}", std::process::id()));
        let field = dir.join("fields/r0c0");
        std::fs::create_dir_all(&field).unwrap();
        let board = fpm_physics::LedGeometry {
            dx_mm: 1.66,
            theta_deg: -4.6,
            ..fpm_physics::LedGeometry::paper()
        };
        let manifest = ScanManifest {
            format: FORMAT.into(),
            rows: 1,
            cols: 1,
            overlap: 0.15,
            fields: vec![ScanField {
                row: 0,
                col: 0,
                dataset: "fields/r0c0".into(),
                stage_um: [0.0, 0.0],
                z_um: None,
                focus: None,
            }],
        };
        let nominal = fpm_physics::LedGeometry::paper();
        let acquired = |source: &str| {
            let record = serde_json::json!({"geometry": board, "geometry_source": source});
            std::fs::write(field.join("acquisition.json"), record.to_string()).unwrap();
            field_job(&dir, &manifest, &field, &Job::default()).geometry
        };
        let resolved =
            |choice: reconstruction::GeometryChoice| choice.resolve(&field, &nominal).unwrap();
        assert_eq!(
            resolved(acquired("board")),
            (board, crate::calibration::GeometrySource::Board)
        );
        // The controller's nominal array: the dataset's own nominal placement.
        assert_eq!(
            resolved(acquired("nominal")),
            (nominal, crate::calibration::GeometrySource::Dataset)
        );
        // A placement file it was given: the geometry recorded, wherever the path points.
        let (geometry, source) = resolved(acquired("placement.json"));
        assert_eq!(geometry, board);
        assert_eq!(
            source.to_string(),
            "as acquired with placement.json (acquisition.json)"
        );
        // A record that names a measured geometry without it is refused, naming it.
        std::fs::write(
            field.join("acquisition.json"),
            r#"{"geometry_source": "board"}"#,
        )
        .unwrap();
        let err = reconstruction::GeometryChoice::AsAcquired
            .resolve(&field, &nominal)
            .unwrap_err();
        assert!(
            format!("{err:#}")
                .contains("acquisition.json: geometry_source \"board\" but no geometry"),
            "{err:#}"
        );
        // A calibration of the scan's own comes first.
        std::fs::write(field.join("calibration.json"), "{}").unwrap();
        assert_eq!(
            acquired("board"),
            reconstruction::GeometryChoice::File(field.join("calibration.json"))
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
