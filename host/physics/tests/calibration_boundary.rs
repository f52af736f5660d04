//! h without trusting the stage: a calibration whose defocus is misreported by 10 %
//! gets h 10 % wrong, and the bright/dark-field boundary of the in-focus acquisition
//! (full wave-optics simulator, every LED of the 21×21 array, the truth hidden) brings
//! it back.

use fpm_physics::calibrate::{boundary, Options};
use fpm_physics::frame::LitFrame;
use fpm_physics::simulate::{acquire, CalibrationScene, ObjectField, SimFrame};
use fpm_physics::study::calibrate_simulated;
use fpm_physics::{LedGeometry, LedIndex};

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
        let shift_error = cal.height_mm - truth.height_mm;
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
        let h = cal.height_mm;
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
