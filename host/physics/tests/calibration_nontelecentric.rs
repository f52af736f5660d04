//! pdcFPM through an objective that is not telecentric (a camera lens, a simple
//! low-power objective): its entrance pupil at a finite distance p.

use fpm_physics::calibrate::Options;
use fpm_physics::coverage::errors;
use fpm_physics::simulate::CalibrationScene;
use fpm_physics::study::calibrate_simulated;
use fpm_physics::LedGeometry;

/// The defocused feature's shift is the shadow its illumination casts over the defocus,
/// whatever the pupil: with the pupil 15 mm above the focal plane and the feature
/// (15, −10) µm off the axis, the array is still found within 3σ. A simulator (or a
/// calibrator) that let the pupil's chirp travel with the defocus would see a
/// magnification z·x/p, common to all LEDs, and read it as the board moved by x·h/p:
/// (−91, +61) µm here, some 50σ.
#[test]
fn an_entrance_pupil_at_a_finite_distance_does_not_move_the_array() {
    let truth = LedGeometry::paper().placed(0.9, -0.7, 3.0, 91.0);
    for (p, seed) in [(15.0, 5u64), (40.0, 6)] {
        let mut scene = CalibrationScene::paper(truth, seed);
        scene.system.entrance_pupil_mm = Some(p);
        scene.feature_at_um = (15.0, -10.0);
        let frames = scene.acquire();
        let (c, _) =
            calibrate_simulated(&scene, &frames, &LedGeometry::paper(), &Options::default())
                .expect("the calibration set calibrates");
        let (e, s) = errors(&c, &truth);
        eprintln!("p {p} mm: errors {e:.3?} (Δx, Δy µm, θ °, h mm), σ {s:.3?}");
        for k in 0..4 {
            assert!(
                e[k].abs() <= 3.0 * s[k],
                "p {p} mm: parameter {k}: {e:?} beyond 3σ {s:?}"
            );
        }
        // The shifts' own accuracy, as on a telecentric objective (~1.6 µm σ).
        assert!(e[0].hypot(e[1]) < 5.0, "p {p} mm: Δx, Δy off by {e:?} µm");
    }
}
