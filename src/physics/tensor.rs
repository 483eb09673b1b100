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
