//! Linear-elastic constant-strain tetrahedra: element and global stiffness (the paper's eq. 1),
//! elimination of the clamped DOFs, and the sparse factorisation of `K` (faer's supernodal
//! analysis, METIS ordering): Cholesky, or for the locking-free formulation's mixed system a
//! signed `G Σ Gᵀ` ([`Factor`]).

use faer::sparse::SparseColMat;
use faer::{Mat, Side};
use glam::DVec3;

use crate::mesh::units::Material;
use crate::mesh::Mesh;

pub mod error;
mod factor;
pub mod frontal;
pub mod gram;
pub mod locking_free;
mod numeric;
mod ordering;
pub use error::FemError;
pub use factor::Factor;
pub(crate) use numeric::llt_else_ldlt;
pub use ordering::Ordering;
use ordering::{metis_order, nested_dissection};

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
    /// [`crate::fem::frontal`] on `threads` threads and read through a map (supernodal analyses
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
        self.factorize_with(ord, crate::threads::faer_par())
    }

    /// As [`Stiffness::factorize_timed`] with the numeric factorisation's parallelism `par`.
    pub fn factorize_with(
        &self,
        ord: Ordering,
        par: faer::Par,
    ) -> Result<(Factor, f64, f64), FemError> {
        let (symbolic, sym_s) = self.analyse(ord)?;
        let t1 = crate::threads::Stopwatch::start();
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
        let t1 = crate::threads::Stopwatch::start();
        let supernodal = matches!(
            symbolic.raw(),
            faer::sparse::linalg::cholesky::SymbolicCholeskyRaw::Supernodal(_)
        );
        let bytes = 8 * symbolic.len_val();
        let f = match store {
            FactorStore::File { dir, threads } if supernodal => {
                let file = crate::fem::frontal::factor_file(dir, bytes)?;
                self.numeric_file(symbolic, &file, *threads)?
            }
            FactorStore::Auto {
                dir,
                threads,
                above,
            } if supernodal && bytes > *above => {
                // No room for the file (or no directory): memory, as before.
                match crate::fem::frontal::factor_file(dir, bytes) {
                    Ok(file) => self.numeric_file(symbolic, &file, *threads)?,
                    Err(_) => self.numeric_heap(symbolic, crate::threads::faer_par())?,
                }
            }
            _ => self.numeric_heap(symbolic, crate::threads::faer_par())?,
        };
        Ok((f, sym_s, t1.elapsed().as_secs_f64()))
    }

    /// The ordering and faer's symbolic analysis, with its seconds.
    fn analyse(
        &self,
        ord: Ordering,
    ) -> Result<(faer::sparse::linalg::cholesky::SymbolicCholesky<usize>, f64), FemError> {
        use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, SymmetricOrdering};
        let t0 = crate::threads::Stopwatch::start();
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
        // The one numeric step, written once for both of faer's factorisations.
        macro_rules! numeric {
            ($scratch:ident, $factor:ident) => {
                |values| {
                    let mut buf =
                        MemBuffer::try_new(symbolic.$scratch::<f64>(par, Default::default()))
                            .map_err(|e| fact_err(&e))?;
                    symbolic.$factor::<f64>(
                        values,
                        self.k.as_ref(),
                        Side::Lower,
                        Default::default(),
                        par,
                        MemStack::new(&mut buf),
                        Default::default(),
                    )?;
                    Ok(())
                }
            };
        }
        llt_else_ldlt(
            !negative.is_empty(),
            &mut values,
            numeric!(factorize_numeric_llt_scratch, factorize_numeric_llt),
            numeric!(factorize_numeric_ldlt_scratch, factorize_numeric_ldlt),
            singular,
        )?;
        if !negative.is_empty() {
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
                    crate::fem::frontal::signed_column(
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
            values: crate::fem::frontal::Values::Heap(values),
            front_bytes: 0,
            negative,
        })
    }

    /// The out-of-core multifrontal factorisation of [`crate::fem::frontal`] (`symbolic` must be
    /// supernodal): the factor goes to `file` ([`crate::fem::frontal::factor_file`]) and is read
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
        let order = crate::fem::frontal::Elimination {
            fwd: &fwd,
            inv: &inv,
            negative: &negative,
        };
        let (values, front_bytes) = crate::fem::frontal::factorize_to_file(
            sn,
            self.k.as_ref(),
            order,
            file,
            threads,
            &owner,
        )?;
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

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;
    use crate::mesh::cube;

    /// The direct CSC assembly equals the dense assembly of the element matrices on the free
    /// DOFs (to round-off: the sums run in another order), zero off its pattern.
    #[cfg_attr(test, test)]
    pub(crate) fn direct_assembly_equals_the_dense_assembly() {
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

    #[cfg_attr(test, test)]
    pub(crate) fn element_stiffness_is_symmetric_and_kills_rigid_modes() {
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

    #[cfg_attr(test, test)]
    pub(crate) fn cube_assembles_and_factorizes() {
        let m = cube();
        let s = Stiffness::assemble(&m).unwrap();
        assert_eq!(s.dofs.n_free, (125 - 25) * 3);
        s.factorize().unwrap();
    }
}
