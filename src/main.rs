//! The `mpmcg` command; everything is in the library (`mpmcg::cli`).

#![forbid(unsafe_code)]

fn main() -> std::process::ExitCode {
    mpmcg::cli::main()
}
