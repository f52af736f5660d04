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
mod simulate;
mod streaming;

#[pymodule]
fn _fpm(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("FpmError", py.get_type::<convert::FpmError>())?;
    m.add("DatasetError", py.get_type::<convert::DatasetError>())?;
    m.add_class::<dataset::Dataset>()?;
    m.add_class::<calibrate::Calibration>()?;
    m.add_class::<reconstruct::Reconstruction>()?;
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
