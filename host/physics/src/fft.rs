//! 2-D FFTs over row-major complex arrays, with plans and scratch reused across calls.

use std::sync::Arc;

use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};

/// A planned 2-D transform for one grid size.
pub struct Fft2 {
    width: usize,
    height: usize,
    row_fwd: Arc<dyn Fft<f32>>,
    row_inv: Arc<dyn Fft<f32>>,
    col_fwd: Arc<dyn Fft<f32>>,
    col_inv: Arc<dyn Fft<f32>>,
    scratch: Vec<Complex32>,
    transposed: Vec<Complex32>,
}

impl Fft2 {
    /// Plan transforms for `width × height` arrays.
    pub fn new(width: usize, height: usize) -> Self {
        let mut planner = FftPlanner::new();
        let row_fwd = planner.plan_fft_forward(width);
        let row_inv = planner.plan_fft_inverse(width);
        let col_fwd = planner.plan_fft_forward(height);
        let col_inv = planner.plan_fft_inverse(height);
        let scratch_len = [&row_fwd, &row_inv, &col_fwd, &col_inv]
            .iter()
            .map(|p| p.get_inplace_scratch_len())
            .max()
            .unwrap_or(0);
        Self {
            width,
            height,
            row_fwd,
            row_inv,
            col_fwd,
            col_inv,
            scratch: vec![Complex32::default(); scratch_len],
            transposed: vec![Complex32::default(); width * height],
        }
    }

    /// Grid width.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Grid height.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Forward transform in place (unnormalised).
    pub fn forward(&mut self, data: &mut [Complex32]) {
        let (r, c) = (self.row_fwd.clone(), self.col_fwd.clone());
        self.run(data, &*r, &*c);
    }

    /// Inverse transform in place, normalised by 1/(width·height).
    pub fn inverse(&mut self, data: &mut [Complex32]) {
        let (r, c) = (self.row_inv.clone(), self.col_inv.clone());
        self.run(data, &*r, &*c);
        let norm = 1.0 / (self.width * self.height) as f32;
        for v in data.iter_mut() {
            *v *= norm;
        }
    }

    /// Unnormalised inverse transform of an array that is zero outside `rows` (row
    /// indices): the other rows' 1-D transforms are skipped (zeros stay zeros). EPRY's
    /// ψ is non-zero only inside the pupil disc, a quarter of the rows at NA 0.1.
    pub fn inverse_unnormalised_sparse_rows(&mut self, data: &mut [Complex32], rows: &[usize]) {
        let (w, h) = (self.width, self.height);
        assert_eq!(data.len(), w * h, "array does not match the planned size");
        for &r in rows {
            self.row_inv
                .process_with_scratch(&mut data[r * w..(r + 1) * w], &mut self.scratch);
        }
        transpose(data, &mut self.transposed, w, h);
        self.col_inv
            .process_with_scratch(&mut self.transposed, &mut self.scratch);
        transpose(&self.transposed, data, h, w);
    }

    /// Forward transform where only the columns `cols` of the result are wanted: rows
    /// are transformed in full, then only those columns. The other columns hold
    /// row-transformed values, not the 2-D transform.
    pub fn forward_wanted_cols(&mut self, data: &mut [Complex32], cols: &[usize]) {
        let (w, h) = (self.width, self.height);
        assert_eq!(data.len(), w * h, "array does not match the planned size");
        self.row_fwd.process_with_scratch(data, &mut self.scratch);
        let column = &mut self.transposed[..h];
        for &c in cols {
            for (r, v) in column.iter_mut().enumerate() {
                *v = data[r * w + c];
            }
            self.col_fwd.process_with_scratch(column, &mut self.scratch);
            for (r, v) in column.iter().enumerate() {
                data[r * w + c] = *v;
            }
        }
    }

    fn run(&mut self, data: &mut [Complex32], rows: &dyn Fft<f32>, cols: &dyn Fft<f32>) {
        let (w, h) = (self.width, self.height);
        assert_eq!(data.len(), w * h, "array does not match the planned size");
        rows.process_with_scratch(data, &mut self.scratch);
        transpose(data, &mut self.transposed, w, h);
        cols.process_with_scratch(&mut self.transposed, &mut self.scratch);
        transpose(&self.transposed, data, h, w);
    }
}

/// `dst[c·h + r] = src[r·w + c]` in cache-friendly blocks.
fn transpose(src: &[Complex32], dst: &mut [Complex32], w: usize, h: usize) {
    const B: usize = 32;
    for r0 in (0..h).step_by(B) {
        for c0 in (0..w).step_by(B) {
            for r in r0..(r0 + B).min(h) {
                for c in c0..(c0 + B).min(w) {
                    dst[c * h + r] = src[r * w + c];
                }
            }
        }
    }
}

/// The frequency of FFT bin `k` on an `n`-point grid with sample spacing `dx`, in
/// cycles per unit of `dx`.
pub fn bin_frequency(k: usize, n: usize, dx: f64) -> f64 {
    let k = k as f64;
    let n_f = n as f64;
    if k < n_f / 2.0 {
        k / (n_f * dx)
    } else {
        (k - n_f) / (n_f * dx)
    }
}

#[cfg(test)]
mod pruned_tests {
    use super::*;

    fn pseudo_random(n: usize, seed: u32) -> Vec<Complex32> {
        let mut x = seed;
        (0..n)
            .map(|_| {
                x = x.wrapping_mul(1664525).wrapping_add(1013904223);
                let a = (x >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
                x = x.wrapping_mul(1664525).wrapping_add(1013904223);
                let b = (x >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
                Complex32::new(a, b)
            })
            .collect()
    }

    #[test]
    fn pruned_transforms_match_the_full_ones_where_it_matters() {
        let (w, h) = (48, 40);
        let mut fft = Fft2::new(w, h);
        // Sparse rows: zero everywhere but rows 3, 7 and 39.
        let rows = [3usize, 7, 39];
        let mut sparse = pseudo_random(w * h, 1);
        for (r, chunk) in sparse.chunks_mut(w).enumerate() {
            if !rows.contains(&r) {
                chunk.fill(Complex32::default());
            }
        }
        let mut full = sparse.clone();
        fft.inverse(&mut full);
        fft.inverse_unnormalised_sparse_rows(&mut sparse, &rows);
        let norm = 1.0 / (w * h) as f32;
        for (a, b) in sparse.iter().zip(&full) {
            assert!((a * norm - b).norm() < 1e-5);
        }
        // Wanted columns of a forward transform.
        let cols = [0usize, 5, 47];
        let mut some = pseudo_random(w * h, 2);
        let mut full = some.clone();
        fft.forward(&mut full);
        fft.forward_wanted_cols(&mut some, &cols);
        for r in 0..h {
            for &c in &cols {
                assert!((some[r * w + c] - full[r * w + c]).norm() < 1e-3);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_a_plane_wave_lands_in_its_bin() {
        let (w, h) = (48, 20);
        let mut fft = Fft2::new(w, h);
        let (kx, ky) = (5usize, 3usize);
        let mut data: Vec<Complex32> = (0..w * h)
            .map(|i| {
                let (r, c) = ((i / w) as f32, (i % w) as f32);
                let ph = 2.0
                    * std::f32::consts::PI
                    * (kx as f32 * c / w as f32 + ky as f32 * r / h as f32);
                Complex32::new(ph.cos(), ph.sin())
            })
            .collect();
        let orig = data.clone();
        fft.forward(&mut data);
        let peak = data
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.norm().total_cmp(&b.1.norm()))
            .unwrap()
            .0;
        assert_eq!((peak / w, peak % w), (ky, kx));
        assert!((data[peak].norm() - (w * h) as f32).abs() < 1e-2);
        fft.inverse(&mut data);
        let err: f32 = data
            .iter()
            .zip(&orig)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f32::max);
        assert!(err < 1e-4, "{err}");
    }

    #[test]
    fn bin_frequencies_wrap_at_nyquist() {
        assert_eq!(bin_frequency(0, 8, 0.5), 0.0);
        assert_eq!(bin_frequency(1, 8, 0.5), 0.25);
        assert_eq!(bin_frequency(4, 8, 0.5), -1.0);
        assert_eq!(bin_frequency(7, 8, 0.5), -0.25);
    }
}
