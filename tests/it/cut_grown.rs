//! A cut's correction that grows the compliance by the nodes the cut made touchable (the
//! copies a split made, the nodes its faces exposed; `Cut::grown_correction`): the grown
//! compliance's blocks, `L′_xx⁻¹`, displacements and haptic force against a full recompute of
//! the separated mesh and against the cut's own exact poke.

use std::sync::Arc;

use glam::{DMat3, DVec3};
use touchfem::compliance::{Compliance, Selection};
use touchfem::contact::force::{finger_force, ForceBc, ForceModel};
use touchfem::contact::ContactPoint;
use touchfem::cut::{point_poke, Cut};
use touchfem::mesh::{cube, mouse};
use touchfem::Mesh;

use crate::common::rel_err;
use crate::cut_split::{max_abs, quad, Recompute, MOUSE_BLADE};

/// Checks the compliance `c` grown by `cut`'s correction against a recompute of the
/// separated body: every moving copy and exposed node is an extra column; blocks between
/// extra and old columns, `L′_xx⁻¹`, the displacement of old rows and of extra nodes under
/// forces on both kinds, and a point finger's exact force on a cut face. Returns the worst
/// relative error.
fn check_grown(name: &str, cut: &Cut, mesh: &Mesh, c: &Compliance) -> f64 {
    let n0 = mesh.nodes.len() as u32;
    let g = c
        .with_correction(Arc::new(cut.grown_correction(c).unwrap()))
        .unwrap();
    let extra = g.extra_nodes().to_vec();
    let copies: Vec<u32> = (n0..cut.node_count() as u32)
        .filter(|&v| !cut.holds_still(v))
        .collect();
    assert!(!copies.is_empty(), "{name}: no copy moves");
    for v in &copies {
        let col = g
            .col_of(*v)
            .unwrap_or_else(|| panic!("{name}: copy {v} is not touchable"));
        assert_eq!(g.col_node(col), *v);
    }
    let exposed = extra.iter().filter(|&&v| v < n0).count();
    assert!(exposed > 0, "{name}: no exposed node of the uncut mesh");
    assert_eq!(g.n_cols(), c.cols().len() + extra.len());
    let re = Recompute::new(cut, mesh);
    // Nodes to check: two copies, an exposed node, an old column near the cut and one far.
    let dist = |v: u32| cut.nodes()[v as usize].distance(cut.nodes()[copies[0] as usize]);
    let old_near = (c.cols().iter().copied())
        .filter(|&v| !cut.holds_still(v))
        .min_by(|&a, &b| dist(a).total_cmp(&dist(b)))
        .unwrap();
    let far = (c.cols().iter().copied())
        .filter(|&v| !cut.holds_still(v))
        .max_by(|&a, &b| dist(a).total_cmp(&dist(b)))
        .unwrap();
    let exposed0 = *extra.iter().find(|&&v| v < n0).unwrap();
    let nodes = [copies[0], copies[copies.len() / 2], exposed0, old_near, far];
    let col = |v: u32| g.col_of(v).unwrap();
    let scale = max_abs(g.touch_block(col(copies[0]), col(copies[0])));
    let mut worst = 0.0f64;
    for &j in &nodes {
        let cj = col(j);
        let mut x = [vec![], vec![], vec![]];
        for (b, xb) in x.iter_mut().enumerate() {
            let mut f = DVec3::ZERO;
            f[b] = 1.0;
            *xb = re.solve(&[(j, f)]);
        }
        for &i in &nodes {
            let blk = g.touch_block(col(i), cj);
            for (b, xb) in x.iter().enumerate() {
                worst = worst.max((blk.col(b) - xb[i as usize]).length() / scale);
            }
        }
        // L′_jj⁻¹ L′_jj = I.
        let e = g.diag_inv(cj) * g.touch_block(cj, cj) - DMat3::IDENTITY;
        worst = worst.max(max_abs(e));
    }
    // Displacements under forces on copies, an exposed node and old columns: the old rows
    // (`displace`) and the extra nodes (`displace_extra`).
    let forces = [
        (col(copies[0]) as u32, DVec3::new(0.02, -0.01, 0.03)),
        (col(exposed0) as u32, DVec3::new(-0.01, 0.02, 0.01)),
        (col(old_near) as u32, DVec3::new(0.0, 0.015, -0.02)),
        (col(far) as u32, DVec3::new(0.0, 0.0, -0.02)),
    ];
    let by_node: Vec<(u32, DVec3)> = forces
        .iter()
        .map(|&(c, f)| (g.col_node(c as usize), f))
        .collect();
    let reference = re.solve(&by_node);
    let mut rows = vec![DVec3::ZERO; g.rows().len()];
    g.displace(&forces, &mut rows);
    let mut extra_u = vec![DVec3::ZERO; extra.len()];
    g.displace_extra(&forces, &mut extra_u);
    let held = g.l_rows();
    let got: Vec<DVec3> = rows[..held]
        .iter()
        .copied()
        .chain(extra_u.iter().copied())
        .collect();
    let want: Vec<DVec3> = (g.rows()[..held].iter().chain(&extra))
        .map(|&v| reference[v as usize])
        .collect();
    worst = worst.max(rel_err(&got, &want));
    // A point finger on a cut face (a triangle of copies and exposed nodes): the grown
    // compliance's exact force equals the cut's own.
    let sep = cut.separated_mesh(mesh);
    let tri = *sep
        .surface
        .iter()
        .find(|t| t.iter().all(|v| extra.contains(v)) && t.iter().any(|&v| v >= n0))
        .expect("a cut face of extra nodes");
    let alpha = [0.5, 0.3, 0.2];
    let p = (0..3).fold(DVec3::ZERO, |s, a| {
        s + cut.nodes()[tri[a] as usize] * alpha[a]
    });
    let u = DVec3::new(0.2e-3, -0.1e-3, -0.3e-3);
    let contact = ContactPoint {
        nodes: tri,
        alpha,
        proxy: p,
        finger: p + u,
        ..ContactPoint::default()
    };
    let mut bc = ForceBc::default();
    let grown = finger_force(&g, &contact, ForceModel::Exact, &mut bc).feedback;
    let (own, _, _) = point_poke(cut, tri, alpha, u).unwrap();
    worst = worst.max((grown - own).length() / own.length());
    eprintln!(
        "{name}: {} extra columns ({} copies, {exposed} exposed nodes), rank {}, grown L′ against a recompute {worst:.1e}",
        extra.len(),
        copies.len(),
        cut.rank()
    );
    worst
}

#[test]
fn a_grown_compliance_equals_a_recompute_at_the_copies_and_the_exposed_nodes() {
    let mesh = cube();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let mut cut = Cut::new(&mesh).unwrap();
    // A cut ending inside the body, then a second one across it.
    cut.split(
        &mesh,
        &[quad(&mesh, [11.0, 5.0, 30.0], [11.0, 22.0, 30.0], 12.0)],
    )
    .unwrap();
    assert!(check_grown("cube, a cut ending inside", &cut, &mesh, &c) < 1e-9);
    cut.split(
        &mesh,
        &[quad(&mesh, [2.0, 15.0, 30.0], [28.0, 15.0, 30.0], 16.0)],
    )
    .unwrap();
    assert!(check_grown("cube, a second cut across", &cut, &mesh, &c) < 1e-9);
    // On the mouse, one blade across its back.
    let mesh = mouse();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let mut cut = Cut::new(&mesh).unwrap();
    let (a, b) = MOUSE_BLADE;
    cut.split(&mesh, &[quad(&mesh, a, b, 8.0)]).unwrap();
    assert!(check_grown("mouse, one blade", &cut, &mesh, &c) < 1e-9);
}

#[test]
fn a_correction_that_does_not_grow_leaves_the_columns_as_they_were() {
    // The removal's correction (and the plain one of a split) has no extra column: the
    // exposed nodes stay untouchable, as before.
    let mesh = cube();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let mut cut = Cut::new(&mesh).unwrap();
    cut.split(
        &mesh,
        &[quad(&mesh, [11.0, 5.0, 30.0], [11.0, 22.0, 30.0], 12.0)],
    )
    .unwrap();
    let plain = c
        .with_correction(Arc::new(cut.correction(&c).unwrap()))
        .unwrap();
    assert!(plain.extra_nodes().is_empty());
    assert_eq!(plain.n_cols(), c.cols().len());
    let copy = mesh.nodes.len() as u32;
    assert_eq!(plain.col_of(copy), None);
    // A grown correction offered to a compliance it does not fit is refused, typed.
    let mut k = cut.grown_correction(&c).unwrap();
    assert!(!k.extra.is_empty());
    k.extra.reverse();
    assert!(c.with_correction(Arc::new(k)).is_err());
}

#[test]
fn a_grown_fold_keeps_the_new_columns_and_the_next_cut_reads_a_recompute() {
    let mesh = cube();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let mut cut = Cut::new(&mesh).unwrap();
    cut.split(
        &mesh,
        &[quad(&mesh, [11.0, 5.0, 30.0], [11.0, 22.0, 30.0], 12.0)],
    )
    .unwrap();
    let g = c
        .with_correction(Arc::new(cut.grown_correction(&c).unwrap()))
        .unwrap();
    let folded = g.folded().unwrap();
    // The extra nodes are columns of the folded L now, at the same indices, and rows too.
    assert!(folded.extra_nodes().is_empty());
    assert_eq!(folded.cols().len(), g.n_cols());
    let extra = g.extra_nodes().to_vec();
    for (k, &x) in extra.iter().enumerate() {
        assert_eq!(folded.col_of(x), Some(c.cols().len() + k));
        assert!(folded.row_of(x).is_some_and(|r| r < folded.l_rows()));
    }
    // It reads what the carried correction reads: blocks and displacements.
    let pick: Vec<u32> = (extra.iter().step_by(7).copied())
        .chain(c.cols().iter().step_by(97).copied())
        .filter(|&v| g.col_of(v).is_some())
        .collect();
    let scale = max_abs(g.touch_block(g.col_of(pick[0]).unwrap(), g.col_of(pick[0]).unwrap()));
    let mut worst = 0.0f64;
    for &i in &pick {
        for &j in &pick {
            let (gi, gj) = (g.col_of(i).unwrap(), g.col_of(j).unwrap());
            let (fi, fj) = (folded.col_of(i).unwrap(), folded.col_of(j).unwrap());
            let d = folded.touch_block(fi, fj) - g.touch_block(gi, gj);
            worst = worst.max(max_abs(d) / scale);
        }
    }
    let forces: Vec<(u32, DVec3)> = (pick.iter().take(4).enumerate())
        .map(|(n, &v)| {
            (
                g.col_of(v).unwrap() as u32,
                DVec3::new(0.01, -0.02, 0.005 * n as f64),
            )
        })
        .collect();
    let mut rows = vec![DVec3::ZERO; g.rows().len()];
    g.displace(&forces, &mut rows);
    let mut ex = vec![DVec3::ZERO; extra.len()];
    g.displace_extra(&forces, &mut ex);
    let mut frows = vec![DVec3::ZERO; folded.rows().len()];
    folded.displace(&forces, &mut frows);
    let at = |v: u32| -> DVec3 {
        match g.row_of(v) {
            Some(r) => rows[r],
            None => ex[extra.binary_search(&v).unwrap()],
        }
    };
    let want: Vec<DVec3> = folded.rows()[..folded.l_rows()]
        .iter()
        .map(|&v| at(v))
        .collect();
    worst = worst.max(rel_err(&frows[..folded.l_rows()], &want));
    eprintln!(
        "cube, a grown fold ({} extra columns) against the carried correction: {worst:.1e}",
        extra.len()
    );
    assert!(worst < 1e-12, "{worst}");
    // The cut started afresh on the folded L, then a second cut across the first: still a
    // recompute's compliance, at the first cut's copies (old columns now) and the new ones.
    let mut cut = cut.rebase(&mesh).unwrap();
    cut.split(
        &mesh,
        &[quad(&mesh, [2.0, 15.0, 30.0], [28.0, 15.0, 30.0], 16.0)],
    )
    .unwrap();
    assert!(
        check_grown(
            "cube, folded, then a second cut across",
            &cut,
            &mesh,
            &folded
        ) < 1e-9
    );
}
