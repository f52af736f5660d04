//! A sample left out of focus: frames rendered by the full wave-optics model with the
//! sample 80 µm toward the LEDs, reconstructed as if in focus and told the defocus
//! (`Settings::defocus_um`), against the in-focus truth. Told, EPRY recovers the
//! sample's own plane; not told, the learned pupil cannot follow a defocus of several
//! waves and the result is far off (the real ring-array set in `data/` was taken so).

mod common;

use fpm_physics::metrics::{central, complex_nrmse, resample};
use fpm_physics::reconstruct::Settings;
use fpm_physics::simulate::{acquire, Camera, ObjectField};
use fpm_physics::{Image, LedGeometry, LedIndex, System};

#[test]
fn a_defocused_sample_is_recovered_when_the_defocus_is_told() {
    let system = System::paper();
    let geometry = LedGeometry {
        rows: 15,
        cols: 15,
        center: LedIndex::new(7, 7),
        ..LedGeometry::paper()
    };
    let object = ObjectField::test_sample(&system, 96, 32, 2, 5);
    let camera = Camera::realistic();
    let defocus_um = 80.0;
    let shots: Vec<(LedIndex, f64)> = geometry
        .leds()
        .into_iter()
        .map(|l| (l, defocus_um))
        .collect();
    let frames = acquire(
        &system,
        &geometry,
        &object,
        &shots,
        &camera,
        |img| camera.auto_exposure(img),
        5,
    );
    let unit = camera.electrons_per_ms * camera.gain_dn_per_e;
    let images: Vec<Image> = frames
        .iter()
        .map(|f| {
            f.counts
                .mapv(|v| (v as f32 - camera.dark_level_dn as f32) / (f.exposure_ms * unit) as f32)
        })
        .collect();
    let shots = common::shots(&frames, &images);
    let truth = object.crop_to_camera();
    let m = truth.dim().0;
    let discs: Vec<(f64, f64)> = frames
        .iter()
        .map(|f| geometry.illumination_frequency(f.led, 0.0, 0.0, system.wavelength_um))
        .collect();
    let in_aperture = |fx: f64, fy: f64| {
        discs
            .iter()
            .any(|f| (fx + f.0).hypot(fy + f.1) <= system.cutoff())
    };
    let truth_bl = resample(&truth, object.pitch_um(), m, in_aperture);
    let nrmse = |told_um: f64| {
        let settings = Settings {
            upsample: 4,
            defocus_um: told_um,
            ..Settings::default()
        };
        let mut out = common::epry(&system, &geometry, &shots, settings, 12);
        let rec = resample(
            &out.sample(),
            system.sample_pixel_um() / 4.0,
            m,
            in_aperture,
        );
        complex_nrmse(&central(&rec, 0.75), &central(&truth_bl, 0.75))
    };
    let (told, as_in_focus, wrong_sign) = (nrmse(defocus_um), nrmse(0.0), nrmse(-defocus_um));
    eprintln!(
        "complex NRMSE: told {told:.3}, as in focus {as_in_focus:.3}, told the wrong sign {wrong_sign:.3}"
    );
    assert!(told < 0.5 * as_in_focus, "{told} against {as_in_focus}");
    assert!(told < 0.5 * wrong_sign, "{told} against {wrong_sign}");
}
