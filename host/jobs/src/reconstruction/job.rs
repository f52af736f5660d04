//! A reconstruction job: one dataset, how to reconstruct it, and where the result goes
//! — what `fpm reconstruct`, its batch runner (`--out-root`) and Python all run. Its
//! settings are checked up front, each against a stated range, and a value outside it
//! is an error naming the setting (a camera gamma is checked where the dataset's own
//! `[camera] gamma` is, as the job applies it).

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use fpm_physics::reconstruct::refocus::DefocusEstimate;
use fpm_physics::reconstruct::{GammaScan, Settings};
use fpm_physics::{LedGeometry, System};

use super::height;
use super::refocus::{defocus_on_disk, RefocusChoice, RefocusReport};
use super::{reconstruct_on_disk, reconstruct_with_system, Reconstruction, Request, StepTime};
use crate::calibration::{GeometrySource, PlacementFile};
use crate::dataset::{Dataset, DatasetInfo, DatasetOnDisk};

/// Which LED geometry the job reconstructs with.
#[derive(Debug, Clone, PartialEq)]
pub enum GeometryChoice {
    /// What the dataset was acquired with, where its acquisition.json records a
    /// measured placement (the calibration made then, or the one stored on the board:
    /// [`crate::calibration::as_acquired`]), else its nominal placement: the default,
    /// so a dataset acquired calibrated is reconstructed calibrated without flags.
    AsAcquired,
    /// The dataset's nominal placement (dataset.toml), whatever it was acquired with.
    Nominal,
    /// A calibration.json, refined-board.json or placement file.
    File(PathBuf),
    /// The nominal placement at this LED height, mm.
    LedHeightMm(f64),
    /// A geometry the caller made, and what to call its source.
    Given(LedGeometry, String),
}

impl GeometryChoice {
    /// The geometry and its source, for the dataset in `dir` whose nominal geometry is
    /// `nominal`.
    pub fn resolve(
        &self,
        dir: &Path,
        nominal: &LedGeometry,
    ) -> Result<(LedGeometry, GeometrySource)> {
        Ok(match self {
            Self::AsAcquired => crate::calibration::as_acquired(dir, nominal)?
                .unwrap_or((*nominal, GeometrySource::Dataset)),
            Self::Nominal => (*nominal, GeometrySource::Dataset),
            Self::File(path) => (
                PlacementFile::read(path)?.geometry(nominal),
                GeometrySource::File(path.clone()),
            ),
            Self::LedHeightMm(height_mm) => (
                LedGeometry {
                    height_mm: *height_mm,
                    ..*nominal
                },
                GeometrySource::DatasetAtHeight(*height_mm),
            ),
            Self::Given(geometry, name) => (*geometry, GeometrySource::Given(name.clone())),
        })
    }
}

/// How the frames were encoded, when the dataset's `[camera] gamma` is not to be used.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraGamma {
    /// Read it from the frames ([`crate::camera_gamma::scan`]).
    Auto,
    /// This display gamma.
    Exponent(f64),
}

/// Why a job read the camera gamma from the frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum GammaScanReason {
    /// `--camera-gamma auto`: decoded with whatever the scan found.
    Asked,
    /// 8-bit frames (by the dataset's bit depth, else their sample type) whose dataset
    /// states no gamma: images saved for viewing often
    /// carry one (the vendored USAF set does), and read as linear they ring. Decoded
    /// only where the scan is clear ([`GammaScan::is_clear`]).
    EightBitUnstated,
    /// Integer frames of more than 8 bits whose dataset states no gamma: a display
    /// gamma is rare there, but read as linear it raised the 12-bit sets' error by
    /// 60–320 % (`fpm bench warnings`). Screened first (linear against 1.4, a few
    /// passes), scanned only where the screen shows a gamma, decoded only where clear.
    Unstated,
}

/// How far the frames are refocused.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Refocus {
    /// This far, µm (toward the LEDs positive, as a dataset's `defocus_um`; 0: as in
    /// focus).
    Distance(f64),
    /// As far as the bright-field frames' shifts say
    /// ([`fpm_physics::reconstruct::refocus`]), however weakly.
    Auto,
    /// As far as the frames' shifts say where they clearly show a defocus (beyond 3σ
    /// of none), else as in focus: the default, since a sample left out of focus is
    /// the commonest cause of a blurred first run and the shifts cost one FFT a frame.
    #[default]
    WhereClear,
}

/// A reconstruction job; see the module's doc.
#[derive(Debug, Clone)]
pub struct Job {
    /// The LED geometry.
    pub geometry: GeometryChoice,
    /// The objective's entrance pupil above the sample, mm (None: telecentric).
    pub entrance_pupil_mm: Option<f64>,
    /// Overrides the dataset's `[camera] gamma` (None: the dataset's; 8-bit frames that
    /// state none are scanned, and decoded where the scan is clear).
    pub camera_gamma: Option<CameraGamma>,
    /// EPRY's settings (their `defocus_um` is set from [`Self::refocus`]).
    pub settings: Settings,
    /// How far the frames are refocused.
    pub refocus: Refocus,
    /// Passes over all frames.
    pub passes: usize,
    /// Tile side, camera pixels (None: from the physics).
    pub tile: Option<usize>,
    /// In-focus frames up to this many GB are held in memory; more are read from disk
    /// band by band (the same result; 0: always from disk).
    pub frame_memory_gb: f64,
}

impl Default for Job {
    fn default() -> Self {
        Self {
            geometry: GeometryChoice::AsAcquired,
            entrance_pupil_mm: None,
            camera_gamma: None,
            settings: Settings::default(),
            refocus: Refocus::default(),
            passes: fpm_physics::reconstruct::defaults::PASSES,
            tile: None,
            frame_memory_gb: 8.0,
        }
    }
}

/// Ranges the job's settings are held to (named in the errors).
pub use fpm_physics::reconstruct::limits;

/// What a job reports as it goes.
#[derive(Debug, Clone, Copy)]
pub enum JobEvent {
    /// `--camera-gamma auto`: candidates reconstructed so far.
    GammaCandidates {
        /// Done.
        done: usize,
        /// In all.
        total: usize,
    },
    /// The frames are over the memory budget and are read from disk band by band.
    FromDisk {
        /// Bytes the in-focus frames take.
        bytes: u64,
    },
    /// The bright/dark-field edge's LED height is [`height::WEIGH_SIGMA`] from the
    /// dataset's: the run is done again at it, and the one whose frames fit clearly
    /// better kept ([`height`]).
    WeighingEdgeHeight {
        /// The dataset's, mm.
        stated_mm: f64,
        /// The edge's, mm.
        edge_mm: f64,
    },
    /// Frame updates so far, over all tiles.
    Updates {
        /// Done.
        done: usize,
        /// In all.
        total: usize,
    },
}

/// A finished job: the reconstruction (its report scored against a simulation's truth
/// when the dataset has one) and what the outputs need of the dataset.
pub struct Finished {
    /// The images and report.
    pub reconstruction: Reconstruction,
    /// The gamma `--camera-gamma auto` found, with its scan.
    pub gamma_scan: Option<GammaScan>,
    /// The dataset's optics, as reconstructed.
    pub system: System,
    /// The dataset's nominal geometry.
    pub nominal: LedGeometry,
}

impl Job {
    /// Every setting in its range, or an error naming the first that is not.
    pub fn validate(&self) -> Result<()> {
        self.settings.validate()?;
        if let Refocus::Distance(um) = self.refocus {
            Settings {
                defocus_um: um,
                ..self.settings
            }
            .validate()?;
        }
        let positive = |x: f64| x.is_finite() && x > 0.0;
        limits::check_run(self.passes, self.tile)?;
        if let Some(p) = self.entrance_pupil_mm {
            if !positive(p) {
                bail!("entrance_pupil_mm {p}: must be a positive distance in mm");
            }
        }
        if let GeometryChoice::LedHeightMm(h) = self.geometry {
            if !positive(h) {
                bail!("led_height_mm {h}: must be a positive distance in mm");
            }
        }
        if !(self.frame_memory_gb.is_finite() && self.frame_memory_gb >= 0.0) {
            bail!(
                "frame_memory_gb {}: must be a size in GB, 0 or more (0: always read the frames from disk band by band)",
                self.frame_memory_gb
            );
        }
        Ok(())
    }

    /// Reconstruct the dataset in `dir`: the geometry resolved, the gamma applied or read
    /// from the frames, the frames held in memory within the budget (else read from disk
    /// band by band), and the result scored against the dataset's truth if it has one.
    pub fn run(&self, dir: &Path, on: &(dyn Fn(JobEvent) + Sync)) -> Result<Finished> {
        self.validate()?;
        let mut on_disk = DatasetOnDisk::open(dir)?;
        on_disk.manifest.entrance_pupil_mm = self.entrance_pupil_mm;
        let nominal = on_disk.manifest.geometry();
        let (geometry, source) = self.geometry.resolve(dir, &nominal)?;
        let reason = self.gamma_reason(&mut on_disk)?;
        let mut steps = Steps::default();
        let gamma_scan = match reason {
            Some(reason) => Some(steps.time("gamma scan", true, || {
                self.scan_gamma(&mut on_disk, &geometry, reason, on)
            })?),
            None => None,
        };
        let system = on_disk.manifest.system();
        let bytes = on_disk.in_focus_bytes();
        // Loaded once, whether the run is done at one height or two.
        let loaded = if bytes as f64 <= self.frame_memory_gb * 1e9 {
            let mut ds = steps.time("frames loaded", false, || Ok(Dataset::load(dir)?))?;
            ds.manifest.entrance_pupil_mm = self.entrance_pupil_mm;
            ds.manifest.camera = on_disk.manifest.camera;
            Some(ds)
        } else {
            on(JobEvent::FromDisk { bytes });
            None
        };
        let progress = |done, total| on(JobEvent::Updates { done, total });
        let reconstruct_at = |geometry: &LedGeometry, source: &GeometrySource| match &loaded {
            Some(ds) => self.reconstruct_loaded(ds, &system, (geometry, source), &progress),
            None => {
                let refocus = self.refocus_of(|| defocus_on_disk(&on_disk, &system, geometry))?;
                let request = self.request(geometry, source, refocus.refocus_um);
                let mut r = reconstruct_on_disk(&on_disk, &request, &progress)?;
                r.report.refocus = refocus;
                Ok(r)
            }
        };
        let r = steps.reconstruction(|| reconstruct_at(&geometry, &source))?;
        let mut r = steps.weighing(|| {
            self.with_edge_height_weighed(r, (&geometry, &source), |at_edge, source| {
                on(JobEvent::WeighingEdgeHeight {
                    stated_mm: geometry.height_mm,
                    edge_mm: at_edge.height_mm,
                });
                reconstruct_at(at_edge, source)
            })
        })?;
        drop(loaded); // the frames are not needed to score the result
        steps.time("scored against the truth", false, || {
            score(&on_disk, &mut r);
            Ok(())
        })?;
        r.report.steps_ms = steps.done;
        r.report.camera_gamma_scan = gamma_scan.clone();
        r.report.camera_gamma_scan_reason = reason;
        Ok(Finished {
            reconstruction: r,
            gamma_scan,
            system,
            nominal,
        })
    }

    /// Why the frames' gamma is to be read from them, if it is: asked for, or by
    /// default for frames whose dataset states none (8-bit ones always, deeper ones
    /// screened first). A gamma given is applied to `on_disk` here.
    fn gamma_reason(&self, on_disk: &mut DatasetOnDisk) -> Result<Option<GammaScanReason>> {
        Ok(match self.camera_gamma {
            Some(CameraGamma::Exponent(gamma)) => {
                // γ = 1 is linear: nothing to decode, so no full scale needed.
                decode_with(on_disk, Some(gamma).filter(|&g| g != 1.0))?;
                None
            }
            Some(CameraGamma::Auto) => Some(GammaScanReason::Asked),
            None if on_disk.manifest.camera.gamma.is_none()
                && on_disk
                    .manifest
                    .camera
                    .bit_depth
                    .unwrap_or(on_disk.sample_bits())
                    <= 8 =>
            {
                Some(GammaScanReason::EightBitUnstated)
            }
            None if on_disk.manifest.camera.gamma.is_none() && on_disk.sample_bits() <= 16 => {
                Some(GammaScanReason::Unstated)
            }
            None => None,
        })
    }

    /// `r`, the run with `geometry`, or the run at the bright/dark-field edge's height
    /// (made by `reconstruct_at`) if the frames fit that clearly better, the weighing
    /// in the report ([`height`]). Weighed only for the dataset's own nominal geometry
    /// (a calibration, recorded or given, a file or a height given is the user's word),
    /// and where the two heights are [`height::WEIGH_SIGMA`] apart.
    fn with_edge_height_weighed(
        &self,
        r: Reconstruction,
        (geometry, source): (&LedGeometry, &GeometrySource),
        reconstruct_at: impl FnOnce(&LedGeometry, &GeometrySource) -> Result<Reconstruction>,
    ) -> Result<Reconstruction> {
        let edge = (*source == GeometrySource::Dataset)
            .then_some(r.report.height_from_boundary)
            .flatten()
            .filter(height::worth_weighing);
        let Some(edge) = edge else {
            return Ok(r);
        };
        let at_edge = height::at_edge(geometry, &edge);
        let alternative = reconstruct_at(&at_edge, &GeometrySource::EdgeHeight(at_edge.height_mm))?;
        let choice = height::HeightChoice::weigh(&r.report, &alternative.report, &edge);
        tracing::info!(
            stated_mm = choice.stated_mm,
            edge_mm = choice.edge_mm,
            stated_error = choice.stated_error,
            edge_error = choice.edge_error,
            taken = choice.edge_taken,
            "the LED height from the bright/dark-field edge weighed on the frames"
        );
        let mut kept = if choice.edge_taken { alternative } else { r };
        kept.report.height_choice = Some(choice);
        Ok(kept)
    }

    /// Reconstruct a dataset already in memory (Python's `Dataset`), through `system`
    /// (the dataset's own, or one with an entrance pupil it cannot state); scored
    /// against its truth if it has one.
    pub fn run_in_memory(
        &self,
        ds: &Dataset,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<Reconstruction> {
        self.validate()?;
        if self.camera_gamma.is_some() {
            bail!("camera_gamma: a dataset in memory states its gamma itself (Dataset.from_arrays(gamma=...))");
        }
        let system = System {
            entrance_pupil_mm: self.entrance_pupil_mm,
            ..ds.manifest.system()
        };
        let (geometry, source) = self.geometry.resolve(&ds.dir, &ds.manifest.geometry())?;
        let mut steps = Steps::default();
        let r = steps.reconstruction(|| {
            self.reconstruct_loaded(ds, &system, (&geometry, &source), progress)
        })?;
        let mut r = steps.weighing(|| {
            self.with_edge_height_weighed(r, (&geometry, &source), |at_edge, source| {
                self.reconstruct_loaded(ds, &system, (at_edge, source), progress)
            })
        })?;
        steps.time("scored against the truth", false, || {
            score(ds, &mut r);
            Ok(())
        })?;
        r.report.steps_ms = steps.done;
        Ok(r)
    }

    /// Reconstruct a dataset in memory through `system` with `geometry` (and its
    /// source), refocused as [`Self::refocus`] says.
    fn reconstruct_loaded(
        &self,
        ds: &Dataset,
        system: &System,
        (geometry, source): (&LedGeometry, &GeometrySource),
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<Reconstruction> {
        let refocus = self.refocus_of(|| {
            Ok(fpm_physics::reconstruct::refocus::estimate(
                system,
                geometry,
                &ds.in_focus(),
            ))
        })?;
        let request = self.request(geometry, source, refocus.refocus_um);
        let mut r = reconstruct_with_system(ds, system, &request, progress)?;
        r.report.refocus = refocus;
        Ok(r)
    }

    /// The request this job makes of one reconstruction with `geometry`, refocused by
    /// `refocus_um`.
    fn request<'a>(
        &self,
        geometry: &'a LedGeometry,
        source: &'a GeometrySource,
        refocus_um: f64,
    ) -> Request<'a> {
        Request {
            geometry,
            source,
            settings: Settings {
                defocus_um: refocus_um,
                ..self.settings
            },
            passes: self.passes,
            tile: self.tile,
        }
    }

    /// How far to refocus, as [`Self::refocus`] says: a distance given, or the one the
    /// frames' shifts show (`estimate` measures them; not called for a distance).
    fn refocus_of(
        &self,
        estimate: impl FnOnce() -> Result<Option<DefocusEstimate>>,
    ) -> Result<RefocusReport> {
        let chosen = match self.refocus {
            Refocus::Distance(um) => return Ok(RefocusReport::given(um)),
            Refocus::Auto => RefocusChoice::Auto,
            Refocus::WhereClear => RefocusChoice::WhereClear,
        };
        let estimate = estimate()?;
        let report = RefocusReport::found(chosen, estimate);
        if let Some(e) = &report.estimate {
            tracing::info!(
                z_um = e.z_um,
                sigma_um = e.sigma_um,
                frames = e.kept(),
                refocus_um = report.refocus_um,
                "defocus read from the bright-field frames' shifts"
            );
        }
        Ok(report)
    }

    /// Scan the frames' gamma and decode them with what was found (asked: as the scan
    /// says; by default: only a clear gamma, else as linear). Without a stated bit
    /// depth, the frames' sample type gives the full scale.
    fn scan_gamma(
        &self,
        ds: &mut DatasetOnDisk,
        geometry: &LedGeometry,
        reason: GammaScanReason,
        on: &(dyn Fn(JobEvent) + Sync),
    ) -> Result<GammaScan> {
        let system = ds.manifest.system();
        let progress = |done, total| on(JobEvent::GammaCandidates { done, total });
        let scan = crate::camera_gamma::scan(
            ds,
            &system,
            geometry,
            self.settings,
            self.passes,
            reason == GammaScanReason::Unstated,
            &progress,
        )?;
        decode_with(
            ds,
            match reason {
                GammaScanReason::Asked => scan.gamma(),
                GammaScanReason::EightBitUnstated | GammaScanReason::Unstated => {
                    scan.gamma().filter(|_| scan.is_clear())
                }
            },
        )?;
        Ok(scan)
    }
}

/// The steps a job has timed so far ([`super::Report::steps_ms`]).
#[derive(Default)]
struct Steps {
    done: Vec<StepTime>,
}

impl Steps {
    /// The step `name`, begun at `start`, ended now.
    fn push(&mut self, name: &'static str, automatic: bool, start: std::time::Instant) {
        self.done.push(StepTime {
            step: name,
            ms: start.elapsed().as_secs_f64() * 1e3,
            automatic,
        });
    }

    /// Run `step`, timing it as `name`.
    fn time<T>(
        &mut self,
        name: &'static str,
        automatic: bool,
        step: impl FnOnce() -> Result<T>,
    ) -> Result<T> {
        let start = std::time::Instant::now();
        let out = step()?;
        self.push(name, automatic, start);
        Ok(out)
    }

    /// Run `weigh` (the edge's height weighed on the frames), a step only where it
    /// weighed: most runs decide in microseconds that there is nothing to weigh.
    fn weighing(
        &mut self,
        weigh: impl FnOnce() -> Result<Reconstruction>,
    ) -> Result<Reconstruction> {
        let start = std::time::Instant::now();
        let r = weigh()?;
        if r.report.height_choice.is_some() {
            self.push("edge height weighed", true, start);
        }
        Ok(r)
    }

    /// Run the reconstruction, timed as two steps: EPRY itself (the report's
    /// `total_ms`) and the refocus estimate and edge checks around it (the rest).
    fn reconstruction(
        &mut self,
        run: impl FnOnce() -> Result<Reconstruction>,
    ) -> Result<Reconstruction> {
        let start = std::time::Instant::now();
        let r = run()?;
        let wall_ms = start.elapsed().as_secs_f64() * 1e3;
        let epry_ms = r.report.total_ms.min(wall_ms);
        self.done.push(StepTime {
            step: "refocus estimate and edge checks",
            ms: wall_ms - epry_ms,
            automatic: true,
        });
        self.done.push(StepTime {
            step: "EPRY",
            ms: epry_ms,
            automatic: false,
        });
        Ok(r)
    }
}

/// Decode `ds`'s frames with `gamma` (None: as linear). Without a stated bit depth,
/// integer frames' sample type gives the full scale (so advice to give a gamma holds
/// for frames whose dataset does not say); float frames carry no display encoding.
fn decode_with(ds: &mut DatasetOnDisk, gamma: Option<f64>) -> Result<()> {
    let Some(gamma) = gamma else {
        ds.manifest.camera.gamma = None;
        return Ok(());
    };
    let bits = ds.sample_bits();
    if bits > 16 {
        bail!(
            "camera_gamma {gamma}: the frames of {} are floats, which no display encoding stores (give no gamma, or 1)",
            ds.dir.display()
        );
    }
    let camera = &mut ds.manifest.camera;
    if camera.bit_depth.is_none() {
        camera.bit_depth = Some(bits);
    }
    camera.set_gamma(gamma, &ds.dir.join("dataset.toml"))?;
    Ok(())
}

/// Scores against a simulation's truth, when the dataset has one.
fn score(ds: &(impl DatasetInfo + ?Sized), r: &mut Reconstruction) {
    r.report.versus_truth = crate::truth::score_reconstruction(ds, &r.object, r.report.upsample);
    if let Some(refined) = r.report.refined_leds.as_mut() {
        refined.versus_truth = crate::truth::score_led_positions(ds, refined);
    }
}
