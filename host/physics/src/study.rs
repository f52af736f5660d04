//! End-to-end studies on simulated data: how much a misplaced LED array costs the
//! reconstruction, and how much calibration wins back (the paper's Fig. 1 and Fig. 5).

use crate::frame::Region;
use crate::optics::LedIndex;
use rustfft::num_complex::Complex32;

use crate::calibrate::{self, Calibration, Options};
use crate::metrics::{central, complex_nrmse, resample};
use crate::reconstruct::{run, Field, Settings, Shot};
use crate::simulate::{acquire, CalibrationScene, Camera, ObjectField, SimFrame};
use crate::{Image, LedGeometry, System};

/// Reconstruction quality of one misplaced array.
#[derive(Debug, Clone, serde::Serialize)]
pub struct GeometryCase {
    /// The real array.
    pub truth: LedGeometry,
    /// What pdcFPM recovered.
    pub calibrated: LedGeometry,
    /// Complex NRMSE with the nominal geometry.
    pub nrmse_nominal: f64,
    /// With the calibrated geometry.
    pub nrmse_calibrated: f64,
    /// With the true geometry.
    pub nrmse_true: f64,
    /// The up-sampled centre frame, for scale.
    pub nrmse_centre_frame: f64,
}

/// Calibrate from frames simulated for `scene`, as the calibrator would receive them
/// from a dataset (dark-subtracted, with the camera's saturation level). Returns the
/// result and the time the calibration itself took.
pub fn calibrate_simulated(
    scene: &CalibrationScene,
    frames: &[SimFrame],
    nominal: &LedGeometry,
    options: &Options,
) -> Result<(Calibration, std::time::Duration), calibrate::CalibrationError> {
    let images: Vec<Image> = frames
        .iter()
        .map(|f| {
            let m = f.measured(&scene.camera);
            m.dark_subtracted(Region::whole(m.dim()))
        })
        .collect();
    let input: Vec<calibrate::Frame> = frames
        .iter()
        .zip(&images)
        .map(|(f, image)| calibrate::Frame {
            led: f.led,
            defocus_um: f.defocus_um,
            exposure_ms: f.exposure_ms,
            image,
            saturation: Some(scene.camera.saturation()),
        })
        .collect();
    let start = std::time::Instant::now();
    let cal = calibrate::calibrate(&scene.system, nominal, &input, options)?;
    Ok((cal, start.elapsed()))
}

/// Simulate an acquisition (`camera_px`² frames of the test sample, every LED) and a
/// calibration set with the array at `truth`, calibrate, and reconstruct with the
/// nominal, calibrated and true geometry.
pub fn geometry_case(
    system: &System,
    nominal: &LedGeometry,
    truth: &LedGeometry,
    camera_px: usize,
    passes: usize,
    seed: u64,
) -> Option<GeometryCase> {
    let camera = Camera::realistic();
    // The calibration slide.
    let scene = CalibrationScene {
        system: *system,
        ..CalibrationScene::paper(*truth, seed)
    };
    let cal_frames = scene.acquire();
    let (cal, _) = calibrate_simulated(&scene, &cal_frames, nominal, &Options::default()).ok()?;
    let calibrated = cal.geometry(nominal);

    // The sample.
    let object = ObjectField::test_sample(system, camera_px, 32, 2, seed);
    let shots: Vec<(LedIndex, f64)> = nominal.leds().into_iter().map(|l| (l, 0.0)).collect();
    let frames = acquire(
        system,
        truth,
        &object,
        &shots,
        &camera,
        |img| camera.auto_exposure(img),
        seed ^ 0xAC0,
    );
    let images: Vec<Image> = frames
        .iter()
        .map(|f| {
            let m = f.measured(&camera);
            m.intensity(Region::whole(m.dim()))
        })
        .collect();
    let shot_refs: Vec<Shot> = frames
        .iter()
        .zip(&images)
        .map(|(f, image)| Shot {
            led: f.led,
            also: &f.also,
            image,
        })
        .collect();

    // Truth, band-limited to the true synthetic aperture, on its own grid.
    let truth_field = object.crop_to_camera();
    let m = truth_field.dim().0;
    let discs: Vec<(f64, f64)> = shots
        .iter()
        .map(|s| truth.illumination_frequency(s.0, 0.0, 0.0, system.wavelength_um))
        .collect();
    let cutoff = system.cutoff();
    let in_aperture = |fx: f64, fy: f64| discs.iter().any(|f| (fx + f.0).hypot(fy + f.1) <= cutoff);
    let truth_bl = resample(&truth_field, object.pitch_um(), m, in_aperture);
    let truth_c = central(&truth_bl, 0.75);
    let settings = Settings::default();
    let score = |geometry: &LedGeometry| -> Option<f64> {
        let mut out = run(
            system,
            geometry,
            Field::default(),
            &shot_refs,
            settings,
            passes,
            |_, _| {},
        )?;
        let rec = out.sample();
        let pitch = system.sample_pixel_um() / settings.upsample as f64;
        Some(complex_nrmse(
            &central(&resample(&rec, pitch, m, in_aperture), 0.75),
            &truth_c,
        ))
    };
    let centre = shots.iter().position(|s| s.0 == nominal.center)?;
    let base = images[centre].mapv(|v| Complex32::new(v.max(0.0).sqrt(), 0.0));
    let nrmse_centre_frame = complex_nrmse(
        &central(
            &resample(&base, system.sample_pixel_um(), m, |_, _| true),
            0.75,
        ),
        &truth_c,
    );
    Some(GeometryCase {
        truth: *truth,
        calibrated,
        nrmse_nominal: score(nominal)?,
        nrmse_calibrated: score(&calibrated)?,
        nrmse_true: score(truth)?,
        nrmse_centre_frame,
    })
}
