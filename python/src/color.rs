//! Colour datasets from Python: `fpm.reconstruct` of a colour dataset's directory gives
//! a `ColorResult` (every channel's own `Result`, the registered channels as arrays, an
//! sRGB preview), and `fpm.simulate_color_acquisition` makes one, as `fpm reconstruct`
//! and `fpm simulate acquisition --colors` do.

use std::collections::HashMap;
use std::path::PathBuf;

use fpm_host::color::{ColorDataset, ColorGeometry, ColorRun};
use fpm_host::reconstruction::Job;
use ndarray::{Array2, Array3, Axis};
use numpy::{IntoPyArray, PyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{failed, to_py, Progress};
use crate::result::{output_options, Reconstruction};

/// A colour reconstruction: each channel reconstructed with its own wavelength, LEDs
/// and pupil, then registered to the reference channel.
#[pyclass(frozen, module = "fpm", name = "ColorResult")]
pub struct ColorResult {
    pub(crate) inner: ColorRun,
}

impl ColorResult {
    fn stack(&self, f: impl Fn(&numpy::Complex32) -> f32) -> Array3<f32> {
        let planes: Vec<Array2<f32>> = self
            .inner
            .channels
            .iter()
            .map(|c| c.registered.map(&f))
            .collect();
        let views: Vec<_> = planes.iter().map(|p| p.view()).collect();
        ndarray::stack(Axis(0), &views).unwrap_or_else(|_| Array3::zeros((0, 0, 0)))
    }
}

#[pymethods]
impl ColorResult {
    /// The channels' names, in the dataset's order.
    #[getter]
    fn names(&self) -> Vec<String> {
        self.inner.channels.iter().map(|c| c.name.clone()).collect()
    }
    /// Their wavelengths, µm.
    #[getter]
    fn wavelengths_um(&self) -> Vec<f64> {
        self.inner
            .report
            .channels
            .iter()
            .map(|c| c.wavelength_um)
            .collect()
    }
    /// Each channel's own reconstruction (before registration), by name.
    #[getter]
    fn channels(&self) -> HashMap<String, Reconstruction> {
        self.inner
            .channels
            .iter()
            .map(|c| {
                (
                    c.name.clone(),
                    Reconstruction {
                        inner: c.finished.reconstruction.clone(),
                    },
                )
            })
            .collect()
    }
    /// |object| of every channel, registered: float32, (channel, y, x).
    #[getter]
    fn amplitude<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f32>> {
        self.stack(|z| z.norm()).into_pyarray(py)
    }
    /// arg(object) of every channel, registered, radians: float32, (channel, y, x).
    #[getter]
    fn phase<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f32>> {
        self.stack(|z| z.arg()).into_pyarray(py)
    }
    /// The sRGB preview (each channel's |t|² over its clear background's, in the
    /// primary its wavelength is nearest): uint8, (y, x, 3).
    #[getter]
    fn rgb<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<u8>> {
        let ((h, w), rgb) = self.inner.preview();
        Array3::from_shape_vec((h, w, 3), rgb)
            .unwrap_or_else(|_| Array3::zeros((0, 0, 3)))
            .into_pyarray(py)
    }
    /// The reconstructed grid's pixel at the sample, µm.
    #[getter]
    fn pixel_um(&self) -> f64 {
        self.inner.report.pixel_um
    }
    /// report.json of the colour result (each channel's wavelength, geometry, shift,
    /// clear level, score against a simulation's truth, warnings).
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.inner.report)
    }
    /// What a user must know, each with the action that applies.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.inner.report.all_warnings()
    }
    /// Write the colour result into `dir` as `fpm reconstruct` does: amplitude/phase
    /// with one channel per wavelength (`format="tiff"` or `"ome-zarr"`), color.png,
    /// report.json, and each channel's own outputs in `dir/<name>/`.
    #[pyo3(signature = (dir, *, format = "tiff", compress = false))]
    fn save(&self, py: Python<'_>, dir: PathBuf, format: &str, compress: bool) -> PyResult<()> {
        let options = output_options(format, compress)?;
        py.detach(|| -> anyhow::Result<()> {
            for c in &self.inner.channels {
                let out = dir.join(&c.name);
                fpm_host::reconstruction::write_outputs_with(
                    &c.finished.reconstruction,
                    &out,
                    options,
                )?;
                fpm_report::preview::reconstruction(&c.finished.reconstruction, &out)?;
            }
            fpm_host::color::write_outputs(&self.inner, &dir, options)
        })
        .map_err(failed)
    }

    fn __repr__(&self) -> String {
        format!(
            "ColorResult({} at {:.3} µm)",
            self.names().join(", "),
            self.inner.report.pixel_um
        )
    }
}

/// Reconstruct the colour dataset in `dir` with `job`'s settings; `calibration`: a
/// colour calibration.json (each channel its own placement) or one for every channel.
pub(crate) fn reconstruct(
    py: Python<'_>,
    dir: PathBuf,
    job: Job,
    calibration: Option<PathBuf>,
    progress: &Progress,
) -> PyResult<ColorResult> {
    let geometry = match calibration {
        Some(path) => ColorGeometry::File(path),
        None => ColorGeometry::Nominal,
    };
    let ds = ColorDataset::open(&dir).map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let channels = ds.channels.len();
    let current = std::sync::Mutex::new(String::new());
    let run = py.detach(|| {
        fpm_host::color::reconstruct(&ds, &job, &geometry, &|name, event| {
            if let fpm_host::reconstruction::JobEvent::Updates { done: d, total } = event {
                if let Ok(mut c) = current.lock() {
                    if *c != name {
                        if !c.is_empty() {
                            done.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        }
                        *c = name.to_string();
                    }
                }
                let k = done.load(std::sync::atomic::Ordering::Relaxed);
                progress.report(k * total + d, channels * total);
            }
        })
    });
    Ok(ColorResult {
        inner: run.map_err(failed)?,
    })
}
