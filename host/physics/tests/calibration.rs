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

/// A hand-soldered board: each bright-field LED off its grid place by its own move
/// (σ 0.25 mm each way). The calibration's per-LED offsets find each LED's own place
/// (compared after taking out what a placed board holds of the moves — a common shift,
/// turn and scale, which the fitted Δx, Δy, θ, h absorb); refinement inside the
/// reconstruction leaves 0.28 mm RMS of such moves (results.md, "LEDs off their grid").
#[test]
fn each_bright_field_leds_own_place_is_measured() {
    let truth = truth(1.0, -0.5, 2.0, 92.0);
    let mut scene = CalibrationScene::paper(truth, 7);
    scene.led_jitter_mm = 0.25;
    let frames = scene.acquire();
    let (cal, _) =
        calibrate_simulated(&scene, &frames, &nominal(), &Options::default()).expect("calibrates");
    // True minus measured, per LED, at its place on the board (mm).
    let mut rows = vec![];
    for r in &cal.leds {
        let (Some(measured), Some(sigma)) = (r.offset_mm, r.offset_sigma_mm) else {
            continue;
        };
        let moved = scene.led_offset_mm(r.led);
        let (x, y, _) = truth.led_position_3d_mm(r.led);
        rows.push((
            (x, y),
            (moved.0 - measured[0], moved.1 - measured[1]),
            sigma,
        ));
    }
    assert!(rows.len() >= 20, "{} LEDs measured", rows.len());
    // Take out the similarity (shift, turn, scale) that best explains the differences.
    let mut ata = nalgebra::Matrix4::<f64>::zeros();
    let mut atb = nalgebra::Vector4::<f64>::zeros();
    for &((x, y), (dx, dy), _) in &rows {
        for (a, b) in [([1.0, 0.0, x, -y], dx), ([0.0, 1.0, y, x], dy)] {
            let a = nalgebra::Vector4::from(a);
            ata += a * a.transpose();
            atb += a * b;
        }
    }
    let t = ata.try_inverse().expect("a spread of LEDs") * atb;
    // Each LED's error per axis, and its σ (per axis).
    let errors: Vec<([f64; 2], f64)> = rows
        .iter()
        .map(|&((x, y), (dx, dy), sigma)| {
            let ex = dx - (t[0] + t[2] * x - t[3] * y);
            let ey = dy - (t[1] + t[3] * x + t[2] * y);
            ([ex, ey], sigma)
        })
        .collect();
    let per_axis = |e: [f64; 2]| e[0].hypot(e[1]) / 2f64.sqrt();
    let rms =
        (errors.iter().map(|e| per_axis(e.0).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
    let grid = fpm_physics::calibrate::calibration_grid(&truth, scene.half_grid);
    let moved_rms = (grid
        .iter()
        .map(|&led| {
            let m = scene.led_offset_mm(led);
            0.5 * (m.0 * m.0 + m.1 * m.1)
        })
        .sum::<f64>()
        / grid.len() as f64)
        .sqrt();
    let median_sigma = {
        let mut s: Vec<f64> = errors.iter().map(|e| e.1).collect();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    };
    eprintln!(
        "per-LED offsets: {} LEDs moved {moved_rms:.3} mm RMS, measured to {rms:.4} mm RMS (median σ {median_sigma:.4} mm); worst {:.4} mm",
        errors.len(),
        errors.iter().map(|e| per_axis(e.0)).fold(0.0, f64::max)
    );
    // Measured: 0.0030 mm RMS of 0.254 mm moves, every LED within 3σ of its own σ.
    assert!(
        rms < 0.05 * moved_rms,
        "{rms} mm left of {moved_rms} mm of moves"
    );
    // Each LED's error on each axis against its own σ (a normal passes 4σ once in
    // 16 000).
    let worst = errors
        .iter()
        .map(|&(e, sigma)| e[0].abs().max(e[1].abs()) / sigma)
        .fold(0.0, f64::max);
    eprintln!("farthest LED on either axis: {worst:.2}σ of its own σ");
    assert!(worst < 4.0, "an LED {worst:.2}σ off its measured place");
}
