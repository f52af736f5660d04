//! # fpm (Python)
//!
//! The native module of the `fpm` Python package (`import fpm`): datasets, pdcFPM
//! calibration, EPRY reconstruction and simulated datasets, from the same crates as
//! the `fpm` command (`fpm-host`, `fpm-physics`), so Python and the CLI give the same
//! numbers. The Python side (`python/fpm/`) re-exports it with docstrings and stubs.

use pyo3::prelude::*;

mod calibrate;
mod color;
mod convert;
mod dataset;
mod dpc;
mod reconstruct;
mod result;
mod simulate;
mod streaming;

/// The reconstruction's defaults as Python's signatures state them (`upsample = 4`, …,
/// in reconstruct.rs and streaming.rs): a default changed in the library fails this
/// build until the signatures follow. That the signatures say these numbers is checked
/// by pytest (test_the_defaults_are_the_librarys_and_its_limits_are_enforced).
const _: () = {
    use fpm_physics::reconstruct::defaults;
    assert!(defaults::UPSAMPLE == 4);
    assert!(defaults::PASSES == 10);
    assert!(defaults::FLOOR_SIGMA == 3.0);
    assert!(defaults::NOISE_BAND_SIGMA == 7.5);
};

/// `RECONSTRUCT_DEFAULTS` and `RECONSTRUCT_LIMITS` (inclusive `(low, high)` ranges):
/// the library's, for Python code that offers the settings (the napari widget).
fn add_reconstruct_settings(m: &Bound<'_, PyModule>) -> PyResult<()> {
    use fpm_physics::reconstruct::{defaults, limits};
    let py = m.py();
    let d = pyo3::types::PyDict::new(py);
    d.set_item("upsample", defaults::UPSAMPLE)?;
    d.set_item("passes", defaults::PASSES)?;
    d.set_item("floor_sigma", defaults::FLOOR_SIGMA)?;
    d.set_item("noise_band_sigma", defaults::NOISE_BAND_SIGMA)?;
    m.add("RECONSTRUCT_DEFAULTS", d)?;
    let l = pyo3::types::PyDict::new(py);
    let range = |r: std::ops::RangeInclusive<usize>| (*r.start(), *r.end());
    l.set_item("upsample", range(limits::UPSAMPLE))?;
    l.set_item("passes", range(limits::PASSES))?;
    l.set_item("tile", range(limits::TILE))?;
    m.add("RECONSTRUCT_LIMITS", l)?;
    Ok(())
}

#[pymodule]
fn _fpm(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("FpmError", py.get_type::<convert::FpmError>())?;
    m.add("DatasetError", py.get_type::<convert::DatasetError>())?;
    add_reconstruct_settings(m)?;
    m.add_class::<dataset::Dataset>()?;
    m.add_class::<calibrate::Calibration>()?;
    m.add_class::<result::Reconstruction>()?;
    m.add_class::<color::ColorResult>()?;
    m.add_class::<streaming::Streaming>()?;
    m.add_function(wrap_pyfunction!(calibrate::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct::reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(dpc::dpc, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::simulate_acquisition, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::simulate_calibration, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::simulate_color_acquisition, m)?)?;
    Ok(())
}
