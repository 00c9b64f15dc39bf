//! Columns of `L₀` solved before the cutting starts, for the DOFs a cut may reach (the
//! nodes of the scene's cuttable region's tets), so that a pass reads the columns of the
//! DOFs it brings into `D` instead of solving for them (a solve of the phantom's 7,890 DOFs
//! costs about 1 ms on a 2-core VM, and a separating pass of the incision brings 30–80).
//!
//! The columns are solved in fixed blocks of [`BLOCK`] DOFs in ascending order, so they
//! hold the same bits however and whenever they are made (and, faer's supernodal solve
//! treating each right-hand side alone, the same bits as a pass's own solve: the tests find
//! no difference): a replay reads what the live run read. A rebased cut (after a fold) derives its own from the cut it
//! comes from, on the fold's thread ([`super::Rebase::run`], `cut/derive.rs`). Where they would take more than [`BUDGET`] bytes, none
//! are kept and every pass solves, as before.

/// DOFs solved together.
pub const BLOCK: usize = 64;

/// The most bytes a cut's precomputed columns may take (f64, every row of `K₀`'s
/// factored body).
pub const BUDGET: usize = 256 << 20;

/// Columns of `L₀` at chosen free DOFs of a cut's factored body.
pub struct Columns {
    /// Per node of the factored body: whether its DOFs' columns are held.
    pub(super) nodes: Vec<bool>,
    /// Per free DOF: its column's index in `cols`, or `u32::MAX`.
    pub(super) at: Vec<u32>,
    /// `n_free × m`, column-major.
    pub(super) cols: Vec<f64>,
    /// The factored body's free DOFs (each column's rows).
    pub(super) n_free: usize,
}

impl Columns {
    /// The column of free DOF `f` (its `n_free` rows), if held.
    pub fn column(&self, f: usize) -> Option<&[f64]> {
        let j = *self.at.get(f)?;
        (j != u32::MAX).then(|| &self.cols[j as usize * self.n_free..][..self.n_free])
    }

    /// How many columns are held.
    pub fn len(&self) -> usize {
        self.cols.len() / self.n_free.max(1)
    }

    /// Whether none are held.
    pub fn is_empty(&self) -> bool {
        self.cols.is_empty()
    }

    /// The nodes whose columns are held (over the factored body's nodes).
    pub fn nodes(&self) -> &[bool] {
        &self.nodes
    }
}

/// What a rebased cut's columns are derived from: the old cut's `L_D`, `C`, held columns
/// and DOF numbering (`Cut::derive_from`, `cut/derive.rs`).
pub struct Derive {
    /// The old cut's held columns.
    pub(super) columns: std::sync::Arc<Columns>,
    /// `L_D` at every DOF of the old `K₀` (`n_old × rank`).
    pub(super) ld: nalgebra::DMatrix<f64>,
    /// The old capacitance `C`.
    pub(super) cap: nalgebra::DMatrix<f64>,
    /// Each old DOF's place in `D` (`u32::MAX`: none).
    pub(super) place: Vec<u32>,
    /// The old `K₀`'s diagonal (a copy's `S`).
    pub(super) diag0: Vec<f64>,
    /// Per node: its three DOFs in the old `K₀` (`u32::MAX`: none).
    pub(super) dof: Vec<[u32; 3]>,
}
