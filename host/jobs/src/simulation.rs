//! Simulated datasets from the full wave-optics model, written to disk with their
//! truth (`truth.json`, and for acquisitions the true object's images): what `fpm
//! simulate` and the Python package's `simulate_*` make. The physics is
//! `fpm_physics::simulate`; this module only chooses the scene and writes the files.

use std::path::Path;

use anyhow::{Context, Result};
use fpm_physics::color::Channel;
use fpm_physics::multiplex::Multiplex;
use fpm_physics::simulate::{
    acquire_from, acquire_sets, acquire_spectral, CalibrationScene, Camera, ObjectField,
    SampleKind, SimFrame,
};
use fpm_physics::{Image, LedGeometry, LedIndex, System};
use rand::{Rng, SeedableRng};
use rand_distr::Distribution;

use crate::color::{ColorDataset, ColorManifest};
use crate::dataset::{CameraSection, Dataset, FrameEntry, Manifest};
use crate::truth::{write_truth_images, TrueLed, Truth};

/// Camera noise of a simulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Noise {
    /// Shot noise, read noise, offset, 12-bit quantisation.
    Realistic,
    /// A home-built rig's 8-bit camera ([`Camera::eight_bit`]): strong read noise
    /// about a small offset, clipped at zero.
    EightBit,
    /// Quantisation only.
    None,
}

/// The hidden (true) LED array and the camera: what every simulated set shares.
#[derive(Debug, Clone, Copy)]
pub struct Scene {
    /// Where the array really is (the dataset states only the nominal one).
    pub truth: LedGeometry,
    /// Camera noise.
    pub noise: Noise,
    /// Sensor side, pixels (square).
    pub size: usize,
    /// Seed of the noise (and of anything else drawn).
    pub seed: u64,
    /// Stray light on every pixel, as a fraction of a clear sample's brightness under
    /// the on-axis LED.
    pub stray_light: f64,
}

impl Default for Scene {
    /// The paper's array at its nominal place, realistic noise, a 256² sensor.
    fn default() -> Self {
        Self {
            truth: nominal(),
            noise: Noise::Realistic,
            size: 256,
            seed: 1,
            stray_light: 0.0,
        }
    }
}

/// Sensor sides the simulator renders (it holds the whole upsampled field and every
/// frame in memory: 2048² at 2× is about 4 GB).
pub const SIZE_PX: std::ops::RangeInclusive<usize> = 16..=2048;
/// Simulation pixels per camera pixel.
pub const UPSAMPLE: std::ops::RangeInclusive<usize> = 1..=8;

impl Scene {
    /// Every setting in its range, or an error naming it.
    pub fn validate(&self) -> Result<()> {
        if !SIZE_PX.contains(&self.size) {
            anyhow::bail!(
                "size {}: the simulated sensor must be {}-{} px (the whole upsampled field and every frame are held in memory)",
                self.size,
                SIZE_PX.start(),
                SIZE_PX.end()
            );
        }
        if !(self.stray_light.is_finite() && (0.0..=1.0).contains(&self.stray_light)) {
            anyhow::bail!(
                "stray_light {}: must be 0-1 (a fraction of a clear sample's brightness)",
                self.stray_light
            );
        }
        let g = &self.truth;
        if !(g.height_mm.is_finite() && g.height_mm > 0.0) {
            anyhow::bail!(
                "height_mm {}: must be a positive distance in mm",
                g.height_mm
            );
        }
        for (name, v) in [
            ("dx_mm", g.dx_mm),
            ("dy_mm", g.dy_mm),
            ("theta_deg", g.theta_deg),
        ] {
            if !v.is_finite() {
                anyhow::bail!("{name} {v}: must be finite");
            }
        }
        Ok(())
    }

    /// The paper's array moved by (`dx_mm`, `dy_mm`), turned by `theta_deg`, at
    /// `height_mm` (flat: `.tilted(…)` tilts it).
    pub fn placed(dx_mm: f64, dy_mm: f64, theta_deg: f64, height_mm: f64) -> LedGeometry {
        LedGeometry {
            dx_mm,
            dy_mm,
            theta_deg,
            height_mm,
            ..nominal()
        }
    }

    /// An array drawn from the paper's range (±2.5 mm, ±5°, 87–97 mm) with `seed`.
    pub fn random_placement(seed: u64) -> LedGeometry {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x5EED);
        LedGeometry {
            dx_mm: rng.gen_range(-2.5..2.5),
            dy_mm: rng.gen_range(-2.5..2.5),
            theta_deg: rng.gen_range(-5.0..5.0),
            height_mm: rng.gen_range(87.0..97.0),
            ..nominal()
        }
    }

    /// The camera model.
    pub fn camera(&self) -> Camera {
        let camera = match self.noise {
            Noise::Realistic => Camera::realistic(),
            Noise::EightBit => Camera::eight_bit(),
            Noise::None => Camera::noiseless(),
        };
        Camera {
            stray_light: self.stray_light.max(0.0),
            ..camera
        }
    }

    fn truth_file(&self) -> Truth {
        let t = &self.truth;
        Truth {
            placement: t.placement(),
            defocus_um: None,
            feature_um: None,
            feature_at_um: None,
            object_pixel_um: None,
            seed: Some(self.seed),
            leds: None,
            entrance_pupil_mm: None,
            sample: None,
        }
    }
}

/// A pdcFPM calibration set: an in-focus reference and defocused frames of the LEDs
/// around the centre, of a small square hole.
#[derive(Debug, Clone, Copy)]
pub struct CalibrationSet {
    /// Defocus of the sample toward the LEDs, µm.
    pub defocus_um: f64,
    /// Side of the square hole, µm.
    pub feature_um: f64,
    /// Where the hole is, µm from the optical axis.
    pub feature_at_um: (f64, f64),
    /// Each LED off its grid place by its own move, 1σ per axis, mm
    /// ([`CalibrationScene::led_offset_mm`]).
    pub led_jitter_mm: f64,
}

impl Default for CalibrationSet {
    fn default() -> Self {
        Self {
            defocus_um: 200.0,
            feature_um: 50.0,
            feature_at_um: (0.0, 0.0),
            led_jitter_mm: 0.0,
        }
    }
}

/// A full acquisition: every LED, in focus, of a complex test sample.
#[derive(Debug, Clone, Copy)]
pub struct AcquisitionSet {
    /// Simulation pixels per camera pixel (the truth's resolution).
    pub upsample: usize,
    /// Dark-field frames recorded dim: their brightest pixel this many counts above the
    /// offset, instead of auto-exposed to 80 % of full scale.
    pub dark_field_peak_dn: Option<f64>,
    /// Each LED off its grid place by this much (1σ per axis, mm).
    pub led_jitter_mm: f64,
    /// The objective's entrance pupil distance above the sample, mm (None:
    /// telecentric). The dataset cannot state it; truth.json does.
    pub entrance_pupil_mm: Option<f64>,
    /// Frames stored for display with this gamma ([`Camera::display_gamma`]); the
    /// dataset states it as `[camera] gamma`.
    pub display_gamma: Option<f64>,
    /// What the sample is made of.
    pub sample: SampleKind,
    /// LEDs lit together in each frame, dark field and bright field
    /// ([`fpm_physics::multiplex::sets`] chooses them). Each frame is exposed for the
    /// sum of its LEDs' single-LED exposures, or less where the sum would saturate: the
    /// scan never takes more exposure time than the one-LED scan.
    pub multiplex: Multiplex,
}

impl Default for AcquisitionSet {
    fn default() -> Self {
        Self {
            upsample: 2,
            dark_field_peak_dn: None,
            led_jitter_mm: 0.0,
            entrance_pupil_mm: None,
            display_gamma: None,
            sample: SampleKind::Cells,
            multiplex: Multiplex::ONE,
        }
    }
}

/// What was written.
#[derive(Debug, Clone)]
pub struct Written {
    /// Frames in the dataset.
    pub frames: usize,
    /// The truth, as in `truth.json`.
    pub truth: Truth,
}

/// Most LEDs [`AcquisitionSet::multiplex`] lights in one frame: the controller's own
/// limit (one frame's LED list on the wire), so that a simulated set is one a board
/// could take.
pub const MAX_MULTIPLEX: usize = fpm_protocol::limits::MAX_LEDS_PER_LIST;

/// The paper's array at its nominal place: what a simulated dataset states.
fn nominal() -> LedGeometry {
    LedGeometry {
        height_mm: 92.0,
        ..LedGeometry::paper()
    }
}

/// Write `scene`'s calibration set into `out` (dataset.toml, frames/, truth.json).
pub fn write_calibration_set(scene: &Scene, set: &CalibrationSet, out: &Path) -> Result<Written> {
    write_calibration_set_at(scene, set, (System::paper().wavelength_um, 0.0), out)
}

/// [`write_calibration_set`] in light of a wavelength (µm) whose focus lies a focal
/// shift (µm) from the one the stage was zeroed in.
fn write_calibration_set_at(
    scene: &Scene,
    set: &CalibrationSet,
    (wavelength_um, focal_shift_um): (f64, f64),
    out: &Path,
) -> Result<Written> {
    scene.validate()?;
    if !(set.defocus_um.is_finite() && set.feature_um.is_finite() && set.feature_um > 0.0) {
        anyhow::bail!(
            "defocus_um {} / feature_um {}: the defocus must be finite and the feature a positive size",
            set.defocus_um,
            set.feature_um
        );
    }
    let mut sim = CalibrationScene::paper(scene.truth, scene.seed);
    sim.system.wavelength_um = wavelength_um;
    sim.defocus_um = set.defocus_um;
    sim.feature_um = set.feature_um;
    sim.feature_at_um = set.feature_at_um;
    sim.camera_px = scene.size;
    sim.camera = scene.camera();
    check_led_jitter(set.led_jitter_mm)?;
    sim.led_jitter_mm = set.led_jitter_mm;
    let frames = sim.acquire_focused_off(focal_shift_um);
    write_frames(out, &sim.system, &sim.camera, &frames, &nominal())?;
    // Where the calibration's LEDs really were, when they were moved.
    let leds = (set.led_jitter_mm > 0.0).then(|| {
        fpm_physics::calibrate::calibration_grid(&scene.truth, sim.half_grid)
            .into_iter()
            .map(|led| {
                let (x, y, h) = scene.truth.led_position_3d_mm(led);
                let (dx, dy) = sim.led_offset_mm(led);
                TrueLed {
                    led,
                    position_mm: [x + dx, y + dy, h],
                }
            })
            .collect()
    });
    let truth = Truth {
        defocus_um: Some(set.defocus_um),
        feature_um: Some(set.feature_um),
        feature_at_um: Some([set.feature_at_um.0, set.feature_at_um.1]),
        leds,
        ..scene.truth_file()
    };
    write_json(&out.join("truth.json"), &truth)?;
    Ok(Written {
        frames: frames.len(),
        truth,
    })
}

/// Write `scene`'s full acquisition into `out` (dataset.toml, frames/, truth.json,
/// truth_amplitude.tif, truth_phase.tif). Frames are auto-exposed as a camera would:
/// the brightest pixel at 80 % of full scale, from 2 ms (bright field) up to 1 s.
pub fn write_acquisition(scene: &Scene, set: &AcquisitionSet, out: &Path) -> Result<Written> {
    write_acquisition_lit(scene, set, None, out)
}

/// Colour: the LED colours lit in turn ([`fpm_physics::color`]) and how finely their
/// spectra are sampled.
#[derive(Debug, Clone)]
pub struct ColorSet {
    /// The channels, each acquired as a whole scan of its own.
    pub channels: Vec<Channel>,
    /// Wavelengths rendered per channel to stand for its LED's spectrum (1: its
    /// centre line only).
    pub spectral_samples: usize,
}

/// Most wavelengths rendered per channel.
pub const MAX_SPECTRAL_SAMPLES: usize = 15;

impl ColorSet {
    fn validate(&self) -> Result<()> {
        if self.channels.is_empty() {
            anyhow::bail!("colors: name at least one channel (red, green, blue)");
        }
        if !(1..=MAX_SPECTRAL_SAMPLES).contains(&self.spectral_samples) {
            anyhow::bail!(
                "spectral_samples {}: must be 1-{MAX_SPECTRAL_SAMPLES}",
                self.spectral_samples
            );
        }
        for c in &self.channels {
            if !(c.wavelength_um.is_finite() && (0.2..=2.0).contains(&c.wavelength_um)) {
                anyhow::bail!(
                    "channel {}: wavelength {} µm: give a wavelength in µm (0.2-2)",
                    c.name,
                    c.wavelength_um
                );
            }
            if !(c.fwhm_nm.is_finite() && (0.0..=200.0).contains(&c.fwhm_nm)) {
                anyhow::bail!(
                    "channel {}: FWHM {} nm: must be 0-200 nm",
                    c.name,
                    c.fwhm_nm
                );
            }
            if !c.die_offset_mm.iter().all(|v| v.is_finite()) || !c.focal_shift_um.is_finite() {
                anyhow::bail!(
                    "channel {}: die offset and focal shift must be finite",
                    c.name
                );
            }
        }
        Ok(())
    }
}

/// Write a colour acquisition into `out`: each channel a whole acquisition of its own
/// (`out/<name>/`, with its truth at its central wavelength) and the colour dataset's
/// `dataset.toml` joining them. Each channel's LEDs are its dies (the true board moved
/// by the channel's die offset), its frames the sum over its spectrum, its sample the
/// same cells as the others' in its own light, its focus shifted by the objective's
/// chromatic focal shift; its dataset states the board's nominal place, as a user who
/// has not calibrated each colour would.
pub fn write_color_acquisition(
    scene: &Scene,
    set: &AcquisitionSet,
    color: &ColorSet,
    out: &Path,
) -> Result<Vec<(String, Written)>> {
    color.validate()?;
    if !set.multiplex.is_one() {
        anyhow::bail!("multiplex: a colour acquisition lights one LED per frame (multiplexed colour frames are not simulated)");
    }
    write_channels(color, out, |k, channel, dir| {
        write_acquisition_lit(scene, set, Some((channel, color.spectral_samples, k)), dir)
    })
}

/// Write a colour pdcFPM calibration set into `out`: one calibration set per channel
/// (`out/<name>/`: the same hole, each colour's dies as its LEDs, at its central
/// wavelength) and the colour dataset's `dataset.toml`.
pub fn write_color_calibration(
    scene: &Scene,
    set: &CalibrationSet,
    color: &ColorSet,
    out: &Path,
) -> Result<Vec<(String, Written)>> {
    color.validate()?;
    write_channels(color, out, |k, channel, dir| {
        let lit = Scene {
            truth: channel.geometry(&scene.truth),
            seed: channel_seed(scene.seed, k),
            ..*scene
        };
        write_calibration_set_at(
            &lit,
            set,
            (channel.wavelength_um, channel.focal_shift_um),
            dir,
        )
    })
}

/// The noise seed of channel `k` (the sample keeps the scene's own seed: every colour
/// sees the same sample).
fn channel_seed(seed: u64, k: usize) -> u64 {
    seed ^ 0xC010_0000u64.wrapping_mul(k as u64 + 1)
}

fn write_channels(
    color: &ColorSet,
    out: &Path,
    write: impl Fn(usize, &Channel, &Path) -> Result<Written>,
) -> Result<Vec<(String, Written)>> {
    let mut written = vec![];
    for (k, channel) in color.channels.iter().enumerate() {
        let dir = out.join(&channel.name);
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        written.push((channel.name.clone(), write(k, channel, &dir)?));
    }
    let manifest = ColorManifest::of_names(color.channels.iter().map(|c| c.name.clone()), None);
    ColorDataset::write_manifest(out, &manifest)?;
    ColorDataset::open(out)?;
    Ok(written)
}

/// [`write_acquisition`], lit by one colour channel (its spectrum sampled so finely,
/// and its index for the noise seed) or, without one, by the single-colour
/// simulator's line at the paper's wavelength.
fn write_acquisition_lit(
    scene: &Scene,
    set: &AcquisitionSet,
    channel: Option<(&Channel, usize, usize)>,
    out: &Path,
) -> Result<Written> {
    let lit;
    let scene = match channel {
        Some((c, _, _)) => {
            lit = Scene {
                truth: c.geometry(&scene.truth),
                ..*scene
            };
            &lit
        }
        None => scene,
    };
    scene.validate()?;
    if !UPSAMPLE.contains(&set.upsample) {
        anyhow::bail!(
            "upsample {}: must be {}-{}",
            set.upsample,
            UPSAMPLE.start(),
            UPSAMPLE.end()
        );
    }
    check_led_jitter(set.led_jitter_mm)?;
    if let Some(gamma) = set
        .display_gamma
        .filter(|g| !CameraSection::is_valid_gamma(*g))
    {
        anyhow::bail!("display gamma {gamma}: give an exponent above 0 and at most 5 (2.2 for sRGB-like images)");
    }
    let system = System {
        entrance_pupil_mm: set.entrance_pupil_mm,
        wavelength_um: channel.map_or(System::paper().wavelength_um, |c| c.0.wavelength_um),
        ..System::paper()
    };
    let camera = Camera {
        display_gamma: set.display_gamma,
        ..scene.camera()
    };
    let sample_at = |wavelength_um: f64| {
        ObjectField::sample_in_light(
            &system,
            scene.size,
            48,
            set.upsample,
            scene.seed,
            set.sample,
            wavelength_um,
        )
    };
    let object = sample_at(system.wavelength_um);
    let truth = scene.truth;
    set.multiplex.check(MAX_MULTIPLEX)?;
    let positions = led_positions(&truth, set.led_jitter_mm, scene.seed)?;
    let board = |led| {
        positions
            .iter()
            .find(|p: &&TrueLed| p.led == led)
            .map(|p| (p.position_mm[0], p.position_mm[1], p.position_mm[2]))
            .unwrap_or_else(|| truth.led_position_3d_mm(led))
    };
    let single = |img: &Image| match set.dark_field_peak_dn {
        Some(peak) => camera.dim_dark_field_exposure(img, peak),
        None => camera.auto_exposure(img),
    };
    let frames = if let Some((c, samples, k)) = channel {
        let lights: Vec<(f64, f64, ObjectField)> = c
            .spectrum(samples)
            .into_iter()
            .map(|(l, w)| (l, w, sample_at(l)))
            .collect();
        let shots: Vec<(LedIndex, f64)> = truth.leds().into_iter().map(|l| (l, 0.0)).collect();
        acquire_spectral(
            &system,
            &board,
            &lights,
            c.focal_shift_um,
            &shots,
            &camera,
            single,
            channel_seed(scene.seed, k),
        )
    } else if set.multiplex.is_one() {
        let shots: Vec<(LedIndex, f64)> = truth.leds().into_iter().map(|l| (l, 0.0)).collect();
        acquire_from(
            &system, &board, &object, &shots, &camera, single, scene.seed,
        )
    } else {
        let sets = fpm_physics::multiplex::sets(&truth, &system, set.multiplex, scene.seed);
        acquire_sets(
            &system,
            &board,
            &object,
            &sets,
            &camera,
            |sum, each| {
                let budget: f64 = each.iter().map(single).sum();
                budget.min(camera.unsaturated_exposure(sum))
            },
            scene.seed,
        )
    };
    write_frames(out, &system, &camera, &frames, &nominal())?;
    write_truth_images(out, &object)?;
    let truth = Truth {
        object_pixel_um: Some(object.pitch_um()),
        leds: (set.led_jitter_mm > 0.0).then_some(positions),
        entrance_pupil_mm: set.entrance_pupil_mm,
        sample: Some(set.sample),
        ..scene.truth_file()
    };
    write_json(&out.join("truth.json"), &truth)?;
    Ok(Written {
        frames: frames.len(),
        truth,
    })
}

/// One full single-LED acquisition of `object` (already made: a field of a larger
/// slide, say) under `scene`'s array and camera, written as a dataset into `out` with
/// `object`'s truth beside it.
pub fn write_acquisition_of(
    scene: &Scene,
    system: &System,
    object: &ObjectField,
    out: &Path,
) -> Result<Written> {
    scene.validate()?;
    let camera = scene.camera();
    let truth = scene.truth;
    let shots: Vec<(LedIndex, f64)> = truth.leds().into_iter().map(|l| (l, 0.0)).collect();
    let frames = acquire_from(
        system,
        &|led| truth.led_position_3d_mm(led),
        object,
        &shots,
        &camera,
        |img: &Image| camera.auto_exposure(img),
        scene.seed,
    );
    // The dataset states the board's grid at its nominal place.
    let stated = LedGeometry {
        rows: truth.rows,
        cols: truth.cols,
        center: truth.center,
        pitch_mm: truth.pitch_mm,
        ..nominal()
    };
    write_frames(out, system, &camera, &frames, &stated)?;
    write_truth_images(out, object)?;
    let truth = Truth {
        object_pixel_um: Some(object.pitch_um()),
        ..scene.truth_file()
    };
    write_json(&out.join("truth.json"), &truth)?;
    Ok(Written {
        frames: frames.len(),
        truth,
    })
}

/// A scene's LED jitter (`led_jitter_mm`): a standard deviation, 0 or more.
fn check_led_jitter(jitter_mm: f64) -> Result<()> {
    if !(jitter_mm.is_finite() && jitter_mm >= 0.0) {
        anyhow::bail!("led_jitter_mm {jitter_mm}: must be 0 or a positive distance in mm");
    }
    Ok(())
}

/// Every LED of `truth`'s board, each moved laterally by N(0, σ = `jitter_mm`) per
/// axis (its own stream of the seed).
fn led_positions(truth: &LedGeometry, jitter_mm: f64, seed: u64) -> Result<Vec<TrueLed>> {
    if !(jitter_mm.is_finite() && jitter_mm >= 0.0) {
        anyhow::bail!("LED jitter {jitter_mm} mm: give a standard deviation in mm (≥ 0)");
    }
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x1ED5);
    let normal = rand_distr::Normal::new(0.0, jitter_mm)?;
    Ok(truth
        .leds()
        .into_iter()
        .map(|led| {
            let (x, y, h) = truth.led_position_3d_mm(led);
            TrueLed {
                led,
                position_mm: [x + normal.sample(&mut rng), y + normal.sample(&mut rng), h],
            }
        })
        .collect())
}

/// Write simulated frames as a dataset with the nominal (uncalibrated) array.
fn write_frames(
    out: &Path,
    system: &System,
    camera: &Camera,
    frames: &[SimFrame],
    stated: &LedGeometry,
) -> Result<()> {
    let entries = frames
        .iter()
        .map(|f| FrameEntry {
            file: String::new(),
            led: f.led,
            also: f.also.clone(),
            defocus_um: f.defocus_um,
            exposure_ms: f.exposure_ms,
        })
        .collect();
    let section = CameraSection {
        dark_level: camera.stored_dark_level(),
        bit_depth: Some(camera.bit_depth),
        gamma: camera.display_gamma,
        ..CameraSection::default()
    };
    let manifest = Manifest::new(system, stated, section, entries);
    let images: Vec<_> = frames.iter().map(|f| f.counts.clone()).collect();
    Dataset::write(out, &manifest, &images)?;
    Ok(())
}

fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(value)?)
        .with_context(|| format!("writing {}", path.display()))
}
