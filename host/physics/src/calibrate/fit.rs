//! Fitting the LED array to measured shifts.
//!
//! The shift of a feature at (x_c, y_c) under LED (p, q) is
//! s = (z/h)·(x_c − Δx − d(p cos θ − q sin θ), y_c − Δy − d(p sin θ + q cos θ)):
//! a similarity transform of the grid. Its linear least-squares solution is exact and
//! unique; Gauss–Newton on (Δx, Δy, θ, h) then applies robust weights and yields the
//! parameter covariance.

use nalgebra::{Matrix4, Vector4};

/// One LED's measured shift.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Grid offsets (p, q) from the nominal centre LED.
    pub grid: (f64, f64),
    /// Measured shift (x, y), µm in the sample plane.
    pub shift_um: (f64, f64),
}

/// The fitted array, in µm and radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Params {
    /// Δx, µm.
    pub dx: f64,
    /// Δy, µm.
    pub dy: f64,
    /// θ, rad.
    pub theta: f64,
    /// h, µm.
    pub h: f64,
}

/// Known quantities of the fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setup {
    /// Feature position, µm.
    pub feature_um: (f64, f64),
    /// Defocus, µm.
    pub z_um: f64,
    /// LED pitch, µm.
    pub pitch_um: f64,
}

/// Shift predicted for grid offset (p, q).
pub fn predict(s: &Setup, p: &Params, grid: (f64, f64)) -> (f64, f64) {
    let (sin, cos) = p.theta.sin_cos();
    let x = s.pitch_um * (grid.0 * cos - grid.1 * sin) + p.dx;
    let y = s.pitch_um * (grid.0 * sin + grid.1 * cos) + p.dy;
    (
        s.z_um / p.h * (s.feature_um.0 - x),
        s.z_um / p.h * (s.feature_um.1 - y),
    )
}

/// The linear least-squares similarity fit. `None` with fewer than 3 observations or a
/// degenerate layout.
pub fn closed_form(s: &Setup, obs: &[Observation], weights: &[f64]) -> Option<Params> {
    // s_x = tx − A p + B q,  s_y = ty − B p − A q, with A = a cos θ, B = a sin θ, a = z d/h
    let mut ata = Matrix4::<f64>::zeros();
    let mut atb = Vector4::<f64>::zeros();
    let mut used = 0;
    for (o, &w) in obs.iter().zip(weights) {
        if w <= 0.0 {
            continue;
        }
        used += 1;
        let (p, q) = o.grid;
        for (row, rhs) in [
            ([-p, q, 1.0, 0.0], o.shift_um.0),
            ([-q, -p, 0.0, 1.0], o.shift_um.1),
        ] {
            let v = Vector4::from(row);
            ata += w * v * v.transpose();
            atb += w * v * rhs;
        }
    }
    if used < 3 {
        return None;
    }
    let sol = ata.try_inverse()? * atb;
    let (a_cos, a_sin, tx, ty) = (sol[0], sol[1], sol[2], sol[3]);
    // a = z·d/h carries the sign of z.
    let sign = s.z_um.signum();
    let a = sign * a_cos.hypot(a_sin);
    if a == 0.0 || !a.is_finite() {
        return None;
    }
    let theta = (a_sin / a).atan2(a_cos / a);
    let h = s.z_um * s.pitch_um / a;
    Some(Params {
        dx: s.feature_um.0 - tx * h / s.z_um,
        dy: s.feature_um.1 - ty * h / s.z_um,
        theta,
        h,
    })
}

/// Jacobian rows (∂s_x, ∂s_y) with respect to (Δx, Δy, θ, h).
pub(crate) fn jacobian(s: &Setup, p: &Params, grid: (f64, f64)) -> ([f64; 4], [f64; 4]) {
    let (sin, cos) = p.theta.sin_cos();
    let k = s.z_um / p.h;
    let m = predict(s, p, grid);
    let d = s.pitch_um;
    (
        [-k, 0.0, k * d * (grid.0 * sin + grid.1 * cos), -m.0 / p.h],
        [0.0, -k, -k * d * (grid.0 * cos - grid.1 * sin), -m.1 / p.h],
    )
}

/// A weighted Gauss–Newton fit and what it says about itself.
#[derive(Debug, Clone, PartialEq)]
pub struct Refined {
    /// The parameters.
    pub params: Params,
    /// One standard deviation of (Δx µm, Δy µm, θ rad, h µm).
    pub sigma: [f64; 4],
    /// Residual vector per observation, µm.
    pub residuals: Vec<(f64, f64)>,
    /// Weighted rms residual (per component), µm.
    pub rms_um: f64,
}

/// Refine `start` by weighted Gauss–Newton.
pub fn refine(s: &Setup, obs: &[Observation], weights: &[f64], start: Params) -> Option<Refined> {
    let mut p = start;
    let mut jtj = Matrix4::<f64>::zeros();
    for _ in 0..10 {
        jtj = Matrix4::zeros();
        let mut jtr = Vector4::<f64>::zeros();
        for (o, &w) in obs.iter().zip(weights) {
            if w <= 0.0 {
                continue;
            }
            let m = predict(s, &p, o.grid);
            let (jx, jy) = jacobian(s, &p, o.grid);
            for (j, r) in [(jx, o.shift_um.0 - m.0), (jy, o.shift_um.1 - m.1)] {
                let j = Vector4::from(j);
                jtj += w * j * j.transpose();
                jtr += w * j * r;
            }
        }
        let step = jtj.try_inverse()? * jtr;
        p = Params {
            dx: p.dx + step[0],
            dy: p.dy + step[1],
            theta: p.theta + step[2],
            h: p.h + step[3],
        };
        if step[0].abs() < 1e-9
            && step[1].abs() < 1e-9
            && step[3].abs() < 1e-9
            && step[2].abs() < 1e-13
        {
            break;
        }
    }
    let residuals: Vec<(f64, f64)> = obs
        .iter()
        .map(|o| {
            let m = predict(s, &p, o.grid);
            (o.shift_um.0 - m.0, o.shift_um.1 - m.1)
        })
        .collect();
    let (mut rss, mut wsum, mut n) = (0.0, 0.0, 0usize);
    for (r, &w) in residuals.iter().zip(weights) {
        if w > 0.0 {
            rss += w * (r.0 * r.0 + r.1 * r.1);
            wsum += w;
            n += 1;
        }
    }
    let dof = (2 * n).saturating_sub(4).max(1) as f64;
    // Weights are relative; scale them so they average to one.
    let mean_w = wsum / n.max(1) as f64;
    let sigma2 = rss / mean_w / dof;
    let cov = jtj.try_inverse()? * (sigma2 * mean_w);
    Some(Refined {
        params: p,
        sigma: [
            cov[(0, 0)].sqrt(),
            cov[(1, 1)].sqrt(),
            cov[(2, 2)].sqrt(),
            cov[(3, 3)].sqrt(),
        ],
        residuals,
        rms_um: (rss / wsum.max(1e-300) / 2.0).sqrt(),
    })
}

/// Robust fit: closed form, then Gauss–Newton with Huber weights; observations beyond
/// `reject` robust standard deviations get weight 0. Returns the fit and the weights.
pub fn robust(s: &Setup, obs: &[Observation], reject: f64) -> Option<(Refined, Vec<f64>)> {
    let mut weights = vec![1.0; obs.len()];
    let start = closed_form(s, obs, &weights)?;
    let mut fit = refine(s, obs, &weights, start)?;
    for _ in 0..6 {
        let norms: Vec<f64> = fit.residuals.iter().map(|r| r.0.hypot(r.1)).collect();
        let active: Vec<f64> = norms
            .iter()
            .zip(&weights)
            .filter(|(_, &w)| w > 0.0)
            .map(|(n, _)| *n)
            .collect();
        let mad = crate::image::median(active.iter().map(|&x| x as f32)) as f64;
        // Robust σ of a 2-D residual norm; floored so a perfect fit does not reject noise.
        let scale = (1.4826 * mad).max(1e-3);
        let new: Vec<f64> = norms
            .iter()
            .map(|&r| {
                let u = r / scale;
                if u > reject {
                    0.0
                } else if u <= 1.5 {
                    1.0
                } else {
                    1.5 / u
                }
            })
            .collect();
        if new.iter().filter(|&&w| w > 0.0).count() < 4 {
            break;
        }
        let changed = new.iter().zip(&weights).any(|(a, b)| (a - b).abs() > 1e-9);
        weights = new;
        fit = refine(s, obs, &weights, fit.params)?;
        if !changed {
            break;
        }
    }
    Some((fit, weights))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setup() -> Setup {
        Setup {
            feature_um: (30.0, -20.0),
            z_um: 200.0,
            pitch_um: 2500.0,
        }
    }

    fn observations(truth: &Params, noise: impl Fn(usize) -> (f64, f64)) -> Vec<Observation> {
        let s = setup();
        let mut v = vec![];
        for q in -2..=2 {
            for p in -2..=2 {
                let grid = (p as f64, q as f64);
                let m = predict(&s, truth, grid);
                let n = noise(v.len());
                v.push(Observation {
                    grid,
                    shift_um: (m.0 + n.0, m.1 + n.1),
                });
            }
        }
        v
    }

    #[test]
    fn the_closed_form_inverts_the_model_exactly() {
        let truth = Params {
            dx: 1500.0,
            dy: -2200.0,
            theta: 4.0f64.to_radians(),
            h: 91_000.0,
        };
        let obs = observations(&truth, |_| (0.0, 0.0));
        let p = closed_form(&setup(), &obs, &vec![1.0; obs.len()]).unwrap();
        assert!((p.dx - truth.dx).abs() < 1e-6 && (p.dy - truth.dy).abs() < 1e-6);
        assert!((p.theta - truth.theta).abs() < 1e-12 && (p.h - truth.h).abs() < 1e-6);
        // negative defocus works the same
        let mut s = setup();
        s.z_um = -150.0;
        let obs: Vec<_> = obs
            .iter()
            .map(|o| Observation {
                shift_um: predict(&s, &truth, o.grid),
                ..*o
            })
            .collect();
        let p = closed_form(&s, &obs, &vec![1.0; obs.len()]).unwrap();
        assert!((p.h - truth.h).abs() < 1e-6 && (p.theta - truth.theta).abs() < 1e-12);
    }

    #[test]
    fn a_gross_outlier_is_rejected_and_the_uncertainty_is_honest() {
        let truth = Params {
            dx: -800.0,
            dy: 300.0,
            theta: -2.0f64.to_radians(),
            h: 95_000.0,
        };
        // deterministic pseudo-noise of 0.01 µm, plus one LED 2 µm off
        let mut obs = observations(&truth, |k| {
            (
                0.01 * ((k * 7 % 5) as f64 - 2.0),
                0.01 * ((k * 3 % 5) as f64 - 2.0),
            )
        });
        obs[7].shift_um.0 += 2.0;
        let (fit, w) = robust(&setup(), &obs, 5.0).unwrap();
        assert_eq!(w[7], 0.0);
        assert_eq!(w.iter().filter(|&&x| x == 0.0).count(), 1);
        let p = fit.params;
        assert!(
            (p.dx - truth.dx).abs() < 3.0 * fit.sigma[0] + 1.0,
            "{p:?} σ {:?}",
            fit.sigma
        );
        assert!((p.h - truth.h).abs() < 3.0 * fit.sigma[3] + 10.0);
        assert!(fit.rms_um < 0.03);
    }
}
