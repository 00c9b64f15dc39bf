//! Why a compliance cannot be computed: the stiffness's error, or the hierarchical `L`'s.

use thiserror::Error;

/// Errors from computing a compliance with a hierarchical `L`.
#[derive(Debug, Error)]
pub enum ComplianceError {
    /// Building or factorising the stiffness.
    #[error(transparent)]
    Fem(#[from] crate::fem::FemError),
    /// The hierarchical compliance could not be built.
    #[error("hierarchical compliance: {0}")]
    Hier(#[from] crate::compliance::hmatrix::HError),
}
