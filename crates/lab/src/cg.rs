//! The iterative alternative to a precomputed `L`: conjugate gradient on the sparse stiffness,
//! preconditioned with its 3×3 node blocks (block Jacobi) and warm-started from the previous
//! frame's solution, so a finger that moves a little between frames costs a few iterations.
//! `touchfem bench` times it per frame at tolerances from 1e-2 to 1e-10 beside the
//! precomputed product and the direct sparse solve.

use glam::{DMat3, DVec3};

use touchfem_core::fem::Stiffness;

/// What one solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct CgStats {
    /// Iterations run.
    pub iterations: usize,
    /// Final `‖b − K x‖ / ‖b‖` (0 for b = 0).
    pub rel_residual: f64,
    /// Whether the tolerance was reached within the iteration limit.
    pub converged: bool,
}

/// A warm-started, block-Jacobi preconditioned CG solver for `K x = b` over the free DOFs.
/// Allocates only in [`CgSolver::new`].
pub(crate) struct CgSolver<'k> {
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

    /// Forgets the warm start.
    #[cfg(test)]
    fn reset(&mut self) {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cg_matches_the_direct_solve_and_warm_starts_cut_the_iterations() {
        let mesh = touchfem_core::mesh::cube();
        let k = Stiffness::assemble(&mesh).unwrap();
        let f = k.factorize().unwrap();
        let n = k.dofs.n_free;
        let mut cg = CgSolver::new(&k);
        let mut b = vec![0.0; n];
        b[n - 1] = -0.1;
        b[n - 5] = 0.05;
        let mut direct = faer::Mat::<f64>::zeros(n, 1);
        for (i, v) in b.iter().enumerate() {
            direct[(i, 0)] = *v;
        }
        f.solve_in_place(&mut direct);
        let cold = cg.solve(&b, 1e-12, 10_000);
        assert!(cold.converged, "{cold:?}");
        let scale = (0..n).map(|i| direct[(i, 0)].abs()).fold(0.0, f64::max);
        let err = (0..n)
            .map(|i| (cg.solution()[i] - direct[(i, 0)]).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-9 * scale, "{err:e} of {scale:e}");
        // A slightly different load (0.1 %) from the last solution: the residual starts 1000×
        // smaller, so CG needs about half the iterations for 1e-6.
        b[n - 1] = -0.1001;
        let warm = cg.solve(&b, 1e-6, 10_000);
        cg.reset();
        let fresh = cg.solve(&b, 1e-6, 10_000);
        assert!(warm.converged && fresh.converged);
        assert!(
            warm.iterations * 3 <= fresh.iterations * 2,
            "warm {} vs cold {}",
            warm.iterations,
            fresh.iterations
        );
        // A zero load is solved by zero.
        let z = cg.solve(&vec![0.0; n], 1e-8, 10);
        assert_eq!(z.iterations, 0);
        assert!(cg.solution().iter().all(|v| *v == 0.0));
    }
}
