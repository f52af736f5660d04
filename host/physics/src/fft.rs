//! 2-D FFTs over row-major complex arrays, with plans and scratch reused across calls.

use std::sync::Arc;

use rayon::prelude::*;
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
    /// Spread the pruned transforms over rayon's pool (see [`Self::set_parallel`]).
    parallel: bool,
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
            parallel: false,
        }
    }

    /// Run the pruned transforms' row batches and column blocks on rayon's pool
    /// (`Epry` decides when; `fpm bench epry` prints passes on 1 and 2 threads).
    pub fn set_parallel(&mut self, parallel: bool) {
        self.parallel = parallel;
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

    /// Unnormalised inverse transform of an array that is zero outside the columns
    /// `cols`: only those columns are transformed (zeros stay zeros), then every row in
    /// one batch, with no full transpose. EPRY's ψ is non-zero only on the pupil disc,
    /// a quarter of the columns at NA 0.1.
    pub fn inverse_unnormalised_sparse_cols(&mut self, data: &mut [Complex32], cols: &[usize]) {
        let (w, h) = (self.width, self.height);
        assert_eq!(data.len(), w * h, "array does not match the planned size");
        self.inverse_unnormalised_sparse_rows(data, cols, 0..h);
    }

    /// [`Self::inverse_unnormalised_sparse_cols`] where only the rows `rows` of the
    /// result are wanted: the last pass transforms just those. The other rows hold
    /// column-transformed values, not the 2-D transform.
    pub fn inverse_unnormalised_sparse_rows(
        &mut self,
        data: &mut [Complex32],
        cols: &[usize],
        rows: std::ops::Range<usize>,
    ) {
        let (w, h) = (self.width, self.height);
        assert_eq!(data.len(), w * h, "array does not match the planned size");
        assert!(rows.end <= h, "rows {rows:?} beyond the grid's {h}");
        let plan = self.col_inv.clone();
        self.columns(data, cols, &*plan);
        let plan = self.row_inv.clone();
        self.rows(&mut data[rows.start * w..rows.end * w], &*plan);
    }

    /// Forward transform where only the columns `cols` of the result are wanted: rows
    /// are transformed in full, then only those columns. The other columns hold
    /// row-transformed values, not the 2-D transform.
    pub fn forward_wanted_cols(&mut self, data: &mut [Complex32], cols: &[usize]) {
        let (w, h) = (self.width, self.height);
        assert_eq!(data.len(), w * h, "array does not match the planned size");
        let plan = self.row_fwd.clone();
        self.rows(data, &*plan);
        let plan = self.col_fwd.clone();
        self.columns(data, cols, &*plan);
    }

    /// Every row of `data` transformed with `plan`: one batch, or a few per thread.
    fn rows(&mut self, data: &mut [Complex32], plan: &dyn Fft<f32>) {
        if !self.parallel {
            plan.process_with_scratch(data, &mut self.scratch);
            return;
        }
        let w = self.width;
        let chunk_rows = self
            .height
            .div_ceil(2 * rayon::current_num_threads().max(1))
            .max(1);
        let scratch_len = self.scratch.len();
        data.par_chunks_mut(chunk_rows * w).for_each_init(
            || vec![Complex32::default(); scratch_len],
            |scratch, rows| plan.process_with_scratch(rows, scratch),
        );
    }

    /// Transform the columns `cols` (ascending) of `data` with `plan`: runs of adjacent
    /// columns are copied out a block at a time (each row contributes one cache line),
    /// transformed in one batch, and copied back.
    fn columns(&mut self, data: &mut [Complex32], cols: &[usize], plan: &dyn Fft<f32>) {
        let (w, h) = (self.width, self.height);
        let runs = column_runs(cols);
        if self.parallel {
            // Blocks are copied out and transformed in parallel (reading `data`
            // shared), then written back by rows in parallel.
            let scratch_len = self.scratch.len();
            let mut jobs: Vec<(usize, &mut [Complex32])> = Vec::with_capacity(runs.len());
            let mut rest = &mut self.transposed[..cols.len() * h];
            for &(first, len) in &runs {
                let (block, tail) = rest.split_at_mut(len * h);
                jobs.push((first, block));
                rest = tail;
            }
            let source: &[Complex32] = data;
            jobs.par_iter_mut().for_each_init(
                || vec![Complex32::default(); scratch_len],
                |scratch, (first, block)| {
                    gather_columns(source, w, *first, block, h);
                    plan.process_with_scratch(block, scratch);
                },
            );
            drop(jobs);
            let blocks = &self.transposed[..cols.len() * h];
            data.par_chunks_mut(w)
                .enumerate()
                .with_min_len(16)
                .for_each(|(r, row)| {
                    let mut offset = 0;
                    for &(first, len) in &runs {
                        for j in 0..len {
                            row[first + j] = blocks[offset + j * h + r];
                        }
                        offset += len * h;
                    }
                });
            return;
        }
        for (first, len) in runs {
            let block = &mut self.transposed[..len * h];
            gather_columns(data, w, first, block, h);
            plan.process_with_scratch(block, &mut self.scratch);
            for r in 0..h {
                let row = &mut data[r * w + first..r * w + first + len];
                for (j, v) in row.iter_mut().enumerate() {
                    *v = block[j * h + r];
                }
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

/// Runs of adjacent indices in ascending `cols`, at most eight long: (first, length).
/// Eight complex f32 are one 64-byte cache line of a row.
fn column_runs(cols: &[usize]) -> Vec<(usize, usize)> {
    const BLOCK: usize = 8;
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for &c in cols {
        match runs.last_mut() {
            Some((first, len)) if *len < BLOCK && *first + *len == c => *len += 1,
            _ => runs.push((c, 1)),
        }
    }
    runs
}

/// Columns `first..first + len` of the row-major `w`-wide `data` into `block`, one
/// column after another (`block[j·h + r] = data[r·w + first + j]`).
fn gather_columns(data: &[Complex32], w: usize, first: usize, block: &mut [Complex32], h: usize) {
    let len = block.len() / h;
    for r in 0..h {
        let row = &data[r * w + first..r * w + first + len];
        for (j, &v) in row.iter().enumerate() {
            block[j * h + r] = v;
        }
    }
}

/// `dst[c·h + r] = src[r·w + c]`: the `transpose` crate's tiled, recursive kernel
/// (rustfft's own), twice as fast at 256² as plain 32 × 32 blocks (`fpm bench epry`
/// measures the pair against the floor).
fn transpose(src: &[Complex32], dst: &mut [Complex32], w: usize, h: usize) {
    transpose::transpose(src, dst, w, h);
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
        for parallel in [false, true] {
            pruned_transforms_match(parallel);
        }
    }

    fn pruned_transforms_match(parallel: bool) {
        let (w, h) = (48, 40);
        let mut fft = Fft2::new(w, h);
        fft.set_parallel(parallel);
        // Sparse columns: zero everywhere but columns 0–9 (a run longer than one
        // block), 30 and 47.
        let cols: Vec<usize> = (0..10).chain([30, 47]).collect();
        let mut sparse = pseudo_random(w * h, 1);
        for (i, v) in sparse.iter_mut().enumerate() {
            if !cols.contains(&(i % w)) {
                *v = Complex32::default();
            }
        }
        let mut full = sparse.clone();
        let mut some_rows = sparse.clone();
        fft.inverse(&mut full);
        fft.inverse_unnormalised_sparse_cols(&mut sparse, &cols);
        let norm = 1.0 / (w * h) as f32;
        for (a, b) in sparse.iter().zip(&full) {
            assert!((a * norm - b).norm() < 1e-5);
        }
        // Wanted rows of that inverse: the same values there.
        let rows = 7..19;
        fft.inverse_unnormalised_sparse_rows(&mut some_rows, &cols, rows.clone());
        for (a, b) in some_rows[rows.start * w..rows.end * w]
            .iter()
            .zip(&full[rows.start * w..rows.end * w])
        {
            assert!((a * norm - b).norm() < 1e-5);
        }
        // Wanted columns of a forward transform.
        let cols = [0usize, 5, 6, 7, 47];
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
