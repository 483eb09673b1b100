//! The element types of the particle arrays as values of the f64 migration and
//! checkpoint record.

/// An array element as a fixed number of `f64` values, for permutation and the
/// migration and checkpoint record. Integers round-trip exactly (material indices are
/// u16, ids < 2^53).
pub trait Record: Copy {
    const WIDTH: usize;
    fn put(&self, out: &mut Vec<f64>);
    fn get(s: &[f64]) -> Self;
}

impl Record for f64 {
    const WIDTH: usize = 1;
    fn put(&self, out: &mut Vec<f64>) {
        out.push(*self);
    }
    fn get(s: &[f64]) -> Self {
        s[0]
    }
}

impl Record for u16 {
    const WIDTH: usize = 1;
    fn put(&self, out: &mut Vec<f64>) {
        out.push(f64::from(*self));
    }
    fn get(s: &[f64]) -> Self {
        s[0] as u16
    }
}

impl Record for u64 {
    const WIDTH: usize = 1;
    fn put(&self, out: &mut Vec<f64>) {
        out.push(*self as f64);
    }
    fn get(s: &[f64]) -> Self {
        s[0] as u64
    }
}

impl<const D: usize> Record for [f64; D] {
    const WIDTH: usize = D;
    fn put(&self, out: &mut Vec<f64>) {
        out.extend_from_slice(self);
    }
    fn get(s: &[f64]) -> Self {
        std::array::from_fn(|a| s[a])
    }
}

impl<const R: usize, const C: usize> Record for nalgebra::SMatrix<f64, R, C> {
    const WIDTH: usize = R * C;
    fn put(&self, out: &mut Vec<f64>) {
        out.extend_from_slice(self.as_slice());
    }
    fn get(s: &[f64]) -> Self {
        Self::from_column_slice(&s[..R * C])
    }
}
