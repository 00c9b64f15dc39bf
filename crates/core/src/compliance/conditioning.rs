//! Early warning: how well conditioned a body's stiffness is, how well shaped its worst
//! element, and how far storing its compliance in f32 or f16 moves the displayed
//! displacement — measured, not guessed, on the compliance itself.

use glam::DVec3;

use crate::compliance::Compliance;
use crate::fem::Stiffness;
use crate::mesh::Mesh;

/// Storage errors above this get a warning.
pub(crate) const WARN_ERROR: f64 = 1e-3;

/// A body's conditioning.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Conditioning {
    /// Largest eigenvalue of K (power iteration), N/m.
    pub lambda_max: f64,
    /// Smallest eigenvalue of K (inverse iteration with its Cholesky factor), N/m.
    pub lambda_min: f64,
    /// `lambda_max / lambda_min`: the 2-norm condition number of K, estimated.
    pub condition_estimate: f64,
    /// Worst element quality `6V/ℓ³` (regular tet 0.707; validation refuses ≤ 1e-8).
    pub worst_quality: f64,
}

/// Estimates K's extreme eigenvalues with `iters` power and inverse iterations. For the
/// locking-free formulation, whose K is only held as a mixed system, the power iteration runs
/// on the nodal-average stiffness (an upper bound: the stabilised system is softer), the
/// inverse iteration on the mixed system itself.
pub fn estimate(mesh: &Mesh, iters: usize) -> Result<Conditioning, crate::fem::FemError> {
    let k = Stiffness::assemble(mesh)?;
    let f = k.factorize()?;
    let bound = if k.n_aux() > 0 {
        Some(crate::fem::locking_free::stiffness(
            mesh,
            crate::fem::locking_free::Smoothing::Nodal,
        )?)
    } else {
        None
    };
    let product = bound.as_ref().unwrap_or(&k);
    let n = k.dofs.n_free;
    // A start with components along every eigenvector (deterministic).
    let start: Vec<f64> = (0..n)
        .map(|i| 1.0 + 0.37 * ((i as f64) * 0.61).sin())
        .collect();
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    let mut x = start.clone();
    let mut y = vec![0.0; n];
    let mut lambda_max = 0.0;
    for _ in 0..iters.max(1) {
        let nx = norm(&x);
        x.iter_mut().for_each(|v| *v /= nx);
        product.mul(&x, &mut y);
        lambda_max = norm(&y);
        std::mem::swap(&mut x, &mut y);
    }
    // The free DOFs' part of the system's solve (a mixed system's pressures zeroed).
    let mut b = faer::Mat::<f64>::zeros(k.n(), 1);
    for (i, v) in start.iter().enumerate() {
        b[(i, 0)] = *v;
    }
    let mut mu = 0.0;
    for _ in 0..iters.max(1) {
        let nb = (0..n).map(|i| b[(i, 0)] * b[(i, 0)]).sum::<f64>().sqrt();
        for i in 0..n {
            b[(i, 0)] /= nb;
        }
        for i in n..k.n() {
            b[(i, 0)] = 0.0;
        }
        f.solve_in_place(&mut b);
        mu = (0..n).map(|i| b[(i, 0)] * b[(i, 0)]).sum::<f64>().sqrt();
    }
    let lambda_min = 1.0 / mu;
    Ok(Conditioning {
        lambda_max,
        lambda_min,
        condition_estimate: lambda_max / lambda_min,
        worst_quality: crate::mesh::worst_quality(mesh),
    })
}

/// What storing L in f32 and in f16 does to `u = L·F`, relative to the largest displacement:
/// measured for a unit force at the most compliant touchable node and for opposite forces at
/// it and another one (where the sum cancels), in the GPU's arithmetic (f32 sums; f16 entries
/// scaled by a power of two near max |L|). Returns (f32 error, f16 error).
pub(crate) fn storage_error(c: &Compliance) -> (f64, f64) {
    let nc = c.cols().len();
    let nr = c.rows().len();
    if nc == 0 || nr == 0 || !c.holds_l() {
        // (Not measured when L stayed in its cache file: `touchfem info` predicts it.)
        return (0.0, 0.0);
    }
    // The most compliant column (smallest diagonal stiffness), and another column.
    let soft = (0..nc)
        .min_by(|&a, &b| {
            c.diag_inv(a)
                .determinant()
                .abs()
                .total_cmp(&c.diag_inv(b).determinant().abs())
        })
        .unwrap_or(0) as u32;
    let other = (0..nc as u32).find(|&j| j != soft).unwrap_or(soft);
    let loads = [
        vec![(soft, DVec3::new(0.3, -0.4, -1.0))],
        vec![
            (soft, DVec3::new(0.0, 0.0, -1.0)),
            (other, DVec3::new(0.0, 0.0, 1.0)),
        ],
    ];
    let (mut e32, mut e16) = (0.0f64, 0.0f64);
    let mut exact = vec![DVec3::ZERO; nr];
    for load in &loads {
        c.displace(load, &mut exact);
        if exact.iter().all(|v| *v == DVec3::ZERO) || !exact.iter().all(|v| v.is_finite()) {
            continue;
        }
        let err = |u: Vec<DVec3>| crate::compliance::precision::rel_err(&u, &exact);
        e32 = e32.max(err(crate::compliance::precision::displace_f32(c, load)));
        e16 = e16.max(err(crate::compliance::precision::displace_f16(c, load)));
    }
    (e32, e16)
}

/// `storage_error` without the whole compliance: the two columns it needs (the free-surface
/// node farthest from the clamp, and another) solved with rows on the surface. For `info`.
pub fn predict_storage_error(mesh: &Mesh) -> Result<(f64, f64), crate::fem::FemError> {
    use crate::compliance::{NodeSet, Selection};
    let free = mesh.free_surface_nodes();
    let clamped: Vec<DVec3> = (0..mesh.nodes.len())
        .filter(|&i| mesh.fixed[i])
        .map(|i| mesh.nodes[i])
        .collect();
    let far = |n: u32| {
        clamped
            .iter()
            .map(|p| p.distance(mesh.nodes[n as usize]))
            .fold(f64::INFINITY, f64::min)
    };
    let Some(&soft) = free.iter().max_by(|&&a, &&b| far(a).total_cmp(&far(b))) else {
        return Ok((0.0, 0.0));
    };
    let mut cols = vec![soft];
    if let Some(&other) = free.iter().find(|&&n| n != soft) {
        cols.push(other);
    }
    let sel = Selection {
        rows: NodeSet::Surface,
        cols: NodeSet::Nodes(cols),
    };
    let c = Compliance::compute(mesh, &sel)?;
    Ok(storage_error(&c))
}

/// A warning when a storage's measured error exceeds `WARN_ERROR`, saying what to use.
pub fn storage_warning(name: &str, f32_error: f64, f16_error: f64) -> Option<String> {
    if f32_error > WARN_ERROR {
        Some(format!(
            "warning: '{name}': storing L in f32 moves the displacement by {f32_error:.1e} of its largest value (> {WARN_ERROR:.0e}); use the f64 CPU path (cpu-f64)"
        ))
    } else if f16_error > WARN_ERROR {
        Some(format!(
            "warning: '{name}': storing L in f16 moves the displacement by {f16_error:.1e} of its largest value (> {WARN_ERROR:.0e}); use f32 storage (the default)"
        ))
    } else {
        None
    }
}

/// The free-DOF stiffness as a dense matrix (for independent checks on small meshes); of a
/// mixed system, its condensed stiffness (NaN if the pressure block is not negative definite).
pub fn dense_k(k: &Stiffness) -> nalgebra::DMatrix<f64> {
    let n = k.n();
    let mut a = nalgebra::DMatrix::<f64>::zeros(n, n);
    let m = k.k.as_ref();
    for c in 0..n {
        for (r, v) in m.row_idx_of_col(c).zip(m.val_of_col(c)) {
            a[(r, c)] = *v;
        }
    }
    let nf = k.dofs.n_free;
    if n == nf {
        return a;
    }
    // A mixed system: the Schur complement K_uu − K_up K_pp⁻¹ K_pu (K_pp negative definite).
    let kuu = a.view((0, 0), (nf, nf)).into_owned();
    let kup = a.view((0, nf), (nf, n - nf)).into_owned();
    let neg_kpp = -a.view((nf, nf), (n - nf, n - nf)).into_owned();
    match neg_kpp.cholesky() {
        Some(c) => kuu + &kup * c.solve(&kup.transpose()),
        None => kuu * f64::NAN,
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    /// The estimate for `mesh`, its smallest eigenvalue checked against the dense (for a
    /// mixed system, condensed) stiffness's to 1e-6; returns it and the dense largest one.
    fn estimate_against_dense(mesh: &Mesh) -> (Conditioning, f64) {
        let c = estimate(mesh, 200).unwrap();
        let ev = dense_k(&Stiffness::assemble(mesh).unwrap()).symmetric_eigenvalues();
        let (lo, hi) = ev
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(l, h), v| (l.min(*v), h.max(*v)));
        assert!(
            (c.lambda_min - lo).abs() < 1e-6 * lo,
            "{} vs {lo}",
            c.lambda_min
        );
        (c, hi)
    }

    /// The locking-free cube (a mixed system): the smallest eigenvalue from inverse
    /// iteration on the mixed factor equals the condensed stiffness's (formed densely by the
    /// Schur complement, an independent route), and the largest is bounded above by the
    /// nodal-average stiffness's without falling far below the true one.
    #[cfg_attr(test, test)]
    pub(crate) fn a_mixed_system_is_estimated_against_its_condensed_stiffness() {
        let mut mesh = crate::mesh::cube();
        mesh.material.poisson = 0.49;
        mesh.formulation = crate::mesh::units::Formulation::LockingFree;
        assert!(Stiffness::assemble(&mesh).unwrap().n_aux() > 0);
        let (c, hi) = estimate_against_dense(&mesh);
        assert!(
            c.lambda_max >= 0.95 * hi && c.lambda_max < 3.0 * hi,
            "{} vs {hi}",
            c.lambda_max
        );
    }

    #[cfg_attr(test, test)]
    pub(crate) fn the_cube_is_estimated_against_its_dense_eigenvalues() {
        let mesh = crate::mesh::cube();
        let (c, hi) = estimate_against_dense(&mesh);
        assert!(
            (c.lambda_max - hi).abs() < 0.05 * hi,
            "{} vs {hi}",
            c.lambda_max
        );
        assert!(
            (c.worst_quality - 0.3536).abs() < 1e-3,
            "{}",
            c.worst_quality
        );
        let comp = Compliance::compute(&mesh, &Default::default()).unwrap();
        let (e32, e16) = storage_error(&comp);
        assert!(e32 < 1e-6 && e16 < 1e-3 && e16 > e32, "{e32} {e16}");
        assert!(storage_warning("cube", e32, e16).is_none());
        assert!(storage_warning("x", 1e-7, 2e-3)
            .unwrap()
            .contains("use f32"));
        assert!(storage_warning("x", 2e-3, 2e-3).unwrap().contains("f64"));
    }
}
