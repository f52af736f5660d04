//! A field larger than the illumination's curvature allows one plane wave per LED to
//! describe, from the full wave-optics simulator (spherical waves from every LED):
//! reconstructed with the defaults, it comes back without a phase bowl, and no worse
//! than the tilings one would try by hand.

use fpm_physics::frame::LitFrame;
use fpm_physics::metrics::{central, complex_nrmse, resample};
use fpm_physics::reconstruct::{tiled, Settings};
use fpm_physics::simulate::{acquire_in_focus, Camera, ObjectField};
use fpm_physics::tiles::auto_tile_side;
use fpm_physics::{LedGeometry, LedIndex, System};
use ndarray::Array2;
use rustfft::num_complex::Complex32;

/// Complex NRMSE against the truth (both band-limited to the synthetic aperture, the
/// central 75 %), and the phase bowl: the quadratic term of the phase error, in rad at
/// the edge of that central region.
fn score(
    rec: &Array2<Complex32>,
    rec_pitch_um: f64,
    truth: &Array2<Complex32>,
    truth_pitch_um: f64,
    in_aperture: &impl Fn(f64, f64) -> bool,
) -> (f64, f64) {
    let m = truth.dim().0;
    let t = central(&resample(truth, truth_pitch_um, m, in_aperture), 0.75);
    let r = central(&resample(rec, rec_pitch_um, m, in_aperture), 0.75);
    let nrmse = complex_nrmse(&r, &t);
    // Phase error, after the best global phase, fitted by a + b·x + c·y + q·(x² + y²)
    // with x, y in units of the region's half-width.
    let c: Complex32 = r.iter().zip(&t).map(|(a, b)| a.conj() * b).sum();
    let rotate = c / c.norm();
    let m75 = ((m as f64) * 0.75).round() as usize;
    let half = m75 as f64 / 2.0;
    let mut rows = vec![];
    let mut rhs = vec![];
    for (k, (v, w)) in r.iter().zip(&t).enumerate() {
        let d = (v * rotate * w.conj()).arg() as f64;
        let (i, j) = (k / m75, k % m75);
        let (x, y) = ((j as f64 - half) / half, (i as f64 - half) / half);
        rows.push([1.0, x, y, x * x + y * y]);
        rhs.push(d);
    }
    let a = nalgebra::DMatrix::from_fn(rows.len(), 4, |i, k| rows[i][k]);
    let b = nalgebra::DVector::from_vec(rhs);
    let fit = a.svd(true, true).solve(&b, 1e-12).expect("least squares");
    (nrmse, fit[3])
}

#[test]
fn a_field_wider_than_the_curvature_allows_comes_back_flat_with_the_default_tiles() {
    // 240 camera pixels of 1.2 µm at the sample: a 288 µm field, across which the
    // axial LED's wave at 92 mm turns by 1.4 rad from centre to edge (more than a
    // frequency bin of local tilt), on a 13×13 array.
    let system = System {
        pixel_size_um: 4.8,
        ..System::paper()
    };
    let geometry = LedGeometry {
        rows: 13,
        cols: 13,
        center: LedIndex::new(6, 6),
        ..LedGeometry::paper()
    };
    let w = 240;
    let object = ObjectField::test_sample(&system, w, 24, 2, 3);
    let camera = Camera::realistic();
    let frames = acquire_in_focus(&system, &geometry, &object, &camera, 5);
    let lit: Vec<LitFrame> = frames.iter().map(|f| f.lit(&camera)).collect();
    let settings = Settings {
        upsample: 2,
        ..Settings::default()
    };
    let truth = object.crop_to_camera();
    let cutoff = system.cutoff();
    let discs: Vec<(f64, f64)> = frames
        .iter()
        .map(|f| geometry.illumination_frequency(f.led, 0.0, 0.0, system.wavelength_um))
        .collect();
    let in_aperture = |fx: f64, fy: f64| discs.iter().any(|f| (fx + f.0).hypot(fy + f.1) <= cutoff);
    let rec_pitch = system.sample_pixel_um() / 2.0;
    let run = |tile: Option<usize>| {
        let out = tiled::reconstruct(&system, &geometry, &lit, settings, 8, tile, &|_, _| {})
            .expect("reconstructs");
        let (nrmse, bowl) = score(
            &out.object,
            rec_pitch,
            &truth,
            object.pitch_um(),
            &in_aperture,
        );
        (out.layout.size, out.layout.tiles.len(), nrmse, bowl)
    };

    let auto = auto_tile_side(&system, &geometry);
    let default = run(None);
    let by_hand: Vec<_> = [w, 160, 96].into_iter().map(|t| run(Some(t))).collect();
    eprintln!("physics tile side {auto} px; default {default:.3?}; by hand {by_hand:.3?}");
    let best = by_hand.iter().map(|r| r.2).fold(f64::INFINITY, f64::min);
    assert!(
        default.2 <= 1.1 * best,
        "default {default:?} against the best by hand {best}"
    );
    // No bowl: the curvature, 1.4 rad at the field's edge, is neither left in nor
    // removed twice.
    assert!(default.3.abs() < 0.15, "phase bowl {:.3} rad", default.3);
}
