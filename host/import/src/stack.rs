//! Image stacks as sources store them, cut into frames in sample-plane orientation.

use fpm_host::dataset::Pixels;
use ndarray::{Array2, ShapeBuilder};

use crate::mat::Values;

/// How a stack's values are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Layout {
    /// MATLAB's H × W × N, column-major: value (r, c, k) at r + H·(c + W·k).
    MatlabHwn,
    /// NumPy's N × H × W, row-major: value (k, r, c) at c + W·(r + H·k).
    NumpyNhw,
}

/// Frame `k` of the stack (`h` rows, `w` columns): row r, column c as stored.
pub(crate) fn frame(values: &Values, layout: Layout, (h, w): (usize, usize), k: usize) -> Pixels {
    let range = k * h * w..(k + 1) * h * w;
    fn cut<T: Clone>(v: &[T], layout: Layout, (h, w): (usize, usize)) -> Array2<T> {
        let shape = match layout {
            Layout::MatlabHwn => (h, w).f(),
            Layout::NumpyNhw => (h, w).into_shape_with_order(),
        };
        Array2::from_shape_vec(shape, v.to_vec())
            .expect("a slice of h·w values")
            .as_standard_layout()
            .to_owned()
    }
    match values {
        Values::U8(v) => Pixels::U8(cut(&v[range], layout, (h, w))),
        Values::U16(v) => Pixels::U16(cut(&v[range], layout, (h, w))),
        Values::F32(v) => Pixels::F32(cut(&v[range], layout, (h, w))),
        Values::F64(v) => Pixels::F32(cut(&v[range], layout, (h, w)).mapv(|x| x as f32)),
    }
}
