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
    keep_freed_memory();
    let cli = args::Cli::parse();
    match cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::from(2)
        }
    }
}

/// Tells glibc's allocator to keep the memory it is given back (up to 1 GiB) and to hand
/// out blocks below 32 MiB from it, instead of mapping fresh pages for each: a live cut
/// builds and drops tens of megabytes of its correction every pass, and beside the renderer
/// the page faults of fresh mappings were a third of a pass (the separating incision's
/// median stroke-to-haptic delay 53/45/56 ms against 67/98/55 ms without, alternated:
/// `docs/measurements/2026-12-06-separating-cut.md`). Elsewhere, nothing.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only sets the allocator's parameters; called once, before any thread.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TOP_PAD, 64 << 20);
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
