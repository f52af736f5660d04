//! What a client may ask the service to do: the job requests, with the same defaults
//! and ranges as the CLI's flags (`fpm_acquire::acquisition::defaults`, `Plan::validate`).

use std::path::PathBuf;

use anyhow::{bail, Result};
use fpm_acquire::acquisition::{defaults, Plan};
use fpm_frames::ServiceNames;
use fpm_host::reconstruction::Refocus;
use fpm_physics::reconstruct::Flatten;
use fpm_physics::System;
use fpm_protocol::{LedIndex, Rgb};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

/// The kinds a request may have, as an error lists them.
const KINDS: &str =
    "\"acquire\", \"calibrate\", \"reconstruct\", \"sequence\", \"resume\", \"dpc\" or \"scan\"";

/// A job to queue.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum JobRequest {
    /// Acquire a dataset (as `fpm acquire`): optionally calibrate first and
    /// reconstruct while the frames arrive.
    Acquire(AcquireRequest),
    /// Calibrate the LED array on the rig (pdcFPM, as `fpm acquire --calibrate` does
    /// first) and store the result on the controller, for the acquisitions after it.
    Calibrate(CalibrateRequest),
    /// Reconstruct a dataset on disk (as `fpm reconstruct`): the images, the report
    /// page, and the finished image as the job's snapshot.
    Reconstruct(ReconstructRequest),
    /// A raw capture sequence: the LEDs given, in their order, one labelled frame each,
    /// written as a dataset (no calibration, no reconstruction).
    Sequence(SequenceRequest),
    /// Complete an acquisition job that ended part-way (interrupted, cancelled,
    /// failed): its frames are kept, only the LEDs they lack are lit, into its output
    /// directory, with its settings.
    Resume(ResumeRequest),
    /// A live DPC preview (Tian & Waller 2015): the controller's four half-circle
    /// patterns at the objective's NA, `rounds` times, each round's phase and
    /// absorption the job's snapshot as soon as its fourth frame arrives; the last
    /// round written (phase.tif, absorption.tif, dpc.json). To find the sample and
    /// focus before a calibration or a scan.
    Dpc(DpcRequest),
    /// A scan of many fields (as `fpm scan`): the stage moves over a grid from where it
    /// is, each field acquired as `acquire` says into `out/fields/r<row>c<col>/`
    /// (calibrated at the first field when `acquire.calibrate`), and with
    /// `acquire.reconstruct` each field reconstructed while the next is acquired and
    /// all stitched into `out/mosaic/mosaic.zarr`. Needs a motorised stage. A scan
    /// ended part-way is completed by a `resume` job (fields done are skipped).
    Scan(ScanRequest),
}

/// A scan's settings: every field may be left out.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ScanRequest {
    /// Output directory (absolute): scan.json, the fields' datasets, the mosaic. It
    /// must not already hold a scan. Absent: a new directory under the service's runs
    /// directory.
    #[serde(default)]
    #[schema(value_type = Option<String>)]
    pub out: Option<PathBuf>,
    /// The grid, [rows, columns]; field [0, 0] is where the stage is, the scan runs
    /// over +x and +y from there.
    #[serde(default = "three_by_three")]
    pub fields: [usize; 2],
    /// Neighbouring fields overlap by this fraction of a field (0–0.9).
    #[serde(default = "overlap")]
    pub overlap: f64,
    /// The stage's position error, 1σ, µm: how far stitching searches and how much
    /// it trusts the stage.
    #[serde(default = "stage_sigma_um")]
    pub stage_sigma_um: f64,
    /// Focus each field before acquiring it: the defocus read from a few bright-field
    /// frames, the stage moved when it is clear (default true).
    #[serde(default = "yes")]
    pub autofocus: bool,
    /// Each field's acquisition, as an `acquire` job's settings (without `out`, which
    /// is the scan's, and in one colour).
    #[serde(default = "field_acquisition")]
    pub acquire: AcquireRequest,
}

fn three_by_three() -> [usize; 2] {
    [3, 3]
}
fn overlap() -> f64 {
    0.15
}
fn stage_sigma_um() -> f64 {
    fpm_physics::stitch::Settings::default().stage_sigma_um
}
fn field_acquisition() -> AcquireRequest {
    // Every field of an acquire request has its default.
    serde_json::from_value(serde_json::json!({})).expect("an acquire request's defaults")
}

impl ScanRequest {
    /// The scan's plan on camera `camera`, checked: a field out of its range is named
    /// (`acquire.step_ms`, `fields`).
    pub fn plan(&self, camera: &ServiceNames) -> Result<fpm_acquire::scan::ScanPlan> {
        let Some(out) = &self.out else {
            bail!("out: missing (the service places a job without one under its runs directory)");
        };
        if out.join("scan.json").exists() {
            bail!(
                "out {}: already holds a scan; resume its job to complete it, or pick another directory",
                out.display()
            );
        }
        self.plan_in(camera, out)
    }

    /// The plan writing into `out`, which may hold the part-way scan of an earlier run
    /// of this request (a resume).
    pub fn plan_in(
        &self,
        camera: &ServiceNames,
        out: &std::path::Path,
    ) -> Result<fpm_acquire::scan::ScanPlan> {
        if !out.is_absolute() {
            bail!(
                "out {}: give an absolute path (the service's working directory is not the client's)",
                out.display()
            );
        }
        if self.acquire.out.is_some() {
            bail!("acquire.out: a scan's fields go under its own out; leave acquire.out out");
        }
        if self.acquire.colors.is_some() || self.acquire.focus_color.is_some() {
            bail!(
                "acquire.colors: a scan is in one colour for now; scan each colour as its own job"
            );
        }
        let field = self
            .acquire
            .plan_in(camera, out)
            .map_err(|e| anyhow::anyhow!("acquire.{e:#}"))?;
        let [rows, cols] = self.fields;
        let plan = fpm_acquire::scan::ScanPlan {
            autofocus: self.autofocus,
            ..fpm_acquire::scan::ScanPlan::new(rows, cols, self.overlap, field, self.stage_sigma_um)
        };
        // Its messages name the request's fields (`fields`, `overlap`, `stage_sigma_um`).
        plan.validate()?;
        Ok(plan)
    }
}

/// A live DPC preview's settings: every field may be left out.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct DpcRequest {
    /// Output directory (absolute) for the last round. Absent: a new directory under
    /// the service's runs directory.
    #[serde(default)]
    #[schema(value_type = Option<String>)]
    pub out: Option<PathBuf>,
    /// Rounds of four frames (1–256).
    #[serde(default = "one_round")]
    pub rounds: usize,
    /// How long each pattern stays lit, ms.
    #[serde(default = "step_ms")]
    pub step_ms: f64,
    /// LED colour, [r, g, b] (0–255).
    #[serde(default = "color")]
    pub color: [u8; 3],
    /// The camera's dark level, counts.
    #[serde(default = "dark_level")]
    pub dark_level: f64,
    /// Illumination wavelength, µm.
    #[serde(default = "wavelength_um")]
    pub wavelength_um: f64,
    /// Objective NA (the patterns' outer NA).
    #[serde(default = "na")]
    pub na: f64,
    /// Objective magnification.
    #[serde(default = "magnification")]
    pub magnification: f64,
    /// Camera pixel, µm.
    #[serde(default = "pixel_um")]
    pub pixel_um: f64,
    /// Tikhonov weight of the phase (as `fpm dpc --reg-phase`).
    #[serde(default = "reg")]
    pub reg_phase: f64,
    /// Tikhonov weight of the absorption.
    #[serde(default = "reg")]
    pub reg_absorption: f64,
}

fn one_round() -> usize {
    1
}

fn reg() -> f64 {
    fpm_physics::dpc::Regularisation::default().phase
}

impl DpcRequest {
    /// The plan on the rig, the LEDs placed by `geometry` (the board's stored
    /// calibration, or its nominal grid).
    pub fn plan(
        &self,
        camera: &ServiceNames,
        geometry: fpm_physics::LedGeometry,
    ) -> Result<fpm_acquire::dpc::LivePlan> {
        let Some(out) = &self.out else {
            bail!("out: missing (the service places a job without one under its runs directory)");
        };
        if !out.is_absolute() {
            bail!(
                "out {}: give an absolute path (the service's working directory is not the client's)",
                out.display()
            );
        }
        let max = fpm_acquire::dpc::MAX_ROUNDS;
        if !(1..=max).contains(&self.rounds) {
            bail!("rounds {}: give 1 to {max}", self.rounds);
        }
        if !(self.step_ms.is_finite() && self.step_ms > 0.0) {
            bail!("step_ms {}: give a positive time in ms", self.step_ms);
        }
        for (key, v) in [
            ("reg_phase", self.reg_phase),
            ("reg_absorption", self.reg_absorption),
        ] {
            if !(v.is_finite() && v > 0.0) {
                bail!("{key} {v}: give a positive weight (1e-3 by default)");
            }
        }
        let system = System {
            wavelength_um: self.wavelength_um,
            na: self.na,
            magnification: self.magnification,
            pixel_size_um: self.pixel_um,
            entrance_pupil_mm: None,
        };
        if let Some((key, v, why)) = system.out_of_range() {
            let key = if key == "pixel_size_um" {
                "pixel_um"
            } else {
                key
            };
            bail!("{key} {v}: {why}");
        }
        let [r, g, b] = self.color;
        Ok(fpm_acquire::dpc::LivePlan {
            camera: camera.clone(),
            out: out.clone(),
            system,
            geometry,
            rounds: self.rounds,
            step_ms: self.step_ms,
            color: Rgb { r, g, b },
            dark_level: self.dark_level,
            reg: fpm_physics::dpc::Regularisation {
                phase: self.reg_phase,
                absorption: self.reg_absorption,
            },
        })
    }
}

/// Which job to complete.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ResumeRequest {
    /// The job to complete (an `acquire` job, or a `resume` of one).
    pub job: i64,
    /// Set by the service: that job's output directory (a value sent is replaced).
    #[serde(default)]
    #[schema(value_type = Option<String>)]
    pub out: Option<PathBuf>,
}

impl JobRequest {
    /// Read a request from its JSON body; what is wrong is named by its field's path
    /// (`passes: invalid type: string "five", expected usize`).
    pub fn parse(body: &[u8]) -> Result<Self, String> {
        let mut value: serde_json::Value =
            serde_json::from_slice(body).map_err(|e| format!("not a JSON request: {e}"))?;
        let fields = value
            .as_object_mut()
            .ok_or("a job request is a JSON object with a \"kind\"")?;
        let kind = match fields.remove("kind") {
            Some(serde_json::Value::String(k)) => k,
            Some(other) => return Err(format!("kind {other}: give {KINDS}")),
            None => return Err(format!("kind: missing; give {KINDS}")),
        };
        let named = |e: serde_path_to_error::Error<serde_json::Error>| {
            let path = e.path().to_string();
            match path.as_str() {
                "." => e.inner().to_string(),
                _ => format!("{path}: {}", e.inner()),
            }
        };
        match kind.as_str() {
            "acquire" => serde_path_to_error::deserialize(value)
                .map(JobRequest::Acquire)
                .map_err(named),
            "calibrate" => serde_path_to_error::deserialize(value)
                .map(JobRequest::Calibrate)
                .map_err(named),
            "reconstruct" => serde_path_to_error::deserialize(value)
                .map(JobRequest::Reconstruct)
                .map_err(named),
            "sequence" => serde_path_to_error::deserialize(value)
                .map(JobRequest::Sequence)
                .map_err(named),
            "resume" => serde_path_to_error::deserialize(value)
                .map(JobRequest::Resume)
                .map_err(named),
            "dpc" => serde_path_to_error::deserialize(value)
                .map(JobRequest::Dpc)
                .map_err(named),
            "scan" => serde_path_to_error::deserialize(value)
                .map(JobRequest::Scan)
                .map_err(named),
            other => Err(format!("kind \"{other}\": unknown; give {KINDS}")),
        }
    }

    /// Check every value the request holds, as the job would when it runs, so that
    /// a bad one is said at submission (the service's one check of a request; a
    /// `resume` is checked against the store by the service). The DPC plan's LED
    /// places are the board's, read when the job runs: here the paper's board stands
    /// in, and only the request's own values are checked.
    pub fn check(&self, camera: &ServiceNames) -> Result<()> {
        match self {
            JobRequest::Acquire(a) => a.plan(camera).map(drop),
            JobRequest::Calibrate(c) => c.plan(camera).map(drop),
            JobRequest::Sequence(s) => s.as_acquisition().plan(camera).map(drop),
            JobRequest::Reconstruct(r) => r.job().map(drop),
            JobRequest::Scan(s) => s.plan(camera).map(drop),
            JobRequest::Dpc(d) => d.plan(camera, fpm_physics::LedGeometry::paper()).map(drop),
            JobRequest::Resume(_) => Ok(()),
        }
    }

    /// Whether the job lights LEDs or takes frames (all but a reconstruction): it
    /// needs a controller that speaks this host's protocol.
    pub fn drives_rig(&self) -> bool {
        !matches!(self, JobRequest::Reconstruct(_))
    }

    /// The kind, as the job list shows it.
    pub fn kind(&self) -> &'static str {
        match self {
            JobRequest::Acquire(_) => "acquire",
            JobRequest::Calibrate(_) => "calibrate",
            JobRequest::Reconstruct(_) => "reconstruct",
            JobRequest::Sequence(_) => "sequence",
            JobRequest::Resume(_) => "resume",
            JobRequest::Dpc(_) => "dpc",
            JobRequest::Scan(_) => "scan",
        }
    }

    /// Where the job writes (set by [`JobRequest::place`] when the client left it out).
    pub fn out(&self) -> Option<&std::path::Path> {
        match self {
            JobRequest::Acquire(a) => a.out.as_deref(),
            JobRequest::Calibrate(c) => c.out.as_deref(),
            JobRequest::Reconstruct(r) => r.out.as_deref(),
            JobRequest::Sequence(s) => s.out.as_deref(),
            JobRequest::Resume(r) => r.out.as_deref(),
            JobRequest::Dpc(d) => d.out.as_deref(),
            JobRequest::Scan(s) => s.out.as_deref(),
        }
    }

    /// Give a job sent without `out` a new directory of its own under `runs` (named by
    /// the time it was queued, to the microsecond; a clash takes the next name).
    pub fn place(&mut self, runs: &std::path::Path) {
        let out = match self {
            JobRequest::Acquire(a) => &mut a.out,
            JobRequest::Calibrate(c) => &mut c.out,
            JobRequest::Reconstruct(r) => &mut r.out,
            JobRequest::Sequence(s) => &mut s.out,
            JobRequest::Resume(_) => return,
            JobRequest::Dpc(d) => &mut d.out,
            JobRequest::Scan(s) => &mut s.out,
        };
        if out.is_some() {
            return;
        }
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        let stamp = format!("run-{}-{:06}", now.as_secs(), now.subsec_micros());
        let mut dir = runs.join(&stamp);
        for n in 1.. {
            if !dir.exists() {
                break;
            }
            dir = runs.join(format!("{stamp}-{n}"));
        }
        *out = Some(dir);
    }
}

/// `fpm acquire` as a request: every field may be left out (the CLI's defaults; `out`
/// a new directory under the service's runs directory).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct AcquireRequest {
    /// Output directory (absolute): dataset.toml + frames/, acquisition.json, the
    /// calibration and the reconstruction. It must not already hold a dataset. Absent:
    /// a new directory under the service's runs directory.
    #[serde(default)]
    #[schema(value_type = Option<String>)]
    pub out: Option<PathBuf>,
    /// Calibrate the LED array first (pdcFPM).
    #[serde(default)]
    pub calibrate: bool,
    /// Store the calibration on the controller.
    #[serde(default)]
    pub store_geometry: bool,
    /// Reconstruct while the frames arrive.
    #[serde(default)]
    pub reconstruct: bool,
    /// How long each LED stays lit, ms.
    #[serde(default = "step_ms")]
    pub step_ms: f64,
    /// Defocus for calibration, µm toward the LEDs.
    #[serde(default = "defocus_um")]
    pub defocus_um: f64,
    /// 1σ of that defocus, µm.
    #[serde(default = "defocus_sigma_um")]
    pub defocus_sigma_um: f64,
    /// LED colour, [r, g, b] (0–255).
    #[serde(default = "color")]
    pub color: [u8; 3],
    /// The camera's dark level, counts.
    #[serde(default = "dark_level")]
    pub dark_level: f64,
    /// Illumination wavelength, µm.
    #[serde(default = "wavelength_um")]
    pub wavelength_um: f64,
    /// Objective NA.
    #[serde(default = "na")]
    pub na: f64,
    /// Objective magnification.
    #[serde(default = "magnification")]
    pub magnification: f64,
    /// Camera pixel, µm.
    #[serde(default = "pixel_um")]
    pub pixel_um: f64,
    /// The objective's entrance pupil distance above the sample, mm (absent:
    /// telecentric).
    #[serde(default)]
    pub entrance_pupil_mm: Option<f64>,
    /// EPRY passes after the last frame.
    #[serde(default = "passes")]
    pub passes: usize,
    /// Tile side, camera pixels (absent: from the physics).
    #[serde(default)]
    pub tile: Option<usize>,
    /// Take the clear background's low-order phase off.
    #[serde(default)]
    pub flatten_background: bool,
    /// Frames between live snapshots of the reconstruction (0: only the finished one).
    #[serde(default = "snapshot_every")]
    pub snapshot_every: usize,
    /// Light only these LEDs, `[row, col]`, in this order. Absent: every LED of the
    /// array, nearest the axis first.
    #[serde(default)]
    pub leds: Option<Vec<[u8; 2]>>,
    /// Dark-field LEDs lit together in each frame (1: one each; more: a multiplexed
    /// acquisition through the controller's LED sets, from its stored calibration).
    #[serde(default = "one_round")]
    pub multiplex: usize,
    /// Bright-field LEDs lit together in each frame (default 1).
    #[serde(default = "one_round")]
    pub multiplex_bright: usize,
    /// Acquire in colour: a whole acquisition per colour (`red`, `green`, `blue`, each
    /// optionally `NAME:UM`), written as a colour dataset (each colour calibrated with
    /// `calibrate`); `color` and `wavelength_um` then do not apply. Absent: one colour.
    #[serde(default)]
    pub colors: Option<Vec<String>>,
    /// With `colors`: the colour the sample was focused in (default green).
    #[serde(default)]
    pub focus_color: Option<String>,
}

/// A calibration on the rig: every field may be left out (`fpm acquire --calibrate`'s
/// defaults; the result is stored on the controller unless `store_geometry` is false).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CalibrateRequest {
    /// Output directory (absolute): calibration/ (its frames), calibration.json and its
    /// page. Absent: a new directory under the service's runs directory.
    #[serde(default)]
    #[schema(value_type = Option<String>)]
    pub out: Option<PathBuf>,
    /// Store the calibration on the controller (acquisitions without `calibrate` then
    /// start from it).
    #[serde(default = "yes")]
    pub store_geometry: bool,
    /// How long each LED stays lit, ms.
    #[serde(default = "step_ms")]
    pub step_ms: f64,
    /// Defocus, µm toward the LEDs.
    #[serde(default = "defocus_um")]
    pub defocus_um: f64,
    /// 1σ of that defocus, µm.
    #[serde(default = "defocus_sigma_um")]
    pub defocus_sigma_um: f64,
    /// LED colour, [r, g, b] (0–255).
    #[serde(default = "color")]
    pub color: [u8; 3],
    /// The camera's dark level, counts.
    #[serde(default = "dark_level")]
    pub dark_level: f64,
    /// Illumination wavelength, µm.
    #[serde(default = "wavelength_um")]
    pub wavelength_um: f64,
    /// Objective NA.
    #[serde(default = "na")]
    pub na: f64,
    /// Objective magnification.
    #[serde(default = "magnification")]
    pub magnification: f64,
    /// Camera pixel, µm.
    #[serde(default = "pixel_um")]
    pub pixel_um: f64,
}

impl CalibrateRequest {
    /// The calibration's plan on camera `camera`, checked as an acquisition's is.
    pub fn plan(&self, camera: &ServiceNames) -> Result<Plan> {
        let Some(out) = &self.out else {
            bail!("out: missing (the service places a job without one under its runs directory)");
        };
        if out.join("calibration.json").exists() {
            bail!(
                "out {}: already holds a calibration; pick another directory",
                out.display()
            );
        }
        let as_acquisition = AcquireRequest {
            out: self.out.clone(),
            calibrate: true,
            store_geometry: self.store_geometry,
            reconstruct: false,
            step_ms: self.step_ms,
            defocus_um: self.defocus_um,
            defocus_sigma_um: self.defocus_sigma_um,
            color: self.color,
            dark_level: self.dark_level,
            wavelength_um: self.wavelength_um,
            na: self.na,
            magnification: self.magnification,
            pixel_um: self.pixel_um,
            entrance_pupil_mm: None,
            passes: passes(),
            tile: None,
            flatten_background: false,
            snapshot_every: 0,
            leds: None,
            multiplex: 1,
            multiplex_bright: 1,
            colors: None,
            focus_color: None,
        };
        Ok(Plan {
            capture: false,
            ..as_acquisition.plan_in(camera, out)?
        })
    }
}

/// `refocus_um`: a distance in µm, or the word "auto".
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum RefocusValue {
    /// A distance, µm.
    Um(f64),
    /// "auto".
    Word(String),
}

/// `fpm reconstruct` as a request: the dataset, and settings that may be left out
/// (the CLI's defaults).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ReconstructRequest {
    /// The dataset's directory (absolute; with dataset.toml): an acquisition job's
    /// `out`, say.
    #[schema(value_type = String)]
    pub dataset: PathBuf,
    /// Output directory (absolute): amplitude, phase, pupil, report.json and
    /// report.html. Absent: a new directory under the service's runs directory.
    #[serde(default)]
    #[schema(value_type = Option<String>)]
    pub out: Option<PathBuf>,
    /// The LED placement (absolute path): a calibration.json, refined-board.json or
    /// placement file. Absent: the dataset's nominal placement.
    #[serde(default)]
    #[schema(value_type = Option<String>)]
    pub calibration: Option<PathBuf>,
    /// The LEDs' height below the sample, mm, instead of the dataset's.
    #[serde(default)]
    pub led_height_mm: Option<f64>,
    /// The objective's entrance pupil distance above the sample, mm (absent:
    /// telecentric).
    #[serde(default)]
    pub entrance_pupil_mm: Option<f64>,
    /// Passes over all frames.
    #[serde(default = "reconstruct_passes")]
    pub passes: usize,
    /// Upsampling of the object over the camera's sampling.
    #[serde(default = "upsample")]
    pub upsample: usize,
    /// Tile side, camera pixels (absent: from the physics).
    #[serde(default)]
    pub tile: Option<usize>,
    /// Keep the pupil fixed (no aberration recovery).
    #[serde(default)]
    pub fixed_pupil: bool,
    /// Refine each LED's position from the frames.
    #[serde(default)]
    pub refine_leds: bool,
    /// Take the clear background's low-order phase off.
    #[serde(default)]
    pub flatten_background: bool,
    /// Refocus the object by this many µm (toward the LEDs positive), or "auto": as
    /// far as the bright-field frames' shifts say. Absent: that too where the shifts
    /// clearly show a defocus, else as in focus (the report's `refocus` says which).
    #[serde(default)]
    #[schema(value_type = Option<Object>, example = json!(140.0))]
    pub refocus_um: Option<RefocusValue>,
    /// Image format: "tiff" or "ome-zarr".
    #[serde(default)]
    pub format: OutputFormat,
}

/// How a reconstruction's images are written.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "kebab-case")]
pub enum OutputFormat {
    /// OME-TIFF (and plain TIFF) files.
    #[default]
    Tiff,
    /// One OME-Zarr store.
    OmeZarr,
}

fn reconstruct_passes() -> usize {
    fpm_physics::reconstruct::defaults::PASSES
}
fn upsample() -> usize {
    fpm_physics::reconstruct::defaults::UPSAMPLE
}

impl ReconstructRequest {
    /// The reconstruction job, checked: a path that is not absolute or not there, or a
    /// setting out of its range, is named.
    pub fn job(&self) -> Result<fpm_host::reconstruction::Job> {
        use fpm_host::reconstruction::{GeometryChoice, Job};
        let absolute = |name: &str, path: &std::path::Path| -> Result<()> {
            if !path.is_absolute() {
                bail!(
                    "{name} {}: give an absolute path (the service's working directory is not the client's)",
                    path.display()
                );
            }
            Ok(())
        };
        absolute("dataset", &self.dataset)?;
        if !self.dataset.join("dataset.toml").is_file() {
            bail!("dataset {}: no dataset.toml there", self.dataset.display());
        }
        if let Some(out) = &self.out {
            absolute("out", out)?;
        }
        let geometry = match (&self.calibration, self.led_height_mm) {
            (Some(_), Some(_)) => bail!("calibration and led_height_mm: give one"),
            (Some(path), None) => {
                absolute("calibration", path)?;
                if !path.is_file() {
                    bail!("calibration {}: no such file", path.display());
                }
                GeometryChoice::File(path.clone())
            }
            (None, Some(h)) => GeometryChoice::LedHeightMm(h),
            (None, None) => GeometryChoice::AsAcquired,
        };
        let defaults = Job::default();
        let job = Job {
            geometry,
            entrance_pupil_mm: self.entrance_pupil_mm,
            settings: fpm_physics::reconstruct::Settings {
                upsample: self.upsample,
                update_pupil: !self.fixed_pupil,
                refine_leds: self
                    .refine_leds
                    .then(fpm_physics::reconstruct::Refine::default),
                flatten: if self.flatten_background {
                    Flatten::Auto
                } else {
                    Flatten::Keep
                },
                ..defaults.settings
            },
            refocus: match &self.refocus_um {
                None => Refocus::WhereClear,
                Some(RefocusValue::Um(um)) => Refocus::Distance(*um),
                Some(RefocusValue::Word(w)) if w.eq_ignore_ascii_case("auto") => Refocus::Auto,
                Some(RefocusValue::Word(w)) => {
                    bail!("refocus_um \"{w}\": give a distance in µm or \"auto\"")
                }
            },
            passes: self.passes,
            tile: self.tile,
            ..defaults
        };
        job.validate()?;
        Ok(job)
    }
}

/// A raw capture sequence as a request: the LEDs, and settings that may be left out
/// (`fpm acquire`'s defaults).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SequenceRequest {
    /// The LEDs to light, `[row, col]`, in this order, one frame each.
    pub leds: Vec<[u8; 2]>,
    /// Output directory (absolute; it must not hold a dataset). Absent: a new directory
    /// under the service's runs directory.
    #[serde(default)]
    #[schema(value_type = Option<String>)]
    pub out: Option<PathBuf>,
    /// How long each LED stays lit, ms.
    #[serde(default = "step_ms")]
    pub step_ms: f64,
    /// LED colour, [r, g, b] (0–255).
    #[serde(default = "color")]
    pub color: [u8; 3],
    /// The camera's dark level, counts.
    #[serde(default = "dark_level")]
    pub dark_level: f64,
    /// Illumination wavelength, µm.
    #[serde(default = "wavelength_um")]
    pub wavelength_um: f64,
    /// Objective NA.
    #[serde(default = "na")]
    pub na: f64,
    /// Objective magnification.
    #[serde(default = "magnification")]
    pub magnification: f64,
    /// Camera pixel, µm.
    #[serde(default = "pixel_um")]
    pub pixel_um: f64,
}

impl SequenceRequest {
    /// The acquisition of just these LEDs that the sequence is.
    pub fn as_acquisition(&self) -> AcquireRequest {
        AcquireRequest {
            out: self.out.clone(),
            calibrate: false,
            store_geometry: false,
            reconstruct: false,
            step_ms: self.step_ms,
            defocus_um: defocus_um(),
            defocus_sigma_um: defocus_sigma_um(),
            color: self.color,
            dark_level: self.dark_level,
            wavelength_um: self.wavelength_um,
            na: self.na,
            magnification: self.magnification,
            pixel_um: self.pixel_um,
            entrance_pupil_mm: None,
            passes: passes(),
            tile: None,
            flatten_background: false,
            snapshot_every: 0,
            leds: Some(self.leds.clone()),
            multiplex: 1,
            multiplex_bright: 1,
            colors: None,
            focus_color: None,
        }
    }
}

fn yes() -> bool {
    true
}
fn step_ms() -> f64 {
    defaults::STEP_MS
}
fn defocus_um() -> f64 {
    defaults::DEFOCUS_UM
}
fn defocus_sigma_um() -> f64 {
    defaults::DEFOCUS_SIGMA_UM
}
fn color() -> [u8; 3] {
    let c = defaults::COLOR;
    [c.r, c.g, c.b]
}
fn dark_level() -> f64 {
    defaults::DARK_LEVEL
}
fn wavelength_um() -> f64 {
    defaults::WAVELENGTH_UM
}
fn na() -> f64 {
    defaults::NA
}
fn magnification() -> f64 {
    defaults::MAGNIFICATION
}
fn pixel_um() -> f64 {
    defaults::PIXEL_UM
}
fn passes() -> usize {
    defaults::PASSES
}
fn snapshot_every() -> usize {
    defaults::SNAPSHOT_EVERY
}

impl AcquireRequest {
    /// The acquisition's plan on camera `camera`, checked: a field out of its range is
    /// named (as the CLI names its flag, without the dashes).
    pub fn plan(&self, camera: &ServiceNames) -> Result<Plan> {
        let Some(out) = &self.out else {
            bail!("out: missing (the service places a job without one under its runs directory)");
        };
        if out.join("dataset.toml").exists() {
            bail!(
                "out {}: already holds a dataset; pick another directory",
                out.display()
            );
        }
        self.plan_in(camera, out)
    }

    /// The plan writing into `out`, which may hold the partial dataset of an earlier run
    /// of this request (a resume).
    pub fn plan_in(&self, camera: &ServiceNames, out: &std::path::Path) -> Result<Plan> {
        if !out.is_absolute() {
            bail!(
                "out {}: give an absolute path (the service's working directory is not the client's)",
                out.display()
            );
        }
        if self.store_geometry && !self.calibrate {
            bail!("store_geometry needs calibrate");
        }
        let [r, g, b] = self.color;
        let plan = Plan {
            camera: camera.clone(),
            out: out.to_path_buf(),
            calibrate: self.calibrate,
            capture: true,
            store_geometry: self.store_geometry,
            reconstruct: self.reconstruct,
            step_ms: self.step_ms,
            defocus_um: self.defocus_um,
            defocus_sigma_um: self.defocus_sigma_um,
            color: Rgb { r, g, b },
            dark_level: self.dark_level,
            system: System {
                wavelength_um: self.wavelength_um,
                na: self.na,
                magnification: self.magnification,
                pixel_size_um: self.pixel_um,
                entrance_pupil_mm: self.entrance_pupil_mm,
            },
            passes: self.passes,
            tile: self.tile,
            flatten: if self.flatten_background {
                Flatten::Auto
            } else {
                Flatten::Keep
            },
            snapshot_every: self.snapshot_every,
            geometry: None,
            leds: self
                .leds
                .as_ref()
                .map(|l| l.iter().map(|&[r, c]| LedIndex::new(r, c)).collect()),
            multiplex: fpm_physics::multiplex::Multiplex {
                dark_field: self.multiplex,
                bright_field: self.multiplex_bright,
            },
        };
        // The system's own names, as the request names them.
        plan.validate().map_err(|e| {
            anyhow::anyhow!("{}", e.to_string().replace("pixel_size_um", "pixel_um"))
        })?;
        self.color_plan()?;
        Ok(plan)
    }

    /// The colours asked for (`colors`, `focus_color`), checked; None for one colour.
    pub fn color_plan(&self) -> Result<Option<fpm_acquire::color::ColorPlan>> {
        match &self.colors {
            None => {
                if self.focus_color.is_some() {
                    bail!("focus_color applies with colors");
                }
                Ok(None)
            }
            Some(colors) => {
                if self.multiplex > 1 || self.multiplex_bright > 1 {
                    bail!("colors with multiplex: a colour acquisition lights one LED per frame");
                }
                if self.leds.is_some() {
                    bail!(
                        "colors with leds: a colour acquisition lights every LED in every colour"
                    );
                }
                let focus = self.focus_color.as_deref().unwrap_or("green");
                fpm_acquire::color::ColorPlan::parse(colors, focus, "colors").map(Some)
            }
        }
    }
}
