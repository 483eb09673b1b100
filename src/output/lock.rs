//! The output folder's lock: one run at a time writes a folder. Two runs writing the
//! same folder interleave `history.csv`, list each other's snapshots in
//! `particles.xmf` and prune each other's checkpoints.
//!
//! Rank 0 creates `OUT/mpmcg.lock` with `O_EXCL` (atomic, also on NFS v3 and later)
//! and writes the holder's host and pid into it; the file is deleted when the run ends
//! by any path that returns (completed, error, unstable, stopped by a signal) or
//! unwinds. A run that was killed leaves it behind: a lock whose host is this host and
//! whose pid is not alive is stale and taken over. A lock of another host cannot be
//! checked from here; the message says how to remove it. A pid reused by another
//! process since the run was killed makes a stale lock look held (the message then
//! names the pid, which the user can check).

use std::io::{ErrorKind, Write};
use std::path::{Path, PathBuf};

/// The lock file's name inside the output folder.
pub const LOCK_NAME: &str = "mpmcg.lock";

/// Why a folder could not be locked.
#[derive(Debug)]
pub enum LockError {
    /// Another run holds it (exit 2: a usage conflict, not an I/O failure).
    Held(String),
    /// The lock file could not be created or read (exit 1).
    Io(String),
}

/// A held lock; dropping it deletes the lock file if it is still this run's.
#[derive(Debug)]
pub struct Lock {
    path: PathBuf,
    text: String,
}

impl Drop for Lock {
    fn drop(&mut self) {
        // Only our own: had someone deleted it and another run locked the folder since,
        // removing it would unlock theirs.
        if std::fs::read_to_string(&self.path).is_ok_and(|t| t == self.text) {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// This machine's host name.
pub fn hostname() -> String {
    let mut buf = [0u8; 256];
    // SAFETY: the buffer is writable for its whole length, which is what is passed.
    let r = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) };
    if r != 0 {
        return "unknown-host".into();
    }
    let n = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    String::from_utf8_lossy(&buf[..n]).into_owned()
}

/// Whether process `pid` exists on this host.
fn alive(pid: i32) -> bool {
    if pid <= 0 {
        return false;
    }
    // SAFETY: signal 0 only checks that the process exists; nothing is sent.
    let r = unsafe { libc::kill(pid, 0) };
    // EPERM: it exists but belongs to another user.
    let exists = r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
    // A killed run's rank is a zombie until its parent reaps it: dead for our purpose.
    exists && !zombie(pid)
}

/// Whether `/proc` says that `pid` has ended but is not yet reaped (Linux).
fn zombie(pid: i32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| {
        // "pid (comm) state ...": comm may contain spaces and parentheses.
        s.rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().next())
            .is_some_and(|state| state == "Z" || state == "X")
    })
}

/// Host and pid of a lock file's text.
fn holder(text: &str) -> Option<(String, i32)> {
    let field = |k: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(k)?.trim_start().strip_prefix('='))
            .map(|v| v.trim().to_string())
    };
    Some((field("host")?, field("pid")?.parse().ok()?))
}

/// Lock the folder `dir` (which exists) for this process.
pub fn acquire(dir: &Path) -> Result<Lock, LockError> {
    let path = dir.join(LOCK_NAME);
    let host = hostname();
    let pid = std::process::id();
    let since = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let text = format!("mpmcg run lock\nhost = {host}\npid = {pid}\nstarted = {since}\n");
    let io = |e: std::io::Error| LockError::Io(format!("{}: {e}", path.display()));
    // A few rounds: a stale lock taken over by another run at the same moment.
    for _ in 0..3 {
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
        {
            Ok(mut f) => {
                if let Err(e) = f.write_all(text.as_bytes()).and_then(|()| f.sync_all()) {
                    let _ = std::fs::remove_file(&path);
                    return Err(io(e));
                }
                return Ok(Lock { path, text });
            }
            Err(e) if e.kind() == ErrorKind::AlreadyExists => {}
            Err(e) => return Err(io(e)),
        }
        let found = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            // Released between our attempt and the read: try again.
            Err(e) if e.kind() == ErrorKind::NotFound => continue,
            Err(e) => return Err(io(e)),
        };
        match holder(&found) {
            Some((h, p)) if h == host && !alive(p) => take_over(&path, &found).map_err(io)?,
            Some((h, p)) => {
                let started = found
                    .lines()
                    .find_map(|l| l.strip_prefix("started = "))
                    .and_then(|s| s.trim().parse::<u64>().ok())
                    .map_or(String::new(), |s| {
                        format!(", for {} s", since.saturating_sub(s))
                    });
                let check = if h == host {
                    String::new()
                } else {
                    format!(" (on another host: this run cannot check whether pid {p} is alive there)")
                };
                return Err(LockError::Held(format!(
                    "{}: the output folder is in use by another run (host {h}, pid {p}{started}){check}; \
                     wait for it to end or choose another --out, or, if no run uses the folder, delete {}",
                    dir.display(),
                    path.display()
                )));
            }
            None => {
                return Err(LockError::Held(format!(
                    "{}: the output folder is locked by {}, which names no host and pid; if no run uses the folder, delete it",
                    dir.display(),
                    path.display()
                )))
            }
        }
    }
    Err(LockError::Held(format!(
        "{}: could not lock the output folder: {} keeps changing (several runs starting at once?)",
        dir.display(),
        path.display()
    )))
}

/// Remove a stale lock whose text is `stale`, unless another run replaced it in the
/// meantime: it is renamed to a name of our own first (one rename wins), and put back
/// if what was renamed is not the stale lock.
fn take_over(path: &Path, stale: &str) -> std::io::Result<()> {
    let mine = path.with_extension(format!("lock.stale.{}", std::process::id()));
    match std::fs::rename(path, &mine) {
        Ok(()) => {}
        Err(e) if e.kind() == ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e),
    }
    if std::fs::read_to_string(&mine)? == stale {
        std::fs::remove_file(&mine)
    } else {
        std::fs::rename(&mine, path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn holder_parses_the_lock_text() {
        let t = "mpmcg run lock\nhost = node7\npid = 4242\nstarted = 1\n";
        assert_eq!(holder(t), Some(("node7".into(), 4242)));
        assert_eq!(holder("host = a\n"), None);
        assert_eq!(holder(""), None);
    }

    #[test]
    fn this_process_is_alive_and_pid_0_and_a_zombie_are_not() {
        assert!(alive(std::process::id() as i32));
        assert!(!alive(0));
        // An ended child not yet waited for is a zombie.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id() as i32;
        let t = std::time::Instant::now();
        while alive(pid) && t.elapsed().as_secs() < 10 {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert!(!alive(pid), "an unreaped child that has ended is not alive");
        child.wait().unwrap();
    }
}
