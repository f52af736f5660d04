//! `fpm.simulate_acquisition` / `fpm.simulate_calibration`: datasets from the full
//! wave-optics model, written to disk with their truth, as `fpm simulate` makes them.

use fpm_physics::simulate::SampleKind;
use std::path::PathBuf;

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
    let sample: SampleKind = serde_json::from_value(serde_json::json!(sample)).map_err(|_| {
        PyValueError::new_err(format!(
            "sample = '{sample}': give 'cells', 'weak-phase' or 'stained'"
        ))
    })?;
    if let Some(g) = display_gamma.filter(|g| !(g.is_finite() && *g > 0.0 && *g <= 5.0)) {
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
/// with the array really at (dx_mm, dy_mm, theta_deg, height_mm). Written into `out`;
/// returns (Dataset, truth dict).
#[pyfunction]
#[pyo3(signature = (out, *, size = 256, seed = 1, dx_mm = 1.0, dy_mm = 1.0, theta_deg = 5.0, height_mm = 92.0, tilt_deg = (0.0, 0.0), noise = "realistic", stray_light = 0.0, defocus_um = 200.0, feature_um = 50.0, feature_at_um = (0.0, 0.0)))]
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
    };
    let written = py
        .detach(|| simulation::write_calibration_set(&scene, &set, &out))
        .map_err(failed)?;
    loaded(py, &out, written)
}
