//! The stages of [`super::calibrate`], in order: split the frames, locate the feature
//! in the focused reference, measure its shift under every defocused LED, fit the rigid
//! placement (with the model-based bias taken off the second time), the final fit with
//! the board's tilt, and the report with its uncertainty.

use super::feature::{self, Feature, FeatureError};
use super::fit::{self, Observation, Params, Setup};
use super::{
    corrected, enough, frame_brightness, model, reclassify_outliers, saturated_pixels, shift, tilt,
    tilt_observable, to_geometry, uncertainty, Calibration, CalibrationError, FeatureInfo, Frame,
    LedResult, LedStatus, Measured, Options,
};
use crate::optics::{LedGeometry, Placement, System};

/// The focused reference under the centre LED, the defocused frames, and their one
/// defocus, µm.
pub(super) fn split<'f, 'a>(
    nominal: &LedGeometry,
    frames: &'f [Frame<'a>],
) -> Result<(&'f Frame<'a>, Vec<&'f Frame<'a>>, f64), CalibrationError> {
    let reference = frames
        .iter()
        .find(|f| f.defocus_um == 0.0 && f.led == nominal.center)
        .ok_or(CalibrationError::NoReference(nominal.center))?;
    let defocused: Vec<&Frame> = frames.iter().filter(|f| f.defocus_um != 0.0).collect();
    let z = defocused
        .first()
        .ok_or(CalibrationError::NoDefocused)?
        .defocus_um;
    if let Some(f) = defocused.iter().find(|f| (f.defocus_um - z).abs() > 1e-9) {
        return Err(CalibrationError::MixedDefocus {
            led: f.led,
            got: f.defocus_um,
            expected: z,
        });
    }
    Ok((reference, defocused, z))
}

/// The feature in the focused reference, and the windows its shifts are measured in.
pub(super) struct Located {
    pub feature: Feature,
    /// Half side of a defocused frame's window, pixels: the feature and its defocus blur.
    pub half_window: usize,
    /// Half side of the reference's window, pixels: the feature and its edge's ringing.
    pub reference_half: usize,
    /// The reference's first moment.
    pub reference: shift::Moment,
    /// Where the feature is in the sample plane, µm.
    pub sample_um: (f64, f64),
    /// The camera pixel size in the sample plane, µm.
    pub px: f64,
}

impl Located {
    /// Find the feature in `reference` (refused if it is saturated on the feature).
    pub fn find(
        system: &System,
        reference: &Frame<'_>,
        z: f64,
        options: &Options,
    ) -> Result<Self, CalibrationError> {
        let (height, width) = reference.image.dim();
        let px = system.sample_pixel_um();
        let feature = feature::find(reference.image, options.roi)?;
        let half_feature = (feature.bbox.w.max(feature.bbox.h) as f64 / 2.0).ceil();
        let blur_px = z.abs() * system.na / (1.0 - system.na * system.na).sqrt() / px;
        let half_window = (half_feature + 1.2 * blur_px + 6.0).ceil() as usize;
        // The focused reference needs only the feature and its edge's ringing (a few
        // resolution elements): every pixel more adds noise to the moment that every
        // shift subtracts, magnified h/|z| in Δx, Δy.
        let resolution_px = system.wavelength_um / system.na / px;
        let reference_half = (half_feature + 2.0 * resolution_px + 6.0).ceil() as usize;
        let moment = shift::first_moment(
            reference.image,
            feature.polarity,
            feature.center_px,
            reference_half.min(half_window),
            3,
        )
        .map(|m| m.with_pixel_noise(reference.image))
        .ok_or(FeatureError::NotFound {
            area: feature.area_px,
        })?;
        if let Some(sat) = reference.saturation {
            let n = saturated_pixels(reference.image, moment.window, sat);
            if n > 0 {
                return Err(CalibrationError::SaturatedReference(n));
            }
        }
        let c = moment.center_px;
        let sample_um = system.pixel_to_sample(c.0, c.1, width, height);
        Ok(Self {
            feature,
            half_window,
            reference_half,
            reference: moment,
            sample_um,
            px,
        })
    }
}

/// A window cut by the frame's edge is used if at least this share of it is left.
pub(super) const MIN_WINDOW_LEFT: f64 = 0.5;

/// Every defocused frame measured: the window starts where the nominal geometry (with
/// generous slack) puts the feature and then follows it.
pub(super) fn measure(
    nominal: &LedGeometry,
    reference: &Frame<'_>,
    defocused: &[&Frame<'_>],
    located: &Located,
    z: f64,
    options: &Options,
) -> Vec<Measured> {
    let (px, ref_center) = (located.px, located.reference.center_px);
    let (xc, yc) = located.sample_um;
    let ref_brightness = frame_brightness(reference);
    defocused
        .iter()
        .map(|f| {
            let grid = nominal.grid_offset(f.led);
            let brightness = frame_brightness(f) / ref_brightness.max(1e-300);
            let expect = nominal.defocus_shift_um(f.led, xc, yc, z);
            let start = (ref_center.0 + expect.0 / px, ref_center.1 + expect.1 / px);
            let polarity = located.feature.polarity;
            let m = shift::first_moment(f.image, polarity, start, located.half_window, 4)
                .map(|m| m.with_pixel_noise(f.image));
            let saturated = |m: &shift::Moment| {
                f.saturation
                    .is_some_and(|sat| saturated_pixels(f.image, m.window, sat) > 0)
            };
            let shift_of = |m: &shift::Moment| {
                Some((
                    (m.center_px.0 - ref_center.0) * px,
                    (m.center_px.1 - ref_center.1) * px,
                ))
            };
            let full = (2 * located.half_window + 1).pow(2) as f64;
            let (shift_um, mut status, cut_by_edge) = match m {
                Some(m) if saturated(&m) => (None, LedStatus::Saturated, false),
                Some(m) if !m.clipped => (shift_of(&m), LedStatus::Used, false),
                // Cut by the frame's edge: the moment is biased toward the inside, and
                // the bias model, cut the same way, accounts for it; most of the
                // window must be left.
                Some(m)
                    if options.bias_correction
                        && (m.window.w * m.window.h) as f64 >= MIN_WINDOW_LEFT * full =>
                {
                    (shift_of(&m), LedStatus::Used, true)
                }
                _ => (None, LedStatus::FeatureLost, false),
            };
            let sigma_um = m.map_or((0.0, 0.0), |m| (m.sigma_px.0 * px, m.sigma_px.1 * px));
            if brightness < options.min_brightness {
                status = LedStatus::NotBrightField;
            }
            Measured {
                led: f.led,
                grid,
                brightness,
                shift_um,
                sigma_um,
                status,
                cut_by_edge,
            }
        })
        .collect()
}

/// The rigid placement, robustly: fit; leave out LEDs whose spectrum the pupil cuts;
/// take each shift's model-based bias off; fit again. The parameters and the bias.
pub(super) fn fit_rigid(
    system: &System,
    nominal: &LedGeometry,
    reference: &Frame<'_>,
    located: &Located,
    setup: &Setup,
    measured: &mut [Measured],
    options: &Options,
) -> Result<(Params, Vec<(f64, f64)>), CalibrationError> {
    let (px, z) = (located.px, setup.z_um);
    let (xc, yc) = located.sample_um;
    let mut bias: Vec<(f64, f64)> = vec![(0.0, 0.0); measured.len()];
    let mut model = options.bias_correction.then(|| {
        let max_shift_px = measured
            .iter()
            .filter(|m| m.status == LedStatus::Used)
            .filter_map(|m| m.shift_um)
            .map(|s| s.0.hypot(s.1) / px)
            .fold(0.0, f64::max);
        let mut m = model::FeatureModel::new(
            system,
            reference.image,
            &located.feature,
            located.half_window,
            max_shift_px + 4.0,
        );
        m.reference_half_window = located.reference_half.min(located.half_window);
        m.pupil_centre = system.chief_ray_frequency(xc, yc);
        let (h, w) = reference.image.dim();
        m.cut_at_frame(w, h);
        m
    });
    // Model-based bias of each measured shift under `geometry` (only the frames cut
    // by the edge when `cut_only`).
    let biases = |model: &mut model::FeatureModel,
                  geometry: &LedGeometry,
                  measured: &[Measured],
                  bias: &mut [(f64, f64)],
                  cut_only: bool| {
        let f_ref = geometry.illumination_frequency(nominal.center, xc, yc, system.wavelength_um);
        for (m, b) in measured.iter().zip(bias.iter_mut()) {
            if m.shift_um.is_none() || (cut_only && !m.cut_by_edge) {
                continue;
            }
            let f_led = geometry.illumination_frequency(m.led, xc, yc, system.wavelength_um);
            let ideal = geometry.defocus_shift_um(m.led, xc, yc, z);
            let start = (ideal.0 / px, ideal.1 / px);
            if let Some(pred) = model.predicted_shift_um(system, f_ref, f_led, z, start) {
                *b = (pred.0 - ideal.0, pred.1 - ideal.1);
            }
        }
    };
    // A shift the edge cut is far off until its bias is taken off: under the nominal
    // geometry for the first fit.
    if let Some(model) = model.as_mut() {
        biases(model, nominal, measured, &mut bias, true);
    }
    // The feature's spectrum is ~2/size wide; keep LEDs whose disc edge clears it.
    let feature_size_um = (located.feature.area_px as f64).sqrt() * px;
    let spectral_margin = 2.0 / feature_size_um.max(px);
    let mut result = None;
    for round in 0..2 {
        let obs = corrected(measured, &bias);
        let mask: Vec<bool> = measured
            .iter()
            .map(|m| m.status == LedStatus::Used)
            .collect();
        let masked: Vec<Observation> = obs
            .iter()
            .zip(&mask)
            .filter(|(_, &k)| k)
            .map(|(o, _)| *o)
            .collect();
        let (fit, weights) =
            fit::robust(setup, &masked, options.reject_sigma).ok_or(CalibrationError::Fit)?;
        let mut wi = weights.iter();
        for (m, &k) in measured.iter_mut().zip(&mask) {
            if k && wi.next().is_some_and(|&w| w == 0.0) {
                m.status = LedStatus::Outlier;
            }
        }
        let geometry = to_geometry(nominal, &fit.params);
        // Leave out LEDs near the pupil edge under the fitted geometry, also those the
        // robust fit has just rejected: the edge's cut of the feature's spectrum is why
        // their shift is off, not their place on the board (a perfect board's corner
        // LED, 0.06 mm "off" at 8σ, was reported as misplaced).
        for m in measured
            .iter_mut()
            .filter(|m| matches!(m.status, LedStatus::Used | LedStatus::Outlier))
        {
            let (fx, fy) = geometry.pupil_frequency(m.led, xc, yc, system);
            if fx.hypot(fy) > system.cutoff() - spectral_margin {
                m.status = LedStatus::NearPupilEdge;
            }
        }
        result = Some(fit.params);
        if round == 1 || enough(measured).is_err() {
            break;
        }
        let Some(model) = model.as_mut() else {
            break;
        };
        biases(model, &geometry, measured, &mut bias, false);
    }
    Ok((result.ok_or(CalibrationError::Fit)?, bias))
}

/// The final fit and what it rests on.
pub(super) struct FinalFit {
    /// The bias-corrected shifts.
    obs: Vec<Observation>,
    /// 1σ of each shift from its frame's noise, µm.
    shift_sigma: Vec<(f64, f64)>,
    /// How much of the model's bias counts as its own error.
    model_share: f64,
    fit: fit::Refined,
    used: Vec<bool>,
    tilted: Option<tilt::TiltFit>,
}

/// The final fit on exactly the LEDs reported as used, and the board's tilt from the
/// second-order pattern it leaves in the shifts. A tilt the rigid fit cannot describe
/// can make it reject good LEDs: once the tilt is seen, the outliers are decided again
/// under the tilted model.
pub(super) fn fit_final(
    setup: &Setup,
    measured: &mut [Measured],
    bias: &[(f64, f64)],
    start: Params,
    options: &Options,
) -> Result<FinalFit, CalibrationError> {
    let obs = corrected(measured, bias);
    let shift_sigma: Vec<(f64, f64)> = measured.iter().map(|m| m.sigma_um).collect();
    let model_share = if options.bias_correction {
        options.model_fraction
    } else {
        0.0
    };
    let tilt_sigma: Vec<(f64, f64)> = shift_sigma
        .iter()
        .zip(bias)
        .map(|(s, b)| (s.0.hypot(model_share * b.0), s.1.hypot(model_share * b.1)))
        .collect();
    let mut round = 0;
    loop {
        let used: Vec<bool> = measured
            .iter()
            .map(|m| m.status == LedStatus::Used)
            .collect();
        let weights: Vec<f64> = used.iter().map(|&u| f64::from(u8::from(u))).collect();
        let fit = fit::refine(setup, &obs, &weights, start).ok_or(CalibrationError::Fit)?;
        let tilted = options
            .fit_tilt
            .then(|| tilt::fit(setup, &obs, &tilt_sigma, &used, fit.params))
            .flatten();
        round += 1;
        let changed = match tilted.as_ref().filter(|t| tilt_observable(t)) {
            Some(t) if round < 2 => {
                reclassify_outliers(measured, &obs, setup, &t.params, options.reject_sigma)
            }
            _ => false,
        };
        if !changed {
            return Ok(FinalFit {
                obs,
                shift_sigma,
                model_share,
                fit,
                used,
                tilted,
            });
        }
        enough(measured)?;
    }
}

/// The calibration as reported: the placement (tilted where the tilt is seen), its
/// uncertainty by source, and every LED's measured, fitted and residual shift.
pub(super) fn report(
    located: &Located,
    setup: &Setup,
    measured: &[Measured],
    bias: &[(f64, f64)],
    final_fit: FinalFit,
    options: &Options,
) -> Result<Calibration, CalibrationError> {
    let FinalFit {
        obs,
        shift_sigma,
        model_share,
        fit,
        used,
        tilted,
    } = final_fit;
    let (px, z) = (located.px, setup.z_um);
    let p = fit.params;
    let reference_sigma = located.reference.sigma_px;
    let sources = uncertainty::propagate(&uncertainty::Inputs {
        setup,
        obs: &obs,
        used: &used,
        params: p,
        fit_sigma: fit.sigma,
        shift_sigma_um: &shift_sigma,
        reference_sigma_um: (reference_sigma.0 * px, reference_sigma.1 * px),
        bias_um: bias,
        model_fraction: model_share,
        defocus_sigma_um: options.defocus_sigma_um,
    })
    .ok_or(CalibrationError::Fit)?;
    let tilt_sigma_rad = tilted.as_ref().map(|t| {
        let s = t.sigma();
        (s[4], s[5])
    });
    let observable = tilted.as_ref().is_some_and(tilt_observable);
    let (final_params, tilt_rad) = match &tilted {
        Some(t) if observable => (t.params.rigid, t.params.tilt),
        _ => (p, (0.0, 0.0)),
    };
    let model = tilt::TiltedParams {
        rigid: final_params,
        tilt: tilt_rad,
    };
    // Freeing the tilt costs precision when it is fitted; an unseen one could bias the
    // rigid fit by as much. Either way it is a source of its own.
    let tilt_source = tilted.as_ref().map_or([0.0; 4], |t| t.freed_sigma());
    let sources = sources.with_tilt(tilt_source);
    let residuals: Vec<(f64, f64)> = obs
        .iter()
        .map(|o| {
            let m = tilt::predict(setup, &model, o.grid);
            (o.shift_um.0 - m.0, o.shift_um.1 - m.1)
        })
        .collect();
    let rms_um = {
        let (ss, n) = residuals
            .iter()
            .zip(&used)
            .filter(|(_, &u)| u)
            .fold((0.0, 0usize), |(ss, n), (r, _)| {
                (ss + r.0 * r.0 + r.1 * r.1, n + 1)
            });
        (ss / (2 * n.max(1)) as f64).sqrt()
    };
    let mut uncertainty = uncertainty::to_report(sources.total);
    if let Some((a, b)) = tilt_sigma_rad {
        uncertainty.tilt_x_deg = a.to_degrees();
        uncertainty.tilt_y_deg = b.to_degrees();
    }
    // A shift of the feature of s = (z/h)(x_c − x_LED) moves by −(z/h) per µm of LED.
    let to_board = -final_params.h / z;
    let leds = measured
        .iter()
        .zip(bias)
        .zip(&residuals)
        .zip(&shift_sigma)
        .map(|(((m, b), r), sigma)| {
            let fitted = tilt::predict(setup, &model, m.grid);
            let bias_share = model_share * b.0.hypot(b.1) / 2f64.sqrt();
            let shift_sigma = (0.5 * (sigma.0 * sigma.0 + sigma.1 * sigma.1)).sqrt();
            LedResult {
                led: m.led,
                grid: [m.grid.0 as i64, m.grid.1 as i64],
                status: m.status,
                brightness: m.brightness,
                measured_um: m.shift_um.map(|s| [s.0, s.1]),
                bias_um: m.shift_um.map(|_| [b.0, b.1]),
                fitted_um: [fitted.0, fitted.1],
                residual_um: m.shift_um.map(|_| r.0.hypot(r.1)),
                offset_mm: m
                    .shift_um
                    .map(|_| [r.0 * to_board * 1e-3, r.1 * to_board * 1e-3]),
                offset_sigma_mm: m
                    .shift_um
                    .map(|_| shift_sigma.hypot(bias_share) * to_board.abs() * 1e-3),
                cut_by_edge: m.cut_by_edge,
            }
        })
        .collect();
    let p = final_params;
    let ref_center = located.reference.center_px;
    let (xc, yc) = located.sample_um;
    Ok(Calibration {
        placement: Placement {
            dx_mm: p.dx * 1e-3,
            dy_mm: p.dy * 1e-3,
            theta_deg: p.theta.to_degrees(),
            height_mm: p.h * 1e-3,
            tilt_x_deg: tilt_rad.0.to_degrees(),
            tilt_y_deg: tilt_rad.1.to_degrees(),
        },
        tilt_observable: observable,
        uncertainty,
        uncertainty_sources: Some(uncertainty::Budget::from(&sources)),
        defocus_sigma_um: options.defocus_sigma_um,
        defocus_um: z,
        height_per_defocus_um: p.h * 1e-3 / z.abs(),
        rms_residual_um: rms_um,
        feature: FeatureInfo {
            x_um: xc,
            y_um: yc,
            pixel: [ref_center.0, ref_center.1],
            area_px: located.feature.area_px,
            polarity: located.feature.polarity,
        },
        leds,
    })
}
