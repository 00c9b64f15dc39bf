//! Cutting: the exact low-rank update of `L` against an independent dense solve of the
//! remaining tets.

use glam::DVec3;
use touchfem::cut::{tets_near, Cut};
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

/// An independent FEM of the remaining tets: our own constant-strain element, assembled
/// into faer's sparse matrix over the unclamped nodes that still have a tet, faer's sparse
/// Cholesky. Nodes without a tet do not move.
fn sparse_reference(mesh: &Mesh, removed: &[bool], forces: &[(u32, DVec3)]) -> Vec<DVec3> {
    let tets: Vec<[usize; 4]> = (mesh.tets.iter().zip(removed))
        .filter(|(_, &r)| !r)
        .map(|(t, _)| t.map(|v| v as usize))
        .collect();
    let mats: Vec<(f64, f64)> = (0..mesh.tets.len())
        .filter(|&t| !removed[t])
        .map(|t| {
            let m = mesh.tet_material(t);
            (m.young_pa, m.poisson)
        })
        .collect();
    independent_fem(&mesh.nodes, &tets, &mats, &mesh.fixed, forces)
}

/// The independent FEM itself: `tets` over `nodes` (m), each of its (Young's modulus Pa,
/// Poisson's ratio), `fixed` nodes clamped, `forces` (node, N) applied; every node's
/// displacement.
fn independent_fem(
    nodes: &[DVec3],
    tets: &[[usize; 4]],
    mats: &[(f64, f64)],
    fixed: &[bool],
    forces: &[(u32, DVec3)],
) -> Vec<DVec3> {
    use faer::linalg::solvers::Solve;
    use faer::sparse::{SparseColMat, Triplet};
    use std::collections::HashMap;
    let nn = nodes.len();
    let mut has_tet = vec![false; nn];
    for t in tets {
        for &v in t {
            has_tet[v] = true;
        }
    }
    let mut dof = vec![usize::MAX; 3 * nn];
    let mut n = 0;
    for v in 0..nn {
        if has_tet[v] && !fixed[v] {
            for a in 0..3 {
                dof[3 * v + a] = n;
                n += 1;
            }
        }
    }
    let mut sum: HashMap<(usize, usize), f64> = HashMap::new();
    for (t, &(e, nu)) in tets.iter().zip(mats) {
        let p = t.map(|v| nodes[v]);
        let jm = glam::DMat3::from_cols(p[1] - p[0], p[2] - p[0], p[3] - p[0]);
        let vol = jm.determinant().abs() / 6.0;
        let inv = jm.inverse();
        let g1 = inv.row(0);
        let g2 = inv.row(1);
        let g3 = inv.row(2);
        let g = [-(g1 + g2 + g3), g1, g2, g3];
        let lambda = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
        let mu = e / (2.0 * (1.0 + nu));
        for a in 0..4 {
            for b in 0..4 {
                for i in 0..3 {
                    for j in 0..3 {
                        let (da, db) = (dof[3 * t[a] + i], dof[3 * t[b] + j]);
                        if da == usize::MAX || db == usize::MAX {
                            continue;
                        }
                        let mut v = lambda * g[a][i] * g[b][j] + mu * g[a][j] * g[b][i];
                        if i == j {
                            v += mu * g[a].dot(g[b]);
                        }
                        *sum.entry((da, db)).or_insert(0.0) += vol * v;
                    }
                }
            }
        }
    }
    let trips: Vec<Triplet<usize, usize, f64>> = sum
        .into_iter()
        .map(|((r, c), val)| Triplet {
            row: r,
            col: c,
            val,
        })
        .collect();
    let k = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &trips).unwrap();
    let llt = k
        .sp_cholesky(faer::Side::Lower)
        .expect("the remaining body is held");
    let mut b = faer::Mat::<f64>::zeros(n, 1);
    for &(v, f) in forces {
        for a in 0..3 {
            let d = dof[3 * v as usize + a];
            if d != usize::MAX {
                b[(d, 0)] += f[a];
            }
        }
    }
    let x = llt.solve(&b);
    let mut u = vec![DVec3::ZERO; nn];
    for v in 0..nn {
        for a in 0..3 {
            let d = dof[3 * v + a];
            if d != usize::MAX {
                u[v][a] = x[(d, 0)];
            }
        }
    }
    u
}

#[test]
fn cuts_on_the_mouse_and_the_phantom_equal_a_full_recompute() {
    for (name, mesh, at) in [
        (
            "mouse",
            touchfem::mesh::mouse(),
            DVec3::new(-0.01, 0.0, 0.04),
        ),
        (
            "phantom",
            touchfem::mesh::phantom(),
            DVec3::new(0.0, 0.0, 0.018),
        ),
    ] {
        let pick = |k: usize| mesh.surface_nodes[k % mesh.surface_nodes.len()];
        let forces = [
            (pick(100), DVec3::new(0.0, 0.0, -0.01)),
            (pick(517), DVec3::new(0.004, -0.002, 0.003)),
        ];
        let mut cut = Cut::new(&mesh).unwrap();
        let mut done = 0;
        for n in [1, 10, 50] {
            let tets = tets_near(&mesh, at, n);
            let rep = cut.remove(&mesh, &tets[done.min(tets.len())..]).unwrap();
            done = n;
            let u = cut.displace(&forces);
            let reference = sparse_reference(&mesh, cut.removed(), &forces);
            let e = rel_err(&u, &reference);
            eprintln!("{name}, {n} tets: {rep:?}, relative error {e:.2e}");
            assert!(e < 1e-9, "{name}, {n} tets: {e}");
        }
    }
}

use crate::common::rel_err;
use crate::common::touchfem_status as touchfem;

fn poke_json(args: &[&str]) -> serde_json::Value {
    let (code, out, err) = touchfem(args);
    assert_eq!(code, 0, "{args:?}: {err}");
    serde_json::from_str(out.trim()).unwrap()
}

#[test]
fn pressing_beside_a_deepening_incision_needs_less_force() {
    // The cube's top pressed 3 mm at x = 20 mm with the exact force, beside a blade drawn
    // across y at x = 11 mm: the blade separates the material, nothing is removed.
    let base = [
        "poke", "cube", "--at", "20,15,30", "--push", "0,0,-3", "--json", "--exact",
    ];
    let uncut = poke_json(&base);
    let f0 = uncut["force"][2].as_f64().unwrap();
    let mut last = f0;
    let mut split_last = 0;
    for depth in ["8", "16", "24"] {
        let v = poke_json(
            &[
                &base[..],
                &["--cut", "11,0.5,30:11,29.5,30", "--depth", depth],
            ]
            .concat(),
        );
        let f = v["force"][2].as_f64().unwrap();
        let split = v["nodes_split"].as_u64().unwrap();
        eprintln!(
            "depth {depth} mm: {split} nodes split, {} snapped, {} tets removed, rank {}, force {f:.5} N",
            v["nodes_snapped"], v["tets_removed"], v["correction_rank"]
        );
        assert!(
            split > split_last,
            "depth {depth}: {split} after {split_last}"
        );
        assert_eq!(v["tets_removed"].as_u64(), Some(0), "{v}");
        assert!(f <= last * (1.0 + 1e-12), "depth {depth}: {f} after {last}");
        assert!(f > 0.0);
        last = f;
        split_last = split;
    }
    assert!(last < 0.95 * f0, "{last} vs uncut {f0}");
}

#[test]
fn a_cut_pokes_vtu_agrees_with_an_independent_fem_of_the_separated_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let vtu = dir.path().join("cut.vtu");
    let v = poke_json(&[
        "poke",
        "cube",
        "--at",
        "12,16,30",
        "--push",
        "0,0,-3",
        "--cut",
        "11,0.5,30:11,29.5,30",
        "--depth",
        "16",
        "--json",
        "--vtu",
        vtu.to_str().unwrap(),
    ]);
    let text = std::fs::read_to_string(&vtu).unwrap();
    let array = |name: &str| -> Vec<f64> {
        let start = text.find(&format!("Name=\"{name}\"")).unwrap();
        let body = &text[start..];
        let open = body.find('>').unwrap() + 1;
        let close = body.find("</DataArray>").unwrap();
        body[open..close]
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect()
    };
    // The points: the cube's 125 nodes (some snapped onto the blade's plane), then a copy for
    // each further side of a split node.
    let points: Vec<DVec3> = {
        let start = text.find("<Points>").unwrap();
        let body = &text[start..];
        let open = body.find("ascii\">").unwrap() + 7;
        let close = body.find("</DataArray>").unwrap();
        let xs: Vec<f64> = body[open..close]
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect();
        xs.chunks(3).map(|c| DVec3::new(c[0], c[1], c[2])).collect()
    };
    let mesh = cube();
    let split = v["nodes_split"].as_u64().unwrap() as usize;
    assert!(split > 0, "{v}");
    assert_eq!(points.len(), mesh.nodes.len() + split);
    let tets: Vec<[usize; 4]> = array("connectivity")
        .chunks(4)
        .map(|c| [c[0], c[1], c[2], c[3]].map(|x| x as usize))
        .collect();
    assert_eq!(
        mesh.tets.len() - tets.len(),
        v["tets_removed"].as_u64().unwrap() as usize
    );
    assert!(tets.iter().flatten().any(|&n| n >= mesh.nodes.len()));
    let young = array("young");
    let poisson = array("poisson");
    let mats: Vec<(f64, f64)> = young.iter().copied().zip(poisson).collect();
    let fixed: Vec<bool> = array("fixed").iter().map(|&x| x != 0.0).collect();
    let disp = array("displacement");
    let force = array("force");
    let forces: Vec<(u32, DVec3)> = force
        .chunks(3)
        .enumerate()
        .filter(|(_, f)| f.iter().any(|&x| x != 0.0))
        .map(|(i, f)| (i as u32, DVec3::new(f[0], f[1], f[2])))
        .collect();
    assert!(!forces.is_empty());
    let reference = independent_fem(&points, &tets, &mats, &fixed, &forces);
    let u: Vec<DVec3> = disp
        .chunks(3)
        .map(|d| DVec3::new(d[0], d[1], d[2]))
        .collect();
    let e = rel_err(&u, &reference);
    eprintln!(
        "separating poke's VTU ({} points, {split} copies) against an independent FEM: {e:.2e}",
        points.len()
    );
    assert!(e < 1e-6, "{e}");
    // The finger feels minus the nodal forces.
    let sum: DVec3 = forces.iter().map(|f| f.1).sum();
    let fb = DVec3::from_slice(
        &v["force"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect::<Vec<_>>(),
    );
    assert!((fb + sum).length() < 1e-6 * sum.length());
}

#[test]
fn bad_cut_flags_exit_2_naming_the_flag() {
    for (args, flag) in [
        (vec!["--cut", "1,1,30:20,20,30", "--depth", "0"], "--depth"),
        (
            vec!["--cut", "1,1,30:20,20,30", "--depth", "nan"],
            "--depth",
        ),
        (vec!["--cut", "1,1,30:20,20,30", "--depth", "-3"], "--depth"),
        (vec!["--cut", "1,1,30:20,20,30"], "--depth"),
        (vec!["--cut", "1,1,30", "--depth", "3"], "--cut"),
        (vec!["--cut", "1,nan,30:2,2,2", "--depth", "3"], "--cut"),
        (vec!["--depth", "3"], "--cut"),
        (
            vec!["--cut", "1,1,30:20,20,30", "--depth", "3", "--sphere", "8"],
            "--sphere",
        ),
    ] {
        let all = [
            &["poke", "cube", "--at", "15,15,30", "--push", "0,0,-3"][..],
            &args[..],
        ]
        .concat();
        let (code, _, err) = touchfem(&all);
        assert_eq!(code, 2, "{all:?}: {err}");
        assert!(
            err.starts_with("error:") && err.contains(flag),
            "{all:?}: {err}"
        );
    }
}

#[test]
fn a_fold_is_exact_and_cutting_folding_and_cutting_again_stays_exact() {
    use touchfem::compliance::{Compliance, Selection};
    let mesh = cube();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let mut cut = Cut::new(&mesh).unwrap();
    let order = tets_near(&mesh, DVec3::new(0.012, 0.018, 0.027), 25);
    for (step, tets) in [&order[..10], &order[10..25]].iter().enumerate() {
        cut.remove(&mesh, tets).unwrap();
        let folded = cut.fold(&c).unwrap();
        // Every stored block against the correction's; a press through the folded L against
        // the dense solve of the remaining tets.
        let mut worst = 0.0f64;
        let mut scale = 0.0f64;
        for (ci, &i) in folded.cols().iter().enumerate() {
            for (cj, &j) in folded.cols().iter().enumerate().step_by(7) {
                // (Both sides read the same solve's bits: expect equality to round-off.)
                let d = folded.touch_block(ci, cj) - cut.block(i, j);
                worst = worst.max(d.abs().to_cols_array().iter().cloned().fold(0.0, f64::max));
            }
            scale = scale.max(
                folded
                    .touch_block(ci, ci)
                    .abs()
                    .to_cols_array()
                    .iter()
                    .cloned()
                    .fold(0.0, f64::max),
            );
        }
        assert!(worst <= 1e-10 * scale, "step {step}: {worst} vs {scale}");
        let col = folded.cols().len() / 2;
        let node = folded.cols()[col];
        let f = DVec3::new(0.01, -0.02, -0.05);
        let mut u = vec![DVec3::ZERO; folded.rows().len()];
        folded.displace(&[(col as u32, f)], &mut u);
        let reference = dense_reference(&mesh, cut.removed(), &[(node, f)]);
        let r: Vec<DVec3> = folded
            .rows()
            .iter()
            .map(|&n| reference[n as usize])
            .collect();
        let e = rel_err(&u, &r);
        eprintln!(
            "fold after {} tets: {} columns kept of {}, blocks {:.1e} of the diagonal, press {e:.2e}",
            cut.removed().iter().filter(|&&x| x).count(),
            folded.cols().len(),
            c.cols().len(),
            worst / scale
        );
        assert!(e < 1e-9, "step {step}: {e}");
    }
}

#[test]
fn a_piece_hanging_by_an_edge_is_removed() {
    // A tet of the cube's top layer, with every other tet at two of its nodes cut away,
    // touches the rest by one edge only: a hinge, which could rotate about it. The cut
    // removes it as a piece (its two lone nodes are pinned), and the rest stays exact.
    let mesh = cube();
    let t0 = tets_near(&mesh, DVec3::new(0.015, 0.015, 0.028), 1)[0];
    let [_, _, c, d] = mesh.tets[t0];
    let around: Vec<usize> = (0..mesh.tets.len())
        .filter(|&t| t != t0 && (mesh.tets[t].contains(&c) || mesh.tets[t].contains(&d)))
        .collect();
    let mut cut = Cut::new(&mesh).unwrap();
    let rep = cut.remove(&mesh, &around).unwrap();
    assert!(rep.pieces_removed >= 1, "{rep:?}");
    assert!(cut.removed()[t0]);
    let forces = [(mesh.surface_nodes[40], DVec3::new(0.0, 0.02, -0.1))];
    let u = cut.displace(&forces);
    let reference = sparse_reference(&mesh, cut.removed(), &forces);
    assert!(rel_err(&u, &reference) < 1e-9);
}
