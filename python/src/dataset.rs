//! `fpm.Dataset`: a dataset (docs/dataset.md) loaded from disk or made from NumPy
//! arrays. Its frames are read-only NumPy views of the frames in Rust memory.

use std::path::PathBuf;

use fpm_host::dataset::{CameraSection, FrameEntry, Manifest, Pixels};
use fpm_physics::{LedGeometry, LedIndex};
use numpy::{PyArray2, PyReadonlyArray2};
use pyo3::exceptions::{PyIndexError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{dataset_error, from_py, system_from_py, to_py};

/// The `dir` of a dataset made from arrays without one.
const IN_MEMORY: &str = "<in memory>";

/// An FPM dataset: frames, the LED lit for each, the optics and the LED array.
#[pyclass(frozen, module = "fpm")]
pub struct Dataset {
    pub inner: fpm_host::dataset::Dataset,
}

/// `value` as one number per frame: a number for all, or a sequence of `n`.
fn per_frame(value: &Bound<'_, PyAny>, n: usize, name: &str) -> PyResult<Vec<f64>> {
    if let Ok(v) = value.extract::<f64>() {
        return Ok(vec![v; n]);
    }
    let v: Vec<f64> = value
        .extract()
        .map_err(|_| PyValueError::new_err(format!("{name}: give a number or one per frame")))?;
    if v.len() != n {
        return Err(PyValueError::new_err(format!(
            "{name}: {} values for {n} frames",
            v.len()
        )));
    }
    Ok(v)
}

/// Frame `index` as stored pixels: uint8, uint16 and float32 as they are, any other
/// real dtype as float32.
pub(crate) fn pixels(frame: &Bound<'_, PyAny>, index: usize) -> PyResult<Pixels> {
    if let Ok(a) = frame.extract::<PyReadonlyArray2<'_, u16>>() {
        return Ok(Pixels::U16(a.as_array().to_owned()));
    }
    if let Ok(a) = frame.extract::<PyReadonlyArray2<'_, u8>>() {
        return Ok(Pixels::U8(a.as_array().to_owned()));
    }
    let numpy = frame.py().import("numpy")?;
    let floats = numpy
        .call_method1("asarray", (frame, "float32"))
        .map_err(|e| PyValueError::new_err(format!("frames[{index}]: not an image ({e})")))?;
    let a = floats.extract::<PyReadonlyArray2<'_, f32>>().map_err(|_| {
        let shape: Vec<usize> = floats
            .getattr("shape")
            .and_then(|s| s.extract())
            .unwrap_or_default();
        PyValueError::new_err(format!(
            "frames[{index}]: shape {shape:?}: each frame must be a 2-D image"
        ))
    })?;
    Ok(Pixels::F32(a.as_array().to_owned()))
}

#[pymethods]
impl Dataset {
    /// Load and check the dataset in `path` (a directory with dataset.toml).
    ///
    /// Raises DatasetError naming the file, key or frame that is wrong.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let inner = py
            .detach(|| fpm_host::dataset::Dataset::load(&path))
            .map_err(dataset_error)?;
        Ok(Self { inner })
    }

    /// Zheng lab MATLAB data (`fpm import zheng-mat`), written as a dataset in `out`
    /// and loaded. Keywords state what the file does not give (docs/import.md).
    #[staticmethod]
    #[pyo3(signature = (src, out, **stated))]
    fn from_zheng_mat(
        py: Python<'_>,
        src: PathBuf,
        out: PathBuf,
        stated: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        imported(py, fpm_import::Format::ZhengMat, src, out, stated)
    }

    /// Caltech FPM_software MATLAB data (`fpm import caltech-mat`).
    #[staticmethod]
    #[pyo3(signature = (src, out, **stated))]
    fn from_caltech_mat(
        py: Python<'_>,
        src: PathBuf,
        out: PathBuf,
        stated: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        imported(py, fpm_import::Format::CaltechMat, src, out, stated)
    }

    /// PtyLab FPM HDF5 data (`fpm import ptylab-h5`).
    #[staticmethod]
    #[pyo3(signature = (src, out, **stated))]
    fn from_ptylab_h5(
        py: Python<'_>,
        src: PathBuf,
        out: PathBuf,
        stated: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        imported(py, fpm_import::Format::PtylabH5, src, out, stated)
    }

    /// TIFFs and a CSV of LED positions or NAs (`fpm import tiff-csv`).
    #[staticmethod]
    #[pyo3(signature = (src, out, **stated))]
    fn from_tiff_csv(
        py: Python<'_>,
        src: PathBuf,
        out: PathBuf,
        stated: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        imported(py, fpm_import::Format::TiffCsv, src, out, stated)
    }

    /// Where an imported dataset came from: format, path and what the import
    /// assumed (None for fpm's own datasets).
    #[getter]
    fn source<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.inner.manifest.source)
    }

    /// A dataset from arrays in memory: `frames` (a 3-D array or a sequence of 2-D
    /// images in the sample-plane orientation; uint8, uint16 or float), `leds` (the
    /// (row, col) lit for each), `system` and `geometry` as dicts of the dataset's
    /// keys, each frame's exposure (ms) and defocus (µm), the camera's dark level, and
    /// `gamma` for frames saved with a display gamma (needs `bit_depth`).
    #[staticmethod]
    #[pyo3(signature = (frames, leds, system, geometry, exposure_ms = None, defocus_um = None, dark_level = 0.0, bit_depth = None, dir = None, gamma = None))]
    #[allow(clippy::too_many_arguments)] // Python keyword arguments, one parameter each
    fn from_arrays(
        frames: &Bound<'_, PyAny>,
        leds: Vec<(u8, u8)>,
        system: &Bound<'_, PyAny>,
        geometry: &Bound<'_, PyAny>,
        exposure_ms: Option<&Bound<'_, PyAny>>,
        defocus_um: Option<&Bound<'_, PyAny>>,
        dark_level: f64,
        bit_depth: Option<u32>,
        dir: Option<PathBuf>,
        gamma: Option<f64>,
    ) -> PyResult<Self> {
        let system = system_from_py(system)?;
        let geometry: LedGeometry = from_py(geometry, "geometry")?;
        let images: Vec<Pixels> = frames
            .try_iter()?
            .enumerate()
            .map(|(k, f)| pixels(&f?, k))
            .collect::<PyResult<_>>()?;
        let n = images.len();
        if leds.len() != n {
            return Err(PyValueError::new_err(format!(
                "leds: {} LEDs for {n} frames",
                leds.len()
            )));
        }
        let exposure = match exposure_ms {
            Some(v) => per_frame(v, n, "exposure_ms")?,
            None => vec![1.0; n],
        };
        let defocus = match defocus_um {
            Some(v) => per_frame(v, n, "defocus_um")?,
            None => vec![0.0; n],
        };
        let entries = (0..n)
            .map(|k| FrameEntry {
                also: vec![],
                file: String::new(),
                led: LedIndex::new(leds[k].0, leds[k].1),
                defocus_um: defocus[k],
                exposure_ms: exposure[k],
            })
            .collect();
        let camera = CameraSection {
            dark_level,
            bit_depth,
            gamma,
            ..CameraSection::default()
        };
        let manifest = Manifest::new(&system, &geometry, camera, entries);
        // Without a directory the dataset has none: not the working directory, whose
        // truth.json (if any) belongs to something else.
        let dir = dir.unwrap_or_else(|| PathBuf::from(IN_MEMORY));
        let inner = fpm_host::dataset::Dataset::from_pixels(&dir, manifest, images)
            .map_err(dataset_error)?;
        Ok(Self { inner })
    }

    /// Write the dataset into `dir` (frames as TIFF under frames/, dataset.toml).
    fn save(&self, py: Python<'_>, dir: PathBuf) -> PyResult<()> {
        let mut copy = self.inner.clone();
        copy.dir = dir;
        py.detach(|| copy.save()).map_err(dataset_error)
    }

    /// Where the dataset came from.
    #[getter]
    fn dir(&self) -> PathBuf {
        self.inner.dir.clone()
    }

    /// The microscope: wavelength_um, na, magnification, pixel_size_um.
    #[getter]
    fn system<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.inner.manifest.system())
    }

    /// The LED array as the dataset states it (its nominal placement).
    #[getter]
    fn geometry<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.inner.manifest.geometry())
    }

    /// The LED (row, col) lit for each frame (a multiplexed frame's first; all of
    /// them: `frame_leds`).
    #[getter]
    fn leds(&self) -> Vec<(u8, u8)> {
        self.inner
            .frames
            .iter()
            .map(|f| (f.entry.led.row, f.entry.led.col))
            .collect()
    }

    /// Every LED (row, col) lit for each frame: one for most datasets, several for a
    /// multiplexed one (`leds = [...]` in dataset.toml).
    #[getter]
    fn frame_leds(&self) -> Vec<Vec<(u8, u8)>> {
        self.inner
            .frames
            .iter()
            .map(|f| f.entry.leds().map(|l| (l.row, l.col)).collect())
            .collect()
    }

    /// Where the dataset's LED array puts each frame's LED, (x, y, z) mm in the sample's
    /// frame (z: its distance below the sample), one row per frame.
    #[getter]
    fn led_positions_mm(&self) -> Vec<(f64, f64, f64)> {
        let geometry = self.inner.manifest.geometry();
        self.inner
            .frames
            .iter()
            .map(|f| geometry.led_position_3d_mm(f.entry.led))
            .collect()
    }

    /// Each frame's exposure, ms.
    #[getter]
    fn exposure_ms(&self) -> Vec<f64> {
        self.inner
            .frames
            .iter()
            .map(|f| f.entry.exposure_ms)
            .collect()
    }

    /// Each frame's defocus, µm (0: in focus).
    #[getter]
    fn defocus_um(&self) -> Vec<f64> {
        self.inner
            .frames
            .iter()
            .map(|f| f.entry.defocus_um)
            .collect()
    }

    /// The camera's dark level, counts.
    #[getter]
    fn dark_level(&self) -> f64 {
        self.inner.manifest.camera.dark_level
    }

    /// The display gamma the frames were saved with (None: linear counts).
    #[getter]
    fn gamma(&self) -> Option<f64> {
        self.inner.manifest.camera.gamma
    }

    /// Every frame, as read-only NumPy views of the frames in memory (no copy).
    #[getter]
    fn frames<'py>(slf: &Bound<'py, Self>) -> PyResult<Vec<Bound<'py, PyAny>>> {
        (0..slf.get().inner.frames.len())
            .map(|k| view(slf, k))
            .collect()
    }

    /// Frame `index` (negative counts from the end), a read-only NumPy view.
    fn frame<'py>(slf: &Bound<'py, Self>, index: isize) -> PyResult<Bound<'py, PyAny>> {
        let n = slf.get().inner.frames.len();
        let k = if index < 0 { index + n as isize } else { index };
        if k < 0 || k as usize >= n {
            return Err(PyIndexError::new_err(format!(
                "frame {index}: the dataset has {n} frames"
            )));
        }
        view(slf, k as usize)
    }

    fn __len__(&self) -> usize {
        self.inner.frames.len()
    }

    fn __repr__(&self) -> String {
        let (h, w) = self.inner.frames.first().map_or((0, 0), |f| f.raw.dim());
        format!(
            "Dataset('{}', {} frames of {w}x{h})",
            self.inner.dir.display(),
            self.inner.frames.len()
        )
    }
}

/// Frame `k` of the dataset behind `slf` as a read-only array that keeps `slf` alive.
fn view<'py>(slf: &Bound<'py, Dataset>, k: usize) -> PyResult<Bound<'py, PyAny>> {
    let py = slf.py();
    let owner = slf.clone().into_any();
    // SAFETY: the dataset is frozen (never mutated or moved out of) and `owner` keeps
    // it, and so the frame's buffer, alive as long as the array exists.
    let array = unsafe {
        match &slf.get().inner.frames[k].raw {
            Pixels::U8(a) => PyArray2::borrow_from_array(a, owner).into_any(),
            Pixels::U16(a) => PyArray2::borrow_from_array(a, owner).into_any(),
            Pixels::F32(a) => PyArray2::borrow_from_array(a, owner).into_any(),
        }
    };
    let flags = PyDict::new(py);
    flags.set_item("write", false)?;
    array.call_method("setflags", (), Some(&flags))?;
    Ok(array)
}

/// `src` read as `format`, written to `out` and loaded; `stated` the keywords of
/// [`fpm_import::Stated`], each refused by name if unknown or of the wrong type.
fn imported(
    py: Python<'_>,
    format: fpm_import::Format,
    src: PathBuf,
    out: PathBuf,
    stated: Option<&Bound<'_, PyDict>>,
) -> PyResult<Dataset> {
    let mut s = fpm_import::Stated::default();
    for (key, value) in stated
        .map(|d| d.iter().collect::<Vec<_>>())
        .unwrap_or_default()
    {
        let key: String = key.extract()?;
        let number = || -> PyResult<Option<f64>> { Ok(Some(value.extract::<f64>()?)) };
        match key.as_str() {
            "wavelength_um" => s.wavelength_um = number()?,
            "na" => s.na = number()?,
            "magnification" => s.magnification = number()?,
            "pixel_size_um" => s.pixel_size_um = number()?,
            "height_mm" => s.height_mm = number()?,
            "pitch_mm" => s.pitch_mm = number()?,
            "dark_level" => s.dark_level = number()?,
            "bit_depth" => s.bit_depth = Some(value.extract::<u32>()?),
            "csv" => s.csv = Some(value.extract::<PathBuf>()?),
            other => {
                return Err(PyValueError::new_err(format!(
                    "{other}: not a keyword of {} (wavelength_um, na, magnification, pixel_size_um, height_mm, pitch_mm, bit_depth, dark_level, csv)",
                    format.name()
                )))
            }
        }
    }
    let inner = py
        .detach(|| {
            fpm_import::import(format, &src, &out, &s)
                .map_err(|e| e.to_string())
                .and_then(|_| fpm_host::dataset::Dataset::load(&out).map_err(|e| e.to_string()))
        })
        .map_err(crate::convert::DatasetError::new_err)?;
    Ok(Dataset { inner })
}
