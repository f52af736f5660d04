//! Does the calibration know how sure it is? Random hard cases from the full
//! wave-optics simulator (dim and bright exposures, small and large features on and off
//! the axis, both defocus signs), the truth hidden from the calibrator, and how often
//! the reported 1σ covers the error.

use rand::Rng;

use crate::calibrate::{Calibration, Options};
use crate::simulate::CalibrationScene;
use crate::study::calibrate_simulated;
use crate::LedGeometry;

/// The parameters' names, in the order of every array here.
pub const PARAMETERS: [&str; 4] = ["Δx", "Δy", "θ", "h"];

/// A random hard case: the array anywhere in the paper's range; a square hole of
/// 15–60 µm, on the axis or up to 40 µm off it; defocus ±100–300 µm; a peak exposure
/// of 300–3000 counts (log-uniform). `seed` drives the scene's noise.
pub fn hard_case(rng: &mut impl Rng, seed: u64) -> CalibrationScene {
    let nominal = LedGeometry::paper();
    let truth = LedGeometry {
        dx_mm: rng.gen_range(-2.5..2.5),
        dy_mm: rng.gen_range(-2.5..2.5),
        theta_deg: rng.gen_range(-5.0..5.0),
        height_mm: rng.gen_range(87.0..97.0),
        ..nominal
    };
    let mut scene = CalibrationScene::paper(truth, seed);
    scene.feature_um = rng.gen_range(15.0..60.0);
    scene.feature_at_um = if rng.gen_bool(0.5) {
        (0.0, 0.0)
    } else {
        (rng.gen_range(-40.0..40.0), rng.gen_range(-40.0..40.0))
    };
    let sign = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
    scene.defocus_um = sign * rng.gen_range(100.0..300.0);
    scene.peak_dn = Some(10f64.powf(rng.gen_range(300f64.log10()..3000f64.log10())));
    scene
}

/// One case's outcome.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Outcome {
    /// What made the case hard.
    pub feature_um: f64,
    /// Feature position, µm.
    pub feature_at_um: (f64, f64),
    /// Defocus, µm.
    pub defocus_um: f64,
    /// Peak exposure, counts.
    pub peak_dn: f64,
    /// Signed error (found − truth) in µm, µm, °, mm; None when the calibration
    /// refused (an error is an honest answer, not a confident one).
    pub error: Option<[f64; 4]>,
    /// The reported 1σ, same units.
    pub sigma: Option<[f64; 4]>,
    /// What the σ is made of.
    pub sources: Option<crate::calibrate::uncertainty::Budget>,
    /// Which parameters the calibration warned about (beyond its accuracy target).
    pub warned: Option<[bool; 4]>,
    /// Why the calibration refused.
    pub refused: Option<String>,
    /// Calibration time, ms.
    pub ms: f64,
}

impl Outcome {
    /// |error| / σ per parameter.
    pub fn in_sigmas(&self) -> Option<[f64; 4]> {
        let (e, s) = (self.error?, self.sigma?);
        Some(std::array::from_fn(|p| e[p].abs() / s[p].max(1e-300)))
    }
}

/// Simulate `scene`, calibrate it against the nominal array with `options`, and
/// compare with the hidden truth.
pub fn run_case(scene: &CalibrationScene, options: &Options) -> Outcome {
    let nominal = LedGeometry::paper();
    let frames = scene.acquire();
    let t = scene.truth;
    let (error, sigma, sources, warned, refused, ms) =
        match calibrate_simulated(scene, &frames, &nominal, options) {
            Ok((c, took)) => {
                let (e, s) = errors(&c, &t);
                let ms = took.as_secs_f64() * 1e3;
                let warned = c.accuracy_warned();
                (
                    Some(e),
                    Some(s),
                    c.uncertainty_sources,
                    Some(warned),
                    None,
                    ms,
                )
            }
            Err(e) => (None, None, None, None, Some(e.to_string()), 0.0),
        };
    Outcome {
        feature_um: scene.feature_um,
        feature_at_um: scene.feature_at_um,
        defocus_um: scene.defocus_um,
        peak_dn: scene.peak_dn.unwrap_or(f64::NAN),
        error,
        sigma,
        sources,
        warned,
        refused,
        ms,
    }
}

/// Signed errors (found − truth; µm, µm, °, mm) of `c` against `t`, and the
/// reported 1σ in the same units.
pub fn errors(c: &Calibration, t: &LedGeometry) -> ([f64; 4], [f64; 4]) {
    let u = &c.uncertainty;
    (
        [
            (c.placement.dx_mm - t.dx_mm) * 1e3,
            (c.placement.dy_mm - t.dy_mm) * 1e3,
            c.placement.theta_deg - t.theta_deg,
            c.placement.height_mm - t.height_mm,
        ],
        [u.dx_mm * 1e3, u.dy_mm * 1e3, u.theta_deg, u.height_mm],
    )
}

/// Coverage over many outcomes.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Coverage {
    /// Cases run.
    pub cases: usize,
    /// Cases the calibration refused.
    pub refused: usize,
    /// Share of the answered cases whose error is within 1σ, per parameter.
    pub within_1_sigma: [f64; 4],
    /// Within 3σ.
    pub within_3_sigma: [f64; 4],
    /// Count within 3σ.
    pub count_within_3_sigma: [usize; 4],
    /// Median |error|, per parameter (µm, µm, °, mm).
    pub median_abs_error: [f64; 4],
    /// Largest |error|.
    pub max_abs_error: [f64; 4],
    /// Median reported σ.
    pub median_sigma: [f64; 4],
    /// Answered cases whose error is beyond the accuracy target
    /// ([`crate::calibrate::ACCURACY_TARGET`]), per parameter…
    pub beyond_target: [usize; 4],
    /// …and of those, the ones the calibration did not warn about: confident numbers
    /// that are wrong.
    pub beyond_target_unwarned: [usize; 4],
    /// Answered cases the calibration warned about, per parameter.
    pub warned: [usize; 4],
}

/// Whether `o`'s error in parameter `p` is beyond the accuracy target.
fn beyond(o: &Outcome, p: usize) -> bool {
    o.error
        .is_some_and(|e| e[p].abs() > crate::calibrate::ACCURACY_TARGET[p])
}

/// The coverage of `outcomes`.
pub fn coverage(outcomes: &[Outcome]) -> Coverage {
    let answered: Vec<&Outcome> = outcomes.iter().filter(|o| o.error.is_some()).collect();
    let n = answered.len().max(1) as f64;
    let count = |p: usize, k: f64| {
        answered
            .iter()
            .filter_map(|o| o.in_sigmas())
            .filter(|s| s[p] <= k)
            .count()
    };
    let median = |mut v: Vec<f64>| crate::stats::median(&mut v).unwrap_or(f64::NAN);
    let column = |f: &dyn Fn(&Outcome) -> Option<f64>| -> Vec<f64> {
        answered.iter().filter_map(|o| f(o)).map(f64::abs).collect()
    };
    Coverage {
        cases: outcomes.len(),
        refused: outcomes.len() - answered.len(),
        within_1_sigma: std::array::from_fn(|p| count(p, 1.0) as f64 / n),
        within_3_sigma: std::array::from_fn(|p| count(p, 3.0) as f64 / n),
        count_within_3_sigma: std::array::from_fn(|p| count(p, 3.0)),
        median_abs_error: std::array::from_fn(|p| median(column(&|o| o.error.map(|e| e[p])))),
        max_abs_error: std::array::from_fn(|p| {
            column(&|o| o.error.map(|e| e[p]))
                .into_iter()
                .fold(0.0, f64::max)
        }),
        median_sigma: std::array::from_fn(|p| median(column(&|o| o.sigma.map(|s| s[p])))),
        beyond_target: std::array::from_fn(|p| answered.iter().filter(|o| beyond(o, p)).count()),
        beyond_target_unwarned: std::array::from_fn(|p| {
            answered
                .iter()
                .filter(|o| beyond(o, p) && !o.warned.is_some_and(|w| w[p]))
                .count()
        }),
        warned: std::array::from_fn(|p| {
            answered
                .iter()
                .filter(|o| o.warned.is_some_and(|w| w[p]))
                .count()
        }),
    }
}
