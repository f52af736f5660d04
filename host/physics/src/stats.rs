//! Order statistics with one rank rule, for every median, percentile and display
//! window in fpm: the q-quantile of n samples is the sample at sorted index
//! ⌊q·n⌋ (the last for q = 1), so the median of an even count is the upper middle.
//! Selections are O(n) (`select_nth_unstable`) and reorder the slice they are given.

use std::cmp::Ordering;

/// A sample that can be ordered totally (NaN after every number).
pub trait Sample: Copy {
    /// Total order.
    fn order(&self, other: &Self) -> Ordering;
}

impl Sample for f32 {
    fn order(&self, other: &Self) -> Ordering {
        self.total_cmp(other)
    }
}

impl Sample for f64 {
    fn order(&self, other: &Self) -> Ordering {
        self.total_cmp(other)
    }
}

impl Sample for u64 {
    fn order(&self, other: &Self) -> Ordering {
        self.cmp(other)
    }
}

impl Sample for i64 {
    fn order(&self, other: &Self) -> Ordering {
        self.cmp(other)
    }
}

/// The sorted index of the q-quantile of `n` samples (n ≥ 1): ⌊q·n⌋, at most n − 1.
pub fn rank(n: usize, q: f64) -> usize {
    ((q.clamp(0.0, 1.0) * n as f64) as usize).min(n.saturating_sub(1))
}

/// The q-quantile of `v` (reordered); None when `v` is empty.
pub fn quantile<T: Sample>(v: &mut [T], q: f64) -> Option<T> {
    if v.is_empty() {
        return None;
    }
    let k = rank(v.len(), q);
    Some(*v.select_nth_unstable_by(k, T::order).1)
}

/// The median of `v` (reordered); None when `v` is empty.
pub fn median<T: Sample>(v: &mut [T]) -> Option<T> {
    quantile(v, 0.5)
}

/// Several quantiles of `v` (reordered), each by the one rule; None when `v` is empty.
pub fn quantiles<T: Sample, const N: usize>(v: &mut [T], qs: [f64; N]) -> Option<[T; N]> {
    if v.is_empty() {
        return None;
    }
    Some(qs.map(|q| quantile(v, q).unwrap_or(v[0])))
}

/// The median absolute deviation about the median, scaled to a normal σ (× 1.4826);
/// with the median. None when `v` is empty.
pub fn median_and_sigma(v: &[f64]) -> Option<(f64, f64)> {
    let m = median(&mut v.to_vec())?;
    let mut deviations: Vec<f64> = v.iter().map(|x| (x - m).abs()).collect();
    Some((m, median(&mut deviations)? * 1.4826))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_rank_rule_for_medians_and_percentiles() {
        let mut odd = vec![5.0, 1.0, 3.0];
        assert_eq!(median(&mut odd), Some(3.0));
        // An even count: the upper middle.
        let mut even = vec![4.0, 1.0, 3.0, 2.0];
        assert_eq!(median(&mut even), Some(3.0));
        let mut hundred: Vec<f64> = (0..100).rev().map(f64::from).collect();
        assert_eq!(
            quantiles(&mut hundred, [0.0, 0.005, 0.5, 0.99, 1.0]),
            Some([0.0, 0.0, 50.0, 99.0, 99.0])
        );
        assert_eq!(median::<f64>(&mut []), None);
        // NaN sorts last, so it never becomes a median of numbers.
        let mut with_nan = vec![f32::NAN, 1.0, 2.0, 3.0, f32::NAN];
        assert_eq!(quantile(&mut with_nan, 0.2), Some(2.0));
        let (m, s) = median_and_sigma(&[1.0, 2.0, 3.0, 4.0, 100.0]).unwrap();
        assert_eq!(m, 3.0);
        assert!((s - 1.4826).abs() < 1e-12);
    }
}
