//! Linear-elastic constant-strain tetrahedra: element and global stiffness (the paper's eq. 1),
//! elimination of the clamped DOFs, and the sparse factorisation of `K` (faer's supernodal
//! analysis, METIS ordering): Cholesky, or for the locking-free formulation's mixed system a
//! signed `G Σ Gᵀ` ([`Factor`]).

use faer::reborrow::{Reborrow, ReborrowMut};
use faer::sparse::SparseColMat;
use faer::{Accum, Mat, MatMut, MatRef, Par, Side};
use glam::DVec3;

use crate::mesh::Mesh;
use crate::units::Material;

pub mod error;
pub mod locking_free;
pub use error::FemError;

/// The numbering of free (unclamped) DOFs: DOF `3·node + axis` → free index.
#[derive(Clone, Debug)]
pub struct Dofs {
    map: Vec<u32>,
    /// Number of free DOFs.
    pub n_free: usize,
    /// The node and axis of each free DOF.
    pub owner: Vec<(u32, u8)>,
}

impl Dofs {
    /// Numbers the DOFs of the unclamped nodes in node order.
    pub fn new(fixed: &[bool]) -> Dofs {
        let mut map = vec![u32::MAX; fixed.len() * 3];
        let mut owner = Vec::new();
        for (n, &f) in fixed.iter().enumerate() {
            if !f {
                for a in 0..3 {
                    map[3 * n + a] = owner.len() as u32;
                    owner.push((n as u32, a as u8));
                }
            }
        }
        Dofs {
            n_free: owner.len(),
            map,
            owner,
        }
    }
    /// The free index of (node, axis), or `None` if the node is clamped.
    #[inline]
    pub fn free(&self, node: u32, axis: usize) -> Option<usize> {
        let d = self.map[3 * node as usize + axis];
        (d != u32::MAX).then_some(d as usize)
    }
}

/// K in compressed columns from its 3×3 node-pair blocks (`blocks[a]`: `(b, K_ab)` row-major,
/// clamped nodes absent), built directly — a count, then a fill in row order, so every
/// column's rows come out sorted — instead of sorting triplets: the same matrix bit for bit
/// (each entry is one block value), several times faster on large meshes.
fn csc_from_blocks(
    dofs: &Dofs,
    blocks: &[Vec<(u32, [f64; 9])>],
) -> Result<SparseColMat<usize, f64>, FemError> {
    let n = dofs.n_free;
    let mut col_ptr = vec![0usize; n + 1];
    for row in blocks {
        for (nb, _) in row {
            for j in 0..3 {
                if let Some(c) = dofs.free(*nb, j) {
                    col_ptr[c + 1] += 3;
                }
            }
        }
    }
    for c in 0..n {
        col_ptr[c + 1] += col_ptr[c];
    }
    let nnz = col_ptr[n];
    let mut row_idx = vec![0usize; nnz];
    let mut val = vec![0.0f64; nnz];
    let mut next = col_ptr[..n].to_vec();
    // Rows in increasing order: nodes in order, then axes (`Dofs` numbers them so).
    for (na, row) in blocks.iter().enumerate() {
        for i in 0..3 {
            let Some(r) = dofs.free(na as u32, i) else {
                continue;
            };
            for (nb, m) in row {
                for j in 0..3 {
                    if let Some(c) = dofs.free(*nb, j) {
                        row_idx[next[c]] = r;
                        val[next[c]] = m[3 * i + j];
                        next[c] += 1;
                    }
                }
            }
        }
    }
    // Sorted and without repeats by construction (one block per node pair).
    let sym = faer::sparse::SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
    Ok(SparseColMat::new(sym, val))
}

/// The value under `key` in a short row of `(key, value)` pairs (a node's neighbours), appended
/// as `zero` when absent.
pub(crate) fn row_entry<T>(row: &mut Vec<(u32, T)>, key: u32, zero: T) -> &mut T {
    let i = match row.iter().position(|e| e.0 == key) {
        Some(i) => i,
        None => {
            row.push((key, zero));
            row.len() - 1
        }
    };
    &mut row[i].1
}

/// Gradients of the four linear shape functions of a tet and its volume.
pub(crate) fn shape_gradients(p: [DVec3; 4]) -> ([DVec3; 4], f64) {
    let j = glam::DMat3::from_cols(p[1] - p[0], p[2] - p[0], p[3] - p[0]);
    let vol = j.determinant() / 6.0;
    // Rows of J⁻¹ are ∇N₁, ∇N₂, ∇N₃.
    let inv = j.inverse().transpose();
    let g1 = inv.x_axis;
    let g2 = inv.y_axis;
    let g3 = inv.z_axis;
    ([-(g1 + g2 + g3), g1, g2, g3], vol)
}

/// The 12×12 stiffness of a constant-strain tet, `V·Bᵀ D B`, DOFs ordered (node, axis).
pub(crate) fn element_stiffness(p: [DVec3; 4], mat: &Material) -> [[f64; 12]; 12] {
    let (g, vol) = shape_gradients(p);
    let (lambda, mu) = mat.lame();
    let mut k = [[0.0; 12]; 12];
    // K_ab(i,j) = V (λ g_a,i g_b,j + μ g_a,j g_b,i + μ δ_ij g_a·g_b)
    for a in 0..4 {
        for b in 0..4 {
            let ga = g[a].to_array();
            let gb = g[b].to_array();
            let dot = g[a].dot(g[b]);
            for i in 0..3 {
                for jx in 0..3 {
                    let mut v = lambda * ga[i] * gb[jx] + mu * ga[jx] * gb[i];
                    if i == jx {
                        v += mu * dot;
                    }
                    k[3 * a + i][3 * b + jx] = vol * v;
                }
            }
        }
    }
    k
}

/// The full (unconstrained) global stiffness as a dense matrix, for tests on small meshes
/// (of the mesh's formulation).
pub fn dense_stiffness(mesh: &Mesh) -> Vec<Vec<f64>> {
    if locking_free::wanted(mesh) {
        return locking_free::dense(mesh, locking_free::Smoothing::CHOSEN);
    }
    let n = mesh.nodes.len() * 3;
    let mut k = vec![vec![0.0; n]; n];
    for (ti, t) in mesh.tets.iter().enumerate() {
        let ke = element_stiffness(t.map(|i| mesh.nodes[i as usize]), &mesh.tet_material(ti));
        for a in 0..4 {
            for b in 0..4 {
                for i in 0..3 {
                    for j in 0..3 {
                        k[3 * t[a] as usize + i][3 * t[b] as usize + j] += ke[3 * a + i][3 * b + j];
                    }
                }
            }
        }
    }
    k
}

/// A dense matrix of `nodes` nodes' DOFs from 3×3 node-pair blocks.
fn dense_from_blocks(nodes: usize, blocks: &[Vec<(u32, [f64; 9])>]) -> Vec<Vec<f64>> {
    let mut k = vec![vec![0.0; 3 * nodes]; 3 * nodes];
    for (a, row) in blocks.iter().enumerate() {
        for (b, m) in row {
            for i in 0..3 {
                for j in 0..3 {
                    k[3 * a + i][3 * *b as usize + j] += m[3 * i + j];
                }
            }
        }
    }
    k
}

/// The stiffness over the free DOFs (`K` of the paper's eq. 1), sparse, both triangles stored.
pub struct Stiffness {
    /// Free-DOF numbering.
    pub dofs: Dofs,
    /// K over free DOFs, N/m.
    pub k: SparseColMat<usize, f64>,
    /// Position of each free node (free DOFs `3i..3i + 3` belong to free node `i`), metres:
    /// the geometry the nested-dissection ordering cuts.
    free_coords: Vec<DVec3>,
    /// The node of each auxiliary unknown (DOF `n_free + j`): empty for `K` itself; for the
    /// mixed system of [`locking_free::mixed`], one pressure per node and region, which the
    /// factorisation eliminates with negative pivots.
    aux_owner: Vec<u32>,
    /// The position of each auxiliary unknown's node, metres (for the ordering).
    aux_coords: Vec<DVec3>,
}

/// Where a factorisation keeps its factor.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FactorStore {
    /// In memory (faer's supernodal factorisation).
    Heap,
    /// In an unlinked temporary file in `dir`, written by the multifrontal sweep of
    /// [`crate::frontal`] on `threads` threads and read through a map (supernodal analyses
    /// only; the heap otherwise).
    File {
        /// Directory of the temporary file.
        dir: std::path::PathBuf,
        /// Threads factorising subtrees.
        threads: usize,
    },
    /// `File` when the factor would take more than `above` bytes, else `Heap`; `Heap` too
    /// when the file cannot be made (no directory, no room on its disk).
    Auto {
        /// Directory of the temporary file.
        dir: std::path::PathBuf,
        /// Threads factorising subtrees.
        threads: usize,
        /// Bytes of factor above which it goes to the file.
        above: usize,
    },
}

/// One auxiliary unknown of a mixed system: its node, its diagonal entry, its couplings to
/// the displacements (per node, a 3-vector), and to other auxiliary unknowns (by index; each
/// pair given from both sides).
pub(crate) type AuxRow = (u32, f64, Vec<(u32, DVec3)>, Vec<(u32, f64)>);

/// The fill-reducing ordering of the sparse Cholesky factorisation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Ordering {
    /// faer's approximate minimum degree.
    Amd,
    /// Nested dissection of the node graph by coordinate bisection (separators last), on
    /// 3-DOF node blocks: less fill than AMD on 3D meshes (see README, precompute).
    NestedDissection,
    /// METIS's multilevel nested dissection (`METIS_NodeND`) of the node graph, on 3-DOF
    /// node blocks: the least fill of the three (falls back to `NestedDissection` if METIS
    /// fails).
    #[default]
    Metis,
}

/// METIS's fill-reducing order of the graph `ptr`/`idx` (new → old), `None` if METIS fails.
fn metis_order(ptr: &[usize], idx: &[usize]) -> Option<Vec<usize>> {
    let n = ptr.len().checked_sub(1)?;
    if n == 0 {
        return Some(Vec::new());
    }
    let mut nv = i32::try_from(n).ok()?;
    let mut xadj: Vec<i32> = ptr
        .iter()
        .map(|&p| i32::try_from(p).ok())
        .collect::<Option<_>>()?;
    let mut adj: Vec<i32> = idx
        .iter()
        .map(|&p| i32::try_from(p).ok())
        .collect::<Option<_>>()?;
    let mut opts = [0i32; metis_sys::METIS_NOPTIONS as usize];
    let mut perm = vec![0i32; n];
    let mut iperm = vec![0i32; n];
    // METIS seeds one process-wide random generator at the start of each call: two calls at
    // once would share it and give orderings (and factors' bits) that depend on timing.
    static METIS: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one_at_a_time = METIS.lock().unwrap_or_else(|e| e.into_inner());
    // SAFETY: the arrays have the lengths METIS_NodeND requires (xadj n + 1, adjncy xadj[n],
    // options METIS_NOPTIONS, perm and iperm n); METIS only reads the inputs and writes the
    // outputs during the call.
    let rc = unsafe {
        metis_sys::METIS_SetDefaultOptions(opts.as_mut_ptr());
        metis_sys::METIS_NodeND(
            &mut nv,
            xadj.as_mut_ptr(),
            adj.as_mut_ptr(),
            std::ptr::null_mut(),
            opts.as_mut_ptr(),
            perm.as_mut_ptr(),
            iperm.as_mut_ptr(),
        )
    };
    if rc != metis_sys::rstatus_et_METIS_OK {
        return None;
    }
    let order: Vec<usize> = perm.iter().map(|&p| p as usize).collect();
    let mut seen = vec![false; n];
    for &o in &order {
        if o >= n || std::mem::replace(&mut seen[o], true) {
            return None;
        }
    }
    Some(order)
}

/// Leaves of the nested dissection hold at most this many nodes.
const ND_LEAF: usize = 96;

/// Nested dissection of the node graph `adj` (CSR: `ptr`, `idx`) by coordinate bisection:
/// the nodes are split at the median of the bounding box's longest axis, the nodes of the first
/// half that touch the second half form the separator, which is ordered after both halves.
/// Returns the nodes in elimination order.
fn nested_dissection(coords: &[DVec3], ptr: &[usize], idx: &[usize]) -> Vec<usize> {
    fn rec(
        nodes: &mut [usize],
        coords: &[DVec3],
        ptr: &[usize],
        idx: &[usize],
        side: &mut [u8],
        order: &mut Vec<usize>,
    ) {
        if nodes.len() <= ND_LEAF {
            order.extend_from_slice(nodes);
            return;
        }
        // Try a median cut across each axis; keep the one with the smallest separator.
        let mid = nodes.len() / 2;
        let mut best: Option<(usize, usize)> = None; // (separator size, axis)
        for ax in 0..3 {
            split(nodes, coords, ax, mid);
            let sep = separator(nodes, mid, ptr, idx, side).len();
            if best.is_none_or(|(s, _)| sep < s) {
                best = Some((sep, ax));
            }
        }
        let ax = best.map_or(0, |b| b.1);
        split(nodes, coords, ax, mid);
        let sep = separator(nodes, mid, ptr, idx, side);
        for &i in sep.iter() {
            side[i] = 3;
        }
        let mut a: Vec<usize> = nodes[..mid]
            .iter()
            .copied()
            .filter(|&i| side[i] != 3)
            .collect();
        for &i in sep.iter() {
            side[i] = 0;
        }
        let mut b = nodes[mid..].to_vec();
        rec(&mut a, coords, ptr, idx, side, order);
        rec(&mut b, coords, ptr, idx, side, order);
        order.extend_from_slice(&sep);
    }
    /// Puts the nodes below the median of axis `ax` first.
    fn split(nodes: &mut [usize], coords: &[DVec3], ax: usize, mid: usize) {
        nodes.select_nth_unstable_by(mid, |&a, &b| {
            coords[a][ax]
                .partial_cmp(&coords[b][ax])
                .unwrap_or(std::cmp::Ordering::Equal)
                .then(a.cmp(&b))
        });
    }
    /// The nodes of `nodes[..mid]` with a neighbour in `nodes[mid..]`.
    fn separator(
        nodes: &[usize],
        mid: usize,
        ptr: &[usize],
        idx: &[usize],
        side: &mut [u8],
    ) -> Vec<usize> {
        for &i in &nodes[mid..] {
            side[i] = 2;
        }
        let sep = nodes[..mid]
            .iter()
            .copied()
            .filter(|&i| idx[ptr[i]..ptr[i + 1]].iter().any(|&j| side[j] == 2))
            .collect();
        for &i in &nodes[mid..] {
            side[i] = 0;
        }
        sep
    }
    let n = coords.len();
    let mut nodes: Vec<usize> = (0..n).collect();
    let mut side = vec![0u8; n];
    let mut order = Vec::with_capacity(n);
    rec(&mut nodes, coords, ptr, idx, &mut side, &mut order);
    order
}

impl Stiffness {
    /// Assembles K with the clamped DOFs eliminated, in the mesh's formulation, each tet of its
    /// own material ([`Mesh::tet_material`]): for the standard formulation K itself, for
    /// the locking-free one its mixed system ([`locking_free::mixed`]: the same
    /// displacements, with [`Stiffness::n_aux`] pressures after the free DOFs). Checks the
    /// materials and that every connected part of the mesh is held by at least three
    /// non-collinear clamped nodes.
    pub fn assemble(mesh: &Mesh) -> Result<Stiffness, FemError> {
        if locking_free::wanted(mesh) {
            return locking_free::mixed(mesh, locking_free::Smoothing::CHOSEN);
        }
        mesh.validate_materials()?;
        check_constrained(mesh)?;
        // Sum element matrices into 3×3 node-pair blocks first (each node has a few dozen
        // neighbours), so the sparse constructor sorts ~9× fewer triplets.
        let mut blocks: Vec<Vec<(u32, [f64; 9])>> = vec![Vec::new(); mesh.nodes.len()];
        for (ti, t) in mesh.tets.iter().enumerate() {
            let ke = element_stiffness(t.map(|i| mesh.nodes[i as usize]), &mesh.tet_material(ti));
            for a in 0..4 {
                if mesh.fixed[t[a] as usize] {
                    continue;
                }
                let row = &mut blocks[t[a] as usize];
                for b in 0..4 {
                    if mesh.fixed[t[b] as usize] {
                        continue;
                    }
                    let block = row_entry(row, t[b], [0.0; 9]);
                    for i in 0..3 {
                        for j in 0..3 {
                            block[3 * i + j] += ke[3 * a + i][3 * b + j];
                        }
                    }
                }
            }
        }
        Stiffness::from_blocks(mesh, &blocks)
    }

    /// The stiffness from 3×3 node-pair blocks (rows of clamped nodes empty, their columns
    /// absent).
    fn from_blocks(mesh: &Mesh, blocks: &[Vec<(u32, [f64; 9])>]) -> Result<Stiffness, FemError> {
        let dofs = Dofs::new(&mesh.fixed);
        let k = csc_from_blocks(&dofs, blocks)?;
        let free_coords = (0..dofs.n_free / 3)
            .map(|i| mesh.nodes[dofs.owner[3 * i].0 as usize])
            .collect();
        Ok(Stiffness {
            dofs,
            k,
            free_coords,
            aux_owner: Vec::new(),
            aux_coords: Vec::new(),
        })
    }

    /// A mixed system ([`locking_free::mixed`]): the 3×3 blocks `dev` between free nodes, and
    /// per auxiliary unknown `(node, diagonal, coupling)`: its diagonal entry and its row of
    /// couplings to the displacements (per node, a 3-vector; clamped nodes' dropped).
    pub(crate) fn from_mixed(
        mesh: &Mesh,
        dev: &[Vec<(u32, [f64; 9])>],
        aux: &[AuxRow],
    ) -> Result<Stiffness, FemError> {
        let dofs = Dofs::new(&mesh.fixed);
        let nf = dofs.n_free;
        let n = nf + aux.len();
        let mut cols: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n];
        for (na, row) in dev.iter().enumerate() {
            for (nb, m) in row {
                for j in 0..3 {
                    let Some(c) = dofs.free(*nb, j) else { continue };
                    for i in 0..3 {
                        if let Some(r) = dofs.free(na as u32, i) {
                            cols[c].push((r, m[3 * i + j]));
                        }
                    }
                }
            }
        }
        for (k, (_, diag, coupling, others)) in aux.iter().enumerate() {
            let p = nf + k;
            for &(h, v) in others {
                cols[p].push((nf + h as usize, v));
            }
            for &(node, v) in coupling {
                for a in 0..3 {
                    if let Some(d) = dofs.free(node, a) {
                        cols[d].push((p, v[a]));
                        cols[p].push((d, v[a]));
                    }
                }
            }
            cols[p].push((p, *diag));
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut val = Vec::new();
        col_ptr.push(0);
        for mut c in cols {
            c.sort_unstable_by_key(|e| e.0);
            for (r, v) in c {
                if !v.is_finite() {
                    return Err(FemError::Factorisation(format!(
                        "a non-finite entry in row {r} of the mixed system"
                    )));
                }
                row_idx.push(r);
                val.push(v);
            }
            col_ptr.push(row_idx.len());
        }
        let sym = faer::sparse::SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        let free_coords = (0..nf / 3)
            .map(|i| mesh.nodes[dofs.owner[3 * i].0 as usize])
            .collect();
        Ok(Stiffness {
            dofs,
            k: SparseColMat::new(sym, val),
            free_coords,
            aux_owner: aux.iter().map(|a| a.0).collect(),
            aux_coords: aux.iter().map(|a| mesh.nodes[a.0 as usize]).collect(),
        })
    }

    /// Unknowns of the system: the free DOFs, then the auxiliary ones.
    pub fn n(&self) -> usize {
        self.k.nrows()
    }

    /// Auxiliary unknowns (pressures) after the free DOFs: 0 for `K` itself.
    pub fn n_aux(&self) -> usize {
        self.aux_owner.len()
    }

    /// Factorises K = LLᵀ (METIS ordering; faer's supernodal or simplicial factorisation as it
    /// sees fit).
    pub fn factorize(&self) -> Result<Factor, FemError> {
        self.factorize_timed(Ordering::default()).map(|(f, _, _)| f)
    }

    /// The fill-reducing permutation of the free DOFs (forward: new → old; inverse), `None`
    /// for faer's AMD.
    fn ordering(&self, ord: Ordering) -> Option<(Vec<usize>, Vec<usize>)> {
        if ord == Ordering::Amd {
            return None;
        }
        // Blocks: each free node's three DOFs with the auxiliary unknowns of that node; the
        // auxiliary unknowns of a clamped node form a block of their own.
        let nf = self.free_coords.len();
        let n = self.n();
        let mut block_of = vec![0usize; n];
        for (d, b) in block_of.iter_mut().enumerate().take(3 * nf) {
            *b = d / 3;
        }
        let mut coords = self.free_coords.clone();
        let mut extra: std::collections::HashMap<u32, usize> = Default::default();
        for (j, &node) in self.aux_owner.iter().enumerate() {
            block_of[3 * nf + j] = match self.dofs.free(node, 0) {
                Some(d) => d / 3,
                None => *extra.entry(node).or_insert_with(|| {
                    coords.push(self.aux_coords[j]);
                    coords.len() - 1
                }),
            };
        }
        let nb = coords.len();
        let mut members: Vec<Vec<usize>> = vec![Vec::new(); nb];
        for (d, &b) in block_of.iter().enumerate() {
            members[b].push(d);
        }
        let k = self.k.symbolic();
        let mut ptr = Vec::with_capacity(nb + 1);
        let mut idx = Vec::new();
        let mut seen = vec![usize::MAX; nb];
        ptr.push(0);
        for (b, m) in members.iter().enumerate() {
            seen[b] = b;
            for &d in m {
                for r in k.row_idx_of_col(d) {
                    let rb = block_of[r];
                    if seen[rb] != b {
                        seen[rb] = b;
                        idx.push(rb);
                    }
                }
            }
            ptr.push(idx.len());
        }
        let order = match ord {
            Ordering::Metis => {
                metis_order(&ptr, &idx).unwrap_or_else(|| nested_dissection(&coords, &ptr, &idx))
            }
            _ => nested_dissection(&coords, &ptr, &idx),
        };
        let fwd: Vec<usize> = order
            .iter()
            .flat_map(|&b| members[b].iter().copied())
            .collect();
        let mut inv = vec![0usize; fwd.len()];
        for (new, &old) in fwd.iter().enumerate() {
            inv[old] = new;
        }
        Some((fwd, inv))
    }

    /// As [`Stiffness::factorize`] with the ordering `ord`, with the seconds spent on the
    /// symbolic (ordering) and the numeric factorisation.
    pub fn factorize_timed(&self, ord: Ordering) -> Result<(Factor, f64, f64), FemError> {
        // faer splits the big fronts' dense work over the cores; the bits do not depend on
        // how many (tests/precompute.rs), so merged shards made on different machines still
        // equal the unsharded file.
        self.factorize_with(ord, faer::Par::rayon(0))
    }

    /// As [`Stiffness::factorize_timed`] with the numeric factorisation's parallelism `par`.
    pub fn factorize_with(
        &self,
        ord: Ordering,
        par: faer::Par,
    ) -> Result<(Factor, f64, f64), FemError> {
        let (symbolic, sym_s) = self.analyse(ord)?;
        let t1 = std::time::Instant::now();
        let f = self.numeric_heap(symbolic, par)?;
        Ok((f, sym_s, t1.elapsed().as_secs_f64()))
    }

    /// As [`Stiffness::factorize_timed`], with the factor kept where `store` says.
    pub fn factorize_in(
        &self,
        ord: Ordering,
        store: &FactorStore,
    ) -> Result<(Factor, f64, f64), FemError> {
        let (symbolic, sym_s) = self.analyse(ord)?;
        let t1 = std::time::Instant::now();
        let supernodal = matches!(
            symbolic.raw(),
            faer::sparse::linalg::cholesky::SymbolicCholeskyRaw::Supernodal(_)
        );
        let bytes = 8 * symbolic.len_val();
        let f = match store {
            FactorStore::File { dir, threads } if supernodal => {
                let file = crate::frontal::factor_file(dir, bytes)?;
                self.numeric_file(symbolic, &file, *threads)?
            }
            FactorStore::Auto {
                dir,
                threads,
                above,
            } if supernodal && bytes > *above => {
                // No room for the file (or no directory): memory, as before.
                match crate::frontal::factor_file(dir, bytes) {
                    Ok(file) => self.numeric_file(symbolic, &file, *threads)?,
                    Err(_) => self.numeric_heap(symbolic, faer::Par::rayon(0))?,
                }
            }
            _ => self.numeric_heap(symbolic, faer::Par::rayon(0))?,
        };
        Ok((f, sym_s, t1.elapsed().as_secs_f64()))
    }

    /// The ordering and faer's symbolic analysis, with its seconds.
    fn analyse(
        &self,
        ord: Ordering,
    ) -> Result<(faer::sparse::linalg::cholesky::SymbolicCholesky<usize>, f64), FemError> {
        use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, SymmetricOrdering};
        let t0 = std::time::Instant::now();
        let perm = self.ordering(ord);
        let ordering = match &perm {
            None => SymmetricOrdering::Amd,
            Some((fwd, inv)) => {
                SymmetricOrdering::Custom(faer::perm::PermRef::new_checked(fwd, inv, self.n()))
            }
        };
        // A mixed system is factorised with signed pivots by the supernodal code only.
        let mut params = faer::sparse::linalg::cholesky::CholeskySymbolicParams::default();
        if self.n_aux() > 0 {
            params.supernodal_flop_ratio_threshold =
                faer::sparse::linalg::SupernodalThreshold::FORCE_SUPERNODAL;
        }
        let symbolic =
            factorize_symbolic_cholesky(self.k.symbolic(), Side::Lower, ordering, params)
                .map_err(|e| FemError::Factorisation(format!("{e:?}")))?;
        Ok((symbolic, t0.elapsed().as_secs_f64()))
    }

    /// The DOF's node, for errors.
    fn owner_of(&self, dof: usize) -> u32 {
        match dof.checked_sub(self.dofs.n_free) {
            None => self.dofs.owner.get(dof).map_or(0, |o| o.0),
            Some(j) => self.aux_owner.get(j).copied().unwrap_or(0),
        }
    }

    /// Whether each factor column (in elimination order) is an auxiliary unknown, whose
    /// pivot is negative; empty for `K` itself.
    fn negative_columns(
        &self,
        symbolic: &faer::sparse::linalg::cholesky::SymbolicCholesky<usize>,
    ) -> Vec<bool> {
        if self.n_aux() == 0 {
            return Vec::new();
        }
        let nf = self.dofs.n_free;
        match symbolic.perm() {
            Some(p) => p.arrays().0.iter().map(|&d| d >= nf).collect(),
            None => (0..self.n()).map(|d| d >= nf).collect(),
        }
    }

    /// faer's numeric factorisation, on the heap: `LLᵀ`, or for a mixed system `LDLᵀ`
    /// turned into the signed form `G Σ Gᵀ` ([`Factor`]).
    fn numeric_heap(
        &self,
        symbolic: faer::sparse::linalg::cholesky::SymbolicCholesky<usize>,
        par: faer::Par,
    ) -> Result<Factor, FemError> {
        use faer::dyn_stack::{MemBuffer, MemStack};
        let fact_err = |e: &dyn std::fmt::Debug| FemError::Factorisation(format!("{e:?}"));
        let mut values = Vec::new();
        values
            .try_reserve_exact(symbolic.len_val())
            .map_err(|e| fact_err(&e))?;
        values.resize(symbolic.len_val(), 0.0f64);
        // `index` is in the permuted order; name the DOF's node as best we can.
        let singular = |index: usize| {
            let dof = symbolic
                .perm()
                .map_or(index, |p| p.arrays().0.get(index).copied().unwrap_or(0))
                .min(self.n().saturating_sub(1));
            FemError::Singular {
                node: self.owner_of(dof),
                dof,
            }
        };
        let negative = self.negative_columns(&symbolic);
        if negative.is_empty() {
            let mut buf = MemBuffer::try_new(
                symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
            )
            .map_err(|e| fact_err(&e))?;
            symbolic
                .factorize_numeric_llt::<f64>(
                    &mut values,
                    self.k.as_ref(),
                    Side::Lower,
                    Default::default(),
                    par,
                    MemStack::new(&mut buf),
                    Default::default(),
                )
                .map_err(|e| {
                    let faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } =
                        e;
                    singular(index)
                })?;
        } else {
            let mut buf = MemBuffer::try_new(
                symbolic.factorize_numeric_ldlt_scratch::<f64>(par, Default::default()),
            )
            .map_err(|e| fact_err(&e))?;
            symbolic
                .factorize_numeric_ldlt::<f64>(
                    &mut values,
                    self.k.as_ref(),
                    Side::Lower,
                    Default::default(),
                    par,
                    MemStack::new(&mut buf),
                    Default::default(),
                )
                .map_err(|e| {
                    let faer::linalg::cholesky::ldlt::factor::LdltError::ZeroPivot { index } = e;
                    singular(index)
                })?;
            let faer::sparse::linalg::cholesky::SymbolicCholeskyRaw::Supernodal(sn) =
                symbolic.raw()
            else {
                return Err(FemError::Factorisation(
                    "a mixed system needs a supernodal analysis".into(),
                ));
            };
            let vp = sn.col_ptr_for_val();
            for sup in 0..sn.n_supernodes() {
                let b0 = sn.supernode_begin()[sup];
                let ns = sn.supernode_end()[sup] - b0;
                let m = ns + sn.supernode(sup).pattern().len();
                let block = &mut values[vp[sup]..vp[sup + 1]];
                for j in 0..ns {
                    crate::frontal::signed_column(
                        &mut block[j * m..(j + 1) * m],
                        j,
                        negative[b0 + j],
                    )
                    .map_err(|()| singular(b0 + j))?;
                }
            }
        }
        Ok(Factor {
            symbolic,
            values: crate::frontal::Values::Heap(values),
            front_bytes: 0,
            negative,
        })
    }

    /// The out-of-core multifrontal factorisation of [`crate::frontal`] (`symbolic` must be
    /// supernodal): the factor goes to `file` ([`crate::frontal::factor_file`]) and is read
    /// back through a map.
    fn numeric_file(
        &self,
        symbolic: faer::sparse::linalg::cholesky::SymbolicCholesky<usize>,
        file: &std::fs::File,
        threads: usize,
    ) -> Result<Factor, FemError> {
        let faer::sparse::linalg::cholesky::SymbolicCholeskyRaw::Supernodal(sn) = symbolic.raw()
        else {
            return Err(FemError::Factorisation(
                "the out-of-core factorisation needs a supernodal analysis".into(),
            ));
        };
        let n = self.n();
        let negative = self.negative_columns(&symbolic);
        let (fwd, inv): (Vec<usize>, Vec<usize>) = match symbolic.perm() {
            Some(p) => (p.arrays().0.to_vec(), p.arrays().1.to_vec()),
            None => ((0..n).collect(), (0..n).collect()),
        };
        let owner = |dof: usize| self.owner_of(dof);
        let order = crate::frontal::Elimination {
            fwd: &fwd,
            inv: &inv,
            negative: &negative,
        };
        let (values, front_bytes) =
            crate::frontal::factorize_to_file(sn, self.k.as_ref(), order, file, threads, &owner)?;
        Ok(Factor {
            symbolic,
            values,
            front_bytes,
            negative,
        })
    }

    /// y = K·x over the system's unknowns (for a mixed system, the mixed matrix's product).
    pub fn mul(&self, x: &[f64], y: &mut [f64]) {
        y.iter_mut().for_each(|v| *v = 0.0);
        let k = self.k.as_ref();
        for (c, &xc) in x.iter().enumerate().take(k.ncols()) {
            if xc == 0.0 {
                continue;
            }
            for (r, v) in k.row_idx_of_col(c).zip(k.val_of_col(c)) {
                y[r] += v * xc;
            }
        }
    }
}

/// The factor of the system: `P K Pᵀ = G Gᵀ` (Cholesky) for `K`; for a mixed system
/// ([`locking_free::mixed`], quasi-definite), `P K Pᵀ = G Σ Gᵀ` with `Σ = diag(±1)`: −1 at the
/// auxiliary unknowns' columns. `G` has a positive diagonal either way, so forward solves
/// are the same; the solves and the Gram product put `Σ` between.
pub struct Factor {
    symbolic: faer::sparse::linalg::cholesky::SymbolicCholesky<usize>,
    values: crate::frontal::Values,
    /// Peak bytes of the out-of-core factorisation's fronts and update stacks (0 on the heap).
    front_bytes: usize,
    /// Per factor column, whether `Σ` is −1 there; empty when `Σ = I`.
    negative: Vec<bool>,
}

impl Factor {
    /// Solves K X = B in place (B has a row per unknown of the system — the free DOFs, then
    /// any auxiliary ones — and m columns), on the calling thread.
    pub fn solve_in_place(&self, b: &mut Mat<f64>) {
        use faer::dyn_stack::{MemBuffer, MemStack};
        if !self.negative.is_empty() {
            // The signed form: forward, Σ, back, in the factor's order.
            let pos = self.position_of_dof();
            let mut x = Mat::<f64>::zeros(b.nrows(), b.ncols());
            for j in 0..b.ncols() {
                for (d, &p) in pos.iter().enumerate() {
                    x[(p, j)] = b[(d, j)];
                }
            }
            self.solve_in_factor_order(x.as_mut());
            for j in 0..b.ncols() {
                for (d, &p) in pos.iter().enumerate() {
                    b[(d, j)] = x[(p, j)];
                }
            }
            return;
        }
        let llt =
            faer::sparse::linalg::cholesky::LltRef::new(&self.symbolic, self.values.as_slice());
        let mut buf = MemBuffer::new(
            self.symbolic
                .solve_in_place_scratch::<f64>(b.ncols(), faer::Par::Seq),
        );
        llt.solve_in_place_with_conj(
            faer::Conj::No,
            b.as_mut(),
            faer::Par::Seq,
            MemStack::new(&mut buf),
        );
    }

    /// Solves `K X = B` in place with `B`'s rows in the factor's order (the elimination order):
    /// forward, `Σ`, back, over every supernode (a supernodal factor only; else nothing).
    pub(crate) fn solve_in_factor_order(&self, x: MatMut<'_, f64>) {
        let Some((sym, _)) = self.supernodal() else {
            return;
        };
        let all = vec![true; sym.n_supernodes()];
        self.sweeps(x, &all, &all);
    }

    /// The forward sweep `G⁻¹` over the supernodes `reach`, `Σ`, and the back sweep `G⁻ᵀ` over
    /// `keep`, on `x` in the factor's order.
    pub(crate) fn sweeps(&self, mut x: MatMut<'_, f64>, reach: &[bool], keep: &[bool]) {
        let f = self;
        let Some((sym, val)) = f.supernodal() else {
            return;
        };
        let nsn = sym.n_supernodes();
        let k = x.ncols();
        let vp = sym.col_ptr_for_val();
        let mut tmp: Vec<f64> = Vec::new();
        let (begin, end) = (sym.supernode_begin(), sym.supernode_end());
        let block = |s: usize| {
            let pattern = sym.supernode(s).pattern();
            let ns = end[s] - begin[s];
            let ls =
                MatRef::from_column_major_slice(&val[vp[s]..vp[s + 1]], ns + pattern.len(), ns);
            (begin[s], ns, pattern, ls)
        };
        // Values passed since the last release: the forward sweep climbs the values, the back
        // sweep descends them.
        let mut passed = crate::frontal::Passed::default();
        let mut pass = |s: usize| {
            if let Some(r) = passed.add(vp[s]..vp[s + 1]) {
                f.release(r);
            }
        };
        for s in (0..nsn).filter(|&s| reach[s]) {
            let (start, ns, pattern, ls) = block(s);
            let (l11, l21) = ls.split_at_row(ns);
            let npat = pattern.len();
            let mut xs = x.rb_mut().subrows_mut(start, ns);
            faer::linalg::triangular_solve::solve_lower_triangular_in_place(
                l11,
                xs.rb_mut(),
                Par::Seq,
            );
            tmp.clear();
            tmp.resize(npat * k, 0.0);
            let mut t = MatMut::from_column_major_slice_mut(&mut tmp, npat, k);
            faer::linalg::matmul::matmul(t.rb_mut(), Accum::Replace, l21, xs.rb(), 1.0, Par::Seq);
            for j in 0..k {
                let tc = &tmp[j * npat..][..npat];
                let mut xc = x.rb_mut().col_mut(j);
                for (&r, v) in pattern.iter().zip(tc) {
                    xc[r] -= *v;
                }
            }
            pass(s);
        }
        for (r, _) in f.negative().iter().enumerate().filter(|(_, &n)| n) {
            for j in 0..k {
                x[(r, j)] = -x[(r, j)];
            }
        }
        for s in (0..nsn).rev().filter(|&s| keep[s]) {
            let (start, ns, pattern, ls) = block(s);
            let (l11, l21) = ls.split_at_row(ns);
            let npat = pattern.len();
            tmp.clear();
            tmp.resize(npat * k, 0.0);
            for j in 0..k {
                let xc = x.rb().col(j);
                for (t, &r) in tmp[j * npat..][..npat].iter_mut().zip(pattern) {
                    *t = xc[r];
                }
            }
            let t = MatRef::from_column_major_slice(&tmp, npat, k);
            let mut xs = x.rb_mut().subrows_mut(start, ns);
            faer::linalg::matmul::matmul(
                xs.rb_mut(),
                Accum::Add,
                l21.transpose(),
                t,
                -1.0,
                Par::Seq,
            );
            faer::linalg::triangular_solve::solve_upper_triangular_in_place(
                l11.transpose(),
                xs.rb_mut(),
                Par::Seq,
            );
            pass(s);
        }
        if let Some(r) = passed.rest() {
            f.release(r);
        }
    }

    /// Whether the values stream from a file ([`FactorStore::File`]).
    pub fn is_mapped(&self) -> bool {
        self.values.is_mapped()
    }

    /// Drops this process's pages of the values `range` when they stream from a file (see
    /// [`crate::frontal::Values::release`]).
    pub fn release(&self, range: std::ops::Range<usize>) {
        self.values.release(range);
    }

    /// Peak bytes of the out-of-core factorisation's fronts and update stacks (0 for faer's).
    pub fn front_bytes(&self) -> usize {
        self.front_bytes
    }

    /// Per factor column, whether `Σ` is −1 there (see [`Factor`]); empty when `Σ = I`.
    pub(crate) fn negative(&self) -> &[bool] {
        &self.negative
    }

    /// Non-zeros of the Cholesky factor.
    pub fn nonzeros(&self) -> usize {
        self.symbolic.len_val()
    }

    /// The supernodal structure and values of the factor of the permuted K, or `None` when
    /// faer chose a simplicial factorisation (small or very sparse K).
    pub fn supernodal(
        &self,
    ) -> Option<(
        &faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky<usize>,
        &[f64],
    )> {
        match self.symbolic.raw() {
            faer::sparse::linalg::cholesky::SymbolicCholeskyRaw::Supernodal(s) => {
                Some((s, self.values.as_slice()))
            }
            _ => None,
        }
    }

    /// The position of each free DOF in the factor's elimination order.
    pub(crate) fn position_of_dof(&self) -> Vec<usize> {
        match self.symbolic.perm() {
            Some(p) => p.arrays().1.to_vec(),
            None => (0..self.symbolic.nrows()).collect(),
        }
    }
}

/// Solves the static problem K u = f on the whole mesh (a fresh factorisation): `forces` are
/// (node, force in N); returns the displacement of every node in metres (zero on clamped nodes).
/// This is the direct reference that the precomputed `L·F` must reproduce.
pub fn solve_static(mesh: &Mesh, forces: &[(u32, DVec3)]) -> Result<Vec<DVec3>, FemError> {
    Stiffness::assemble(mesh)?.solve(mesh.nodes.len(), forces)
}

impl Stiffness {
    /// Solves `K u = f` (a fresh factorisation) for `forces` (node, force in N) on a mesh of
    /// `nodes` nodes; returns every node's displacement in metres (zero on clamped nodes).
    pub fn solve(&self, nodes: usize, forces: &[(u32, DVec3)]) -> Result<Vec<DVec3>, FemError> {
        let factor = self.factorize()?;
        let mut b = Mat::<f64>::zeros(self.n(), 1);
        for &(node, f) in forces {
            if node as usize >= nodes {
                return Err(FemError::BadSelection(format!(
                    "force on node {node} out of range"
                )));
            }
            for a in 0..3 {
                if let Some(d) = self.dofs.free(node, a) {
                    b[(d, 0)] += f[a];
                }
            }
        }
        factor.solve_in_place(&mut b);
        let mut u = vec![DVec3::ZERO; nodes];
        for (d, &(node, a)) in self.dofs.owner.iter().enumerate() {
            if let Some(v) = u.get_mut(node as usize) {
                v[a as usize] = b[(d, 0)];
            }
        }
        Ok(u)
    }
}

/// Checks that every connected part of the mesh has at least three non-collinear clamped nodes.
fn check_constrained(mesh: &Mesh) -> Result<(), FemError> {
    if mesh.fixed_count() == 0 {
        return Err(FemError::NoFixedNodes);
    }
    let n = mesh.nodes.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    for t in &mesh.tets {
        for &v in &t[1..] {
            join(&mut parent, t[0], v);
        }
    }
    // Per component: node count, fixed nodes.
    let mut comp_nodes: std::collections::HashMap<u32, (usize, Vec<DVec3>)> = Default::default();
    for i in 0..n as u32 {
        let r = root(&mut parent, i);
        let e = comp_nodes.entry(r).or_insert((0, Vec::new()));
        e.0 += 1;
        if mesh.fixed[i as usize] {
            e.1.push(mesh.nodes[i as usize]);
        }
    }
    let (lo, hi) = mesh.bounds();
    let scale = (hi - lo).length().max(f64::MIN_POSITIVE);
    for (root, (count, fixed)) in comp_nodes {
        // (A part clamped at every node has no free DOF: nothing there can move. A cut's
        // rebased body has such parts: nodes left with no tet, held still.)
        let ok = fixed.len() == count || (fixed.len() >= 3 && !collinear(&fixed, scale));
        if !ok {
            return Err(FemError::Unconstrained {
                part_nodes: count,
                example_node: root,
                fixed_in_part: fixed.len(),
                how: if fixed.len() >= 3 {
                    "that are collinear"
                } else {
                    ""
                },
            });
        }
    }
    Ok(())
}

/// The root of `x` in the union–find forest `parent` (path halving).
pub(crate) fn root(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        parent[x as usize] = parent[parent[x as usize] as usize];
        x = parent[x as usize];
    }
    x
}

/// Joins the sets of `a` and `b` in the union–find forest `parent`.
pub(crate) fn join(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (root(parent, a), root(parent, b));
    if ra != rb {
        parent[rb as usize] = ra;
    }
}

/// True when all points lie (to 1e-9 of `scale`) on one line.
pub(crate) fn collinear(p: &[DVec3], scale: f64) -> bool {
    let a = p[0];
    let Some(b) = p.iter().copied().max_by(|x, y| {
        x.distance(a)
            .partial_cmp(&y.distance(a))
            .unwrap_or(std::cmp::Ordering::Equal)
    }) else {
        return true;
    };
    let d = b - a;
    if d.length() <= 1e-9 * scale {
        return true;
    }
    let dir = d.normalize();
    p.iter()
        .all(|&q| (q - a).cross(dir).length() <= 1e-9 * scale)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::cube;

    /// The direct CSC assembly equals the dense assembly of the element matrices on the free
    /// DOFs (to round-off: the sums run in another order), zero off its pattern.
    #[test]
    fn direct_assembly_equals_the_dense_assembly() {
        let mesh =
            crate::mesh::cube_with([5, 4, 6], [30.0, 20.0, 40.0], Material::DEFAULT).expect("mesh");
        let k = Stiffness::assemble(&mesh).unwrap();
        let dense = dense_stiffness(&mesh);
        let owner = &k.dofs.owner;
        let max = dense.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut seen = 0usize;
        for (c, &(nc, ac)) in owner.iter().enumerate() {
            let rows = k.k.symbolic().row_idx_of_col(c).collect::<Vec<_>>();
            assert!(rows.windows(2).all(|w| w[0] < w[1]), "sorted, no repeats");
            let vals = k.k.val_of_col(c);
            for (r, &(nr, ar)) in owner.iter().enumerate() {
                let want = dense[3 * nr as usize + ar as usize][3 * nc as usize + ac as usize];
                let got = rows.iter().position(|&x| x == r).map_or(0.0, |i| vals[i]);
                assert!(
                    (got - want).abs() <= 1e-13 * max,
                    "({r}, {c}): {got} vs {want}"
                );
            }
            seen += rows.len();
        }
        assert_eq!(seen, k.k.compute_nnz());
        assert!(max > 0.0);
    }

    #[test]
    fn element_stiffness_is_symmetric_and_kills_rigid_modes() {
        let p = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.1, 0.0),
            DVec3::new(0.2, 1.0, 0.1),
            DVec3::new(0.1, 0.3, 1.2),
        ];
        let k = element_stiffness(p, &Material::DEFAULT);
        for (i, row) in k.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                assert!((v - k[j][i]).abs() < 1e-12 * 1000.0);
            }
        }
        // Translation along x and rotation about z.
        let mut t = [0.0; 12];
        let mut r = [0.0; 12];
        for a in 0..4 {
            t[3 * a] = 1.0;
            r[3 * a] = -p[a].y;
            r[3 * a + 1] = p[a].x;
        }
        for v in [t, r] {
            for row in &k {
                let s: f64 = row.iter().zip(&v).map(|(a, b)| a * b).sum();
                assert!(s.abs() < 1e-10, "{s}");
            }
        }
    }

    #[test]
    fn cube_assembles_and_factorizes() {
        let m = cube();
        let s = Stiffness::assemble(&m).unwrap();
        assert_eq!(s.dofs.n_free, (125 - 25) * 3);
        s.factorize().unwrap();
    }
}
