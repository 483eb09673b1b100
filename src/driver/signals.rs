//! SIGTERM, SIGINT and SIGUSR1 as a request to stop: the handler only records the
//! signal in an atomic (the one thing a signal handler may safely do); the run loop
//! reads it once per step, agrees on it over all ranks, finishes the step, writes a
//! checkpoint and ends with status "interrupted".
//!
//! SIGUSR1 is there for `mpirun` (Open MPI): it forwards SIGUSR1 to every rank at once,
//! while a SIGTERM to `mpirun` reaches the ranks only after `odls_base_sigkill_timeout`
//! and is followed by SIGKILL as long after, too soon for a large checkpoint.
//!
//! A second SIGINT (Ctrl-C pressed twice) ends the process at once with status 130.
//! Repeated SIGTERMs are not escalated: `mpirun` forwards the SIGTERM a scheduler
//! sends to it, so every rank may see two.
//!
//! Not `signal-hook` (assessed for issue 16): its safe `flag` API could replace the
//! `sigaction` block below (`register_usize` per signal, though it keeps the latest
//! signal where we report the first, and a SIGINT-only flag with
//! `register_conditional_shutdown` for the double Ctrl-C), but ignoring SIGXFSZ would
//! still need `libc::signal`. One `unsafe` block less is not worth a dependency here;
//! both blocks are argued where they stand.

use std::sync::atomic::{AtomicI32, AtomicU32, Ordering};

/// The first stop signal received, 0 if none.
static PENDING: AtomicI32 = AtomicI32::new(0);
static INTERRUPTS: AtomicU32 = AtomicU32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    if sig == libc::SIGINT && INTERRUPTS.fetch_add(1, Ordering::SeqCst) >= 1 {
        // SAFETY: _exit is async-signal-safe.
        unsafe { libc::_exit(130) };
    }
    let _ = PENDING.compare_exchange(0, sig, Ordering::SeqCst, Ordering::SeqCst);
}

/// Install the handlers for SIGTERM, SIGINT and SIGUSR1 (with SA_RESTART, so that
/// interrupted system calls in MPI and HDF5 resume).
pub fn install() -> Result<(), String> {
    // A file size limit (`ulimit -f`) would kill the process with SIGXFSZ in the middle
    // of a collective write; ignored, the write fails with EFBIG, which the run reports
    // (exit 1, naming the file) like any other I/O error.
    // SAFETY: setting a signal's disposition to SIG_IGN installs no code.
    unsafe { libc::signal(libc::SIGXFSZ, libc::SIG_IGN) };
    for sig in [libc::SIGTERM, libc::SIGINT, libc::SIGUSR1] {
        // SAFETY: a zeroed sigaction is valid; the handler only touches atomics and
        // calls _exit, both async-signal-safe.
        let r = unsafe {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            sa.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(sig, &sa, std::ptr::null_mut())
        };
        if r != 0 {
            return Err(format!(
                "cannot install a handler for {}: {}",
                name(sig),
                std::io::Error::last_os_error()
            ));
        }
    }
    Ok(())
}

/// The stop signal received so far on this process (0 if none).
pub fn pending() -> i32 {
    PENDING.load(Ordering::SeqCst)
}

/// "SIGTERM", "SIGINT", "SIGUSR1" or "signal N".
pub fn name(sig: i32) -> String {
    match sig {
        libc::SIGTERM => "SIGTERM".into(),
        libc::SIGINT => "SIGINT".into(),
        libc::SIGUSR1 => "SIGUSR1".into(),
        n => format!("signal {n}"),
    }
}
