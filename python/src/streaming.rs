//! `fpm.Streaming`: EPRY fed frame by frame while an acquisition runs (frames pushed
//! as NumPy arrays from a camera loop), a snapshot at any time, and the same finish as
//! an offline run.

use std::time::Instant;

use fpm_host::dataset::Pixels;
use fpm_host::reconstruction::Report;
use fpm_physics::frame::{LitFrame, Measured, Response};
use fpm_physics::reconstruct::{Settings, TiledStreaming};
use fpm_physics::{LedGeometry, LedIndex, System};
use numpy::{IntoPyArray, PyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{from_py, system_from_py, FpmError, Progress};
use crate::dataset::pixels;
use crate::reconstruct::settings;
use crate::result::Reconstruction;

/// A frame kept for the finish: its LED, counts and exposure.
struct Kept {
    led: LedIndex,
    counts: Pixels,
    exposure_ms: f32,
}

/// A reconstruction that takes frames as they are taken.
#[pyclass(module = "fpm")]
pub struct Streaming {
    system: System,
    geometry: LedGeometry,
    settings: Settings,
    dark_level: f32,
    size: (usize, usize),
    /// None once finished.
    stream: Option<TiledStreaming>,
    frames: Vec<Kept>,
    started: Instant,
}

impl Kept {
    fn lit(&self, dark_level: f32) -> LitFrame<'_> {
        LitFrame {
            also: &[],
            led: self.led,
            measured: Measured {
                counts: self.counts.view(),
                response: Response::Linear,
                dark_level,
                exposure_ms: self.exposure_ms,
                floor: 0.0,
                soft_floor: false,
                band: 0.0,
            },
        }
    }
}

#[pymethods]
impl Streaming {
    /// A stream for `width` × `height` frames of a microscope (`system`, a dict, with
    /// `entrance_pupil_mm` for an objective that is not telecentric) with
    /// the LED array `geometry` (a dict, e.g. `Calibration.geometry`), cut into tiles
    /// as `reconstruct` cuts them; `dark_level` is the camera's offset in counts.
    #[new]
    #[pyo3(signature = (system, geometry, width, height, *, tile = None, upsample = 4, dark_level = 0.0, fixed_pupil = false, background = "per-frame", floor = "soft", floor_sigma = 3.0, noise_band_sigma = 7.5, flatten_background = false, background_block_um = None))]
    #[allow(clippy::too_many_arguments)] // Python keyword arguments, one parameter each
    fn new(
        system: &Bound<'_, PyAny>,
        geometry: &Bound<'_, PyAny>,
        width: usize,
        height: usize,
        tile: Option<usize>,
        upsample: usize,
        dark_level: f32,
        fixed_pupil: bool,
        background: &str,
        floor: &str,
        floor_sigma: f32,
        noise_band_sigma: f32,
        flatten_background: bool,
        background_block_um: Option<f64>,
    ) -> PyResult<Self> {
        let system = system_from_py(system)?;
        let geometry: LedGeometry = from_py(geometry, "geometry")?;
        if width < 16 || height < 16 {
            return Err(PyValueError::new_err(format!(
                "{width}x{height}: frames need at least 16 pixels a side"
            )));
        }
        let settings = settings(
            upsample,
            fixed_pupil,
            background,
            floor,
            floor_sigma,
            noise_band_sigma,
            flatten_background,
            background_block_um,
        )?;
        Ok(Self {
            system,
            geometry,
            settings,
            dark_level,
            size: (height, width),
            stream: Some(TiledStreaming::new(
                system, geometry, settings, width, height, tile,
            )),
            frames: vec![],
            started: Instant::now(),
        })
    }

    /// A frame taken under LED `led` = (row, col) with `exposure_ms`: the estimate is
    /// updated at once (the stream keeps a copy of the frame for the finish).
    #[pyo3(signature = (led, frame, exposure_ms = 1.0))]
    fn push(
        &mut self,
        py: Python<'_>,
        led: (u8, u8),
        frame: &Bound<'_, PyAny>,
        exposure_ms: f32,
    ) -> PyResult<()> {
        let index = self.frames.len();
        let led = LedIndex::new(led.0, led.1);
        if led.r() >= self.geometry.rows || led.c() >= self.geometry.cols {
            return Err(PyValueError::new_err(format!(
                "frame {index}: LED ({}, {}) is not on the {}x{} array",
                led.row, led.col, self.geometry.rows, self.geometry.cols
            )));
        }
        if !(exposure_ms.is_finite() && exposure_ms > 0.0) {
            return Err(PyValueError::new_err(format!(
                "frame {index}: exposure_ms = {exposure_ms}: give a positive time"
            )));
        }
        let counts = pixels(frame, index)?;
        if counts.dim() != self.size {
            return Err(PyValueError::new_err(format!(
                "frame {index} (LED ({}, {})): {:?} (rows, cols), the stream takes {:?}",
                led.row,
                led.col,
                counts.dim(),
                self.size
            )));
        }
        let kept = Kept {
            led,
            counts,
            exposure_ms,
        };
        let dark = self.dark_level;
        let stream = self
            .stream
            .as_mut()
            .ok_or_else(|| FpmError::new_err("the stream is finished"))?;
        py.detach(|| stream.push(&kept.lit(dark)))
            .map_err(|e| FpmError::new_err(e.to_string()))?;
        self.frames.push(kept);
        Ok(())
    }

    /// Frames received.
    #[getter]
    fn received(&self) -> usize {
        self.frames.len()
    }

    /// The sample as it stands, complex64 (None until every tile has seen a
    /// bright-field frame).
    fn snapshot<'py>(
        &mut self,
        py: Python<'py>,
    ) -> PyResult<Option<Bound<'py, PyArray2<numpy::Complex32>>>> {
        let stream = self
            .stream
            .as_mut()
            .ok_or_else(|| FpmError::new_err("the stream is finished"))?;
        Ok(py
            .detach(|| stream.snapshot())
            .map(|object| object.into_pyarray(py)))
    }

    /// Run `passes` more passes over every frame received, as `reconstruct` does, and
    /// return the Result. The stream cannot take frames afterwards.
    #[pyo3(signature = (passes = 10, progress = None))]
    fn finish(
        &mut self,
        py: Python<'_>,
        passes: usize,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<Reconstruction> {
        let stream = self
            .stream
            .take()
            .ok_or_else(|| FpmError::new_err("the stream is finished"))?;
        let progress = Progress::new(progress);
        let dark = self.dark_level;
        let lit: Vec<LitFrame<'_>> = self.frames.iter().map(|k| k.lit(dark)).collect();
        let outcome =
            py.detach(|| stream.finish(&lit, passes, &|done, total| progress.report(done, total)));
        progress.finish()?;
        let outcome = outcome.map_err(|e| FpmError::new_err(e.to_string()))?;
        let source = fpm_host::calibration::GeometrySource::Given("given to fpm.Streaming".into());
        let request = fpm_host::reconstruction::Request {
            geometry: &self.geometry,
            source: &source,
            settings: self.settings,
            passes,
            tile: None,
        };
        let report = Report::new(
            std::path::Path::new("(streamed)"),
            &self.system,
            &request,
            lit.len(),
            &outcome,
            self.started.elapsed().as_secs_f64() * 1e3,
        );
        Ok(Reconstruction {
            inner: fpm_host::reconstruction::Reconstruction::from_outcome(outcome, report),
        })
    }
}
