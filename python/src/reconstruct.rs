//! `fpm.reconstruct`: EPRY phase retrieval of a dataset's in-focus frames, tiled and
//! in parallel as `fpm reconstruct` does, with the GIL released while it runs.

use std::path::PathBuf;

use fpm_host::calibration::PlacementFile;
use fpm_host::reconstruction::{GeometryChoice, Job, Refocus};
use fpm_physics::background::Correction;
use fpm_physics::reconstruct::{Flatten, Refine, Settings};
use fpm_physics::LedGeometry;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::calibrate::Calibration;
use crate::convert::{entrance_pupil, failed, from_py, Progress};
use crate::dataset::Dataset;
use crate::result::Reconstruction;

/// The geometry a reconstruction uses: the dataset's nominal one, a Calibration, a
/// dict (a whole geometry, or a placement with dx_mm, dy_mm, theta_deg, height_mm), or
/// the path of a calibration.json / refined-board.json.
fn geometry_from(
    given: Option<&Bound<'_, PyAny>>,
    nominal: &LedGeometry,
) -> PyResult<GeometryChoice> {
    let Some(given) = given.filter(|g| !g.is_none()) else {
        return Ok(GeometryChoice::AsAcquired);
    };
    if let Ok(c) = given.cast::<Calibration>() {
        return Ok(GeometryChoice::Given(
            c.get().file.geometry(),
            "fpm.calibrate".into(),
        ));
    }
    if let Ok(d) = given.cast::<PyDict>() {
        if d.contains("rows")? {
            return Ok(GeometryChoice::Given(
                from_py(given, "geometry")?,
                "a geometry dict".into(),
            ));
        }
        let text: String = given
            .py()
            .import("json")?
            .call_method1("dumps", (given,))?
            .extract()?;
        let placement = PlacementFile::parse(&text)
            .map_err(|e| PyValueError::new_err(format!("geometry: {e:#}")))?;
        return Ok(GeometryChoice::Given(
            placement.geometry(nominal),
            "a placement dict".into(),
        ));
    }
    let path: PathBuf = given.extract().map_err(|_| {
        PyValueError::new_err(
            "geometry: give a Calibration, a dict, or the path of a calibration.json",
        )
    })?;
    Ok(GeometryChoice::File(path))
}

/// EPRY's settings from the keyword arguments that `reconstruct` and `Streaming` share.
#[allow(clippy::too_many_arguments)] // Python keyword arguments, one parameter each
pub(crate) fn settings(
    upsample: usize,
    fixed_pupil: bool,
    background: &str,
    floor: &str,
    floor_sigma: f32,
    noise_band_sigma: f32,
    flatten_background: bool,
    background_block_um: Option<f64>,
) -> PyResult<Settings> {
    let soft = match floor {
        "soft" => true,
        "hard" => false,
        other => {
            return Err(PyValueError::new_err(format!(
                "floor = '{other}': give 'soft' or 'hard'"
            )))
        }
    };
    let background = match background {
        "per-frame" => Correction::PerFrame {
            floor_sigma,
            soft,
            band_sigma: noise_band_sigma,
        },
        "dark-level" => Correction::DarkLevel,
        other => {
            return Err(PyValueError::new_err(format!(
                "background = '{other}': give 'per-frame' or 'dark-level'"
            )))
        }
    };
    let flatten = match (flatten_background, background_block_um) {
        (false, None) => Flatten::Keep,
        (false, Some(_)) => {
            return Err(PyValueError::new_err(
                "background_block_um needs flatten_background=True",
            ))
        }
        (true, None) => Flatten::Auto,
        (true, Some(um)) if um > 0.0 && um.is_finite() => Flatten::BlockUm(um),
        (true, Some(um)) => {
            return Err(PyValueError::new_err(format!(
                "background_block_um = {um}: give a positive size in µm"
            )))
        }
    };
    let settings = Settings {
        upsample,
        update_pupil: !fixed_pupil,
        background,
        flatten,
        ..Settings::default()
    };
    settings
        .validate()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(settings)
}

/// Reconstruct `dataset`'s in-focus frames with EPRY: the object and the pupil.
///
/// `geometry`: see `geometry_from`. `tile`: side in camera pixels (default from the
/// physics). `background`: "per-frame" (each dark-field frame's own background taken
/// off, light near `floor_sigma` of its noise shrunk, noise read as no light) or
/// "dark-level". `floor`: "soft" (default: light v counts as v·(v²/(v² + f²))², f the
/// floor) or "hard" (everything up to the floor cut), as `fpm reconstruct --floor`.
/// `noise_band_sigma`: the dark-field frames' noise band in σ of their background
/// noise, on the frames that are mostly noise (default 7.5: their noise kept off
/// clear glass; 0 imposes each pixel exactly), as
/// `fpm reconstruct --noise-band-sigma`.
/// `progress(done, total)` is called as frame updates complete (tqdm: pass
/// `lambda d, t: bar.update(d - bar.n)`). `flatten_background`: take the clear
/// background's low-order phase off, over blocks of `background_block_um` (default
/// from the LED array), for samples on clear glass (see `fpm reconstruct --help`).
/// `entrance_pupil_mm`: the objective's entrance pupil distance above the sample, for
/// objectives that are not telecentric (camera lenses, simple low-power objectives;
/// default telecentric; see `fpm reconstruct --help`). `refocus_um`: how far the
/// sample sat from focus when the frames were taken, µm (toward the LEDs positive); the
/// pupil starts with that defocus and the image comes out refocused. "auto": as far as
/// the bright-field frames' shifts say; None (default): that too where the shifts
/// clearly show a defocus, else as in focus (the report's `refocus` says which).
/// `dataset` may also be a dataset's directory; a colour dataset's (docs/dataset.md
/// §5.9) gives a `ColorResult`, every channel reconstructed with its own wavelength,
/// LEDs and pupil and registered (`geometry`: the path of a colour calibration.json,
/// or of one calibration for every channel, which the result warns of).
/// Raises FpmError when it cannot run.
#[pyfunction]
// The defaults are spelled out for `help()` (PyO3 shows a constant as `...`): a change
// of the library's fails the build (lib.rs), and pytest checks these against it.
#[pyo3(signature = (dataset, *, geometry = None, upsample = 4, passes = 10, tile = None, refine_leds = false, fixed_pupil = false, background = "per-frame", floor = "soft", floor_sigma = 3.0, noise_band_sigma = 7.5, flatten_background = false, background_block_um = None, entrance_pupil_mm = None, refocus_um = None, progress = None))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments, one parameter each
pub fn reconstruct(
    py: Python<'_>,
    dataset: &Bound<'_, PyAny>,
    geometry: Option<&Bound<'_, PyAny>>,
    upsample: usize,
    passes: usize,
    tile: Option<usize>,
    refine_leds: bool,
    fixed_pupil: bool,
    background: &str,
    floor: &str,
    floor_sigma: f32,
    noise_band_sigma: f32,
    flatten_background: bool,
    background_block_um: Option<f64>,
    entrance_pupil_mm: Option<f64>,
    refocus_um: Option<&Bound<'_, PyAny>>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Py<PyAny>> {
    let refocus = match refocus_um {
        None => Refocus::WhereClear,
        Some(v) => match v.extract::<f64>() {
            Ok(um) => Refocus::Distance(um),
            Err(_) => match v.extract::<String>() {
                Ok(w) if w.eq_ignore_ascii_case("auto") => Refocus::Auto,
                _ => {
                    return Err(PyValueError::new_err(format!(
                        "refocus_um = {v}: give a distance in µm, 'auto' or None"
                    )))
                }
            },
        },
    };
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
    let loaded;
    let ds = match dataset.cast::<Dataset>() {
        Ok(d) => &d.get().inner,
        Err(_) => {
            let dir: PathBuf = dataset.extract().map_err(|_| {
                PyValueError::new_err("dataset: give a Dataset, or a dataset's directory")
            })?;
            if fpm_host::color::is_color(&dir) {
                let calibration = match geometry.filter(|g| !g.is_none()) {
                    None => None,
                    Some(g) => Some(g.extract::<PathBuf>().map_err(|_| {
                        PyValueError::new_err("geometry: a colour dataset takes the path of a calibration.json (a colour one places each colour's LEDs)")
                    })?),
                };
                let job = Job {
                    entrance_pupil_mm: entrance_pupil(entrance_pupil_mm)?,
                    settings,
                    refocus,
                    passes,
                    tile,
                    ..Job::default()
                };
                if refine_leds {
                    return Err(PyValueError::new_err(
                        "refine_leds: not for a colour dataset; refine each channel's dataset on its own",
                    ));
                }
                job.validate()
                    .map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
                let progress = Progress::new(progress);
                let result = crate::color::reconstruct(py, dir, job, calibration, &progress);
                progress.finish()?;
                return Ok(Py::new(py, result?)?.into_any());
            }
            loaded =
                fpm_host::dataset::Dataset::load(&dir).map_err(crate::convert::dataset_error)?;
            &loaded
        }
    };
    let geometry = geometry_from(geometry, &ds.manifest.geometry())?;
    let job = Job {
        geometry,
        entrance_pupil_mm: entrance_pupil(entrance_pupil_mm)?,
        camera_gamma: None,
        settings: Settings {
            refine_leds: refine_leds.then(Refine::default),
            ..settings
        },
        refocus,
        passes,
        tile,
        ..Job::default()
    };
    // The same checks, and the same words, as `fpm reconstruct`.
    job.validate()
        .map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
    let progress = Progress::new(progress);
    let result = py.detach(|| job.run_in_memory(ds, &|done, total| progress.report(done, total)));
    progress.finish()?;
    Ok(Py::new(
        py,
        Reconstruction {
            inner: result.map_err(failed)?,
        },
    )?
    .into_any())
}
