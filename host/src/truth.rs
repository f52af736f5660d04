//! The ground truth that `fpm simulate` writes beside a simulated dataset
//! (`truth.json`, `truth_amplitude.tif`, `truth_phase.tif`), and scoring a
//! reconstruction against it (PHYSICS.md §6).

use std::path::Path;

use anyhow::{bail, Context, Result};
use fpm_physics::metrics::{score, synthetic_aperture, Scores};
use fpm_physics::LedGeometry;
use ndarray::Array2;
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};

use crate::dataset::{image_io, Dataset, Pixels};

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
    /// Seed of the simulation.
    pub seed: u64,
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
    let gt = object.crop_to_camera();
    image_io::write_tiff_f32(&dir.join("truth_amplitude.tif"), &gt.mapv(|c| c.norm()))
        .map_err(anyhow::Error::msg)?;
    image_io::write_tiff_f32(&dir.join("truth_phase.tif"), &gt.mapv(|c| c.arg()))
        .map_err(anyhow::Error::msg)?;
    Ok(())
}

/// Score the HR object `reconstruction` (`upsample` × the camera grid) of dataset `ds`
/// against the truth beside it. `None` when the dataset carries no object truth.
pub fn score_reconstruction(
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
    let (amp_path, phase_path) = (
        ds.dir.join("truth_amplitude.tif"),
        ds.dir.join("truth_phase.tif"),
    );
    let read = |p: &Path| -> Result<Array2<f32>> {
        match image_io::read(p).map_err(anyhow::Error::msg)? {
            Pixels::F32(a) => Ok(a),
            _ => bail!("{}: expected a float32 TIFF", p.display()),
        }
    };
    let (amp, phase) = (read(&amp_path)?, read(&phase_path)?);
    if amp.dim() != phase.dim() || amp.dim().0 != amp.dim().1 {
        bail!(
            "{} and {}: the truth must be two square images of one size",
            amp_path.display(),
            phase_path.display()
        );
    }
    let (rh, rw) = reconstruction.dim();
    if rh != rw {
        bail!("scoring takes square reconstructions ({rw}x{rh})");
    }
    let object = Array2::from_shape_fn(amp.dim(), |i| Complex32::from_polar(amp[i], phase[i]));
    let system = ds.manifest.system();
    let geometry = truth.geometry(&ds.manifest.geometry());
    let discs: Vec<(f64, f64)> = ds
        .frames
        .iter()
        .filter(|f| f.entry.defocus_um == 0.0)
        .map(|f| {
            geometry.illumination_frequency(
                f.entry.led[0],
                f.entry.led[1],
                0.0,
                0.0,
                system.wavelength_um,
            )
        })
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
