//! A rebased cut's columns of `L₀` derived from the cut it comes from instead of solved
//! again: the rebased body's `K₀` is the old cut's `K′`, so its columns are `L′`'s, which the
//! old cut holds exactly as `L′[:, f] = L₀[:, f] + L_D C L_D[f, :]ᵀ` (the Woodbury
//! identity of [`super`]). One matrix product of `n × rank × m` multiply-adds, about a
//! quarter of the time of `m` solves on the phantom; a column the old cut could not give
//! (its DOF neither held nor in `D`) is solved.

use faer::{MatMut, MatRef};

use super::body::Cut;
use super::columns::{Derive, BLOCK};
use crate::compliance::product_seq;

/// Columns derived at once (bounds the scratch: `n × CHUNK` doubles).
const CHUNK: usize = 256;

impl Cut {
    /// What [`Cut::derive_columns`] on this cut's rebase needs (`None`: no columns held).
    pub(super) fn derive_from(&self) -> Option<Derive> {
        let columns = self.columns.clone()?;
        let n = self.n_dofs();
        let r = self.d.len();
        let ld = self.ld.view((0, 0), (n, r)).into_owned();
        let dof = (0..self.nodes.len() as u32)
            .map(|v| [0, 1, 2].map(|a| self.dof(v, a).map_or(u32::MAX, |f| f as u32)))
            .collect();
        Some(Derive {
            columns,
            ld,
            cap: self.cap.clone(),
            place: self.place.clone(),
            diag0: self.diag0.clone(),
            dof,
        })
    }

    /// Keeps `L₀`'s columns at the free DOFs of the marked nodes as
    /// [`Cut::precompute_columns`] does, derived from the cut this one was rebased from
    /// (`from`) where it can give them, solved otherwise. Returns how many it keeps.
    pub(super) fn derive_columns(&mut self, nodes: &[bool], from: &Derive) -> usize {
        let Some(dofs) = self.column_dofs(nodes) else {
            self.columns = None;
            return 0;
        };
        let nf = self.dofs.n_free;
        // Each new DOF's row in the old numbering (`u32::MAX`: none).
        let mut old_row = vec![u32::MAX; nf];
        for v in 0..self.base_nodes {
            for a in 0..3 {
                if let Some(g) = self.dofs.free(v as u32, a) {
                    old_row[g] = from.dof.get(v).map_or(u32::MAX, |d| d[a]);
                }
            }
        }
        let (n_old, r) = from.ld.shape();
        let old_nf = from.columns.n_free;
        let mut cols = vec![0.0; dofs.len() * nf];
        let mut solve: Vec<usize> = Vec::new();
        for (k, chunk) in dofs.chunks(CHUNK).enumerate() {
            let m = chunk.len();
            // L₀'s columns at the old DOFs, and their rows of L_D (transposed); whether the
            // old cut could give each.
            let mut a = vec![0.0; n_old * m];
            let mut w = vec![0.0; r * m];
            let mut given = vec![false; m];
            for (j, &g) in chunk.iter().enumerate() {
                let f = old_row[g] as usize;
                if f >= n_old {
                    continue;
                }
                let col = &mut a[j * n_old..][..n_old];
                let p = from.place[f];
                if p != u32::MAX {
                    col.copy_from_slice(from.ld.column(p as usize).as_slice());
                } else if let Some(c) = from.columns.column(f) {
                    col[..old_nf].copy_from_slice(c);
                } else if f >= old_nf {
                    col[f] = 1.0 / from.diag0[f];
                } else {
                    continue;
                }
                given[j] = true;
                for q in 0..r {
                    w[j * r + q] = from.ld[(f, q)];
                }
            }
            if r > 0 {
                // A += L_D (C W).
                let mut z = vec![0.0; r * m];
                product_seq(
                    MatMut::from_column_major_slice_mut(&mut z, r, m),
                    MatRef::from_column_major_slice(from.cap.as_slice(), r, r),
                    MatRef::from_column_major_slice(&w, r, m),
                    false,
                );
                product_seq(
                    MatMut::from_column_major_slice_mut(&mut a, n_old, m),
                    MatRef::from_column_major_slice(from.ld.as_slice(), n_old, r),
                    MatRef::from_column_major_slice(&z, r, m),
                    true,
                );
            }
            for j in 0..m {
                let col = k * CHUNK + j;
                if !given[j] {
                    solve.push(col);
                    continue;
                }
                let src = &a[j * n_old..][..n_old];
                let out = &mut cols[col * nf..][..nf];
                for (o, &i) in out.iter_mut().zip(&old_row) {
                    *o = src.get(i as usize).copied().unwrap_or(0.0);
                }
            }
        }
        // The few the old cut could not give, solved with this cut's factor.
        for block in solve.chunks(BLOCK) {
            let dof_block: Vec<usize> = block.iter().map(|&col| dofs[col]).collect();
            let mut out = vec![0.0; block.len() * nf];
            self.solve_block(&dof_block, &mut out);
            for (&col, src) in block.iter().zip(out.chunks_exact(nf)) {
                cols[col * nf..][..nf].copy_from_slice(src);
            }
        }
        self.keep_columns(nodes, &dofs, cols)
    }
}
