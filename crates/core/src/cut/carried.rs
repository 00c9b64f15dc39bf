//! What a [`super::Cut`] carries from one cut to the next for its `V` (made in
//! [`super::carry`]).

use std::sync::Arc;

use nalgebra::DMatrix;

use crate::compliance::Compliance;

/// A matrix's entries, shared between the cut that made them and the correction that holds
/// them (no copy).
pub(super) type Shared = Arc<Vec<f64>>;

/// One cut's term of the capacitance: `S G Sᵀ`.
pub(super) struct Update {
    /// `S`, `rank × |T|` at the rank of its cut.
    pub(super) s: DMatrix<f64>,
    /// `G`, `|T| × |T|`.
    pub(super) g: DMatrix<f64>,
}

/// The last `U` and `V` made and the updates since.
#[derive(Default)]
pub(super) struct Carried {
    pub(super) pending: Vec<Update>,
    /// `Vᵀ` (`rank × 3·C`, column-major) of the compliance `L` it was made for, at `rank`.
    pub(super) v: Option<(Compliance, usize, Shared)>,
    /// `U` at the rows and, transposed, at the columns of the compliance it was read for,
    /// at `rank` ([`super::Cut::correction`]'s `rows` and `u_cols`).
    pub(super) u: Option<(Compliance, usize, Shared, Shared)>,
}
