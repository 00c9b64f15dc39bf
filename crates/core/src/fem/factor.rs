//! The factor of `K` (or of a mixed system), on the heap or in a file.

use faer::reborrow::{Reborrow, ReborrowMut};
use faer::{Accum, Mat, MatMut, MatRef, Par};

/// The factor of the system: `P K Pᵀ = G Gᵀ` (Cholesky) for `K`; for a mixed system
/// ([`super::locking_free::mixed`], quasi-definite), `P K Pᵀ = G Σ Gᵀ` with `Σ = diag(±1)`:
/// −1 at the auxiliary unknowns' columns. `G` has a positive diagonal either way, so forward
/// solves are the same; the solves and the Gram product put `Σ` between.
pub struct Factor {
    pub(super) symbolic: faer::sparse::linalg::cholesky::SymbolicCholesky<usize>,
    pub(super) values: crate::fem::frontal::Values,
    /// Peak bytes of the out-of-core factorisation's fronts and update stacks (0 on the heap).
    pub(super) front_bytes: usize,
    /// Per factor column, whether `Σ` is −1 there; empty when `Σ = I`.
    pub(super) negative: Vec<bool>,
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
        let mut passed = crate::fem::frontal::Passed::default();
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

    /// Whether the values stream from a file ([`FactorStore::File`](super::FactorStore::File)).
    pub fn is_mapped(&self) -> bool {
        self.values.is_mapped()
    }

    /// Drops this process's pages of the values `range` when they stream from a file (see
    /// [`crate::fem::frontal::Values::release`]).
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
