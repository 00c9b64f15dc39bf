//! A hierarchical compliance: `L` stored as a block partition whose far blocks are low-rank
//! factors truncated to a chosen tolerance and whose near blocks are dense.
//!
//! # Construction
//! * **Cluster trees** over the row nodes and the column nodes, a node's 3 DOFs together: the
//!   bounding box of a cluster's nodes is bisected at its midpoint along its longest axis until
//!   a cluster holds at most [`HOptions::leaf_size`] nodes. A cluster is a contiguous range of
//!   its tree's permutation. When rows and columns are the same points (a whole-surface
//!   selection) there is one tree.
//! * **Block partition** by the standard admissibility `min(diam τ, diam σ) ≤ η·dist(τ, σ)`
//!   (bounding boxes; `dist > 0`): an admissible (far) pair is one block unless a side is wider
//!   than a panel ([`HOptions::panel_size`]), then that side is split; an inadmissible pair is
//!   split (both clusters, or the one that is not a leaf) until both are leaves, when it is a
//!   near block, stored dense. With one tree the partition is symmetric: only the blocks on
//!   and below the diagonal are solved, compressed and saved; each block above is the
//!   transpose of its mirror, made when the panels are joined (same error, same norm).
//! * **Panels** ([`HPlan`]): the largest column clusters of at most `panel_size` nodes. A
//!   panel's columns of `L` are solved together (only the rows its stored blocks need), its
//!   blocks compressed ([`HPlan::compress_panel`]), and the columns dropped, so the dense `L`
//!   is never held; shards are runs of panels ([`HMatrix::from_panels`] joins them).
//! * **Compression** of a far block `B` (3|τ| × 3|σ|) from its values: a randomized range
//!   finder (16 Gaussian test vectors at a time, seeded by the block's position) until
//!   `‖B − QQᵀB‖_F² ≤ ½ε²‖B‖_F²`, then the SVD of the small `QᵀB` truncated within the rest of
//!   the budget; the error `‖B − UVᵀ‖_F` is then measured on the block itself. A block over
//!   budget (rounding) or whose factors would take more room than the block stays dense.
//!   Stored as `U` (singular values folded in) and `V`.
//! * **Sketching** ([`HPlan::compress_panel_with`], [`BlockProducts`]): with the Gram method's
//!   `W` at hand, a far block for which `2k + p` vectors cost less than its `3|σ|` columns is
//!   never formed. `Y = BΩ` (`k` Gaussian vectors and `p` = 10 held-out probes) and `BᵀQ`
//!   (`Q` an orthonormal basis of the first `k` columns of `Y`) come from two products through
//!   `W` over the supernodes both clusters reach (`GramPlan::apply`); the probes estimate the
//!   residual `‖(I − QQᵀ)B‖_F²`, which is charged ten times to the budget (`k` doubled while
//!   it takes more than half); the SVD of `QᵀB` is truncated within the rest. `‖B‖_F²` is
//!   `‖QᵀB‖_F²` plus the estimate.
//!
//! # Guarantee
//! * Per far block: `‖B − UVᵀ‖_F ≤ ε‖B‖_F` — measured for a block compressed from its values;
//!   for a sketched block it holds unless the probes underestimate the residual more than
//!   tenfold, which for 10 Gaussian probes has probability below 2·10⁻⁴ per block (`χ²₁₀ < 1`);
//!   an underestimate by `f > 10` lets the block's error reach at most `√(1 + f/20)·ε‖B‖_F`.
//! * Globally: the blocks partition `L` and near blocks are exact, so
//!   `‖L − L_H‖_F² = Σ_far ‖B − UVᵀ‖_F² ≤ ε² Σ_far ‖B‖_F² ≤ ε²‖L‖_F²`, i.e.
//!   `‖L − L_H‖_F ≤ ε‖L‖_F`. [`HMatrix::truncation_error`] is that left-hand side, measured
//!   for blocks compressed from their values and estimated (unbiased) for sketched ones.
//! * Per point load `f` at one column: `‖Δu‖₂ ≤ ‖L − L_H‖₂·|f| ≤ ε‖L‖_F·|f|` (relative to `‖L‖_F`,
//!   not to `‖u‖`: the relative error of one load is measured, not bounded).
//!
//! Factors are held in f64; [`HMatrix::bytes_f32`] is what an f32 copy takes. The compliance
//! module builds one from the factor's solves (`Compliance::compute_hier`) or from a dense `L`
//! (`Compliance::compress`).

use std::ops::Range;

use faer::reborrow::ReborrowMut;
use glam::{DMat3, DVec3};

use tree::ClusterTree;

pub(crate) mod compress;
mod plan;
mod tree;

/// Why a hierarchical compliance cannot be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum HError {
    /// The tolerance is not a number in (0, 1).
    #[error("the tolerance must be in (0, 1), got {0}")]
    Tolerance(f64),
    /// The admissibility parameter is not a finite positive number.
    #[error("the admissibility η must be finite and positive, got {0}")]
    Eta(f64),
    /// A leaf size of zero, or panels smaller than leaves.
    #[error("the cluster leaf size must be at least 1 and at most the panel size")]
    LeafSize,
    /// No row or no column.
    #[error("nothing to compress: {rows} rows × {cols} columns")]
    Empty {
        /// Row nodes.
        rows: usize,
        /// Column nodes.
        cols: usize,
    },
    /// A node position that is not finite.
    #[error("{which} point {index} is not finite")]
    Point {
        /// `row` or `column`.
        which: &'static str,
        /// Its index.
        index: usize,
    },
    /// Fewer output rows than row nodes.
    #[error("{out_rows} output rows cannot hold {rows} row nodes")]
    OutRows {
        /// Output rows asked for.
        out_rows: usize,
        /// Row nodes.
        rows: usize,
    },
    /// The compliance does not hold a dense `L` on the host.
    #[error("the compliance does not hold L on the host (a lean compliance)")]
    NotHeld,
    /// The compliance carries a cut's correction.
    #[error("the compliance carries a cut's correction: fold it first")]
    Correction,
    /// A compliance node is not a node of the mesh given.
    #[error("node {node} is not in the mesh ({nodes} nodes)")]
    Node {
        /// The node index.
        node: u32,
        /// The mesh's node count.
        nodes: usize,
    },
    /// The block source gave a matrix of the wrong shape.
    #[error("the block source gave a {got:?} matrix for a {want:?} block")]
    BlockShape {
        /// Rows × columns expected.
        want: (usize, usize),
        /// Rows × columns given.
        got: (usize, usize),
    },
    /// The block source gave a non-finite entry.
    #[error("the block source gave a non-finite entry")]
    NonFinite,
    /// A panel index out of range.
    #[error("panel {0} of {1}")]
    Panel(usize, usize),
    /// Not every panel of the plan, exactly once.
    #[error("{got} panels for a plan of {want}")]
    Panels {
        /// Panels of the plan.
        want: usize,
        /// Panels given.
        got: usize,
    },
    /// A panel's ranks or values do not fit its blocks.
    #[error("panel {0}'s blocks do not match the plan")]
    PanelData(usize),
    /// The SVD of a block did not converge.
    #[error("the SVD of a {0}×{1} block did not converge")]
    Svd(usize, usize),
}

/// How to build an [`HMatrix`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HOptions {
    /// Relative Frobenius tolerance ε of each far block, in (0, 1).
    pub tolerance: f64,
    /// Admissibility η: a pair is far when `min(diam) ≤ η·dist`.
    pub eta: f64,
    /// Most nodes in a leaf cluster.
    pub leaf_size: usize,
    /// Most column nodes of a panel: the columns solved and compressed together, and the
    /// widest far block (at least `leaf_size`).
    pub panel_size: usize,
}

impl HOptions {
    /// Tolerance `tolerance`, η = 2, leaves of 32 nodes, panels of up to 512.
    pub fn new(tolerance: f64) -> HOptions {
        HOptions {
            tolerance,
            eta: 2.0,
            leaf_size: 32,
            panel_size: 512,
        }
    }

    /// Checks each option's range.
    pub fn check(&self) -> Result<(), HError> {
        if !(self.tolerance > 0.0 && self.tolerance < 1.0) {
            return Err(HError::Tolerance(self.tolerance));
        }
        if !(self.eta.is_finite() && self.eta > 0.0) {
            return Err(HError::Eta(self.eta));
        }
        if self.leaf_size == 0 || self.panel_size < self.leaf_size {
            return Err(HError::LeafSize);
        }
        Ok(())
    }
}

/// One block of the partition, as [`HMatrix::blocks`] describes it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BlockInfo {
    /// Row-node positions (in [`HMatrix::row_perm`]).
    pub rows: Range<usize>,
    /// Column-node positions (in [`HMatrix::col_perm`]).
    pub cols: Range<usize>,
    /// The rank of a low-rank block; `None` for a dense one.
    pub rank: Option<usize>,
    /// Whether the pair is admissible (far); a far block may still be stored dense.
    pub far: bool,
    /// Where its values start in [`HMatrix::values`]: a dense block `3|rows| × 3|cols|`
    /// column-major; a rank-k block `U` (`3|rows| × k`, column-major, singular values folded
    /// in) then `V` (`3|cols| × k`, row-major: one column DOF's k weights together), so that
    /// the block is `U·Vᵀ`.
    pub offset: usize,
    /// For a block above the diagonal of a symmetric plan: the block (index in
    /// [`HMatrix::blocks`]) it is the transpose of. Its own values at `offset` are that
    /// block's transposed; a reader may use the source's instead (the GPU pass does).
    pub mirror_of: Option<usize>,
}

#[derive(Clone, Debug)]
struct Block {
    rows: Range<u32>,
    cols: Range<u32>,
    /// `None`: dense, 3m × 3n column-major at `offset`. `Some(k)`: `U` (3m × k, column-major)
    /// at `offset`, then `V` (3n × k, row-major: one DOF's k weights contiguous).
    rank: Option<u32>,
    far: bool,
    offset: usize,
    /// The transpose of a stored block (a symmetric plan's block above the diagonal), its
    /// values made from that block's when the panels were joined.
    mirror: bool,
    /// That stored block's index (for a mirror).
    source: u32,
}

/// `L` as a hierarchical matrix: dense near blocks and low-rank far blocks (module docs).
#[derive(Clone, Debug)]
pub struct HMatrix {
    opts: HOptions,
    out_rows: usize,
    row_perm: Vec<u32>,
    col_perm: Vec<u32>,
    /// Each row's position.
    row_pos: Vec<u32>,
    /// Each column's position.
    col_pos: Vec<u32>,
    blocks: Vec<Block>,
    data: Vec<f64>,
    /// Each column position's leaf (index into `leaf_start`).
    col_leaf: Vec<u32>,
    /// The blocks covering each column leaf: `leaf_blocks[leaf_start[l]..leaf_start[l + 1]]`.
    leaf_start: Vec<u32>,
    leaf_blocks: Vec<u32>,
    norm_sq: f64,
    discarded_sq: f64,
    /// The points it was planned from (rows, then columns), so that it can be saved.
    row_points: Vec<DVec3>,
    col_points: Vec<DVec3>,
    /// Each panel's run of `blocks`, the range of `data` its stored blocks hold, and its
    /// `(norm_sq, discarded_sq)` (of the stored blocks).
    panel_runs: Vec<Range<u32>>,
    panel_data: Vec<Range<usize>>,
    panel_norms: Vec<(f64, f64)>,
}

/// The layout of an [`HMatrix`] before its values: the cluster trees, the block partition in
/// block-column order, and the panels (the column clusters solved and compressed together).
/// It depends only on the points and the options, so a loader or a shard rebuilds the same.
#[derive(Clone, Debug)]
pub struct HPlan {
    opts: HOptions,
    out_rows: usize,
    row_perm: Vec<u32>,
    col_perm: Vec<u32>,
    col_leaves: Vec<Range<u32>>,
    /// Blocks in block-column order: row positions, column positions, far.
    pairs: Vec<(Range<u32>, Range<u32>, bool)>,
    /// Column-position ranges of the panels, in order.
    panels: Vec<Range<u32>>,
    /// Each panel's run of `pairs`.
    panel_pairs: Vec<Range<usize>>,
    /// Rows and columns are the same points (one tree): each pair above the diagonal is the
    /// transpose of the pair here (its mirror), which is solved and stored instead.
    mirror: Vec<Option<u32>>,
    /// Whether a pair's transpose is a mirror of it.
    has_mirror: Vec<bool>,
    row_points: Vec<DVec3>,
    col_points: Vec<DVec3>,
}

/// One panel's blocks, compressed ([`HPlan::compress_panel`]): a shard's unit of work, joined
/// by [`HMatrix::from_panels`].
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    pub(crate) index: usize,
    /// Each block's rank (`None`: dense), in the plan's order.
    pub(crate) ranks: Vec<Option<u32>>,
    pub(crate) data: Vec<f64>,
    pub(crate) norm_sq: f64,
    pub(crate) discarded_sq: f64,
}

impl Panel {
    /// Its index in the plan.
    pub fn index(&self) -> usize {
        self.index
    }
    /// Values stored.
    pub fn values(&self) -> usize {
        self.data.len()
    }
}

/// Products with blocks of `L`, for the far blocks a panel compresses by sketching
/// ([`HPlan::compress_panel_with`]) instead of from its columns.
pub trait BlockProducts: Sync {
    /// `out = L[rows, cols]·x` (`transpose` false; `x` is `3|cols| × k`, `out` `3|rows| × k`)
    /// or `L[rows, cols]ᵀ·x` (`x` `3|rows| × k`, `out` `3|cols| × k`): `rows` are row
    /// indices, `cols` column indices, DOFs in their order; `out` is zero on entry.
    fn products(
        &self,
        rows: &[u32],
        cols: &[u32],
        transpose: bool,
        x: faer::MatRef<'_, f64>,
        out: faer::MatMut<'_, f64>,
    ) -> Result<(), HError>;

    /// `out = [L[rows₁, cols]ᵀ·x₁, L[rows₂, cols]ᵀ·x₂, …]` (`out` `3|cols| × Σ kᵢ`, zero on
    /// entry): the second products of the far blocks of one column cluster at once. By
    /// default one [`BlockProducts::products`] each.
    fn products_t_pieces(
        &self,
        pieces: &[(&[u32], faer::MatRef<'_, f64>)],
        cols: &[u32],
        mut out: faer::MatMut<'_, f64>,
    ) -> Result<(), HError> {
        let mut at = 0;
        for (rows, x) in pieces {
            let k = x.ncols();
            self.products(rows, cols, true, *x, out.rb_mut().subcols_mut(at, k))?;
            at += k;
        }
        Ok(())
    }
}

impl HMatrix {
    /// Builds from a column source: `solve(cols)` gives `L`'s columns for those column indices
    /// as [`HPlan::compress_panel`] wants them. Panels are solved and compressed one at a
    /// time, so at most one panel of dense columns is held.
    pub fn build<E: From<HError>>(
        row_points: &[DVec3],
        col_points: &[DVec3],
        out_rows: usize,
        opts: &HOptions,
        mut solve: impl FnMut(&[u32]) -> Result<Vec<f64>, E>,
    ) -> Result<HMatrix, E> {
        let plan = HPlan::new(row_points, col_points, out_rows, opts)?;
        let threads = crate::threads::available().min(16);
        let mut panels = Vec::with_capacity(plan.panels());
        for p in 0..plan.panels() {
            let data = solve(plan.panel_cols(p))?;
            panels.push(plan.compress_panel(p, &data, threads)?);
        }
        Ok(HMatrix::from_panels(plan, panels)?)
    }

    /// Joins the compressed panels of `plan` (each once, in any order), checking each block's
    /// size against the plan.
    pub fn from_panels(plan: HPlan, mut panels: Vec<Panel>) -> Result<HMatrix, HError> {
        panels.sort_by_key(|p| p.index);
        if panels.len() != plan.panels() || panels.iter().enumerate().any(|(i, p)| p.index != i) {
            return Err(HError::Panels {
                want: plan.panels(),
                got: panels.len(),
            });
        }
        let total: usize = panels.iter().map(|p| p.data.len()).sum();
        let mut h = HMatrix {
            opts: plan.opts,
            out_rows: plan.out_rows,
            row_pos: vec![0; plan.row_perm.len()],
            col_pos: vec![0; plan.col_perm.len()],
            blocks: Vec::with_capacity(plan.pairs.len()),
            data: Vec::with_capacity(total),
            col_leaf: vec![0; plan.col_perm.len()],
            leaf_start: Vec::new(),
            leaf_blocks: Vec::new(),
            norm_sq: 0.0,
            discarded_sq: 0.0,
            row_perm: Vec::new(),
            col_perm: Vec::new(),
            row_points: Vec::new(),
            col_points: Vec::new(),
            panel_runs: Vec::with_capacity(panels.len()),
            panel_data: Vec::with_capacity(panels.len()),
            panel_norms: Vec::with_capacity(panels.len()),
        };
        // Mirrors' values come after every panel's, made once their stored blocks are in.
        let mut mirrors = Vec::new();
        for (p, panel) in panels.into_iter().enumerate() {
            let run = plan.panel_pairs[p].clone();
            let stored: Vec<usize> = plan.stored(p).collect();
            if panel.ranks.len() != stored.len() {
                return Err(HError::PanelData(p));
            }
            let mut want = 0usize;
            for (&i, &rank) in stored.iter().zip(&panel.ranks) {
                let (r, c, far) = &plan.pairs[i];
                let min = 3 * r.len().min(c.len());
                if rank.is_some_and(|k| !far || k as usize > min) {
                    return Err(HError::PanelData(p));
                }
                want += plan.block_values(i, rank);
            }
            if want != panel.data.len()
                || !(panel.norm_sq.is_finite() && panel.discarded_sq.is_finite())
                || panel.norm_sq < 0.0
                || panel.discarded_sq < 0.0
            {
                return Err(HError::PanelData(p));
            }
            if panel.data.iter().any(|v| !v.is_finite()) {
                return Err(HError::NonFinite);
            }
            let (base, mut local) = (h.data.len(), 0);
            h.panel_runs
                .push(h.blocks.len() as u32..(h.blocks.len() + run.len()) as u32);
            h.panel_data.push(base..base + panel.data.len());
            h.panel_norms.push((panel.norm_sq, panel.discarded_sq));
            let mut ranks = panel.ranks.iter();
            for i in run {
                let (rows, cols, far) = plan.pairs[i].clone();
                if let Some(src) = plan.mirror[i] {
                    // Filled below from its stored block (always in an earlier position).
                    mirrors.push((h.blocks.len(), src as usize));
                    h.blocks.push(Block {
                        rows,
                        cols,
                        rank: None,
                        far,
                        offset: 0,
                        mirror: true,
                        source: src,
                    });
                    continue;
                }
                let rank = *ranks.next().ok_or(HError::PanelData(p))?;
                h.blocks.push(Block {
                    rows,
                    cols,
                    rank,
                    far,
                    offset: base + local,
                    mirror: false,
                    source: 0,
                });
                local += plan.block_values(i, rank);
            }
            h.data.extend_from_slice(&panel.data);
            h.norm_sq += panel.norm_sq;
            h.discarded_sq += panel.discarded_sq;
        }
        // The mirrors: each the transpose of its stored block, the same error.
        for (bi, src) in mirrors {
            if src >= bi || h.blocks[src].mirror {
                return Err(HError::PanelData(0));
            }
            let s = h.blocks[src].clone();
            let (m_, n_) = (3 * s.rows.len(), 3 * s.cols.len());
            let offset = h.data.len();
            match s.rank {
                None => {
                    // Bᵀ (n × m, column-major): entry (i, j) = B(j, i).
                    for j in 0..m_ {
                        for i in 0..n_ {
                            let v = h.data[s.offset + i * m_ + j];
                            h.data.push(v);
                        }
                    }
                }
                Some(k) => {
                    // (U Vᵀ)ᵀ = V Uᵀ: U' = V (n × k, column-major), V' = U (m × k, row-major).
                    let k = k as usize;
                    for l in 0..k {
                        for i in 0..n_ {
                            let v = h.data[s.offset + k * m_ + i * k + l];
                            h.data.push(v);
                        }
                    }
                    for j in 0..m_ {
                        for l in 0..k {
                            let v = h.data[s.offset + l * m_ + j];
                            h.data.push(v);
                        }
                    }
                }
            }
            let b = &mut h.blocks[bi];
            b.rank = s.rank;
            b.offset = offset;
        }
        for (p, &r) in plan.row_perm.iter().enumerate() {
            h.row_pos[r as usize] = p as u32;
        }
        for (p, &c) in plan.col_perm.iter().enumerate() {
            h.col_pos[c as usize] = p as u32;
        }
        h.row_perm = plan.row_perm;
        h.col_perm = plan.col_perm;
        h.row_points = plan.row_points;
        h.col_points = plan.col_points;
        h.index_columns(&plan.col_leaves);
        Ok(h)
    }

    /// For each column leaf, the blocks whose column range covers it (a block's column range
    /// is a cluster: a run of whole leaves).
    fn index_columns(&mut self, leaves: &[Range<u32>]) {
        for (li, r) in leaves.iter().enumerate() {
            for p in r.clone() {
                self.col_leaf[p as usize] = li as u32;
            }
        }
        let covered = |b: &Block| {
            self.col_leaf[b.cols.start as usize] as usize
                ..=self.col_leaf[b.cols.end as usize - 1] as usize
        };
        let mut count = vec![0u32; leaves.len() + 1];
        for b in &self.blocks {
            for l in covered(b) {
                count[l + 1] += 1;
            }
        }
        for l in 0..leaves.len() {
            count[l + 1] += count[l];
        }
        let mut next = count.clone();
        let mut lb = vec![0u32; count[leaves.len()] as usize];
        for (bi, b) in self.blocks.iter().enumerate() {
            for l in covered(b) {
                lb[next[l] as usize] = bi as u32;
                next[l] += 1;
            }
        }
        // By row start: a leaf's blocks partition the rows, so a row's block is found by
        // bisection.
        for l in 0..leaves.len() {
            lb[count[l] as usize..count[l + 1] as usize]
                .sort_unstable_by_key(|&b| self.blocks[b as usize].rows.start);
        }
        self.leaf_start = count;
        self.leaf_blocks = lb;
    }

    /// u = L_H·F over the active columns, with `Compliance::displace`'s meaning: `forces` are
    /// (column index, force in N), `out` gets one entry per output row (metres). The cost is
    /// that of the blocks in the active columns' block columns; a far block shared by several
    /// active columns applies its `U` once. Columns out of range are ignored.
    pub fn displace(&self, forces: &[(u32, DVec3)], out: &mut [DVec3]) {
        out[..self.out_rows].fill(DVec3::ZERO);
        let mut hits: Vec<(u32, u32, DVec3)> = Vec::new();
        for &(c, f) in forces {
            let Some(&p) = self.col_pos.get(c as usize) else {
                continue;
            };
            let leaf = self.col_leaf[p as usize] as usize;
            let bs = &self.leaf_blocks
                [self.leaf_start[leaf] as usize..self.leaf_start[leaf + 1] as usize];
            for &b in bs {
                hits.push((b, p - self.blocks[b as usize].cols.start, f));
            }
        }
        hits.sort_unstable_by_key(|h| h.0);
        let mut z = Vec::new();
        for group in hits.chunk_by(|a, b| a.0 == b.0) {
            let b = &self.blocks[group[0].0 as usize];
            let rows = &self.row_perm[b.rows.start as usize..b.rows.end as usize];
            let m = 3 * rows.len();
            match b.rank {
                None => {
                    for &(_, j, f) in group {
                        for (ax, fb) in f.to_array().into_iter().enumerate() {
                            if fb == 0.0 {
                                continue;
                            }
                            let col = &self.data[b.offset + (3 * j as usize + ax) * m..][..m];
                            for (&r, e) in rows.iter().zip(col.chunks_exact(3)) {
                                out[r as usize] += DVec3::new(e[0], e[1], e[2]) * fb;
                            }
                        }
                    }
                }
                Some(k) => {
                    let k = k as usize;
                    if k == 0 {
                        continue;
                    }
                    z.clear();
                    z.resize(k, 0.0);
                    let v = &self.data[b.offset + k * m..];
                    for &(_, j, f) in group {
                        for (ax, fb) in f.to_array().into_iter().enumerate() {
                            let w = &v[(3 * j as usize + ax) * k..][..k];
                            for (zl, wl) in z.iter_mut().zip(w) {
                                *zl += wl * fb;
                            }
                        }
                    }
                    for (l, &zl) in z.iter().enumerate() {
                        let u = &self.data[b.offset + l * m..][..m];
                        for (&r, e) in rows.iter().zip(u.chunks_exact(3)) {
                            out[r as usize] += DVec3::new(e[0], e[1], e[2]) * zl;
                        }
                    }
                }
            }
        }
    }

    /// The 3×3 block L_H(row r, column c), m/N, and whether it is exact (it lies in a dense
    /// block: the near field the haptic path reads); `None` for an index out of range.
    pub fn block(&self, r: usize, c: usize) -> Option<(DMat3, bool)> {
        let pr = *self.row_pos.get(r)?;
        let pc = *self.col_pos.get(c)?;
        let leaf = self.col_leaf[pc as usize] as usize;
        let bs =
            &self.leaf_blocks[self.leaf_start[leaf] as usize..self.leaf_start[leaf + 1] as usize];
        // The last block starting at or before the row (a leaf's blocks partition the rows).
        let k = bs.partition_point(|&b| self.blocks[b as usize].rows.start <= pr);
        let b = &self.blocks[bs[k.checked_sub(1)?] as usize];
        if !b.rows.contains(&pr) {
            return None;
        }
        let (i, j) = ((pr - b.rows.start) as usize, (pc - b.cols.start) as usize);
        let m = 3 * b.rows.len();
        let entry = |a: usize, e: usize| -> f64 {
            match b.rank {
                None => self.data[b.offset + (3 * j + e) * m + 3 * i + a],
                Some(k) => {
                    let k = k as usize;
                    let v = &self.data[b.offset + k * m + (3 * j + e) * k..][..k];
                    (0..k)
                        .map(|l| self.data[b.offset + l * m + 3 * i + a] * v[l])
                        .sum()
                }
            }
        };
        let col = |e: usize| DVec3::new(entry(0, e), entry(1, e), entry(2, e));
        Some((DMat3::from_cols(col(0), col(1), col(2)), b.rank.is_none()))
    }

    /// The options it was built with.
    pub fn options(&self) -> &HOptions {
        &self.opts
    }
    /// The row points it was planned from ([`HPlan::new`]).
    pub fn row_points(&self) -> &[DVec3] {
        &self.row_points
    }
    /// The column points it was planned from ([`HPlan::new`]).
    pub fn col_points(&self) -> &[DVec3] {
        &self.col_points
    }
    /// Number of panels it was joined from.
    pub fn panels(&self) -> usize {
        self.panel_runs.len()
    }
    /// Panel `p` as [`HMatrix::from_panels`] took it (a copy of its values), so that a plan
    /// rebuilt from the same points and options joins the panels into an equal matrix;
    /// `None` out of range.
    pub fn panel(&self, p: usize) -> Option<Panel> {
        let run = self.panel_runs.get(p)?;
        let blocks = &self.blocks[run.start as usize..run.end as usize];
        let (norm_sq, discarded_sq) = self.panel_norms[p];
        Some(Panel {
            index: p,
            ranks: blocks
                .iter()
                .filter(|b| !b.mirror)
                .map(|b| b.rank)
                .collect(),
            data: self.data[self.panel_data[p].clone()].to_vec(),
            norm_sq,
            discarded_sq,
        })
    }
    /// Row nodes (the output rows that hold `L`).
    pub fn rows(&self) -> usize {
        self.row_perm.len()
    }
    /// Column nodes.
    pub fn cols(&self) -> usize {
        self.col_perm.len()
    }
    /// Row index at each position of the row cluster tree.
    pub fn row_perm(&self) -> &[u32] {
        &self.row_perm
    }
    /// Column index at each position of the column cluster tree.
    pub fn col_perm(&self) -> &[u32] {
        &self.col_perm
    }
    /// The blocks, in block-column order.
    pub fn blocks(&self) -> impl Iterator<Item = BlockInfo> + '_ {
        self.blocks.iter().map(|b| BlockInfo {
            rows: b.rows.start as usize..b.rows.end as usize,
            cols: b.cols.start as usize..b.cols.end as usize,
            rank: b.rank.map(|k| k as usize),
            far: b.far,
            offset: b.offset,
            mirror_of: b.mirror.then_some(b.source as usize),
        })
    }
    /// Every stored value, blocks in [`HMatrix::blocks`] order (see [`BlockInfo::offset`]).
    pub fn values(&self) -> &[f64] {
        &self.data
    }
    /// Position of row index `r` in [`HMatrix::row_perm`].
    pub fn row_pos(&self, r: usize) -> Option<usize> {
        self.row_pos.get(r).map(|&p| p as usize)
    }
    /// Position of column index `c` in [`HMatrix::col_perm`].
    pub fn col_pos(&self, c: usize) -> Option<usize> {
        self.col_pos.get(c).map(|&p| p as usize)
    }
    /// Number of column leaves (clusters that are not split).
    pub fn col_leaves(&self) -> usize {
        self.leaf_start.len().saturating_sub(1)
    }
    /// The leaf of column position `p`.
    pub fn leaf_of(&self, p: usize) -> usize {
        self.col_leaf[p] as usize
    }
    /// The blocks (indices into [`HMatrix::blocks`]) whose columns cover column leaf `leaf`:
    /// their row ranges partition the row positions, in increasing order of row start.
    pub fn leaf_blocks(&self, leaf: usize) -> &[u32] {
        &self.leaf_blocks[self.leaf_start[leaf] as usize..self.leaf_start[leaf + 1] as usize]
    }
    /// Output rows of [`HMatrix::displace`] (the row nodes, then rows that stay at rest).
    pub fn out_rows(&self) -> usize {
        self.out_rows
    }
    /// Values stored (dense entries and factor entries).
    pub fn stored_values(&self) -> usize {
        self.data.len()
    }
    /// Bytes of the stored values in f64.
    pub fn bytes_f64(&self) -> usize {
        8 * self.data.len()
    }
    /// Bytes of the stored values in f32 (a GPU copy).
    pub fn bytes_f32(&self) -> usize {
        4 * self.data.len()
    }
    /// Bytes of the index (permutations, block table, column index), beside the values.
    pub fn index_bytes(&self) -> usize {
        4 * (2 * self.row_perm.len()
            + 2 * self.col_perm.len()
            + self.col_leaf.len()
            + self.leaf_start.len()
            + self.leaf_blocks.len())
            + self.blocks.len() * std::mem::size_of::<Block>()
    }
    /// Values the dense `L` over the same rows and columns holds (`3·rows × 3·cols`).
    pub fn dense_values(&self) -> usize {
        9 * self.row_perm.len() * self.col_perm.len()
    }
    /// `‖L‖_F` of the blocks it was built from.
    pub fn norm(&self) -> f64 {
        self.norm_sq.sqrt()
    }
    /// `‖L − L_H‖_F` as the truncations discarded it (exact up to rounding); at most
    /// `tolerance·‖L‖_F`.
    pub fn truncation_error(&self) -> f64 {
        self.discarded_sq.sqrt()
    }
    /// `L_H` expanded into the compliance module's dense layout (`(3c + b)·3·rows + 3r + a`), for
    /// checks: as large as the dense `L`.
    pub fn to_dense(&self) -> Vec<f64> {
        let nr3 = 3 * self.row_perm.len();
        let mut l = vec![0.0; nr3 * 3 * self.col_perm.len()];
        for b in &self.blocks {
            let rows = &self.row_perm[b.rows.start as usize..b.rows.end as usize];
            let cols = &self.col_perm[b.cols.start as usize..b.cols.end as usize];
            let (m, n) = (3 * rows.len(), 3 * cols.len());
            let entry = |i: usize, j: usize| -> f64 {
                match b.rank {
                    None => self.data[b.offset + j * m + i],
                    Some(k) => {
                        let k = k as usize;
                        let v = &self.data[b.offset + k * m + j * k..][..k];
                        (0..k).map(|l| self.data[b.offset + l * m + i] * v[l]).sum()
                    }
                }
            };
            for j in 0..n {
                let cj = 3 * cols[j / 3] as usize + j % 3;
                for i in 0..m {
                    l[cj * nr3 + 3 * rows[i / 3] as usize + i % 3] = entry(i, j);
                }
            }
        }
        l
    }
}

/// The mean rank of a far block at tolerance `eps`, measured on the compliance of clamped
/// surfaces (η = 2, leaves of 32: the cube study and our mouse and organs), linear in
/// `log10(1/ε)` between the measured points: 5 at 10⁻², 9 at 10⁻³, 14 at 10⁻⁴, 29 at 10⁻⁶.
pub fn mean_rank_estimate(eps: f64) -> f64 {
    const AT: [(f64, f64); 4] = [(2.0, 5.0), (3.0, 9.0), (4.0, 14.0), (6.0, 29.0)];
    let x = (1.0 / eps.clamp(1e-15, 0.5)).log10();
    let seg = if x <= AT[1].0 {
        (AT[0], AT[1])
    } else if x <= AT[2].0 {
        (AT[1], AT[2])
    } else {
        (AT[2], AT[3])
    };
    let ((x0, y0), (x1, y1)) = seg;
    (y0 + (x - x0) * (y1 - y0) / (x1 - x0)).max(1.0)
}

/// When `rows` and `cols` hold the same points (in any order), the row index of each column's
/// point; `None` otherwise.
fn same_points(rows: &[DVec3], cols: &[DVec3]) -> Option<Vec<u32>> {
    if rows.len() != cols.len() {
        return None;
    }
    let key = |p: &DVec3| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
    let order = |pts: &[DVec3]| {
        let mut o: Vec<u32> = (0..pts.len() as u32).collect();
        o.sort_unstable_by_key(|&i| (key(&pts[i as usize]), i));
        o
    };
    let (ro, co) = (order(rows), order(cols));
    let mut row_of_col = vec![0u32; cols.len()];
    for (&r, &c) in ro.iter().zip(&co) {
        if key(&rows[r as usize]) != key(&cols[c as usize]) {
            return None;
        }
        row_of_col[c as usize] = r;
    }
    Some(row_of_col)
}

/// `f(0), …, f(n − 1)` on up to `threads` threads, in order.
fn par_map<T: Send>(n: usize, threads: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
    let next = AtomicUsize::new(0);
    let work = || {
        let mut got = Vec::new();
        loop {
            let i = next.fetch_add(1, Relaxed);
            if i >= n {
                return got;
            }
            got.push((i, f(i)));
        }
    };
    let mut all: Vec<(usize, T)> = Vec::new();
    for got in crate::threads::fan_out(threads.clamp(1, n.max(1)), work, |_| work()) {
        // A worker only panics if `f` does: pass it on.
        all.extend(got.unwrap_or_else(|e| std::panic::resume_unwind(e)));
    }
    all.sort_unstable_by_key(|x| x.0);
    all.into_iter().map(|x| x.1).collect()
}

/// The errors of unit point loads, `L_H` against the dense compliance it was built from: for
/// each column `c` and axis `b` (index `3c + b`), the relative L2 error `‖Δu‖₂/‖u‖₂` and the
/// relative max-norm error `max|Δu_r|/max|u_r|` over the rows.
#[derive(Clone, Debug, Default)]
pub struct LoadErrors {
    /// Relative L2 errors, one per (column, axis).
    pub l2: Vec<f64>,
    /// Relative max-norm errors, one per (column, axis).
    pub max: Vec<f64>,
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn bad_build_input_is_a_typed_error() {
        let o = HOptions::new(1e-3);
        let p = [DVec3::ZERO];
        let blk = |c: &[u32]| Ok::<_, HError>(vec![0.0; 9 * c.len()]);
        assert!(matches!(
            HMatrix::build(&[], &p, 0, &o, blk),
            Err(HError::Empty { .. })
        ));
        assert!(matches!(
            HMatrix::build(&p, &[], 1, &o, blk),
            Err(HError::Empty { .. })
        ));
        assert!(matches!(
            HMatrix::build(&p, &p, 0, &o, blk),
            Err(HError::OutRows { .. })
        ));
        let nan = [DVec3::new(0.0, f64::NAN, 0.0)];
        assert!(matches!(
            HMatrix::build(&nan, &p, 1, &o, blk),
            Err(HError::Point { .. })
        ));
        assert!(matches!(
            HMatrix::build(&p, &p, 1, &o, |_| Ok::<_, HError>(vec![0.0; 6])),
            Err(HError::BlockShape { .. })
        ));
        assert_eq!(
            HMatrix::build(&p, &p, 1, &o, |_| Ok::<_, HError>(vec![f64::NAN; 9])).unwrap_err(),
            HError::NonFinite
        );
        let small = HOptions { panel_size: 8, ..o };
        assert_eq!(
            HMatrix::build(&p, &p, 1, &small, blk).unwrap_err(),
            HError::LeafSize
        );
    }

    #[cfg_attr(test, test)]
    pub(crate) fn coincident_points_and_a_zero_matrix_build() {
        // All points in one place: one leaf that cannot split, one dense block.
        let p = vec![DVec3::ONE; 100];
        let h = HMatrix::build(&p, &p, 100, &HOptions::new(1e-3), |c| {
            Ok::<_, HError>(vec![0.0; 900 * c.len()])
        })
        .expect("H");
        assert_eq!(h.blocks().count(), 1);
        let mut out = vec![DVec3::ONE; 100];
        h.displace(&[(3, DVec3::X), (1000, DVec3::Y)], &mut out);
        assert!(out.iter().all(|v| *v == DVec3::ZERO));
        // Two far clouds of a zero matrix: rank-0 far blocks.
        let q: Vec<DVec3> = (0..64)
            .map(|i| {
                DVec3::new(
                    if i < 32 { 0.0 } else { 100.0 },
                    (i % 32) as f64 * 0.01,
                    0.0,
                )
            })
            .collect();
        let h = HMatrix::build(&q, &q, 64, &HOptions::new(1e-3), |c| {
            Ok::<_, HError>(vec![0.0; 576 * c.len()])
        })
        .expect("H");
        assert!(h.blocks().any(|b| b.rank == Some(0)));
        assert_eq!(h.truncation_error(), 0.0);
    }
}
