//! pdcFPM on a dataset: picks the frames, runs the physics, and writes
//! `calibration.json` and the residual plot.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use fpm_physics::calibrate::{self, Calibration, LedStatus, Options};
use fpm_physics::LedGeometry;
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
    /// Read a `calibration.json`.
    pub fn read(path: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        serde_json::from_str(&text)
            .with_context(|| format!("{} is not a calibration file", path.display()))
    }

    /// The calibrated geometry.
    pub fn geometry(&self) -> LedGeometry {
        self.calibration.geometry(&self.nominal)
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
            led: (f.entry.led[0], f.entry.led[1]),
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

/// Draw the residual plot into a PNG; returns the residual magnification.
pub fn write_residual_plot(cal: &Calibration, path: &Path) -> Result<f64> {
    let points: Vec<_> = cal
        .leds
        .iter()
        .filter_map(|l| {
            let m = l.measured_um?;
            let b = l.bias_um.unwrap_or([0.0, 0.0]);
            Some(crate::plot::ShiftPoint {
                measured: [m[0] - b[0], m[1] - b[1]],
                fitted: l.fitted_um,
                used: l.status == LedStatus::Used,
            })
        })
        .collect();
    let (canvas, gain) = crate::plot::residual_plot(&points, 800);
    crate::dataset::image_io::write_png_rgb(path, canvas.width, canvas.height, &canvas.rgb)
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))?;
    Ok(gain)
}
