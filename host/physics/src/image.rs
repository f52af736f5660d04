//! A grey-scale image: row-major `f32` samples, row = y, column = x.

use ndarray::Array2;

/// Intensities on the camera grid, `[row, col]`.
pub type Image = Array2<f32>;

/// Row `r` of `img` as a slice: borrowed (an image in standard layout, as every image
/// built here is), or copied.
pub fn row_slice(img: &Image, r: usize) -> std::borrow::Cow<'_, [f32]> {
    let row = img.row(r);
    match row.to_slice() {
        Some(values) => std::borrow::Cow::Borrowed(values),
        None => std::borrow::Cow::Owned(row.to_vec()),
    }
}

/// The sum of one row of samples, in f32: eight running sums, so the compiler may keep
/// them in one vector register (it must not reorder a single float sum).
pub fn row_sum(row: ndarray::ArrayView1<'_, f32>) -> f32 {
    const LANES: usize = 8;
    let Some(values) = row.as_slice() else {
        return row.iter().sum();
    };
    let mut lanes = [0.0f32; LANES];
    let chunks = values.chunks_exact(LANES);
    let tail: f32 = chunks.remainder().iter().sum();
    for chunk in chunks {
        for (lane, &v) in lanes.iter_mut().zip(chunk) {
            *lane += v;
        }
    }
    lanes.iter().sum::<f32>() + tail
}

/// The median of a set of samples (a robust background level); non-finite samples
/// are left out, and an empty set gives 0.
pub fn median(values: impl IntoIterator<Item = f32>) -> f32 {
    let mut keys: Vec<u32> = values
        .into_iter()
        .filter(|x| x.is_finite())
        .map(order_key)
        .collect();
    if keys.is_empty() {
        return 0.0;
    }
    // crate::stats' rank rule, on integer keys (twice as fast as comparing floats).
    let mid = crate::stats::rank(keys.len(), 0.5);
    let (_, m, _) = keys.select_nth_unstable(mid);
    from_order_key(*m)
}

/// `x`'s bits rearranged so that unsigned order is numeric order (for finite `x`):
/// selections then compare integers, about twice as fast as `f32::total_cmp`.
pub fn order_key(x: f32) -> u32 {
    let bits = x.to_bits();
    if bits >> 31 == 1 {
        !bits
    } else {
        bits | 0x8000_0000
    }
}

/// The inverse of [`order_key`].
pub fn from_order_key(key: u32) -> f32 {
    f32::from_bits(if key >> 31 == 1 {
        key & 0x7FFF_FFFF
    } else {
        !key
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_keys_sort_like_the_numbers_and_come_back() {
        let values = [
            f32::MIN,
            -3.5e7,
            -1.0,
            -1e-40,
            -0.0,
            0.0,
            1e-40,
            0.25,
            1.0,
            4095.0,
            f32::MAX,
        ];
        for pair in values.windows(2) {
            assert!(order_key(pair[0]) <= order_key(pair[1]), "{pair:?}");
        }
        for v in values {
            assert_eq!(from_order_key(order_key(v)).to_bits(), v.to_bits());
        }
    }

    #[test]
    fn the_median_is_the_middle_of_the_sorted_finite_samples() {
        let samples: Vec<f32> = (0..101).map(|i| ((i * 37) % 101) as f32 - 50.5).collect();
        let mut sorted = samples.clone();
        sorted.sort_by(f32::total_cmp);
        let with_junk = samples.iter().copied().chain([f32::NAN, f32::INFINITY]);
        assert_eq!(median(with_junk), sorted[50]);
        assert_eq!(median(std::iter::empty()), 0.0);
    }
}
