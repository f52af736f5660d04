//! A tilted board. Tilted about its x or y axis, the board puts its LEDs at different
//! heights, and the shifts stop being a similarity transform of the grid: an LED at
//! (a, b) from the centre LED sits b·sin α + a·sin β farther away, which scales its shift
//! by 1 − (b·sin α + a·sin β)/h. The tilt therefore shows only in terms of second order
//! in the LED's distance (z·a·b·α/h²), but their mean over the grid is absorbed into
//! the rigid fit's Δx, Δy: a 2° tilt moves them by several µm.
//!
//! The fit frees the two tilts alongside (Δx, Δy, θ, h), by Gauss–Newton weighted by
//! each shift's own noise, and says how well the data pin them down.

use nalgebra::{SMatrix, SVector};

use super::fit::{Observation, Params, Setup};
use crate::optics::board_offset;

/// Six parameters: the rigid four and the tilts about x and y, radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TiltedParams {
    /// Δx, Δy (µm), θ (rad), h (µm) of the centre LED.
    pub rigid: Params,
    /// Tilt about the board's x and y axes, radians.
    pub tilt: (f64, f64),
}

impl TiltedParams {
    fn to_vector(self) -> SVector<f64, 6> {
        let r = self.rigid;
        SVector::from([r.dx, r.dy, r.theta, r.h, self.tilt.0, self.tilt.1])
    }

    fn from_vector(v: &SVector<f64, 6>) -> Self {
        Self {
            rigid: Params {
                dx: v[0],
                dy: v[1],
                theta: v[2],
                h: v[3],
            },
            tilt: (v[4], v[5]),
        }
    }
}

/// The shift under grid offset `grid` on a tilted board: z·(x_c − x, y_c − y)/h_led.
pub fn predict(s: &Setup, p: &TiltedParams, grid: (f64, f64)) -> (f64, f64) {
    let r = &p.rigid;
    let [x, y, depth] = board_offset(s.pitch_um, r.theta, p.tilt, grid, 0.0);
    let k = s.z_um / (r.h + depth);
    (
        k * (s.feature_um.0 - x - r.dx),
        k * (s.feature_um.1 - y - r.dy),
    )
}

/// Finite-difference steps of the six parameters: far below their uncertainties, far
/// above rounding.
const STEPS: [f64; 6] = [1e-3, 1e-3, 1e-8, 1e-2, 1e-7, 1e-7];

/// Jacobian rows (∂s_x, ∂s_y) of the six parameters, by central differences.
fn jacobian(s: &Setup, p: &TiltedParams, grid: (f64, f64)) -> [SVector<f64, 6>; 2] {
    let v = p.to_vector();
    let mut jx = SVector::<f64, 6>::zeros();
    let mut jy = SVector::<f64, 6>::zeros();
    for k in 0..6 {
        let (mut up, mut down) = (v, v);
        up[k] += STEPS[k];
        down[k] -= STEPS[k];
        let a = predict(s, &TiltedParams::from_vector(&up), grid);
        let b = predict(s, &TiltedParams::from_vector(&down), grid);
        jx[k] = (a.0 - b.0) / (2.0 * STEPS[k]);
        jy[k] = (a.1 - b.1) / (2.0 * STEPS[k]);
    }
    [jx, jy]
}

/// The six-parameter fit and what it says about itself.
#[derive(Debug, Clone, PartialEq)]
pub struct TiltFit {
    /// The parameters.
    pub params: TiltedParams,
    /// Covariance of (Δx, Δy, θ, h, tilt x, tilt y), scaled up by the reduced χ² when
    /// the shifts scatter more than their noise says.
    pub covariance: SMatrix<f64, 6, 6>,
    /// Covariance of the rigid four with the tilts held at zero, same weights and
    /// scale: what freeing the tilts costs is the difference.
    pub rigid_covariance: SMatrix<f64, 4, 4>,
    /// χ² per degree of freedom.
    pub reduced_chi2: f64,
}

impl TiltFit {
    /// One standard deviation of each of the six parameters.
    pub fn sigma(&self) -> [f64; 6] {
        std::array::from_fn(|k| self.covariance[(k, k)].max(0.0).sqrt())
    }

    /// The extra 1σ of each rigid parameter that freeing the tilts adds, in
    /// quadrature to the rigid fit's.
    pub fn freed_sigma(&self) -> [f64; 4] {
        std::array::from_fn(|k| {
            (self.covariance[(k, k)] - self.rigid_covariance[(k, k)])
                .max(0.0)
                .sqrt()
        })
    }
}

/// Fit the six parameters to the `used` shifts, each weighted by its 1σ (x, y), from
/// the rigid fit `start`. `None` if the used shifts cannot constrain six parameters.
pub fn fit(
    s: &Setup,
    obs: &[Observation],
    sigma_um: &[(f64, f64)],
    used: &[bool],
    start: Params,
) -> Option<TiltFit> {
    let rows: Vec<(Observation, (f64, f64))> = obs
        .iter()
        .zip(sigma_um)
        .zip(used)
        .filter(|(_, &u)| u)
        .map(|((o, &sg), _)| (*o, (sg.0.max(1e-6), sg.1.max(1e-6))))
        .collect();
    if rows.len() < 5 {
        return None;
    }
    let normal = |p: &TiltedParams| {
        let mut jtj = SMatrix::<f64, 6, 6>::zeros();
        let mut jtr = SVector::<f64, 6>::zeros();
        let mut chi2 = 0.0;
        for (o, sg) in &rows {
            let m = predict(s, p, o.grid);
            let [jx, jy] = jacobian(s, p, o.grid);
            for (j, r, w) in [
                (jx, o.shift_um.0 - m.0, 1.0 / (sg.0 * sg.0)),
                (jy, o.shift_um.1 - m.1, 1.0 / (sg.1 * sg.1)),
            ] {
                jtj += w * j * j.transpose();
                jtr += w * j * r;
                chi2 += w * r * r;
            }
        }
        (jtj, jtr, chi2)
    };
    let mut p = TiltedParams {
        rigid: start,
        tilt: (0.0, 0.0),
    };
    let flat_normal = normal(&p).0;
    for _ in 0..20 {
        let (jtj, jtr, _) = normal(&p);
        let step = jtj.try_inverse()? * jtr;
        p = TiltedParams::from_vector(&(p.to_vector() + step));
        // Done once every step is below its finite-difference step.
        if step.iter().zip(STEPS).all(|(d, h)| d.abs() < h) {
            break;
        }
    }
    let (jtj, _, chi2) = normal(&p);
    let dof = (2 * rows.len()).saturating_sub(6).max(1) as f64;
    let reduced_chi2 = chi2 / dof;
    let scale = reduced_chi2.max(1.0);
    let covariance = jtj.try_inverse()? * scale;
    let rigid_covariance = flat_normal
        .fixed_view::<4, 4>(0, 0)
        .into_owned()
        .try_inverse()?
        * scale;
    Some(TiltFit {
        params: p,
        covariance,
        rigid_covariance,
        reduced_chi2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::fit;

    fn setup() -> Setup {
        Setup {
            feature_um: (20.0, -10.0),
            z_um: 200.0,
            pitch_um: 2500.0,
        }
    }

    /// Without tilt the model is the rigid one.
    #[test]
    fn a_flat_board_predicts_the_rigid_shifts() {
        let rigid = Params {
            dx: 800.0,
            dy: -600.0,
            theta: 0.05,
            h: 92_000.0,
        };
        let flat = TiltedParams {
            rigid,
            tilt: (0.0, 0.0),
        };
        for grid in [(2.0, -1.0), (0.0, 0.0), (-3.0, 3.0)] {
            let (a, b) = (
                predict(&setup(), &flat, grid),
                fit::predict(&setup(), &rigid, grid),
            );
            assert!((a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9);
        }
    }

    /// Noise-free shifts of a tilted board: the fit finds the tilt and the rigid four,
    /// which the rigid fit gets wrong.
    #[test]
    fn the_tilt_is_recovered_from_clean_shifts() {
        let truth = TiltedParams {
            rigid: Params {
                dx: 500.0,
                dy: 300.0,
                theta: 0.03,
                h: 90_000.0,
            },
            tilt: (2f64.to_radians(), -1f64.to_radians()),
        };
        let obs: Vec<Observation> = (-3..=3)
            .flat_map(|a| (-3..=3).map(move |b| (a as f64, b as f64)))
            .map(|grid| Observation {
                grid,
                shift_um: predict(&setup(), &truth, grid),
            })
            .collect();
        let n = obs.len();
        let ones = vec![1.0; n];
        let rigid = fit::refine(
            &setup(),
            &obs,
            &ones,
            fit::closed_form(&setup(), &obs, &ones).unwrap(),
        )
        .unwrap()
        .params;
        assert!((rigid.dy - truth.rigid.dy).abs() > 2.0, "{rigid:?}");
        let f = fit(
            &setup(),
            &obs,
            &vec![(0.01, 0.01); n],
            &vec![true; n],
            rigid,
        )
        .unwrap();
        let p = f.params;
        assert!((p.rigid.dx - truth.rigid.dx).abs() < 1e-3, "{p:?}");
        assert!((p.rigid.dy - truth.rigid.dy).abs() < 1e-3, "{p:?}");
        assert!((p.rigid.h - truth.rigid.h).abs() < 1e-2, "{p:?}");
        assert!((p.tilt.0 - truth.tilt.0).abs() < 1e-6 && (p.tilt.1 - truth.tilt.1).abs() < 1e-6);
        assert!(f.freed_sigma()[1] > 0.0);
    }
}
