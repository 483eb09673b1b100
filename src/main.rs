//! The `mpmcg` command; everything is in the library (`mpmcg::driver::cli`).

#![forbid(unsafe_code)]

use std::io::{IoSlice, Write};
use std::process::ExitCode;

fn main() -> ExitCode {
    // Before the library runs: a build for another CPU would die of SIGILL in it. The
    // message is written from fixed pieces, without formatting, whose code could
    // itself use the vector instructions in question (`tests/cpu_check.rs` reads the
    // binary: no AVX-512 instruction in `main` or the check).
    if let Some(missing) = mpmcg::driver::cpu::missing_feature() {
        // Rank 0 reports; another rank waits for rank 0 to end the job first, and
        // reports only if it is still alive (its node's CPU differs; see
        // `cli::early_error`).
        if mpmcg::driver::cli::launched_as_other_rank() {
            std::thread::sleep(mpmcg::driver::cli::OTHER_RANK_WAIT);
        }
        // One writev, so that the launcher's forwarding never splits the line (see
        // `say!`). Three slices, not a formatted string.
        let _ = std::io::stderr().write_vectored(&[
            IoSlice::new(b"error: this mpmcg was built for a CPU with `"),
            IoSlice::new(missing.as_bytes()),
            IoSlice::new(
                b"`, which this CPU lacks; rebuild it on this machine (`cargo clean && cargo build --release`: \
                  cargo does not see that the CPU changed) \
                  or for the oldest CPU it must run on \
                  (`RUSTFLAGS=\"-C target-cpu=x86-64-v3\" cargo build --release`; README, On a cluster)\n",
            ),
        ]);
        return ExitCode::from(1);
    }
    mpmcg::driver::cli::main()
}
