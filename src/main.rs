fn main() { mpmcg::cli::main() }
