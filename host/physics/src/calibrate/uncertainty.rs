//! Uncertainties that cover the truth: every error source that matters, propagated to
//! (Δx, Δy, θ, h) through the fit's linearisation, then added in quadrature.
//!
//! - statistical: the largest of three estimates of the fit's own spread: the residual
//!   scatter, the leave-one-LED-out jackknife (one bad LED shows here), and the
//!   defocused frames' pixel noise propagated through their moments;
//! - reference: the in-focus reference frame's pixel noise. Its moment is subtracted
//!   from every shift, so its error moves all shifts alike and the residuals cannot show
//!   it; it maps into Δx, Δy magnified by h/z (≈ 460× at 200 µm);
//! - model: a share of the model-based bias correction, for a feature the model does
//!   not describe exactly (not a sharp-edged amplitude object, a tilted slide);
//! - defocus: h is proportional to z, so h carries z's relative uncertainty.

use nalgebra::{Matrix4, Vector4};
use serde::{Deserialize, Serialize};

use super::fit::{self, Observation, Params, Setup};

/// One standard deviation of each parameter, in the fit's units (µm, µm, rad, µm).
pub type Sigma = [f64; 4];

/// What the uncertainty is made of.
pub struct Inputs<'a> {
    /// The model's constants.
    pub setup: &'a Setup,
    /// Bias-corrected shifts, one per defocused frame.
    pub obs: &'a [Observation],
    /// Which of them are in the fit.
    pub used: &'a [bool],
    /// The fitted parameters.
    pub params: Params,
    /// The fit's residual-scatter σ.
    pub fit_sigma: Sigma,
    /// Each shift's 1σ from its frame's pixel noise, µm (x, y).
    pub shift_sigma_um: &'a [(f64, f64)],
    /// The reference moment's 1σ, µm (x, y).
    pub reference_sigma_um: (f64, f64),
    /// The bias subtracted from each shift, µm.
    pub bias_um: &'a [(f64, f64)],
    /// Share of the bias correction taken as its uncertainty.
    pub model_fraction: f64,
    /// The defocus's 1σ, µm.
    pub defocus_sigma_um: f64,
}

/// Each source's σ and their sum in quadrature.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sources {
    /// The fit's own spread (largest of residual scatter, jackknife, pixel noise).
    pub statistical: Sigma,
    /// The reference frame's pixel noise.
    pub reference: Sigma,
    /// The uncertain share of the bias correction.
    pub model: Sigma,
    /// The defocus's uncertainty.
    pub defocus: Sigma,
    /// The board's tilt: what fitting it costs, or what an unseen one could do.
    pub tilt: Sigma,
    /// All of them in quadrature.
    pub total: Sigma,
}

impl Sources {
    /// The same sources with the tilt's share added.
    pub fn with_tilt(self, tilt: Sigma) -> Self {
        let total = std::array::from_fn(|p| self.total[p].hypot(tilt[p]));
        Self {
            tilt,
            total,
            ..self
        }
    }
}

/// Propagate every source. `None` if the used frames cannot constrain the parameters.
pub fn propagate(i: &Inputs<'_>) -> Option<Sources> {
    let rows: Vec<(usize, [f64; 4], [f64; 4])> = i
        .obs
        .iter()
        .enumerate()
        .filter(|(k, _)| i.used[*k])
        .map(|(k, o)| {
            let (jx, jy) = fit::jacobian(i.setup, &i.params, o.grid);
            (k, jx, jy)
        })
        .collect();
    let mut jtj = Matrix4::<f64>::zeros();
    for (_, jx, jy) in &rows {
        for j in [jx, jy] {
            let j = Vector4::from(*j);
            jtj += j * j.transpose();
        }
    }
    let m = jtj.try_inverse()?;
    // The parameter change for a change `e(k)` (x, y) of each used shift.
    let response = |e: &dyn Fn(usize) -> (f64, f64)| -> Vector4<f64> {
        let mut g = Vector4::zeros();
        for (k, jx, jy) in &rows {
            let (ex, ey) = e(*k);
            g += Vector4::from(*jx) * ex + Vector4::from(*jy) * ey;
        }
        m * g
    };
    let mut noise = Vector4::<f64>::zeros();
    for (k, jx, jy) in &rows {
        let (sx, sy) = i.shift_sigma_um[*k];
        let (ax, ay) = (m * Vector4::from(*jx), m * Vector4::from(*jy));
        noise += ax.component_mul(&ax) * (sx * sx) + ay.component_mul(&ay) * (sy * sy);
    }
    let along_x = response(&|_| (1.0, 0.0)) * i.reference_sigma_um.0;
    let along_y = response(&|_| (0.0, 1.0)) * i.reference_sigma_um.1;
    let model = response(&|k| i.bias_um[k]) * i.model_fraction;
    let jack = jackknife(i)?;
    let statistical: Sigma =
        std::array::from_fn(|p| i.fit_sigma[p].max(jack[p]).max(noise[p].sqrt()));
    let reference: Sigma = std::array::from_fn(|p| along_x[p].hypot(along_y[p]));
    let model: Sigma = std::array::from_fn(|p| model[p].abs());
    let defocus: Sigma = [
        0.0,
        0.0,
        0.0,
        i.params.h.abs() * i.defocus_sigma_um / i.setup.z_um.abs().max(1e-9),
    ];
    let total = std::array::from_fn(|p| {
        (statistical[p].powi(2) + reference[p].powi(2) + model[p].powi(2) + defocus[p].powi(2))
            .sqrt()
    });
    Some(Sources {
        statistical,
        reference,
        model,
        defocus,
        tilt: [0.0; 4],
        total,
    })
}

/// Leave-one-LED-out jackknife σ of each parameter.
fn jackknife(i: &Inputs<'_>) -> Option<Sigma> {
    let used: Vec<usize> = (0..i.obs.len()).filter(|&k| i.used[k]).collect();
    let n = used.len();
    if n < 6 {
        // Too few to leave one out and still be over-determined: no estimate.
        return Some([0.0; 4]);
    }
    let mut fits = vec![];
    for &skip in &used {
        let weights: Vec<f64> = (0..i.obs.len())
            .map(|k| if i.used[k] && k != skip { 1.0 } else { 0.0 })
            .collect();
        let p = fit::refine(i.setup, i.obs, &weights, i.params)?.params;
        fits.push([p.dx, p.dy, p.theta, p.h]);
    }
    Some(std::array::from_fn(|p| {
        let mean = fits.iter().map(|f| f[p]).sum::<f64>() / n as f64;
        let ss = fits.iter().map(|f| (f[p] - mean).powi(2)).sum::<f64>();
        ((n - 1) as f64 / n as f64 * ss).sqrt()
    }))
}

/// A σ in the units of `calibration.json` (mm, mm, °, mm).
pub fn to_report(s: Sigma) -> super::Uncertainty {
    super::Uncertainty {
        dx_mm: s[0] * 1e-3,
        dy_mm: s[1] * 1e-3,
        theta_deg: s[2].to_degrees(),
        height_mm: s[3] * 1e-3,
        tilt_x_deg: 0.0,
        tilt_y_deg: 0.0,
    }
}

/// The sources in `calibration.json` (`uncertainty_sources`).
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct Budget {
    /// The fit's own spread: the largest of the residual scatter, the leave-one-LED-out
    /// jackknife and the defocused frames' pixel noise.
    pub statistical: super::Uncertainty,
    /// The in-focus reference frame's pixel noise (moves every shift alike).
    pub reference_frame: super::Uncertainty,
    /// The uncertain share of the model-based bias correction.
    pub model_bias: super::Uncertainty,
    /// The defocus's uncertainty (h only).
    pub defocus: super::Uncertainty,
    /// The board's tilt: the precision fitting it costs, or, when the shifts cannot
    /// see it, what an unseen tilt of that size could do to the rigid fit.
    #[serde(default)]
    pub tilt: Option<super::Uncertainty>,
}

impl From<&Sources> for Budget {
    fn from(s: &Sources) -> Self {
        Self {
            statistical: to_report(s.statistical),
            reference_frame: to_report(s.reference),
            model_bias: to_report(s.model),
            defocus: to_report(s.defocus),
            tilt: Some(to_report(s.tilt)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setup() -> Setup {
        Setup {
            feature_um: (0.0, 0.0),
            z_um: 200.0,
            pitch_um: 2500.0,
        }
    }

    fn grid_obs(p: &Params) -> Vec<Observation> {
        (-2..=2)
            .flat_map(|a| (-2..=2).map(move |b| (a as f64, b as f64)))
            .map(|grid| Observation {
                grid,
                shift_um: fit::predict(&setup(), p, grid),
            })
            .collect()
    }

    /// A reference moment off by δ moves Δx by δ·h/z, and the propagation says so.
    #[test]
    fn the_reference_frame_error_is_magnified_by_h_over_z() {
        let p = Params {
            dx: 1000.0,
            dy: -500.0,
            theta: 0.05,
            h: 92_000.0,
        };
        let obs = grid_obs(&p);
        let n = obs.len();
        let s = propagate(&Inputs {
            setup: &setup(),
            obs: &obs,
            used: &vec![true; n],
            params: p,
            fit_sigma: [0.0; 4],
            shift_sigma_um: &vec![(0.0, 0.0); n],
            reference_sigma_um: (0.01, 0.0),
            bias_um: &vec![(0.0, 0.0); n],
            model_fraction: 0.0,
            defocus_sigma_um: 2.0,
        })
        .unwrap();
        let expected = 0.01 * p.h / 200.0;
        assert!((s.reference[0] / expected - 1.0).abs() < 0.05, "{s:?}");
        assert!(s.reference[1] < 0.05 * expected);
        // h carries z's relative error: 2/200 of 92 mm.
        assert!((s.defocus[3] - 920.0).abs() < 1.0);
        assert!(s.total[0] >= s.reference[0]);
    }

    /// One LED off by a few µm shows in the jackknife even when weighted like the rest.
    #[test]
    fn a_single_bad_led_widens_the_statistical_spread() {
        let p = Params {
            dx: 0.0,
            dy: 0.0,
            theta: 0.0,
            h: 90_000.0,
        };
        let mut obs = grid_obs(&p);
        let n = obs.len();
        let clean = |obs: &[Observation]| {
            propagate(&Inputs {
                setup: &setup(),
                obs,
                used: &vec![true; n],
                params: p,
                fit_sigma: [0.0; 4],
                shift_sigma_um: &vec![(0.001, 0.001); n],
                reference_sigma_um: (0.0, 0.0),
                bias_um: &vec![(0.0, 0.0); n],
                model_fraction: 0.0,
                defocus_sigma_um: 0.0,
            })
            .unwrap()
        };
        let before = clean(&obs).statistical[0];
        obs[0].shift_um.0 += 0.05;
        let after = clean(&obs).statistical[0];
        assert!(after > 3.0 * before, "{before} → {after}");
    }
}
