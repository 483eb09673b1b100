//! The process's allocator: the system's, except that a request it cannot meet ends
//! the process with one line that says so, what was asked and what to change, and
//! exit 2, where Rust's default prints "memory allocation of N bytes failed", a
//! backtrace and aborts (exit 134, and under `mpirun` a dump of the signal).
//!
//! The checks before seeding and before reading a checkpoint refuse a job whose
//! particles' state alone is too large; this catches the rest (the grid, the
//! buffers, a rank that particles crowd into). No code of ours asks for memory that
//! it may be refused (`try_reserve`): every failed request would have aborted.

use std::alloc::{GlobalAlloc, Layout, System};
use std::fmt::Write as _;
use std::sync::atomic::{AtomicI64, Ordering};

use super::memory::Size;

/// [`System`], ending the process where it returns no memory ([`refused`]).
pub struct EndWhenRefused;

#[global_allocator]
static ALLOCATOR: EndWhenRefused = EndWhenRefused;

/// This process's MPI rank once known, for the message; −1 before.
static RANK: AtomicI64 = AtomicI64::new(-1);

/// Name `rank` in the message of a refused request.
pub fn set_rank(rank: usize) {
    RANK.store(rank as i64, Ordering::Relaxed);
}

// SAFETY: every method forwards its arguments unchanged to `System`, whose
// `GlobalAlloc` contract is the one the caller has met; a null from it never
// reaches the caller (`refused` does not return), and `System`'s non-null results
// are returned as they are.
unsafe impl GlobalAlloc for EndWhenRefused {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's layout, as `GlobalAlloc::alloc` requires (nonzero size).
        let p = unsafe { System.alloc(layout) };
        if p.is_null() {
            refused(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as in `alloc`.
        let p = unsafe { System.alloc_zeroed(layout) };
        if p.is_null() {
            refused(layout.size());
        }
        p
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: `ptr` was given by this allocator, so by `System`, with `layout`;
        // `new_size` is the caller's, as `GlobalAlloc::realloc` requires.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if p.is_null() {
            refused(new_size);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` was given by `System` with `layout` (see `realloc`).
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// A line formed on the stack: no memory is left to ask for.
struct Line {
    buf: [u8; 512],
    len: usize,
}

impl std::fmt::Write for Line {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        let room = self.buf.len() - self.len;
        let n = s.len().min(room);
        self.buf[self.len..self.len + n].copy_from_slice(&s.as_bytes()[..n]);
        self.len += n;
        if n < s.len() {
            Err(std::fmt::Error)
        } else {
            Ok(())
        }
    }
}

/// The soft address-space limit (`ulimit -v`), if there is one.
fn address_space_limit() -> Option<u64> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `getrlimit` writes one `rlimit` through a pointer to ours.
    let ok = unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut lim) } == 0;
    (ok && lim.rlim_cur != libc::RLIM_INFINITY).then_some(lim.rlim_cur)
}

/// Say that a request for `bytes` was refused, in one write (as `say!`, so that the
/// launcher's forwarding never splits it), and end the process with exit 2. `_exit`,
/// not `exit`: the libraries' exit handlers (HDF5 closes its files) would ask for
/// memory again; a checkpoint already written is complete (each is written beside
/// its final name and renamed), so nothing is lost but the steps since.
fn refused(bytes: usize) -> ! {
    let mut line = Line {
        buf: [0; 512],
        len: 0,
    };
    let _ = write!(line, "error: out of memory");
    let rank = RANK.load(Ordering::Relaxed);
    if rank >= 0 {
        let _ = write!(line, " on rank {rank}");
    }
    let _ = write!(
        line,
        ": a request for {} more was refused",
        Size(bytes as u64)
    );
    if let Some(limit) = address_space_limit() {
        let _ = write!(
            line,
            " (its address-space limit, ulimit -v, is {})",
            Size(limit)
        );
    }
    let _ = write!(
        line,
        "; run on more nodes, or with fewer particles per cell or a coarser grid (a checkpoint restarts on any rank count)"
    );
    let end = line.len.min(line.buf.len() - 1);
    line.buf[end] = b'\n';
    // SAFETY: `write` reads `end + 1` initialised bytes of `line.buf`; `_exit` ends
    // the process without returning and without running exit handlers.
    unsafe {
        libc::write(2, line.buf.as_ptr().cast(), end + 1);
        libc::_exit(2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stack line keeps what fits and says when it did not.
    #[test]
    fn a_line_keeps_what_fits() {
        let mut line = Line {
            buf: [0; 512],
            len: 0,
        };
        assert!(write!(line, "{}", Size(3 << 20)).is_ok());
        assert_eq!(&line.buf[..line.len], b"3.0 MiB");
        let long = "x".repeat(600);
        assert!(write!(line, "{long}").is_err());
        assert_eq!(line.len, 512);
    }
}
