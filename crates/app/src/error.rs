//! The program's error: every library's, wrapped, and the command line's own. `main` prints it
//! as one `error:` line and exits with status 2.

use thiserror::Error;

/// Why a command failed.
#[derive(Debug, Error)]
pub enum Error {
    /// The engine's error.
    #[error(transparent)]
    Core(#[from] touchfem_core::Error),
    /// A study's error (`bench`), and the GPU pass's and the renderer's, which the lab's
    /// error wraps.
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

// The GPU pass's and the renderer's errors convert through `touchfem_lab::Error`, which wraps
// them transparently (the message is theirs).
impl From<touchfem_gpu::GpuError> for Error {
    fn from(e: touchfem_gpu::GpuError) -> Error {
        Error::Lab(e.into())
    }
}
impl From<touchfem_gpu::render::RenderError> for Error {
    fn from(e: touchfem_gpu::render::RenderError) -> Error {
        Error::Lab(e.into())
    }
}
