//! Operations on the particle arrays: growth, splitting, the order by cell and id, and
//! removal of marked entries.

/// Room for `n` elements in `v`: where it must grow, to `n` and a sixteenth, not to
/// twice its capacity as pushes would (particle state is most of a run's memory), so
/// arrivals rarely reallocate and never double the arrays.
pub fn reserve<T>(v: &mut Vec<T>, n: usize) {
    if v.capacity() < n {
        v.reserve_exact(n + n / 16 - v.len());
    }
}

/// Room for exactly `n` elements in `v` where it has less.
pub fn reserve_exact<T>(v: &mut Vec<T>, n: usize) {
    if v.capacity() < n {
        v.reserve_exact(n - v.len());
    }
}

/// Split a (possibly absent, i.e. empty) array at `mid`.
pub fn split_mut<T>(s: &mut [T], mid: usize) -> (&mut [T], &mut [T]) {
    if s.is_empty() {
        (&mut [], &mut [])
    } else {
        s.split_at_mut(mid)
    }
}

/// The indices `0 .. ids.len()` ordered by `(key(i), ids[i])` into `order`, with
/// `spare` as room (both a u32 per particle). The ids are distinct, so this is the
/// one order any sort by that pair gives; here it takes linear time: a stable radix
/// sort of the keys' span (a cell number: 15 bits for a 128² grid), 11 bits a pass,
/// then each run of equal keys (one cell's particles, mostly in id order already)
/// sorted by id. The comparison sort it replaced took `n log n` comparisons of
/// scattered keys, a quarter of a step's time on the vortex (0.85 ms; this 0.29).
pub fn order_by_key_then_id(
    key: impl Fn(u32) -> u64,
    ids: &[u64],
    order: &mut Vec<u32>,
    spare: &mut Vec<u32>,
) {
    const BITS: u32 = 11;
    // A rank's particles fit in u32 indices, as the node indices do (`ptile`): 4e9
    // particles would take over a terabyte.
    let n = u32::try_from(ids.len()).expect("fewer than 2^32 particles per rank");
    order.clear();
    order.extend(0..n);
    let (lo, hi) = (0..n).fold((u64::MAX, 0), |(lo, hi), p| {
        let k = key(p);
        (lo.min(k), hi.max(k))
    });
    let span_bits = if n == 0 {
        0
    } else {
        u64::BITS - (hi - lo).leading_zeros()
    };
    spare.clear();
    spare.resize(n as usize, 0);
    let mut shift = 0;
    while shift < span_bits {
        let digit = |p: u32| ((key(p) - lo) >> shift) as usize & ((1 << BITS) - 1);
        let mut at = [0u32; 1 << BITS];
        for &p in order.iter() {
            at[digit(p)] += 1;
        }
        let mut sum = 0;
        for a in at.iter_mut() {
            (*a, sum) = (sum, sum + *a);
        }
        for &p in order.iter() {
            let d = digit(p);
            spare[at[d] as usize] = p;
            at[d] += 1;
        }
        std::mem::swap(order, spare);
        shift += BITS;
    }
    // Each cell's run by id: one scan, a run sorted only where it is out of order.
    let (mut start, mut run_key, mut in_order) = (0, None, true);
    for i in 0..=order.len() {
        let k = order.get(i).map(|&p| key(p));
        if i > 0 && k.is_some() && k == run_key {
            in_order &= ids[order[i - 1] as usize] < ids[order[i] as usize];
            continue;
        }
        if !in_order {
            order[start..i].sort_unstable_by_key(|&p| ids[p as usize]);
        }
        (start, run_key, in_order) = (i, k, true);
    }
}

pub(super) fn retain<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
    if v.is_empty() {
        return;
    }
    let mut w = 0;
    for r in 0..v.len() {
        if keep[r] {
            v[w] = v[r];
            w += 1;
        }
    }
    v.truncate(w);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The radix order is the comparison sort's by (key, id), ids breaking ties: keys
    /// with many ties (few cells), keys spanning 41 bits (four passes), input sorted
    /// but for a few moved entries (the particles between two sorts), and 0 or 1 entry.
    #[test]
    fn order_by_key_then_id_is_the_sort_by_key_and_id() {
        let mut rng = decomposition::splitmix::Rng::new(7);
        let mut cases: Vec<(Vec<u64>, Vec<u64>)> = Vec::new();
        for (n, span) in [(5000, 40), (3000, 1u64 << 41), (0, 1), (1, 1)] {
            let keys = (0..n)
                .map(|_| 1000 + rng.below(span as usize) as u64)
                .collect();
            let mut ids: Vec<u64> = (0..n as u64).map(|k| 3 * k + 1).collect();
            for k in (1..ids.len()).rev() {
                ids.swap(k, rng.below(k + 1));
            }
            cases.push((keys, ids));
        }
        // Sorted by (key, id), then 50 entries given other keys.
        let (mut keys, mut ids): (Vec<u64>, Vec<u64>) = (0..4000u64).map(|k| (k / 9, k)).unzip();
        for _ in 0..50 {
            let k = rng.below(keys.len());
            keys[k] = rng.below(450) as u64;
            let j = rng.below(ids.len());
            ids.swap(k, j);
        }
        cases.push((keys, ids));
        let (mut order, mut spare) = (Vec::new(), Vec::new());
        for (keys, ids) in &cases {
            order_by_key_then_id(|p| keys[p as usize], ids, &mut order, &mut spare);
            let mut want: Vec<u32> = (0..keys.len() as u32).collect();
            want.sort_by_key(|&p| (keys[p as usize], ids[p as usize]));
            assert_eq!(order, want, "{} keys", keys.len());
        }
    }
}
