//! Quality metrics of PHYSICS.md §6 and the resampling they need.

use ndarray::Array2;
use rustfft::num_complex::Complex32;

use crate::fft::{bin_frequency, Fft2};

/// Resample a complex field over the same field of view onto an `m × m` grid by
/// cropping or zero-padding its spectrum, keeping only frequencies where `keep(fx, fy)`
/// (cycles per unit of `pitch`) holds. Amplitudes are preserved.
pub fn resample(
    field: &Array2<Complex32>,
    pitch: f64,
    m: usize,
    keep: impl Fn(f64, f64) -> bool,
) -> Array2<Complex32> {
    let (n, n2) = field.dim();
    assert_eq!(n, n2, "square fields only");
    let mut spec: Vec<Complex32> = field.iter().copied().collect();
    Fft2::new(n, n).forward(&mut spec);
    let mut out = vec![Complex32::default(); m * m];
    let half = n.min(m) / 2;
    let signed = |k: usize, len: usize| {
        if k < len / 2 {
            k as i64
        } else {
            k as i64 - len as i64
        }
    };
    for ky in 0..n {
        let sy = signed(ky, n);
        if sy.unsigned_abs() as usize >= half {
            continue;
        }
        for kx in 0..n {
            let sx = signed(kx, n);
            if sx.unsigned_abs() as usize >= half {
                continue;
            }
            if !keep(bin_frequency(kx, n, pitch), bin_frequency(ky, n, pitch)) {
                continue;
            }
            let (oy, ox) = (
                sy.rem_euclid(m as i64) as usize,
                sx.rem_euclid(m as i64) as usize,
            );
            out[oy * m + ox] = spec[ky * n + kx];
        }
    }
    Fft2::new(m, m).inverse(&mut out);
    let scale = (m * m) as f32 / (n * n) as f32;
    Array2::from_shape_fn((m, m), |(r, c)| out[r * m + c] * scale)
}

/// The central `fraction` of a square array (PHYSICS.md compares on the central 75 %).
pub fn central(a: &Array2<Complex32>, fraction: f64) -> Vec<Complex32> {
    let n = a.dim().0;
    let k = ((n as f64) * fraction).round() as usize;
    let o = (n - k) / 2;
    a.slice(ndarray::s![o..o + k, o..o + k])
        .iter()
        .copied()
        .collect()
}

pub use crate::reconstruct::complex_nrmse;
