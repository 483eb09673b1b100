//! Walks over index boxes in the order of a local node numbering (axis 0 fastest).

/// Call `f` for every index tuple `i` with `i[a] < lens[a]`, axis 0 fastest (so local
/// node boxes are walked in increasing linear index).
pub(crate) fn odometer<const D: usize>(lens: [usize; D], mut f: impl FnMut([usize; D])) {
    if lens.contains(&0) {
        return;
    }
    let mut i = [0usize; D];
    loop {
        f(i);
        let mut a = 0;
        loop {
            if a == D {
                return;
            }
            i[a] += 1;
            if i[a] < lens[a] {
                break;
            }
            i[a] = 0;
            a += 1;
        }
    }
}

/// Call `f` for every index tuple `i` with `i[a] < lens[a]` for which `inner(a, i[a])`
/// is false on at least one axis, in the order of [`odometer`]. The work is
/// proportional to the tuples visited plus the inner tuples' projections, not to the
/// product of the lengths: a node box's ghost layer is walked without its interior, so
/// a huge box with a small body costs its surface, not its volume.
pub(crate) fn odometer_outside<const D: usize>(
    lens: [usize; D],
    inner: impl Fn(usize, usize) -> bool,
    mut f: impl FnMut([usize; D]),
) {
    if lens.contains(&0) {
        return;
    }
    // Per axis, the positions that are not inner.
    let outer: [Vec<usize>; D] =
        std::array::from_fn(|a| (0..lens[a]).filter(|&v| !inner(a, v)).collect());
    fn rec<const D: usize>(
        a: usize,
        i: &mut [usize; D],
        lens: &[usize; D],
        outer: &[Vec<usize>; D],
        inner: &impl Fn(usize, usize) -> bool,
        outside: bool,
        f: &mut impl FnMut([usize; D]),
    ) {
        if outside {
            // Everything below axis `a` (inclusive), in odometer order.
            let mut sub = [1usize; D];
            sub[..=a].copy_from_slice(&lens[..=a]);
            let hi = *i;
            odometer::<D>(sub, |j| {
                let mut t = hi;
                t[..=a].copy_from_slice(&j[..=a]);
                f(t);
            });
            return;
        }
        if a == 0 {
            for &v in &outer[0] {
                i[0] = v;
                f(*i);
            }
            return;
        }
        for v in 0..lens[a] {
            i[a] = v;
            rec(a - 1, i, lens, outer, inner, !inner(a, v), f);
        }
    }
    let mut i = [0usize; D];
    rec(D - 1, &mut i, &lens, &outer, &inner, false, &mut f);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The walk without the interior visits exactly the tuples of the full walk that
    /// have an outer position, in the same order.
    #[test]
    fn odometer_outside_skips_only_the_interior() {
        let lens = [5usize, 4, 3];
        let inner = |a: usize, v: usize| [(1..4), (1..3), (0..2)][a].contains(&v);
        let mut want = Vec::new();
        odometer(lens, |i| {
            if !(0..3).all(|a| inner(a, i[a])) {
                want.push(i);
            }
        });
        let mut got = Vec::new();
        odometer_outside(lens, inner, |i| got.push(i));
        assert_eq!(got, want);
        let mut none = 0;
        odometer_outside([4, 4], |_, _| true, |_| none += 1);
        assert_eq!(none, 0);
    }

    #[test]
    fn odometer_walks_in_linear_order() {
        let mut seen = Vec::new();
        odometer([3, 2, 2], |c| seen.push(c[0] + 3 * (c[1] + 2 * c[2])));
        assert_eq!(seen, (0..12).collect::<Vec<_>>());
        let mut n = 0;
        odometer([3, 0], |_| n += 1);
        assert_eq!(n, 0);
    }
}
