//! Cutting: the exact low-rank update of `L` against an independent dense solve of the
//! remaining tets.

use glam::DVec3;
use touchfem::cut::Cut;
use touchfem::mesh::cube;
use touchfem::Mesh;

/// The displacement of every node under `forces` on `mesh` without the `removed` tets, by a
/// dense LU of the remaining tets' stiffness (nalgebra), clamped and tet-less nodes fixed.
fn dense_reference(mesh: &Mesh, removed: &[bool], forces: &[(u32, DVec3)]) -> Vec<DVec3> {
    let mut m = mesh.clone();
    m.tets = mesh
        .tets
        .iter()
        .zip(removed)
        .filter(|(_, &r)| !r)
        .map(|(t, _)| *t)
        .collect();
    let k = touchfem::fem::dense_stiffness(&m);
    let nn = mesh.nodes.len();
    let mut has_tet = vec![false; nn];
    for t in &m.tets {
        for &v in t {
            has_tet[v as usize] = true;
        }
    }
    let free: Vec<usize> = (0..3 * nn)
        .filter(|&d| !mesh.fixed[d / 3] && has_tet[d / 3])
        .collect();
    let n = free.len();
    let kk = nalgebra::DMatrix::from_fn(n, n, |i, j| k[free[i]][free[j]]);
    let mut f = nalgebra::DVector::zeros(n);
    for &(v, fv) in forces {
        for a in 0..3 {
            if let Some(p) = free.iter().position(|&d| d == 3 * v as usize + a) {
                f[p] += fv[a];
            }
        }
    }
    let x = kk.lu().solve(&f).expect("the remaining body is held");
    let mut u = vec![DVec3::ZERO; nn];
    for (p, &d) in free.iter().enumerate() {
        u[d / 3][d % 3] = x[p];
    }
    u
}

fn rel_err(a: &[DVec3], b: &[DVec3]) -> f64 {
    let num: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (*x - *y).length_squared())
        .sum();
    let den: f64 = b.iter().map(|y| y.length_squared()).sum();
    (num / den).sqrt()
}

/// Tets whose centroid is nearest `p`, `n` of them.
fn tets_near(mesh: &Mesh, p: DVec3, n: usize) -> Vec<usize> {
    let mut v: Vec<(f64, usize)> = mesh
        .tets
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let c = t.iter().map(|&k| mesh.nodes[k as usize]).sum::<DVec3>() / 4.0;
            (c.distance(p), i)
        })
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v.into_iter().take(n).map(|x| x.1).collect()
}

#[test]
fn cuts_of_1_10_and_50_tets_equal_a_dense_recompute() {
    let mesh = cube();
    let forces = [
        (
            touchfem::mesh::cube().surface_nodes[40],
            DVec3::new(0.0, 0.0, -0.1),
        ),
        (
            touchfem::mesh::cube().surface_nodes[70],
            DVec3::new(0.05, 0.02, -0.03),
        ),
    ];
    for n in [1, 10, 50] {
        let mut cut = Cut::new(&mesh).unwrap();
        let tets = tets_near(&mesh, DVec3::new(0.015, 0.015, 0.026), n);
        let rep = cut.remove(&mesh, &tets).unwrap();
        assert!(rep.tets_removed >= n && rep.rank > 0, "{rep:?}");
        let u = cut.displace(&forces);
        let reference = dense_reference(&mesh, cut.removed(), &forces);
        let e = rel_err(&u, &reference);
        eprintln!("{n} tets: {rep:?}, relative error {e:.2e}");
        assert!(e < 1e-9, "{n} tets: {e}");
    }
}

#[test]
fn cutting_in_steps_equals_cutting_at_once_and_the_blocks_match() {
    let mesh = cube();
    let tets = tets_near(&mesh, DVec3::new(0.01, 0.02, 0.028), 30);
    let mut once = Cut::new(&mesh).unwrap();
    once.remove(&mesh, &tets).unwrap();
    let mut steps = Cut::new(&mesh).unwrap();
    for chunk in tets.chunks(7) {
        steps.remove(&mesh, chunk).unwrap();
    }
    let i = mesh.surface_nodes[60];
    let j = mesh.surface_nodes[61];
    let (a, b) = (once.block(i, j), steps.block(i, j));
    let scale = once
        .block(i, i)
        .abs()
        .to_cols_array()
        .iter()
        .cloned()
        .fold(0.0, f64::max);
    let diff = (a - b)
        .abs()
        .to_cols_array()
        .iter()
        .cloned()
        .fold(0.0, f64::max);
    assert!(diff <= 1e-9 * scale, "{diff} vs {scale}");
    // The block is the displacement of i under a unit force at j.
    for c in 0..3 {
        let mut f = DVec3::ZERO;
        f[c] = 1.0;
        let u = dense_reference(&mesh, once.removed(), &[(j, f)]);
        let col = a.col(c);
        assert!(
            (col - u[i as usize]).length() <= 1e-9 * scale,
            "{col} vs {}",
            u[i as usize]
        );
    }
}

#[test]
fn a_cut_that_severs_a_piece_removes_it_and_the_rest_stays_exact() {
    // Cut the whole layer of cells at z ∈ [7.5, 15] mm: everything above loses the clamp.
    let mesh = cube();
    let layer: Vec<usize> = mesh
        .tets
        .iter()
        .enumerate()
        .filter(|(_, t)| {
            let z = t.iter().map(|&k| mesh.nodes[k as usize].z).sum::<f64>() / 4.0;
            (0.0075..0.015).contains(&z)
        })
        .map(|(i, _)| i)
        .collect();
    let mut cut = Cut::new(&mesh).unwrap();
    let rep = cut.remove(&mesh, &layer).unwrap();
    assert_eq!(rep.pieces_removed, 1, "{rep:?}");
    // The top is gone: a force there moves nothing; a force low on the stump is exact.
    let top = mesh
        .surface_nodes
        .iter()
        .copied()
        .find(|&v| mesh.nodes[v as usize].z > 0.029)
        .unwrap();
    let u = cut.displace(&[(top, DVec3::new(0.0, 0.0, -1.0))]);
    assert!(u.iter().all(|v| v.is_finite() && *v == DVec3::ZERO));
    let low = (0..mesh.nodes.len() as u32)
        .find(|&v| {
            (mesh.nodes[v as usize].z - 0.0075).abs() < 1e-9 && mesh.nodes[v as usize].x > 0.029
        })
        .unwrap();
    let forces = [(low, DVec3::new(0.02, 0.0, 0.0))];
    let u = cut.displace(&forces);
    let reference = dense_reference(&mesh, cut.removed(), &forces);
    assert!(rel_err(&u, &reference) < 1e-9);
}

#[test]
fn hostile_cuts_never_panic_or_go_non_finite() {
    let mesh = cube();
    let mut seed = 11u64;
    for round in 0..40 {
        let mut cut = Cut::new(&mesh).unwrap();
        let mut tets = Vec::new();
        for _ in 0..(1 + round % 17) {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            tets.push((seed >> 33) as usize % mesh.tets.len());
        }
        let rep = cut.remove(&mesh, &tets).unwrap();
        let f = [(
            mesh.surface_nodes[(seed as usize >> 7) % mesh.surface_nodes.len()],
            DVec3::new(0.01, -0.02, 0.03),
        )];
        let u = cut.displace(&f);
        assert!(u.iter().all(|v| v.is_finite()), "{rep:?}");
    }
    let mut cut = Cut::new(&mesh).unwrap();
    assert!(cut.remove(&mesh, &[mesh.tets.len()]).is_err());
    // Everything: every piece goes, nothing is left to move.
    let all: Vec<usize> = (0..mesh.tets.len()).collect();
    let rep = cut.remove(&mesh, &all).unwrap();
    assert_eq!(rep.tets_removed, mesh.tets.len());
    let u = cut.displace(&[(mesh.surface_nodes[3], DVec3::X)]);
    assert!(u.iter().all(|v| *v == DVec3::ZERO));
}
