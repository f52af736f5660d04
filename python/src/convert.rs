//! What crosses between Rust and Python: errors as Python exceptions that name the
//! file, key or frame, JSON-shaped values as dicts and lists, and progress callbacks
//! called from the reconstruction's worker threads.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use serde::de::DeserializeOwned;
use serde::Serialize;

pyo3::create_exception!(
    fpm,
    FpmError,
    PyRuntimeError,
    "A calibration or reconstruction failed; the message says what and where."
);
pyo3::create_exception!(
    fpm,
    DatasetError,
    PyValueError,
    "A dataset is wrong: the message names the file, key or frame."
);

/// A dataset's own error, as [`DatasetError`].
pub fn dataset_error(e: fpm_host::dataset::DatasetError) -> PyErr {
    DatasetError::new_err(e.to_string())
}

/// A failed calibration or reconstruction, as [`FpmError`] with its whole context.
pub fn failed(e: anyhow::Error) -> PyErr {
    FpmError::new_err(format!("{e:#}"))
}

/// `value` as Python's `json.loads` reads it (dicts, lists, floats; NaN as None).
pub fn to_py<'py>(py: Python<'py>, value: &impl Serialize) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value).map_err(|e| FpmError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// `entrance_pupil_mm` as given by a keyword: None (telecentric) or a positive,
/// finite distance; anything else is refused by name.
pub fn entrance_pupil(entrance_pupil_mm: Option<f64>) -> PyResult<Option<f64>> {
    match entrance_pupil_mm {
        Some(p) if !(p.is_finite() && p > 0.0) => Err(PyValueError::new_err(format!(
            "entrance_pupil_mm: {p} is not a positive distance in mm"
        ))),
        other => Ok(other),
    }
}

/// A `system` dict read as the microscope, with `entrance_pupil_mm` checked as the
/// keyword of the same name is ([`entrance_pupil`]).
pub fn system_from_py(value: &Bound<'_, PyAny>) -> PyResult<fpm_physics::System> {
    let system: fpm_physics::System = from_py(value, "system")?;
    Ok(fpm_physics::System {
        entrance_pupil_mm: entrance_pupil(system.entrance_pupil_mm)?,
        ..system
    })
}

/// A Python value (a dict, say) read as `T`; `what` names it in the error.
pub fn from_py<T: DeserializeOwned>(value: &Bound<'_, PyAny>, what: &str) -> PyResult<T> {
    let text: String = value
        .py()
        .import("json")?
        .call_method1("dumps", (value,))
        .map_err(|e| PyValueError::new_err(format!("{what}: {e}")))?
        .extract()?;
    serde_json::from_str(&text).map_err(|e| PyValueError::new_err(format!("{what}: {e}")))
}

/// A Python progress callback `progress(done, total)`, called from any thread (the
/// GIL taken for the call) at most once per 0.1 % of the work; the first exception
/// it raises is kept and raised when the work is done.
pub struct Progress {
    callback: Option<Py<PyAny>>,
    permille: AtomicUsize,
    raised: Mutex<Option<PyErr>>,
}

impl Progress {
    /// Wrap `callback` (None: no progress reported).
    pub fn new(callback: Option<Py<PyAny>>) -> Self {
        Self {
            callback,
            permille: AtomicUsize::new(0),
            raised: Mutex::new(None),
        }
    }

    /// `done` of `total` work items are done.
    pub fn report(&self, done: usize, total: usize) {
        let Some(callback) = &self.callback else {
            return;
        };
        let permille = (done * 1000).checked_div(total).unwrap_or(1000);
        let finished = done >= total;
        if self.permille.fetch_max(permille, Ordering::Relaxed) >= permille && !finished {
            return;
        }
        Python::attach(|py| {
            if let Err(e) = callback.call1(py, (done, total)) {
                if let Ok(mut raised) = self.raised.lock() {
                    raised.get_or_insert(e);
                }
            }
        });
    }

    /// The first exception the callback raised, if any.
    pub fn finish(self) -> PyResult<()> {
        match self.raised.into_inner().ok().flatten() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}
