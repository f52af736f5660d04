//! Far from the axis, an LED's direct light can cross the pupil edge inside a tile:
//! the frame is partly bright, which neither the bright-field nor the dark-field rule
//! describes (the vignetting of Fourier ptychography's off-axis fields). On a 1024²
//! field from the full wave-optics simulator, with the array 2 mm off the axis, the
//! corner tiles must come back within 1.3× of the centre tile's NRMSE.

use fpm_physics::frame::LitFrame;
use fpm_physics::metrics::complex_nrmse;
use fpm_physics::reconstruct::{tiled, Settings};
use fpm_physics::simulate::{acquire_in_focus, Camera, ObjectField};
use fpm_physics::{LedGeometry, System};

/// LEDs whose light is bright-field at some corner of the square `side_um` wide at
/// `centre_um` and dark-field at another: the partly bright frames there.
fn straddling(
    geometry: &LedGeometry,
    system: &System,
    centre_um: (f64, f64),
    side_um: f64,
) -> usize {
    let h = side_um / 2.0;
    let corners = [(-h, -h), (h, -h), (-h, h), (h, h)];
    geometry
        .leds()
        .into_iter()
        .filter(|&led| {
            let lit: Vec<bool> = corners
                .iter()
                .map(|(dx, dy)| {
                    geometry.is_bright_field(led, centre_um.0 + dx, centre_um.1 + dy, system)
                })
                .collect();
            lit.iter().any(|&b| b) && lit.iter().any(|&b| !b)
        })
        .count()
}

#[test]
fn corner_tiles_of_an_off_axis_array_are_as_good_as_the_centre() {
    let system = System::paper();
    // 2 mm off the axis, diagonally, and turned: the reconstruction is given the
    // true placement (calibration is another test's business).
    let geometry = LedGeometry {
        dx_mm: 1.414,
        dy_mm: 1.414,
        theta_deg: 3.0,
        ..LedGeometry::paper()
    };
    let size = 1024;
    let object = ObjectField::test_sample(&system, size, 48, 2, 4);
    let camera = Camera::realistic();
    let frames = acquire_in_focus(&system, &geometry, &object, &camera, 4);
    let lit: Vec<LitFrame> = frames.iter().map(|f| f.lit(&camera)).collect();
    let settings = Settings {
        upsample: 2,
        ..Settings::default()
    };
    let out = tiled::reconstruct(&system, &geometry, &lit, settings, 5, None, &|_, _| {})
        .expect("reconstructs");
    let truth = object.crop_to_camera();
    assert_eq!(
        truth.dim(),
        out.object.dim(),
        "the truth's grid is the reconstruction's"
    );

    // Each tile scored on its inner part (an eighth of the side off each edge, where
    // the blend gives it full weight), its own global complex factor removed.
    let side = out.layout.size;
    let pixel_um = system.sample_pixel_um();
    let scores: Vec<((f64, f64), f64, usize)> = out
        .tiles
        .iter()
        .map(|t| {
            let m = side / 8;
            let rows = 2 * (t.tile.y0 + m)..2 * (t.tile.y0 + side - m);
            let cols = 2 * (t.tile.x0 + m)..2 * (t.tile.x0 + side - m);
            let region = ndarray::s![rows, cols];
            let r: Vec<_> = out.object.slice(region).iter().copied().collect();
            let w: Vec<_> = truth.slice(region).iter().copied().collect();
            let partly = straddling(&geometry, &system, t.centre_um, side as f64 * pixel_um);
            (t.centre_um, complex_nrmse(&r, &w), partly)
        })
        .collect();
    for (centre, nrmse, partly) in &scores {
        eprintln!(
            "tile at ({:+7.1}, {:+7.1}) µm: NRMSE {nrmse:.3}, {partly} partly bright frames",
            centre.0, centre.1
        );
    }
    let centre = scores
        .iter()
        .min_by(|a, b| a.0 .0.hypot(a.0 .1).total_cmp(&b.0 .0.hypot(b.0 .1)))
        .expect("tiles");
    let far = centre.0 .0.hypot(centre.0 .1) + 1.0;
    let corners: Vec<_> = scores
        .iter()
        .filter(|s| s.0 .0.abs() > far / 2.0 && s.0 .1.abs() > far / 2.0)
        .collect();
    assert_eq!(corners.len(), 4, "a 3×3 tiling has four corner tiles");
    // The case is hard enough: the edge of the bright field crosses corner tiles.
    let crossed = corners.iter().filter(|c| c.2 > 0).count();
    assert!(
        crossed >= 2,
        "partly bright frames in only {crossed} corner tiles"
    );
    for corner in corners {
        assert!(
            corner.1 <= 1.3 * centre.1,
            "corner at {:?}: NRMSE {:.3} against the centre's {:.3}",
            corner.0,
            corner.1,
            centre.1
        );
    }
}
