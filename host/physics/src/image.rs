//! A grey-scale image: row-major `f32` samples, row = y, column = x.

use ndarray::Array2;

/// Intensities on the camera grid, `[row, col]`.
pub type Image = Array2<f32>;

/// The median of a set of samples (a robust background level).
pub fn median(values: impl IntoIterator<Item = f32>) -> f32 {
    let mut v: Vec<f32> = values.into_iter().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    *m
}
