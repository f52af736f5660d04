//! pdcFPM calibration with the feature near the frame's edge, on data from the full
//! wave-optics simulator (the truth hidden): every defocused window is cut by the
//! frame's edge. The moment is then biased toward the inside; the bias model, cut the
//! same way, accounts for it, so the frames are used rather than lost (they used to be
//! refused: "0 usable bright-field frames (25 lost the feature)"), and the uncertainty
//! still covers the error.

use fpm_physics::calibrate::{CalibrationError, LedStatus, Options};
use fpm_physics::simulate::CalibrationScene;
use fpm_physics::study::calibrate_simulated;
use fpm_physics::LedGeometry;

fn scene(truth: LedGeometry, x_um: f64, seed: u64) -> CalibrationScene {
    let mut scene = CalibrationScene::paper(truth, seed);
    // The 256² frame spans ±77 µm; the 50 µm feature's defocused windows reach past it.
    scene.feature_at_um = (x_um, 0.3 * x_um);
    scene
}

#[test]
fn a_feature_whose_defocused_windows_the_edge_cuts_still_calibrates_within_its_uncertainty() {
    let truths = [
        LedGeometry {
            dx_mm: 1.2,
            dy_mm: -0.8,
            theta_deg: 3.0,
            height_mm: 91.0,
            ..LedGeometry::paper()
        },
        LedGeometry {
            dx_mm: -0.6,
            dy_mm: 1.5,
            theta_deg: -2.0,
            height_mm: 94.0,
            ..LedGeometry::paper()
        },
    ];
    for (k, truth) in truths.into_iter().enumerate() {
        for x in [40.0, 44.0, 48.0] {
            let scene = scene(truth, x, 700 + k as u64);
            let frames = scene.acquire();
            let (cal, _) =
                calibrate_simulated(&scene, &frames, &LedGeometry::paper(), &Options::default())
                    .unwrap_or_else(|e| panic!("x = {x} µm: {e}"));
            let used = cal.leds.iter().filter(|l| l.status == LedStatus::Used);
            let cut = used.clone().filter(|l| l.cut_by_edge).count();
            let (p, u) = (cal.placement, cal.uncertainty);
            let errors = [
                ((p.dx_mm - truth.dx_mm) * 1e3, u.dx_mm * 1e3),
                ((p.dy_mm - truth.dy_mm) * 1e3, u.dy_mm * 1e3),
                (p.theta_deg - truth.theta_deg, u.theta_deg),
                (p.height_mm - truth.height_mm, u.height_mm),
            ];
            eprintln!(
                "x = {x} µm: {} used, {cut} of them cut by the edge; (error, 1σ): Δx {:.2?} µm, Δy {:.2?} µm, θ {:.4?}°, h {:.3?} mm",
                used.count(),
                errors[0],
                errors[1],
                errors[2],
                errors[3]
            );
            assert!(cut >= 10, "the edge cuts the windows here: {cut}");
            for (e, sigma) in errors {
                assert!(
                    e.abs() <= 3.0 * sigma,
                    "x = {x} µm: error {e} against 1σ {sigma}"
                );
            }
        }
    }
}

/// Without the bias model nothing can account for the cut: the frames are lost, and
/// the refusal says what would help.
#[test]
fn without_the_bias_model_cut_frames_are_lost_and_the_refusal_says_what_helps() {
    let scene = scene(LedGeometry::paper(), 44.0, 9);
    let frames = scene.acquire();
    let options = Options {
        bias_correction: false,
        ..Options::default()
    };
    match calibrate_simulated(&scene, &frames, &LedGeometry::paper(), &options) {
        Err(e @ CalibrationError::TooFew { .. }) => {
            let text = e.to_string();
            assert!(
                text.contains("lost the feature") && text.contains("--roi"),
                "{text}"
            );
        }
        other => panic!("expected a refusal, got {:?}", other.map(|c| c.0.placement)),
    }
}
