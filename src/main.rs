//! The `touchfem` program (the `app` feature): see the `touchfem-app` crate.

fn main() -> std::process::ExitCode {
    touchfem_app::main()
}
