//! `fpm.simulate_acquisition` / `fpm.simulate_calibration`: datasets from the full
//! wave-optics model, written to disk with their truth, as `fpm simulate` makes them.

use fpm_physics::simulate::SampleKind;
use std::path::PathBuf;

use fpm_host::dataset::CameraSection;
use fpm_host::simulation::{self, AcquisitionSet, CalibrationSet, Noise, Scene, Written};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{entrance_pupil, failed, to_py};
use crate::dataset::Dataset;

/// The scene from the common arguments, checked.
fn scene(
    size: usize,
    seed: u64,
    placement: (f64, f64, f64, f64),
    tilt_deg: (f64, f64),
    noise: &str,
    stray_light: f64,
) -> PyResult<Scene> {
    if !(16..=4096).contains(&size) {
        return Err(PyValueError::new_err(format!(
            "size = {size}: give a sensor side of 16 to 4096 pixels"
        )));
    }
    let noise = match noise {
        "realistic" => Noise::Realistic,
        "eight-bit" => Noise::EightBit,
        "none" => Noise::None,
        other => {
            return Err(PyValueError::new_err(format!(
                "noise = '{other}': give 'realistic', 'eight-bit' or 'none'"
            )))
        }
    };
    let (dx, dy, theta, h) = placement;
    if !(h.is_finite() && h > 0.0) {
        return Err(PyValueError::new_err(format!(
            "height_mm = {h}: give a positive distance"
        )));
    }
    Ok(Scene {
        truth: Scene::placed(dx, dy, theta, h).tilted(tilt_deg.0, tilt_deg.1),
        noise,
        size,
        seed,
        stray_light,
    })
}

/// `sample = "…"` as the simulator's sample kind.
fn sample_kind(sample: &str) -> PyResult<SampleKind> {
    serde_json::from_value(serde_json::json!(sample)).map_err(|_| {
        PyValueError::new_err(format!(
            "sample = '{sample}': give 'cells', 'weak-phase' or 'stained'"
        ))
    })
}

/// The dataset written into `out`, loaded, and its truth as a dict.
fn loaded<'py>(
    py: Python<'py>,
    out: &std::path::Path,
    written: Written,
) -> PyResult<(Dataset, Bound<'py, PyAny>)> {
    let ds = Dataset {
        inner: fpm_host::dataset::Dataset::load(out).map_err(crate::convert::dataset_error)?,
    };
    Ok((ds, to_py(py, &written.truth)?))
}

/// Simulate a full acquisition (every LED, in focus, of a complex test sample) with
/// the LED array really at (dx_mm, dy_mm, theta_deg, height_mm) and tilted by
/// `tilt_deg`, while the dataset states the nominal array. Written into `out`
/// (dataset.toml, frames/, truth.json, truth_amplitude.tif, truth_phase.tif);
/// returns (Dataset, truth dict). `entrance_pupil_mm`: image through an objective
/// that is not telecentric (the dataset cannot state it; the truth does). `sample`:
/// "cells" (absorbing and phase cells with bar groups), "weak-phase" (unstained
/// cells) or "stained" (dense, strongly absorbing). `multiplex`, `multiplex_bright`:
/// dark-field and bright-field LEDs lit together in each frame (`fpm simulate
/// acquisition --multiplex --multiplex-bright`).
#[pyfunction]
#[pyo3(signature = (out, *, size = 256, seed = 1, dx_mm = 1.0, dy_mm = 1.0, theta_deg = 5.0, height_mm = 92.0, tilt_deg = (0.0, 0.0), noise = "realistic", stray_light = 0.0, upsample = 2, dark_field_peak_dn = None, led_jitter_mm = 0.0, entrance_pupil_mm = None, display_gamma = None, sample = "cells", multiplex = 1, multiplex_bright = 1))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments, one parameter each
pub fn simulate_acquisition<'py>(
    py: Python<'py>,
    out: PathBuf,
    size: usize,
    seed: u64,
    dx_mm: f64,
    dy_mm: f64,
    theta_deg: f64,
    height_mm: f64,
    tilt_deg: (f64, f64),
    noise: &str,
    stray_light: f64,
    upsample: usize,
    dark_field_peak_dn: Option<f64>,
    led_jitter_mm: f64,
    entrance_pupil_mm: Option<f64>,
    display_gamma: Option<f64>,
    sample: &str,
    multiplex: usize,
    multiplex_bright: usize,
) -> PyResult<(Dataset, Bound<'py, PyAny>)> {
    let entrance_pupil_mm = entrance_pupil(entrance_pupil_mm)?;
    let sample = sample_kind(sample)?;
    if let Some(g) = display_gamma.filter(|g| !CameraSection::is_valid_gamma(*g)) {
        return Err(PyValueError::new_err(format!(
            "display_gamma: {g} is not an exponent above 0 and at most 5 (2.2 for sRGB-like images)"
        )));
    }
    let scene = scene(
        size,
        seed,
        (dx_mm, dy_mm, theta_deg, height_mm),
        tilt_deg,
        noise,
        stray_light,
    )?;
    let set = AcquisitionSet {
        upsample: upsample.max(1),
        dark_field_peak_dn,
        led_jitter_mm,
        entrance_pupil_mm,
        display_gamma,
        sample,
        multiplex: fpm_physics::multiplex::Multiplex {
            dark_field: multiplex,
            bright_field: multiplex_bright,
        },
    };
    let written = py
        .detach(|| simulation::write_acquisition(&scene, &set, &out))
        .map_err(failed)?;
    loaded(py, &out, written)
}

/// Simulate a pdcFPM calibration set (an in-focus reference and defocused frames of
/// the LEDs around the centre, of a square hole `feature_um` wide at `feature_at_um`)
/// with the array really at (dx_mm, dy_mm, theta_deg, height_mm), each LED moved off
/// its grid by its own draw of σ `led_jitter_mm` per axis (a hand-built board; the
/// truth dict's `leds` lists where they were). Written into `out`; returns (Dataset,
/// truth dict).
#[pyfunction]
#[pyo3(signature = (out, *, size = 256, seed = 1, dx_mm = 1.0, dy_mm = 1.0, theta_deg = 5.0, height_mm = 92.0, tilt_deg = (0.0, 0.0), noise = "realistic", stray_light = 0.0, defocus_um = 200.0, feature_um = 50.0, feature_at_um = (0.0, 0.0), led_jitter_mm = 0.0))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments, one parameter each
pub fn simulate_calibration<'py>(
    py: Python<'py>,
    out: PathBuf,
    size: usize,
    seed: u64,
    dx_mm: f64,
    dy_mm: f64,
    theta_deg: f64,
    height_mm: f64,
    tilt_deg: (f64, f64),
    noise: &str,
    stray_light: f64,
    defocus_um: f64,
    feature_um: f64,
    feature_at_um: (f64, f64),
    led_jitter_mm: f64,
) -> PyResult<(Dataset, Bound<'py, PyAny>)> {
    let scene = scene(
        size,
        seed,
        (dx_mm, dy_mm, theta_deg, height_mm),
        tilt_deg,
        noise,
        stray_light,
    )?;
    let set = CalibrationSet {
        defocus_um,
        feature_um,
        feature_at_um,
        led_jitter_mm,
    };
    let written = py
        .detach(|| simulation::write_calibration_set(&scene, &set, &out))
        .map_err(failed)?;
    loaded(py, &out, written)
}

/// Simulate a colour acquisition (`fpm simulate acquisition --colors`): a whole scan
/// per colour of `colors` (red, green, blue: the WS2812B's wavelengths, spectra, dies
/// and focal shifts, `fpm_physics::color::ws2812b`), each written into `out/<colour>/`
/// with its truth, joined by `out/dataset.toml`. `die_offset_mm`: {colour: (x, y)} in
/// the board's axes, mm; `focal_shift_um`: {colour: µm}; `spectral_samples`:
/// wavelengths rendered per colour. Returns (the colour dataset's directory,
/// {colour: truth dict}); `fpm.reconstruct(path)` reconstructs it.
#[pyfunction]
#[pyo3(signature = (out, *, colors = vec!["red".to_string(), "green".to_string(), "blue".to_string()], die_offset_mm = None, focal_shift_um = None, spectral_samples = 5, size = 128, seed = 1, dx_mm = 0.0, dy_mm = 0.0, theta_deg = 0.0, height_mm = 92.0, noise = "realistic", sample = "cells"))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments, one parameter each
pub fn simulate_color_acquisition<'py>(
    py: Python<'py>,
    out: PathBuf,
    colors: Vec<String>,
    die_offset_mm: Option<std::collections::HashMap<String, (f64, f64)>>,
    focal_shift_um: Option<std::collections::HashMap<String, f64>>,
    spectral_samples: usize,
    size: usize,
    seed: u64,
    dx_mm: f64,
    dy_mm: f64,
    theta_deg: f64,
    height_mm: f64,
    noise: &str,
    sample: &str,
) -> PyResult<(PathBuf, Bound<'py, PyAny>)> {
    let sample = sample_kind(sample)?;
    let mut channels = fpm_physics::color::parse_channels(&colors, "colors")
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    for c in &mut channels {
        if let Some((x, y)) = die_offset_mm.as_ref().and_then(|m| m.get(&c.name)) {
            c.die_offset_mm = [*x, *y];
        }
        if let Some(f) = focal_shift_um.as_ref().and_then(|m| m.get(&c.name)) {
            c.focal_shift_um = *f;
        }
    }
    for (what, keys) in [
        (
            "die_offset_mm",
            die_offset_mm
                .as_ref()
                .map(|m| m.keys().cloned().collect::<Vec<_>>()),
        ),
        (
            "focal_shift_um",
            focal_shift_um.as_ref().map(|m| m.keys().cloned().collect()),
        ),
    ] {
        if let Some(k) = keys
            .unwrap_or_default()
            .iter()
            .find(|k| !channels.iter().any(|c| &c.name == *k))
        {
            return Err(PyValueError::new_err(format!(
                "{what}: '{k}' is not one of colors"
            )));
        }
    }
    let scene = scene(
        size,
        seed,
        (dx_mm, dy_mm, theta_deg, height_mm),
        (0.0, 0.0),
        noise,
        0.0,
    )?;
    let set = AcquisitionSet {
        sample,
        ..AcquisitionSet::default()
    };
    let color = simulation::ColorSet {
        channels,
        spectral_samples,
    };
    let written = py
        .detach(|| simulation::write_color_acquisition(&scene, &set, &color, &out))
        .map_err(failed)?;
    let truths: std::collections::BTreeMap<String, _> =
        written.into_iter().map(|(n, w)| (n, w.truth)).collect();
    Ok((out, to_py(py, &truths)?))
}
