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

use crate::correction::Correction;
use crate::hmatrix::{HError, HMatrix, HOptions, HPlan, LoadErrors, Panel};
use crate::near::NearBlocks;
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::Mat;
use glam::{DMat3, DVec3, Vec3};
use std::time::Instant;

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
    /// column) or `"gram"` (sparse forward solves and their Gram product, see [`crate::gram`]).
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
        let t0 = Instant::now();
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
            let tm = Instant::now();
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
        let t_fin = Instant::now();
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
    /// Column index of a mesh node, if touchable.
    #[inline]
    pub fn col_of(&self, node: u32) -> Option<usize> {
        let c = *self.col_of_node.get(node as usize)?;
        if c == u32::MAX {
            return None;
        }
        // A node a cut pinned is no longer touchable: the haptic path treats it as clamped.
        if let Some(k) = &self.correction {
            if k.dead_cols[c as usize] {
                return None;
            }
        }
        Some(c as usize)
    }
    /// Row index of column `c`'s node.
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
    /// The 3×3 block L(row r, column c), m/N.
    #[inline]
    pub fn block(&self, r: usize, c: usize) -> DMat3 {
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
    /// `L_ii⁻¹` and displacement then reads `L + U C Uᵀ` (see [`crate::correction`]). Costs
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
        let mut c = self.clone();
        c.correction = Some(correction);
        Ok(c)
    }
    /// This compliance with its correction folded into a new `L`: `L′ = L + U_R V_Cᵀ` (one
    /// matrix product, `9·R·C·rank` multiply-adds), pinned rows and columns zeroed, the same
    /// rows and columns (so every column index stays valid), and a rank-0 correction that
    /// still marks the pinned ones. Exact, like the correction; made off the haptic thread
    /// when the correction has grown too large to carry. A compliance with no correction
    /// comes back as it is (sharing `L`).
    pub fn folded(&self) -> Result<Compliance, FemError> {
        let Some(k) = &self.correction else {
            return Ok(self.clone());
        };
        if !self.holds_l() {
            return Err(FemError::BadSelection(
                "folding a correction needs a dense L on the host (not a lean or hierarchical compliance)".into(),
            ));
        }
        let (nr3, nc3) = (3 * self.l_rows, 3 * self.cols.len());
        let mut l = nalgebra::DMatrix::from_column_slice(nr3, nc3, &self.l);
        if k.rank > 0 {
            let u = nalgebra::DMatrixView::from_slice(&k.rows, nr3, k.rank);
            let vt = nalgebra::DMatrixView::from_slice(&k.v_cols, k.rank, nc3);
            l.gemm(1.0, &u, &vt, 1.0);
        }
        for (c, &dead) in k.dead_cols.iter().enumerate() {
            if dead {
                l.columns_mut(3 * c, 3).fill(0.0);
            }
        }
        for (r, &dead) in k.dead_rows.iter().enumerate() {
            if dead {
                l.rows_mut(3 * r, 3).fill(0.0);
            }
        }
        if !l.iter().all(|v| v.is_finite()) {
            return Err(FemError::BadSelection(
                "the folded compliance is not finite".into(),
            ));
        }
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
        for &(c, f) in forces {
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
        for &(c, f) in forces {
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
    ) -> Result<Compliance, FemError> {
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
    ) -> Result<HierParts, FemError> {
        let t0 = Instant::now();
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
            let tc = Instant::now();
            let src = products
                .as_ref()
                .map(|g| g as &dyn crate::hmatrix::BlockProducts);
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
    pub fn from_hier_parts(parts: HierParts, n_nodes: usize) -> Result<Compliance, FemError> {
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

/// [`crate::hmatrix::BlockProducts`] through the Gram method's `W`
/// ([`crate::gram::GramPlan::apply`]).
pub(crate) struct GramProducts<'a> {
    gp: &'a crate::gram::GramPlan,
    w: &'a [f64],
    /// Gram position of each row index (`usize::MAX`: clamped, no row of `L`).
    pos_of_row: Vec<usize>,
    /// Gram position of each column index.
    pos_of_col: Vec<usize>,
}

impl GramProducts<'_> {
    /// Gram positions of `idx` through `map`, ascending, each with its place in `idx`.
    fn sorted(map: &[usize], idx: &[u32]) -> Result<Vec<(usize, usize)>, HError> {
        let mut p = idx
            .iter()
            .enumerate()
            .map(|(t, &i)| match map.get(i as usize) {
                Some(&g) if g != usize::MAX => Ok((g, t)),
                _ => Err(HError::Node {
                    node: i,
                    nodes: map.len(),
                }),
            })
            .collect::<Result<Vec<_>, _>>()?;
        p.sort_unstable();
        Ok(p)
    }

    /// `x`'s rows (3 per node) in the order of `at`.
    fn permuted(x: faer::MatRef<'_, f64>, at: &[(usize, usize)]) -> Mat<f64> {
        let mut xs = Mat::<f64>::zeros(3 * at.len(), x.ncols());
        for j in 0..x.ncols() {
            for (t, &(_, from)) in at.iter().enumerate() {
                for a in 0..3 {
                    xs[(3 * t + a, j)] = x[(3 * from + a, j)];
                }
            }
        }
        xs
    }

    /// `(K⁻¹)[O, I₁]·x₁, …` side by side, `O` given by `o` (sorted), the pieces sorted too,
    /// written into `out` in the callers' row order.
    fn run(
        &self,
        o: &[(usize, usize)],
        pieces: &[(Vec<usize>, Mat<f64>)],
        mut out: faer::MatMut<'_, f64>,
    ) -> Result<(), HError> {
        let k: usize = pieces.iter().map(|p| p.1.ncols()).sum();
        if out.nrows() != 3 * o.len() || out.ncols() != k {
            return Err(HError::BlockShape {
                want: (3 * o.len(), k),
                got: (out.nrows(), out.ncols()),
            });
        }
        let op: Vec<usize> = o.iter().map(|p| p.0).collect();
        let refs: Vec<(&[usize], faer::MatRef<'_, f64>)> = pieces
            .iter()
            .map(|(p, x)| (p.as_slice(), x.as_ref()))
            .collect();
        let mut os = Mat::<f64>::zeros(3 * o.len(), k);
        thread_local! {
            static SCRATCH: std::cell::RefCell<crate::gram::ApplyScratch> =
                std::cell::RefCell::new(crate::gram::ApplyScratch::default());
        }
        SCRATCH.with_borrow_mut(|sc| self.gp.apply_pieces(self.w, &op, &refs, os.as_mut(), sc));
        for j in 0..k {
            for (t, &(_, back)) in o.iter().enumerate() {
                for a in 0..3 {
                    out[(3 * back + a, j)] = os[(3 * t + a, j)];
                }
            }
        }
        Ok(())
    }
}

impl crate::hmatrix::BlockProducts for GramProducts<'_> {
    fn products(
        &self,
        rows: &[u32],
        cols: &[u32],
        transpose: bool,
        x: faer::MatRef<'_, f64>,
        out: faer::MatMut<'_, f64>,
    ) -> Result<(), HError> {
        let r = Self::sorted(&self.pos_of_row, rows)?;
        let c = Self::sorted(&self.pos_of_col, cols)?;
        let (o, i) = if transpose { (c, r) } else { (r, c) };
        if x.nrows() != 3 * i.len() {
            return Err(HError::BlockShape {
                want: (3 * i.len(), x.ncols()),
                got: (x.nrows(), x.ncols()),
            });
        }
        let xs = Self::permuted(x, &i);
        self.run(&o, &[(i.iter().map(|p| p.0).collect(), xs)], out)
    }

    fn products_t_pieces(
        &self,
        pieces: &[(&[u32], faer::MatRef<'_, f64>)],
        cols: &[u32],
        out: faer::MatMut<'_, f64>,
    ) -> Result<(), HError> {
        let o = Self::sorted(&self.pos_of_col, cols)?;
        let mut sorted = Vec::with_capacity(pieces.len());
        for (rows, x) in pieces {
            let i = Self::sorted(&self.pos_of_row, rows)?;
            if x.nrows() != 3 * i.len() {
                return Err(HError::BlockShape {
                    want: (3 * i.len(), x.ncols()),
                    got: (x.nrows(), x.ncols()),
                });
            }
            let xs = Self::permuted(*x, &i);
            sorted.push((i.iter().map(|p| p.0).collect(), xs));
        }
        self.run(&o, &sorted, out)
    }
}

/// Columns per solve batch. Batches sit on a fixed grid of column indices (batch `b` holds
/// columns `64b .. 64b + 64`), so a column's values never depend on how the work is split
/// over threads or shards: merged shards equal the unsharded result bit for bit.
pub const BATCH_COLS: usize = 64;

/// How the precompute computes its columns.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Method {
    /// A forward and a back substitution per touchable DOF, each visiting only the
    /// supernodes the column reaches and the displayed rows need
    /// ([`crate::gram::UnitSolver`]).
    Columns,
    /// As `Columns` through every supernode (faer's solve; for comparisons).
    Full,
    /// Sparse forward solves for the displayed DOFs and their Gram product
    /// ([`crate::gram`]); the column method where the factor is not supernodal.
    Gram,
    /// Whichever is estimated cheaper.
    #[default]
    Auto,
}

/// The method named by the environment variable `TOUCHFEM_PRECOMPUTE` (`columns`, `gram`,
/// `full`; anything else or unset: [`Method::Auto`]).
pub fn method() -> Method {
    match crate::options::var("TOUCHFEM_PRECOMPUTE")
        .as_deref()
        .ok_or(())
    {
        Ok("columns") => Method::Columns,
        Ok("full") => Method::Full,
        Ok("gram") => Method::Gram,
        _ => Method::Auto,
    }
}

/// `read(DOF column, first row, out)`: rows of an earlier batch, for [`ColumnPlan::mirror`].
pub(crate) type ReadRows<'a, E> = dyn FnMut(usize, usize, &mut [f64]) -> Result<(), E> + 'a;

/// Column nodes per pruned column solve (a batch is solved in groups of this many).
const SOLVE_COLS: usize = 32;

/// Panels of a hierarchical precompute between two checks of a panel's first column against
/// a direct solve.
const HIER_CHECK_EVERY: usize = 4;

/// Batches between two checks of a Gram batch against a direct solve of its first column.
const GRAM_CHECK_EVERY: usize = 16;

/// The ordering of the precompute's factorisation: METIS, or by the environment variable
/// `TOUCHFEM_ORDERING` our coordinate nested dissection (`nd`) or faer's AMD (`amd`), for
/// comparisons.
fn ordering() -> crate::fem::Ordering {
    match crate::options::var("TOUCHFEM_ORDERING")
        .as_deref()
        .ok_or(())
    {
        Ok("amd") => crate::fem::Ordering::Amd,
        Ok("nd") => crate::fem::Ordering::NestedDissection,
        _ => crate::fem::Ordering::Metis,
    }
}

/// Bytes of Cholesky factor above which the precompute keeps it in a file (see
/// [`factor_store`]).
pub(crate) const FACTOR_FILE_ABOVE: usize = 256 << 20;

/// Where the precompute keeps its Cholesky factor, by the environment variable
/// `TOUCHFEM_FACTOR`: `heap` (faer's factorisation, in memory), `file` (the out-of-core
/// multifrontal factorisation of [`crate::frontal`]), or, unset or anything else, `file`
/// for factors above [`FACTOR_FILE_ABOVE`]. The file is unlinked at once and lives in the
/// cache directory ([`crate::options::cache_dir`]), or the system's temporary one.
pub(crate) fn factor_store() -> crate::fem::FactorStore {
    use crate::fem::FactorStore;
    let dir = crate::options::cache_dir()
        .filter(|d| std::fs::create_dir_all(d).is_ok())
        .unwrap_or_else(std::env::temp_dir);
    let threads = solver_threads();
    match crate::options::var("TOUCHFEM_FACTOR").as_deref().ok_or(()) {
        Ok("heap") => FactorStore::Heap,
        Ok("file") => FactorStore::File { dir, threads },
        _ => FactorStore::Auto {
            dir,
            threads,
            above: FACTOR_FILE_ABOVE,
        },
    }
}

/// The factorised stiffness and the resolved selection, ready to solve column batches.
pub(crate) struct ColumnPlan {
    /// Displayed nodes (rows); the touchable nodes are included. The free ones come first,
    /// then the clamped ones.
    pub rows: Vec<u32>,
    /// The free rows, which hold `L` (see [`Compliance::l_rows`]).
    pub l_rows: usize,
    /// Touchable nodes (columns).
    pub cols: Vec<u32>,
    /// Assembly and factorisation times (the solve phases are filled by the caller).
    pub phases: PhaseTimes,
    stiff: Stiffness,
    factor: crate::fem::Factor,
    /// The Gram method's plan, `W`, and the row index of each of its nodes.
    gram: Option<(crate::gram::GramPlan, Vec<f64>, Vec<u32>)>,
    /// Symmetric Gram plans: the first column whose batch is at hand when the upper rows are
    /// mirrored (see [`ColumnPlan::mirror_from`]).
    mirror_from: Option<usize>,
    /// The column method's pruned solver (supernodal factors).
    units: Option<crate::gram::UnitSolver>,
    /// For the Gram method on a factor in a file: the sweeps of the check solves, which drop
    /// the pages behind them.
    sweeper: Option<crate::gram::UnitSolver>,
    /// Batch buffers handed back by the workers, for the next batches (see
    /// [`ColumnPlan::buffer`]).
    pool: std::sync::Mutex<Vec<Vec<f64>>>,
}

/// A worker's groups of [`ColumnPlan::solve_cols`] (group, columns) and its seconds.
type GroupsSolved = (Vec<(usize, Vec<f64>)>, [f64; 3]);

/// The largest residual and the seconds solving, checking and scattering.
type SolveSummary = (f64, [f64; 3]);

/// A solver worker: runs until the work is out, reporting columns done to its argument.
type SolveWork<'a> = dyn Fn(&mut dyn FnMut(usize)) -> Result<SolveSummary, FemError> + Sync + 'a;

/// Runs `work` on `workers` threads, the calling one (which reports `progress`) included,
/// and combines what they return: the largest residual and, per phase, the slowest worker's
/// seconds.
fn run_workers(
    workers: usize,
    work: &SolveWork<'_>,
    progress: &mut dyn FnMut(usize),
) -> Result<SolveSummary, FemError> {
    let mut results = Vec::with_capacity(workers);
    std::thread::scope(|sc| {
        let handles: Vec<_> = (1..workers)
            .map(|_| sc.spawn(move || work(&mut |_| {})))
            .collect();
        results.push(work(progress));
        for h in handles {
            results.push(h.join().unwrap_or_else(|_| {
                Err(FemError::Factorisation("a solver thread panicked".into()))
            }));
        }
    });
    let mut out = (0.0f64, [0.0f64; 3]);
    for r in results {
        let (res, t) = r?;
        out.0 = out.0.max(res);
        for (a, v) in out.1.iter_mut().zip(t) {
            *a = a.max(v);
        }
    }
    Ok(out)
}

fn solver_threads() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
        .clamp(1, 16)
}

impl ColumnPlan {
    /// Resolves and checks the selection, assembles K and factorises it, with the method of
    /// [`method`] (for the Gram method, `W` is computed here).
    pub fn new(mesh: &Mesh, sel: &Selection) -> Result<ColumnPlan, FemError> {
        Self::with_method(mesh, sel, method())
    }

    /// As [`ColumnPlan::new`] with the method `how`.
    pub(crate) fn with_method(
        mesh: &Mesh,
        sel: &Selection,
        how: Method,
    ) -> Result<ColumnPlan, FemError> {
        Self::with_method_in(mesh, sel, how, &factor_store())
    }

    /// As [`ColumnPlan::with_method`] with the factor kept where `store` says.
    pub(crate) fn with_method_in(
        mesh: &Mesh,
        sel: &Selection,
        how: Method,
        store: &crate::fem::FactorStore,
    ) -> Result<ColumnPlan, FemError> {
        let t0 = Instant::now();
        let n = mesh.nodes.len();
        let cols = sel.cols.resolve(mesh);
        let mut rows = sel.rows.resolve(mesh);
        let mut row_of_node = vec![u32::MAX; n];
        let mut col_of_node = vec![u32::MAX; n];
        for (ci, &c) in cols.iter().enumerate() {
            if c as usize >= n {
                return Err(FemError::BadSelection(format!(
                    "touchable node {c} does not exist ({n} nodes)"
                )));
            }
            if mesh.fixed[c as usize] {
                return Err(FemError::BadSelection(format!(
                    "touchable node {c} is clamped"
                )));
            }
            if col_of_node[c as usize] != u32::MAX {
                return Err(FemError::BadSelection(format!("node {c} selected twice")));
            }
            col_of_node[c as usize] = ci as u32;
        }
        for (ri, &r) in rows.iter().enumerate() {
            if r as usize >= n || row_of_node[r as usize] != u32::MAX {
                return Err(FemError::BadSelection(format!(
                    "displayed node {r} is out of range or repeated"
                )));
            }
            row_of_node[r as usize] = ri as u32;
        }
        for &c in &cols {
            if row_of_node[c as usize] == u32::MAX {
                row_of_node[c as usize] = rows.len() as u32;
                rows.push(c);
            }
        }
        // Free rows first: the clamped ones hold no `L`.
        let (mut free, clamped): (Vec<u32>, Vec<u32>) =
            rows.iter().partition(|&&r| !mesh.fixed[r as usize]);
        let l_rows = free.len();
        free.extend(clamped);
        rows = free;
        for (i, &r) in rows.iter().enumerate() {
            row_of_node[r as usize] = i as u32;
        }
        let mut phases = PhaseTimes::default();
        let stiff = Stiffness::assemble(mesh)?;
        phases.assemble_s = t0.elapsed().as_secs_f64();
        let (factor, sym_s, num_s) = stiff.factorize_in(ordering(), store)?;
        phases.factor_in_file = factor.is_mapped();
        phases.front_bytes = factor.front_bytes();
        phases.symbolic_s = sym_s;
        phases.numeric_s = num_s;
        phases.factor_nonzeros = factor.nonzeros();
        phases.column_flops = 12.0 * cols.len() as f64 * factor.nonzeros() as f64;
        phases.method = "columns".into();
        let mut cols = cols;
        let mut gram = None;
        if how != Method::Columns && how != Method::Full {
            let shown: Vec<u32> = rows
                .iter()
                .copied()
                .filter(|&r| !mesh.fixed[r as usize])
                .collect();
            if let Some(g) = crate::gram::GramPlan::new(&factor, &stiff.dofs, &shown, &cols) {
                phases.gram_flops = g.forward_flops + g.gram_flops;
                if how == Method::Gram || phases.gram_flops < 0.7 * phases.column_flops {
                    let tf = Instant::now();
                    if let Some(w) = g.forward(&factor, solver_threads()) {
                        phases.forward_s = tf.elapsed().as_secs_f64();
                        phases.w_bytes = g.w_bytes();
                        phases.method = "gram".into();
                        cols = g.touchable();
                        if g.symmetric() {
                            // Rows in Gram order (then the clamped ones): the columns are the
                            // first rows, and a tile's upper rows mirror earlier tiles.
                            let mut r = g.nodes().to_vec();
                            r.extend(rows.iter().filter(|&&n| mesh.fixed[n as usize]));
                            rows = r;
                            for (i, &n) in rows.iter().enumerate() {
                                row_of_node[n as usize] = i as u32;
                            }
                        }
                        let row_of: Vec<u32> =
                            g.nodes().iter().map(|&n| row_of_node[n as usize]).collect();
                        gram = Some((g, w, row_of));
                    }
                }
            }
        }
        let units = if gram.is_none() && how != Method::Full {
            let d = &stiff.dofs;
            crate::gram::UnitSolver::new(
                &factor,
                rows.iter()
                    .flat_map(|&r| (0..3).filter_map(move |a| d.free(r, a))),
            )
        } else {
            None
        };
        let sweeper = if units.is_none() && factor.is_mapped() {
            crate::gram::UnitSolver::new(&factor, std::iter::empty())
        } else {
            None
        };
        Ok(ColumnPlan {
            rows,
            l_rows,
            cols,
            phases,
            stiff,
            factor,
            units,
            sweeper,
            gram,
            mirror_from: None,
            pool: std::sync::Mutex::new(Vec::new()),
        })
    }

    /// For a symmetric plan (every displayed free node touchable, Gram method), promises
    /// that the batches from column `first` on will all be at hand after [`ColumnPlan::solve`]:
    /// the solve then leaves a batch's rows `first .. its first column` zero, and
    /// [`ColumnPlan::mirror`] fills them from those batches' lower rows, halving the products.
    /// Returns whether the plan is symmetric (otherwise the batches come out complete).
    pub(crate) fn mirror_from(&mut self, first: usize) -> bool {
        let sym = self.gram.as_ref().is_some_and(|g| g.0.symmetric());
        self.mirror_from = sym.then_some(first);
        sym
    }

    /// Fills the rows left for mirroring in batch `b`'s `data` (see
    /// [`ColumnPlan::mirror_from`]): `read(dof column q, first row, out)` must give rows
    /// `first .. first + out.len()` of DOF column `q` of an earlier batch. Returns the DOF
    /// rows filled.
    pub fn mirror<E>(
        &self,
        b: usize,
        data: &mut [f64],
        read: &mut ReadRows<'_, E>,
    ) -> Result<std::ops::Range<usize>, E> {
        let rows = self.mirror_rows(b);
        let chunk = self.batch_cols(b);
        let nr3 = 3 * self.l_rows;
        let k = 3 * chunk.len();
        let mut vals = vec![0.0f64; k];
        for q in rows.clone() {
            read(q, 3 * chunk.start, &mut vals)?;
            for (j, v) in vals.iter().enumerate() {
                data[j * nr3 + q] = *v;
            }
        }
        Ok(rows)
    }

    /// The DOF rows of batch `b` that [`ColumnPlan::mirror`] fills (empty unless the plan
    /// mirrors): the solve leaves them zero, so a first write may skip them.
    pub(crate) fn mirror_rows(&self, b: usize) -> std::ops::Range<usize> {
        let Some(first) = self.mirror_from else {
            return 0..0;
        };
        let start = self.batch_cols(b).start;
        3 * first.min(start)..3 * start
    }

    /// Free DOFs of K.
    pub fn free_dofs(&self) -> usize {
        self.stiff.dofs.n_free
    }

    /// Number of column batches.
    pub fn batches(&self) -> usize {
        self.cols.len().div_ceil(BATCH_COLS)
    }

    /// The column indices of batch `b`.
    pub(crate) fn batch_cols(&self, b: usize) -> std::ops::Range<usize> {
        let lo = (b * BATCH_COLS).min(self.cols.len());
        lo..(lo + BATCH_COLS).min(self.cols.len())
    }

    /// A zeroed batch buffer of `len` values, reused from the pool when one is there. A 45k
    /// mesh's batch is 46 MB, above glibc's largest `mmap` threshold (32 MB): each fresh one
    /// came from new pages (17.5k nodes with every large allocation mapped: 14.3 → 17.6–18.6 s).
    fn buffer(&self, len: usize) -> Vec<f64> {
        let mut v = self
            .pool
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop()
            .unwrap_or_default();
        v.clear();
        v.resize(len, 0.0);
        v
    }

    /// Hands a batch buffer back for the next batches.
    fn give_back(&self, v: Vec<f64>) {
        self.pool.lock().unwrap_or_else(|e| e.into_inner()).push(v);
    }

    /// Solves the batches `batches` (indices on the batch grid) on all cores. For each batch, `sink(b, data)` receives its
    /// slice of L (`9·R'·batch columns` f64, R' = [`ColumnPlan::l_rows`], this module's layout) from whichever worker solved
    /// it; a sink returning `false` stops the work (the caller keeps its own error). Returns
    /// max |K·x − e| over one checked DOF column per batch and the slowest worker's seconds
    /// solving, checking and scattering. `progress(columns done)` is called on the calling
    /// thread now and then.
    pub fn solve(
        &self,
        batches: &[usize],
        sink: &(dyn Fn(usize, &mut [f64]) -> bool + Sync),
        progress: &mut dyn FnMut(usize),
    ) -> Result<(f64, [f64; 3]), FemError> {
        self.solve_until(
            batches,
            sink,
            progress,
            &std::sync::atomic::AtomicBool::new(false),
        )
    }

    /// As [`ColumnPlan::solve`], with the stop flag the caller's: it is set when a sink
    /// returns `false` or a worker fails, and a sink that waits for another batch must give
    /// up when it is set. Workers take `batches` in the order given.
    pub(crate) fn solve_until(
        &self,
        batches: &[usize],
        sink: &(dyn Fn(usize, &mut [f64]) -> bool + Sync),
        progress: &mut dyn FnMut(usize),
        stop: &std::sync::atomic::AtomicBool,
    ) -> Result<(f64, [f64; 3]), FemError> {
        if let Some(u) = &self.units {
            return self.solve_pruned(batches, sink, progress, stop, u);
        }
        let workers = solver_threads().min(batches.len().max(1));
        let next = std::sync::atomic::AtomicUsize::new(0);
        let done = std::sync::atomic::AtomicUsize::new(0);
        let work = |progress: &mut dyn FnMut(usize)| -> Result<(f64, [f64; 3]), FemError> {
            use std::sync::atomic::Ordering::Relaxed;
            let mut acc = (0.0f64, [0.0f64; 3]);
            loop {
                if stop.load(Relaxed) {
                    return Ok(acc);
                }
                let Some(&b) = batches.get(next.fetch_add(1, Relaxed)) else {
                    return Ok(acc);
                };
                let (res, t, mut data) = self.solve_batch(b).inspect_err(|_| {
                    stop.store(true, Relaxed);
                })?;
                acc.0 = acc.0.max(res);
                for (a, v) in acc.1.iter_mut().zip(t) {
                    *a += v;
                }
                if !sink(b, &mut data) {
                    stop.store(true, Relaxed);
                }
                self.give_back(data);
                let d = done.fetch_add(self.batch_cols(b).len(), Relaxed);
                progress(d + self.batch_cols(b).len());
            }
        };
        run_workers(workers, &work, progress)
    }

    /// [`ColumnPlan::solve_until`] for the column method's pruned sweeps: the work is shared
    /// out by groups of [`SOLVE_COLS`] column nodes, not whole batches, so a few batches keep
    /// every core busy (the 45k organ's ball: 5 batches, 10 groups). A batch goes to the sink
    /// once its last group is in, from the worker that solved that group, after its first
    /// column's check.
    fn solve_pruned(
        &self,
        batches: &[usize],
        sink: &(dyn Fn(usize, &mut [f64]) -> bool + Sync),
        progress: &mut dyn FnMut(usize),
        stop: &std::sync::atomic::AtomicBool,
        u: &crate::gram::UnitSolver,
    ) -> Result<(f64, [f64; 3]), FemError> {
        use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
        let groups = |b: usize| self.batch_cols(b).len().div_ceil(SOLVE_COLS);
        let units: Vec<(usize, usize)> = batches
            .iter()
            .enumerate()
            .flat_map(|(i, &b)| (0..groups(b)).map(move |g| (i, g)))
            .collect();
        // Each batch's slice of L while its groups come in, and the groups still out.
        let pending: Vec<(std::sync::Mutex<Vec<f64>>, AtomicUsize)> = batches
            .iter()
            .map(|&b| {
                (
                    std::sync::Mutex::new(Vec::new()),
                    AtomicUsize::new(groups(b)),
                )
            })
            .collect();
        let workers = solver_threads().min(units.len().max(1));
        let next = AtomicUsize::new(0);
        let done = AtomicUsize::new(0);
        // Rows of a solve: every unknown of the system (a mixed one's pressures too).
        let (nr, nf) = (self.l_rows, self.stiff.n());
        let per = 3 * SOLVE_COLS;
        let work = |progress: &mut dyn FnMut(usize)| -> Result<(f64, [f64; 3]), FemError> {
            let mut acc = (0.0f64, [0.0f64; 3]);
            let mut x = Mat::<f64>::zeros(nf, 0);
            loop {
                if stop.load(Relaxed) {
                    return Ok(acc);
                }
                let Some(&(i, g)) = units.get(next.fetch_add(1, Relaxed)) else {
                    return Ok(acc);
                };
                let b = batches[i];
                let chunk = self.batch_cols(b);
                let mut dofs = Vec::with_capacity(per);
                for ci in chunk.clone().skip(g * SOLVE_COLS).take(SOLVE_COLS) {
                    for a in 0..3 {
                        dofs.push(self.first_dof(self.cols[ci])? + a);
                    }
                }
                let ts = Instant::now();
                if x.ncols() < dofs.len() {
                    x = Mat::zeros(nf, per);
                } else {
                    x.fill(0.0);
                }
                let mut xg = x.as_mut().subcols_mut(0, dofs.len());
                u.solve(&self.factor, &dofs, xg.rb_mut());
                acc.1[0] += ts.elapsed().as_secs_f64();
                let tsc = Instant::now();
                {
                    let mut out = pending[i].0.lock().unwrap_or_else(|e| e.into_inner());
                    if out.is_empty() {
                        *out = self.buffer(9 * nr * chunk.len());
                    }
                    for jj in 0..dofs.len() {
                        let xc = xg.rb().col(jj);
                        let j = g * per + jj;
                        self.scatter_rows(|d| xc[u.row(d)], &mut out[j * 3 * nr..][..3 * nr])
                            .inspect_err(|_| stop.store(true, Relaxed))?;
                    }
                }
                acc.1[2] += tsc.elapsed().as_secs_f64();
                if pending[i].1.fetch_sub(1, Relaxed) != 1 {
                    continue;
                }
                // The batch's last group: check its first column, hand it over.
                let mut out =
                    std::mem::take(&mut *pending[i].0.lock().unwrap_or_else(|e| e.into_inner()));
                let tc = Instant::now();
                let node = self.cols[chunk.start];
                let (xs, residual) = self
                    .check_solve(node)
                    .and_then(|(xs, r)| self.agrees(&out, &xs, |_| true, node).map(|_| (xs, r)))
                    .inspect_err(|_| stop.store(true, Relaxed))?;
                drop(xs);
                acc.1[1] += tc.elapsed().as_secs_f64();
                acc.0 = acc.0.max(residual);
                if !sink(b, &mut out) {
                    stop.store(true, Relaxed);
                }
                self.give_back(out);
                let d = done.fetch_add(chunk.len(), Relaxed);
                progress(d + chunk.len());
            }
        };
        run_workers(workers, &work, progress)
    }

    /// Products with blocks of `L` through the Gram method's `W` (`None` without it).
    pub(crate) fn gram_products(&self) -> Option<GramProducts<'_>> {
        let (gp, w, row_of) = self.gram.as_ref()?;
        let mut pos_of_row = vec![usize::MAX; self.rows.len()];
        for (g, &r) in row_of.iter().enumerate() {
            pos_of_row[r as usize] = g;
        }
        let at: std::collections::HashMap<u32, usize> =
            self.rows.iter().enumerate().map(|(i, &n)| (n, i)).collect();
        let pos_of_col = self
            .cols
            .iter()
            .map(|n| at.get(n).map(|&r| pos_of_row[r]))
            .collect::<Option<Vec<usize>>>()?;
        if pos_of_col.contains(&usize::MAX) {
            return None;
        }
        Some(GramProducts {
            gp,
            w,
            pos_of_row,
            pos_of_col,
        })
    }

    /// The columns `want` (column indices, any order) of `L` for the hierarchical build, on
    /// all cores: `3R' × 3|want|` column-major (R' = [`ColumnPlan::l_rows`], rows by index),
    /// column `3q + b` for `want[q]` axis `b`. With `check`, the first column is checked
    /// against a direct solve. Returns the columns, the check's residual and the seconds solving, checking and
    /// scattering (summed over workers).
    ///
    /// The columns come in groups (ranges of `want` covering it), each with the rows it needs
    /// (`None`: all): the Gram method's tiles then compute only those rows (the other methods
    /// solve every row); the first column's rows of its group are the ones checked.
    pub(crate) fn solve_col_groups(
        &self,
        want: &[u32],
        parts: &[(std::ops::Range<usize>, Option<Vec<bool>>)],
        check: bool,
    ) -> Result<(Vec<f64>, f64, [f64; 3]), FemError> {
        use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
        let nr = self.l_rows;
        let ld = 3 * nr;
        if want.iter().any(|&c| c as usize >= self.cols.len()) {
            return Err(FemError::BadSelection(
                "a column index is out of range".into(),
            ));
        }
        if parts.iter().map(|p| p.0.len()).sum::<usize>() != want.len()
            || parts.iter().any(|p| p.0.end > want.len())
            || parts
                .iter()
                .any(|p| p.1.as_ref().is_some_and(|n| n.len() < self.l_rows))
        {
            return Err(FemError::BadSelection(
                "column groups do not cover the columns".into(),
            ));
        }
        // Groups of columns solved together; the Gram tiles want ascending indices.
        let mut order: Vec<usize> = (0..want.len()).collect();
        let per = if self.gram.is_some() {
            BATCH_COLS
        } else {
            SOLVE_COLS
        };
        let mut groups: Vec<(&[usize], usize)> = Vec::new();
        for (r, _) in parts {
            let o = &mut order[r.clone()];
            if self.gram.is_some() {
                o.sort_by_key(|&q| want[q]);
            }
        }
        for (pi, (r, _)) in parts.iter().enumerate() {
            // A part of the caller's is one group when it is not much wider than a batch.
            let per = if r.len() <= 2 * per {
                r.len().max(1)
            } else {
                per
            };
            groups.extend(order[r.clone()].chunks(per).map(|g| (g, pi)));
        }
        // The rows wanted, in the Gram plan's node order (the other methods solve every row).
        let gram_rows: Vec<Option<Vec<bool>>> = parts
            .iter()
            .map(|(_, need)| match (&self.gram, need) {
                (Some((_, _, row_of)), Some(need)) => {
                    Some(row_of.iter().map(|&r| need[r as usize]).collect())
                }
                _ => None,
            })
            .collect();
        let next = AtomicUsize::new(0);
        let work = || -> Result<GroupsSolved, FemError> {
            let mut got = Vec::new();
            let mut t = [0.0f64; 3];
            loop {
                let gi = next.fetch_add(1, Relaxed);
                let Some(&(g, pi)) = groups.get(gi) else {
                    return Ok((got, t));
                };
                let cols: Vec<usize> = g.iter().map(|&q| want[q] as usize).collect();
                let mut out = vec![0.0f64; ld * 3 * cols.len()];
                let ts = Instant::now();
                if let Some((gp, w, row_of)) = &self.gram {
                    let m = 3 * gp.nodes().len();
                    let mut tile = vec![0.0f64; m * 3 * cols.len()];
                    gp.tile_cols(w, &cols, gram_rows[pi].as_deref(), &mut tile, m);
                    t[0] += ts.elapsed().as_secs_f64();
                    let tsc = Instant::now();
                    for j in 0..3 * cols.len() {
                        let (src, dst) = (&tile[j * m..][..m], &mut out[j * ld..][..ld]);
                        for (gi, &ri) in row_of.iter().enumerate() {
                            for a in 0..3 {
                                let v = src[3 * gi + a];
                                if !v.is_finite() {
                                    return Err(FemError::Singular {
                                        node: gp.nodes()[gi],
                                        dof: a,
                                    });
                                }
                                dst[3 * ri as usize + a] = v;
                            }
                        }
                    }
                    t[2] += tsc.elapsed().as_secs_f64();
                } else {
                    let nf = self.stiff.n();
                    let mut dofs = Vec::with_capacity(3 * cols.len());
                    for &ci in &cols {
                        let d = self.first_dof(self.cols[ci])?;
                        dofs.extend([d, d + 1, d + 2]);
                    }
                    let mut x = Mat::<f64>::zeros(nf, dofs.len());
                    match &self.units {
                        Some(u) => u.solve(&self.factor, &dofs, x.as_mut()),
                        None => {
                            for (j, &d) in dofs.iter().enumerate() {
                                x[(d, j)] = 1.0;
                            }
                            self.factor.solve_in_place(&mut x);
                        }
                    }
                    t[0] += ts.elapsed().as_secs_f64();
                    let tsc = Instant::now();
                    for j in 0..dofs.len() {
                        let xc = x.col(j);
                        let dst = &mut out[j * ld..][..ld];
                        match &self.units {
                            Some(u) => self.scatter_rows(|d| xc[u.row(d)], dst)?,
                            None => self.scatter_rows(|d| xc[d], dst)?,
                        }
                    }
                    t[2] += tsc.elapsed().as_secs_f64();
                }
                got.push((gi, out));
            }
        };
        let workers = solver_threads().min(groups.len()).max(1);
        let results: Vec<_> = std::thread::scope(|sc| {
            let hs: Vec<_> = (1..workers).map(|_| sc.spawn(work)).collect();
            let mut r = vec![work()];
            for h in hs {
                r.push(h.join().unwrap_or_else(|_| {
                    Err(FemError::Factorisation("a solver thread panicked".into()))
                }));
            }
            r
        });
        let mut out = vec![0.0f64; ld * 3 * want.len()];
        let mut times = [0.0f64; 3];
        for r in results {
            let (got, t) = r?;
            for (a, v) in times.iter_mut().zip(t) {
                *a += v;
            }
            for (gi, data) in got {
                for (k, &q) in groups[gi].0.iter().enumerate() {
                    out[3 * q * ld..][..3 * ld].copy_from_slice(&data[3 * k * ld..][..3 * ld]);
                }
            }
        }
        let mut residual = 0.0;
        if let Some((r0, need)) = parts.iter().find(|p| check && !p.0.is_empty()) {
            let tc = Instant::now();
            let q0 = r0.start;
            let node = self.cols[want[q0] as usize];
            let (xs, r) = self.check_solve(node)?;
            let at = &out[3 * q0 * ld..][..3 * ld];
            self.agrees(at, &xs, |ri| need.as_ref().is_none_or(|n| n[ri]), node)?;
            residual = r;
            times[1] += tc.elapsed().as_secs_f64();
        }
        Ok((out, residual, times))
    }

    /// Solves one batch: its slice of L, the residual of its checked column and the seconds
    /// spent solving, checking and scattering.
    fn solve_batch(&self, batch: usize) -> Result<(f64, [f64; 3], Vec<f64>), FemError> {
        if let Some((g, w, row_of)) = &self.gram {
            return self.gram_batch(batch, g, w, row_of);
        }
        let nr = self.l_rows;
        let nf = self.stiff.n();
        let chunk = self.batch_cols(batch);
        let mut times = [0.0f64; 3];
        let mut b = Mat::<f64>::zeros(nf, 3 * chunk.len());
        for (k, ci) in chunk.clone().enumerate() {
            for a in 0..3 {
                let d = self
                    .stiff
                    .dofs
                    .free(self.cols[ci], a)
                    .ok_or(FemError::BadSelection("a touchable node is clamped".into()))?;
                b[(d, 3 * k + a)] = 1.0;
            }
        }
        let ts = Instant::now();
        self.factor.solve_in_place(&mut b);
        times[0] += ts.elapsed().as_secs_f64();
        let tc = Instant::now();
        // The check K·x = e costs about as much as a solve per column: it is done on one DOF
        // column per batch (the batch's first), which catches a bad factorisation all the same.
        let residual = {
            let node = self.cols[chunk.start];
            let e = self.first_dof(node)?;
            let xs: Vec<f64> = (0..nf).map(|i| b[(i, 0)]).collect();
            if xs.iter().any(|v| !v.is_finite()) {
                return Err(FemError::Singular { node, dof: e });
            }
            self.unit_residual(&xs, e)
        };
        times[1] += tc.elapsed().as_secs_f64();
        let tsc = Instant::now();
        let mut out = self.buffer(9 * nr * chunk.len());
        for j in 0..3 * chunk.len() {
            let x = b.col(j);
            self.scatter_rows(|d| x[d], &mut out[j * 3 * nr..][..3 * nr])?;
        }
        times[2] += tsc.elapsed().as_secs_f64();
        Ok((residual, times, out))
    }

    /// One DOF column of `L` into `dst` (3R', this module's layout): each stored row's
    /// entries from `x(free DOF)`; a non-finite value is [`FemError::Singular`].
    fn scatter_rows(&self, x: impl Fn(usize) -> f64, dst: &mut [f64]) -> Result<(), FemError> {
        for (ri, &r) in self.rows[..self.l_rows].iter().enumerate() {
            for a in 0..3 {
                if let Some(d) = self.stiff.dofs.free(r, a) {
                    let v = x(d);
                    if !v.is_finite() {
                        return Err(FemError::Singular { node: r, dof: d });
                    }
                    dst[3 * ri + a] = v;
                }
            }
        }
        Ok(())
    }

    /// Checks that the batch's first column `out` (this module's layout) equals the direct
    /// solve `xs` on the displayed rows `keep(row)` accepts, to 1e-8 of max |x|.
    fn agrees(
        &self,
        out: &[f64],
        xs: &[f64],
        keep: impl Fn(usize) -> bool,
        node: u32,
    ) -> Result<(), FemError> {
        let scale = xs.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let mut diff = 0.0f64;
        for (ri, &r) in self.rows[..self.l_rows].iter().enumerate() {
            if !keep(ri) {
                continue; // mirrored later, or not wanted
            }
            for a in 0..3 {
                if let Some(d) = self.stiff.dofs.free(r, a) {
                    diff = diff.max((out[3 * ri + a] - xs[d]).abs());
                }
            }
        }
        if diff.is_nan() || diff > 1e-8 * scale {
            return Err(FemError::Factorisation(format!(
                "the computed column disagrees with a direct solve by {:.1e} of max |L| \
                 (column of node {node})",
                diff / scale
            )));
        }
        Ok(())
    }

    /// The free DOF of a touchable node's x axis.
    fn first_dof(&self, node: u32) -> Result<usize, FemError> {
        self.stiff
            .dofs
            .free(node, 0)
            .ok_or(FemError::BadSelection("a touchable node is clamped".into()))
    }

    /// faer's full solve of `K x = e` for `node`'s x axis, and its residual max |K·x − e|:
    /// the independent check of the pruned and Gram batches.
    fn check_solve(&self, node: u32) -> Result<(Vec<f64>, f64), FemError> {
        let e = self.first_dof(node)?;
        let nf = self.stiff.n();
        let mut b = Mat::<f64>::zeros(nf, 1);
        let sweeps = self.units.as_ref().or(self.sweeper.as_ref());
        let xs: Vec<f64> = match sweeps.filter(|_| self.factor.is_mapped()) {
            // A factor in a file: a sweep that drops the pages behind it (faer's solve
            // would map the whole factor into this process).
            Some(u) => {
                u.solve_full(&self.factor, &[e], b.as_mut());
                (0..nf).map(|d| b[(u.row(d), 0)]).collect()
            }
            None => {
                b[(e, 0)] = 1.0;
                self.factor.solve_in_place(&mut b);
                (0..nf).map(|i| b[(i, 0)]).collect()
            }
        };
        let residual = self.unit_residual(&xs, e);
        Ok((xs, residual))
    }

    /// max |K·x − e_e| for a solution `x` of K·x = e_e.
    fn unit_residual(&self, x: &[f64], e: usize) -> f64 {
        let mut kx = vec![0.0; x.len()];
        self.stiff.mul(x, &mut kx);
        kx.iter().enumerate().fold(0.0f64, |r, (i, v)| {
            let target = if i == e { 1.0 } else { 0.0 };
            r.max((v - target).abs())
        })
    }

    /// The Gram method's batch: its tile of `(K⁻¹)[S, T]` moved into this module's layout;
    /// every [`GRAM_CHECK_EVERY`]th batch compares its first column with a direct solve.
    fn gram_batch(
        &self,
        batch: usize,
        g: &crate::gram::GramPlan,
        w: &[f64],
        row_of: &[u32],
    ) -> Result<(f64, [f64; 3], Vec<f64>), FemError> {
        let nr = self.l_rows;
        let chunk = self.batch_cols(batch);
        let mut times = [0.0f64; 3];
        let m = 3 * g.nodes().len();
        let nt = 3 * chunk.len();
        let ts = Instant::now();
        let skip = match self.mirror_from {
            Some(first) => first.min(chunk.start)..chunk.start,
            None => 0..0,
        };
        let mut out = self.buffer(9 * nr * chunk.len());
        // Rows in Gram order (symmetric plans): the products land in the batch itself.
        let in_order = row_of.iter().enumerate().all(|(g, &r)| g == r as usize);
        if in_order {
            g.tile(w, chunk.start, chunk.end, skip.clone(), &mut out, 3 * nr);
            times[0] = ts.elapsed().as_secs_f64();
            if let Some(i) = out.iter().position(|v| !v.is_finite()) {
                let gi = (i % (3 * nr)) / 3;
                return Err(FemError::Singular {
                    node: self.rows[gi],
                    dof: i % 3,
                });
            }
        }
        let mut tile = Vec::new();
        if !in_order {
            tile.resize(m * nt, 0.0f64);
            g.tile(w, chunk.start, chunk.end, skip.clone(), &mut tile, m);
            times[0] = ts.elapsed().as_secs_f64();
        }
        let tsc = Instant::now();
        // Otherwise each row moves to its place in this module's layout.
        for j in (0..nt).filter(|_| !in_order) {
            let src = &tile[j * m..][..m];
            let dst = &mut out[j * 3 * nr..][..3 * nr];
            for (gi, &ri) in row_of.iter().enumerate() {
                for a in 0..3 {
                    let v = src[3 * gi + a];
                    if !v.is_finite() {
                        return Err(FemError::Singular {
                            node: g.nodes()[gi],
                            dof: a,
                        });
                    }
                    dst[3 * ri as usize + a] = v;
                }
            }
        }
        times[2] = tsc.elapsed().as_secs_f64();
        let tc = Instant::now();
        let mut residual = 0.0f64;
        if batch.is_multiple_of(GRAM_CHECK_EVERY) {
            let node = self.cols[chunk.start];
            let (xs, r) = self.check_solve(node)?;
            residual = r;
            // The Gram column must be the direct solve's displayed rows.
            self.agrees(&out, &xs, |ri| !skip.contains(&ri), node)?;
        }
        times[1] = tc.elapsed().as_secs_f64();
        Ok((residual, times, out))
    }
}
