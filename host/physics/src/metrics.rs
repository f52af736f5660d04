//! Quality metrics of docs/dataset.md §6 and the resampling they need.

use ndarray::Array2;
use rustfft::num_complex::Complex32;

use crate::fft::{bin_frequency, Fft2};

/// Resample a square complex field onto an `m × m` grid over the same field of view;
/// see [`resample_to`].
pub fn resample(
    field: &Array2<Complex32>,
    pitch: f64,
    m: usize,
    keep: impl Fn(f64, f64) -> bool,
) -> Array2<Complex32> {
    resample_to(field, pitch, (m, m), keep)
}

/// Resample a complex field over the same field of view onto a `rows × cols` grid by
/// cropping or zero-padding its spectrum, keeping only frequencies where `keep(fx, fy)`
/// (cycles per unit of `pitch`) holds. Amplitudes are preserved. Fields need not be
/// square; both axes keep their own frequency step.
pub fn resample_to(
    field: &Array2<Complex32>,
    pitch: f64,
    (rows, cols): (usize, usize),
    keep: impl Fn(f64, f64) -> bool,
) -> Array2<Complex32> {
    let (h, w) = field.dim();
    let mut spec: Vec<Complex32> = field.iter().copied().collect();
    Fft2::new(w, h).forward(&mut spec);
    let mut out = vec![Complex32::default(); rows * cols];
    let (half_y, half_x) = (h.min(rows) / 2, w.min(cols) / 2);
    let signed = |k: usize, len: usize| {
        if k < len / 2 {
            k as i64
        } else {
            k as i64 - len as i64
        }
    };
    for ky in 0..h {
        let sy = signed(ky, h);
        if sy.unsigned_abs() as usize >= half_y {
            continue;
        }
        for kx in 0..w {
            let sx = signed(kx, w);
            if sx.unsigned_abs() as usize >= half_x {
                continue;
            }
            if !keep(bin_frequency(kx, w, pitch), bin_frequency(ky, h, pitch)) {
                continue;
            }
            let (oy, ox) = (
                sy.rem_euclid(rows as i64) as usize,
                sx.rem_euclid(cols as i64) as usize,
            );
            out[oy * cols + ox] = spec[ky * w + kx];
        }
    }
    Fft2::new(cols, rows).inverse(&mut out);
    let scale = (rows * cols) as f32 / (h * w) as f32;
    Array2::from_shape_fn((rows, cols), |(r, c)| out[r * cols + c] * scale)
}

/// The central `fraction` (of each side) of an array (docs/dataset.md compares on the
/// central 75 %).
pub fn central(a: &Array2<Complex32>, fraction: f64) -> Vec<Complex32> {
    let (h, w) = a.dim();
    let (kh, kw) = (central_side(h, fraction), central_side(w, fraction));
    let (oy, ox) = ((h - kh) / 2, (w - kw) / 2);
    a.slice(ndarray::s![oy..oy + kh, ox..ox + kw])
        .iter()
        .copied()
        .collect()
}

/// The side [`central`] keeps of a side of `n` pixels.
fn central_side(n: usize, fraction: f64) -> usize {
    ((n as f64) * fraction).round() as usize
}

pub use crate::reconstruct::complex_nrmse;

/// [`complex_nrmse`] of `reconstruction` against `truth` (both row-major, `width`
/// columns, e.g. from [`central`]) after the low-order phase between them (piston,
/// the two tilts and the three quadratic terms) is fitted out. FPM pins the lowest
/// spatial frequencies of the phase only weakly (the bright-field frames barely see a
/// slow phase), and on simulated 128² sets that slow phase held nearly all of the
/// complex NRMSE and moved by tens of % between nearly identical runs; what LED
/// positions change is the detail this score keeps.
pub fn complex_nrmse_low_order_free(
    reconstruction: &[Complex32],
    truth: &[Complex32],
    width: usize,
) -> f64 {
    use nalgebra::{SMatrix, SVector};
    let width = width.max(1);
    let n = reconstruction.len().min(truth.len());
    let height = n / width;
    let n = width * height;
    let basis = |i: usize| {
        let (half_w, half_h) = (width as f64 / 2.0, height.max(1) as f64 / 2.0);
        let (x, y) = (
            ((i % width) as f64 - half_w) / half_w,
            ((i / width) as f64 - half_h) / half_h,
        );
        SVector::<f64, 6>::from([1.0, x, y, x * x, x * y, y * y])
    };
    let mut p = SVector::<f64, 6>::zeros();
    // Gauss–Newton on the wrapped phase of r·t̄, weighted by its modulus.
    for _ in 0..6 {
        let mut jtj = SMatrix::<f64, 6, 6>::zeros();
        let mut jtr = SVector::<f64, 6>::zeros();
        for i in 0..n {
            let d = reconstruction[i] * truth[i].conj();
            let w = d.norm() as f64;
            if w == 0.0 {
                continue;
            }
            let b = basis(i);
            let residual = (d.arg() as f64 - b.dot(&p) + std::f64::consts::PI)
                .rem_euclid(2.0 * std::f64::consts::PI)
                - std::f64::consts::PI;
            jtj += b * b.transpose() * w;
            jtr += b * (residual * w);
        }
        match jtj.try_inverse() {
            Some(inverse) => p += inverse * jtr,
            None => break,
        }
    }
    let flattened: Vec<Complex32> = (0..n)
        .map(|i| reconstruction[i] * Complex32::from_polar(1.0, -basis(i).dot(&p) as f32))
        .collect();
    complex_nrmse(&flattened, &truth[..n])
}

/// docs/dataset.md §6 reconstruction scores.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Scores {
    /// Complex NRMSE (global complex factor removed).
    pub complex_nrmse: f64,
    /// Amplitude NRMSE (best real scale) where the true amplitude exceeds 20 % of its
    /// maximum.
    pub amplitude_nrmse: f64,
    /// Phase RMSE, radians, there (global phase removed, differences wrapped).
    pub phase_rmse_rad: f64,
    /// Complex NRMSE once the low-order phase (piston, tilts, quadratic) is fitted out
    /// too ([`complex_nrmse_low_order_free`]): the detail, without the slow phase FPM
    /// pins only weakly.
    pub detail_nrmse: f64,
}

/// Score a reconstruction against the truth: both resampled to the truth's grid and
/// band-limited to the synthetic aperture (`in_aperture(fx, fy)`, cycles/µm), compared
/// on the central 75 % (docs/dataset.md §6). Pitches in µm; both fields cover the same area
/// (any aspect ratio).
pub fn score(
    reconstruction: &Array2<Complex32>,
    reconstruction_pitch_um: f64,
    truth: &Array2<Complex32>,
    truth_pitch_um: f64,
    in_aperture: impl Fn(f64, f64) -> bool,
) -> Scores {
    // docs/dataset.md §6: the central 75 %.
    const SCORED: f64 = 0.75;
    let grid = truth.dim();
    let t = central(
        &resample_to(truth, truth_pitch_um, grid, &in_aperture),
        SCORED,
    );
    let r = central(
        &resample_to(reconstruction, reconstruction_pitch_um, grid, &in_aperture),
        SCORED,
    );
    let complex = complex_nrmse(&r, &t);
    let detail = complex_nrmse_low_order_free(&r, &t, central_side(grid.1, SCORED));
    // Global complex factor c = ⟨r, t⟩/⟨r, r⟩, for the phase.
    let mut rt = rustfft::num_complex::Complex64::default();
    for (a, b) in r.iter().zip(&t) {
        let (a64, b64) = (
            rustfft::num_complex::Complex64::new(a.re as f64, a.im as f64),
            rustfft::num_complex::Complex64::new(b.re as f64, b.im as f64),
        );
        rt += a64.conj() * b64;
    }
    let rotation = if rt.norm() > 0.0 {
        rt / rt.norm()
    } else {
        1.0.into()
    };
    let max_amp = t.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
    let strong: Vec<usize> = (0..t.len())
        .filter(|&i| t[i].norm() > 0.2 * max_amp)
        .collect();
    let (mut ab, mut aa, mut bb, mut phase2) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for &i in &strong {
        let (a, b) = (r[i].norm() as f64, t[i].norm() as f64);
        ab += a * b;
        aa += a * a;
        bb += b * b;
        let ra = rustfft::num_complex::Complex64::new(r[i].re as f64, r[i].im as f64) * rotation;
        let d = (ra.arg() - (t[i].arg() as f64) + std::f64::consts::PI)
            .rem_euclid(2.0 * std::f64::consts::PI)
            - std::f64::consts::PI;
        phase2 += d * d;
    }
    let n = strong.len().max(1) as f64;
    Scores {
        complex_nrmse: complex,
        amplitude_nrmse: if aa > 0.0 && bb > 0.0 {
            ((bb - ab * ab / aa).max(0.0) / bb).sqrt()
        } else {
            1.0
        },
        phase_rmse_rad: (phase2 / n).sqrt(),
        detail_nrmse: detail,
    }
}

/// Whether (fx, fy) lies in the synthetic aperture: inside some pupil disc of radius
/// `cutoff` centred at −f_i for the illumination frequencies `discs`.
pub fn synthetic_aperture(discs: &[(f64, f64)], cutoff: f64) -> impl Fn(f64, f64) -> bool + '_ {
    let grid = DiscGrid::new(discs, cutoff);
    // Squared distances: `hypot` made this half of a 1 MP reconstruction's run time.
    let r2 = cutoff * cutoff;
    move |fx, fy| {
        grid.near(fx, fy).any(|f| {
            let (dx, dy) = (fx + f.0, fy + f.1);
            dx * dx + dy * dy <= r2
        })
    }
}

/// The discs' centres (−f_i) binned in square cells a little wider than the cutoff, so
/// that a point is tested against the discs of its cell and the eight around it, the
/// only ones that can hold it, instead of all of them (every bin of a scored field
/// against 441 discs was most of the score's time). Without a usable cutoff, one cell.
struct DiscGrid<'a> {
    discs: &'a [(f64, f64)],
    /// Cell side (0: one cell holds every disc).
    cell: f64,
    /// Cell index of the grid's first column and row.
    origin: (i64, i64),
    columns: usize,
    rows: usize,
    /// Disc indices by cell, row-major.
    cells: Vec<Vec<usize>>,
}

impl<'a> DiscGrid<'a> {
    /// More cells than this (discs scattered far apart) and the grid is not worth it.
    const MAX_CELLS: usize = 1 << 16;

    fn new(discs: &'a [(f64, f64)], cutoff: f64) -> Self {
        let one_cell = |discs| DiscGrid {
            discs,
            cell: 0.0,
            origin: (0, 0),
            columns: 1,
            rows: 1,
            cells: vec![(0..discs.len()).collect()],
        };
        // 1 % wider than the cutoff: a centre within the cutoff of a point is in the
        // point's cell or a neighbour despite the rounding of the division.
        let cell = cutoff * 1.01;
        if discs.is_empty()
            || !(cell.is_finite() && cell > 0.0)
            || discs.iter().any(|f| !(f.0.is_finite() && f.1.is_finite()))
        {
            return one_cell(discs);
        }
        let index = |f: &(f64, f64)| ((-f.0 / cell).floor() as i64, (-f.1 / cell).floor() as i64);
        let (mut lo, mut hi) = ((i64::MAX, i64::MAX), (i64::MIN, i64::MIN));
        for f in discs {
            let (x, y) = index(f);
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        let (columns, rows) = ((hi.0 - lo.0 + 1) as usize, (hi.1 - lo.1 + 1) as usize);
        if columns.saturating_mul(rows) > Self::MAX_CELLS {
            return one_cell(discs);
        }
        let mut cells = vec![Vec::new(); columns * rows];
        for (i, f) in discs.iter().enumerate() {
            let (x, y) = index(f);
            cells[(y - lo.1) as usize * columns + (x - lo.0) as usize].push(i);
        }
        DiscGrid {
            discs,
            cell,
            origin: lo,
            columns,
            rows,
            cells,
        }
    }

    /// The discs that can hold (fx, fy).
    fn near(&self, fx: f64, fy: f64) -> impl Iterator<Item = &(f64, f64)> + '_ {
        let (x0, y0, span) = if self.cell == 0.0 {
            (0, 0, 0)
        } else {
            (
                (fx / self.cell).floor() as i64 - 1 - self.origin.0,
                (fy / self.cell).floor() as i64 - 1 - self.origin.1,
                2,
            )
        };
        (y0..=y0 + span)
            .filter(|&y| y >= 0 && (y as usize) < self.rows)
            .flat_map(move |y| {
                (x0..=x0 + span)
                    .filter(|&x| x >= 0 && (x as usize) < self.columns)
                    .flat_map(move |x| &self.cells[y as usize * self.columns + x as usize])
            })
            .map(|&i| &self.discs[i])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The binned aperture holds exactly the points the plain test over every disc
    /// does, on a grid of points at and around the discs' edges.
    #[test]
    fn the_binned_aperture_is_the_union_of_its_discs() {
        let cutoff = 0.37;
        let discs: Vec<(f64, f64)> = (-6i32..=6)
            .flat_map(|r| {
                (-6i32..=6).map(move |c| (c as f64 * 0.29 + 0.01 * r as f64, r as f64 * 0.31))
            })
            .filter(|&(x, y)| x.hypot(y) < 1.8)
            .collect();
        let binned = synthetic_aperture(&discs, cutoff);
        let plain = |fx: f64, fy: f64| {
            discs.iter().any(|f| {
                let (dx, dy) = (fx + f.0, fy + f.1);
                dx * dx + dy * dy <= cutoff * cutoff
            })
        };
        let (mut inside, mut outside) = (0, 0);
        for i in -400..=400 {
            for j in -400..=400 {
                let (fx, fy) = (i as f64 * 0.00613, j as f64 * 0.00571);
                assert_eq!(binned(fx, fy), plain(fx, fy), "({fx}, {fy})");
                if plain(fx, fy) {
                    inside += 1
                } else {
                    outside += 1
                }
            }
        }
        assert!(
            inside > 10_000 && outside > 10_000,
            "{inside} in, {outside} out"
        );
        // Points on the discs' edges, where a cell's border is most often crossed.
        for f in &discs {
            for (fx, fy) in [(-f.0 + cutoff, -f.1), (-f.0, -f.1 - cutoff)] {
                assert_eq!(binned(fx, fy), plain(fx, fy), "({fx}, {fy})");
            }
        }
        // Without a usable cutoff every disc is tried, as before.
        assert!(!synthetic_aperture(&discs, 0.0)(5.0, 5.0));
        assert!(synthetic_aperture(&discs, f64::INFINITY)(5.0, 5.0));
        assert!(!synthetic_aperture(&[], cutoff)(0.0, 0.0));
    }

    #[test]
    fn a_slow_phase_is_fitted_out_and_detail_is_not() {
        let side = 48;
        let truth: Vec<Complex32> = (0..side * side)
            .map(|i| {
                let (x, y) = ((i % side) as f32, (i / side) as f32);
                Complex32::from_polar(1.0 + 0.3 * (x * 0.9).sin(), 0.8 * (y * 1.3).cos())
            })
            .collect();
        let slow = |i: usize| {
            let (x, y) = (
                (i % side) as f32 / 24.0 - 1.0,
                (i / side) as f32 / 24.0 - 1.0,
            );
            0.7 + 1.2 * x - 0.4 * y + 0.9 * x * x - 0.5 * x * y + 0.6 * y * y
        };
        let tilted: Vec<Complex32> = (0..side * side)
            .map(|i| truth[i] * Complex32::from_polar(2.0, slow(i)))
            .collect();
        assert!(complex_nrmse(&tilted, &truth) > 0.5);
        assert!(complex_nrmse_low_order_free(&tilted, &truth, side) < 1e-4);
        // Detail changed is still counted.
        let blurred: Vec<Complex32> = (0..side * side)
            .map(|i| {
                if i % 7 == 0 {
                    tilted[i] * 0.5
                } else {
                    tilted[i]
                }
            })
            .collect();
        assert!(complex_nrmse_low_order_free(&blurred, &truth, side) > 0.05);
    }
}
