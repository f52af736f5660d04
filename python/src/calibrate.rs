//! `fpm.calibrate`: pdcFPM calibration of the LED array from a defocus dataset, with
//! every value's 1σ and the warnings a user must see.

use std::path::PathBuf;

use fpm_host::calibration::{calibrate_dataset, warnings, CalibrationFile};
use fpm_physics::calibrate::feature::Roi;
use fpm_physics::calibrate::{Options, DEFAULT_DEFOCUS_SIGMA_UM};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{failed, to_py, FpmError};
use crate::dataset::Dataset;

/// A calibrated LED array: Δx, Δy (mm), θ (°), h (mm) and the board's tilt, each
/// with its 1σ in `uncertainty`, the per-LED shifts and residuals in `leds`, and
/// `warnings` where the numbers cannot be trusted.
#[pyclass(frozen, module = "fpm")]
pub struct Calibration {
    pub file: CalibrationFile,
}

#[pymethods]
impl Calibration {
    /// Δx of the array, mm.
    #[getter]
    fn dx_mm(&self) -> f64 {
        self.file.calibration.placement.dx_mm
    }
    /// Δy of the array, mm.
    #[getter]
    fn dy_mm(&self) -> f64 {
        self.file.calibration.placement.dy_mm
    }
    /// Rotation θ, degrees.
    #[getter]
    fn theta_deg(&self) -> f64 {
        self.file.calibration.placement.theta_deg
    }
    /// LED-to-sample distance h, mm.
    #[getter]
    fn height_mm(&self) -> f64 {
        self.file.calibration.placement.height_mm
    }
    /// The board's tilt about x and y, degrees (0 where not observable).
    #[getter]
    fn tilt_deg(&self) -> (f64, f64) {
        let c = &self.file.calibration;
        (c.placement.tilt_x_deg, c.placement.tilt_y_deg)
    }
    /// Whether the data determine the tilt.
    #[getter]
    fn tilt_observable(&self) -> bool {
        self.file.calibration.tilt_observable
    }
    /// 1σ of every value (dx_mm, dy_mm, theta_deg, height_mm, tilt_x_deg, tilt_y_deg).
    #[getter]
    fn uncertainty<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.file.calibration.uncertainty)
    }
    /// Per LED: its status, measured and fitted shifts, residual.
    #[getter]
    fn leds<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.file.calibration.leds)
    }
    /// What a user must know before trusting the numbers (empty when all is well).
    #[getter]
    fn warnings(&self) -> Vec<String> {
        warnings(&self.file.calibration)
    }
    /// The calibrated geometry, as a dict that `reconstruct(geometry=...)` and
    /// `Dataset.from_arrays` take.
    #[getter]
    fn geometry<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.file.geometry())
    }
    /// Everything, as in calibration.json.
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.file)
    }
    /// How long the calibration took, ms.
    #[getter]
    fn time_ms(&self) -> f64 {
        self.file.time_ms
    }
    /// Write calibration.json (readable by `fpm reconstruct --calibration`).
    fn save(&self, path: PathBuf) -> PyResult<()> {
        let text = serde_json::to_string_pretty(&self.file)
            .map_err(|e| FpmError::new_err(e.to_string()))?;
        std::fs::write(&path, text)
            .map_err(|e| FpmError::new_err(format!("writing {}: {e}", path.display())))
    }

    fn __repr__(&self) -> String {
        let c = &self.file.calibration;
        let u = &c.uncertainty;
        format!(
            "Calibration(dx_mm={:.4}±{:.4}, dy_mm={:.4}±{:.4}, theta_deg={:.4}±{:.4}, height_mm={:.3}±{:.3}, warnings={})",
            c.placement.dx_mm,
            u.dx_mm,
            c.placement.dy_mm,
            u.dy_mm,
            c.placement.theta_deg,
            u.theta_deg,
            c.placement.height_mm,
            u.height_mm,
            warnings(c).len()
        )
    }
}

/// Calibrate the LED array (pdcFPM) from `dataset`: one in-focus frame under the
/// nominal centre LED and frames of the LEDs around it with the sample defocused.
///
/// `roi` = (x, y, w, h) limits the search for the feature; `defocus_sigma_um` is the
/// stage's 1σ. Raises FpmError when the frames cannot be calibrated.
#[pyfunction]
#[pyo3(signature = (dataset, *, roi = None, defocus_sigma_um = DEFAULT_DEFOCUS_SIGMA_UM, bias_correction = true, fit_tilt = true))]
pub fn calibrate(
    py: Python<'_>,
    dataset: &Bound<'_, Dataset>,
    roi: Option<(usize, usize, usize, usize)>,
    defocus_sigma_um: f64,
    bias_correction: bool,
    fit_tilt: bool,
) -> PyResult<Calibration> {
    if !(defocus_sigma_um.is_finite() && defocus_sigma_um >= 0.0) {
        return Err(PyValueError::new_err(format!(
            "defocus_sigma_um = {defocus_sigma_um}: give a standard deviation (≥ 0)"
        )));
    }
    let roi = match roi {
        Some((_, _, 0, _)) | Some((_, _, _, 0)) => {
            return Err(PyValueError::new_err(
                "roi: (x, y, w, h) with a positive width and height",
            ))
        }
        Some((x, y, w, h)) => Some(Roi { x, y, w, h }),
        None => None,
    };
    let options = Options {
        roi,
        bias_correction,
        defocus_sigma_um,
        fit_tilt,
        ..Options::default()
    };
    let ds = &dataset.get().inner;
    let file = py
        .detach(|| calibrate_dataset(ds, &options))
        .map_err(failed)?;
    Ok(Calibration { file })
}
