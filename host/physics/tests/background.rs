//! Dim dark-field frames on a background of stray light, from the full wave-optics
//! simulator: each frame's own background must be found (against the light the
//! simulator added, which the reconstruction never sees) and taken off, so that the
//! result is as good as without stray light; the dataset's dark level alone is not.

use fpm_physics::background::Correction;
use fpm_physics::frame::LitFrame;
use fpm_physics::metrics::{central, complex_nrmse, resample};
use fpm_physics::reconstruct::{tiled, Settings};
use fpm_physics::simulate::{acquire, Camera, ObjectField, SimFrame};
use fpm_physics::{LedGeometry, LedIndex, System};
use rustfft::num_complex::Complex32;

fn lit<'a>(frames: &'a [SimFrame], camera: &Camera) -> Vec<LitFrame<'a>> {
    frames.iter().map(|f| f.lit(camera)).collect()
}

#[test]
fn stray_light_under_dim_dark_field_frames_is_found_and_taken_off() {
    let system = System::paper();
    let geometry = LedGeometry {
        rows: 21,
        cols: 21,
        pitch_mm: 2.5,
        height_mm: 92.0,
        center: LedIndex::new(10, 10),
        dx_mm: 0.4,
        dy_mm: -0.3,
        theta_deg: 2.0,
        tilt_x_deg: 0.0,
        tilt_y_deg: 0.0,
        rings: None,
        list: None,
    };
    let w = 128;
    let object = ObjectField::test_sample(&system, w, 32, 2, 3);
    let shots: Vec<(LedIndex, f64)> = geometry.leds().into_iter().map(|l| (l, 0.0)).collect();
    // Dark-field frames exposed until their brightest pixel reads 200 counts.
    let record = |camera: &Camera| {
        acquire(
            &system,
            &geometry,
            &object,
            &shots,
            camera,
            |img| camera.dim_dark_field_exposure(img, 200.0),
            5,
        )
    };
    let clean_camera = Camera::realistic();
    let stray_camera = Camera {
        stray_light: 2e-4,
        ..clean_camera
    };
    let clean = record(&clean_camera);
    let stray = record(&stray_camera);

    let truth = object.crop_to_camera();
    let m = truth.dim().0;
    let cutoff = system.cutoff();
    let discs: Vec<(f64, f64)> = shots
        .iter()
        .map(|s| geometry.illumination_frequency(s.0, 0.0, 0.0, system.wavelength_um))
        .collect();
    let in_aperture = |fx: f64, fy: f64| discs.iter().any(|f| (fx + f.0).hypot(fy + f.1) <= cutoff);
    let truth_bl = resample(&truth, object.pitch_um(), m, in_aperture);
    let settings = Settings::default();
    let solve = |frames: &[LitFrame<'_>], background: Correction| {
        let settings = Settings {
            background,
            ..settings
        };
        let out = tiled::reconstruct(&system, &geometry, frames, settings, 8, None, &|_, _| {})
            .expect("a reconstruction");
        let on_truth = resample(
            &out.object,
            system.sample_pixel_um() / settings.upsample as f64,
            m,
            in_aperture,
        );
        let (rec, tru) = (central(&on_truth, 0.75), central(&truth_bl, 0.75));
        let modulus = |a: &[Complex32]| -> Vec<Complex32> {
            a.iter().map(|v| Complex32::new(v.norm(), 0.0)).collect()
        };
        let nrmse = complex_nrmse(&rec, &tru);
        let amplitude = complex_nrmse(&modulus(&rec), &modulus(&tru));
        ((nrmse, amplitude), out.backgrounds)
    };
    let per_frame = settings.background;
    assert!(
        matches!(per_frame, Correction::PerFrame { .. }),
        "per-frame backgrounds are the default"
    );
    let (reference, _) = solve(&lit(&clean, &clean_camera), per_frame);
    let (corrected, backgrounds) = solve(&lit(&stray, &stray_camera), per_frame);
    let (uncorrected, _) = solve(&lit(&stray, &stray_camera), Correction::DarkLevel);
    eprintln!(
        "complex (amplitude) NRMSE without stray light {reference:.3?}; with it: per-frame backgrounds {corrected:.3?}, dark level only {uncorrected:.3?}"
    );

    // The levels found against the stray light the simulator added (never seen by
    // the reconstruction): counts = intensity · exposure · e⁻/ms · DN/e⁻.
    let taken: Vec<_> = backgrounds.iter().filter(|(_, b)| b.is_flat()).collect();
    assert!(
        taken.len() * 10 >= backgrounds.len() * 9,
        "{} of {} dark-field frames judged flat",
        taken.len(),
        backgrounds.len()
    );
    let mut worst: f32 = 0.0;
    for (led, b) in &taken {
        let f = stray
            .iter()
            .find(|f| f.led == *led)
            .expect("frame of the LED");
        let added = (stray_camera.stray_light
            * f.exposure_ms
            * stray_camera.electrons_per_ms
            * stray_camera.gain_dn_per_e) as f32;
        // Frames lit just outside the bright field keep some of the sample's own
        // light in their darkest blocks (about a count here): allowed up to two pixel
        // standard deviations, which the 3σ floor reads as no light anyway.
        worst = worst.max(((b.level - added).abs() - 0.05 * added) / b.noise);
    }
    assert!(
        worst < 2.0,
        "a background off by {worst:.2} of its pixel noise beyond 5 % of the stray light"
    );
    assert!(
        corrected.0 < 1.1 * reference.0 && corrected.1 < 1.2 * reference.1,
        "with its background taken off, {corrected:?} against {reference:?} without stray light"
    );
    assert!(
        uncorrected.1 > 2.0 * corrected.1,
        "the dark level alone should suffer: amplitude {} against {}",
        uncorrected.1,
        corrected.1
    );
}
