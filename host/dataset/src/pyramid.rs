//! Smaller copies of a complex object, for pyramids and previews: 2×2 blocks averaged
//! with the amplitude as the mean of |z| and the phase as the argument of the mean z,
//! so that wrapped phase is not averaged across ±π.

use ndarray::{Array2, ArrayView2};
use rustfft::num_complex::Complex32;

/// The mean of each 2×2 block of the `(2h, 2w)` image `at` reads: an `(h, w)` image.
fn block_means<T>(h: usize, w: usize, at: impl Fn(usize, usize) -> T) -> Array2<T>
where
    T: std::ops::Add<Output = T> + std::ops::Div<f32, Output = T>,
{
    Array2::from_shape_fn((h, w), |(r, c)| {
        (at(2 * r, 2 * c) + at(2 * r + 1, 2 * c) + at(2 * r, 2 * c + 1) + at(2 * r + 1, 2 * c + 1))
            / 4.0
    })
}

/// The next level: `amplitude` and `object` at half size. Odd last rows and columns
/// are dropped.
pub fn halve(
    amplitude: ArrayView2<'_, f32>,
    object: ArrayView2<'_, Complex32>,
) -> (Array2<f32>, Array2<Complex32>) {
    let (h, w) = (object.nrows() / 2, object.ncols() / 2);
    (
        block_means(h, w, |r, c| amplitude[[r, c]]),
        block_means(h, w, |r, c| object[[r, c]]),
    )
}

/// A copy of `object` halved until its longer side is at most `max_side`: its
/// amplitude, its complex values (for the phase) and how many times smaller it is.
/// `None` when it is that small already. No full-size copy is made: the first level's
/// amplitude is read from the object itself.
pub fn shrunk(
    object: &Array2<Complex32>,
    max_side: usize,
) -> Option<(Array2<f32>, Array2<Complex32>, usize)> {
    let side = |o: &Array2<Complex32>| o.nrows().max(o.ncols());
    if side(object) <= max_side.max(1) {
        return None;
    }
    let (h, w) = (object.nrows() / 2, object.ncols() / 2);
    let mut amplitude = block_means(h, w, |r, c| object[[r, c]].norm());
    let mut complex = block_means(h, w, |r, c| object[[r, c]]);
    let mut factor = 2;
    while side(&complex) > max_side.max(1) && complex.nrows() >= 2 && complex.ncols() >= 2 {
        (amplitude, complex) = halve(amplitude.view(), complex.view());
        factor *= 2;
    }
    Some((amplitude, complex, factor))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_large_object_shrinks_to_the_side_asked_keeping_its_mean() {
        let object = Array2::from_shape_fn((1000, 600), |(r, c)| {
            Complex32::from_polar(1.0 + (r % 7) as f32 * 0.1, 0.3 + (c % 5) as f32 * 0.01)
        });
        let (amp, complex, factor) = shrunk(&object, 256).expect("shrunk");
        assert_eq!(factor, 4);
        assert_eq!(amp.dim(), (250, 150));
        assert_eq!(complex.dim(), (250, 150));
        let mean = |a: &Array2<f32>| a.sum() / a.len() as f32;
        let full = object.mapv(|z| z.norm());
        assert!((mean(&amp) - mean(&full)).abs() < 0.01);
        assert!(complex.iter().all(|z| (z.arg() - 0.32).abs() < 0.03));
        assert!(shrunk(&object, 1000).is_none());
    }
}
