//! EPRY on data from the full wave-optics simulator: with the true geometry the
//! reconstruction must be far closer to the (synthetic-aperture band-limited) truth
//! than the up-sampled centre frame.

mod common;

use fpm_physics::metrics::{central, complex_nrmse, resample};
use fpm_physics::reconstruct::Settings;
use fpm_physics::simulate::{acquire, Camera, ObjectField};
use fpm_physics::{Image, LedGeometry, LedIndex, System};
use rustfft::num_complex::Complex32;

#[test]
fn epry_beats_the_centre_frame_by_far() {
    let system = System::paper();
    let geometry = LedGeometry {
        rows: 15,
        cols: 15,
        pitch_mm: 2.5,
        height_mm: 92.0,
        center: LedIndex::new(7, 7),
        dx_mm: 0.3,
        dy_mm: -0.2,
        theta_deg: 1.0,

        tilt_x_deg: 0.0,
        tilt_y_deg: 0.0,
        rings: None,
        list: None,
    };
    let w = 96;
    let object = ObjectField::test_sample(&system, w, 32, 2, 5);
    let camera = Camera::realistic();
    let shots: Vec<(LedIndex, f64)> = geometry.leds().into_iter().map(|l| (l, 0.0)).collect();
    let frames = acquire(
        &system,
        &geometry,
        &object,
        &shots,
        &camera,
        |img| camera.auto_exposure(img),
        11,
    );
    // Intensity relative to a clear field: (counts − dark) / (exposure · e⁻/ms · gain).
    let unit = camera.electrons_per_ms * camera.gain_dn_per_e;
    let norm = |k: usize| -> Image {
        frames[k].counts.mapv(|v| {
            (v as f32 - camera.dark_level_dn as f32) / (frames[k].exposure_ms * unit) as f32
        })
    };
    let centre = shots
        .iter()
        .position(|s| s.0 == LedIndex::new(7, 7))
        .unwrap();
    let freq =
        |k: usize| geometry.illumination_frequency(frames[k].led, 0.0, 0.0, system.wavelength_um);
    let settings = Settings {
        upsample: 4,
        ..Settings::default()
    };
    let images: Vec<Image> = (0..frames.len()).map(norm).collect();
    let shots = common::shots(&frames, &images);
    let mut out = common::epry(&system, &geometry, &shots, settings, 12);
    assert_eq!(
        shots[out.initial].led,
        LedIndex::new(7, 7),
        "starts from the axial LED"
    );
    let errors = out.errors.clone();
    let rec = out.sample();

    // Compare on the truth's grid, both band-limited to the synthetic aperture.
    let truth = object.crop_to_camera();
    let m = truth.dim().0;
    let cutoff = system.cutoff();
    let discs: Vec<(f64, f64)> = (0..frames.len()).map(freq).collect();
    let in_aperture = |fx: f64, fy: f64| discs.iter().any(|f| (fx + f.0).hypot(fy + f.1) <= cutoff);
    let truth_bl = resample(&truth, object.pitch_um(), m, in_aperture);
    let rec_on_truth = resample(&rec, system.sample_pixel_um() / 4.0, m, in_aperture);
    let nrmse = complex_nrmse(&central(&rec_on_truth, 0.75), &central(&truth_bl, 0.75));
    // The centre frame's amplitude, up-sampled, as the baseline.
    let base: ndarray::Array2<Complex32> =
        images[centre].mapv(|v| Complex32::new(v.max(0.0).sqrt(), 0.0));
    let base_on_truth = resample(&base, system.sample_pixel_um(), m, |_, _| true);
    let base_nrmse = complex_nrmse(&central(&base_on_truth, 0.75), &central(&truth_bl, 0.75));
    eprintln!("per-pass amplitude error {errors:.4?}; NRMSE EPRY {nrmse:.3} vs centre frame {base_nrmse:.3}");
    // The data misfit falls from the first pass (later it may creep up again as the
    // adaptive step stops the estimate from chasing noise).
    let best = errors[1..].iter().copied().fold(f64::INFINITY, f64::min);
    assert!(
        best < errors[0],
        "passes must reduce the misfit: {errors:?}"
    );
    assert!(
        nrmse < 0.5 * base_nrmse,
        "EPRY {nrmse} vs centre frame {base_nrmse}"
    );

    // The same frames streamed in a scrambled order (dark-field first), then finished:
    // as good as the offline run.
    let mut streaming = fpm_physics::reconstruct::Streaming::new(system, geometry, settings);
    let mut scrambled: Vec<usize> = (0..frames.len()).collect();
    scrambled.sort_by_key(|&k| std::cmp::Reverse((k * 7919) % 225));
    scrambled.sort_by_key(|&k| {
        let f = freq(k);
        f.0.hypot(f.1) < system.cutoff()
    });
    assert!(
        !streaming.push(frames[scrambled[0]].led, images[scrambled[0]].clone()),
        "no estimate before a bright-field frame"
    );
    assert!(streaming.snapshot().is_none());
    for &k in &scrambled[1..] {
        streaming.push(frames[k].led, images[k].clone());
    }
    assert!(streaming.snapshot().is_some());
    let mut finished = streaming.finish(&shots, 11).unwrap();
    assert_eq!(finished.errors.len(), 11);
    let streamed = resample(
        &finished.sample(),
        system.sample_pixel_um() / 4.0,
        m,
        in_aperture,
    );
    let streamed_nrmse = complex_nrmse(&central(&streamed, 0.75), &central(&truth_bl, 0.75));
    eprintln!("streamed NRMSE {streamed_nrmse:.3}");
    assert!(
        streamed_nrmse < 1.2 * nrmse,
        "streamed {streamed_nrmse} vs offline {nrmse}"
    );
}

/// The paper's Fig. 1 and Fig. 5 trends on data from the full wave-optics model: a
/// misplaced array ruins the reconstruction with the nominal geometry, and the geometry
/// pdcFPM recovers from a separate simulated calibration set brings it back to within
/// 20 % of what the true geometry gives.
#[test]
fn calibration_recovers_what_a_misplaced_array_costs() {
    let system = System::paper();
    let nominal = LedGeometry::paper();
    for (dx, dy, theta) in [(0.8, 0.0, 0.0), (2.0, 2.0, 5.0)] {
        let truth = nominal.placed(dx, dy, theta, 92.0);
        let case = fpm_physics::study::geometry_case(&system, &nominal, &truth, 96, 10, 3)
            .expect("the case runs");
        let label = format!("array at ({dx}, {dy}) mm, {theta}°");
        assert!(
            case.nrmse_true < 0.6 * case.nrmse_centre_frame,
            "{label}: the true geometry must beat the centre frame: {case:?}"
        );
        assert!(
            case.nrmse_nominal > 2.0 * case.nrmse_true,
            "{label}: the nominal geometry should fail: {case:?}"
        );
        assert!(
            case.nrmse_calibrated <= 1.2 * case.nrmse_true,
            "{label}: calibrated must be within 20 % of true: {case:?}"
        );
    }
}

/// Tiled streaming is the offline tiled reconstruction fed early: frames of a field cut
/// into tiles, pushed one by one as an acquisition delivers them (nearest-first), then
/// finished, must score against the truth as well as the offline run over the same
/// tiles does.
#[test]
fn tiled_streaming_is_as_good_as_offline_tiles() {
    use fpm_physics::frame::{Counts, LitFrame, Measured, Response};
    use fpm_physics::reconstruct::{tiled, TiledStreaming};

    let system = System::paper();
    let geometry = LedGeometry::grid(15, 15, 2.5, 92.0, LedIndex::new(7, 7));
    let w = 160;
    let tile = Some(80);
    let object = ObjectField::test_sample(&system, w, 32, 2, 7);
    let camera = Camera::realistic();
    let all = geometry.leds();
    let order = geometry.nearest_first(&all, (0.0, 0.0), &system);
    let shots: Vec<(LedIndex, f64)> = order.iter().map(|&k| (all[k], 0.0)).collect();
    let frames = acquire(
        &system,
        &geometry,
        &object,
        &shots,
        &camera,
        |img| camera.auto_exposure(img),
        13,
    );
    let lit: Vec<LitFrame> = frames
        .iter()
        .map(|f| LitFrame {
            also: &[],
            led: f.led,
            measured: Measured {
                counts: Counts::U16(f.counts.view()),
                response: Response::Linear,
                dark_level: camera.dark_level_dn as f32,
                exposure_ms: f.exposure_ms as f32,
                floor: 0.0,
                soft_floor: false,
                band: 0.0,
            },
        })
        .collect();
    let settings = Settings::default();
    let passes = 6;
    let offline = tiled::reconstruct(&system, &geometry, &lit, settings, passes, tile, &|_, _| {})
        .expect("offline tiles");
    assert!(offline.tiles.len() >= 4, "{} tiles", offline.tiles.len());

    let mut streaming = TiledStreaming::new(system, geometry, settings, w, w, tile);
    for f in &lit {
        streaming.push(f).expect("frame of the right size");
    }
    assert_eq!(streaming.layout(), &offline.layout, "the same tiles");
    let streamed = streaming
        .finish(&lit, passes - 1, &|_, _| {})
        .expect("streamed tiles");
    // A frame of another size is refused, naming it.
    let mut other = TiledStreaming::new(system, geometry, settings, w, w / 2, tile);
    assert!(other.push(&lit[0]).is_err());

    let truth = object.crop_to_camera();
    let m = truth.dim().0;
    let discs: Vec<(f64, f64)> = frames
        .iter()
        .map(|f| geometry.illumination_frequency(f.led, 0.0, 0.0, system.wavelength_um))
        .collect();
    let cutoff = system.cutoff();
    let in_aperture = |fx: f64, fy: f64| discs.iter().any(|f| (fx + f.0).hypot(fy + f.1) <= cutoff);
    let truth_bl = resample(&truth, object.pitch_um(), m, in_aperture);
    let nrmse = |rec: &ndarray::Array2<Complex32>| {
        let on_truth = resample(rec, system.sample_pixel_um() / 4.0, m, in_aperture);
        complex_nrmse(&central(&on_truth, 0.75), &central(&truth_bl, 0.75))
    };
    let (n_offline, n_streamed) = (nrmse(&offline.object), nrmse(&streamed.object));
    eprintln!("tiles: offline NRMSE {n_offline:.3}, streamed {n_streamed:.3}");
    assert!(n_offline < 0.3, "offline tiles {n_offline}");
    assert!(
        n_streamed < 1.2 * n_offline,
        "streamed {n_streamed} vs offline {n_offline}"
    );
}
