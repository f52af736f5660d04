//! pdcFPM calibration on data from the full wave-optics simulator (never from the shift
//! model the calibrator fits), against the hidden truth.

use fpm_physics::calibrate::Options;
use fpm_physics::simulate::CalibrationScene;
use fpm_physics::study::calibrate_simulated;
use fpm_physics::LedGeometry;

fn nominal() -> LedGeometry {
    LedGeometry::paper()
}

/// (|Δx err| µm, |Δy err| µm, |θ err| °, |h err| mm)
fn run(
    truth: LedGeometry,
    feature_at: (f64, f64),
    feature_um: f64,
    seed: u64,
) -> (f64, f64, f64, f64) {
    let mut scene = CalibrationScene::paper(truth, seed);
    scene.feature_at_um = feature_at;
    scene.feature_um = feature_um;
    let frames = scene.acquire();
    let (cal, took) =
        calibrate_simulated(&scene, &frames, &nominal(), &Options::default()).expect("calibrates");
    let errs = (
        (cal.placement.dx_mm - truth.dx_mm).abs() * 1e3,
        (cal.placement.dy_mm - truth.dy_mm).abs() * 1e3,
        (cal.placement.theta_deg - truth.theta_deg).abs(),
        (cal.placement.height_mm - truth.height_mm).abs(),
    );
    eprintln!(
        "truth ({:.3}, {:.3}, {:.2}°, {:.2}) → ({:.4}, {:.4}, {:.3}°, {:.3}) errors {:.2} µm {:.2} µm {:.4}° {:.3} mm, rms {:.4} µm, used {}, {:?}",
        truth.dx_mm, truth.dy_mm, truth.theta_deg, truth.height_mm, cal.placement.dx_mm, cal.placement.dy_mm, cal.placement.theta_deg, cal.placement.height_mm,
        errs.0, errs.1, errs.2, errs.3, cal.rms_residual_um,
        cal.leds.iter().filter(|l| l.status == fpm_physics::calibrate::LedStatus::Used).count(),
        took
    );
    errs
}

fn truth(dx: f64, dy: f64, theta: f64, h: f64) -> LedGeometry {
    LedGeometry {
        dx_mm: dx,
        dy_mm: dy,
        theta_deg: theta,
        height_mm: h,
        ..nominal()
    }
}

/// The paper's Table 1 cases: it reached 12 µm, 0.25°, 0.92 mm at worst. The required
/// bounds of the issue: 10 µm, 0.1°, 0.5 mm.
#[test]
fn beats_the_paper_on_its_table_1() {
    for (k, (dx, dy)) in [(1.5, 1.5), (2.0, 2.0), (2.5, 2.5)].into_iter().enumerate() {
        let e = run(truth(dx, dy, 5.0, 92.0), (0.0, 0.0), 50.0, 100 + k as u64);
        assert!(e.0 <= 10.0 && e.1 <= 10.0, "{e:?}");
        assert!(e.2 <= 0.1, "{e:?}");
        assert!(e.3 <= 0.5, "{e:?}");
    }
}

#[test]
fn an_off_axis_feature_and_a_negative_offset() {
    // A 30 µm feature 36 µm off the axis: its own wave vectors differ from the centre's.
    let e = run(truth(-1.7, 0.8, -3.5, 88.0), (30.0, -20.0), 30.0, 7);
    assert!(
        e.0 <= 10.0 && e.1 <= 10.0 && e.2 <= 0.1 && e.3 <= 0.5,
        "{e:?}"
    );
}
