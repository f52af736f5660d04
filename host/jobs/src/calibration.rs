//! pdcFPM on a dataset: picks the frames, runs the physics, and writes
//! `calibration.json` and the residual plot.

use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use fpm_physics::calibrate::{self, Calibration, LedStatus, Options};
use fpm_physics::{LedGeometry, Placement};
use serde::{Deserialize, Serialize};

use crate::dataset::Dataset;

/// `calibration.json`: the result plus what it was computed from.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CalibrationFile {
    /// The calibrated array.
    #[serde(flatten)]
    pub calibration: Calibration,
    /// The nominal geometry it started from.
    pub nominal: LedGeometry,
    /// Dataset directory.
    pub dataset: String,
    /// Time the calibration took (frames already in memory), ms.
    pub time_ms: f64,
}

impl CalibrationFile {
    /// The calibrated geometry.
    pub fn geometry(&self) -> LedGeometry {
        self.calibration.geometry(&self.nominal)
    }
}

/// Where the LED geometry a reconstruction or acquisition used came from.
#[derive(Debug, Clone, PartialEq)]
pub enum GeometrySource {
    /// The dataset's nominal placement (dataset.toml).
    Dataset,
    /// The dataset's nominal placement at another LED height (`--led-height-mm`).
    DatasetAtHeight(f64),
    /// The dataset's nominal placement at the height the frames' bright/dark-field
    /// edge reads, which fitted them clearly better than the dataset's
    /// ([`crate::reconstruction::height`]).
    EdgeHeight(f64),
    /// The controller's nominal array (an acquisition without calibration).
    Controller,
    /// The calibration stored on the controller board.
    Board,
    /// Calibrated by this acquisition (its calibration.json).
    CalibratedNow,
    /// A file: calibration.json, refined-board.json, a placement.
    File(std::path::PathBuf),
    /// Given by a caller, as it named it (Python: a Calibration, a dict).
    Given(String),
}

impl GeometrySource {
    /// Whether the geometry is a nominal one (nothing measured it).
    pub fn is_nominal(&self) -> bool {
        matches!(
            self,
            Self::Dataset | Self::DatasetAtHeight(_) | Self::EdgeHeight(_) | Self::Controller
        )
    }

    /// The one-word name acquisition.json uses: "nominal", "board", "calibration.json".
    pub fn short_name(&self) -> String {
        match self {
            Self::Dataset | Self::DatasetAtHeight(_) | Self::EdgeHeight(_) | Self::Controller => {
                "nominal".into()
            }
            Self::Board => "board".into(),
            Self::CalibratedNow => "calibration.json".into(),
            other => other.to_string(),
        }
    }
}

impl std::fmt::Display for GeometrySource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Dataset => write!(f, "nominal (dataset.toml)"),
            Self::DatasetAtHeight(h) => write!(f, "nominal (dataset.toml) at --led-height-mm {h}"),
            Self::EdgeHeight(h) => write!(
                f,
                "nominal (dataset.toml) at the bright/dark-field edge's height, {h:.2} mm"
            ),
            Self::Controller => write!(f, "nominal (controller)"),
            Self::Board => write!(f, "stored on the board"),
            Self::CalibratedNow => write!(f, "calibration.json"),
            Self::File(path) => write!(f, "{}", path.display()),
            Self::Given(name) => write!(f, "{name}"),
        }
    }
}

/// report.json states the source as the text a person reads.
impl Serialize for GeometrySource {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// acquisition.json states it by its short name ([`GeometrySource::short_name`]).
pub fn serialize_short<S: serde::Serializer>(g: &GeometrySource, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&g.short_name())
}

/// The geometry the dataset in `dir` was acquired with, where its `acquisition.json`
/// records a measured one (`geometry_source` "calibration.json": the calibration made
/// then, beside the dataset, read as `--calibration` reads it on the `nominal` grid;
/// "board": the one stored on the controller; else the path of the placement file it
/// was given) with the `geometry` it used. None where it records the nominal array, or
/// there is no record (a simulated or imported dataset): the dataset's nominal
/// placement applies. A record that names a measured geometry but cannot give it is an
/// error, not a silent fall back to the nominal array.
pub fn as_acquired(
    dir: &Path,
    nominal: &LedGeometry,
) -> Result<Option<(LedGeometry, GeometrySource)>> {
    let path = dir.join("acquisition.json");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(None);
    };
    let record: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let source = match record.get("geometry_source") {
        None => return Ok(None),
        Some(serde_json::Value::String(s)) if s == "nominal" => return Ok(None),
        Some(serde_json::Value::String(s)) => s.clone(),
        Some(other) => bail!(
            "{}: geometry_source {other}: expected \"nominal\", \"board\", \"calibration.json\" or a placement file's path",
            path.display()
        ),
    };
    let geometry = || -> Result<LedGeometry> {
        let value = record.get("geometry").cloned().with_context(|| {
            format!(
                "{}: geometry_source {source:?} but no geometry: give the placement with --calibration, or --nominal-geometry",
                path.display()
            )
        })?;
        serde_json::from_value(value).with_context(|| {
            format!(
                "{}: geometry is not an LED geometry: give the placement with --calibration, or --nominal-geometry",
                path.display()
            )
        })
    };
    let beside = dir.join("calibration.json");
    Ok(Some(match source.as_str() {
        "board" => (geometry()?, GeometrySource::Board),
        "calibration.json" if beside.is_file() => (
            PlacementFile::read(&beside)?.geometry(nominal),
            GeometrySource::File(beside),
        ),
        // A placement file's path may be relative to wherever the acquisition ran: the
        // geometry recorded is what it gave.
        "calibration.json" => (
            geometry()?,
            GeometrySource::Given(
                "as acquired (acquisition.json; its calibration.json is no longer beside it)"
                    .into(),
            ),
        ),
        file => (
            geometry()?,
            GeometrySource::Given(format!("as acquired with {file} (acquisition.json)")),
        ),
    }))
}

/// The four numbers that place an LED array (docs/dataset.md, "calibration.json").
pub const GEOMETRY_KEYS: [&str; 4] = ["dx_mm", "dy_mm", "theta_deg", "height_mm"];

/// What a calibration should reach (1σ): beyond it, a warning says so rather than
/// letting the number look confident ([`calibrate::ACCURACY_TARGET`]).
pub const TARGET_LATERAL_UM: f64 = calibrate::ACCURACY_TARGET[0];
/// θ, degrees.
pub const TARGET_THETA_DEG: f64 = calibrate::ACCURACY_TARGET[2];
/// h from the shifts alone (the defocus's own error aside), mm.
pub const TARGET_HEIGHT_MM: f64 = calibrate::ACCURACY_TARGET[3];

/// The board's tilt, optional (a flat board when absent).
pub const TILT_KEYS: [&str; 2] = ["tilt_x_deg", "tilt_y_deg"];

/// An LED array placement read from a `calibration.json`: either a full file written by
/// `fpm calibrate`, or a hand-written one with only [`GEOMETRY_KEYS`] (an array measured
/// by other means), the tilt optional ([`TILT_KEYS`]). The grid itself (rows, cols,
/// pitch, centre LED) comes from the file's `nominal` block when it has one, else from
/// the dataset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlacementFile {
    /// The placement.
    pub placement: Placement,
    /// The grid the file was computed for, if it says.
    pub nominal: Option<LedGeometry>,
}

impl PlacementFile {
    /// Read `path`. A missing or non-numeric key among [`GEOMETRY_KEYS`] is an error that
    /// names every such key.
    pub fn read(path: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        Self::parse(&text).with_context(|| format!("{}", path.display()))
    }

    /// Parse the JSON text of a calibration file.
    pub fn parse(text: &str) -> Result<Self> {
        let value: serde_json::Value =
            serde_json::from_str(text).context("not a JSON calibration file")?;
        let object = value.as_object().context(
            "a calibration file is a JSON object with dx_mm, dy_mm, theta_deg, height_mm",
        )?;
        if object.contains_key("channels") && !object.contains_key("dx_mm") {
            bail!("a colour calibration (one placement per channel): give it with the colour dataset it was made for, or give one channel's own calibration.json");
        }
        let mut numbers = [0.0; 4];
        let mut missing = vec![];
        let mut invalid = vec![];
        for (slot, key) in numbers.iter_mut().zip(GEOMETRY_KEYS) {
            match object.get(key) {
                None => missing.push(key),
                Some(v) => match v.as_f64().filter(|x| x.is_finite()) {
                    Some(x) => *slot = x,
                    None => invalid.push(format!("{key} = {v}")),
                },
            }
        }
        if !missing.is_empty() {
            bail!(
                "missing key(s) {}: a calibration file needs all of {}",
                missing.join(", "),
                GEOMETRY_KEYS.join(", ")
            );
        }
        if !invalid.is_empty() {
            bail!("not a finite number: {}", invalid.join(", "));
        }
        let [dx_mm, dy_mm, theta_deg, height_mm] = numbers;
        if height_mm <= 0.0 {
            bail!("height_mm = {height_mm}: the LED array must sit below the sample (> 0)");
        }
        let mut tilt_deg = [0.0; 2];
        for (slot, key) in tilt_deg.iter_mut().zip(TILT_KEYS) {
            if let Some(v) = object.get(key) {
                *slot = v
                    .as_f64()
                    .filter(|x| x.is_finite() && x.abs() < 45.0)
                    .with_context(|| format!("{key} = {v}: not a tilt in degrees (|tilt| < 45)"))?;
            }
        }
        let nominal = match object.get("nominal") {
            None => None,
            Some(v) => Some(
                serde_json::from_value::<LedGeometry>(v.clone())
                    .context("the `nominal` block is not an LED grid")?,
            ),
        };
        let [tilt_x, tilt_y] = tilt_deg;
        Ok(Self {
            placement: Placement::from_array([dx_mm, dy_mm, theta_deg, height_mm, tilt_x, tilt_y]),
            nominal,
        })
    }

    /// The placed array on the file's grid, or on `dataset_nominal` when the file has
    /// none. A file whose grid differs from the dataset's is used as written, with a
    /// warning.
    pub fn geometry(&self, dataset_nominal: &LedGeometry) -> LedGeometry {
        let grid = match self.nominal {
            Some(n) => {
                if !n.same_grid(dataset_nominal) {
                    tracing::warn!(
                        "the calibration's LED grid ({}x{}, pitch {} mm, centre {}) differs from the dataset's ({}x{}, pitch {} mm, centre {}); using the calibration's",
                        n.rows, n.cols, n.pitch_mm, n.center,
                        dataset_nominal.rows, dataset_nominal.cols, dataset_nominal.pitch_mm, dataset_nominal.center
                    );
                }
                n
            }
            None => *dataset_nominal,
        };
        grid.placed_at(self.placement)
    }
}

/// Calibrate the LED array from a pdcFPM dataset.
pub fn calibrate_dataset(ds: &Dataset, options: &Options) -> Result<CalibrationFile> {
    let system = ds.manifest.system();
    let nominal = ds.manifest.geometry();
    let images: Vec<_> = (0..ds.frames.len()).map(|k| ds.corrected(k)).collect();
    let saturation = ds.saturation();
    let frames: Vec<calibrate::Frame> = ds
        .frames
        .iter()
        .zip(&images)
        .map(|(f, img)| calibrate::Frame {
            led: f.entry.led,
            defocus_um: f.entry.defocus_um,
            exposure_ms: f.entry.exposure_ms,
            image: img,
            saturation,
        })
        .collect();
    let start = Instant::now();
    let calibration = calibrate::calibrate(&system, &nominal, &frames, options)
        .with_context(|| format!("calibrating {}", ds.dir.display()))?;
    Ok(CalibrationFile {
        calibration,
        nominal,
        dataset: ds.dir.display().to_string(),
        time_ms: start.elapsed().as_secs_f64() * 1e3,
    })
}

/// What a user must know before trusting `cal`.
pub fn warnings(cal: &Calibration) -> Vec<String> {
    let used = cal
        .leds
        .iter()
        .filter(|l| l.status == LedStatus::Used)
        .count();
    let outliers = cal
        .leds
        .iter()
        .filter(|l| l.status == LedStatus::Outlier)
        .count();
    let mut out = vec![];
    let u = &cal.uncertainty;
    // LEDs off a rigid board by far more than each is measured to: the fit's scatter
    // is the board's own, which no exposure or defocus takes away.
    let board_scatter = cal
        .led_offsets()
        .filter(|o| o.rms_mm > 0.05 && o.rms_mm > 10.0 * o.median_sigma_mm);
    let help = |usual: &str| match board_scatter {
        Some(_) => "the LEDs' own places off the board set it (below)".to_string(),
        None => usual.to_string(),
    };
    if used < calibrate::MIN_USED_LEDS {
        out.push(format!(
            "only {used} LEDs were usable: check the defocus, the exposure and the feature"
        ));
    } else {
        // The same rule `fpm bench calibration` scores: which parameters are warned.
        let [lateral, _, theta, height] = cal.accuracy_warned();
        if lateral {
            out.push(format!(
                "Δx, Δy are uncertain by {:.1} µm (1σ), more than the {TARGET_LATERAL_UM} µm a calibration should reach: {}",
                u.dx_mm.max(u.dy_mm) * 1e3,
                help("a brighter exposure (without saturating), a larger feature or a larger defocus would help")
            ));
        }
        if theta {
            out.push(format!(
                "θ is uncertain by {:.3}° (1σ), more than {TARGET_THETA_DEG}°: {}",
                u.theta_deg,
                help("more LEDs or a larger defocus would help")
            ));
        }
        // h's share from the shifts alone: the defocus's own σ is the user's to state.
        if height {
            out.push(format!(
                "h is uncertain by {:.2} mm (1σ) from the shifts alone, more than {TARGET_HEIGHT_MM} mm: {}",
                cal.height_sigma_from_shifts_mm(),
                help("a larger defocus or more LEDs would help")
            ));
        }
    }
    if !cal.tilt_observable && cal.uncertainty.tilt_x_deg == 0.0 {
        out.push("the board's tilt was not fitted: it was taken as flat".to_string());
    } else if !cal.tilt_observable {
        out.push(format!(
            "the shifts cannot pin down the board's tilt (1σ {:.2}° / {:.2}°, more than {}°): the board was taken as flat, and Δx, Δy carry what such a tilt could do; {}",
            cal.uncertainty.tilt_x_deg, cal.uncertainty.tilt_y_deg, calibrate::TILT_OBSERVABLE_SIGMA_DEG,
            help("more LEDs or a larger defocus would show it")
        ));
    } else if cal.placement.tilt_x_deg.hypot(cal.placement.tilt_y_deg) > 3.0 {
        out.push(format!(
            "the board is tilted by {:.1}° about x and {:.1}° about y: check that it is mounted parallel to the stage",
            cal.placement.tilt_x_deg, cal.placement.tilt_y_deg
        ));
    }
    if let Some(o) = board_scatter {
        out.push(format!(
            "the LEDs sit off a rigid board by {:.2} mm RMS, each measured to about {:.3} mm (farthest ({}, {}) {:.2} mm; offset_mm in calibration.json): a hand-built board's own scatter, which widens Δx, Δy, θ, h's σ honestly; the reconstruction takes each LED on the fitted board, and `fpm reconstruct --refine-leds` moves them within it",
            o.rms_mm, o.median_sigma_mm, o.farthest.row, o.farthest.col, o.farthest_mm
        ));
    }
    // Outliers whose shift puts their LED off the fitted board beyond 5σ of its own
    // measurement (its σ is a little optimistic: the bias model's error): a board
    // problem, or dust. One within it is the robust fit trimming its tail (seen at
    // 3.1σ on a simulated perfect board), listed in the report only.
    let off: Vec<String> = cal
        .leds
        .iter()
        .filter(|l| l.status == LedStatus::Outlier)
        .filter_map(|l| {
            let ([x, y], sigma) = (l.offset_mm?, l.offset_sigma_mm?);
            (x.hypot(y) > 5.0 * sigma).then(|| {
                format!(
                    "({}, {}) {:.3} ± {:.3} mm off",
                    l.led.row,
                    l.led.col,
                    x.hypot(y),
                    sigma
                )
            })
        })
        .collect();
    let unmeasured = cal
        .leds
        .iter()
        .filter(|l| l.status == LedStatus::Outlier && l.offset_mm.is_none())
        .count();
    if !off.is_empty() || unmeasured > 0 {
        out.push(format!(
            "{} of {outliers} LED(s) rejected as outliers sit off the fitted board by more than 5σ [{}]; the fit went on without them. Look at those LEDs on the board (a bent leg, a package askew) and at the slide for dust there; a feature cut by the pupil's edge does this too",
            off.len() + unmeasured,
            off.join(", ")
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpm_physics::simulate::CalibrationScene;

    /// An outlier is named with where its LED sits when that is beyond 5σ of its own
    /// measurement; one within it (the robust fit trimming its tail) is not warned.
    #[test]
    fn an_outlier_is_named_by_how_far_its_led_sits_off_the_board() {
        let truth =
            LedGeometry::paper().placed_at(Placement::from_array([1.0, -0.5, 2.0, 92.0, 0.0, 0.0]));
        let scene = CalibrationScene::paper(truth, 3);
        let (mut cal, _) = fpm_physics::study::calibrate_simulated(
            &scene,
            &scene.acquire(),
            &LedGeometry::paper(),
            &Options::default(),
        )
        .expect("calibrates");
        let outlier_warning = |cal: &Calibration| {
            warnings(cal)
                .into_iter()
                .find(|w| w.contains("rejected as outliers"))
        };
        let k = cal
            .leds
            .iter()
            .position(|l| l.status == LedStatus::Used)
            .expect("a used LED");
        cal.leds.iter_mut().for_each(|l| {
            if l.status == LedStatus::Outlier {
                l.status = LedStatus::Used;
            }
        });
        let led = cal.leds[k].led;
        cal.leds[k].status = LedStatus::Outlier;
        cal.leds[k].offset_mm = Some([0.012, 0.0]);
        cal.leds[k].offset_sigma_mm = Some(0.003);
        assert_eq!(outlier_warning(&cal), None, "4σ: the fit's own tail");
        cal.leds[k].offset_mm = Some([0.4, 0.1]);
        let warning = outlier_warning(&cal).expect("a LED 0.41 mm off");
        assert!(
            warning.contains(&format!("({}, {}) 0.412 ± 0.003 mm off", led.row, led.col)),
            "{warning}"
        );
    }
}
