//! What `fpm.reconstruct` returns (`fpm.Result`) and how it is saved: shared by the
//! single-wavelength run (reconstruct.rs) and each channel of a colour one (color.rs),
//! which dispatches no further, so neither imports the other.

use std::path::PathBuf;

use fpm_host::dataset::image_io::TiffOptions;
use fpm_host::reconstruction::{write_outputs_with, ImageFormat, OutputOptions};
use numpy::{IntoPyArray, PyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{failed, to_py};

/// A reconstruction: the high-resolution object (amplitude, phase, complex), the
/// recovered pupil, and the report (report.json as a dict).
#[pyclass(frozen, module = "fpm", name = "Result")]
pub struct Reconstruction {
    pub(crate) inner: fpm_host::reconstruction::Reconstruction,
}

#[pymethods]
impl Reconstruction {
    /// |object|, float32, on the reconstructed grid.
    #[getter]
    fn amplitude<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        self.inner.object.mapv(|c| c.norm()).into_pyarray(py)
    }
    /// arg(object), radians, float32.
    #[getter]
    fn phase<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        self.inner.object.mapv(|c| c.arg()).into_pyarray(py)
    }
    /// The complex object, complex64.
    #[getter]
    fn object<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<numpy::Complex32>> {
        self.inner.object.clone().into_pyarray(py)
    }
    /// The recovered pupil (the central tile's), complex64, in the Fourier plane.
    #[getter]
    fn pupil<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<numpy::Complex32>> {
        self.inner.pupil.clone().into_pyarray(py)
    }
    /// The reconstructed grid's pixel at the sample, µm.
    #[getter]
    fn pixel_um(&self) -> f64 {
        self.inner.report.pixel_um
    }
    /// Everything, as in report.json (timings, tiles, errors per pass, refined LEDs,
    /// scores against a simulation's truth when the dataset has one, warnings).
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let json = fpm_host::reconstruction::report_json(&self.inner.report).map_err(failed)?;
        to_py(py, &json)
    }
    /// What a user must know before trusting the images, each with the action that
    /// applies (report.json's `warnings` has each one's check name too).
    #[getter]
    fn warnings(&self) -> Vec<String> {
        fpm_host::reconstruction::warnings(&self.inner.report)
    }
    /// Write amplitude/phase as OME-TIFF (`format="tiff"`: float32, the pixel size
    /// in µm in their OME-XML; deflate-compressed with `compress`) or as one OME-Zarr
    /// pyramid (`format="ome-zarr"`: image.ome.zarr), pupil TIFFs, PNG previews and
    /// report.json into `dir`, as `fpm reconstruct` does.
    #[pyo3(signature = (dir, *, format = "tiff", compress = false))]
    fn save(&self, py: Python<'_>, dir: PathBuf, format: &str, compress: bool) -> PyResult<()> {
        let options = output_options(format, compress)?;
        py.detach(|| {
            write_outputs_with(&self.inner, &dir, options)?;
            fpm_report::preview::reconstruction(&self.inner, &dir)
        })
        .map_err(failed)
    }

    fn __repr__(&self) -> String {
        let (h, w) = self.inner.object.dim();
        let r = &self.inner.report;
        format!(
            "Result({w}x{h} at {:.3} µm, {} frames, {} passes, {} tile(s))",
            r.pixel_um,
            r.frames,
            r.passes,
            r.tiles.len()
        )
    }
}

/// How `save(format=, compress=)` writes the images.
pub(crate) fn output_options(format: &str, compress: bool) -> PyResult<OutputOptions> {
    let format = match format {
        "tiff" => ImageFormat::Tiff,
        "ome-zarr" => ImageFormat::OmeZarr,
        other => {
            return Err(PyValueError::new_err(format!(
                "format = '{other}': give 'tiff' or 'ome-zarr'"
            )))
        }
    };
    let tiff = TiffOptions {
        compress,
        ..TiffOptions::default()
    };
    Ok(OutputOptions { format, tiff })
}
