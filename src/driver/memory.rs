//! The memory a run may take: what its node has available and what the process may
//! still map, so that a scene too large for the machine is refused before it is seeded
//! rather than ended by an allocation failure or the kernel's OOM killer.

use std::path::Path;

/// Bytes the node can still give this job: `MemAvailable` (/proc/meminfo), or less
/// where the process's cgroup (a batch job's allocation) has less left below its
/// limit. `None` where neither is known.
pub fn node_available() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    let cgroup = std::fs::read_to_string("/proc/self/cgroup")
        .ok()
        .and_then(|c| cgroup_left(&c, Path::new("/sys/fs/cgroup")));
    [meminfo.as_deref().and_then(mem_available), cgroup]
        .into_iter()
        .flatten()
        .min()
}

/// Bytes this process may still map under its address-space limit (`ulimit -v`,
/// /proc/self/limits) beyond what it maps now (`VmSize`, /proc/self/status); `None`
/// without a limit.
pub fn address_space_left() -> Option<u64> {
    let limit = address_space_limit(&std::fs::read_to_string("/proc/self/limits").ok()?)?;
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let mapped = kib_field(&status, "VmSize:")?;
    Some(limit.saturating_sub(mapped))
}

/// A size for people: KiB, MiB or GiB.
pub fn size(bytes: u64) -> String {
    Size(bytes).to_string()
}

/// A number of bytes written as [`size`] does, without a `String` of its own (the
/// message of a refused allocation, [`super::out_of_memory`]).
pub struct Size(pub u64);

impl std::fmt::Display for Size {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let b = self.0 as f64;
        let (mib, gib) = (f64::from(1u32 << 20), f64::from(1u32 << 30));
        if b < mib {
            write!(f, "{:.0} KiB", b / 1024.0)
        } else if b < gib {
            write!(f, "{:.1} MiB", b / mib)
        } else {
            write!(f, "{:.1} GiB", b / gib)
        }
    }
}

/// `count` particles of `bytes` each against the `room` bytes that `what` (“the node has
/// available”): their state's size beside it or, where the count stopped once it was
/// too many (`lower`), as at least that many.
pub fn particles_over(count: u64, bytes: u64, room: u64, what: &str, lower: bool) -> String {
    if lower {
        format!(
            "at least {count} particles, whose state alone ({bytes} bytes each) takes more than the {} {what}",
            size(room)
        )
    } else {
        format!(
            "{count} particles, whose state alone takes {} ({bytes} bytes each), more than the {} {what}",
            size(count.saturating_mul(bytes)),
            size(room)
        )
    }
}

/// `MemAvailable` of /proc/meminfo, in bytes.
fn mem_available(meminfo: &str) -> Option<u64> {
    kib_field(meminfo, "MemAvailable:")
}

/// The value of a `NAME:   N kB` line, in bytes.
fn kib_field(text: &str, name: &str) -> Option<u64> {
    let rest = text.lines().find_map(|l| l.strip_prefix(name))?;
    let kib: u64 = rest.trim().strip_suffix("kB")?.trim().parse().ok()?;
    kib.checked_mul(1024)
}

/// The soft limit of `Max address space` in /proc/self/limits, in bytes; `None` when
/// unlimited.
fn address_space_limit(limits: &str) -> Option<u64> {
    let rest = limits
        .lines()
        .find_map(|l| l.strip_prefix("Max address space"))?;
    rest.split_whitespace().next()?.parse().ok()
}

/// What the memory cgroup of /proc/self/cgroup's text leaves below its limit, its files
/// under `root`: cgroup v2 (`0::PATH`, `memory.max` less `memory.current`) or v1
/// (`N:memory:PATH`, `memory.limit_in_bytes` less `memory.usage_in_bytes`). `None`
/// without a limit or where the files cannot be read.
fn cgroup_left(cgroup: &str, root: &Path) -> Option<u64> {
    let read = |dir: &Path, name: &str| -> Option<u64> {
        std::fs::read_to_string(dir.join(name))
            .ok()?
            .trim()
            .parse()
            .ok()
    };
    let left = |line: &str| -> Option<u64> {
        let mut f = line.splitn(3, ':');
        let (_, controllers, path) = (f.next()?, f.next()?, f.next()?);
        let rel = path.trim_start_matches('/');
        if controllers.is_empty() {
            let dir = root.join(rel);
            // "max" (no limit) does not parse.
            let limit = read(&dir, "memory.max")?;
            Some(limit.saturating_sub(read(&dir, "memory.current")?))
        } else if controllers.split(',').any(|c| c == "memory") {
            let dir = root.join("memory").join(rel);
            let limit = read(&dir, "memory.limit_in_bytes")?;
            // v1 writes a huge number for no limit.
            (limit < 1 << 62)
                .then(|| read(&dir, "memory.usage_in_bytes"))
                .flatten()
                .map(|used| limit.saturating_sub(used))
        } else {
            None
        }
    };
    // A hybrid host lists both hierarchies; the first with a limit counts.
    cgroup.lines().find_map(left)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_read_as_people_write_them() {
        assert_eq!(size(43_264), "42 KiB");
        assert_eq!(size(3 << 20), "3.0 MiB");
        assert_eq!(size(24_000_000_000), "22.4 GiB");
        let said = particles_over(10, 160, 1000, "are left", false);
        assert_eq!(said, "10 particles, whose state alone takes 2 KiB (160 bytes each), more than the 1 KiB are left");
    }

    #[test]
    fn proc_files_parse_as_linux_writes_them() {
        let meminfo = "MemTotal:       24563512 kB\nMemFree:        20000000 kB\nMemAvailable:   22000000 kB\n";
        assert_eq!(mem_available(meminfo), Some(22_000_000 * 1024));
        assert_eq!(mem_available("MemTotal: 1 kB\n"), None);
        let limits = "Limit                     Soft Limit           Hard Limit           Units     \n\
                      Max stack size            8388608              unlimited            bytes     \n\
                      Max address space         1024000000           unlimited            bytes     \n";
        assert_eq!(address_space_limit(limits), Some(1_024_000_000));
        let unlimited = limits.replace("1024000000          ", "unlimited           ");
        assert_eq!(address_space_limit(&unlimited), None);
        assert_eq!(
            kib_field("VmSize:\t  600000 kB\n", "VmSize:"),
            Some(600_000 * 1024)
        );
    }

    /// A cgroup v2 limit and a v1 one, in folders laid out as /sys/fs/cgroup lays them
    /// out: what is left below the limit; no limit ("max", or v1's huge number) is none.
    #[test]
    fn cgroup_limits_are_read_below_their_root() {
        let root = std::env::temp_dir().join(format!("mpmcg-cgroup-{}", std::process::id()));
        let v2 = root.join("job.slice/step_0");
        std::fs::create_dir_all(&v2).unwrap();
        std::fs::write(v2.join("memory.max"), "4294967296\n").unwrap();
        std::fs::write(v2.join("memory.current"), "1073741824\n").unwrap();
        assert_eq!(cgroup_left("0::/job.slice/step_0\n", &root), Some(3 << 30));
        std::fs::write(v2.join("memory.max"), "max\n").unwrap();
        assert_eq!(cgroup_left("0::/job.slice/step_0\n", &root), None);
        let v1 = root.join("memory/slurm/job_7");
        std::fs::create_dir_all(&v1).unwrap();
        std::fs::write(v1.join("memory.limit_in_bytes"), "2147483648\n").unwrap();
        std::fs::write(v1.join("memory.usage_in_bytes"), "536870912\n").unwrap();
        let text = "12:cpuset:/slurm/job_7\n4:memory:/slurm/job_7\n";
        assert_eq!(cgroup_left(text, &root), Some(3 << 29));
        std::fs::write(v1.join("memory.limit_in_bytes"), "9223372036854771712\n").unwrap();
        assert_eq!(cgroup_left(text, &root), None);
        let _ = std::fs::remove_dir_all(&root);
    }
}
