//! The dataset format of docs/dataset.md §5: `dataset.toml` plus one image per frame.
//!
//! Loading is strict: an unknown key, a missing file, a frame whose size differs, an
//! LED outside the array or a non-finite value is an error naming the key or frame.
//! `[camera]` flips and transpose are applied on load, so every frame comes out in the
//! sample-plane orientation of docs/dataset.md §1.

pub mod image_io;
pub mod on_disk;

use std::path::{Path, PathBuf};

use fpm_physics::bayer::{self, BayerChannel, BayerPattern};
use fpm_physics::frame::{LitFrame, Measured, Region, Response};
use fpm_physics::{Image, LedGeometry, LedIndex, LedList, ListedLed, Rings, System};
use serde::{Deserialize, Serialize};

pub use image_io::{ImageError, Pixels};
pub use on_disk::DatasetOnDisk;

/// Where a dataset is and what its manifest says, whether its frames are in memory
/// ([`Dataset`]) or read as needed ([`DatasetOnDisk`]).
pub trait DatasetInfo {
    /// Its directory.
    fn dir(&self) -> &Path;
    /// Its manifest, as the frames are in memory.
    fn manifest(&self) -> &Manifest;
}

impl DatasetInfo for Dataset {
    fn dir(&self) -> &Path {
        &self.dir
    }
    fn manifest(&self) -> &Manifest {
        &self.manifest
    }
}

impl DatasetInfo for DatasetOnDisk {
    fn dir(&self) -> &Path {
        &self.dir
    }
    fn manifest(&self) -> &Manifest {
        &self.manifest
    }
}

/// `[system]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SystemSection {
    /// µm.
    pub wavelength_um: f64,
    /// Objective NA.
    pub na: f64,
    /// Objective magnification.
    pub magnification: f64,
    /// Camera pixel, µm.
    pub pixel_size_um: f64,
}

/// `[led]`: the nominal geometry: a grid (`rows`, `cols`, `pitch_mm`, `center`), rings
/// (and `rings`) or a list of the LEDs' places (`position` or `na`; docs/dataset.md
/// §1.2 and §5.2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedSection {
    /// Rows (a grid's or rings'; a list's ids bound them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<usize>,
    /// Columns.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cols: Option<usize>,
    /// Pitch, mm (a list's: the spacing heuristics use; absent: its typical spacing).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pitch_mm: Option<f64>,
    /// LED plane (a list's origin) to sample, mm.
    pub height_mm: f64,
    /// (row, col) of the nominal centre LED (a list's: absent, the LED nearest its
    /// origin).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<LedIndex>,
    /// Δx, Δy, mm.
    #[serde(default)]
    pub offset_mm: [f64; 2],
    /// θ, degrees.
    #[serde(default)]
    pub rotation_deg: f64,
    /// Board tilt about its x and y axes through the centre LED, degrees (an
    /// extension of the format; written only when not zero).
    #[serde(default, skip_serializing_if = "is_flat")]
    pub tilt_deg: [f64; 2],
    /// LEDs per ring, from the centre LED out, for an array of concentric rings
    /// `pitch_mm` apart in radius (an extension of the format; docs/dataset.md §1.2):
    /// `rows` is then the number of rings, `cols` the largest ring's LEDs and `center`
    /// [0, 0]; frame LEDs are [ring, LED on the ring].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rings: Option<Rings>,
    /// `[[led.position]]`: each LED's id and place in the array's own frame, mm (an
    /// extension of the format for domes and hand-placed LEDs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<LedList>,
    /// `[[led.na]]`: each LED's id and illumination NA at the axis, (sin θx, sin θy),
    /// for sources that give only the angles; placed at `height_mm` on the axis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub na: Option<LedNas>,
}

/// One `[[led.na]]`: an LED's id and its illumination NA at the field's centre.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedNa {
    /// The LED's id, (row, col).
    pub led: LedIndex,
    /// (NAx, NAy) = (x, y)/R: the sines of the LED's angle off the axis, seen from the
    /// field's centre, signed as its position (an LED at +x has NAx > 0 and lights
    /// the sample at f_i = −NAx/λ, §1.3).
    pub na: [f64; 2],
}

/// `[[led.na]]`, checked as read: each id once, each NA finite with NAx² + NAy² < 1.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(transparent)]
pub struct LedNas(Vec<LedNa>);

impl LedNas {
    /// `nas`, or what is wrong with them.
    pub fn new(nas: Vec<LedNa>) -> Result<Self, String> {
        if nas.is_empty() {
            return Err("the list holds no LED".into());
        }
        for (k, n) in nas.iter().enumerate() {
            let s2 = n.na[0] * n.na[0] + n.na[1] * n.na[1];
            if !(n.na.iter().all(|v| v.is_finite()) && s2 < 1.0) {
                return Err(format!(
                    "LED {} (entry {k}): na = {:?} must be finite with NAx² + NAy² < 1",
                    n.led, n.na
                ));
            }
            if nas[..k].iter().any(|m| m.led == n.led) {
                return Err(format!("LED {} is listed twice", n.led));
            }
        }
        Ok(Self(nas))
    }

    /// The LEDs as placed `height_mm` below the sample on the axis: an LED seen from
    /// the field's centre at sines (NAx, NAy) sits at h·(NAx, NAy)/√(1 − NAx² − NAy²).
    pub fn positions(&self, height_mm: f64) -> Vec<ListedLed> {
        self.0
            .iter()
            .map(|n| {
                let cos = (1.0 - n.na[0] * n.na[0] - n.na[1] * n.na[1]).sqrt();
                ListedLed {
                    led: n.led,
                    x_mm: height_mm * n.na[0] / cos,
                    y_mm: height_mm * n.na[1] / cos,
                    z_mm: 0.0,
                }
            })
            .collect()
    }
}

impl<'de> Deserialize<'de> for LedNas {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Self::new(Vec::deserialize(d)?).map_err(serde::de::Error::custom)
    }
}

fn is_flat(tilt: &[f64; 2]) -> bool {
    *tilt == [0.0, 0.0]
}

/// `[camera]` (all optional).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSection {
    /// Counts to subtract.
    #[serde(default)]
    pub dark_level: f64,
    /// Bits per sample used by the sensor (saturation is at 2^bits − 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bit_depth: Option<u32>,
    /// Image columns run against +x.
    #[serde(default)]
    pub flip_x: bool,
    /// Image rows run against +y.
    #[serde(default)]
    pub flip_y: bool,
    /// Swap rows and columns before the flips.
    #[serde(default)]
    pub transpose: bool,
    /// A colour sensor's raw mosaic: the filter of the top-left 2 × 2 cell, as stored.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bayer: Option<BayerPattern>,
    /// With `bayer`: the channel the LEDs' light is measured in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel: Option<BayerChannel>,
    /// With `bayer`: interpolate the channel at every pixel (full size, the sensor's
    /// pitch) instead of taking its own pixels (half size, twice the pitch).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub demosaic: bool,
    /// The frames are encoded for display, not raw: a stored value v stands for the
    /// light full·(v/full)^gamma, full = 2^bit_depth − 1 (an extension of the format,
    /// for data saved as viewable 8-bit images; absent: linear counts).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gamma: Option<f64>,
}

impl CameraSection {
    /// Whether `gamma` is one a dataset can state (`camera.gamma`): above 0, at most 5.
    pub fn is_valid_gamma(gamma: f64) -> bool {
        gamma.is_finite() && gamma > 0.0 && gamma <= 5.0
    }

    /// How the stored values stand for light.
    pub fn response(&self) -> Response {
        match (self.gamma, self.bit_depth) {
            (Some(gamma), Some(bits)) => Response::Gamma {
                gamma: gamma as f32,
                full_scale: full_scale(bits),
            },
            _ => Response::Linear,
        }
    }

    /// The dark level as light (decoded when the frames are display-encoded).
    pub fn dark_light(&self) -> f32 {
        self.response().decode(self.dark_level as f32)
    }

    /// State that the frames of the dataset whose manifest is `path` are
    /// display-encoded with `gamma` (a command-line override of the manifest), checked
    /// as the manifest's own key is.
    pub fn set_gamma(&mut self, gamma: f64, path: &Path) -> Result<(), DatasetError> {
        let before = self.gamma.replace(gamma);
        self.check_gamma(path).inspect_err(|_| self.gamma = before)
    }

    /// `gamma`: above 0, at most 5, and with a bit depth for its full scale.
    fn check_gamma(&self, path: &Path) -> Result<(), DatasetError> {
        let Some(gamma) = self.gamma else {
            return Ok(());
        };
        let why = if !Self::is_valid_gamma(gamma) {
            "must be above 0 and at most 5 (2.2 for sRGB-like 8-bit images)"
        } else if self.bit_depth.is_none() {
            "needs camera.bit_depth: full scale is 2^bit_depth - 1"
        } else {
            return Ok(());
        };
        Err(DatasetError::Value {
            path: path.to_path_buf(),
            key: "camera.gamma".into(),
            value: gamma.to_string(),
            why,
        })
    }
}

/// The largest value a `bits`-bit sample holds.
pub fn full_scale(bits: u32) -> f32 {
    ((1u64 << bits.min(32)) - 1) as f32
}

fn one() -> f64 {
    1.0
}

/// `[source]` (optional; written by `fpm import`): the data's origin, so a dataset
/// converted from another lab's format says what it was and what was assumed in
/// mapping it onto this format's conventions.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceSection {
    /// The source format's name (`fpm import --list`).
    pub format: String,
    /// The file or folder it was read from, as given.
    pub path: String,
    /// What the import assumed where the source does not say, one sentence each.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub assumed: Vec<String>,
}

/// One `[[frame]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "StoredFrame", into = "StoredFrame")]
pub struct FrameEntry {
    /// Image path relative to the dataset directory.
    pub file: String,
    /// (row, col) lit: the first of a multiplexed frame's LEDs (`leds = [...]`).
    pub led: LedIndex,
    /// The other LEDs lit in the same frame (multiplexed illumination, docs/dataset.md
    /// §5.4); empty for a frame lit by one LED.
    pub also: Vec<LedIndex>,
    /// Sample displacement toward the LEDs, µm.
    pub defocus_um: f64,
    /// Exposure, ms; intensities are divided by it.
    pub exposure_ms: f64,
}

impl FrameEntry {
    /// A frame lit by `led` alone, in focus, exposed for 1 ms.
    pub fn single(file: impl Into<String>, led: LedIndex) -> Self {
        Self {
            file: file.into(),
            led,
            also: vec![],
            defocus_um: 0.0,
            exposure_ms: 1.0,
        }
    }

    /// Every LED that lit the frame.
    pub fn leds(&self) -> impl Iterator<Item = LedIndex> + '_ {
        std::iter::once(self.led).chain(self.also.iter().copied())
    }

    /// Whether more than one LED lit it.
    pub fn is_multiplexed(&self) -> bool {
        !self.also.is_empty()
    }
}

/// A `[[frame]]` as written: `led = [r, c]` for one LED, or `leds = [[r, c], ...]` for
/// several lit at once.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StoredFrame {
    file: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    led: Option<LedIndex>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    leds: Option<Vec<LedIndex>>,
    #[serde(default)]
    defocus_um: f64,
    #[serde(default = "one")]
    exposure_ms: f64,
}

impl TryFrom<StoredFrame> for FrameEntry {
    type Error = String;

    fn try_from(f: StoredFrame) -> Result<Self, String> {
        let (led, also) = match (f.led, f.leds) {
            (Some(led), None) => (led, vec![]),
            (None, Some(leds)) => {
                let Some((&first, rest)) = leds.split_first() else {
                    return Err(format!(
                        "frame {}: leds = [] lights nothing: list the LEDs lit, or use led = [row, col]",
                        f.file
                    ));
                };
                let mut seen = std::collections::HashSet::new();
                if let Some(twice) = leds.iter().find(|l| !seen.insert(**l)) {
                    return Err(format!(
                        "frame {}: LED {twice} is listed twice in leds",
                        f.file
                    ));
                }
                (first, rest.to_vec())
            }
            (Some(_), Some(_)) => {
                return Err(format!(
                    "frame {}: give led (one LED) or leds (several), not both",
                    f.file
                ))
            }
            (None, None) => {
                return Err(format!(
                    "frame {}: missing led = [row, col] (or leds = [[row, col], ...])",
                    f.file
                ))
            }
        };
        Ok(Self {
            file: f.file,
            led,
            also,
            defocus_um: f.defocus_um,
            exposure_ms: f.exposure_ms,
        })
    }
}

impl From<FrameEntry> for StoredFrame {
    fn from(f: FrameEntry) -> Self {
        let (led, leds) = if f.also.is_empty() {
            (Some(f.led), None)
        } else {
            (None, Some(f.leds().collect()))
        };
        Self {
            file: f.file,
            led,
            leds,
            defocus_um: f.defocus_um,
            exposure_ms: f.exposure_ms,
        }
    }
}

/// The whole `dataset.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// `[system]`.
    pub system: SystemSection,
    /// `[led]`.
    pub led: LedSection,
    /// `[camera]`.
    #[serde(default)]
    pub camera: CameraSection,
    /// `[source]`: where an imported dataset came from and what the import assumed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<SourceSection>,
    /// `[[frame]]`.
    #[serde(rename = "frame")]
    pub frames: Vec<FrameEntry>,
    /// The objective's entrance pupil distance above the sample, mm (None:
    /// telecentric). Not a key of `dataset.toml` (docs/dataset.md §5.1 fixes its
    /// keys): the user states it (`fpm reconstruct --entrance-pupil-mm`).
    #[serde(skip)]
    pub entrance_pupil_mm: Option<f64>,
}

impl Manifest {
    /// Write it as `dir/dataset.toml` (the frames' files are the caller's).
    pub fn write(&self, dir: &Path) -> Result<(), DatasetError> {
        let path = dir.join("dataset.toml");
        let werr = |reason: String| DatasetError::Write {
            path: path.clone(),
            reason,
        };
        // Not `to_string_pretty`: it spreads a multiplexed frame's `leds` over 20 lines.
        let text = toml::to_string(self).map_err(|e| werr(e.to_string()))?;
        std::fs::write(&path, text).map_err(|e| werr(e.to_string()))
    }

    /// A manifest for `frames` taken with `system`, the array described by `geometry`
    /// (the inverse of [`Self::system`] and [`Self::geometry`]) and `camera`.
    pub fn new(
        system: &System,
        geometry: &LedGeometry,
        camera: CameraSection,
        frames: Vec<FrameEntry>,
    ) -> Self {
        Self {
            system: SystemSection {
                wavelength_um: system.wavelength_um,
                na: system.na,
                magnification: system.magnification,
                pixel_size_um: system.pixel_size_um,
            },
            led: LedSection::of(geometry),
            camera,
            source: None,
            frames,
            entrance_pupil_mm: system.entrance_pupil_mm,
        }
    }

    /// The optical system.
    pub fn system(&self) -> System {
        let s = &self.system;
        System {
            wavelength_um: s.wavelength_um,
            na: s.na,
            magnification: s.magnification,
            pixel_size_um: s.pixel_size_um,
            entrance_pupil_mm: self.entrance_pupil_mm,
        }
    }

    /// The nominal LED geometry.
    pub fn geometry(&self) -> LedGeometry {
        self.led.geometry()
    }
}

impl LedSection {
    /// The section describing `geometry` (the inverse of [`Self::geometry`]): a list's
    /// LEDs by position, with its centre LED and pitch.
    pub fn of(geometry: &LedGeometry) -> Self {
        let listed = geometry.list.is_some();
        Self {
            rows: (!listed).then_some(geometry.rows),
            cols: (!listed).then_some(geometry.cols),
            pitch_mm: Some(geometry.pitch_mm),
            height_mm: geometry.height_mm,
            center: Some(geometry.center),
            offset_mm: [geometry.dx_mm, geometry.dy_mm],
            rotation_deg: geometry.theta_deg,
            tilt_deg: [geometry.tilt_x_deg, geometry.tilt_y_deg],
            rings: geometry.rings,
            position: geometry.list,
            na: None,
        }
    }

    /// A section for a list of LEDs `height_mm` below the sample, nominally placed,
    /// before its `position` or `na` is set.
    pub fn listed(height_mm: f64) -> Self {
        Self {
            rows: None,
            cols: None,
            pitch_mm: None,
            height_mm,
            center: None,
            offset_mm: [0.0, 0.0],
            rotation_deg: 0.0,
            tilt_deg: [0.0, 0.0],
            rings: None,
            position: None,
            na: None,
        }
    }

    /// The same section with a grid's keys (rows, cols, pitch, centre, rings) left
    /// out: what a list of LEDs is written with when they are not its own.
    pub fn without_grid(self) -> Self {
        Self {
            rows: None,
            cols: None,
            pitch_mm: None,
            center: None,
            rings: None,
            ..self
        }
    }

    /// The listed LEDs' places, if the section lists them (an NA list placed at
    /// `height_mm`); None for a grid or rings, or a list that is not valid (a section
    /// read from a file never holds one).
    pub fn list(&self) -> Option<LedList> {
        match (&self.position, &self.na) {
            (Some(list), _) => Some(*list),
            (None, Some(nas)) => LedList::new(nas.positions(self.height_mm)).ok(),
            (None, None) => None,
        }
    }

    /// The nominal LED geometry.
    pub fn geometry(&self) -> LedGeometry {
        let base = match self.list() {
            Some(list) => {
                let g = LedGeometry::listed(list, self.height_mm, self.pitch_mm);
                LedGeometry {
                    center: self.center.unwrap_or(g.center),
                    ..g
                }
            }
            None => LedGeometry {
                rings: self.rings,
                ..LedGeometry::grid(
                    self.rows.unwrap_or(0),
                    self.cols.unwrap_or(0),
                    self.pitch_mm.unwrap_or(0.0),
                    self.height_mm,
                    self.center.unwrap_or(LedIndex::new(0, 0)),
                )
            },
        };
        base.placed_at(fpm_physics::Placement {
            dx_mm: self.offset_mm[0],
            dy_mm: self.offset_mm[1],
            theta_deg: self.rotation_deg,
            height_mm: self.height_mm,
            tilt_x_deg: self.tilt_deg[0],
            tilt_y_deg: self.tilt_deg[1],
        })
    }
}

/// What is wrong with a dataset.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// The manifest cannot be read.
    #[error("{path}: {reason}")]
    Manifest {
        /// `dataset.toml`.
        path: PathBuf,
        /// What went wrong (TOML errors name the key and line).
        reason: String,
    },
    /// A value is out of range.
    #[error("{path}: `{key}` = {value}: {why}")]
    Value {
        /// `dataset.toml`.
        path: PathBuf,
        /// The key.
        key: String,
        /// Its value.
        value: String,
        /// The rule it breaks.
        why: &'static str,
    },
    /// A frame is wrong.
    #[error("{path}: frame {index} ({file}): {reason}")]
    Frame {
        /// `dataset.toml`.
        path: PathBuf,
        /// 0-based index among `[[frame]]`.
        index: usize,
        /// Its file.
        file: String,
        /// What is wrong.
        reason: String,
    },
    /// Writing failed.
    #[error("writing {path}: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}

/// A loaded frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Its manifest entry.
    pub entry: FrameEntry,
    /// Raw counts in the sample-plane orientation, as stored (16-bit frames stay
    /// 16-bit: a 441-frame stack of 20 MP frames is 18 GB as f32, 9 GB as u16).
    pub raw: Pixels,
}

/// A dataset in memory.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// Where it came from.
    pub dir: PathBuf,
    /// Its manifest.
    pub manifest: Manifest,
    /// Frames in manifest order.
    pub frames: Vec<Frame>,
}

impl Dataset {
    /// Load and validate the dataset in `dir`.
    pub fn load(dir: &Path) -> Result<Self, DatasetError> {
        let (path, stored) = read_manifest(dir)?;
        let mut frames: Vec<Frame> = Vec::with_capacity(stored.frames.len());
        for (index, entry) in stored.frames.iter().enumerate() {
            let expected = frames.first().map(|f: &Frame| f.raw.dim());
            let raw = read_frame(dir, &path, &stored, index, expected)?;
            frames.push(Frame {
                entry: entry.clone(),
                raw,
            });
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest: as_in_memory(stored),
            frames,
        })
    }

    /// Frame `k` as measured: its counts, the dark level and its exposure.
    pub fn measured(&self, k: usize) -> Measured<'_> {
        Measured {
            counts: self.frames[k].raw.view(),
            response: self.manifest.camera.response(),
            dark_level: self.manifest.camera.dark_light(),
            exposure_ms: self.frames[k].entry.exposure_ms as f32,
            floor: 0.0,
            soft_floor: false,
            band: 0.0,
        }
    }

    /// The in-focus frames (defocus 0) with their LEDs: what a reconstruction uses.
    pub fn in_focus(&self) -> Vec<LitFrame<'_>> {
        (0..self.frames.len())
            .filter(|&k| self.frames[k].entry.defocus_um == 0.0)
            .map(|k| LitFrame {
                led: self.frames[k].entry.led,
                also: &self.frames[k].entry.also,
                measured: self.measured(k),
            })
            .collect()
    }

    /// Frame `k`, dark-subtracted (not yet divided by exposure).
    pub fn corrected(&self, k: usize) -> Image {
        let m = self.measured(k);
        m.dark_subtracted(Region::whole(m.dim()))
    }

    /// The dark-subtracted value at which the sensor saturates, if the bit depth is known.
    pub fn saturation(&self) -> Option<f32> {
        let camera = &self.manifest.camera;
        camera
            .bit_depth
            .map(|b| camera.response().decode(full_scale(b)) - camera.dark_light())
    }

    /// A dataset made in memory (an acquisition), to be [`Self::save`]d into `dir`:
    /// 16-bit frames in sample-plane orientation, one per entry of `manifest.frames`.
    /// The frames are moved in, not copied.
    pub fn from_frames(
        dir: &Path,
        manifest: Manifest,
        images: Vec<Array2U16>,
    ) -> Result<Self, DatasetError> {
        Self::from_pixels(dir, manifest, images.into_iter().map(Pixels::U16).collect())
    }

    /// A dataset made in memory from frames of any stored type (8- or 16-bit counts,
    /// or floats), in sample-plane orientation, one per entry of `manifest.frames`,
    /// checked as [`Self::load`] checks a dataset on disk. The frames are moved in.
    pub fn from_pixels(
        dir: &Path,
        manifest: Manifest,
        images: Vec<Pixels>,
    ) -> Result<Self, DatasetError> {
        let path = dir.join("dataset.toml");
        if images.len() != manifest.frames.len() {
            return Err(DatasetError::Value {
                path,
                key: "frame".into(),
                value: images.len().to_string(),
                why: "one image per [[frame]] entry",
            });
        }
        validate(&path, &manifest)?;
        let frames: Vec<Frame> = manifest
            .frames
            .iter()
            .zip(images)
            .map(|(entry, raw)| Frame {
                entry: entry.clone(),
                raw,
            })
            .collect();
        let bad = |index: usize, f: &Frame, reason: String| DatasetError::Frame {
            path: path.clone(),
            index,
            file: f.entry.file.clone(),
            reason,
        };
        for (index, f) in frames.iter().enumerate() {
            if f.raw.dim() != frames[0].raw.dim() {
                let reason = format!(
                    "size {:?} differs from frame 0 ({:?})",
                    f.raw.dim(),
                    frames[0].raw.dim()
                );
                return Err(bad(index, f, reason));
            }
            if matches!(&f.raw, Pixels::F32(a) if a.iter().any(|v| !v.is_finite())) {
                return Err(bad(index, f, "contains non-finite values".into()));
            }
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
            frames,
        })
    }

    /// Write this dataset into its directory: frames as TIFF under `frames/` (named
    /// here, `[camera]` flips cleared: frames are kept in sample-plane orientation),
    /// then `dataset.toml`.
    pub fn save(&mut self) -> Result<(), DatasetError> {
        self.save_reusing(|_, _| false)
    }

    /// [`Dataset::save`], except that a frame whose file `on_disk(path, pixels)` says
    /// already holds these pixels is not written again (an acquisition's frames,
    /// written as they arrived).
    pub fn save_reusing(
        &mut self,
        on_disk: impl Fn(&Path, &Pixels) -> bool,
    ) -> Result<(), DatasetError> {
        let werr = |path: &Path, reason: String| DatasetError::Write {
            path: path.to_path_buf(),
            reason,
        };
        let dir = self.dir.clone();
        std::fs::create_dir_all(dir.join("frames")).map_err(|e| werr(&dir, e.to_string()))?;
        self.manifest.camera.flip_x = false;
        self.manifest.camera.flip_y = false;
        self.manifest.camera.transpose = false;
        for (k, frame) in self.frames.iter_mut().enumerate() {
            let name = frame_file_name(&frame.entry);
            let path = dir.join(&name);
            if !on_disk(&path, &frame.raw) {
                match &frame.raw {
                    Pixels::U16(a) => image_io::write_tiff_u16(&path, a.view()),
                    Pixels::U8(a) => image_io::write_tiff_u16(&path, a.mapv(u16::from).view()),
                    Pixels::F32(a) => image_io::write_tiff_f32(&path, a),
                }
                .map_err(|e| werr(&path, e.reason()))?;
            }
            frame.entry.file = name.clone();
            self.manifest.frames[k].file = name;
        }
        self.manifest.write(&dir)
    }

    /// Write a dataset: 16-bit TIFF frames under `frames/` and `dataset.toml`. The
    /// entries' `file` fields are set here. Frames are stored in sample-plane
    /// orientation, so `[camera]` flips are cleared.
    pub fn write(
        dir: &Path,
        manifest: &Manifest,
        images: &[Array2U16],
    ) -> Result<(), DatasetError> {
        // Written as given (tests write broken datasets on purpose); `load` validates.
        let frames = manifest
            .frames
            .iter()
            .zip(images)
            .map(|(entry, img)| Frame {
                entry: entry.clone(),
                raw: Pixels::U16(img.clone()),
            })
            .collect();
        Self {
            dir: dir.to_path_buf(),
            manifest: manifest.clone(),
            frames,
        }
        .save()
    }
}

/// A frame's file name: `frames/rRR_cCC.tif`, with `_z±Z` for defocused frames; a
/// frame lit by several LEDs `frames/rRR_cCC_xN_HHHHHHHH.tif` (its first LED, how many,
/// and a hash of the whole set, so that two sets sharing a first LED differ).
pub fn frame_file_name(entry: &FrameEntry) -> String {
    if entry.is_multiplexed() {
        // FNV-1a over the set's (row, col) bytes: stable across runs and platforms.
        let hash = entry.leds().fold(0x811c_9dc5u32, |h, l| {
            [l.row, l.col]
                .iter()
                .fold(h, |h, &b| (h ^ b as u32).wrapping_mul(0x0100_0193))
        });
        format!(
            "frames/r{:02}_c{:02}_x{}_{hash:08x}.tif",
            entry.led.row,
            entry.led.col,
            entry.also.len() + 1
        )
    } else if entry.defocus_um == 0.0 {
        format!("frames/r{:02}_c{:02}.tif", entry.led.row, entry.led.col)
    } else {
        format!(
            "frames/r{:02}_c{:02}_z{:+.0}.tif",
            entry.led.row, entry.led.col, entry.defocus_um
        )
    }
}

/// 16-bit frames to write.
pub type Array2U16 = ndarray::Array2<u16>;

/// Transpose, then flip, into the sample-plane orientation.
fn orient<T: Clone>(img: ndarray::Array2<T>, cam: &CameraSection) -> ndarray::Array2<T> {
    let mut img = if cam.transpose {
        img.reversed_axes().as_standard_layout().to_owned()
    } else {
        img
    };
    if cam.flip_x {
        img.invert_axis(ndarray::Axis(1));
    }
    if cam.flip_y {
        img.invert_axis(ndarray::Axis(0));
    }
    img.as_standard_layout().to_owned()
}

/// `dir/dataset.toml`, read and validated: its path and the manifest as stored.
pub fn read_manifest(dir: &Path) -> Result<(PathBuf, Manifest), DatasetError> {
    let path = dir.join("dataset.toml");
    let text = std::fs::read_to_string(&path).map_err(|e| DatasetError::Manifest {
        path: path.clone(),
        reason: e.to_string(),
    })?;
    if let Ok(table) = text.parse::<toml::Table>() {
        if table.contains_key("color") {
            let reason = "a colour dataset (one dataset per channel, docs/dataset.md §5.9): `fpm reconstruct` and `fpm calibrate` take it whole; for one channel alone give its directory (a [[channel]]'s dataset)".to_string();
            return Err(DatasetError::Manifest { path, reason });
        }
    }
    let manifest: Manifest = toml::from_str(&text).map_err(|e| DatasetError::Manifest {
        path: path.clone(),
        reason: e.to_string(),
    })?;
    validate(&path, &manifest)?;
    Ok((path, manifest))
}

/// An error about frame `index` of the manifest at `path`.
pub(crate) fn frame_error(path: &Path, m: &Manifest, index: usize, reason: String) -> DatasetError {
    DatasetError::Frame {
        path: path.to_path_buf(),
        index,
        file: m
            .frames
            .get(index)
            .map(|e| e.file.clone())
            .unwrap_or_default(),
        reason,
    }
}

/// Frame `index` of the dataset in `dir` (manifest at `path`, as stored), whole, in the
/// sample-plane orientation: a Bayer mosaic's channel taken out first, then the
/// orientation. Checked: the file exists and reads, its size is `expected` (when
/// given), its values are finite.
pub(crate) fn read_frame(
    dir: &Path,
    path: &Path,
    stored: &Manifest,
    index: usize,
    expected: Option<(usize, usize)>,
) -> Result<Pixels, DatasetError> {
    let bad = |reason: String| frame_error(path, stored, index, reason);
    let entry = stored
        .frames
        .get(index)
        .ok_or_else(|| bad("no such [[frame]] entry".into()))?;
    let file = dir.join(&entry.file);
    if !file.is_file() {
        return Err(bad(format!("file {} does not exist", file.display())));
    }
    let camera = &stored.camera;
    let mut pixels = image_io::read(&file).map_err(|e| bad(e.reason()))?;
    if let Some((pattern, channel)) = camera.bayer.zip(camera.channel) {
        let (h, w) = pixels.dim();
        if !camera.demosaic && (h % 2 == 1 || w % 2 == 1) {
            return Err(bad(format!(
                "{w}x{h}: a Bayer mosaic taken by its channel's pixels needs even sizes"
            )));
        }
        let raw = pixels.to_f32();
        pixels = Pixels::F32(if camera.demosaic {
            bayer::demosaic(raw.view(), pattern, channel)
        } else {
            bayer::subsample(raw.view(), pattern, channel)
        });
    }
    let raw = match pixels {
        Pixels::U8(a) => Pixels::U8(orient(a, camera)),
        Pixels::U16(a) => Pixels::U16(orient(a, camera)),
        Pixels::F32(a) => Pixels::F32(orient(a, camera)),
    };
    check_frame(&raw, expected).map_err(bad)?;
    Ok(raw)
}

/// A frame's size against the first's, and its values finite.
pub(crate) fn check_frame(raw: &Pixels, expected: Option<(usize, usize)>) -> Result<(), String> {
    if let Some(first) = expected.filter(|&e| e != raw.dim()) {
        return Err(format!(
            "size {}x{} differs from frame 0 ({}x{})",
            raw.dim().1,
            raw.dim().0,
            first.1,
            first.0
        ));
    }
    if matches!(raw, Pixels::F32(a) if a.iter().any(|v| !v.is_finite())) {
        return Err("contains non-finite values".into());
    }
    Ok(())
}

/// The manifest of frames as they are in memory: a colour sensor's frames are its
/// channel's image (a saved copy says so), and a channel taken by its own pixels has
/// twice the sensor's pitch.
pub(crate) fn as_in_memory(mut manifest: Manifest) -> Manifest {
    if manifest.camera.bayer.zip(manifest.camera.channel).is_some() {
        if !manifest.camera.demosaic {
            manifest.system.pixel_size_um *= 2.0;
        }
        manifest.camera.bayer = None;
        manifest.camera.channel = None;
        manifest.camera.demosaic = false;
    }
    manifest
}

/// A manifest's values checked, each error naming its key (or frame): the system,
/// the LED array, the camera, then the frames.
fn validate(path: &Path, m: &Manifest) -> Result<(), DatasetError> {
    let value = |key: &str, v: String, why: &'static str| bad_value(path, key, v, why);
    if let Some((key, v, why)) = m.system().out_of_range() {
        return Err(value(&format!("system.{key}"), v.to_string(), why));
    }
    positive(path, "led.height_mm", m.led.height_mm)?;
    if let Some(pitch) = m.led.pitch_mm {
        positive(path, "led.pitch_mm", pitch)?;
    }
    if listed(m) {
        validate_listed_leds(path, m)?;
    } else {
        validate_led_grid(path, m)?;
    }
    if !m.led.offset_mm.iter().all(|v| v.is_finite()) {
        return Err(value(
            "led.offset_mm",
            format!("{:?}", m.led.offset_mm),
            "must be finite",
        ));
    }
    if !m.led.rotation_deg.is_finite() {
        return Err(value(
            "led.rotation_deg",
            m.led.rotation_deg.to_string(),
            "must be finite",
        ));
    }
    if !m.camera.dark_level.is_finite() {
        return Err(value(
            "camera.dark_level",
            m.camera.dark_level.to_string(),
            "must be finite",
        ));
    }
    validate_camera(path, m)?;
    validate_frames(path, m)?;
    Ok(())
}

/// The array is a list of LEDs (`[[led.position]]` or `[[led.na]]`), not a grid.
fn listed(m: &Manifest) -> bool {
    m.led.position.is_some() || m.led.na.is_some()
}

/// The camera's gamma, mosaic and channel consistent.
fn validate_camera(path: &Path, m: &Manifest) -> Result<(), DatasetError> {
    let value = |key: &str, v: String, why: &'static str| bad_value(path, key, v, why);
    m.camera.check_gamma(path)?;
    match (m.camera.bayer, m.camera.channel) {
        (Some(_), None) => {
            return Err(value(
                "camera.channel",
                "absent".into(),
                "a Bayer mosaic needs the channel to use: \"R\", \"G\" or \"B\"",
            ))
        }
        (None, Some(c)) => {
            return Err(value(
                "camera.channel",
                format!("{c:?}"),
                "only means something with camera.bayer",
            ))
        }
        _ => {}
    }
    if m.camera.demosaic && m.camera.bayer.is_none() {
        return Err(value(
            "camera.demosaic",
            "true".into(),
            "only means something with camera.bayer",
        ));
    }
    Ok(())
}

/// Every frame's LEDs on the array, its defocus and exposure sensible.
fn validate_frames(path: &Path, m: &Manifest) -> Result<(), DatasetError> {
    let listed = listed(m);
    if m.frames.is_empty() {
        return Err(DatasetError::Manifest {
            path: path.to_path_buf(),
            reason: "no [[frame]] entries".into(),
        });
    }
    let geometry = m.geometry();
    for (index, f) in m.frames.iter().enumerate() {
        let bad = |reason: String| DatasetError::Frame {
            path: path.to_path_buf(),
            index,
            file: f.file.clone(),
            reason,
        };
        if let Some(led) = f.leds().find(|&led| !geometry.contains(led)) {
            return Err(bad(match (m.led.rings, listed) {
                (_, true) => format!("LED {led} is not one of the listed LEDs"),
                (Some(rings), false) => format!(
                    "LED {led} is not on the rings (ring {} holds {} LEDs)",
                    led.r(),
                    rings.count(led.r())
                ),
                (None, false) => format!(
                    "LED {led} is outside the {}x{} array",
                    geometry.rows, geometry.cols
                ),
            }));
        }
        if !f.defocus_um.is_finite() {
            return Err(bad(format!("defocus_um = {} is not finite", f.defocus_um)));
        }
        if f.is_multiplexed() && f.defocus_um != 0.0 {
            return Err(bad(format!(
                "defocus_um = {} with several LEDs: calibration frames are lit by one LED each (leave defocus_um out of multiplexed frames)",
                f.defocus_um
            )));
        }
        if !(f.exposure_ms.is_finite() && f.exposure_ms > 0.0) {
            return Err(bad(format!(
                "exposure_ms = {} must be a positive number",
                f.exposure_ms
            )));
        }
    }
    Ok(())
}

/// The error for `key` = `v` in the manifest at `path`.
fn bad_value(path: &Path, key: &str, v: String, why: &'static str) -> DatasetError {
    DatasetError::Value {
        path: path.to_path_buf(),
        key: key.into(),
        value: v,
        why,
    }
}

fn positive(path: &Path, key: &str, v: f64) -> Result<(), DatasetError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(bad_value(
            path,
            key,
            v.to_string(),
            "must be a positive number",
        ))
    }
}

/// An array given as a list of LEDs (`[[led.position]]` or `[[led.na]]`): nothing that
/// places LEDs another way beside it, and its centre one of them.
fn validate_listed_leds(path: &Path, m: &Manifest) -> Result<(), DatasetError> {
    let value = |key: &str, v: String, why: &'static str| bad_value(path, key, v, why);
    let fixed = if m.led.position.is_some() && m.led.na.is_some() {
        Some((
            "led.position/led.na",
            "give the LEDs' positions or their NAs, not both",
        ))
    } else if m.led.rings.is_some() {
        Some((
            "led.rings",
            "a list places its LEDs itself: leave rings out",
        ))
    } else if m.led.rows.is_some() || m.led.cols.is_some() {
        Some((
            "led.rows/cols",
            "a list's LED ids bound the array: leave rows and cols out",
        ))
    } else {
        None
    };
    if let Some((key, why)) = fixed {
        return Err(value(key, "given".into(), why));
    }
    let Some(list) = m.led.list() else {
        return Err(value(
            "led.na",
            "given".into(),
            "the NAs do not place a valid list of LEDs",
        ));
    };
    if let Some(center) = m.led.center {
        if list.get(center).is_none() {
            return Err(value(
                "led.center",
                center.to_string(),
                "is not one of the listed LEDs",
            ));
        }
    }
    Ok(())
}

/// A grid or ring array: its rows, cols, pitch and centre given and consistent.
fn validate_led_grid(path: &Path, m: &Manifest) -> Result<(), DatasetError> {
    let value = |key: &str, v: String, why: &'static str| bad_value(path, key, v, why);
    let (Some(rows), Some(cols), Some(_), Some(center)) =
        (m.led.rows, m.led.cols, m.led.pitch_mm, m.led.center)
    else {
        let missing = [
            ("rows", m.led.rows.is_none()),
            ("cols", m.led.cols.is_none()),
            ("pitch_mm", m.led.pitch_mm.is_none()),
            ("center", m.led.center.is_none()),
        ]
        .iter()
        .filter(|(_, absent)| *absent)
        .map(|(k, _)| format!("led.{k}"))
        .collect::<Vec<_>>()
        .join(", ");
        return Err(value(
            &missing,
            "absent".into(),
            "a grid or ring array needs rows, cols, pitch_mm and center (or list the LEDs: [[led.position]] or [[led.na]])",
        ));
    };
    if rows == 0 || cols == 0 {
        return Err(value(
            "led.rows/cols",
            format!("{rows}x{cols}"),
            "the array needs at least one LED",
        ));
    }
    if rows > 256 || cols > 256 {
        return Err(value(
            "led.rows/cols",
            format!("{rows}x{cols}"),
            "at most 256x256 (LED indices are 0-255)",
        ));
    }
    if let Some(rings) = m.led.rings {
        let stated = (rows, cols, center);
        let implied = (rings.len(), rings.widest(), LedIndex::new(0, 0));
        if stated != implied {
            return Err(value(
                "led.rows/cols/center",
                format!("{}x{}, center {}", stated.0, stated.1, stated.2),
                "with led.rings: rows = the number of rings, cols = the largest ring's LEDs, center = [0, 0]",
            ));
        }
    }
    if center.r() >= rows || center.c() >= cols {
        return Err(value(
            "led.center",
            center.to_string(),
            "is outside the array",
        ));
    }
    Ok(())
}
