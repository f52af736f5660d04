//! Colour datasets (docs/dataset.md §5.9): one single-wavelength dataset per colour
//! channel, each in its own directory and each a dataset any reader of the format
//! loads, joined by a `dataset.toml` that holds only `[color]` and `[[channel]]`.
//! Each channel keeps its own wavelength, LED positions (the dies of an RGB LED sit
//! apart), calibration and pupil; what joins them is the same sample, camera and
//! objective.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use ndarray::Array2;
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};

use crate::dataset::{read_manifest, DatasetError, Manifest};

/// The colour dataset's `dataset.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorManifest {
    /// `[color]`.
    pub color: ColorSection,
    /// `[[channel]]`, in the order given.
    #[serde(rename = "channel")]
    pub channels: Vec<ChannelEntry>,
}

impl ColorManifest {
    /// Channels called `names`, each in the directory of its name, registered to
    /// `reference` (None: the middle wavelength).
    pub fn of_names(names: impl IntoIterator<Item = String>, reference: Option<String>) -> Self {
        Self {
            color: ColorSection { reference },
            channels: names
                .into_iter()
                .map(|name| ChannelEntry {
                    dataset: name.clone(),
                    name,
                })
                .collect(),
        }
    }
}

/// `[color]`: what the channels share.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorSection {
    /// The channel the others are registered to (default: the one whose wavelength
    /// is the middle one, where an achromat is best corrected).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<String>,
}

/// One `[[channel]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelEntry {
    /// Its name (`red`, …): a plain word, as it names output directories.
    pub name: String,
    /// Its dataset's directory, relative to the colour dataset's (use `/`).
    pub dataset: String,
}

/// A colour dataset opened: its channels' datasets read and checked against each other.
#[derive(Debug, Clone)]
pub struct ColorDataset {
    /// Its directory.
    pub dir: PathBuf,
    /// Its `dataset.toml`.
    pub manifest: ColorManifest,
    /// Each channel's dataset directory and manifest, in the manifest's order.
    pub channels: Vec<ColorChannel>,
    /// Index into `channels` of the reference.
    pub reference: usize,
}

/// One channel of an opened colour dataset.
#[derive(Debug, Clone)]
pub struct ColorChannel {
    /// Its name.
    pub name: String,
    /// Its dataset's directory.
    pub dir: PathBuf,
    /// Its dataset's manifest (as stored).
    pub manifest: Manifest,
}

impl ColorChannel {
    /// Its wavelength, µm.
    pub fn wavelength_um(&self) -> f64 {
        self.manifest.system.wavelength_um
    }
}

/// Whether `dir/dataset.toml` is a colour dataset's (has a `[color]` table). False for
/// anything unreadable: the loader then says what is wrong.
pub fn is_color(dir: &Path) -> bool {
    std::fs::read_to_string(dir.join("dataset.toml"))
        .ok()
        .and_then(|t| t.parse::<toml::Table>().ok())
        .is_some_and(|t| t.contains_key("color"))
}

impl ColorDataset {
    /// Read `dir/dataset.toml` and every channel's dataset manifest, and check that they
    /// make one colour dataset: at least one channel, names unique plain words,
    /// datasets inside `dir`, and the channels the same objective and camera (NA,
    /// magnification, pixel) at different wavelengths.
    pub fn open(dir: &Path) -> Result<Self> {
        let path = dir.join("dataset.toml");
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        let manifest: ColorManifest =
            toml::from_str(&text).with_context(|| format!("{}", path.display()))?;
        let at = |why: String| anyhow::anyhow!("{}: {why}", path.display());
        if manifest.channels.is_empty() {
            return Err(at("no [[channel]] entries".into()));
        }
        let mut channels: Vec<ColorChannel> = vec![];
        for (i, entry) in manifest.channels.iter().enumerate() {
            let name = &entry.name;
            let plain = !name.is_empty()
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
            if !plain {
                return Err(at(format!(
                    "channel {i}: name = {name:?}: must be a plain word (letters, digits, - or _), as it names output directories"
                )));
            }
            if channels.iter().any(|c| &c.name == name) {
                return Err(at(format!("channel {i}: name = {name:?} is given twice")));
            }
            let rel = Path::new(&entry.dataset);
            if rel.is_absolute()
                || rel
                    .components()
                    .any(|c| matches!(c, std::path::Component::ParentDir))
            {
                return Err(at(format!(
                    "channel {name}: dataset = {:?}: must be a directory inside the colour dataset's",
                    entry.dataset
                )));
            }
            let sub = dir.join(rel);
            if is_color(&sub) {
                return Err(at(format!(
                    "channel {name}: dataset = {:?} is itself a colour dataset",
                    entry.dataset
                )));
            }
            let (_, m) = read_manifest(&sub)
                .map_err(|e: DatasetError| at(format!("channel {name}: {e}")))?;
            channels.push(ColorChannel {
                name: name.clone(),
                dir: sub,
                manifest: m,
            });
        }
        let first = &channels[0].manifest.system;
        for c in &channels[1..] {
            let s = &c.manifest.system;
            let same = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs());
            for (key, a, b) in [
                ("na", first.na, s.na),
                ("magnification", first.magnification, s.magnification),
                ("pixel_size_um", first.pixel_size_um, s.pixel_size_um),
            ] {
                if !same(a, b) {
                    return Err(at(format!(
                        "channel {}: system.{key} = {b} differs from channel {}'s {a}: the channels must share the objective and camera",
                        c.name, channels[0].name
                    )));
                }
            }
            if channels
                .iter()
                .take_while(|o| o.name != c.name)
                .any(|o| same(o.manifest.system.wavelength_um, s.wavelength_um))
            {
                return Err(at(format!(
                    "channel {}: system.wavelength_um = {} is another channel's: a colour dataset's channels differ in wavelength",
                    c.name, s.wavelength_um
                )));
            }
        }
        let reference = match &manifest.color.reference {
            Some(name) => channels
                .iter()
                .position(|c| &c.name == name)
                .ok_or_else(|| {
                    at(format!(
                        "color.reference = {name:?} is not one of the channels ({})",
                        names(&channels)
                    ))
                })?,
            None => middle_wavelength(&channels),
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
            channels,
            reference,
        })
    }

    /// Write `manifest` as `dir/dataset.toml` (the channels' datasets are the caller's).
    pub fn write_manifest(dir: &Path, manifest: &ColorManifest) -> Result<()> {
        let path = dir.join("dataset.toml");
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        std::fs::write(&path, toml::to_string(manifest)?)
            .with_context(|| format!("writing {}", path.display()))
    }

    /// The channels' names, comma-separated.
    pub fn names(&self) -> String {
        names(&self.channels)
    }

    /// The channel called `name`.
    pub fn channel(&self, name: &str) -> Result<&ColorChannel> {
        match self.channels.iter().find(|c| c.name == name) {
            Some(c) => Ok(c),
            None => bail!(
                "{}: no channel {name:?} (its channels: {})",
                self.dir.display(),
                self.names()
            ),
        }
    }
}

fn names(channels: &[ColorChannel]) -> String {
    channels
        .iter()
        .map(|c| c.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The channel whose wavelength is the middle one (of two, the shorter).
fn middle_wavelength(channels: &[ColorChannel]) -> usize {
    let mut order: Vec<usize> = (0..channels.len()).collect();
    order.sort_by(|&a, &b| {
        channels[a]
            .wavelength_um()
            .total_cmp(&channels[b].wavelength_um())
    });
    order[(order.len() - 1) / 2]
}

/// A colour calibration: one pdcFPM calibration per channel (`fpm calibrate` on a
/// colour calibration set), written as one `calibration.json` whose `channels` holds
/// each channel's calibration file, and the dies' offsets they imply.
#[derive(Debug, Clone, Serialize)]
pub struct ColorCalibration {
    /// The reference channel (die offsets are relative to its die).
    pub reference: String,
    /// Each channel's calibration, by name, in the dataset's order.
    pub channels: Vec<(String, crate::calibration::CalibrationFile)>,
    /// Each die's place relative to the reference's, in the board's axes, with 1σ.
    pub die_offsets: Vec<DieOffset>,
    /// Each colour's focus relative to the reference's, read from its fitted LED
    /// height (below), with 1σ.
    pub focal_shifts: Vec<FocalShift>,
}

/// A colour's focus against the reference colour's (the objective's chromatic focal
/// shift). The stage's defocus is set from the focus in one light; a colour focusing
/// δ farther away sees the feature defocused by z + δ, and its pdcFPM fit, which takes
/// z, puts the LEDs at h·z/(z + δ) instead of h. The board is one plane, so every
/// colour keeps the reference's h and the ratio gives δ = z·(h_ref/h_c − 1).
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct FocalShift {
    /// δ, µm (toward the LEDs positive, as a dataset's `defocus_um`).
    pub shift_um: f64,
    /// Its 1σ, µm (the two heights' fit errors; the stage's own defocus error is
    /// common to both and cancels).
    pub sigma_um: f64,
    /// The LED height this colour's own fit gave, mm (replaced by the reference's).
    pub height_fitted_mm: f64,
}

/// One colour's die relative to the reference colour's.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct DieOffset {
    /// Board x, y, mm.
    pub offset_mm: [f64; 2],
    /// 1σ of each, mm.
    pub sigma_mm: [f64; 2],
}

impl ColorCalibration {
    /// Calibrate every channel of `ds` (each a pdcFPM calibration set) with `options`.
    pub fn calibrate(ds: &ColorDataset, options: &fpm_physics::calibrate::Options) -> Result<Self> {
        let mut channels = vec![];
        for c in &ds.channels {
            let data = crate::dataset::Dataset::load(&c.dir)?;
            let file = crate::calibration::calibrate_dataset(&data, options)
                .with_context(|| format!("calibrating channel {}", c.name))?;
            channels.push((c.name.clone(), file));
        }
        Ok(Self::from_files(channels, ds.reference))
    }

    /// The colour calibration of each channel's own calibration (by name, in the
    /// dataset's order; `reference` indexes the reference channel).
    pub fn from_files(
        mut channels: Vec<(String, crate::calibration::CalibrationFile)>,
        reference: usize,
    ) -> Self {
        let reference_index = reference;
        let reference_name = channels[reference].0.clone();
        let reference_file = channels[reference].1.clone();
        let reference = &reference_file.calibration;
        let h = reference.placement.height_mm;
        let focal_shifts: Vec<FocalShift> = channels
            .iter()
            .map(|(_, f)| {
                let c = &f.calibration;
                let hc = c.placement.height_mm;
                let z = c.defocus_um;
                // The height's fit error alone: its σ less the defocus's share.
                let fit_sigma = |cal: &fpm_physics::calibrate::Calibration| {
                    let total = cal.uncertainty.height_mm;
                    let from_defocus = cal.placement.height_mm / cal.defocus_um.abs().max(1e-9)
                        * cal.defocus_sigma_um;
                    (total * total - from_defocus * from_defocus)
                        .max(0.0)
                        .sqrt()
                };
                let rel = ((fit_sigma(c) / hc).powi(2) + (fit_sigma(reference) / h).powi(2)).sqrt();
                FocalShift {
                    shift_um: z * (h / hc - 1.0),
                    sigma_um: (z * h / hc * rel).abs(),
                    height_fitted_mm: hc,
                }
            })
            .collect();
        // Each colour's in-focus reference frame was δ from its focus too, so its
        // feature sat δ·p₀/h off (p₀: the centre LED's place), which the fit took as
        // the board's offset: Δ_fit = Δ − δ/(z + δ)·p₀. Put it back, then keep the
        // board's one h.
        for ((_, f), shift) in channels.iter_mut().zip(&focal_shifts) {
            let z = f.calibration.defocus_um;
            let (x0, y0, _) = f.geometry().led_position_3d_mm(f.nominal.center);
            let k = shift.shift_um / (z + shift.shift_um);
            f.calibration.placement.dx_mm += k * x0;
            f.calibration.placement.dy_mm += k * y0;
            f.calibration.placement.height_mm = h;
            f.calibration.uncertainty.height_mm = reference.uncertainty.height_mm;
        }
        let reference = &channels[reference_index].1.calibration;
        let (s, co) = reference.placement.theta_deg.to_radians().sin_cos();
        let die_offsets = channels
            .iter()
            .map(|(_, f)| {
                let c = &f.calibration;
                let (dx, dy) = (
                    c.placement.dx_mm - reference.placement.dx_mm,
                    c.placement.dy_mm - reference.placement.dy_mm,
                );
                let sx = (c.uncertainty.dx_mm.powi(2) + reference.uncertainty.dx_mm.powi(2)).sqrt();
                let sy = (c.uncertainty.dy_mm.powi(2) + reference.uncertainty.dy_mm.powi(2)).sqrt();
                DieOffset {
                    // into the board's axes: turned back by θ
                    offset_mm: [co * dx + s * dy, -s * dx + co * dy],
                    sigma_mm: [sx.max(sy), sx.max(sy)],
                }
            })
            .collect();
        Self {
            reference: reference_name,
            channels,
            die_offsets,
            focal_shifts,
        }
    }

    /// The JSON of `calibration.json`: `{"color": {"reference"}, "channels": {name:
    /// calibration file}, "die_offsets": {name: {offset_mm, sigma_mm}}}`.
    pub fn to_json(&self) -> Result<serde_json::Value> {
        let mut channels = serde_json::Map::new();
        let mut dies = serde_json::Map::new();
        let mut focus = serde_json::Map::new();
        for (((name, file), die), shift) in self
            .channels
            .iter()
            .zip(&self.die_offsets)
            .zip(&self.focal_shifts)
        {
            channels.insert(name.clone(), serde_json::to_value(file)?);
            dies.insert(name.clone(), serde_json::to_value(die)?);
            focus.insert(name.clone(), serde_json::to_value(shift)?);
        }
        Ok(serde_json::json!({
            "color": {"reference": self.reference},
            "channels": channels,
            "die_offsets": dies,
            "focal_shifts": focus,
        }))
    }
}

/// Each channel's placement from a colour `calibration.json` ([`ColorCalibration`]),
/// by channel name; None when the file is a single calibration.
pub fn read_color_placements(
    path: &Path,
) -> Result<Option<Vec<(String, crate::calibration::PlacementFile)>>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let Some(channels) = value.get("channels").and_then(|c| c.as_object()) else {
        return Ok(None);
    };
    channels
        .iter()
        .map(|(name, v)| {
            crate::calibration::PlacementFile::parse(&v.to_string())
                .with_context(|| format!("{}: channel {name}", path.display()))
                .map(|p| (name.clone(), p))
        })
        .collect::<Result<Vec<_>>>()
        .map(Some)
}

/// How a colour reconstruction places each channel's LEDs.
#[derive(Debug, Clone, PartialEq)]
pub enum ColorGeometry {
    /// Each channel's dataset's own nominal placement (the dies' offsets as its `[led]`
    /// states them).
    Nominal,
    /// A calibration file: a colour one ([`ColorCalibration`]) gives each channel its
    /// own; a single one is used for every channel (the dies' offsets then go
    /// uncorrected, which the report warns of).
    File(PathBuf),
    /// One placement for every channel (the board's stored calibration, named here):
    /// the dies' offsets go uncorrected, which the report warns of.
    Given(fpm_physics::LedGeometry, String),
}

/// One channel reconstructed, and where it lies against the reference.
pub struct ChannelRun {
    /// The channel's name.
    pub name: String,
    /// Its dataset's directory.
    pub dir: PathBuf,
    /// The reconstruction, as `fpm reconstruct` of its dataset alone gives it.
    pub finished: crate::reconstruction::Finished,
    /// Its object moved onto the reference's ([`ColorReport`]'s shift taken off).
    pub registered: Array2<Complex32>,
}

/// A colour reconstruction: every channel, registered to the reference.
pub struct ColorRun {
    /// The channels, in the dataset's order.
    pub channels: Vec<ChannelRun>,
    /// `report.json` of the colour result.
    pub report: ColorReport,
}

impl ColorRun {
    /// The registered channels' amplitudes, in order.
    pub fn amplitudes(&self) -> Vec<Array2<f32>> {
        self.channels
            .iter()
            .map(|c| c.registered.mapv(|z| z.norm()))
            .collect()
    }

    /// The sRGB preview ([`fpm_physics::color::srgb_preview`], each channel
    /// white-balanced on its clear level): its (rows, cols) and RGB bytes.
    pub fn preview(&self) -> ((usize, usize), Vec<u8>) {
        self.preview_from(&self.amplitudes())
    }

    /// [`Self::preview`] of `amplitudes` ([`Self::amplitudes`], already made).
    fn preview_from(&self, amplitudes: &[Array2<f32>]) -> ((usize, usize), Vec<u8>) {
        let views: Vec<(f64, ndarray::ArrayView2<'_, f32>)> = self
            .report
            .channels
            .iter()
            .zip(amplitudes)
            .map(|(c, a)| (c.wavelength_um, a.view()))
            .collect();
        let white: Vec<f64> = self.report.channels.iter().map(|c| c.clear_level).collect();
        let dim = amplitudes.first().map_or((0, 0), |a| a.dim());
        (dim, fpm_physics::color::srgb_preview(&views, &white))
    }
}

/// The colour result's `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct ColorReport {
    /// The colour dataset.
    pub dataset: String,
    /// The channel the others are registered to.
    pub reference: String,
    /// Where the LED placements came from: `nominal`, `per-channel calibration`, or
    /// `one calibration for every channel`.
    pub geometry: String,
    /// HR pixel, µm (every channel's: one upsampling).
    pub pixel_um: f64,
    /// Per channel.
    pub channels: Vec<ChannelReport>,
    /// What the user should know, each with what to do.
    pub warnings: Vec<crate::reconstruction::Warning>,
}

impl ColorReport {
    /// The run's warnings, then each channel's, named by it: what a page, a client or
    /// a script shows of them.
    pub fn all_warnings(&self) -> Vec<String> {
        self.warnings
            .iter()
            .map(|w| w.message.clone())
            .chain(self.channels.iter().flat_map(|c| {
                c.warnings
                    .iter()
                    .map(move |w| format!("{}: {}", c.name, w.message))
            }))
            .collect()
    }
}

/// One channel in [`ColorReport`].
#[derive(Debug, Clone, Serialize)]
pub struct ChannelReport {
    /// Its name.
    pub name: String,
    /// Its wavelength, µm.
    pub wavelength_um: f64,
    /// Its own output directory (relative to the colour output).
    pub output: String,
    /// The LED geometry it was reconstructed with.
    pub geometry: fpm_physics::LedGeometry,
    /// Its shift against the reference (x, y), HR pixels, taken off in the colour
    /// images (None: the registration found no texture; left unshifted).
    pub shift_px: Option<[f64; 2]>,
    /// The same in µm.
    pub shift_um: Option<[f64; 2]>,
    /// Its clear background's intensity transmission (the preview's white point).
    pub clear_level: f64,
    /// The frames' amplitude error after the last pass.
    pub final_error: Option<f64>,
    /// Against the simulation's truth of this wavelength, when there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub versus_truth: Option<fpm_physics::metrics::Scores>,
    /// Its own report's warnings (its report.json has them in full).
    pub warnings: Vec<crate::reconstruction::Warning>,
}

/// How far apart two channels may lie before the report warns, µm: a few HR pixels
/// is what chromatic aberration of a corrected objective gives; more says the
/// channels' geometries disagree (a die offset left out).
pub const SHIFT_WARN_UM: f64 = 2.0;

/// Reconstruct every channel of `ds` with `job` (its geometry replaced per channel as
/// `geometry` says), register each to the reference by phase correlation of the
/// amplitudes, and report. `on(channel, event)` reports progress.
pub fn reconstruct(
    ds: &ColorDataset,
    job: &crate::reconstruction::Job,
    geometry: &ColorGeometry,
    on: &(dyn Fn(&str, crate::reconstruction::JobEvent) + Sync),
) -> Result<ColorRun> {
    use crate::reconstruction::{Check, GeometryChoice, Warning};
    let per_channel = match geometry {
        ColorGeometry::File(path) => read_color_placements(path)?,
        _ => None,
    };
    let mut warnings = vec![];
    let one_for_all = |what: String| {
        Warning {
        check: Check::ColorOneCalibration,
        message: format!(
            "one calibration ({what}) placed every colour's LEDs: an RGB LED's dies sit ~0.5-1 mm apart, so the other colours' LEDs are off by that much; calibrate each colour (`fpm calibrate` on a colour calibration set, or `fpm acquire --colors ... --calibrate`) and give that calibration.json"
        ),
    }
    };
    let geometry_name = match (geometry, &per_channel) {
        (ColorGeometry::Nominal, _) => "nominal",
        (ColorGeometry::File(_), Some(_)) => "per-channel calibration",
        (ColorGeometry::File(path), None) => {
            warnings.push(one_for_all(path.display().to_string()));
            "one calibration for every channel"
        }
        (ColorGeometry::Given(_, name), _) => {
            warnings.push(one_for_all(name.clone()));
            "one calibration for every channel"
        }
    };
    let mut channels = vec![];
    for c in &ds.channels {
        let choice = match (&per_channel, geometry) {
            (Some(all), _) => {
                let (_, placement) = all.iter().find(|(n, _)| n == &c.name).ok_or_else(|| {
                    anyhow::anyhow!(
                        "the colour calibration has no channel {:?} (it has {})",
                        c.name,
                        all.iter()
                            .map(|(n, _)| n.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    )
                })?;
                GeometryChoice::Given(
                    placement.geometry(&c.manifest.geometry()),
                    format!("colour calibration, channel {}", c.name),
                )
            }
            (None, ColorGeometry::File(path)) => GeometryChoice::File(path.clone()),
            (None, ColorGeometry::Given(g, name)) => GeometryChoice::Given(*g, name.clone()),
            (None, ColorGeometry::Nominal) => job.geometry.clone(),
        };
        let channel_job = crate::reconstruction::Job {
            geometry: choice,
            ..job.clone()
        };
        let finished = channel_job
            .run(&c.dir, &|e| on(&c.name, e))
            .with_context(|| format!("channel {}", c.name))?;
        channels.push((c, finished));
    }
    let reference = &channels[ds.reference].1.reconstruction;
    let pixel_um = reference.report.pixel_um;
    let reference_amplitude = reference.object.mapv(|z| z.norm());
    let mut runs = vec![];
    let mut reports = vec![];
    for (k, (c, finished)) in channels.into_iter().enumerate() {
        let object = &finished.reconstruction.object;
        let shift = if k == ds.reference {
            Some((0.0, 0.0))
        } else if object.dim() != reference_amplitude.dim() {
            bail!(
                "channel {}: its image is {:?} pixels, the reference's {:?}: give the channels frames of one size",
                c.name,
                object.dim(),
                reference_amplitude.dim()
            );
        } else {
            fpm_physics::color::register(
                reference_amplitude.view(),
                object.mapv(|z| z.norm()).view(),
            )
        };
        let registered = match shift {
            Some((dx, dy)) if (dx, dy) != (0.0, 0.0) => {
                fpm_physics::color::shifted_back(object, dx, dy)
            }
            _ => object.clone(),
        };
        if let Some((dx, dy)) = shift {
            let um = dx.hypot(dy) * pixel_um;
            if um > SHIFT_WARN_UM {
                warnings.push(Warning {
                    check: Check::ColorShift,
                    message: format!(
                        "channel {} lies {um:.1} µm from {} (taken off in the colour image): more than chromatic aberration gives; its LEDs are likely placed wrong (a die offset): calibrate each colour and give that calibration.json",
                        c.name, ds.channels[ds.reference].name
                    ),
                });
            }
        }
        let report = &finished.reconstruction.report;
        reports.push(ChannelReport {
            name: c.name.clone(),
            wavelength_um: c.wavelength_um(),
            output: c.name.clone(),
            geometry: report.geometry,
            shift_px: shift.map(|(x, y)| [x, y]),
            shift_um: shift.map(|(x, y)| [x * pixel_um, y * pixel_um]),
            clear_level: fpm_physics::color::clear_level(registered.mapv(|z| z.norm()).view()),
            final_error: report.error_per_pass.last().copied(),
            versus_truth: report.versus_truth,
            warnings: channel_warnings(report),
        });
        runs.push(ChannelRun {
            name: c.name.clone(),
            dir: c.dir.clone(),
            finished,
            registered,
        });
    }
    Ok(ColorRun {
        channels: runs,
        report: ColorReport {
            dataset: ds.dir.display().to_string(),
            reference: ds.channels[ds.reference].name.clone(),
            geometry: geometry_name.into(),
            pixel_um,
            channels: reports,
            warnings,
        },
    })
}

/// Where a colour result's files go, beside each channel's own directory.
pub const PREVIEW_NAME: &str = "color.png";

/// Write the colour result into `out`: `amplitude.tif` and `phase.tif` as OME-TIFFs
/// with one channel per wavelength (or `image.ome.zarr`: the amplitudes, then the
/// phases), registered to the reference; `color.png`, the sRGB preview white-balanced
/// on the clear background; and `report.json`. Each channel's own outputs are the
/// caller's (`out/<name>/`).
pub fn write_outputs(
    run: &ColorRun,
    out: &Path,
    options: crate::reconstruction::OutputOptions,
) -> Result<()> {
    use crate::reconstruction::ImageFormat;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let report = &run.report;
    let first = &run.channels[0].finished;
    let system = first.reconstruction.report.system;
    let names: Vec<(&str, f64)> = report
        .channels
        .iter()
        .map(|c| (c.name.as_str(), c.wavelength_um))
        .collect();
    let amplitudes = run.amplitudes();
    match options.format {
        ImageFormat::Tiff => {
            let phases: Vec<Array2<f32>> = run
                .channels
                .iter()
                .map(|c| c.registered.mapv(|z| z.arg()))
                .collect();
            for (what, planes, description) in [
                ("amplitude", &amplitudes, "FPM colour reconstruction (EPRY per channel, registered): amplitude of the sample's complex transmission at each wavelength, relative to clear glass"),
                ("phase", &phases, "FPM colour reconstruction (EPRY per channel, registered): phase of the sample's complex transmission at each wavelength, radians in [-pi, pi]"),
            ] {
                let (h, w) = planes[0].dim();
                let xml = crate::ome::ome_xml_channels(
                    &crate::ome::OmeImage {
                        name: what,
                        description,
                        size: (w, h),
                        pixel_um: report.pixel_um,
                        wavelength_um: system.wavelength_um,
                        na: system.na,
                        magnification: system.magnification,
                    },
                    &names,
                );
                let refs: Vec<&Array2<f32>> = planes.iter().collect();
                crate::dataset::image_io::write_tiff_f32_planes_described(
                    &out.join(format!("{what}.tif")),
                    &refs,
                    &xml,
                    report.pixel_um,
                    options.tiff,
                )?;
            }
        }
        ImageFormat::OmeZarr => {
            let objects: Vec<(&str, &Array2<Complex32>)> = run
                .channels
                .iter()
                .map(|c| (c.name.as_str(), &c.registered))
                .collect();
            crate::ome_zarr::write_objects(
                &out.join(crate::reconstruction::ZARR_NAME),
                &objects,
                report.pixel_um,
            )?;
        }
    }
    let ((h, w), rgb) = run.preview_from(&amplitudes);
    crate::dataset::image_io::write_png_rgb(&out.join(PREVIEW_NAME), w, h, &rgb)?;
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(report)?,
    )
    .with_context(|| format!("writing {}", out.join("report.json").display()))
}

/// A channel's warnings: its run's, with focus advice that fits a colour run (the
/// colours focus apart, so "focus the microscope" for one defocuses the others).
fn channel_warnings(report: &crate::reconstruction::Report) -> Vec<crate::reconstruction::Warning> {
    let mut warnings = crate::reconstruction::checks(report);
    for w in warnings
        .iter_mut()
        .filter(|w| w.check == crate::reconstruction::Check::Refocus)
    {
        if let Some(message) = report.refocus.warning_for_colour() {
            w.message = message;
        }
    }
    warnings
}
