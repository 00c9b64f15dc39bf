//! # touchfem-app
//!
//! The `touchfem` program: its command line ([`args`], [`cli`]), the bundled demo ([`demo`]),
//! the interactive window ([`window`]), `precompute` with its progress bar ([`precompute`]) and
//! the VTK output ([`vtu`]). It is the edge of the workspace: environment variables are read and
//! things are printed here, and the libraries' log records are written to stderr.

pub mod args;
pub mod cli;
pub mod demo;
pub mod precompute;
pub mod vtu;
pub mod window;

use clap::Parser;

/// The program: parses the command line, runs it, prints an error as one `error:` line and
/// returns the exit status (2 for bad input).
pub fn main() -> std::process::ExitCode {
    let cli = args::Cli::parse();
    match cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::from(2)
        }
    }
}
