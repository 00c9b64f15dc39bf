//! The one numeric factorisation step that both the heap path and the out-of-core fronts use:
//! `LLᵀ`, else `LDLᵀ`, with one error mapping.

use super::error::FemError;

/// A pivot that stopped a factorisation, at its index in the factor's elimination order, or
/// another failure (scratch that could not be had).
pub(crate) enum Pivot {
    /// The pivot at this index is not positive (`LLᵀ`) or is zero (`LDLᵀ`).
    At(usize),
    /// Not a pivot: the error as it is.
    Other(FemError),
}

impl From<faer::linalg::cholesky::llt::factor::LltError> for Pivot {
    fn from(e: faer::linalg::cholesky::llt::factor::LltError) -> Pivot {
        let faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } = e;
        Pivot::At(index)
    }
}

impl From<faer::linalg::cholesky::ldlt::factor::LdltError> for Pivot {
    fn from(e: faer::linalg::cholesky::ldlt::factor::LdltError) -> Pivot {
        let faer::linalg::cholesky::ldlt::factor::LdltError::ZeroPivot { index } = e;
        Pivot::At(index)
    }
}

impl From<FemError> for Pivot {
    fn from(e: FemError) -> Pivot {
        Pivot::Other(e)
    }
}

/// The one numeric factorisation step: `llt` when no pivot is negative (`K` itself), else
/// `ldlt` (a mixed system's signed factor), either on `work` (the values and the scratch); a
/// failed pivot becomes `singular(index)`.
pub(crate) fn llt_else_ldlt<W>(
    mixed: bool,
    work: &mut W,
    llt: impl FnOnce(&mut W) -> Result<(), Pivot>,
    ldlt: impl FnOnce(&mut W) -> Result<(), Pivot>,
    singular: impl Fn(usize) -> FemError,
) -> Result<(), FemError> {
    let done = if mixed { ldlt(work) } else { llt(work) };
    done.map_err(|p| match p {
        Pivot::At(index) => singular(index),
        Pivot::Other(e) => e,
    })
}
