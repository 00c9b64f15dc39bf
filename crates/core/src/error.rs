//! The crate-level error: one enum that wraps each domain's typed error.

use thiserror::Error;

/// Any touchfem error.
#[derive(Debug, Error)]
pub enum Error {
    /// Reading or validating a mesh.
    #[error(transparent)]
    Mesh(#[from] crate::mesh::MeshError),
    /// Assembling or factorising the stiffness.
    #[error(transparent)]
    Fem(#[from] crate::fem::FemError),
    /// Reading or writing the compliance cache.
    #[error(transparent)]
    Cache(#[from] crate::cache::CacheError),
    /// A hierarchical compliance cannot be built.
    #[error(transparent)]
    HMatrix(#[from] crate::compliance::hmatrix::HError),
    /// A compliance with a hierarchical `L` cannot be computed (a stiffness's error is
    /// [`Error::Fem`]).
    #[error(transparent)]
    Compliance(crate::compliance::ComplianceError),
    /// The UDP bridge cannot start (address, socket, key).
    #[error(transparent)]
    Udp(#[from] crate::devices::udp::UdpError),
    /// A tool or friction value that cannot be used.
    #[error(transparent)]
    Contact(#[from] crate::contact::ContactError),
    /// The haptic loop's thread ended by a panic (the message).
    #[error("the haptic thread panicked: {0}")]
    HapticThread(String),
    /// A scene file is invalid (the message names the file, line and key).
    #[error("{0}")]
    Body(String),
    /// A session file is invalid, or does not match its scene.
    #[error("{0}")]
    Session(String),
    /// A precompute was interrupted (Ctrl-C): its finished batches are kept for a resume.
    #[error(
        "interrupted: {done} of {total} column batches kept in {partial}; run the same command again to resume"
    )]
    Interrupted {
        /// The partial file.
        partial: std::path::PathBuf,
        /// Batches finished.
        done: usize,
        /// Batches in this shard.
        total: usize,
    },
    /// Bad input that is none of the above (a flag, a coordinate).
    #[error("{0}")]
    Input(String),
    /// An I/O error writing an output file.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The file.
        path: std::path::PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
}

impl From<crate::compliance::ComplianceError> for Error {
    fn from(e: crate::compliance::ComplianceError) -> Error {
        match e {
            crate::compliance::ComplianceError::Fem(e) => Error::Fem(e),
            other => Error::Compliance(other),
        }
    }
}

/// Implements `From<E>` for a caller's error type for each of the engine's domain errors
/// (mesh, FEM, cache, UDP), converting through [`Error`](enum@Error) into the variant that wraps it, so that
/// `?` works on them directly: `touchfem_core::from_domain_errors!(MyError::Core);`. The list
/// of domain errors lives here, in one place.
#[macro_export]
macro_rules! from_domain_errors {
    ($err:ident :: $variant:ident) => {
        $crate::from_domain_errors!(@each $err $variant
            $crate::mesh::MeshError,
            $crate::fem::FemError,
            $crate::cache::CacheError,
            $crate::contact::ContactError,
            $crate::compliance::hmatrix::HError,
            $crate::compliance::ComplianceError,
            $crate::devices::udp::UdpError);
    };
    (@each $err:ident $variant:ident $($t:ty),*) => {$(
        impl From<$t> for $err {
            fn from(e: $t) -> Self {
                $err::$variant(e.into())
            }
        }
    )*};
}
