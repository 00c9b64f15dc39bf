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
    // (An exposed node of the uncut mesh where the cut made one, else a second copy.)
    let exposed0 = (extra.iter().copied())
        .find(|&v| v < n0)
        .unwrap_or(copies[copies.len() - 1]);
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
    // A point finger on a cut face (a triangle with a copy): the grown
    // compliance's exact force equals the cut's own.
    let sep = cut.separated_mesh(mesh);
    let tri = *sep
        .surface
        .iter()
        .find(|t| t.iter().all(|&v| g.col_of(v).is_some()) && t.iter().any(|&v| v >= n0))
        .expect("a cut face with a copy");
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
    // A cut ending inside the body, then a second one across it.
    let (mesh, c, mut cut) = cube_cut_ending_inside();
    assert!(check_grown("cube, a cut ending inside", &cut, &mesh, &c) < 1e-9);
    // (Nodes of the uncut mesh inside the body that the cut exposed are extra columns too.)
    let k = cut.grown_correction(&c).unwrap();
    assert!(k
        .extra
        .iter()
        .any(|&v| v < mesh.nodes.len() as u32 && c.row_of(v).is_none()));
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

/// The cube, its compliance (the default selection) and a cut ending inside it: along y from 5
/// to 22 mm at x = 11 mm, 12 mm deep.
pub(crate) fn cube_cut_ending_inside() -> (Mesh, Compliance, Cut) {
    let mesh = cube();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let mut cut = Cut::new(&mesh).unwrap();
    cut.split(
        &mesh,
        &[quad(&mesh, [11.0, 5.0, 30.0], [11.0, 22.0, 30.0], 12.0)],
    )
    .unwrap();
    (mesh, c, cut)
}

#[test]
fn a_correction_that_does_not_grow_leaves_the_columns_as_they_were() {
    // The removal's correction (and the plain one of a split) has no extra column: the
    // exposed nodes stay untouchable, as before.
    let (mesh, c, cut) = cube_cut_ending_inside();
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
    let (mesh, c, cut) = cube_cut_ending_inside();
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

/// The cube (mm scene, E = 1 MPa) with every tet cuttable.
fn cuttable_cube() -> touchfem::scene::World {
    use touchfem::scene::SceneSource;
    touchfem::scene::World::from_source_with(
        &SceneSource {
            name: "cut-cube".into(),
            text: "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\nyoung = 1.0e6\ncuttable = \"all\"\n[[finger]]\ndevice = \"pointer\"\n".into(),
            dir: ".".into(),
            label: "cuttable cube".into(),
        },
        None,
    )
    .unwrap()
}

/// A blade's chord on the cube's top (z = 30 mm), hanging `depth` mm down (metres out).
fn top_stroke(a: [f64; 2], b: [f64; 2], depth: f64) -> touchfem::runtime::cutting::Stroke {
    touchfem::runtime::cutting::Stroke {
        object: 0,
        from: DVec3::new(a[0], a[1], 30.0) * 1e-3,
        to: DVec3::new(b[0], b[1], 30.0) * 1e-3,
        inward: DVec3::NEG_Z,
        depth: depth * 1e-3,
    }
}

#[test]
fn a_separating_cutter_hands_the_haptic_path_a_slit_that_a_recompute_agrees_with() {
    use touchfem::contact::GodObject;
    use touchfem::runtime::cutting::{blade_quads, CutMode, Cutter, Stroke};
    let world = cuttable_cube();
    let mesh = world.objects[0].body.mesh.clone();
    let mut cutter = Cutter::new(&world).unwrap();
    cutter.set_cut_mode(CutMode::Separate);
    // Two strokes of one blade across the top: joined into one chord.
    let strokes = [
        top_stroke([11.0, 5.0], [11.0, 14.0], 12.0),
        top_stroke([11.0, 14.0], [11.0, 22.0], 12.0),
    ];
    let bodies = cutter.apply_all(&strokes).unwrap();
    assert_eq!(bodies.len(), 1);
    let body = &bodies[0].1;
    // Nothing removed but slivers; the copies are in the body's surface and columns.
    let n0 = mesh.nodes.len() as u32;
    assert!(body.nodes_split > 0, "{}", body.nodes_split);
    assert!(body.tets_removed <= 2, "{}", body.tets_removed);
    assert_eq!(body.rest.len(), n0 as usize + body.nodes_split);
    let extra = body.compliance.extra_nodes().to_vec();
    assert!(body.triangles.iter().flatten().any(|&v| v >= n0));
    for t in &body.triangles {
        for &v in t {
            assert!(
                body.compliance.col_of(v).is_some()
                    || body.compliance.row_of(v).is_some()
                    || extra.contains(&v),
                "triangle node {v} is neither displayed nor touchable"
            );
        }
    }
    // The same blade by hand on a cut of its own: the same separated body.
    // (The cutter's quads for the joined chord: reaching out of the body and down to the
    // nearest layer of nodes, `blade_quads`.)
    let mut cut = Cut::new(&mesh).unwrap();
    let chord = Stroke {
        to: strokes[1].to,
        ..strokes[0]
    };
    let quads = blade_quads(&[], &[chord], mesh.mean_edge());
    assert_eq!(quads.len(), 1);
    cut.split(&mesh, &quads).unwrap();
    assert_eq!(cut.nodes(), &body.rest[..]);
    // Its compliance at the copies against a recompute (independent assembly and factor).
    let c = &world.objects[0].body.compliance;
    assert!(check_grown("cube, a separating cutter", &cut, &mesh, c) < 1e-9);
    let re = Recompute::new(&cut, &mesh);
    let copy = (n0..body.rest.len() as u32)
        .find(|&v| !cut.holds_still(v))
        .unwrap();
    let cc = body.compliance.col_of(copy).unwrap();
    let f = DVec3::new(0.0, 0.01, -0.02);
    let x = re.solve(&[(copy, f)]);
    let got = body.compliance.touch_block(cc, cc) * f;
    assert!((got - x[copy as usize]).length() < 1e-9 * x[copy as usize].length());
    // A point finger pressing one lip beside the slit, through the body's surface and the
    // haptic path's force solve: the cut's own exact force.
    let at = DVec3::new(11.0 + 1.0, 13.0, 30.0) * 1e-3;
    let (tri, p0) = body.surface.closest_global(at);
    let mut god = GodObject::touching(tri);
    let contact = god
        .update(&body.surface, p0 + DVec3::new(0.0, 0.0, -0.8e-3))
        .unwrap();
    let mut bc = ForceBc::default();
    let felt = finger_force(&body.compliance, &contact, ForceModel::Exact, &mut bc).feedback;
    let (own, _, _) =
        point_poke(&cut, contact.nodes, contact.alpha, contact.displacement()).unwrap();
    let e = (felt - own).length() / own.length();
    eprintln!("separating cutter: {} copies, {} extra columns, lip press {felt} N ({e:.1e} from the cut's own)", body.nodes_split, extra.len());
    assert!(e < 1e-9 && felt.z > 0.0, "{felt} vs {own}");
}

#[test]
fn a_separating_cut_confined_to_a_region_changes_no_tet_outside_it() {
    let mesh = cube();
    // The tets whose centroids lie at x < 15 mm.
    let region: Vec<bool> = (mesh.tets.iter())
        .map(|t| t.iter().map(|&v| mesh.nodes[v as usize].x).sum::<f64>() / 4.0 < 15e-3)
        .collect();
    let mut cut = Cut::new(&mesh).unwrap();
    // Blades along x, across the region's border: one in the grid plane y = 15 mm (it
    // splits), one beside it at y = 8.5 mm (it snaps nodes of the region onto its plane).
    let rep = cut
        .split_within(
            &mesh,
            &[quad(&mesh, [2.0, 15.0, 30.0], [28.0, 15.0, 30.0], 12.0)],
            Some(&region),
        )
        .unwrap();
    assert!(rep.nodes_split > 0, "{rep:?}");
    let rep = cut
        .split_within(
            &mesh,
            &[quad(&mesh, [2.0, 8.5, 30.0], [28.0, 8.5, 30.0], 20.0)],
            Some(&region),
        )
        .unwrap();
    assert!(rep.nodes_snapped > 0, "{rep:?}");
    for (t, &inside) in region.iter().enumerate() {
        if !inside {
            assert_eq!(
                cut.tets()[t],
                mesh.tets[t],
                "tet {t} outside the region changed"
            );
            for &v in &mesh.tets[t] {
                assert_eq!(
                    cut.nodes()[v as usize],
                    mesh.nodes[v as usize],
                    "node {v} moved"
                );
            }
            assert!(!cut.removed()[t]);
        }
    }
    // Still exact, confined.
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    assert!(check_grown("cube, a cut confined to x < 15 mm", &cut, &mesh, &c) < 1e-9);
    // A region of the wrong length is refused, typed.
    assert!(cut
        .split_within(
            &mesh,
            &[quad(&mesh, [2.0, 20.0, 30.0], [28.0, 20.0, 30.0], 5.0)],
            Some(&region[1..])
        )
        .is_err());
}

#[test]
fn a_separating_cutter_that_folds_feels_what_one_that_carries_feels() {
    use touchfem::runtime::cutting::{CutMode, Cutter};
    let world = cuttable_cube();
    let strokes = [
        top_stroke([11.0, 5.0], [11.0, 22.0], 12.0),
        top_stroke([3.0, 16.0], [27.0, 16.0], 10.0),
        top_stroke([19.0, 2.0], [19.0, 26.0], 8.0),
    ];
    let make = |fold_rank: usize| {
        let mut c = Cutter::new(&world).unwrap();
        c.set_cut_mode(CutMode::Separate);
        c.set_fold_rank(fold_rank);
        c
    };
    let (mut carry, mut fold) = (make(usize::MAX), make(1));
    let mut last = (None, None);
    let mut adopted = 0;
    for s in &strokes {
        last.0 = carry.apply_all(&[*s]).unwrap().pop().or(last.0);
        last.1 = fold.apply_all(&[*s]).unwrap().pop().or(last.1);
        // A deferred fold of each body, run and caught up, then adopted before the next cut.
        for job in fold.take_folds().unwrap() {
            let (o, done) = job.run();
            let mut done = done.unwrap();
            done.catch_up(fold.fold_ops(o)).unwrap();
            fold.adopt(done).unwrap();
            last.1 = Some((o, fold.body_now(o).unwrap()));
            adopted += 1;
        }
    }
    assert!(adopted >= 2, "{adopted} folds adopted");
    let (a, b) = (last.0.unwrap().1, last.1.unwrap().1);
    assert!(b.folds >= 2 && a.folds == 0, "{} {}", a.folds, b.folds);
    assert_eq!(a.rest, b.rest);
    assert_eq!(a.triangles, b.triangles);
    // Every touchable node of the carried body is one of the folded body's, with the same
    // compliance.
    let (ca, cb) = (&a.compliance, &b.compliance);
    let nodes: Vec<u32> = (0..ca.n_cols())
        .step_by(5)
        .map(|c| ca.col_node(c))
        .collect();
    let scale = nodes
        .iter()
        .map(|&v| max_abs(ca.touch_block(ca.col_of(v).unwrap(), ca.col_of(v).unwrap())))
        .fold(0.0, f64::max);
    let mut worst = 0.0f64;
    for &i in &nodes {
        for &j in nodes.iter().step_by(3) {
            let (ai, aj) = (ca.col_of(i).unwrap(), ca.col_of(j).unwrap());
            let (bi, bj) = (
                cb.col_of(i).expect("touchable after the fold"),
                cb.col_of(j).unwrap(),
            );
            worst = worst.max(max_abs(ca.touch_block(ai, aj) - cb.touch_block(bi, bj)) / scale);
        }
    }
    eprintln!(
        "separating cutter, {adopted} folds against none: {} columns, worst {worst:.1e}",
        nodes.len()
    );
    assert!(worst < 1e-9, "{worst}");
}

/// `C`, `U` and `V` carried from cut to cut (each cut's term of rank `|T|` added to the last
/// ones, `U` read for the new columns only; `cut/carry.rs`) against them made afresh: the same cuts on two cuts of the cube, one asked
/// for its correction after every cut (so each `V` is the last one plus the updates since),
/// the other only at the end (its updates are not kept: `V` afresh); both against a recompute
/// of the separated cube.
#[test]
fn v_carried_from_cut_to_cut_equals_v_made_afresh() {
    let mesh = cube();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let (mut carried, mut afresh) = (Cut::new(&mesh).unwrap(), Cut::new(&mesh).unwrap());
    // A long blade across the cube at y = 20 mm, then one drawn along x = 11 mm in short
    // steps (each touches far fewer DOFs than the rank: its `V` is carried).
    let steps = [
        ([2.0, 20.0], [28.0, 20.0]),
        ([11.0, 3.0], [11.0, 6.0]),
        ([11.0, 6.0], [11.0, 9.0]),
        ([11.0, 9.0], [11.0, 12.0]),
        ([11.0, 12.0], [11.0, 15.0]),
    ];
    let mut ranks = Vec::new();
    for (a, b) in steps {
        let q = quad(&mesh, [a[0], a[1], 30.0], [b[0], b[1], 30.0], 10.0);
        carried.split(&mesh, std::slice::from_ref(&q)).unwrap();
        afresh.split(&mesh, &[q]).unwrap();
        ranks.push(carried.rank());
        carried.correction(&c).unwrap();
    }
    let (kc, ka) = (
        carried.correction(&c).unwrap(),
        afresh.correction(&c).unwrap(),
    );
    assert_eq!(kc.rank, ka.rank);
    let scale = ka.v_cols.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let worst =
        (kc.v_cols.iter().zip(ka.v_cols.iter())).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    eprintln!(
        "ranks {ranks:?}: V carried against V afresh {:.1e} (of {scale:.2e})",
        worst / scale
    );
    assert!(scale > 0.0 && worst <= 1e-10 * scale, "{worst} of {scale}");
    // (Not the same bits: the carried `V` was made another way.)
    assert!(worst > 0.0);
    assert!(
        ranks.windows(2).all(|w| w[1] >= w[0]) && ranks[4] > ranks[0],
        "{ranks:?}"
    );
    assert!(check_grown("cube, carried over five cuts", &carried, &mesh, &c) < 1e-9);
}

/// `L₀`'s columns solved up front (`Cut::precompute_columns`) at some of the DOFs a cut
/// reaches, the others solved as the cut goes: the same correction as a cut that solves
/// them all (to roundoff: solved in other blocks), a recompute's compliance, and after a
/// rebase the rebased cut solves its own (the held nodes and their copies).
#[test]
fn columns_solved_up_front_give_the_same_cut() {
    let mesh = cube();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let (mut plain, mut held) = (Cut::new(&mesh).unwrap(), Cut::new(&mesh).unwrap());
    assert_eq!(plain.columns_held(), 0);
    // Columns at the nodes with x < 15 mm: the blade's path runs past them both ways.
    let mark: Vec<bool> = mesh.nodes.iter().map(|p| p.x < 0.015).collect();
    let n = held.precompute_columns(&mark);
    let free = |m: &[bool]| {
        (0..mesh.nodes.len())
            .filter(|&v| m[v] && !mesh.fixed[v])
            .count()
            * 3
    };
    assert_eq!(n, free(&mark));
    assert_eq!(held.columns_held(), n);
    assert!(n > 0 && n < free(&vec![true; mesh.nodes.len()]));
    // Half of them solved by a helper thread (idle on core 0): the same bits.
    let mut helped = Cut::new(&mesh).unwrap();
    assert_eq!(helped.precompute_columns_on(&mark, Some(&[0])), n);
    for v in 0..mesh.nodes.len() as u32 {
        for a in 0..3 {
            assert_eq!(helped.held_column(v, a), held.held_column(v, a), "node {v}");
        }
    }
    for (a, b) in [([2.0, 20.0], [28.0, 20.0]), ([11.0, 3.0], [11.0, 15.0])] {
        let q = quad(&mesh, [a[0], a[1], 30.0], [b[0], b[1], 30.0], 10.0);
        plain.split(&mesh, std::slice::from_ref(&q)).unwrap();
        held.split(&mesh, &[q]).unwrap();
    }
    let (kp, kh) = (plain.correction(&c).unwrap(), held.correction(&c).unwrap());
    assert_eq!(kp.rank, kh.rank);
    let scale = kp.v_cols.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let worst =
        (kp.v_cols.iter().zip(kh.v_cols.iter())).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    eprintln!(
        "cube, rank {}: {n} columns held, V against every column solved as the cut goes {:.1e}",
        kp.rank,
        worst / scale
    );
    assert!(scale > 0.0 && worst <= 1e-10 * scale, "{worst} of {scale}");
    assert!(check_grown("cube, columns held", &held, &mesh, &c) < 1e-9);
    // Rebased: the held nodes and their copies, solved with the new factor.
    let folded = (c.with_correction(Arc::new(held.grown_correction(&c).unwrap())))
        .unwrap()
        .folded()
        .unwrap();
    let mut rebased = held.rebase(&mesh).unwrap();
    let moving_held = |from: usize| {
        (from..held.node_count())
            .filter(|&v| mark[held.origin()[v] as usize] && !held.holds_still(v as u32))
            .count()
    };
    assert_eq!(rebased.columns_held(), 3 * moving_held(0));
    assert!(moving_held(mesh.nodes.len()) > 0, "no copy of a held node");
    // They were derived from the cut before (L′'s columns by its correction): against the
    // same columns solved with the rebased body's own factor.
    let mut solved = held.rebase(&mesh).unwrap();
    let again: Vec<bool> = (0..held.node_count())
        .map(|v| mark[held.origin()[v] as usize])
        .collect();
    assert_eq!(solved.precompute_columns(&again), rebased.columns_held());
    let (mut worst, mut scale, mut n_cmp) = (0.0f64, 0.0f64, 0);
    for v in 0..held.node_count() as u32 {
        for a in 0..3 {
            if let (Some(x), Some(y)) = (rebased.held_column(v, a), solved.held_column(v, a)) {
                n_cmp += 1;
                for (p, q) in x.iter().zip(y) {
                    worst = worst.max((p - q).abs());
                    scale = scale.max(q.abs());
                }
            }
        }
    }
    eprintln!(
        "cube, rebased: {n_cmp} columns derived against solved {:.1e}",
        worst / scale
    );
    assert_eq!(n_cmp, rebased.columns_held());
    assert!(scale > 0.0 && worst <= 1e-10 * scale, "{worst} of {scale}");
    rebased
        .split(
            &mesh,
            &[quad(&mesh, [2.0, 15.0, 30.0], [28.0, 15.0, 30.0], 16.0)],
        )
        .unwrap();
    assert!(
        check_grown(
            "cube, columns held, rebased, cut again",
            &rebased,
            &mesh,
            &folded
        ) < 1e-9
    );
}

/// `V` made with a helper thread taking blocks of its columns (`Cut::share_v_with`, as the
/// live cutter does on the haptic core) has the same bits as `V` made by one thread, carried
/// from cut to cut and afresh: each block is the same products whoever makes it, so a replay
/// (which has no helper) makes what the live run made.
#[test]
fn v_shared_with_a_helper_has_the_same_bits() {
    let mesh = touchfem::mesh::cube_with(
        [6, 6, 6],
        [30.0; 3],
        touchfem::mesh::units::Material {
            young_pa: 10_000.0,
            poisson: 0.49,
        },
    )
    .unwrap();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let n = std::thread::available_parallelism().map_or(1, |n| n.get());
    let cpus: Arc<[usize]> = (0..n).collect();
    let (mut one, mut two) = (Cut::new(&mesh).unwrap(), Cut::new(&mesh).unwrap());
    // (Above 0: the helper takes part in every `V`.)
    two.share_v_with(Some(cpus), 0);
    let steps = [
        ([2.0, 20.0], [28.0, 20.0]),
        ([11.0, 3.0], [11.0, 6.0]),
        ([11.0, 6.0], [11.0, 9.0]),
        ([11.0, 9.0], [11.0, 12.0]),
    ];
    let mut blocks = 0;
    for (k, (a, b)) in steps.into_iter().enumerate() {
        let q = quad(&mesh, [a[0], a[1], 30.0], [b[0], b[1], 30.0], 10.0);
        one.split(&mesh, std::slice::from_ref(&q)).unwrap();
        two.split(&mesh, &[q]).unwrap();
        // (The second cut's `V` afresh on both: asked for only after the third cut.)
        if k == 1 {
            continue;
        }
        let (k1, k2) = (one.correction(&c).unwrap(), two.correction(&c).unwrap());
        assert!(k1.rank > 0 && k1.rank == k2.rank);
        blocks = k1.v_cols.len().div_ceil(128 * k1.rank);
        let same = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        assert!(same(&k1.v_cols, &k2.v_cols), "cut {k}: V differs");
        assert!(same(&k1.u_cols, &k2.u_cols) && same(&k1.rows, &k2.rows));
    }
    assert!(blocks >= 3, "{blocks} blocks of V's columns");
}
