//! pdcFPM calibration: recover the LED array's Δx, Δy, θ and h from how a defocused
//! feature's image moves under each bright-field LED (docs/dataset.md §3).
//!
//! 1. Find the feature in the focused reference frame (or in the given ROI); its
//!    position (x_c, y_c) enters the model.
//! 2. Measure its first moment in every defocused frame, following it with a window.
//! 3. Leave out frames that are not bright-field (much darker than the reference) or
//!    lose the feature (window at the frame's edge).
//! 4. Fit the similarity model (closed form, then robust Gauss–Newton); leave out LEDs
//!    near the bright/dark-field boundary under the fitted geometry.
//! 5. Subtract the model-based bias of each measurement and fit again.

pub mod boundary;
pub mod feature;
pub mod fit;
pub mod model;
pub mod noise;
pub mod shift;
mod stages;
pub mod tilt;
pub mod uncertainty;
pub mod window;

use crate::optics::LedIndex;
use serde::{Deserialize, Serialize};

use crate::image::{row_slice, row_sum};
use crate::optics::{LedGeometry, Placement, System};
use crate::Image;
use feature::{FeatureError, Polarity, Roi};
use fit::{Observation, Params, Setup};

/// One frame handed to the calibrator.
#[derive(Debug, Clone, Copy)]
pub struct Frame<'a> {
    /// LED (row, col).
    pub led: LedIndex,
    /// Sample displacement toward the LEDs, µm (0 = in focus).
    pub defocus_um: f64,
    /// Exposure, ms (intensities are compared per ms).
    pub exposure_ms: f64,
    /// Dark-subtracted intensities.
    pub image: &'a Image,
    /// Values at or above this are saturated (clipped by the camera), if known.
    pub saturation: Option<f32>,
}

/// Calibration settings.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Look for the feature only here.
    pub roi: Option<Roi>,
    /// Subtract the model-based first-moment bias.
    pub bias_correction: bool,
    /// Frames dimmer than this fraction of the reference are not bright-field.
    pub min_brightness: f64,
    /// Residuals beyond this many robust σ are outliers.
    pub reject_sigma: f64,
    /// 1σ of the defocus as the stage set it, µm: h is proportional to it.
    pub defocus_sigma_um: f64,
    /// Share of the model-based bias correction taken as its uncertainty (the feature
    /// may not be the sharp-edged amplitude object the model assumes).
    pub model_fraction: f64,
    /// Fit the board's tilt where the shifts show it (else the board is flat).
    pub fit_tilt: bool,
}

/// The default defocus uncertainty, µm: a focus knob read to its finest graduation
/// (motorised stages do better; say so with `--defocus-sigma-um`).
pub const DEFAULT_DEFOCUS_SIGMA_UM: f64 = 1.0;

/// Half the side of the bright-field grid pdcFPM defocuses under: 5 × 5 LEDs.
pub const GRID_HALF: usize = 2;

/// The LEDs pdcFPM takes its defocused frames under: the (2·`half` + 1)² grid around
/// the centre LED, row by row, those off the board left out (never repeated); on a
/// listed layout the (2·`half` + 1)² LEDs nearest its origin, by id.
pub fn calibration_grid(geometry: &LedGeometry, half: usize) -> Vec<LedIndex> {
    if let Some(list) = &geometry.list {
        let r2 = |l: &crate::ListedLed| l.x_mm * l.x_mm + l.y_mm * l.y_mm;
        let mut nearest: Vec<_> = list.leds().to_vec();
        nearest.sort_by(|a, b| r2(a).total_cmp(&r2(b)));
        let mut leds: Vec<LedIndex> = nearest
            .iter()
            .take((2 * half + 1).pow(2))
            .map(|l| l.led)
            .collect();
        leds.sort_by_key(|l| (l.row, l.col));
        return leds;
    }
    let (r0, c0, k) = (
        geometry.center.r() as i64,
        geometry.center.c() as i64,
        half as i64,
    );
    (-k..=k)
        .flat_map(|dr| (-k..=k).map(move |dc| (r0 + dr, c0 + dc)))
        .filter_map(|(r, c)| Some(LedIndex::new(u8::try_from(r).ok()?, u8::try_from(c).ok()?)))
        .filter(|&led| geometry.contains(led))
        .collect()
}

/// The tilt is fitted when the shifts determine it to this 1σ, degrees: a 1–2° tilt
/// then stands out at 2–4σ.
pub const TILT_OBSERVABLE_SIGMA_DEG: f64 = 0.5;

impl Default for Options {
    fn default() -> Self {
        Self {
            roi: None,
            bias_correction: true,
            min_brightness: 0.6,
            reject_sigma: 5.0,
            defocus_sigma_um: DEFAULT_DEFOCUS_SIGMA_UM,
            model_fraction: 0.05,
            fit_tilt: true,
        }
    }
}

/// Why a frame was or was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LedStatus {
    /// In the fit.
    Used,
    /// Too dim compared with the reference: dark-field.
    NotBrightField,
    /// Bright-field by the fitted geometry, but so close to the pupil edge that the
    /// feature's spectrum is cut.
    NearPupilEdge,
    /// The feature left the frame or could not be measured.
    FeatureLost,
    /// Pixels of the feature are saturated: its moment would be wrong.
    Saturated,
    /// Rejected as an outlier by the robust fit.
    Outlier,
}

/// One LED in the result.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LedResult {
    /// The LED.
    pub led: LedIndex,
    /// Grid offsets (p, q) from the nominal centre LED.
    pub grid: [i64; 2],
    /// Used or why not.
    pub status: LedStatus,
    /// Frame brightness per ms relative to the reference.
    pub brightness: f64,
    /// Measured first-moment shift, µm (sample plane).
    pub measured_um: Option<[f64; 2]>,
    /// Model-based bias subtracted from it, µm.
    pub bias_um: Option<[f64; 2]>,
    /// Shift of the fitted model, µm.
    pub fitted_um: [f64; 2],
    /// |corrected − fitted|, µm.
    pub residual_um: Option<f64>,
    /// Where this LED sits off the fitted board, mm (x, y, the sample's axes): its
    /// residual shift carried back to the board (× −h/z, ≈ 460 at 200 µm), so a few
    /// nm of shift are a µm of LED. What a rigid board cannot hold: a misplaced LED, a
    /// package soldered askew.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset_mm: Option<[f64; 2]>,
    /// 1σ of each of `offset_mm`'s two numbers, mm: its frame's pixel noise through the
    /// shift, and 5 % of its bias correction (the model's own error).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset_sigma_mm: Option<f64>,
    /// Its defocused window was cut by the frame's edge: the bias model saw the same
    /// cut (its bias is then larger, and counts in the uncertainty as every bias does).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub cut_by_edge: bool,
}

/// One standard deviation of each of the placement's numbers (h from the shifts
/// alone; the defocus error adds `height_per_defocus_um`).
pub type Uncertainty = crate::optics::Placement;

/// Where the feature is.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct FeatureInfo {
    /// x_c, µm.
    pub x_um: f64,
    /// y_c, µm.
    pub y_um: f64,
    /// Column and row on the camera.
    pub pixel: [f64; 2],
    /// Pixels above half contrast.
    pub area_px: usize,
    /// Bright or dark.
    pub polarity: Polarity,
}

/// The calibrated LED array (the `calibration.json` that reconstruction takes).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Calibration {
    /// The array's placement (its tilt 0 when the data cannot see it: the board is
    /// then taken as flat).
    #[serde(flatten)]
    pub placement: Placement,
    /// Whether the shifts pin the tilt down (its 1σ at most
    /// [`TILT_OBSERVABLE_SIGMA_DEG`]); if not, the board is taken as flat and Δx, Δy
    /// carry what an unseen tilt could do to them.
    #[serde(default)]
    pub tilt_observable: bool,
    /// Uncertainties (1 σ), every source below in quadrature.
    pub uncertainty: Uncertainty,
    /// What the uncertainties are made of.
    #[serde(default)]
    pub uncertainty_sources: Option<uncertainty::Budget>,
    /// The defocus's 1σ the uncertainty of h assumes, µm.
    #[serde(default)]
    pub defocus_sigma_um: f64,
    /// Defocus the shifts were measured at, µm.
    pub defocus_um: f64,
    /// Only z/h is observable: h changes by this many mm per µm of defocus error.
    pub height_per_defocus_um: f64,
    /// RMS residual per component, µm.
    pub rms_residual_um: f64,
    /// The feature.
    pub feature: FeatureInfo,
    /// Every defocused frame.
    pub leds: Vec<LedResult>,
}

/// How far the calibrated LEDs sit off the fitted board, each measured on its own.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LedOffsets {
    /// RMS per axis over the used LEDs, mm.
    pub rms_mm: f64,
    /// The median of their 1σ, mm: what a perfect board's offsets would scatter by.
    pub median_sigma_mm: f64,
    /// The LED farthest off.
    pub farthest: LedIndex,
    /// How far, mm.
    pub farthest_mm: f64,
    /// Its 1σ per axis, mm.
    pub farthest_sigma_mm: f64,
}

/// What a calibration should reach (1σ): Δx, Δy µm; θ °; h mm from the shifts alone
/// (the defocus's own error aside). Beyond it, a warning says so rather than letting
/// the number look confident.
pub const ACCURACY_TARGET: [f64; 4] = [2.0, 2.0, 0.02, 0.1];

/// Fewer usable LEDs than this, and no parameter is trusted.
pub const MIN_USED_LEDS: usize = 6;

impl Calibration {
    /// Which of (Δx, Δy, θ, h) a user is warned about: its 1σ beyond
    /// [`ACCURACY_TARGET`] (Δx and Δy together, by the larger), or too few usable
    /// LEDs for any.
    pub fn accuracy_warned(&self) -> [bool; 4] {
        let used = self
            .leds
            .iter()
            .filter(|l| l.status == LedStatus::Used)
            .count();
        if used < MIN_USED_LEDS {
            return [true; 4];
        }
        let u = &self.uncertainty;
        let lateral = u.dx_mm.max(u.dy_mm) * 1e3 > ACCURACY_TARGET[0];
        [
            lateral,
            lateral,
            u.theta_deg > ACCURACY_TARGET[2],
            self.height_sigma_from_shifts_mm() > ACCURACY_TARGET[3],
        ]
    }

    /// How far the used LEDs sit off the fitted board ([`LedResult::offset_mm`]).
    /// None without two used LEDs.
    pub fn led_offsets(&self) -> Option<LedOffsets> {
        let used: Vec<(&LedResult, [f64; 2], f64)> = self
            .leds
            .iter()
            .filter(|l| l.status == LedStatus::Used)
            .filter_map(|l| Some((l, l.offset_mm?, l.offset_sigma_mm?)))
            .collect();
        if used.len() < 2 {
            return None;
        }
        let n = used.len() as f64;
        let rms_mm = (used
            .iter()
            .map(|(_, o, _)| 0.5 * (o[0] * o[0] + o[1] * o[1]))
            .sum::<f64>()
            / n)
            .sqrt();
        let mut sigmas: Vec<f64> = used.iter().map(|u| u.2).collect();
        sigmas.sort_by(f64::total_cmp);
        let (farthest, offset, sigma) = used
            .iter()
            .max_by(|a, b| a.1[0].hypot(a.1[1]).total_cmp(&b.1[0].hypot(b.1[1])))
            .map(|(l, o, s)| (l.led, o[0].hypot(o[1]), *s))?;
        Some(LedOffsets {
            rms_mm,
            median_sigma_mm: sigmas[sigmas.len() / 2],
            farthest,
            farthest_mm: offset,
            farthest_sigma_mm: sigma,
        })
    }

    /// h's 1σ without the defocus's share (which is the user's to state).
    pub fn height_sigma_from_shifts_mm(&self) -> f64 {
        let u = &self.uncertainty;
        let defocus_mm = self
            .uncertainty_sources
            .map_or(0.0, |b| b.defocus.height_mm);
        (u.height_mm.powi(2) - defocus_mm.powi(2)).max(0.0).sqrt()
    }

    /// The calibrated geometry, on the nominal grid.
    pub fn geometry(&self, nominal: &LedGeometry) -> LedGeometry {
        nominal.placed_at(self.placement)
    }
}

/// Why calibration failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    /// No in-focus frame under the centre LED.
    #[error("no in-focus reference frame (defocus 0) under the centre LED ({}, {})", .0.row, .0.col)]
    NoReference(LedIndex),
    /// No defocused frames.
    #[error("no defocused frames (frames with defocus_um ≠ 0)")]
    NoDefocused,
    /// The defocused frames disagree on the defocus.
    #[error("defocused frames must share one defocus: LED ({}, {}) has {got} µm, others {expected} µm", led.row, led.col)]
    MixedDefocus {
        /// The frame's LED.
        led: LedIndex,
        /// Its defocus.
        got: f64,
        /// The first defocus seen.
        expected: f64,
    },
    /// The feature could not be found.
    #[error("reference frame: {0}")]
    Feature(#[from] FeatureError),
    /// Too few usable frames.
    #[error("only {usable} usable bright-field frames ({dark} too dim, {lost} lost the feature); at least 4 are needed{}", advice(*.lost))]
    TooFew {
        /// Usable frames.
        usable: usize,
        /// Dark-field frames.
        dark: usize,
        /// Frames that lost the feature.
        lost: usize,
    },
    /// The reference frame is saturated around the feature.
    #[error("the reference frame has {0} saturated pixels on the feature: lower the exposure or the LED brightness")]
    SaturatedReference(usize),
    /// The fit failed (degenerate layout).
    #[error("the fit did not converge (degenerate LED layout?)")]
    Fit,
    /// A listed layout with LEDs off the board's plane (a dome): the shifts are fitted
    /// as a flat board's.
    #[error("the LED list places LED {0} off the board's plane (z_mm ≠ 0): calibration fits a flat board; place a dome's LEDs by its own drawing and reconstruct with --refine-leds")]
    NotFlat(LedIndex),
}

/// Calibrate from a reference frame and defocused frames: find the feature in the
/// reference, measure its shift under every defocused LED, fit the rigid placement
/// (twice, the second time with each shift's model-based bias taken off), then the
/// final fit with the board's tilt, its uncertainty and the report
/// ([`stages`]).
pub fn calibrate(
    system: &System,
    nominal: &LedGeometry,
    frames: &[Frame<'_>],
    options: &Options,
) -> Result<Calibration, CalibrationError> {
    if let Some(off) = nominal
        .list
        .and_then(|l| l.leds().iter().find(|l| l.z_mm != 0.0).map(|l| l.led))
    {
        return Err(CalibrationError::NotFlat(off));
    }
    let (reference, defocused, z) = stages::split(nominal, frames)?;
    let located = stages::Located::find(system, reference, z, options)?;
    let mut measured = stages::measure(nominal, reference, &defocused, &located, z, options);
    let setup = Setup {
        feature_um: located.sample_um,
        z_um: z,
        pitch_um: nominal.pitch_mm * 1e3,
    };
    enough(&measured)?;
    let (start, bias) = stages::fit_rigid(
        system,
        nominal,
        reference,
        &located,
        &setup,
        &mut measured,
        options,
    )?;
    enough(&measured)?;
    let fitted = stages::fit_final(&setup, &mut measured, &bias, start, options)?;
    stages::report(&located, &setup, &measured, &bias, fitted, options)
}

/// One defocused frame as measured.
struct Measured {
    led: LedIndex,
    grid: (f64, f64),
    brightness: f64,
    shift_um: Option<(f64, f64)>,
    /// 1σ of the shift from the frame's pixel noise, µm.
    sigma_um: (f64, f64),
    status: LedStatus,
    /// The window was cut by the frame's edge (usable only with the bias model).
    cut_by_edge: bool,
}

/// Shifts with the model-based bias removed (zero where nothing was measured).
fn corrected(measured: &[Measured], bias: &[(f64, f64)]) -> Vec<Observation> {
    measured
        .iter()
        .zip(bias)
        .map(|(m, b)| Observation {
            grid: m.grid,
            shift_um: m
                .shift_um
                .map(|s| (s.0 - b.0, s.1 - b.1))
                .unwrap_or((0.0, 0.0)),
        })
        .collect()
}

/// At least four frames must remain for the four parameters.
fn enough(measured: &[Measured]) -> Result<(), CalibrationError> {
    let count = |s: LedStatus| measured.iter().filter(|x| x.status == s).count();
    let usable = count(LedStatus::Used);
    if usable < 4 {
        return Err(CalibrationError::TooFew {
            usable,
            dark: count(LedStatus::NotBrightField),
            lost: count(LedStatus::FeatureLost),
        });
    }
    Ok(())
}

fn to_geometry(nominal: &LedGeometry, p: &Params) -> LedGeometry {
    LedGeometry {
        dx_mm: p.dx * 1e-3,
        dy_mm: p.dy * 1e-3,
        theta_deg: p.theta.to_degrees(),
        height_mm: p.h * 1e-3,
        ..*nominal
    }
}

/// Whether the shifts pin the tilt down (see [`TILT_OBSERVABLE_SIGMA_DEG`]).
fn tilt_observable(t: &tilt::TiltFit) -> bool {
    let s = t.sigma();
    s[4].max(s[5]).to_degrees() <= TILT_OBSERVABLE_SIGMA_DEG
}

/// Decide the outliers again under the tilted model, with the robust fit's rule
/// (beyond `reject` robust σ of the used LEDs' residuals). Whether any status changed.
fn reclassify_outliers(
    measured: &mut [Measured],
    obs: &[Observation],
    setup: &Setup,
    params: &tilt::TiltedParams,
    reject: f64,
) -> bool {
    let norm = |o: &Observation| {
        let m = tilt::predict(setup, params, o.grid);
        (o.shift_um.0 - m.0).hypot(o.shift_um.1 - m.1)
    };
    let used = measured
        .iter()
        .zip(obs)
        .filter(|(m, _)| m.status == LedStatus::Used)
        .map(|(_, o)| norm(o) as f32);
    let scale = (1.4826 * crate::image::median(used) as f64).max(1e-3);
    let mut changed = false;
    for (m, o) in measured.iter_mut().zip(obs) {
        if matches!(m.status, LedStatus::Used | LedStatus::Outlier) {
            let status = if norm(o) > reject * scale {
                LedStatus::Outlier
            } else {
                LedStatus::Used
            };
            changed |= status != m.status;
            m.status = status;
        }
    }
    changed
}

/// Pixels of `window` at or above the saturation level `sat`.
fn saturated_pixels(img: &Image, window: Roi, sat: f32) -> usize {
    (window.y..window.y + window.h)
        .map(|r| {
            row_slice(img, r)[window.x..window.x + window.w]
                .iter()
                .filter(|&&v| v >= sat)
                .count()
        })
        .sum()
}

/// Mean intensity per ms of exposure.
fn frame_brightness(f: &Frame) -> f64 {
    let n = f.image.len().max(1) as f64;
    let total: f64 = f
        .image
        .rows()
        .into_iter()
        .map(|row| row_sum(row) as f64)
        .sum();
    total / n / f.exposure_ms.max(1e-12)
}

/// What would help when `lost` frames lost the feature: its defocused window left the
/// frame, or another feature came into it.
fn advice(lost: usize) -> &'static str {
    if lost > 0 {
        ": pick a small isolated feature nearer the frame's centre (--roi), so that its defocused window stays inside the frame under every bright-field LED, or calibrate at a smaller defocus"
    } else {
        ""
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A refusal for frames that lost the feature says what would help; one for dim
    /// frames alone does not send the user after the feature.
    #[test]
    fn too_few_frames_name_what_would_help() {
        let lost = CalibrationError::TooFew {
            usable: 0,
            dark: 0,
            lost: 25,
        }
        .to_string();
        assert!(
            lost.contains("--roi") && lost.contains("nearer the frame's centre"),
            "{lost}"
        );
        let dim = CalibrationError::TooFew {
            usable: 2,
            dark: 30,
            lost: 0,
        }
        .to_string();
        assert!(!dim.contains("--roi"), "{dim}");
    }
}
