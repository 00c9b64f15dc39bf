//! The lab's error: the engine's and the GPU's, wrapped, and the lab's own.

use thiserror::Error;

/// Why a study cannot run.
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
    /// Waiting for the GPU failed.
    #[error("GPU poll: {0}")]
    Poll(#[from] touchfem_gpu::wgpu::PollError),
    /// A study's input does not make sense (a singular matrix, no touchable node).
    #[error("{0}")]
    Study(String),
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
