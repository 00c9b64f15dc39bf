//! A cut's columns of `L₀` solved up front ([`super::columns`]), and `L_D` grown by the
//! columns a pass brings into `D`: read where held, solved otherwise.

use std::sync::Arc;

use super::body::Cut;
use super::columns::{Columns, BLOCK, BUDGET};

/// The rank `L_D`'s first room holds (within [`BUDGET`]): a blade's passes before a fold.
const LD_RANKS: usize = 1024;

impl Cut {
    /// Solves and keeps `L₀`'s columns at the free DOFs of the marked nodes (those of the
    /// factored body; `nodes` is over every node, copies past it ignored), in blocks of
    /// [`BLOCK`]. Keeps none when they would take more than [`BUDGET`] bytes. Returns how
    /// many it keeps.
    pub fn precompute_columns(&mut self, nodes: &[bool]) -> usize {
        self.precompute_columns_on(nodes, None)
    }

    /// [`Cut::precompute_columns`], the blocks shared with a helper thread that runs on
    /// `helper`'s cores in their idle time (the haptic loop's: native builds; the same bits,
    /// each block solved alone; [`crate::threads::share_jobs`]). A block the helper fails to
    /// finish is solved again by this thread.
    pub fn precompute_columns_on(&mut self, nodes: &[bool], helper: Option<&[usize]>) -> usize {
        let Some(dofs) = self.column_dofs(nodes) else {
            self.columns = None;
            return 0;
        };
        let nf = self.dofs.n_free;
        let mut cols = vec![0.0; dofs.len() * nf];
        let blocks = dofs.chunks(BLOCK);
        let lost = {
            let jobs = blocks.clone().zip(cols.chunks_mut(BLOCK * nf));
            let this = &*self;
            let helper = helper.filter(|_| blocks.len() > 1);
            crate::threads::share_jobs(jobs, helper, || {}, |(b, out)| this.solve_block(b, out))
        };
        // (A block is solved afresh into its place: one the helper left half made, again.)
        for k in lost {
            let b = blocks.clone().nth(k).expect("a block the helper took");
            self.solve_block(b, &mut cols[k * BLOCK * nf..][..b.len() * nf]);
        }
        self.keep_columns(nodes, &dofs, cols)
    }

    /// The free DOFs of the marked nodes of the factored body, sorted; `None` when there are
    /// none or their columns would take more than [`BUDGET`] bytes.
    pub(super) fn column_dofs(&self, nodes: &[bool]) -> Option<Vec<usize>> {
        let mut dofs = Vec::new();
        for (v, _) in nodes
            .iter()
            .enumerate()
            .take(self.base_nodes)
            .filter(|p| *p.1)
        {
            for a in 0..3 {
                if let Some(f) = self.dofs.free(v as u32, a) {
                    dofs.push(f);
                }
            }
        }
        dofs.sort_unstable();
        dofs.dedup();
        let bytes = dofs
            .len()
            .saturating_mul(self.dofs.n_free)
            .saturating_mul(8);
        (!dofs.is_empty() && bytes <= BUDGET).then_some(dofs)
    }

    /// `L₀`'s columns at the free DOFs `block`, solved together into `out` (`n_free` rows
    /// each).
    pub(super) fn solve_block(&self, block: &[usize], out: &mut [f64]) {
        let nf = self.dofs.n_free;
        let mut b = faer::Mat::<f64>::zeros(nf, block.len());
        for (j, &f) in block.iter().enumerate() {
            b[(f, j)] = 1.0;
        }
        self.factor.solve_in_place(&mut b);
        for (j, col) in out.chunks_exact_mut(nf).enumerate() {
            for (i, o) in col.iter_mut().enumerate() {
                *o = b[(i, j)];
            }
        }
    }

    /// Holds `cols` (`n_free` rows each) as the columns of `dofs` ([`Cut::column_dofs`] of
    /// the marked `nodes`); returns how many.
    pub(super) fn keep_columns(&mut self, nodes: &[bool], dofs: &[usize], cols: Vec<f64>) -> usize {
        let nf = self.dofs.n_free;
        let mut at = vec![u32::MAX; nf];
        for (k, &f) in dofs.iter().enumerate() {
            at[f] = k as u32;
        }
        let mut mask = nodes.to_vec();
        mask.resize(self.base_nodes, false);
        self.columns = Some(Arc::new(Columns {
            nodes: mask,
            at,
            cols,
            n_free: nf,
        }));
        dofs.len()
    }
}

impl Cut {
    /// The free DOF of a node of the factored body, or `None`.
    fn base_dof(&self, node: u32, a: usize) -> Option<usize> {
        ((node as usize) < self.base_nodes)
            .then(|| self.dofs.free(node, a))
            .flatten()
    }

    /// The column of `L₀` held up front at `node`'s DOF on axis `a` (the factored body's
    /// free DOFs), if held.
    pub fn held_column(&self, node: u32, a: usize) -> Option<&[f64]> {
        self.columns.as_ref()?.column(self.base_dof(node, a)?)
    }

    /// How many columns of `L₀` this cut holds solved up front.
    pub fn columns_held(&self) -> usize {
        self.columns.as_ref().map_or(0, |c| c.len())
    }

    /// Appends `L₀`'s columns at `new` to `L_D`; the cut lives in `C` alone. A column held
    /// up front is copied, a copy's is `S⁻¹` at its DOF, the others are solved together.
    pub(super) fn grow(&mut self, new: &[usize]) {
        use nalgebra::DMatrix;
        let n = self.n_dofs();
        let nf = self.dofs.n_free;
        let mut b = DMatrix::zeros(n, new.len());
        let mut solve = Vec::new();
        for (j, &f) in new.iter().enumerate() {
            if f >= nf {
                b[(f, j)] = 1.0 / self.diag0[f];
            } else if let Some(col) = self.columns.as_ref().and_then(|c| c.column(f)) {
                b.view_mut((0, j), (nf, 1)).copy_from_slice(col);
            } else {
                solve.push(j);
            }
        }
        if !solve.is_empty() {
            let mut x = DMatrix::zeros(n, solve.len());
            for (k, &j) in solve.iter().enumerate() {
                x[(new[j], k)] = 1.0;
            }
            self.solve0(&mut x);
            for (k, &j) in solve.iter().enumerate() {
                b.column_mut(j).copy_from(&x.column(k));
            }
        }
        let old = self.d.len();
        let m = old + new.len();
        // Appended (column-major: the new columns go at the end of the same storage), into
        // room that grows by doubling: `L_D` is tens of megabytes at rank 500, and grown to
        // the exact size each pass the allocator copied it whole where it could not extend
        // it in place (20–70 ms a pass in the incision).
        let rows = self.ld.nrows();
        let mut data: Vec<f64> = std::mem::replace(&mut self.ld, DMatrix::zeros(0, 0))
            .data
            .into();
        // (At first, room for `LD_RANKS` columns: pages not yet written cost nothing, and the
        // first doublings each moved `L_D`, 5–7 ms a pass at rank 300 on the phantom.)
        let room = (rows * LD_RANKS).min(BUDGET / 8).max(rows * m);
        data.reserve(room - data.len());
        for col in b.column_iter() {
            data.extend_from_slice(col.as_slice());
            data.resize(data.len() + rows - n, 0.0);
        }
        self.ld = DMatrix::from_vec(rows, m, data);
        let mut dk = DMatrix::zeros(m, m);
        dk.view_mut((0, 0), (old, old)).copy_from(&self.dk);
        self.dk = dk;
        self.d.extend_from_slice(new);
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    /// `L_D` grows into room that doubles: over twenty cuts on the cube, each bringing new
    /// DOFs into `D`, its storage is moved only when the room runs out (a handful of times),
    /// not once a cut, and always holds what it must.
    #[cfg_attr(test, test)]
    pub(crate) fn l_d_grows_into_room_that_doubles() {
        let mesh = crate::mesh::cube();
        let mut cut = Cut::new(&mesh).expect("the cube factors");
        let (mut grown, mut moved, mut cap) = (0, 0, 0);
        let mut first = 0;
        for t in (0..mesh.tets.len()).step_by(17).take(20) {
            let rank = cut.rank();
            cut.remove(&mesh, &[t]).expect("a tet removed");
            if cut.rank() == rank {
                continue;
            }
            grown += 1;
            let v = cut.ld.data.as_vec();
            assert_eq!(v.len(), cut.ld.nrows() * cut.rank());
            assert!(v.capacity() >= v.len());
            if first == 0 {
                first = v.len();
            }
            if v.capacity() != cap {
                moved += 1;
                cap = v.capacity();
            }
        }
        let last = cut.ld.len();
        let doublings = (last as f64 / first as f64).log2().ceil() as usize;
        eprintln!("L_D grew {grown} times from {first} to {last} entries, moved {moved} times");
        assert!(grown >= 15, "{grown} cuts grew D");
        // (Each move at least doubles the room, which may end up to twice the entries.)
        assert!(
            moved <= doublings + 2,
            "moved {moved} times in {grown} growths"
        );
    }
}
