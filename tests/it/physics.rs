//! The FEM and the compliance checked against independent references: the patch test, the rigid
//! body null space, symmetry and reciprocity of L, K·L = I, the direct sparse solve, beam theory.

use crate::common;

use glam::DVec3;
use nalgebra::{DMatrix, DVector};
use touchfem::compliance::{Compliance, NodeSet, Selection};
use touchfem::fem::{dense_stiffness, solve_static};
use touchfem::mesh::cube;
use touchfem::Material;

#[test]
fn patch_test_reproduces_a_uniform_strain_inside() {
    // A 3×3×3 box whose interior nodes are moved off the grid, so the elements are irregular.
    let mut mesh = common::grid_mesh([3, 3, 3], [1.0; 3], Material::DEFAULT, |_, _, _| true);
    let mut seed = 7u64;
    let interior: Vec<usize> = (0..mesh.nodes.len())
        .filter(|&i| !mesh.surface_nodes.contains(&(i as u32)))
        .collect();
    assert_eq!(interior.len(), 8);
    for &i in &interior {
        let d = DVec3::new(
            common::rand01(&mut seed) - 0.5,
            common::rand01(&mut seed) - 0.5,
            common::rand01(&mut seed) - 0.5,
        );
        mesh.nodes[i] += d * 0.3;
    }
    // u(x) = E x + c with a general (non-symmetric) gradient E.
    let e =
        glam::DMat3::from_cols_array(&[0.01, -0.02, 0.005, 0.03, -0.01, 0.02, 0.004, 0.015, 0.02]);
    let c = DVec3::new(0.001, -0.002, 0.003);
    let exact = |p: DVec3| e * p + c;
    let k = dense_stiffness(&mesh);
    let n = mesh.nodes.len();
    let free: Vec<usize> = interior
        .iter()
        .flat_map(|&i| (0..3).map(move |a| 3 * i + a))
        .collect();
    let bound: Vec<usize> = (0..3 * n).filter(|d| !free.contains(d)).collect();
    let ub: Vec<f64> = bound
        .iter()
        .map(|&d| exact(mesh.nodes[d / 3])[d % 3])
        .collect();
    let kff = DMatrix::from_fn(free.len(), free.len(), |r, q| k[free[r]][free[q]]);
    let rhs = DVector::from_fn(free.len(), |r, _| {
        -bound
            .iter()
            .zip(&ub)
            .map(|(&d, u)| k[free[r]][d] * u)
            .sum::<f64>()
    });
    let uf = kff.lu().solve(&rhs).expect("interior stiffness is regular");
    let mut err = 0.0f64;
    for (r, &d) in free.iter().enumerate() {
        err = err.max((uf[r] - exact(mesh.nodes[d / 3])[d % 3]).abs());
    }
    assert!(err < 1e-12, "patch test error {err:e}");
}

#[test]
fn unconstrained_stiffness_has_exactly_six_rigid_body_modes() {
    let mesh = cube();
    let k = dense_stiffness(&mesh);
    let n = k.len();
    let km = DMatrix::from_fn(n, n, |r, c| k[r][c]);
    // The six rigid modes lie in the null space.
    let centre = DVec3::splat(0.015);
    for mode in 0..6 {
        let v = DVector::from_fn(n, |d, _| {
            let p = mesh.nodes[d / 3] - centre;
            let a = d % 3;
            if mode < 3 {
                (a == mode) as u8 as f64
            } else {
                let w = DVec3::from_array(std::array::from_fn(|i| (i == mode - 3) as u8 as f64));
                w.cross(p)[a] * 100.0
            }
        });
        let r = (&km * &v).amax() / (km.amax() * v.amax());
        assert!(r < 1e-13, "rigid mode {mode} residual {r:e}");
    }
    // ... and nothing else: the seventh smallest eigenvalue is well away from zero.
    let mut ev: Vec<f64> = km.symmetric_eigenvalues().iter().copied().collect();
    ev.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let top = ev[n - 1];
    for (i, &l) in ev.iter().take(6).enumerate() {
        assert!(l.abs() < 1e-12 * top, "eigenvalue {i} = {l:e}");
    }
    assert!(
        ev[6] > 1e-4 * top,
        "seventh eigenvalue {:e} vs max {top:e}",
        ev[6]
    );
}

#[test]
fn compliance_is_symmetric_reciprocal_and_inverts_k() {
    let mesh = cube();
    let sel = Selection {
        rows: NodeSet::All,
        cols: NodeSet::FreeSurface,
    };
    let c = Compliance::compute(&mesh, &sel).unwrap();
    assert_eq!(c.cols().len(), 73);
    assert_eq!(c.rows().len(), 125);
    // K entries are ~E·h ≈ 75 N/m; the residual of K·L = I is at round-off.
    assert!(c.stats.residual < 1e-12, "residual {:e}", c.stats.residual);
    assert!(c.stats.symmetry < 1e-12, "symmetry {:e}", c.stats.symmetry);
    // Reciprocity, block by block: L_ij = L_jiᵀ.
    let mut worst = 0.0f64;
    let scale = c.l_f64().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for i in (0..73).step_by(5) {
        for j in (0..73).step_by(7) {
            let d = c.touch_block(i, j) - c.touch_block(j, i).transpose();
            worst = worst.max(d.abs().to_cols_array().iter().fold(0.0, |m, v| m.max(*v)));
        }
    }
    assert!(worst < 1e-12 * scale, "reciprocity {worst:e}");
    // Diagonal blocks are symmetric positive definite.
    for i in 0..73 {
        let b = c.touch_block(i, i);
        assert!(b.determinant() > 0.0 && b.x_axis.x > 0.0 && b.y_axis.y > 0.0 && b.z_axis.z > 0.0);
        let prod = b * c.diag_inv(i);
        let e = (prod - glam::DMat3::IDENTITY)
            .abs()
            .to_cols_array()
            .iter()
            .fold(0.0f64, |m, v| m.max(*v));
        assert!(e < 1e-10, "L_ii·L_ii⁻¹ − I = {e:e}");
    }
    // Clamped rows are exactly zero.
    for (ri, &node) in c.rows().iter().enumerate() {
        if mesh.fixed[node as usize] {
            assert_eq!(c.block(ri, 0), glam::DMat3::ZERO);
        }
    }
}

#[test]
fn l_times_f_matches_a_direct_sparse_solve() {
    let mesh = cube();
    let c = Compliance::compute(
        &mesh,
        &Selection {
            rows: NodeSet::All,
            cols: NodeSet::FreeSurface,
        },
    )
    .unwrap();
    let forces: Vec<(u32, DVec3)> = [
        (3usize, DVec3::new(0.1, -0.2, 0.3)),
        (40, DVec3::new(-0.5, 0.0, 0.2)),
        (72, DVec3::new(0.0, 0.0, -1.0)),
    ]
    .iter()
    .map(|&(ci, f)| (ci as u32, f))
    .collect();
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    c.displace(&forces, &mut u);
    let nodal: Vec<(u32, DVec3)> = forces
        .iter()
        .map(|&(ci, f)| (c.cols()[ci as usize], f))
        .collect();
    let direct = solve_static(&mesh, &nodal).unwrap();
    let umax = direct.iter().map(|v| v.length()).fold(0.0, f64::max);
    assert!(umax > 1e-4);
    for (ri, &node) in c.rows().iter().enumerate() {
        let e = (u[ri] - direct[node as usize]).length();
        assert!(e < 1e-11 * umax, "node {node}: {e:e}");
    }
}

/// Tip deflection of a slender clamped cantilever under an end load, against Timoshenko beam
/// theory (bending + shear). Linear tets are too stiff in bending on coarse meshes; the error
/// must shrink with refinement and be under 4 % on the finest mesh (80×8×8 cells).
#[test]
fn cantilever_tip_deflection_converges_to_beam_theory() {
    let (len, h): (f64, f64) = (0.1, 0.01);
    let mat = Material {
        young_pa: 1.0e6,
        poisson: 0.3,
    };
    let p_total = 0.01; // N, downward (−z)
    let i_area = h * h.powi(3) / 12.0;
    let g = mat.young_pa / (2.0 * (1.0 + mat.poisson));
    let kappa = 10.0 * (1.0 + mat.poisson) / (12.0 + 11.0 * mat.poisson);
    let theory =
        p_total * len.powi(3) / (3.0 * mat.young_pa * i_area) + p_total * len / (kappa * g * h * h);
    let mut errors = Vec::new();
    for n in [2usize, 4, 8] {
        let cells = [10 * n, n, n];
        let hs = [len / cells[0] as f64, h / n as f64, h / n as f64];
        let mut mesh = common::grid_mesh(cells, hs, mat, |_, _, _| true);
        mesh.set_fixed_where(|p| p.x < 1e-12);
        // Consistent load on the tip face x = len: each tip triangle's area/3 to its nodes.
        let tip: Vec<u32> = (0..mesh.nodes.len() as u32)
            .filter(|&i| (mesh.nodes[i as usize].x - len).abs() < 1e-12)
            .collect();
        let mut load = vec![0.0; mesh.nodes.len()];
        let mut area = 0.0;
        for t in &mesh.surface {
            if t.iter()
                .all(|&v| (mesh.nodes[v as usize].x - len).abs() < 1e-12)
            {
                let [a, b, c] = t.map(|v| mesh.nodes[v as usize]);
                let ar = 0.5 * (b - a).cross(c - a).length();
                area += ar;
                for &v in t {
                    load[v as usize] += ar / 3.0;
                }
            }
        }
        assert!((area - h * h).abs() < 1e-15);
        let forces: Vec<(u32, DVec3)> = tip
            .iter()
            .map(|&v| (v, DVec3::new(0.0, 0.0, -p_total * load[v as usize] / area)))
            .collect();
        let u = solve_static(&mesh, &forces).unwrap();
        let tip_defl = -tip.iter().map(|&v| u[v as usize].z).sum::<f64>() / tip.len() as f64;
        errors.push((tip_defl - theory).abs() / theory);
    }
    eprintln!("cantilever relative errors (n = 2, 4, 8): {errors:?}");
    assert!(
        errors[0] > errors[1] && errors[1] > errors[2],
        "no convergence: {errors:?}"
    );
    assert!(
        errors[2] < 0.04,
        "finest-mesh error {:.3} (theory {theory:e} m)",
        errors[2]
    );
}

#[test]
fn nearly_incompressible_material_stays_accurate() {
    // ν → 0.5 makes K badly conditioned (volumetric locking); the factorisation must still give
    // a finite, symmetric L with a small residual.
    for nu in [0.49, 0.499, 0.4999] {
        let mut mesh = cube();
        mesh.material.poisson = nu;
        let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
        assert!(c.l_f64().iter().all(|v| v.is_finite()));
        assert!(
            c.stats.residual < 1e-9,
            "ν = {nu}: residual {:e}",
            c.stats.residual
        );
        assert!(
            c.stats.symmetry < 1e-9,
            "ν = {nu}: symmetry {:e}",
            c.stats.symmetry
        );
    }
}

#[test]
fn mouse_compliance_is_accurate_and_symmetric() {
    let m = touchfem::mesh::mouse();
    let c = Compliance::compute(&m, &Selection::default()).unwrap();
    assert_eq!((c.rows().len(), c.cols().len()), (1169, 1029));
    assert!(c.stats.residual < 1e-11, "residual {:e}", c.stats.residual);
    assert!(c.stats.symmetry < 1e-12, "symmetry {:e}", c.stats.symmetry);
}
