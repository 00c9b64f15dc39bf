//! The program's error: every library's, wrapped, and the command line's own. `main` prints it
//! as one `error:` line and exits with status 2.

use thiserror::Error;

/// Why a command failed.
#[derive(Debug, Error)]
pub enum Error {
    /// The engine's error.
    #[error(transparent)]
    Core(#[from] touchfem_core::Error),
    /// The GPU pass's error.
    #[error(transparent)]
    Gpu(#[from] touchfem_gpu::GpuError),
    /// The renderer's error.
    #[error(transparent)]
    Render(#[from] touchfem_gpu::render::RenderError),
    /// A study's error (`bench`).
    #[error(transparent)]
    Lab(#[from] touchfem_lab::Error),
    /// The window's error (`view`, `serve --view`).
    #[error(transparent)]
    View(#[from] crate::window::ViewError),
    /// Bad input that the parsers could not catch (a combination of flags, a coordinate).
    #[error("{0}")]
    Input(String),
    /// A scene that cannot be used for this command.
    #[error("{0}")]
    Body(String),
    /// A session file that cannot be replayed.
    #[error("{0}")]
    Session(String),
    /// An output file cannot be written.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The file.
        path: std::path::PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
}

// The engine's domain errors convert through `touchfem_core::Error`.
touchfem_core::from_domain_errors!(Error::Core);
