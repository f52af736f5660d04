//! A tilted LED board, from the full wave-optics simulator (each LED at its own height,
//! its spherical wave rendered and defocused by the angular spectrum), calibrated
//! against the flat nominal array with the truth hidden.

use fpm_physics::calibrate::{Calibration, Options};
use fpm_physics::coverage::errors;
use fpm_physics::simulate::CalibrationScene;
use fpm_physics::study::calibrate_simulated;
use fpm_physics::LedGeometry;

fn calibrate(scene: &CalibrationScene, options: &Options) -> Calibration {
    let frames = scene.acquire();
    calibrate_simulated(scene, &frames, &LedGeometry::paper(), options)
        .expect("calibrates")
        .0
}

/// Boards tilted by 1–2° about x, about y and about both: the tilt is seen and
/// recovered within its 3σ, and Δx, Δy, θ, h are as accurate as on a flat board
/// (within 3σ and within the flat board's bounds), while the flat model, fitted to the
/// same frames, is biased by several µm.
#[test]
fn a_tilted_board_no_longer_biases_the_array() {
    let flat_only = Options {
        fit_tilt: false,
        ..Options::default()
    };
    let mut worst_flat = 0.0f64;
    for (k, (tx, ty)) in [(2.0, 0.0), (0.0, -2.0), (-1.5, 1.0), (1.0, 1.0)]
        .into_iter()
        .enumerate()
    {
        let truth = LedGeometry::paper()
            .placed(0.9, -0.7, 3.0, 91.0)
            .tilted(tx, ty);
        let scene = CalibrationScene::paper(truth, 300 + k as u64);
        let c = calibrate(&scene, &Options::default());
        let (e, s) = errors(&c, &truth);
        let tilt_e = [c.placement.tilt_x_deg - tx, c.placement.tilt_y_deg - ty];
        let tilt_s = [c.uncertainty.tilt_x_deg, c.uncertainty.tilt_y_deg];
        eprintln!(
            "tilt ({tx}, {ty})°: found ({:.2} ± {:.2}, {:.2} ± {:.2})°; errors {e:.3?} σ {s:.3?}",
            c.placement.tilt_x_deg, tilt_s[0], c.placement.tilt_y_deg, tilt_s[1]
        );
        assert!(c.tilt_observable, "a 25-LED calibration sees a 1–2° tilt");
        for p in 0..2 {
            assert!(tilt_s[p] < 0.5, "tilt σ {tilt_s:?}");
            assert!(
                tilt_e[p].abs() <= 3.0 * tilt_s[p],
                "tilt {tilt_e:?} σ {tilt_s:?}"
            );
        }
        for p in 0..4 {
            assert!(
                e[p].abs() <= 3.0 * s[p],
                "parameter {p}: {e:?} beyond 3σ {s:?}"
            );
        }
        // ~2σ of these frames' shift noise (σ ≈ 1.7 µm), well inside the flat
        // model's misses below.
        assert!(e[0].abs() <= 3.5 && e[1].abs() <= 3.5, "{e:?}");
        assert!(e[2].abs() <= 0.05 && e[3].abs() <= 0.1, "{e:?}");

        let flat = calibrate(&scene, &flat_only);
        let (ef, _) = errors(&flat, &truth);
        eprintln!("  the flat model: errors {ef:.3?}");
        worst_flat = worst_flat.max(ef[0].abs().max(ef[1].abs()));
    }
    // The cases are hard enough to matter: the flat model misses by more than the
    // tilted one is allowed.
    assert!(
        worst_flat > 4.0,
        "the flat model's worst Δx/Δy error {worst_flat:.2} µm"
    );
}

/// A flat board: the tilt is found to be zero within its uncertainty, and fitting it
/// costs little precision.
#[test]
fn a_flat_board_is_found_flat() {
    let truth = LedGeometry::paper().placed(-1.2, 0.4, -2.0, 94.0);
    let scene = CalibrationScene::paper(truth, 41);
    let c = calibrate(&scene, &Options::default());
    assert!(c.tilt_observable);
    assert!(
        c.placement.tilt_x_deg.abs() <= 3.0 * c.uncertainty.tilt_x_deg,
        "{c:?}"
    );
    assert!(
        c.placement.tilt_y_deg.abs() <= 3.0 * c.uncertainty.tilt_y_deg,
        "{c:?}"
    );
    let cost = c
        .uncertainty_sources
        .and_then(|b| b.tilt)
        .expect("the tilt's share of the budget");
    assert!(
        cost.dx_mm < 0.5 * c.uncertainty.dx_mm,
        "{cost:?} of {:?}",
        c.uncertainty
    );
}
