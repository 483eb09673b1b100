//! How many threads a rank gets by default when it is one of several: its fair share
//! of the cores it may run on, each core split among the ranks of its node that may run
//! on it. One rank per socket bound to that socket gets the socket's cores; ranks bound
//! one per core, or unbound ranks filling a node, get one each: the node's cores are
//! used, never oversubscribed.

use decomposition::{Communicator, MpiComm};

/// The CPUs of a Linux CPU list such as `0-3,8,10-11`; `None` if it is not one.
pub fn parse_cpu_list(s: &str) -> Option<Vec<usize>> {
    let mut cpus = Vec::new();
    for part in s.trim().split(',') {
        let (lo, hi): (usize, usize) = match part.split_once('-') {
            Some((a, b)) => (a.trim().parse().ok()?, b.trim().parse().ok()?),
            None => {
                let c = part.trim().parse().ok()?;
                (c, c)
            }
        };
        if lo > hi || hi >= 1 << 20 {
            return None;
        }
        cpus.extend(lo..=hi);
    }
    Some(cpus)
}

/// This process's CPUs (`Cpus_allowed_list` of `/proc/self/status`), `None` where
/// the system does not say.
fn my_cpus() -> Option<Vec<usize>> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status
        .lines()
        .find_map(|l| l.strip_prefix("Cpus_allowed_list:"))?;
    parse_cpu_list(line)
}

/// The cores `mine` are worth to a rank when `users(c)` ranks may run on CPU `c`: the
/// sum of `1 / users(c)`, whole cores, at least one.
pub fn fair_share(mine: &[usize], users: impl Fn(usize) -> u64) -> usize {
    let share: f64 = mine.iter().map(|&c| 1.0 / users(c).max(1) as f64).sum();
    // A share that is whole up to round-off counts as whole.
    ((share + 1e-9).floor() as usize).max(1)
}

/// Collective: the default thread count of this rank among the ranks of `comm`
/// ([`fair_share`] over the ranks of its node); 1 where the CPUs are not known.
pub fn node_share(comm: &MpiComm) -> usize {
    let node = comm.node();
    let mine = my_cpus();
    // Every rank takes part alike, whether it knows its CPUs or not.
    let mut top = [mine
        .as_ref()
        .and_then(|c| c.iter().max())
        .map_or(0.0, |&m| m as f64 + 1.0)];
    node.max_f64(&mut top);
    let mut users = vec![0u64; top[0] as usize];
    for &c in mine.iter().flatten() {
        users[c] += 1;
    }
    node.sum_u64(&mut users);
    mine.map_or(1, |c| fair_share(&c, |i| users[i]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_lists_parse_as_linux_writes_them() {
        assert_eq!(
            parse_cpu_list("0-3,8,10-11\n"),
            Some(vec![0, 1, 2, 3, 8, 10, 11])
        );
        assert_eq!(parse_cpu_list("5"), Some(vec![5]));
        assert_eq!(parse_cpu_list("3-1"), None);
        assert_eq!(parse_cpu_list("a-b"), None);
        assert_eq!(parse_cpu_list(""), None);
    }

    /// Two sockets of 16 cores: ranks bound one per socket get 16 threads; two per
    /// socket, each bound to the socket, 8; unbound ranks filling the node, one each;
    /// a rank bound to one core, one.
    #[test]
    fn each_core_is_shared_among_the_ranks_that_may_run_on_it() {
        let socket = |s: usize| (16 * s..16 * s + 16).collect::<Vec<_>>();
        assert_eq!(fair_share(&socket(1), |_| 1), 16);
        assert_eq!(fair_share(&socket(0), |_| 2), 8);
        let node: Vec<usize> = (0..32).collect();
        assert_eq!(fair_share(&node, |_| 32), 1);
        assert_eq!(fair_share(&node, |_| 3), 10);
        assert_eq!(fair_share(&[7], |_| 1), 1);
        // More ranks than cores still get a thread.
        assert_eq!(fair_share(&[0, 1], |_| 16), 1);
        // Thirds that add up to a whole core count as one.
        assert_eq!(fair_share(&[0, 1, 2], |_| 3), 1);
    }

    /// The threads of all ranks never exceed the cores when every rank takes its share.
    #[test]
    fn shares_never_oversubscribe_the_node() {
        // Ranks r = 0..6 on 8 CPUs, rank r may run on CPUs r..r+3 (mod 8).
        let masks: Vec<Vec<usize>> = (0..6)
            .map(|r| (r..r + 3).map(|c| c % 8).collect())
            .collect();
        let users = |c: usize| masks.iter().filter(|m| m.contains(&c)).count() as u64;
        let total: usize = masks.iter().map(|m| fair_share(m, users)).sum();
        let used = (0..8).filter(|&c| users(c) > 0).count();
        assert!(
            total <= used.max(masks.len()),
            "{total} threads on {used} CPUs"
        );
    }
}
