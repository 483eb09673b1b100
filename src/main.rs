fn main() -> std::process::ExitCode {
    mpmcg::cli::main()
}
