//! h without trusting the stage: a calibration whose defocus is misreported by 10 %
//! gets h 10 % wrong, and the bright/dark-field boundary of the in-focus acquisition
//! (full wave-optics simulator, every LED of the 21×21 array, the truth hidden) brings
//! it back.

use fpm_physics::calibrate::{boundary, Options};
use fpm_physics::frame::LitFrame;
use fpm_physics::simulate::{acquire, CalibrationScene, Camera, ObjectField, SimFrame};
use fpm_physics::study::calibrate_simulated;
use fpm_physics::{LedGeometry, LedIndex, System};

#[test]
fn the_boundary_gives_h_when_the_defocus_is_misreported() {
    let nominal = LedGeometry::paper();
    for (k, truth) in [
        nominal.placed(0.9, -0.7, 3.0, 91.0),
        nominal.placed(-1.6, 1.1, -4.0, 95.5),
    ]
    .into_iter()
    .enumerate()
    {
        // The calibration, told a defocus 10 % larger than the stage moved.
        let scene = CalibrationScene::paper(truth, 500 + k as u64);
        let frames = scene.acquire();
        let told: Vec<SimFrame> = frames
            .iter()
            .map(|f| SimFrame {
                defocus_um: f.defocus_um * 1.1,
                ..f.clone()
            })
            .collect();
        let (cal, _) =
            calibrate_simulated(&scene, &told, &nominal, &Options::default()).expect("calibrates");
        let shift_error = cal.placement.height_mm - truth.height_mm;
        assert!(
            shift_error > 5.0,
            "a 10 % defocus error moves h by ~9 mm: {shift_error:.2}"
        );

        // The in-focus acquisition under every LED, at one exposure. The simulator
        // applies the pupil on the padded grid's frequency bins, which moves its edge
        // by up to half a bin (~1/(2·extent)): a wide margin keeps that below 0.3 % of
        // the NA. The camera's own sampling holds every frequency that reaches the
        // pupil from LEDs near the edge, so the sample needs no finer grid.
        let w = 128;
        let object = ObjectField::test_sample(&scene.system, w, 576, 1, 9 + k as u64);
        let shots: Vec<(LedIndex, f64)> = nominal.leds().into_iter().map(|l| (l, 0.0)).collect();
        let acquisition = acquire(
            &scene.system,
            &truth,
            &object,
            &shots,
            &scene.camera,
            |_| 20.0,
            77 + k as u64,
        );
        let lit: Vec<LitFrame> = acquisition.iter().map(|f| f.lit(&scene.camera)).collect();
        let h = cal.placement.height_mm;
        let b = boundary::from_frames(
            &scene.system,
            &cal.geometry(&nominal),
            &lit,
            nominal.center,
            8,
            (0.75 * h, 1.33 * h),
        )
        .expect("the boundary brackets h");
        let e = b.height_mm - truth.height_mm;
        eprintln!(
            "truth h {:.3}: shifts {:.3} (z 10 % off), boundary {:.3} ± {:.3} mm (best {:.3?}, {} deciding frames, {} partly bright, {} blocks mismatched)",
            truth.height_mm, h, b.height_mm, b.sigma_mm, b.best_range_mm, b.deciding_frames, b.partly_bright, b.mismatched_blocks
        );
        assert!(e.abs() <= 0.5, "boundary h off by {e:.3} mm");
        assert!(
            e.abs() <= 3.0 * b.sigma_mm,
            "{e:.3} mm beyond 3σ ({:.3})",
            b.sigma_mm
        );
    }
}

/// docs/dataset.md §2: through an objective whose entrance pupil is 40 mm above the
/// sample (simulated by Fresnel propagation to the pupil), the edges across a 614 µm
/// field fit that distance, and a telecentric acquisition of the same field is not
/// taken for one.
#[test]
fn the_edges_find_an_entrance_pupil_at_a_finite_distance() {
    let geometry = LedGeometry::paper();
    // 1.2 µm pixels: the camera's own grid holds every frequency that reaches the
    // pupil from LEDs near the edge, so 512 px span 614 µm at one simulation pixel each.
    let telecentric = System {
        pixel_size_um: 4.8,
        ..System::paper()
    };
    let camera = Camera::realistic();
    let w = 512;
    let object = ObjectField::test_sample(&telecentric, w, 256, 1, 21);
    // The reference and every LED whose edge can cross the field (h·NA ≈ 9.2 mm).
    let shots: Vec<(LedIndex, f64)> = geometry
        .leds()
        .into_iter()
        .filter(|&l| {
            let (x, y) = geometry.led_position_mm(l);
            l == geometry.center || (6.0..13.0).contains(&x.hypot(y))
        })
        .map(|l| (l, 0.0))
        .collect();
    let fit = |system: &System| {
        let frames = acquire(
            system,
            &geometry,
            &object,
            &shots,
            &camera,
            |img| camera.auto_exposure(img),
            31,
        );
        let lit: Vec<LitFrame> = frames.iter().map(|f| f.lit(&camera)).collect();
        let reader = boundary::BlockReader::from_frames(&telecentric, &lit, geometry.center, 16)
            .expect("the reference frame");
        let search = (69.0, 122.0);
        let as_given = reader
            .estimate(&telecentric, &geometry, search)
            .expect("the edges bound h");
        reader
            .fit_entrance_pupil(&telecentric, &geometry, search, &as_given)
            .expect("the edges bound h")
    };
    let far = fit(&System {
        entrance_pupil_mm: Some(40.0),
        ..telecentric
    });
    eprintln!("pupil at 40 mm: {far:?}");
    let p = far.entrance_pupil_mm.expect("a finite distance");
    assert!((p / 40.0 - 1.0).abs() < 0.15, "{p} mm");
    assert!(far.fits_better(None), "{far:?}");
    assert!(
        (far.mismatched_blocks as f64) < 0.6 * far.mismatched_blocks_as_given as f64,
        "{far:?}"
    );
    assert!((far.height_mm - 92.0).abs() < 3.0, "{far:?}");
    let straight = fit(&telecentric);
    eprintln!("telecentric: {straight:?}");
    assert!(!straight.fits_better(None), "{straight:?}");
}
