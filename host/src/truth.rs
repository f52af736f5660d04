//! The ground truth that `fpm simulate` writes beside a simulated dataset
//! (`truth.json`, `truth_amplitude.tif`, `truth_phase.tif`), and scoring a
//! reconstruction against it (docs/dataset.md §6).

use std::path::Path;

use anyhow::{bail, Context, Result};
use fpm_physics::metrics::{score, synthetic_aperture, Scores};
use fpm_physics::LedGeometry;
use ndarray::Array2;
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};

use crate::dataset::{image_io, Dataset};

/// `truth.json`: the hidden array and what was simulated.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Truth {
    /// True Δx, mm.
    pub dx_mm: f64,
    /// True Δy, mm.
    pub dy_mm: f64,
    /// True rotation, degrees.
    pub theta_deg: f64,
    /// True LED-to-sample distance, mm.
    pub height_mm: f64,
    /// Defocus of a calibration set, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub defocus_um: Option<f64>,
    /// Calibration feature side, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub feature_um: Option<f64>,
    /// Calibration feature position, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub feature_at_um: Option<[f64; 2]>,
    /// Pixel of `truth_amplitude.tif` / `truth_phase.tif`, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub object_pixel_um: Option<f64>,
    /// Seed of the simulation (other simulators may not record one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
}

impl Truth {
    /// `dir/truth.json`, if there is one.
    pub fn find(dir: &Path) -> Result<Option<Self>> {
        let path = dir.join("truth.json");
        if !path.is_file() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        Ok(Some(
            serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?,
        ))
    }

    /// The true geometry: the nominal one moved as recorded.
    pub fn geometry(&self, nominal: &LedGeometry) -> LedGeometry {
        nominal.placed(self.dx_mm, self.dy_mm, self.theta_deg, self.height_mm)
    }
}

/// Write the sample's ground truth on the camera field (`truth_amplitude.tif`,
/// `truth_phase.tif`, float32 at the simulation's pixel) into `dir`.
pub fn write_truth_images(dir: &Path, object: &fpm_physics::simulate::ObjectField) -> Result<()> {
    write_truth_field(dir, &object.crop_to_camera())
}

/// Write a ground-truth field (the camera's field of view, any aspect ratio, at the
/// simulation's pixel) as `truth_amplitude.tif` and `truth_phase.tif` into `dir`.
pub fn write_truth_field(dir: &Path, gt: &Array2<Complex32>) -> Result<()> {
    image_io::write_tiff_f32(&dir.join("truth_amplitude.tif"), &gt.mapv(|c| c.norm()))?;
    image_io::write_tiff_f32(&dir.join("truth_phase.tif"), &gt.mapv(|c| c.arg()))?;
    Ok(())
}

/// Score the HR object `reconstruction` (`upsample` × the camera grid) of dataset `ds`
/// against the truth beside it. Scoring is an extra: `None` when the dataset carries no
/// object truth, and a truth that cannot be read or used gives a warning (naming the
/// file and the reason), never a failed reconstruction.
pub fn score_reconstruction(
    ds: &Dataset,
    reconstruction: &Array2<Complex32>,
    upsample: usize,
) -> Option<Scores> {
    match try_score(ds, reconstruction, upsample) {
        Ok(scores) => scores,
        Err(e) => {
            tracing::warn!("not scored against the truth beside the dataset: {e:#}");
            None
        }
    }
}

fn try_score(
    ds: &Dataset,
    reconstruction: &Array2<Complex32>,
    upsample: usize,
) -> Result<Option<Scores>> {
    let Some(truth) = Truth::find(&ds.dir)? else {
        return Ok(None);
    };
    let Some(pitch) = truth.object_pixel_um else {
        return Ok(None);
    };
    let object = image_io::read_complex(
        &ds.dir.join("truth_amplitude.tif"),
        &ds.dir.join("truth_phase.tif"),
    )?;
    let (rh, rw) = reconstruction.dim();
    let (th, tw) = object.dim();
    if rh * tw != rw * th {
        bail!(
            "truth_amplitude.tif is {tw}x{th}, the reconstruction {rw}x{rh}: not the same field of view"
        );
    }
    let system = ds.manifest.system();
    let geometry = truth.geometry(&ds.manifest.geometry());
    let discs: Vec<(f64, f64)> = ds
        .frames
        .iter()
        .filter(|f| f.entry.defocus_um == 0.0)
        .map(|f| geometry.illumination_frequency(f.entry.led, 0.0, 0.0, system.wavelength_um))
        .collect();
    let rec_pitch = system.sample_pixel_um() / upsample as f64;
    Ok(Some(score(
        reconstruction,
        rec_pitch,
        &object,
        pitch,
        synthetic_aperture(&discs, system.cutoff()),
    )))
}
