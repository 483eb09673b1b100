//! The `mpmcg` command; everything is in the library (`mpmcg::driver::cli`).

#![forbid(unsafe_code)]

fn main() -> std::process::ExitCode {
    mpmcg::driver::cli::main()
}
