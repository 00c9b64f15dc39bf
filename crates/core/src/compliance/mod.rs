//! The precomputed compliance `L = K⁻¹` (the paper's eq. 3), restricted to what a scene needs:
//! rows for the displayed nodes and columns for the touchable nodes, plus each touchable node's
//! 3×3 block `L_ii` and its inverse (eq. 7).
//!
//! # Layout
//! `L` is stored column-major as a dense `(3R') × (3C)` matrix, R' = stored rows, C = columns:
//! entry (row node `r`, axis `a`; column node `c`, axis `b`) is at index
//! `(3c + b)·3R' + 3r + a`. One column node's three DOF columns are contiguous, so a frame with a
//! few active columns touches a few contiguous runs, and the GPU's per-vertex threads read
//! consecutive addresses.
//!
//! The rows of clamped nodes are identically zero and are not stored: the free displayed rows
//! come first (`R'` = [`Compliance::l_rows`] of them), the clamped ones after. The GPU's f32 or
//! f16 copy has the same layout, rounded while uploading: the host holds only the f64.

pub mod conditioning;
pub mod correction;
mod error;
mod grown;
pub(crate) use grown::product_seq;
pub mod hmatrix;
pub mod near;
pub(crate) mod plan;
pub mod precision;
mod products;

pub use error::ComplianceError;
pub(crate) use plan::*;
pub use plan::{method, Method, BATCH_COLS};
pub(crate) use products::GramProducts;

use crate::compliance::correction::Correction;
use crate::compliance::hmatrix::{HError, HMatrix, HOptions, HPlan, LoadErrors, Panel};
use crate::compliance::near::NearBlocks;
use crate::threads::Stopwatch;
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::Mat;
use glam::{DMat3, DVec3, Vec3};

use crate::fem::{FemError, Stiffness};
use crate::mesh::Mesh;

/// A set of mesh nodes.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum NodeSet {
    /// Every node.
    All,
    /// The boundary nodes (clamped ones included).
    Surface,
    /// The boundary nodes that are not clamped.
    FreeSurface,
    /// These nodes, in this order.
    Nodes(Vec<u32>),
}

impl NodeSet {
    /// The node indices this set names on `mesh`.
    pub(crate) fn resolve(&self, mesh: &Mesh) -> Vec<u32> {
        match self {
            NodeSet::All => (0..mesh.nodes.len() as u32).collect(),
            NodeSet::Surface => mesh.surface_nodes.clone(),
            NodeSet::FreeSurface => mesh.free_surface_nodes(),
            NodeSet::Nodes(v) => v.clone(),
        }
    }
}

/// Which part of `L` to precompute.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Selection {
    /// Displayed nodes (rows). The touchable nodes are always added to them.
    pub rows: NodeSet,
    /// Touchable nodes (columns); none may be clamped.
    pub cols: NodeSet,
}

impl Default for Selection {
    /// Rows: the surface; columns: the free surface.
    fn default() -> Self {
        Selection {
            rows: NodeSet::Surface,
            cols: NodeSet::FreeSurface,
        }
    }
}

/// What the precompute cost and how accurate it is.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PrecomputeStats {
    /// Free DOFs of K.
    pub free_dofs: usize,
    /// Non-zeros of K (both triangles).
    pub k_nonzeros: usize,
    /// Wall time for assembly, factorisation and the solves, seconds.
    pub seconds: f64,
    /// Bytes held on the host by L (f64; the GPU holds its own f32 or f16 copy) and the
    /// diagonal blocks.
    pub bytes: usize,
    /// max |K·L − I| over the computed columns (full columns, before row selection).
    pub residual: f64,
    /// max |L_ij − L_jiᵀ| over the touchable square block, relative to max |L|.
    pub symmetry: f64,
    /// Where the time went (wall seconds of each phase).
    pub phases: PhaseTimes,
}

/// Wall seconds of each precompute phase. The solve phases run on several threads: their
/// entries are the wall time of the slowest worker's share (`solve_s`: triangular solves,
/// `check_s`: the residual K·x − e, `scatter_s`: copying the displayed rows out).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PhaseTimes {
    /// Assembling K, s.
    pub assemble_s: f64,
    /// Fill-reducing ordering and symbolic factorisation, s.
    pub symbolic_s: f64,
    /// Numeric Cholesky factorisation, s.
    pub numeric_s: f64,
    /// Forward and back substitution for all columns, s.
    pub solve_s: f64,
    /// Residual check, s.
    pub check_s: f64,
    /// Copying rows into L, s.
    pub scatter_s: f64,
    /// Building the result (diagonal inverses, symmetry check), s.
    pub finish_s: f64,
    /// Non-zeros of the Cholesky factor.
    pub factor_nonzeros: usize,
    /// How the columns were computed: `"columns"` (a forward and back substitution per
    /// column) or `"gram"` (sparse forward solves and their Gram product, see [`crate::fem::gram`]).
    pub method: String,
    /// The Gram method's forward solves (`W`), s; 0 for the column method.
    pub forward_s: f64,
    /// Bytes of the Gram method's `W`; 0 for the column method.
    pub w_bytes: usize,
    /// The symmetric Gram plan's mirrored rows (copied from earlier batches and, in
    /// `touchfem precompute`, the batch's write), s, summed over the workers.
    pub mirror_s: f64,
    /// `touchfem precompute`'s last step: the checksums, the file's sync to disk, the rename
    /// and the directory's sync, s.
    pub sync_s: f64,
    /// Estimated floating-point operations of the column method's solves.
    pub column_flops: f64,
    /// Whether the Cholesky factor was kept in a file (see `factor_store`).
    pub factor_in_file: bool,
    /// Peak bytes of the out-of-core factorisation's fronts and update stacks; 0 when the
    /// factor was kept in memory.
    pub front_bytes: usize,
    /// Estimated floating-point operations of the Gram method (forward solves + products);
    /// 0 when it does not apply.
    pub gram_flops: f64,
}

/// Where a compliance's `L` is ([`Compliance::stored_l`]): row-major `R' × 3C × 3` f64 on the
/// host, or a checked cache file read back when a copy is built (the GPU's).
#[derive(Clone, Copy, Debug)]
pub enum StoredL<'a> {
    /// On the host, f64.
    Host(&'a [f64]),
    /// Outside memory (its cache file).
    File(&'a dyn LSource),
    /// Hierarchical: dense near blocks and low-rank far blocks ([`HMatrix`]).
    Hier(&'a HMatrix),
}

/// `L` kept outside memory (a checked cache file, `cache::FileL`), read back in ranges of
/// entries (`R' × 3C × 3`, row-major) when a copy is built, such as the GPU's.
pub trait LSource: std::fmt::Debug + Send + Sync {
    /// Number of entries.
    fn len(&self) -> usize;
    /// Whether there is no entry.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// max |L| rounded to f32.
    fn max_abs_f32(&self) -> f32;
    /// Entries `range`, rounded to f32.
    fn read_f32(&self, range: std::ops::Range<usize>) -> std::io::Result<Vec<f32>>;
}

/// `L = K⁻¹` for displayed rows × touchable columns, with the touchable diagonal blocks.
#[derive(Clone, Debug)]
pub struct Compliance {
    rows: Vec<u32>,
    cols: Vec<u32>,
    /// For each mesh node, its row index or `u32::MAX`.
    row_of_node: Vec<u32>,
    /// For each mesh node, its column index or `u32::MAX`.
    col_of_node: Vec<u32>,
    /// Row index of each column's node.
    col_row: Vec<u32>,
    /// Rows that hold `L` (the free ones, first); the rest are clamped: zero, not stored.
    l_rows: usize,
    /// Dense `L`, f64; empty when only the near blocks are held (`lean`). Shared: a
    /// compliance with a correction ([`Compliance::with_correction`]) holds the same `L`.
    l: std::sync::Arc<Vec<f64>>,
    /// An exact low-rank correction carried beside `L` (a cut), read by every accessor.
    correction: Option<std::sync::Arc<Correction>>,
    /// Instead of `l`: the haptic path's blocks, with `L` left in its cache file.
    lean: Option<std::sync::Arc<Lean>>,
    /// Instead of `l`: `L` stored hierarchically to a tolerance.
    hier: Option<std::sync::Arc<HMatrix>>,
    diag_inv: Vec<DMat3>,
    clamp_compliance: f64,
    /// Precompute cost and accuracy.
    pub stats: PrecomputeStats,
}

/// The power of two nearest max |L| (in the log): what `L` is divided by before it is stored
/// in half floats, so that any material keeps half-float precision (1 for an empty or
/// non-finite `L`).
pub fn f16_scale(l: &[f32]) -> f32 {
    f16_scale_of_max(l.iter().fold(0.0f32, |m, v| m.max(v.abs())))
}

/// [`f16_scale`] given max |L| (rounded to f32).
pub fn f16_scale_of_max(max_l: f32) -> f32 {
    if max_l.is_finite() && max_l > 0.0 {
        2f32.powi(max_l.log2().round() as i32)
    } else {
        1.0
    }
}

/// Inverts a 3×3 symmetric positive definite block; `None` if it is not invertible.
pub fn invert3(m: DMat3) -> Option<DMat3> {
    let det = m.determinant();
    let scale = m.x_axis.length() * m.y_axis.length() * m.z_axis.length();
    if !det.is_finite() || det.abs() <= 1e-14 * scale || scale == 0.0 {
        return None;
    }
    Some(m.inverse())
}

impl Compliance {
    /// Assembles K, factorises it and solves for the selected columns (f64).
    pub fn compute(mesh: &Mesh, sel: &Selection) -> Result<Compliance, FemError> {
        Self::compute_with_progress(mesh, sel, &mut |_, _| {})
    }

    /// As [`Compliance::compute`], calling `progress(columns done, columns total)` after each
    /// batch of solves.
    pub fn compute_with_progress(
        mesh: &Mesh,
        sel: &Selection,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Compliance, FemError> {
        Self::compute_with_method(mesh, sel, method(), progress)
    }

    /// As [`Compliance::compute_with_progress`] with the precompute method `how`.
    pub fn compute_with_method(
        mesh: &Mesh,
        sel: &Selection,
        how: Method,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Compliance, FemError> {
        Self::compute_in(mesh, sel, how, &factor_store(), progress)
    }

    /// As [`Compliance::compute_with_method`] with the factor kept where `store` says.
    pub fn compute_in(
        mesh: &Mesh,
        sel: &Selection,
        how: Method,
        store: &crate::fem::FactorStore,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Compliance, FemError> {
        let t0 = Stopwatch::start();
        let mut plan = ColumnPlan::with_method_in(mesh, sel, how, store)?;
        let mirrored = plan.mirror_from(0);
        let nr = plan.l_rows;
        let nc = plan.cols.len();
        let mut l = vec![0.0f64; 9 * nr * nc];
        let out = std::sync::Mutex::new(&mut l[..]);
        let mut phases = plan.phases.clone();
        let all: Vec<usize> = (0..plan.batches()).collect();
        let (residual, t) = plan.solve(
            &all,
            &|b, data| {
                let mut g = out.lock().unwrap_or_else(|e| e.into_inner());
                let first = plan.batch_cols(b).start;
                g[9 * nr * first..][..data.len()].copy_from_slice(data);
                true
            },
            &mut |done| progress(done, nc),
        )?;
        if mirrored {
            let tm = Stopwatch::start();
            let stride = 9 * nr * BATCH_COLS;
            for b in 1..plan.batches() {
                let (done, rest) = l.split_at_mut(b * stride);
                let len = 9 * nr * plan.batch_cols(b).len();
                plan.mirror(b, &mut rest[..len], &mut |q, r0, out: &mut [f64]| {
                    out.copy_from_slice(&done[q * 3 * nr + r0..][..out.len()]);
                    Ok::<(), ()>(())
                })
                .expect("reading memory cannot fail");
            }
            phases.mirror_s = tm.elapsed().as_secs_f64();
        }
        progress(nc, nc);
        phases.solve_s = t[0];
        phases.check_s = t[1];
        phases.scatter_s = t[2];
        let t_fin = Stopwatch::start();
        let (rows, cols) = (plan.rows.clone(), plan.cols.clone());
        let mut c = Compliance::from_stored(rows, plan.l_rows, cols, l, mesh.nodes.len())?;
        phases.finish_s = t_fin.elapsed().as_secs_f64();
        c.stats.phases = phases;
        c.stats.free_dofs = plan.stiff.dofs.n_free;
        c.stats.k_nonzeros = plan.stiff.k.compute_nnz();
        c.stats.residual = residual;
        c.stats.seconds = t0.elapsed().as_secs_f64();
        Ok(c)
    }

    /// Builds a compliance from a dense column-major `(3R)×(3C)` matrix in this module's layout,
    /// every row stored. `cols` must be a subset of `rows`; `n_nodes` is the mesh's node count.
    /// Used by tests with synthetic data.
    pub fn from_dense(
        rows: Vec<u32>,
        cols: Vec<u32>,
        l: Vec<f64>,
        n_nodes: usize,
    ) -> Result<Compliance, FemError> {
        let nr = rows.len();
        Self::from_stored(rows, nr, cols, l, n_nodes)
    }

    /// As [`Compliance::from_dense`] with only the first `l_rows` rows stored (`9·l_rows·C`
    /// entries): `rows[l_rows..]` are clamped, their rows of `L` zero. Every column's node
    /// must be among the stored rows. Used by the precompute and the cache.
    pub(crate) fn from_stored(
        rows: Vec<u32>,
        l_rows: usize,
        cols: Vec<u32>,
        l: Vec<f64>,
        n_nodes: usize,
    ) -> Result<Compliance, FemError> {
        let nc = cols.len();
        if l_rows > rows.len() || l.len() != 9 * l_rows * nc {
            return Err(FemError::BadSelection(format!(
                "L has {} entries, expected 9·{l_rows}·{nc} ({} rows)",
                l.len(),
                rows.len()
            )));
        }
        let mut c = Compliance::with_blocks(rows, l_rows, cols, n_nodes, l, None, None)?;
        c.stats.symmetry = c.symmetry_error();
        c.stats.bytes = c.l.len() * 8 + c.diag_inv.len() * 72;
        Ok(c)
    }

    /// A compliance that holds only the haptic path's blocks (`near`, filled) while `L` stays
    /// in `file` (read back when the GPU copy is built, see [`Compliance::stored_l`]).
    /// `max_abs` is max |L| over the whole file (for the symmetry figure).
    pub(crate) fn from_near(
        rows: Vec<u32>,
        l_rows: usize,
        cols: Vec<u32>,
        near: NearBlocks,
        file: Box<dyn LSource>,
        n_nodes: usize,
        max_abs: f64,
    ) -> Result<Compliance, FemError> {
        if near.cols() != cols.len() {
            return Err(FemError::BadSelection(format!(
                "near blocks for {} columns, expected {}",
                near.cols(),
                cols.len()
            )));
        }
        let lean = Some(std::sync::Arc::new(Lean { near, file }));
        let mut c = Compliance::with_blocks(rows, l_rows, cols, n_nodes, Vec::new(), lean, None)?;
        let (asym, bytes) = c.near().map_or((0.0, 0), |n| (n.asymmetry(), n.bytes()));
        c.stats.symmetry = if max_abs > 0.0 { asym / max_abs } else { 0.0 };
        c.stats.bytes = bytes + c.diag_inv.len() * 72;
        Ok(c)
    }

    /// A compliance whose `L` is the hierarchical `h`, built over the first `l_rows` of `rows`
    /// (its row `i` is `rows[i]`) and `cols` (its column `j` is `cols[j]`); `rows[l_rows..]`
    /// are clamped. Every column's node must be among the held rows. The diagonal blocks, and
    /// every block between near nodes, are exact.
    pub fn from_hier(
        rows: Vec<u32>,
        l_rows: usize,
        cols: Vec<u32>,
        h: HMatrix,
        n_nodes: usize,
    ) -> Result<Compliance, FemError> {
        if h.rows() != l_rows || h.cols() != cols.len() || h.out_rows() != rows.len() {
            return Err(FemError::BadSelection(format!(
                "a hierarchical L of {} × {} nodes ({} output rows) does not fit {l_rows} held \
                 rows of {} and {} columns",
                h.rows(),
                h.cols(),
                h.out_rows(),
                rows.len(),
                cols.len()
            )));
        }
        let bytes = h.bytes_f64() + h.index_bytes();
        let hier = Some(std::sync::Arc::new(h));
        let mut c = Compliance::with_blocks(rows, l_rows, cols, n_nodes, Vec::new(), None, hier)?;
        // The diagonal blocks' symmetry (exact blocks; far pairs are within the tolerance).
        let mut asym = 0.0f64;
        let mut maxd = 0.0f64;
        for i in 0..c.cols.len() {
            let d = c.touch_block(i, i);
            asym = asym.max(
                (d - d.transpose())
                    .abs()
                    .to_cols_array()
                    .iter()
                    .fold(0.0, |m, v| m.max(*v)),
            );
            maxd = maxd.max(d.abs().to_cols_array().iter().fold(0.0, |m, v| m.max(*v)));
        }
        c.stats.symmetry = if maxd > 0.0 { asym / maxd } else { 0.0 };
        c.stats.bytes = bytes + c.diag_inv.len() * 72;
        Ok(c)
    }

    /// The index maps, then [`Compliance::finish_blocks`] from `l` or `lean`'s blocks.
    fn with_blocks(
        rows: Vec<u32>,
        l_rows: usize,
        cols: Vec<u32>,
        n_nodes: usize,
        l: Vec<f64>,
        lean: Option<std::sync::Arc<Lean>>,
        hier: Option<std::sync::Arc<HMatrix>>,
    ) -> Result<Compliance, FemError> {
        let (row_of_node, col_of_node, col_row) = index_maps(&rows, &cols, n_nodes)?;
        if let Some(i) = col_row.iter().position(|&r| r as usize >= l_rows) {
            return Err(FemError::BadSelection(format!(
                "touchable node {} is among the clamped rows",
                cols[i]
            )));
        }
        let nc = cols.len();
        let mut c = Compliance {
            rows,
            cols,
            row_of_node,
            col_of_node,
            col_row,
            l_rows,
            l: std::sync::Arc::new(l),
            correction: None,
            lean,
            hier,
            diag_inv: Vec::with_capacity(nc),
            clamp_compliance: 0.0,
            stats: PrecomputeStats::default(),
        };
        c.finish_blocks()?;
        Ok(c)
    }

    /// `L_ii⁻¹` of every column and the clamp compliance, from the diagonal blocks.
    fn finish_blocks(&mut self) -> Result<(), FemError> {
        let nc = self.cols.len();
        self.diag_inv.clear();
        let mut min_trace = f64::INFINITY;
        for ci in 0..nc {
            let d = self.touch_block(ci, ci);
            let inv = invert3(d).ok_or(FemError::Singular {
                node: self.cols[ci],
                dof: 0,
            })?;
            min_trace = min_trace.min(d.x_axis.x + d.y_axis.y + d.z_axis.z);
            self.diag_inv.push(inv);
        }
        // A clamped node is modelled as ten times stiffer than the stiffest touchable node, so
        // that the force near the clamp is large but finite (see `clamp_compliance`).
        self.clamp_compliance = if min_trace.is_finite() {
            0.1 * min_trace / 3.0
        } else {
            0.0
        };
        Ok(())
    }

    /// Displayed nodes (mesh indices): the free ones first, then the clamped ones.
    pub fn rows(&self) -> &[u32] {
        &self.rows
    }
    /// How many of [`Compliance::rows`] hold `L` (`R'` of the layout): the free ones. The
    /// rows after them are clamped nodes, whose rows of `L` are zero and not stored.
    pub fn l_rows(&self) -> usize {
        self.l_rows
    }
    /// Touchable nodes (mesh indices).
    pub fn cols(&self) -> &[u32] {
        &self.cols
    }
    /// Row index of a mesh node, if displayed.
    #[inline]
    pub fn row_of(&self, node: u32) -> Option<usize> {
        let r = *self.row_of_node.get(node as usize)?;
        (r != u32::MAX).then_some(r as usize)
    }
    /// Column index of a mesh node, if touchable: one of [`Compliance::cols`], or past them
    /// an extra column of a grown correction ([`Correction::extra`]: a node a cut made
    /// touchable).
    #[inline]
    pub fn col_of(&self, node: u32) -> Option<usize> {
        let c = self
            .col_of_node
            .get(node as usize)
            .copied()
            .unwrap_or(u32::MAX);
        if c == u32::MAX {
            let k = self.correction.as_deref()?;
            let x = k.extra.binary_search(&node).ok()?;
            return Some(self.cols.len() + x);
        }
        // A node a cut pinned is no longer touchable: the haptic path treats it as clamped.
        if let Some(k) = &self.correction {
            if k.dead_cols[c as usize] {
                return None;
            }
        }
        Some(c as usize)
    }
    /// The number of touchable columns: [`Compliance::cols`] and a grown correction's extra
    /// ones.
    pub fn n_cols(&self) -> usize {
        self.cols.len() + self.correction.as_deref().map_or(0, |k| k.extra.len())
    }
    /// The node of column `c` (one of [`Compliance::n_cols`]).
    pub fn col_node(&self, c: usize) -> u32 {
        match self.cols.get(c) {
            Some(&n) => n,
            None => self.correction.as_deref().map_or(u32::MAX, |k| {
                k.extra
                    .get(c - self.cols.len())
                    .copied()
                    .unwrap_or(u32::MAX)
            }),
        }
    }
    /// The extra nodes of a grown correction (empty when none): column `cols().len() + k`
    /// is node `extra_nodes()[k]`.
    pub fn extra_nodes(&self) -> &[u32] {
        self.correction.as_deref().map_or(&[], |k| &k.extra[..])
    }
    /// Row index of column `c`'s node (a column of `L`).
    #[inline]
    pub fn col_row(&self, c: usize) -> usize {
        self.col_row[c] as usize
    }
    /// The f64 matrix in this module's layout (m/N); empty when `L` is not held on the host
    /// ([`Compliance::holds_l`]).
    pub fn l_f64(&self) -> &[f64] {
        &self.l
    }
    /// Whether `L` is held on the host (otherwise only the haptic path's near blocks are, and
    /// `L` is read from its cache file when the GPU copy is built).
    pub fn holds_l(&self) -> bool {
        self.lean.is_none() && self.hier.is_none()
    }
    /// The hierarchical `L`, when it is stored so ([`Compliance::from_hier`]).
    pub fn hier(&self) -> Option<&HMatrix> {
        self.hier.as_deref()
    }
    /// The near blocks, when `L` is not held on the host.
    pub fn near(&self) -> Option<&NearBlocks> {
        self.lean.as_deref().map(|l| &l.near)
    }
    /// Where `L`'s values are: on the host, or in the cache file they stayed in.
    pub fn stored_l(&self) -> StoredL<'_> {
        if let Some(h) = self.hier() {
            return StoredL::Hier(h);
        }
        match self.lean.as_deref() {
            Some(l) => StoredL::File(l.file.as_ref()),
            None => StoredL::Host(&self.l),
        }
    }
    /// `max |L|` rounded to f32 (what [`f16_scale`] of the GPU's f32 copy sees).
    /// For a hierarchical `L`, the largest stored value instead (dense entries and factors).
    pub fn max_abs_f32(&self) -> f32 {
        let l = self.hier().map_or(&self.l[..], |h| h.values());
        l.iter().fold(0.0f32, |m, &v| m.max((v as f32).abs()))
    }
    /// The 3×3 block L(row r, column c), m/N (`c` may be an extra column of a grown
    /// correction).
    #[inline]
    pub fn block(&self, r: usize, c: usize) -> DMat3 {
        if c >= self.cols.len() {
            return match &self.correction {
                Some(k) if r < self.l_rows => k.row_extra_block(r, c - self.cols.len()),
                _ => DMat3::ZERO,
            };
        }
        if let Some(h) = self.hier() {
            // Exact where the pair is near (a dense block), within the tolerance elsewhere.
            return h.block(r, c).map_or(DMat3::ZERO, |b| b.0);
        }
        if let Some(near) = self.near() {
            // Only rows of touchable nodes near column c are held.
            let i = self
                .rows
                .get(r)
                .and_then(|&n| self.col_of_node.get(n as usize))
                .copied()
                .unwrap_or(u32::MAX);
            return near.get(i as usize, c).unwrap_or(DMat3::ZERO);
        }
        if r >= self.l_rows {
            return DMat3::ZERO;
        }
        let nr3 = 3 * self.l_rows;
        let base = 3 * c * nr3 + 3 * r;
        let col = |b: usize| {
            let o = base + b * nr3;
            DVec3::new(self.l[o], self.l[o + 1], self.l[o + 2])
        };
        let b = DMat3::from_cols(col(0), col(1), col(2));
        match &self.correction {
            Some(k) if k.dead_rows[r] || k.dead_cols[c] => DMat3::ZERO,
            Some(k) => b + k.row_block(r, c),
            None => b,
        }
    }
    /// The 3×3 block between two touchable columns, L(node of column i, column j).
    #[inline]
    pub fn touch_block(&self, i: usize, j: usize) -> DMat3 {
        let nc = self.cols.len();
        if i >= nc || j >= nc {
            return self
                .correction
                .as_deref()
                .map_or(DMat3::ZERO, |k| k.extra_block(i, j));
        }
        match self.near() {
            // A far pair is not held: zero (lean compliances are made for one finger, whose
            // solve reads only near pairs).
            Some(near) => near.get(i, j).unwrap_or(DMat3::ZERO),
            None => self.block(self.col_row[i] as usize, j),
        }
    }
    /// `L_ii⁻¹` of column `c` (N/m): the stiffness felt at that node alone (eq. 7).
    #[inline]
    pub fn diag_inv(&self, c: usize) -> DMat3 {
        match &self.correction {
            Some(k) if c >= self.cols.len() => k.extra_diag_inv[c - self.cols.len()],
            Some(k) => k.diag_inv[c],
            None => self.diag_inv[c],
        }
    }

    /// The low-rank correction carried beside `L`, if any (a cut).
    pub fn correction(&self) -> Option<&Correction> {
        self.correction.as_deref()
    }

    /// Whether `self` and `other` hold the very same `L` (one shared allocation, as after
    /// [`Compliance::with_correction`]): a copy of `L` made for one (the GPU's) is then valid
    /// for the other. `false` for two equal but separately built matrices, and for lean
    /// compliances (no `L` on the host).
    pub fn shares_l(&self, other: &Compliance) -> bool {
        self.holds_l() && other.holds_l() && std::sync::Arc::ptr_eq(&self.l, &other.l)
    }

    /// This compliance with `L` shared and `correction` carried beside it: every block,
    /// `L_ii⁻¹` and displacement then reads `L + U C Uᵀ` (see [`crate::compliance::correction`]). Costs
    /// the index maps' copy, not `L`'s. Errors when `L` is not held on the host or the
    /// correction's sizes do not match this compliance's rows and columns.
    pub fn with_correction(
        &self,
        correction: std::sync::Arc<Correction>,
    ) -> Result<Compliance, FemError> {
        let (nr, nc, r) = (self.l_rows, self.cols.len(), correction.rank);
        if !self.holds_l() {
            return Err(FemError::BadSelection(
                "a correction needs a dense L on the host (not a lean or hierarchical compliance)"
                    .into(),
            ));
        }
        let k = &correction;
        if k.rows.len() != 3 * nr * r
            || k.u_cols.len() != 3 * nc * r
            || k.v_cols.len() != 3 * nc * r
            || k.dead_rows.len() != nr
            || k.dead_cols.len() != nc
            || k.diag_inv.len() != nc
        {
            return Err(FemError::BadSelection(format!(
                "a correction of rank {r} for {} rows and {} columns does not fit {nr} held rows and {nc} columns",
                k.dead_rows.len(),
                k.dead_cols.len()
            )));
        }
        let nx = k.extra.len();
        let grows = k.u_extra.len() == 3 * nx * r
            && k.v_extra.len() == 3 * nx * r
            && k.extra_place.len() == nx
            && k.extra_row.len() == nx
            && k.extra_diag_inv.len() == nx
            && k.extra.windows(2).all(|w| w[0] < w[1])
            && (k.extra.iter()).all(|&x| {
                self.col_of_node
                    .get(x as usize)
                    .is_none_or(|&c| c == u32::MAX)
            })
            && (k.extra_place.iter()).all(|p| p.iter().all(|&q| (q as usize) < r))
            && (k.extra_row.iter().zip(&k.extra)).all(|(&row, &x)| {
                row == u32::MAX || self.rows.get(row as usize) == Some(&x) && (row as usize) < nr
            });
        if !grows {
            return Err(FemError::BadSelection(format!(
                "a correction's {nx} extra columns are not consistent (sizes, order, places or rows)"
            )));
        }
        let mut c = self.clone();
        c.correction = Some(correction);
        Ok(c)
    }
    /// This compliance with its correction folded into a new `L`: `L′ = L + U_R V_Cᵀ` (one
    /// matrix product, `9·R·C·rank` multiply-adds), pinned rows and columns zeroed, the same
    /// rows and columns (so every column index stays valid), and a rank-0 correction that
    /// still marks the pinned ones. Exact, like the correction; made off the haptic thread
    /// when the correction has grown too large to carry. A compliance with no correction
    /// comes back as it is (sharing `L`). A correction with extra nodes
    /// ([`Correction::extra`]) grows `L` by them: each gets a column (after the old ones)
    /// and, if it had none, a row (after the free rows).
    pub fn folded(&self) -> Result<Compliance, FemError> {
        let Some(k) = &self.correction else {
            return Ok(self.clone());
        };
        if !self.holds_l() {
            return Err(FemError::BadSelection(
                "folding a correction needs a dense L on the host (not a lean or hierarchical compliance)".into(),
            ));
        }
        if !k.extra.is_empty() {
            return self.folded_grown(k);
        }
        let (nr3, nc3) = (3 * self.l_rows, 3 * self.cols.len());
        let mut l = nalgebra::DMatrix::from_column_slice(nr3, nc3, &self.l);
        let dst = l.as_mut_slice();
        grown::gemm_seq(dst, (nr3, nc3, nr3), &k.rows, &k.v_cols, k.rank, true);
        grown::pin_and_check(&mut l, k)?;
        let mut c = self.clone();
        c.l = std::sync::Arc::new(l.data.into());
        c.correction = Some(std::sync::Arc::new(k.pins_only()));
        Ok(c)
    }

    /// This dense compliance (without a cut's correction) stored hierarchically: rows are its
    /// free displayed rows ([`Compliance::l_rows`]), columns its touchable ones, positions
    /// from `mesh`. Its clamped rows read zero, as in [`Compliance::displace`].
    pub fn compress(&self, mesh: &Mesh, opts: &HOptions) -> Result<HMatrix, HError> {
        let c = self;
        opts.check()?;
        if !c.holds_l() {
            return Err(HError::NotHeld);
        }
        if c.correction().is_some() {
            return Err(HError::Correction);
        }
        let pos = |n: u32| {
            mesh.nodes.get(n as usize).copied().ok_or(HError::Node {
                node: n,
                nodes: mesh.nodes.len(),
            })
        };
        let nr = c.l_rows();
        let rp = c.rows()[..nr]
            .iter()
            .map(|&n| pos(n))
            .collect::<Result<Vec<_>, _>>()?;
        let cp = c
            .cols()
            .iter()
            .map(|&n| pos(n))
            .collect::<Result<Vec<_>, _>>()?;
        let l = c.l_f64();
        let nr3 = 3 * nr;
        if l.len() != nr3 * 3 * cp.len() {
            return Err(HError::BlockShape {
                want: (nr3, 3 * cp.len()),
                got: (nr3, l.len() / nr3.max(1)),
            });
        }
        HMatrix::build(&rp, &cp, c.rows().len(), opts, |ci| {
            let mut out = Vec::with_capacity(3 * nr3 * ci.len());
            for &col in ci {
                out.extend_from_slice(&l[3 * col as usize * nr3..][..3 * nr3]);
            }
            Ok::<_, HError>(out)
        })
    }

    /// Unit point loads at every column and axis, `h` against this compliance (the one it was
    /// built from, [`Compliance::compress`]).
    pub fn load_errors(&self, h: &HMatrix) -> LoadErrors {
        let c = self;
        let nr = c.rows().len();
        let (mut u, mut uh) = (
            vec![DVec3::ZERO; nr],
            vec![DVec3::ZERO; h.out_rows().max(nr)],
        );
        let mut e = LoadErrors::default();
        for col in 0..c.cols().len().min(h.cols()) {
            for b in 0..3 {
                let f = [(col as u32, DVec3::AXES[b])];
                c.displace(&f, &mut u);
                h.displace(&f, &mut uh);
                let (mut d2, mut n2, mut dm, mut nm) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
                for (a, h) in u.iter().zip(&uh) {
                    let d = *h - *a;
                    d2 += d.length_squared();
                    n2 += a.length_squared();
                    dm = dm.max(d.length());
                    nm = nm.max(a.length());
                }
                e.l2.push(if n2 > 0.0 { (d2 / n2).sqrt() } else { 0.0 });
                e.max.push(if nm > 0.0 { dm / nm } else { 0.0 });
            }
        }
        e
    }

    /// Compliance (m/N) given to clamped nodes when a contact triangle touches the clamp: one
    /// tenth of the smallest touchable diagonal compliance, so that forces stay finite.
    pub fn clamp_compliance(&self) -> f64 {
        self.clamp_compliance
    }

    /// u = L·F over the active columns (eq. 8), f64, into `out` (one entry per row, metres).
    /// Zero when `L` is not held on the host ([`Compliance::holds_l`]).
    pub fn displace(&self, forces: &[(u32, DVec3)], out: &mut [DVec3]) {
        if let Some(h) = self.hier() {
            h.displace(forces, out);
            return;
        }
        out[..self.rows.len()].fill(DVec3::ZERO);
        if !self.holds_l() {
            return;
        }
        let nr = self.l_rows;
        let nr3 = 3 * nr;
        let nc = self.cols.len();
        for &(c, f) in forces.iter().filter(|&&(c, _)| (c as usize) < nc) {
            let f = f.to_array();
            for (b, fb) in f.iter().enumerate() {
                if *fb == 0.0 {
                    continue;
                }
                let col = &self.l[(3 * c as usize + b) * nr3..][..nr3];
                for (r, o) in out[..nr].iter_mut().enumerate() {
                    *o += DVec3::new(col[3 * r], col[3 * r + 1], col[3 * r + 2]) * *fb;
                }
            }
        }
        if let Some(k) = &self.correction {
            let mut z = vec![0.0; k.rank];
            k.weights(forces, &mut z);
            k.add_rows(&z, out);
        }
    }

    /// The displacements of a grown correction's extra nodes that have no row
    /// ([`Correction::extra_rows`]), in [`Compliance::extra_nodes`]' order, into `out`
    /// (zero for the others, whose rows [`Compliance::displace`] gives; nothing without a
    /// correction). Metres.
    pub fn displace_extra(&self, forces: &[(u32, DVec3)], out: &mut [DVec3]) {
        out.fill(DVec3::ZERO);
        if let Some(k) = &self.correction {
            let mut z = vec![0.0; k.rank];
            k.weights(forces, &mut z);
            k.extra_rows(forces, &z, out);
        }
    }

    /// u = L·F from `L` rounded to f32, with f32 sums — the GPU's arithmetic — into `out`.
    pub fn displace_f32(&self, forces: &[(u32, DVec3)], out: &mut [Vec3]) {
        self.displace_rounded(forces, out, 1.0, |v| v);
    }

    /// u = L·F as the GPU's half-float layouts compute it: `L / s` rounded to f16
    /// (`s` = [`f16_scale`]), the forces times `s`, f32 sums; into `out`.
    pub fn displace_f16(&self, forces: &[(u32, DVec3)], out: &mut [Vec3]) {
        let s = f16_scale_of_max(self.max_abs_f32());
        self.displace_rounded(forces, out, s, |v| half::f16::from_f32(v / s).to_f32());
    }

    fn displace_rounded(
        &self,
        forces: &[(u32, DVec3)],
        out: &mut [Vec3],
        scale: f32,
        round: impl Fn(f32) -> f32,
    ) {
        out[..self.rows.len()].fill(Vec3::ZERO);
        if self.hier().is_some() {
            // The f64 product, rounded once (the hierarchical GPU pass has its own checks).
            let mut u = vec![DVec3::ZERO; self.rows.len()];
            self.displace(forces, &mut u);
            for (o, v) in out.iter_mut().zip(&u) {
                *o = v.as_vec3();
            }
            return;
        }
        if !self.holds_l() {
            return;
        }
        let nr = self.l_rows;
        let nc = self.cols.len();
        for &(c, f) in forces.iter().filter(|&&(c, _)| (c as usize) < nc) {
            let f = f.as_vec3() * scale;
            for b in 0..3 {
                let run = &self.l[(3 * c as usize + b) * 3 * nr..][..3 * nr];
                for (r, o) in out[..nr].iter_mut().enumerate() {
                    let e = Vec3::new(
                        round(run[3 * r] as f32),
                        round(run[3 * r + 1] as f32),
                        round(run[3 * r + 2] as f32),
                    );
                    *o += e * f[b];
                }
            }
        }
        if let Some(k) = &self.correction {
            // The correction in f64, rounded once (the GPU's extra columns are f32).
            let mut z = vec![0.0; k.rank];
            k.weights(forces, &mut z);
            let mut extra = vec![DVec3::ZERO; nr];
            k.add_rows(&z, &mut extra);
            for ((o, e), &dead) in out[..nr].iter_mut().zip(&extra).zip(&k.dead_rows) {
                *o = if dead { Vec3::ZERO } else { *o + e.as_vec3() };
            }
        }
    }

    fn symmetry_error(&self) -> f64 {
        let nc = self.cols.len();
        let maxl = self.l.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if maxl == 0.0 {
            return 0.0;
        }
        let mut err = 0.0f64;
        for i in 0..nc {
            for j in i..nc {
                let a = self.touch_block(i, j);
                let b = self.touch_block(j, i).transpose();
                err = err.max(
                    (a - b)
                        .abs()
                        .to_cols_array()
                        .iter()
                        .fold(0.0, |m, v| m.max(*v)),
                );
            }
        }
        err / maxl
    }
}

/// What a lean compliance holds instead of `L`.
#[derive(Debug)]
struct Lean {
    near: NearBlocks,
    file: Box<dyn LSource>,
}

type IndexMaps = (Vec<u32>, Vec<u32>, Vec<u32>);

/// Each mesh node's row and column (or `u32::MAX`), and each column's row.
pub(crate) fn index_maps(
    rows: &[u32],
    cols: &[u32],
    n_nodes: usize,
) -> Result<IndexMaps, FemError> {
    let mut row_of_node = vec![u32::MAX; n_nodes];
    let mut col_of_node = vec![u32::MAX; n_nodes];
    for (i, &r) in rows.iter().enumerate() {
        *row_of_node
            .get_mut(r as usize)
            .ok_or_else(|| FemError::BadSelection(format!("row node {r} out of range")))? =
            i as u32;
    }
    let mut col_row = Vec::with_capacity(cols.len());
    for (i, &c) in cols.iter().enumerate() {
        *col_of_node
            .get_mut(c as usize)
            .ok_or_else(|| FemError::BadSelection(format!("column node {c} out of range")))? =
            i as u32;
        let r = row_of_node[c as usize];
        if r == u32::MAX {
            return Err(FemError::BadSelection(format!(
                "column node {c} is not among the rows"
            )));
        }
        col_row.push(r);
    }
    Ok((row_of_node, col_of_node, col_row))
}

/// A hierarchical precompute's result ([`Compliance::compute_hier_parts`]): the whole `L` or
/// one shard's panels, with what [`Compliance::from_hier_parts`] needs to finish it.
#[derive(Clone, Debug)]
pub struct HierParts {
    /// Displayed nodes, the free ones (which hold `L`) first.
    pub rows: Vec<u32>,
    /// The rows that hold `L`.
    pub l_rows: usize,
    /// Touchable nodes.
    pub cols: Vec<u32>,
    /// The plan (from the rows' and columns' positions and the options).
    pub plan: HPlan,
    /// The panels computed (all of them, or a shard's).
    pub panels: Vec<Panel>,
    /// Cost and accuracy of the precompute.
    pub stats: PrecomputeStats,
}

/// The plan of a hierarchical `L` over `rows[..l_rows]` × `cols`, positions from `mesh`.
pub fn hier_plan(
    mesh: &Mesh,
    rows: &[u32],
    l_rows: usize,
    cols: &[u32],
    opts: &HOptions,
) -> Result<HPlan, HError> {
    let pos = |n: &u32| {
        mesh.nodes.get(*n as usize).copied().ok_or(HError::Node {
            node: *n,
            nodes: mesh.nodes.len(),
        })
    };
    let rp = rows
        .get(..l_rows)
        .ok_or(HError::OutRows {
            out_rows: rows.len(),
            rows: l_rows,
        })?
        .iter()
        .map(pos)
        .collect::<Result<Vec<_>, _>>()?;
    let cp = cols.iter().map(pos).collect::<Result<Vec<_>, _>>()?;
    HPlan::new(&rp, &cp, rows.len(), opts)
}

/// The plan a hierarchical precompute of `sel` on `mesh` builds (its blocks' shapes; the row
/// and column orders may differ from the precompute's), without factorising anything: what
/// `touchfem info --tolerance` estimates from.
pub fn selection_plan(mesh: &Mesh, sel: &Selection, opts: &HOptions) -> Result<HPlan, HError> {
    let cols = sel.cols.resolve(mesh);
    let mut rows = sel.rows.resolve(mesh);
    let shown: std::collections::HashSet<u32> = rows.iter().copied().collect();
    rows.extend(cols.iter().filter(|c| !shown.contains(c)));
    rows.retain(|&r| !mesh.fixed.get(r as usize).copied().unwrap_or(true));
    let n = rows.len();
    hier_plan(mesh, &rows, n, &cols, opts)
}

/// The panels of shard `index` of `count` (1-based): a contiguous run, so that shards in
/// order hold every panel once.
pub fn shard_panels(panels: usize, index: usize, count: usize) -> std::ops::Range<usize> {
    let count = count.max(1);
    let i = index.clamp(1, count) - 1;
    (panels * i / count)..(panels * (i + 1) / count)
}

impl Compliance {
    /// As [`Compliance::compute`] with `L` stored hierarchically to `opts.tolerance`, built
    /// panel by panel from the factor's solves: the dense `L` is never held.
    pub fn compute_hier(
        mesh: &Mesh,
        sel: &Selection,
        opts: &HOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Compliance, ComplianceError> {
        let parts =
            Self::compute_hier_parts(mesh, sel, method(), &factor_store(), opts, (1, 1), progress)?;
        Self::from_hier_parts(parts, mesh.nodes.len())
    }

    /// The panels of shard `shard = (index, count)` (1-based; `(1, 1)` for all) of a
    /// hierarchical `L`, with the precompute method `how` and the factor where `store` says.
    /// `progress(columns done, columns total)` after each panel.
    pub fn compute_hier_parts(
        mesh: &Mesh,
        sel: &Selection,
        how: Method,
        store: &crate::fem::FactorStore,
        opts: &HOptions,
        shard: (usize, usize),
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<HierParts, ComplianceError> {
        let t0 = Stopwatch::start();
        opts.check()?;
        let plan = ColumnPlan::with_method_in(mesh, sel, how, store)?;
        let hp = hier_plan(mesh, &plan.rows, plan.l_rows, &plan.cols, opts)?;
        let which = shard_panels(hp.panels(), shard.0, shard.1);
        let total: usize = which.clone().map(|p| hp.panel_cols(p).len()).sum();
        let threads = solver_threads();
        let mut phases = plan.phases.clone();
        let (mut residual, mut done, mut compress_s) = (0.0f64, 0, 0.0);
        let mut panels = Vec::with_capacity(which.len());
        // With the Gram method's `W`, far blocks are sketched through it (products), and only
        // the other blocks' rows are solved.
        let products = plan.gram_products();
        for p in which {
            let cols = hp.panel_cols(p);
            let parts: Vec<_> = hp
                .panel_leaves(p, products.is_some())
                .into_iter()
                .map(|(r, need)| (r, Some(need)))
                .collect();
            // One panel in HIER_CHECK_EVERY has its first column checked by a direct solve.
            let check = p % HIER_CHECK_EVERY == 0;
            let (data, r, t) = plan.solve_col_groups(cols, &parts, check)?;
            residual = residual.max(r);
            phases.solve_s += t[0];
            phases.check_s += t[1];
            phases.scatter_s += t[2];
            let tc = Stopwatch::start();
            let src = products
                .as_ref()
                .map(|g| g as &dyn crate::compliance::hmatrix::BlockProducts);
            panels.push(hp.compress_panel_with(p, &data, src, threads)?);
            compress_s += tc.elapsed().as_secs_f64();
            done += cols.len();
            progress(done, total);
        }
        phases.finish_s = compress_s;
        phases.method = format!("{}+hier", phases.method);
        let stats = PrecomputeStats {
            free_dofs: plan.stiff.dofs.n_free,
            k_nonzeros: plan.stiff.k.compute_nnz(),
            seconds: t0.elapsed().as_secs_f64(),
            residual,
            phases,
            ..PrecomputeStats::default()
        };
        Ok(HierParts {
            rows: plan.rows.clone(),
            l_rows: plan.l_rows,
            cols: plan.cols.clone(),
            plan: hp,
            panels,
            stats,
        })
    }

    /// The compliance of complete parts (every panel, from one run or merged shards).
    pub fn from_hier_parts(
        parts: HierParts,
        n_nodes: usize,
    ) -> Result<Compliance, ComplianceError> {
        let h = HMatrix::from_panels(parts.plan, parts.panels)?;
        let mut c = Compliance::from_hier(parts.rows, parts.l_rows, parts.cols, h, n_nodes)?;
        let (symmetry, bytes) = (c.stats.symmetry, c.stats.bytes);
        c.stats = PrecomputeStats {
            symmetry,
            bytes,
            ..parts.stats
        };
        Ok(c)
    }
}
