//! The `mpmcg` command; everything is in the library (`mpmcg::driver::cli`).

#![forbid(unsafe_code)]

use std::io::Write;
use std::process::ExitCode;

fn main() -> ExitCode {
    // Before the library runs: a build for another CPU would die of SIGILL in it. The
    // message is written from fixed pieces, without formatting, whose code could
    // itself use the vector instructions in question (`tests/cpu_check.rs` reads the
    // binary: no AVX-512 instruction in `main` or the check).
    if let Some(missing) = mpmcg::driver::cpu::missing_feature() {
        // Once under mpirun, from rank 0.
        if !mpmcg::driver::cli::launched_as_other_rank() {
            let mut e = std::io::stderr().lock();
            // Three calls, not a loop over an array of them (48 bytes the compiler may
            // move with one vector instruction).
            let _ = e.write_all(b"error: this mpmcg was built for a CPU with `");
            let _ = e.write_all(missing.as_bytes());
            let _ = e.write_all(
                b"`, which this CPU lacks; rebuild it on this machine (`cargo clean && cargo build --release`: \
                  cargo does not see that the CPU changed) \
                  or for the oldest CPU it must run on \
                  (`RUSTFLAGS=\"-C target-cpu=x86-64-v3\" cargo build --release`; README, On a cluster)\n",
            );
        }
        return ExitCode::from(1);
    }
    mpmcg::driver::cli::main()
}
