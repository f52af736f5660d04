//! The ground truth that `fpm simulate` writes beside a simulated dataset
//! (`truth.json`, `truth_amplitude.tif`, `truth_phase.tif`), and scoring a
//! reconstruction against it (docs/dataset.md §6).

use std::path::Path;

use anyhow::{bail, Context, Result};
use fpm_physics::metrics::{score, synthetic_aperture, Scores};
use fpm_physics::{LedGeometry, LedIndex, Placement};
use ndarray::Array2;
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};

use crate::dataset::{image_io, DatasetInfo};
use crate::refinement::{LedPositionScore, RefinedLed, RefinedLedsReport};

/// `truth.json`: the hidden array and what was simulated.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Truth {
    /// Where the array really was.
    #[serde(flatten)]
    pub placement: Placement,
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
    /// Where each LED really was, when the board had LEDs off their grid (`fpm simulate
    /// acquisition --led-jitter-mm`): the geometry above places the grid, these the
    /// LEDs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub leds: Option<Vec<TrueLed>>,
    /// The simulated objective's entrance pupil distance above the sample, mm, when it
    /// was not telecentric (`fpm simulate acquisition --entrance-pupil-mm`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub entrance_pupil_mm: Option<f64>,
    /// The simulated sample's kind (`fpm simulate acquisition --sample`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sample: Option<fpm_physics::simulate::SampleKind>,
}

/// One LED's true place.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct TrueLed {
    /// The LED.
    pub led: LedIndex,
    /// (x, y, distance below the sample), mm.
    pub position_mm: [f64; 3],
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
        nominal
            .placed(
                self.placement.dx_mm,
                self.placement.dy_mm,
                self.placement.theta_deg,
                self.placement.height_mm,
            )
            .tilted(self.placement.tilt_x_deg, self.placement.tilt_y_deg)
    }

    /// Where `led` really was (x, y, distance below the sample), mm: its own place when
    /// the truth lists the LEDs, else the true geometry's.
    pub fn led_position_mm(&self, nominal: &LedGeometry, led: LedIndex) -> (f64, f64, f64) {
        self.leds
            .as_ref()
            .and_then(|all| all.iter().find(|l| l.led == led))
            .map(|l| (l.position_mm[0], l.position_mm[1], l.position_mm[2]))
            .unwrap_or_else(|| self.geometry(nominal).led_position_3d_mm(led))
    }

    /// `led`'s true illumination frequency at the sample point (x, y) µm, cycles/µm.
    pub fn illumination_frequency(
        &self,
        nominal: &LedGeometry,
        led: LedIndex,
        at_um: (f64, f64),
        wavelength_um: f64,
    ) -> (f64, f64) {
        let s = fpm_physics::optics::direction_from(self.led_position_mm(nominal, led), at_um);
        (s[0] / wavelength_um, s[1] / wavelength_um)
    }
}

/// Score refined LED positions against the truth beside dataset `ds`. An extra: `None`
/// without a truth (a warning when it cannot be read).
pub fn score_led_positions(
    ds: &(impl DatasetInfo + ?Sized),
    refined: &RefinedLedsReport,
) -> Option<LedPositionScore> {
    let truth = match Truth::find(ds.dir()) {
        Ok(t) => t?,
        Err(e) => {
            tracing::warn!("LED positions not scored against the truth: {e:#}");
            return None;
        }
    };
    let nominal = ds.manifest().geometry();
    let n = refined.leds.len().max(1) as f64;
    let rms = |place: &dyn Fn(&RefinedLed) -> [f64; 2]| {
        let s: f64 = refined
            .leds
            .iter()
            .map(|l| {
                let (x, y, _) = truth.led_position_mm(&nominal, l.led);
                let p = place(l);
                (p[0] - x).powi(2) + (p[1] - y).powi(2)
            })
            .sum();
        (s / n).sqrt()
    };
    Some(LedPositionScore {
        given_rms_mm: rms(&|l| l.given_mm),
        refined_rms_mm: rms(&|l| l.refined_mm),
    })
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
    ds: &(impl DatasetInfo + ?Sized),
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

/// The illumination frequencies of the in-focus frames of the simulated dataset in
/// `dir` as its truth placed them (cycles/µm): with the cutoff, the synthetic aperture
/// a reconstruction of it is scored in.
pub fn aperture_discs(dir: &Path) -> Result<Vec<(f64, f64)>> {
    let ds = crate::dataset::DatasetOnDisk::open(dir)?;
    let truth =
        Truth::find(dir)?.with_context(|| format!("{} has no truth.json", dir.display()))?;
    discs(&ds, &truth)
}

fn discs(ds: &(impl DatasetInfo + ?Sized), truth: &Truth) -> Result<Vec<(f64, f64)>> {
    let system = ds.manifest().system();
    let nominal = ds.manifest().geometry();
    Ok(ds
        .manifest()
        .frames
        .iter()
        .filter(|f| f.defocus_um == 0.0)
        .map(|f| truth.illumination_frequency(&nominal, f.led, (0.0, 0.0), system.wavelength_um))
        .collect())
}

fn try_score(
    ds: &(impl DatasetInfo + ?Sized),
    reconstruction: &Array2<Complex32>,
    upsample: usize,
) -> Result<Option<Scores>> {
    let Some(truth) = Truth::find(ds.dir())? else {
        return Ok(None);
    };
    let Some(pitch) = truth.object_pixel_um else {
        return Ok(None);
    };
    let object = image_io::read_complex(
        &ds.dir().join("truth_amplitude.tif"),
        &ds.dir().join("truth_phase.tif"),
    )?;
    let (rh, rw) = reconstruction.dim();
    let (th, tw) = object.dim();
    if rh * tw != rw * th {
        bail!(
            "truth_amplitude.tif is {tw}x{th}, the reconstruction {rw}x{rh}: not the same field of view"
        );
    }
    let system = ds.manifest().system();
    let discs = discs(ds, &truth)?;
    let rec_pitch = system.sample_pixel_um() / upsample as f64;
    Ok(Some(score(
        reconstruction,
        rec_pitch,
        &object,
        pitch,
        synthetic_aperture(&discs, system.cutoff()),
    )))
}
