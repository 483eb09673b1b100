//! Small fixed-size vectors and matrices (nalgebra), generic over the dimension.

use nalgebra::{SMatrix, SVector};

pub type Vector<const D: usize> = SVector<f64, D>;
pub type Mat<const D: usize> = SMatrix<f64, D, D>;

/// Determinant for D <= 3, written out so generic code needs no extra trait bounds.
#[inline]
pub fn det<const D: usize>(m: &Mat<D>) -> f64 {
    match D {
        1 => m[(0, 0)],
        2 => m[(0, 0)] * m[(1, 1)] - m[(0, 1)] * m[(1, 0)],
        3 => {
            m[(0, 0)] * (m[(1, 1)] * m[(2, 2)] - m[(1, 2)] * m[(2, 1)])
                - m[(0, 1)] * (m[(1, 0)] * m[(2, 2)] - m[(1, 2)] * m[(2, 0)])
                + m[(0, 2)] * (m[(1, 0)] * m[(2, 1)] - m[(1, 1)] * m[(2, 0)])
        }
        _ => unreachable!("dimension is 1, 2 or 3"),
    }
}

/// A vector from a slice of length D.
pub fn vector<const D: usize>(v: &[f64]) -> Vector<D> {
    Vector::<D>::from_column_slice(v)
}

/// The adjugate (transposed cofactors) for D <= 3, written out as [`det`] is:
/// `m · adj m = det m · I`, so `adj m / det m` is the inverse.
#[inline]
pub fn adjugate<const D: usize>(m: &Mat<D>) -> Mat<D> {
    match D {
        1 => Mat::<D>::identity(),
        2 => Mat::<D>::from_fn(|i, k| {
            let s = if i == k { 1.0 } else { -1.0 };
            s * m[(1 - k, 1 - i)]
        }),
        3 => Mat::<D>::from_fn(|i, k| {
            // The cofactor of (k, i): rows and columns taken cyclically carry the sign.
            let (r1, r2) = ((k + 1) % 3, (k + 2) % 3);
            let (c1, c2) = ((i + 1) % 3, (i + 2) % 3);
            m[(r1, c1)] * m[(r2, c2)] - m[(r1, c2)] * m[(r2, c1)]
        }),
        _ => unreachable!("dimension is 1, 2 or 3"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `m · adj m = det m · I` for a few matrices in 1, 2 and 3 dimensions.
    #[test]
    fn matrix_times_adjugate_is_determinant() {
        let a3 = Mat::<3>::new(2.0, -1.0, 0.5, 0.3, 1.7, -0.2, -0.4, 0.6, 1.1);
        assert!((a3 * adjugate(&a3) - Mat::<3>::identity() * det(&a3)).norm() < 1e-14);
        let a2 = Mat::<2>::new(2.0, -1.0, 0.3, 1.7);
        assert!((a2 * adjugate(&a2) - Mat::<2>::identity() * det(&a2)).norm() < 1e-15);
        let a1 = Mat::<1>::new(4.0);
        assert_eq!(a1 * adjugate(&a1), Mat::<1>::new(4.0));
    }
}
