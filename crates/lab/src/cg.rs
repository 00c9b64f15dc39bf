//! The iterative alternative to a precomputed `L`: conjugate gradient on the sparse stiffness,
//! preconditioned with its 3×3 node blocks (block Jacobi) and warm-started from the previous
//! frame's solution, so a finger that moves a little between frames costs a few iterations.
//! `touchfem bench` times it per frame at tolerances from 1e-2 to 1e-10 beside the
//! precomputed product and the direct sparse solve.

use glam::{DMat3, DVec3};

use touchfem_core::fem::Stiffness;

/// What one solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CgStats {
    /// Iterations run.
    pub iterations: usize,
    /// Final `‖b − K x‖ / ‖b‖` (0 for b = 0).
    pub rel_residual: f64,
    /// Whether the tolerance was reached within the iteration limit.
    pub converged: bool,
}

/// A warm-started, block-Jacobi preconditioned CG solver for `K x = b` over the free DOFs.
/// Allocates only in [`CgSolver::new`].
pub struct CgSolver<'k> {
    k: &'k Stiffness,
    /// Per free node: its first free DOF and the inverse of its 3×3 diagonal block.
    blocks: Vec<(usize, DMat3)>,
    x: Vec<f64>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

impl<'k> CgSolver<'k> {
    /// A solver for `k`, starting from x = 0.
    pub fn new(k: &'k Stiffness) -> CgSolver<'k> {
        let n = k.dofs.n_free;
        let mat = k.k.as_ref();
        let mut blocks = Vec::with_capacity(n / 3);
        let mut d = 0;
        while d < n {
            let node = k.dofs.owner[d].0;
            let mut b = [[0.0; 3]; 3];
            for (j, col) in b.iter_mut().enumerate() {
                for (r, v) in mat.row_idx_of_col(d + j).zip(mat.val_of_col(d + j)) {
                    if (d..d + 3).contains(&r) {
                        col[r - d] = *v;
                    }
                }
            }
            debug_assert!((0..3).all(|a| k.dofs.owner[d + a].0 == node));
            let m = DMat3::from_cols_array_2d(&b);
            // A positive definite K has positive definite diagonal blocks.
            let inv = touchfem_core::compliance::invert3(m).unwrap_or(DMat3::IDENTITY);
            blocks.push((d, inv));
            d += 3;
        }
        CgSolver {
            k,
            blocks,
            x: vec![0.0; n],
            r: vec![0.0; n],
            z: vec![0.0; n],
            p: vec![0.0; n],
            q: vec![0.0; n],
        }
    }

    /// The current solution (free DOFs, metres).
    pub fn solution(&self) -> &[f64] {
        &self.x
    }

    /// Forgets the warm start: the next solve starts cold, from zero.
    pub fn reset(&mut self) {
        self.x.fill(0.0);
    }

    fn precondition(&mut self) {
        for &(d, inv) in &self.blocks {
            let v = inv * DVec3::new(self.r[d], self.r[d + 1], self.r[d + 2]);
            self.z[d..d + 3].copy_from_slice(&v.to_array());
        }
    }

    /// Solves `K x = b` to `‖b − K x‖ ≤ tol·‖b‖`, starting from the previous solution, in at
    /// most `max_iter` iterations.
    pub fn solve(&mut self, b: &[f64], tol: f64, max_iter: usize) -> CgStats {
        let bn = dot(b, b).sqrt();
        if bn == 0.0 {
            self.x.fill(0.0);
            return CgStats {
                iterations: 0,
                rel_residual: 0.0,
                converged: true,
            };
        }
        self.k.mul(&self.x, &mut self.q);
        for ((r, b), q) in self.r.iter_mut().zip(b).zip(&self.q) {
            *r = b - q;
        }
        let mut rn = dot(&self.r, &self.r).sqrt();
        if rn <= tol * bn {
            return CgStats {
                iterations: 0,
                rel_residual: rn / bn,
                converged: true,
            };
        }
        self.precondition();
        self.p.copy_from_slice(&self.z);
        let mut rz = dot(&self.r, &self.z);
        let mut it = 0;
        while it < max_iter {
            it += 1;
            self.k.mul(&self.p, &mut self.q);
            let pq = dot(&self.p, &self.q);
            // Not positive (or NaN): K is not positive definite along p; stop.
            if pq.is_nan() || pq <= 0.0 {
                break;
            }
            let alpha = rz / pq;
            for i in 0..self.x.len() {
                self.x[i] += alpha * self.p[i];
                self.r[i] -= alpha * self.q[i];
            }
            rn = dot(&self.r, &self.r).sqrt();
            if rn <= tol * bn {
                break;
            }
            self.precondition();
            let rz_new = dot(&self.r, &self.z);
            let beta = rz_new / rz;
            rz = rz_new;
            for (p, z) in self.p.iter_mut().zip(&self.z) {
                *p = z + beta * *p;
            }
        }
        CgStats {
            iterations: it,
            rel_residual: rn / bn,
            converged: rn <= tol * bn,
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
