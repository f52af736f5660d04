//! A display gamma read from the frames themselves, for frames saved for viewing whose
//! encoding nobody wrote down: the central square of the field is reconstructed with
//! the frames decoded by each candidate gamma ([`Response::Gamma`]), and the gamma whose
//! result explains its frames best (least relative amplitude error) is taken.
//!
//! Why the frames can tell: decoding moves the dim dark-field frames against the bright
//! ones by orders of magnitude (25 of 255 is 10 % of full scale read linearly, 0.6 % at
//! γ = 2.2), and only one ratio lets the light they scatter agree with the object that
//! the bright-field frames' contrast shows. On the vendored USAF frames the error is
//! least at γ 2.2–2.4 (0.607 read as linear, 0.526 at 2.2), where the bright-field
//! fit's offset ([`super::contrast`]) vanishes too.

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;
use serde::Serialize;

use super::tiled::{self, TiledError};
use super::{ContrastFit, Settings};
use crate::frame::{Counts, LitFrame, Measured, Region, Response};
use crate::tiles::auto_tile_side;
use crate::{LedGeometry, System};

/// The first, coarse candidates: linear, up to beyond the sRGB-like 2.2.
pub const COARSE: [f64; 6] = [1.0, 1.4, 1.8, 2.2, 2.6, 3.0];

/// A screened scan ([`scan`]'s `screened`) runs linear and this first, for
/// [`SCREEN_PASSES`], and goes on only where this fits clearly better (by
/// [`FLAT_WITHIN`]): every display gamma simulated (1.8–2.6) fits it better than
/// linear, and linear frames fit it 20–30 % worse.
pub const SCREEN: [f64; 2] = [COARSE[0], COARSE[1]];

/// The side of the central square the screen reconstructs is at most this, camera
/// pixels: it only decides whether to scan, against a threshold of [`FLAT_WITHIN`]
/// (linear frames of the simulated 441×256² set fit γ 1.4 11 % worse on this screen,
/// 1.14 against 1.03), and a quarter of [`MAX_SIDE`]'s pixels cost a quarter as much
/// (issue 63: the screen was 43 % of a default 441×256² run).
pub const SCREEN_SIDE: usize = 128;

/// The screen's frames reach at most this illumination NA, in objective NAs: the
/// bright field and the first dark-field annuli, whose dim light against the bright
/// frames is what a display gamma bends. The far dark field adds cost, not contrast
/// between the two candidates.
pub const SCREEN_REACH: f64 = 1.6;

/// Fewer frames than this within [`SCREEN_REACH`] (a sparse or odd array): the
/// screen takes them all.
const SCREEN_MIN_FRAMES: usize = 16;

/// Passes of the screen's two candidates (at most the scan's): it only decides whether
/// to scan, and the scan runs every candidate at the full passes.
pub const SCREEN_PASSES: usize = 4;

/// The step of the fine candidates around the coarse minimum.
pub const FINE_STEP: f64 = 0.1;

/// A best gamma at or below this is read as linear frames (no decoding).
pub const LINEAR_BELOW: f64 = 1.1;

/// The relative rise of the error over its least that [`GammaScan::range`] spans: a
/// statement of how flat the curve is, not a confidence interval.
pub const FLAT_WITHIN: f64 = 0.01;

/// The side of the central square the scan reconstructs is at most this, camera
/// pixels (enough bright-field structure, cheap enough for a dozen runs).
pub const MAX_SIDE: usize = 256;

/// One candidate's run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GammaCandidate {
    /// The exponent the frames were decoded with (1: linear).
    pub gamma: f64,
    /// The mean relative amplitude error of the frames in the last pass.
    pub error: f64,
    /// The bright-field frames against the result's intensities.
    pub bright_field: Option<ContrastFit>,
}

/// The scan and what it concludes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GammaScan {
    /// Every candidate run, by gamma.
    pub candidates: Vec<GammaCandidate>,
    /// The gamma of least error (refined through its neighbours).
    pub best: f64,
    /// The gammas whose error is within [`FLAT_WITHIN`] of the least (lowest,
    /// highest candidate).
    pub range: (f64, f64),
    /// Whether the frames are read as linear: the best gamma is at most
    /// [`LINEAR_BELOW`].
    pub linear: bool,
    /// The side of the central square reconstructed, camera pixels.
    pub side_px: usize,
    /// Passes per candidate.
    pub passes: usize,
}

impl GammaScan {
    /// The gamma to decode with: None for linear frames.
    pub fn gamma(&self) -> Option<f64> {
        (!self.linear).then_some(self.best)
    }

    /// Whether the frames clearly carry a display gamma: read as not linear, linear
    /// frames beyond [`FLAT_WITHIN`] of the least error, and the curve not flat. What
    /// a run that was not asked for a scan decodes with.
    pub fn is_clear(&self) -> bool {
        !self.linear && self.range.0 > LINEAR_BELOW && !self.is_flat()
    }

    /// Whether the error barely changes with gamma (a sample that shows little
    /// contrast, or frames without dim dark-field light): the estimate is then weak.
    pub fn is_flat(&self) -> bool {
        self.range.1 - self.range.0 > 0.8
    }
}

/// The side of the central square scanned in frames of `(rows, cols)`: at most
/// [`MAX_SIDE`], and no larger than a tile (one illumination curvature holds).
pub fn side(system: &System, geometry: &LedGeometry, (h, w): (usize, usize)) -> usize {
    h.min(w).min(MAX_SIDE).min(auto_tile_side(system, geometry))
}

/// The frames' central `side` × `side` square (the optical axis is the frame's
/// centre, so the square is reconstructed as a field of its own).
fn central_square<'a>(frames: &[LitFrame<'a>], side: usize) -> Vec<LitFrame<'a>> {
    frames
        .iter()
        .map(|f| {
            let (h, w) = f.measured.dim();
            let region = Region {
                y0: (h - side) / 2,
                x0: (w - side) / 2,
                height: side,
                width: side,
            };
            LitFrame {
                measured: Measured {
                    counts: f.measured.counts.region(region),
                    ..f.measured
                },
                ..*f
            }
        })
        .collect()
}

/// The frames a screen reconstructs: those lit by one LED within [`SCREEN_REACH`]
/// objective NAs of the axis, or all of them when too few are.
fn screen_frames<'a>(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'a>],
) -> Vec<LitFrame<'a>> {
    let reach = SCREEN_REACH * system.cutoff();
    let near: Vec<LitFrame<'a>> = frames
        .iter()
        .filter(|f| {
            let (fx, fy) = geometry.pupil_frequency(f.led, 0.0, 0.0, system);
            !f.is_multiplexed() && fx.hypot(fy) <= reach
        })
        .copied()
        .collect();
    match near.len() >= SCREEN_MIN_FRAMES {
        true => near,
        false => frames.to_vec(),
    }
}

/// The frames decoded with `gamma` (1: linear) from stored values of `full_scale`,
/// their stored dark level `dark_counts` decoded alike.
fn decoded<'a>(
    frames: &[LitFrame<'a>],
    gamma: f64,
    full_scale: f32,
    dark_counts: f32,
) -> Vec<LitFrame<'a>> {
    let response = if gamma == 1.0 {
        Response::Linear
    } else {
        Response::Gamma {
            gamma: gamma as f32,
            full_scale,
        }
    };
    frames
        .iter()
        .map(|f| LitFrame {
            measured: Measured {
                response,
                dark_level: response.decode(dark_counts),
                ..f.measured
            },
            ..*f
        })
        .collect()
}

/// How frames' values were stored: what a display gamma is applied over.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stored {
    /// The stored values' full scale.
    pub full_scale: f32,
    /// The stored dark level, counts.
    pub dark_counts: f32,
}

/// Scan the display gamma of `frames` (stored as `stored` says; their own response is
/// ignored): [`COARSE`], then [`FINE_STEP`]s around the coarse minimum, each candidate
/// reconstructed over the central square for `passes` with `settings` (candidates run
/// in parallel). `screened`: [`SCREEN`]'s two first, the rest only where they show a
/// gamma (for frames that seldom carry one, a linear set then costs two candidates,
/// not ten). `progress(done, total)` counts candidates.
#[allow(clippy::too_many_arguments)]
pub fn scan(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'_>],
    stored: Stored,
    settings: Settings,
    passes: usize,
    screened: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<GammaScan, TiledError> {
    let side = side(system, geometry, tiled::check_sizes(frames)?);
    let square = central_square(frames, side);
    // A screen counts its own two candidates; a full scan (after one, too) all ten.
    let full = COARSE.len() + 4;
    let trial = Trial {
        system,
        geometry,
        settings: Settings {
            // Not needed to compare the candidates, and each costs a fit per pass.
            refine_leds: None,
            // The candidates are compared by their frames' error, which a soft floor
            // skews: it shrinks dim dark-field light by how far above the noise decoding
            // leaves it, which depends on the gamma (with it, the vendored USAF set read
            // 1.94 instead of 2.27, a simulated 2.2 read 1.2). A noise band skews it too:
            // it leaves the model free within the band, whose width in decoded units
            // depends on the gamma (with it a good simulated 8-bit stained set read as
            // display-encoded).
            background: settings.background.for_comparing_errors(),
            ..settings
        },
        stored,
        done: AtomicUsize::new(0),
        total: AtomicUsize::new(if screened { SCREEN.len() } else { full }),
        progress,
    };
    let run = |gamma: f64| trial.run(&square, side, gamma, passes);
    if screened {
        let passes = SCREEN_PASSES.min(passes);
        let screen_side = side.min(SCREEN_SIDE);
        let screen_square = central_square(&screen_frames(system, geometry, frames), screen_side);
        let screen: Vec<GammaCandidate> = SCREEN
            .par_iter()
            .map(|&g| trial.run(&screen_square, screen_side, g, passes))
            .collect::<Result<_, _>>()?;
        if screen[1].error >= screen[0].error * (1.0 - FLAT_WITHIN) {
            return Ok(conclude(screen, screen_side, passes));
        }
        trial.total.fetch_add(full, Ordering::Relaxed);
    }
    let mut candidates: Vec<GammaCandidate> = COARSE
        .par_iter()
        .map(|&g| run(g))
        .collect::<Result<_, _>>()?;
    let coarse_best = least(&candidates).gamma;
    let fine: Vec<f64> = [-2.0, -1.0, 1.0, 2.0]
        .iter()
        .map(|k| round_tenth(coarse_best + k * FINE_STEP))
        .filter(|g| (COARSE[0]..=COARSE[COARSE.len() - 1]).contains(g))
        .filter(|g| !candidates.iter().any(|c| c.gamma == *g))
        .collect();
    candidates.extend(
        fine.par_iter()
            .map(|&g| run(g))
            .collect::<Result<Vec<_>, _>>()?,
    );
    let total = trial.total.load(Ordering::Relaxed);
    progress(total, total);
    candidates.sort_by(|a, b| a.gamma.total_cmp(&b.gamma));
    Ok(conclude(candidates, side, passes))
}

/// What every candidate's run shares: the optics, the settings, the stored values'
/// scale and the progress count.
struct Trial<'a> {
    system: &'a System,
    geometry: &'a LedGeometry,
    settings: Settings,
    stored: Stored,
    done: AtomicUsize,
    total: AtomicUsize,
    progress: &'a (dyn Fn(usize, usize) + Sync),
}

impl Trial<'_> {
    /// `square` (frames of `side` px) decoded with `gamma` and reconstructed for
    /// `passes`: the candidate's mean error over its tiles.
    fn run(
        &self,
        square: &[LitFrame<'_>],
        side: usize,
        gamma: f64,
        passes: usize,
    ) -> Result<GammaCandidate, TiledError> {
        let frames = decoded(
            square,
            gamma,
            self.stored.full_scale,
            self.stored.dark_counts,
        );
        let outcome = tiled::reconstruct(
            self.system,
            self.geometry,
            &frames,
            self.settings,
            passes,
            Some(side),
            &|_, _| {},
        )?;
        let n = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        (self.progress)(n, self.total.load(Ordering::Relaxed).max(n));
        Ok(GammaCandidate {
            gamma,
            error: outcome
                .tiles
                .iter()
                .filter_map(|t| t.errors.last())
                .sum::<f64>()
                / outcome.tiles.len().max(1) as f64,
            bright_field: outcome.bright_field,
        })
    }
}

/// Rounded to a tenth (the candidates' grid), so that fine and coarse ones coincide.
fn round_tenth(g: f64) -> f64 {
    (g * 10.0).round() / 10.0
}

/// The candidate of least error (the first of equals).
fn least(candidates: &[GammaCandidate]) -> GammaCandidate {
    candidates
        .iter()
        .copied()
        .min_by(|a, b| a.error.total_cmp(&b.error))
        .unwrap_or(GammaCandidate {
            gamma: 1.0,
            error: f64::NAN,
            bright_field: None,
        })
}

/// The best gamma (a parabola through the least and its neighbours on the fine grid),
/// the flat range and whether that means linear; `candidates` sorted by gamma.
fn conclude(candidates: Vec<GammaCandidate>, side_px: usize, passes: usize) -> GammaScan {
    let best = least(&candidates);
    let at = candidates
        .iter()
        .position(|c| c.gamma == best.gamma)
        .unwrap_or(0);
    let vertex = match (
        at.checked_sub(1).map(|i| candidates[i]),
        candidates.get(at + 1),
    ) {
        (Some(lo), Some(hi))
            if (best.gamma - lo.gamma - FINE_STEP).abs() < 1e-9
                && (hi.gamma - best.gamma - FINE_STEP).abs() < 1e-9 =>
        {
            let curvature = lo.error - 2.0 * best.error + hi.error;
            if curvature > 0.0 {
                best.gamma + 0.5 * FINE_STEP * (lo.error - hi.error) / curvature
            } else {
                best.gamma
            }
        }
        _ => best.gamma,
    };
    let flat: Vec<f64> = candidates
        .iter()
        .filter(|c| c.error <= best.error * (1.0 + FLAT_WITHIN))
        .map(|c| c.gamma)
        .collect();
    let range = (
        flat.first().copied().unwrap_or(best.gamma),
        flat.last().copied().unwrap_or(best.gamma),
    );
    let best = round_hundredth(vertex);
    GammaScan {
        candidates,
        best,
        range,
        linear: best <= LINEAR_BELOW,
        side_px,
        passes,
    }
}

fn round_hundredth(g: f64) -> f64 {
    (g * 100.0).round() / 100.0
}

/// The full scale of samples stored as `counts` without a stated bit depth: decoding
/// is a power law, so a wrong full scale only scales every frame alike, which the clear
/// level takes out. None for floats (no full scale).
pub fn full_scale_of(counts: &Counts<'_>) -> Option<f32> {
    match counts {
        Counts::U8(_) => Some(255.0),
        Counts::U16(_) => Some(65535.0),
        Counts::F32(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn candidate(gamma: f64, error: f64) -> GammaCandidate {
        GammaCandidate {
            gamma,
            error,
            bright_field: None,
        }
    }

    #[test]
    fn the_least_error_is_refined_through_its_neighbours() {
        // error = 0.5 + (γ − 2.23)², sampled on the scan's grid.
        let grid = [1.0, 1.4, 1.8, 2.0, 2.1, 2.2, 2.3, 2.4, 2.6, 3.0];
        let scan = conclude(
            grid.iter()
                .map(|&g| candidate(g, 0.5 + (g - 2.23) * (g - 2.23)))
                .collect(),
            128,
            10,
        );
        assert!((scan.best - 2.23).abs() < 0.006, "{}", scan.best);
        assert_eq!(scan.gamma(), Some(scan.best));
        // Within 1 % of 0.5: |γ − 2.23| ≤ 0.0707.
        assert_eq!(scan.range, (2.2, 2.3));
        assert!(!scan.is_flat());
    }

    #[test]
    fn a_minimum_at_one_means_linear_frames_and_a_flat_curve_says_so() {
        let rising = conclude(
            [1.0, 1.1, 1.2, 1.4, 1.8]
                .iter()
                .map(|&g| candidate(g, 0.46 + 0.05 * (g - 1.0)))
                .collect(),
            128,
            10,
        );
        assert!(rising.linear);
        assert_eq!(rising.gamma(), None);
        let flat = conclude(
            [1.0, 1.4, 1.8, 2.2, 2.6, 3.0]
                .iter()
                .map(|&g| candidate(g, 0.3 + 0.001 * (g - 2.2).abs()))
                .collect(),
            128,
            10,
        );
        assert!(flat.is_flat(), "{:?}", flat.range);
    }
}
