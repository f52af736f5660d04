//! `fpm.dpc`: a weak object's phase and absorption from the four half-circle patterns
//! of a dataset's bright-field frames, as `fpm dpc` computes them.

use fpm_physics::dpc::Regularisation;
use numpy::{IntoPyArray, PyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{failed, to_py};
use crate::dataset::Dataset;

/// DPC of `dataset`: (phase in radians, absorption μ, report dict), the images on the
/// frames' grid with their means removed. `reg_phase` and `reg_absorption` are the
/// Tikhonov weights (default 1e-3). The report's `warnings` say when the sample is
/// not weak enough for the numbers to mean phase.
#[pyfunction]
#[pyo3(signature = (dataset, reg_phase = None, reg_absorption = None))]
#[allow(clippy::type_complexity)] // the Python tuple it returns
pub fn dpc<'py>(
    py: Python<'py>,
    dataset: &Dataset,
    reg_phase: Option<f64>,
    reg_absorption: Option<f64>,
) -> PyResult<(
    Bound<'py, PyArray2<f32>>,
    Bound<'py, PyArray2<f32>>,
    Bound<'py, PyAny>,
)> {
    let defaults = Regularisation::default();
    let reg = Regularisation {
        phase: reg_phase.unwrap_or(defaults.phase),
        absorption: reg_absorption.unwrap_or(defaults.absorption),
    };
    for (name, v) in [("reg_phase", reg.phase), ("reg_absorption", reg.absorption)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(PyValueError::new_err(format!(
                "{name} = {v}: give a positive weight (default 0.001)"
            )));
        }
    }
    let result = py
        .detach(|| fpm_host::dpc::dpc_of(&dataset.inner, reg))
        .map_err(failed)?;
    let report = to_py(py, &result.report)?;
    Ok((
        result.object.phase.into_pyarray(py),
        result.object.absorption.into_pyarray(py),
        report,
    ))
}
