//! # touchfem-app
//!
//! The `touchfem` program: its command line ([`args`], [`cli`]), the bundled demo ([`demo`]),
//! the interactive window ([`window`]), the visual path both draw from ([`visual`]), `precompute`
//! with its progress bar ([`precompute`]), the VTK output ([`vtu`]) and the Haply Inverse3's
//! client ([`haply`]). It is the edge of the workspace: environment variables are read and
//! things are printed here, and the libraries' log records are written to stderr.

pub mod args;
pub mod cli;
mod cut_poke;
pub mod demo;
pub mod error;
pub mod haply;
pub mod precompute;
pub mod report;
pub mod visual;
pub mod vtu;
pub mod window;

use clap::Parser;

/// The program: parses the command line, runs it, prints an error as one `error:` line and
/// returns the exit status (2 for bad input).
pub fn main() -> std::process::ExitCode {
    install_logger();
    let cli = args::Cli::parse();
    match cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::from(2)
        }
    }
}

/// Writes the libraries' warnings and errors to stderr as they are (their messages carry their
/// own `warning:`/`note:` prefix); `TOUCHFEM_LOG=info` (or `debug`) shows more.
struct StderrLogger;

impl log::Log for StderrLogger {
    fn enabled(&self, m: &log::Metadata<'_>) -> bool {
        m.level() <= log::max_level()
    }
    fn log(&self, r: &log::Record<'_>) {
        if self.enabled(r.metadata()) {
            eprintln!("{}", r.args());
        }
    }
    fn flush(&self) {}
}

static LOGGER: StderrLogger = StderrLogger;

/// Installs the stderr logger (once; later calls change nothing).
pub(crate) fn install_logger() {
    if log::set_logger(&LOGGER).is_ok() {
        let level = match std::env::var("TOUCHFEM_LOG").as_deref() {
            Ok("debug") => log::LevelFilter::Debug,
            Ok("info") => log::LevelFilter::Info,
            Ok("off") => log::LevelFilter::Off,
            _ => log::LevelFilter::Warn,
        };
        log::set_max_level(level);
    }
}
