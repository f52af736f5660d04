//! What a user must know before trusting a reconstruction: each check on the
//! finished run's report, worded with the action that applies to the frames at hand.
//! The page shows them, report.json lists them (`check` and `message`), the CLI
//! prints them. How often each fires on good data and on data with its condition is
//! measured by `fpm bench warnings` (docs/results.md).

use serde::Serialize;

use super::{GammaScanReason, Report};

/// Which check a warning comes from: its [`name`](Check::name) in report.json, stable
/// for scripts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Check {
    /// The dataset's nominal LED positions were used.
    NominalGeometry,
    /// The frames' error rose while the steps were full, or far above its least.
    ErrorRose,
    /// The bright-field frames' shifts show a defocus.
    Refocus,
    /// LED refinement's own caveats.
    Refinement,
    /// The bright-field frames carry light no object explains.
    BrightFieldOffset,
    /// `--camera-gamma auto` read a weak gamma.
    GammaWeak,
    /// 8-bit frames stating no gamma were decoded with the one read from them.
    GammaRead,
    /// The bright/dark-field edge puts the LEDs at another height.
    HeightFromEdge,
    /// The edges fit another entrance pupil (a non-telecentric objective).
    EntrancePupil,
    /// Most dark-field backgrounds were not flat.
    DarkFieldBackground,
    /// `--flatten-background` found little clear background.
    FlattenBackground,
    /// A colour run placed every colour's LEDs with one calibration.
    ColorOneCalibration,
    /// A colour channel lies farther from the reference than chromatic aberration
    /// moves it.
    ColorShift,
}

impl Check {
    /// Its name in report.json.
    pub fn name(self) -> &'static str {
        match self {
            Self::NominalGeometry => "nominal-geometry",
            Self::ErrorRose => "error-rose",
            Self::Refocus => "refocus",
            Self::Refinement => "refinement",
            Self::BrightFieldOffset => "bright-field-offset",
            Self::GammaWeak => "gamma-weak",
            Self::GammaRead => "gamma-read",
            Self::HeightFromEdge => "height-from-edge",
            Self::EntrancePupil => "entrance-pupil",
            Self::DarkFieldBackground => "dark-field-background",
            Self::FlattenBackground => "flatten-background",
            Self::ColorOneCalibration => "color-one-calibration",
            Self::ColorShift => "color-shift",
        }
    }
}

impl Serialize for Check {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// One warning: its check and what it says.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Warning {
    /// The check that fired.
    pub check: Check,
    /// What it says, with the action that applies.
    pub message: String,
}

#[derive(Default)]
struct Warnings(Vec<Warning>);

impl Warnings {
    fn push(&mut self, check: Check, message: impl Into<String>) {
        self.0.push(Warning {
            check,
            message: message.into(),
        });
    }

    fn extend(&mut self, check: Check, messages: impl IntoIterator<Item = String>) {
        for m in messages {
            self.push(check, m);
        }
    }
}

/// Most dark-field backgrounds left on where the sample leaves clear glass: light
/// there that is not flat is stray light. Where the sample leaves no clear glass (it
/// fills the field), the darkest blocks of a dark-field frame hold the sample's own
/// light, which is not flat: left on, as it should be, and no sign of stray light. On
/// independent wave-optics sets of a field-filling sample this fired on every set (396
/// of 396 frames left on) before it asked.
fn stray_light(background: &super::BackgroundReport) -> Option<String> {
    let frames = &background.dark_field_frames;
    let refused = frames.iter().filter(|f| !f.taken_off).count();
    let glass = background
        .axis_clear_share
        .is_none_or(fpm_physics::background::leaves_clear_glass);
    (glass && refused * 2 > frames.len().max(1)).then(|| format!(
        "{refused} of {} dark-field frames had a background that was not flat where the sample leaves clear glass, which scatters nothing (structured stray light): it was left on; shade the objective from the room and from reflections off the LED board (the report's dark-field chart shows which frames), and acquire again",
        frames.len()
    ))
}

/// Below this median brightest-block SNR the dark-field frames are dim
/// ([`dim_dark_field`]). Simulated 128² sets read 2.7 (8-bit camera), 18 (12-bit,
/// dark field peaking at 25 counts: refined positions no closer to the truth), 200
/// (peaking at 300 counts) and 550 (auto-exposed: refined positions 0.37 → 0.26 mm);
/// the real USAF set 36, the ring-array set 1.8.
pub const DIM_DARK_FIELD_SNR: f32 = 50.0;

/// The median, over the dark-field frames whose background was taken off, of their
/// brightest block over their noise, when it is below [`DIM_DARK_FIELD_SNR`].
fn dim_dark_field(background: &super::BackgroundReport) -> Option<f32> {
    let mut snr: Vec<f32> = background
        .dark_field_frames
        .iter()
        .filter(|f| f.taken_off && f.noise_counts > 0.0)
        .map(|f| f.brightest_block_counts / f.noise_counts)
        .collect();
    if snr.is_empty() {
        return None;
    }
    snr.sort_by(f32::total_cmp);
    let median = snr[snr.len() / 2];
    (median < DIM_DARK_FIELD_SNR).then_some(median)
}

/// The messages of [`checks`].
pub fn warnings(report: &Report) -> Vec<String> {
    checks(report).into_iter().map(|w| w.message).collect()
}

/// What a user must know before trusting the images of `report`, check by check.
pub fn checks(report: &Report) -> Vec<Warning> {
    let mut out = Warnings::default();
    if report.geometry_source.is_nominal() {
        out.push(
            Check::NominalGeometry,
            "the LED positions are the nominal ones, not calibrated: an array off by a fraction of a millimetre blurs and distorts the image (fpm calibrate, or --calibration)",
        );
    }
    if let Some((pass, error, before)) =
        fpm_physics::reconstruct::schedule::divergence(&report.error_per_pass)
    {
        // Refinement needs frames of one LED each (it refuses multiplexed ones).
        let geometry_help = if report.multiplexed_frames > 0 {
            "fpm calibrate, then --calibration"
        } else {
            "fpm calibrate, or --refine-leds"
        };
        out.push(
            Check::ErrorRose,
            format!(
                "the frames' error rose to {error:.4} in pass {pass} (from {before:.4}): the reconstruction is not converging; check the geometry ({geometry_help}) and the dataset's NA and wavelength"
            ),
        );
    }
    out.extend(Check::Refocus, report.refocus.warning());
    if let Some(r) = &report.refined_leds {
        out.extend(Check::Refinement, crate::refinement::warnings(r));
        if let Some(snr) = dim_dark_field(&report.background) {
            out.push(
                Check::Refinement,
                format!(
                    "the dark-field frames are dim (their brightest block rises {snr:.1}× their noise, the median over them): the refined LED positions sharpen this image but are not a calibration (with dim dark field they came out no closer to the truth than the rigid board); for the array's placement calibrate (fpm calibrate), or expose the dark-field frames longer"
                ),
            );
        }
    }
    if let Some(fit) = report.bright_field_fit.filter(|f| f.is_suspect()) {
        let floats = report.sample_bits == Some(32);
        let cause = match (report.camera_gamma, &report.camera_gamma_scan) {
            (_, Some(_)) => "stray light lifts the frames (the gamma read from them did not explain it)",
            (None, None) if floats => "stray light lifts the frames, or an offset was left in them when they were made floats (the dataset's dark_level takes a known one off); float frames carry no display gamma",
            (None, None) if report.sample_bits.is_some_and(|b| b > 8) => "stray light lifts the frames, or they were saved with a display gamma (rare for frames of more than 8 bits; then reconstruct with --camera-gamma auto)",
            (None, None) => "8-bit frames saved for viewing carry a display gamma (then reconstruct with --camera-gamma auto or 2.2, or set [camera] gamma = 2.2 and bit_depth in dataset.toml), or stray light lifts the frames",
            (Some(_), None) => "stray light lifts the frames, or the dataset's camera.gamma is not the camera's",
        };
        out.push(Check::BrightFieldOffset, format!(
            "the bright-field frames hold {:.0} % of their light as an offset that no object explains (measured ≈ {:.2} × modelled + offset, correlation {:.3}): {cause}; the image will ring around edges",
            100.0 * fit.offset_share, fit.gain, fit.correlation
        ));
    }
    let asked = report.camera_gamma_scan_reason == Some(GammaScanReason::Asked);
    if let (Some(scan), Some(gamma), false) =
        (&report.camera_gamma_scan, report.camera_gamma, asked)
    {
        let frames = match report.camera_gamma_scan_reason {
            Some(GammaScanReason::Unstated) => "integer",
            _ => "8-bit",
        };
        out.push(
            Check::GammaRead,
            format!(
                "the {frames} frames read as saved for viewing with a display gamma: decoded with {gamma:.2} (their error within {:.0} % of its least for gamma {:.1}-{:.1}, and clearly above it as linear); if the camera saved raw counts, give --camera-gamma 1, or state [camera] gamma in dataset.toml",
                100.0 * fpm_physics::reconstruct::gamma::FLAT_WITHIN,
                scan.range.0,
                scan.range.1
            ),
        );
    }
    if let Some(scan) = report
        .camera_gamma_scan
        .as_ref()
        .filter(|s| asked && s.is_flat())
    {
        out.push(Check::GammaWeak, format!(
            "the camera gamma read from the frames is weak: their error stays within {:.0} % of its least for every gamma from {:.1} to {:.1} (a sample with little contrast, or no dim dark-field light); state the camera's gamma if it is known",
            100.0 * fpm_physics::reconstruct::gamma::FLAT_WITHIN,
            scan.range.0,
            scan.range.1
        ));
    }
    let height_choice = report.height_choice;
    if let Some(c) = height_choice.filter(|c| c.edge_taken) {
        out.push(Check::HeightFromEdge, format!(
            "the bright/dark-field boundary puts the LEDs {:.2} ± {:.2} mm below the sample, not the dataset's {:.2} mm, and the frames agree (their error {:.4} at it, {:.4} at the dataset's): reconstructed at {:.2} mm; correct height_mm in dataset.toml or calibrate (fpm calibrate), or give --led-height-mm {} to keep the dataset's",
            c.edge_mm, c.edge_sigma_mm, c.stated_mm, c.edge_error, c.stated_error, c.edge_mm, c.stated_mm
        ));
    }
    // Where the frames fit the dataset's height at least as well as the edge's, the
    // edge is what is off (soft vignetting moves it): no warning.
    let weighed = height_choice.is_some_and(|c| c.edge_taken || c.stated_fits_better());
    if let Some(b) = report
        .height_from_boundary
        .filter(|b| b.disagrees() && !weighed)
    {
        // A calibrated h is only as good as the defocus it was told; a dataset's h
        // may simply be wrong, and the edge's own estimate can stand in for it.
        let advice = if report.geometry_source.is_nominal() {
            format!(
                "the dataset's height_mm (or its NA) may be off: --led-height-mm {:.1} reconstructs with the edge's height",
                b.estimate.height_mm
            )
        } else {
            "check the defocus the calibration was told (h is proportional to it) and the NA"
                .to_string()
        };
        out.push(Check::HeightFromEdge, format!(
            "the bright/dark-field boundary puts the LEDs {:.2} ± {:.2} mm below the sample (the NA's {:.0} % included), the geometry {:.2} mm ({:+.1}σ): {advice}",
            b.estimate.height_mm, b.sigma_with_na_mm, b.na_relative_sigma * 100.0, b.geometry_height_mm, b.difference_sigma
        ));
    }
    if let Some(p) = report
        .height_from_boundary
        .and_then(|b| b.entrance_pupil)
        .filter(|p| p.fits_better(report.system.entrance_pupil_mm))
    {
        let (best, advice) = match p.entrance_pupil_mm {
            Some(mm) => (
                format!("an objective whose entrance pupil is {mm:.0} mm above the sample"),
                format!(
                    "if the objective is not telecentric (a camera lens, a simple low-power objective), reconstruct with --entrance-pupil-mm {mm:.0}{}",
                    if report.geometry_source.is_nominal() {
                        format!(" --led-height-mm {:.1}", p.height_mm)
                    } else {
                        String::new()
                    }
                ),
            ),
            None => (
                "a telecentric objective".to_string(),
                "leave --entrance-pupil-mm out".to_string(),
            ),
        };
        out.push(Check::EntrancePupil, format!(
            "the frames' bright/dark-field edges fit {best} (h {:.1} mm) better than the system as given: {} blocks off against {}; {advice}",
            p.height_mm, p.mismatched_blocks, p.mismatched_blocks_as_given
        ));
    }
    out.extend(Check::DarkFieldBackground, stray_light(&report.background));
    let b = &report.background_phase;
    if b.block_um.is_some() && b.totals.fitted * 2 < b.totals.blocks {
        out.push(Check::FlattenBackground, format!(
            "--flatten-background found clear background in only {} of {} blocks: elsewhere the slow phase is as EPRY left it (is the sample on clear glass? for one that fills the field, leave the flag off)",
            b.totals.fitted, b.totals.blocks
        ));
    }
    out.0
}
