//! LED positions refined inside EPRY, on data from the full wave-optics simulator: a
//! board whose 441 LEDs are each off their grid (σ = 0.25 mm per axis) and which is
//! tilted by 1° about x, while the reconstruction is told only the rigid placement.
//! Refined, the reconstruction must come within 1.2× of the same acquisition from a
//! perfect board, and the refined LED positions must be closer to the truth than the
//! rigid ones.

mod common;

use fpm_physics::frame::Region;
use fpm_physics::metrics::{central, complex_nrmse, resample};
use fpm_physics::optics::direction_from;
use fpm_physics::reconstruct::refine::FieldFrequencies;
use fpm_physics::reconstruct::{Refine, RefinedLeds, Settings};
use fpm_physics::simulate::{acquire_from, Camera, ObjectField, SimFrame};
use fpm_physics::{Image, LedGeometry, LedIndex, System};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

const PASSES: usize = 12;

#[test]
fn refined_leds_recover_a_misbuilt_board() {
    let system = System::paper();
    let rigid = LedGeometry {
        dx_mm: 0.3,
        dy_mm: -0.2,
        theta_deg: 1.0,
        ..LedGeometry::paper()
    };
    let tilted = rigid.tilted(1.0, 0.0);
    let mut rng = rand::rngs::StdRng::seed_from_u64(25);
    let jitter = Normal::new(0.0, 0.25).expect("a normal law");
    let leds = rigid.leds();
    let truth: Vec<(f64, f64, f64)> = leds
        .iter()
        .map(|&l| {
            let (x, y, h) = tilted.led_position_3d_mm(l);
            (x + jitter.sample(&mut rng), y + jitter.sample(&mut rng), h)
        })
        .collect();
    let at = |led: LedIndex| truth[leds.iter().position(|&l| l == led).expect("on the board")];

    let object = ObjectField::test_sample(&system, 128, 32, 2, 9);
    let camera = Camera::realistic();
    let shots: Vec<(LedIndex, f64)> = leds.iter().map(|&l| (l, 0.0)).collect();
    let record = |board: &(dyn Fn(LedIndex) -> (f64, f64, f64) + Sync)| {
        acquire_from(
            &system,
            board,
            &object,
            &shots,
            &camera,
            |img| camera.auto_exposure(img),
            77,
        )
    };
    let perfect = record(&|l| rigid.led_position_3d_mm(l));
    let misbuilt = record(&at);

    // The truth, band-limited to the true board's synthetic aperture.
    let wavelength = system.wavelength_um;
    let frequency = |p: (f64, f64, f64)| {
        let s = direction_from(p, (0.0, 0.0));
        (s[0] / wavelength, s[1] / wavelength)
    };
    let discs: Vec<(f64, f64)> = truth.iter().map(|&p| frequency(p)).collect();
    let cutoff = system.cutoff();
    let in_aperture = |fx: f64, fy: f64| discs.iter().any(|f| (fx + f.0).hypot(fy + f.1) <= cutoff);
    let field = object.crop_to_camera();
    let m = field.dim().0;
    let truth_c = central(&resample(&field, object.pitch_um(), m, in_aperture), 0.75);

    let reconstruct = |frames: &[SimFrame], refine: Option<Refine>| {
        let images: Vec<Image> = frames
            .iter()
            .map(|f| {
                let measured = f.measured(&camera);
                measured.intensity(Region::whole(measured.dim()))
            })
            .collect();
        let shots = common::shots(frames, &images);
        let settings = Settings {
            refine_leds: refine,
            ..Settings::default()
        };
        let mut out = common::epry(&system, &rigid, &shots, settings, PASSES);
        let rec = out.sample();
        let pitch = system.sample_pixel_um() / settings.upsample as f64;
        let nrmse = complex_nrmse(
            &central(&resample(&rec, pitch, m, in_aperture), 0.75),
            &truth_c,
        );
        let refined = RefinedLeds::from_fields(
            &rigid,
            &shots.iter().map(|s| s.led).collect::<Vec<_>>(),
            &[FieldFrequencies {
                centre_um: (0.0, 0.0),
                frequencies: &out.frequencies,
            }],
            wavelength,
            out.epry.bin_step(),
        );
        (nrmse, refined)
    };
    let (nrmse_perfect, _) = reconstruct(&perfect, None);
    let (nrmse_rigid, _) = reconstruct(&misbuilt, None);
    let (nrmse_refined, refined) = reconstruct(&misbuilt, Some(Refine::default()));

    let rms = |positions: &[(f64, f64)]| {
        let s: f64 = refined
            .leds
            .iter()
            .zip(positions)
            .map(|(&l, p)| {
                let t = at(l);
                (p.0 - t.0).powi(2) + (p.1 - t.1).powi(2)
            })
            .sum();
        (s / positions.len() as f64).sqrt()
    };
    // The error by ring of the board (rings 0–3 are bright-field), for the log.
    {
        let mut rings = std::collections::BTreeMap::<u8, (usize, f64, f64)>::new();
        for (k, &l) in refined.leds.iter().enumerate() {
            let t = at(l);
            let ring = (l.row as i32 - 10).abs().max((l.col as i32 - 10).abs()) as u8;
            let e = rings.entry(ring).or_default();
            e.0 += 1;
            e.1 += (refined.given_mm[k].0 - t.0).powi(2) + (refined.given_mm[k].1 - t.1).powi(2);
            e.2 +=
                (refined.refined_mm[k].0 - t.0).powi(2) + (refined.refined_mm[k].1 - t.1).powi(2);
        }
        for (r, (n, a, b)) in rings {
            eprintln!(
                "ring {r}: rigid {:.3} refined {:.3}",
                (a / n as f64).sqrt(),
                (b / n as f64).sqrt()
            );
        }
    }
    let (rigid_rms, refined_rms) = (rms(&refined.given_mm), rms(&refined.refined_mm));
    let board = refined.board.expect("a board fit");
    eprintln!(
        "NRMSE perfect board {nrmse_perfect:.3}, misbuilt with the rigid geometry {nrmse_rigid:.3}, refined {nrmse_refined:.3}; \
         LED position RMS error rigid {rigid_rms:.3} mm, refined {refined_rms:.3} mm (moved {:.3}); \
         board fit tilt ({:.2} ± {:.2}°, {:.2} ± {:.2}°), h {:.2} mm, residual {:.3} mm",
        refined.moved_rms_mm(),
        board.geometry.tilt_x_deg,
        board.sigma[4],
        board.geometry.tilt_y_deg,
        board.sigma[5],
        board.geometry.height_mm,
        board.residual_rms_mm,
    );
    assert!(
        nrmse_rigid > 1.2 * nrmse_perfect,
        "the misbuilt board must hurt without refinement: {nrmse_rigid} vs {nrmse_perfect}"
    );
    assert!(
        nrmse_refined <= 1.2 * nrmse_perfect,
        "refined {nrmse_refined} vs perfect board {nrmse_perfect}"
    );
    assert!(
        refined_rms < 0.75 * rigid_rms,
        "refined positions {refined_rms} mm vs rigid {rigid_rms} mm"
    );
    // The board fitted back to the refined positions: h and the tilts within 3σ.
    for (found, sigma, truth) in [
        (board.geometry.height_mm, board.sigma[3], rigid.height_mm),
        (board.geometry.tilt_x_deg, board.sigma[4], 1.0),
        (board.geometry.tilt_y_deg, board.sigma[5], 0.0),
    ] {
        assert!(
            (found - truth).abs() <= 3.0 * sigma && sigma < 0.5,
            "{found} ± {sigma} vs {truth} (h mm, tilts °)"
        );
    }
}
