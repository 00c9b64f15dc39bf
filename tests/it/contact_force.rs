//! The god-object on faces, edges, vertices and concave corners, thin parts and release; the
//! force's continuity across edges and vertices; paper vs exact; the coupled multi-finger solve.

use crate::common;

use glam::DVec3;
use touchfem::compliance::{Compliance, Selection};
use touchfem::contact::force::{
    coupled_force, finger_force, point_compliance, saturate, ForceBc, ForceModel,
};
use touchfem::contact::{ContactPoint, Feature, GodObject, Surface};
use touchfem::mesh::cube;
use touchfem::Material;

const MM: f64 = 1e-3;

fn mm(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z) * MM
}

/// Moves a finger from `from` to `to` in `n` ticks and returns the last contact.
fn drive(
    god: &mut GodObject,
    s: &Surface,
    from: DVec3,
    to: DVec3,
    n: usize,
) -> Option<ContactPoint> {
    let mut c = None;
    for i in 1..=n {
        c = god.update(s, from.lerp(to, i as f64 / n as f64));
    }
    c
}

#[test]
fn face_contact_projects_onto_the_face() {
    let m = cube();
    let s = Surface::new(&m);
    let mut g = GodObject::new(mm(11.0, 13.0, 35.0));
    assert!(drive(&mut g, &s, mm(11.0, 13.0, 35.0), mm(11.0, 13.0, 31.0), 10).is_none());
    let c = drive(&mut g, &s, mm(11.0, 13.0, 31.0), mm(11.0, 13.0, 27.0), 10).expect("contact");
    assert!((c.proxy - mm(11.0, 13.0, 30.0)).length() < 1e-12);
    assert_eq!(c.feature, Feature::Face);
    assert_eq!(c.feature.active_planes(&s, c.tri), 1);
    assert!((c.alpha.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    assert!(c.alpha.iter().all(|&a| (0.0..=1.0).contains(&a)));
    // The area coordinates reproduce the proxy.
    let p: DVec3 = (0..3)
        .map(|k| m.nodes[c.nodes[k] as usize] * c.alpha[k])
        .sum();
    assert!((p - c.proxy).length() < 1e-12);
    assert!((c.displacement() - mm(0.0, 0.0, -3.0)).length() < 1e-12);
}

#[test]
fn sliding_follows_the_finger_without_jumps_and_releases() {
    let m = cube();
    let s = Surface::new(&m);
    let mut g = GodObject::new(mm(2.0, 2.0, 32.0));
    drive(&mut g, &s, mm(2.0, 2.0, 32.0), mm(2.0, 2.0, 29.0), 5).expect("contact");
    // Slide diagonally across many triangles, edges and vertices at 1 mm depth.
    let mut last = None::<DVec3>;
    for i in 0..=2000 {
        let t = i as f64 / 2000.0;
        let x = mm(2.0 + 26.0 * t, 2.0 + 26.0 * t, 29.0);
        let c = g.update(&s, x).expect("stays in contact");
        assert!((c.proxy - DVec3::new(x.x, x.y, 0.03)).length() < 1e-12);
        if let Some(l) = last {
            assert!((c.proxy - l).length() < 0.03 * MM);
        }
        last = Some(c.proxy);
    }
    // Leaving the object frees the finger.
    assert!(g.update(&s, mm(28.0, 28.0, 30.5)).is_none());
    assert!(!g.in_contact());
}

#[test]
fn convex_edge_and_vertex_of_the_cube() {
    let m = cube();
    let s = Surface::new(&m);
    // Finger inside near the top/front edge, nearer the top face: the proxy stays on the top.
    let mut g = GodObject::new(mm(15.0, 3.0, 33.0));
    let c = drive(&mut g, &s, mm(15.0, 3.0, 33.0), mm(15.0, 3.0, 29.0), 8).unwrap();
    assert!((c.proxy - mm(15.0, 3.0, 30.0)).length() < 1e-12);
    // Moving the finger to where the front face (y = 0) is nearer: like Zilles & Salisbury's
    // god-object, the proxy stays on the face it entered through (one active plane) instead of
    // jumping to the nearer face.
    let c = drive(&mut g, &s, mm(15.0, 3.0, 29.0), mm(15.0, 0.5, 29.0), 20).unwrap();
    assert!(
        (c.proxy - mm(15.0, 0.5, 30.0)).length() < 1e-12,
        "{:?}",
        c.proxy
    );
    assert_eq!(c.feature.active_planes(&s, c.tri), 1);
    // Past the front face the finger is outside the object: released.
    assert!(g.update(&s, mm(15.0, -0.5, 29.0)).is_none());
    // Entering exactly through the cube's corner vertex.
    let mut g = GodObject::new(mm(32.0, 32.0, 32.0));
    let c = drive(&mut g, &s, mm(32.0, 32.0, 32.0), mm(29.5, 29.5, 29.5), 50).unwrap();
    assert!(
        (c.finger - c.proxy).length() - 0.5 * MM < 1e-12,
        "{:?}",
        c.proxy
    );
}

/// A 2×2×2-cell block with the (1,1,1) octant removed: three faces meet at a concave corner
/// (1,1,1) and three concave edges leave it.
#[test]
fn concave_corner_and_valley_hold_the_proxy() {
    let m = common::grid_mesh([2, 2, 2], [0.01; 3], Material::DEFAULT, |i, j, k| {
        !(i == 1 && j == 1 && k == 1)
    });
    let s = Surface::new(&m);
    let corner = DVec3::splat(0.01);
    // Pushing into the corner along the diagonal: the proxy sits at the corner vertex, with
    // the three faces around it active.
    let start = DVec3::splat(0.016);
    let mut g = GodObject::new(start);
    let c = drive(&mut g, &s, start, DVec3::splat(0.008), 40).unwrap();
    assert!((c.proxy - corner).length() < 1e-12, "{:?}", c.proxy);
    assert!(matches!(c.feature, Feature::Vertex(_)));
    assert_eq!(c.feature.active_planes(&s, c.tri), 3);
    // The force pushes the finger back out along the diagonal.
    assert!((c.displacement().normalize() + DVec3::ONE.normalize()).length() < 1e-9);
    // The valley x = y = 0.01 (z between 0.01 and 0.02): the proxy sits on the concave edge.
    let start = DVec3::new(0.016, 0.016, 0.015);
    let mut g = GodObject::new(start);
    let c = drive(&mut g, &s, start, DVec3::new(0.008, 0.008, 0.015), 40).unwrap();
    assert!(
        (c.proxy - DVec3::new(0.01, 0.01, 0.015)).length() < 1e-12,
        "{:?}",
        c.proxy
    );
    assert!(matches!(c.feature, Feature::Edge(_) | Feature::Vertex(_)));
    assert_eq!(c.feature.active_planes(&s, c.tri), 2);
}

#[test]
fn the_proxy_never_pops_through_a_thin_plate() {
    // A plate 1 mm thick, 20 mm wide.
    let m = common::grid_mesh(
        [4, 4, 1],
        [0.005, 0.005, 0.001],
        Material::DEFAULT,
        |_, _, _| true,
    );
    let s = Surface::new(&m);
    let start = DVec3::new(0.011, 0.009, 0.004);
    let mut g = GodObject::new(start);
    // Straight through the plate and 2 mm beyond its bottom in one haptic tick, then further.
    let c = g
        .update(&s, DVec3::new(0.011, 0.009, -0.002))
        .expect("contact on the top face");
    assert!((c.proxy - DVec3::new(0.011, 0.009, 0.001)).length() < 1e-12);
    let c = drive(
        &mut g,
        &s,
        DVec3::new(0.011, 0.009, -0.002),
        DVec3::new(0.012, 0.009, -0.004),
        10,
    )
    .unwrap();
    assert!(
        (c.proxy.z - 0.001).abs() < 1e-12,
        "proxy popped to {:?}",
        c.proxy
    );
    assert!(c.displacement().z < -0.004);
    // Back out above the plate: free.
    assert!(drive(
        &mut g,
        &s,
        DVec3::new(0.012, 0.009, -0.004),
        DVec3::new(0.012, 0.009, 0.003),
        10
    )
    .is_none());
}

fn scene() -> (touchfem::Mesh, Surface, Compliance) {
    let m = cube();
    let s = Surface::new(&m);
    let c = Compliance::compute(&m, &Selection::default()).unwrap();
    (m, s, c)
}

fn contact_at(s: &Surface, tri: u32, alpha: [f64; 3], depth: DVec3) -> ContactPoint {
    let nodes = s.tris[tri as usize];
    let proxy: DVec3 = (0..3).map(|k| s.nodes[nodes[k] as usize] * alpha[k]).sum();
    ContactPoint {
        tri,
        nodes,
        alpha,
        proxy,
        finger: proxy + depth,
        feature: Feature::Face,
    }
}

#[test]
fn paper_and_exact_agree_at_a_vertex_and_exact_follows_the_finger() {
    let (_m, s, c) = scene();
    let u = mm(0.3, -0.2, -2.0);
    // A top-face triangle away from the clamp.
    let tri = (0..s.tris.len() as u32)
        .find(|&t| s.normals[t as usize].z > 0.99)
        .unwrap();
    for k in 0..3 {
        let mut alpha = [0.0; 3];
        alpha[k] = 1.0;
        let cp = contact_at(&s, tri, alpha, u);
        let (mut b1, mut b2) = (ForceBc::default(), ForceBc::default());
        let fp = finger_force(&c, &cp, ForceModel::Paper, &mut b1).feedback;
        let fe = finger_force(&c, &cp, ForceModel::Exact, &mut b2).feedback;
        assert!((fp - fe).length() < 1e-12 * fp.length(), "{fp} vs {fe}");
        // At a node the paper's eq. 7 holds: the node moves exactly by u.
        let col = c.col_of(cp.nodes[k]).unwrap();
        assert!(((c.touch_block(col, col) * -fp) - u).length() < 1e-12);
    }
    // Inside a triangle the exact force moves the contact point by exactly u; the paper's
    // interpolation does not (it is softer), and the difference is measurable.
    let cp = contact_at(&s, tri, [0.2, 0.3, 0.5], u);
    let mut out = vec![DVec3::ZERO; c.rows().len()];
    for model in [ForceModel::Exact, ForceModel::Paper] {
        let mut bc = ForceBc::default();
        let f = finger_force(&c, &cp, model, &mut bc).feedback;
        c.displace(bc.entries(), &mut out);
        let moved: DVec3 = (0..3)
            .map(|k| out[c.row_of(cp.nodes[k]).unwrap()] * cp.alpha[k])
            .sum();
        let sum: DVec3 = bc.entries().iter().map(|e| e.1).sum();
        assert!(
            (sum + f).length() < 1e-12 * f.length(),
            "eq. 12: the reaction balances"
        );
        match model {
            ForceModel::Exact => assert!((moved - u).length() < 1e-12 * u.length()),
            ForceModel::Paper => assert!((moved - u).length() > 1e-3 * u.length()),
        }
    }
}

#[test]
fn force_is_continuous_across_edges_and_vertices() {
    let (_m, s, c) = scene();
    // Slide along the top face at constant depth; a diagonal path crosses edges and passes
    // through vertices. Compare each step's force change with the typical one.
    for model in [ForceModel::Paper, ForceModel::Exact] {
        let mut g = GodObject::new(mm(1.0, 2.0, 31.0));
        drive(&mut g, &s, mm(1.0, 2.0, 31.0), mm(1.0, 2.0, 28.0), 5).unwrap();
        let n = 4000;
        let mut forces = Vec::with_capacity(n + 1);
        for i in 0..=n {
            let t = i as f64 / n as f64;
            let x = mm(1.0 + 27.0 * t, 2.0 + 26.0 * t, 28.0);
            let cp = g.update(&s, x).unwrap();
            let mut bc = ForceBc::default();
            forces.push(finger_force(&c, &cp, model, &mut bc).feedback);
        }
        let jumps: Vec<f64> = forces.windows(2).map(|w| (w[1] - w[0]).length()).collect();
        let fmax = forces.iter().map(|f| f.length()).fold(0.0, f64::max);
        let mut sorted = jumps.clone();
        sorted.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let p99 = sorted[sorted.len() * 99 / 100];
        let worst = sorted[sorted.len() - 1];
        // Lipschitz-like: no step changes the force by more than a few typical steps, and every
        // step is a tiny fraction of the force.
        assert!(
            worst < 4.0 * p99.max(1e-9 * fmax),
            "{model:?}: worst jump {worst:e}, p99 {p99:e}"
        );
        assert!(
            worst < 5e-3 * fmax,
            "{model:?}: worst jump {worst:e} of {fmax:e}"
        );
    }
    // On an edge, the force is the same whichever triangle reports the contact.
    let t0 = (0..s.tris.len() as u32)
        .find(|&t| s.normals[t as usize].z > 0.99)
        .unwrap();
    let nb = s.neighbors[t0 as usize][0];
    let (a, b) = (s.tris[t0 as usize][0], s.tris[t0 as usize][1]);
    let on_edge = |tri: u32| {
        let nodes = s.tris[tri as usize];
        let alpha = nodes.map(|v| {
            if v == a {
                0.3
            } else if v == b {
                0.7
            } else {
                0.0
            }
        });
        contact_at(&s, tri, alpha, mm(0.5, 0.2, -1.5))
    };
    for model in [ForceModel::Paper, ForceModel::Exact] {
        let f1 = finger_force(&c, &on_edge(t0), model, &mut ForceBc::default()).feedback;
        let f2 = finger_force(&c, &on_edge(nb), model, &mut ForceBc::default()).feedback;
        assert!((f1 - f2).length() < 1e-12 * f1.length());
    }
}

#[test]
fn near_the_clamp_the_force_is_large_but_finite() {
    let (m, s, c) = scene();
    // A side triangle with a vertex on the clamped bottom edge.
    let tri = (0..s.tris.len() as u32)
        .find(|&t| {
            s.normals[t as usize].x < -0.99
                && s.tris[t as usize].iter().any(|&v| m.fixed[v as usize])
        })
        .unwrap();
    let fixed_k = s.tris[tri as usize]
        .iter()
        .position(|&v| m.fixed[v as usize])
        .unwrap();
    let mut alpha = [0.0; 3];
    alpha[fixed_k] = 1.0;
    let cp = contact_at(&s, tri, alpha, mm(1.0, 0.0, 0.0));
    for model in [ForceModel::Paper, ForceModel::Exact] {
        let mut bc = ForceBc::default();
        let f = finger_force(&c, &cp, model, &mut bc).feedback;
        assert!(f.is_finite());
        assert!(
            bc.is_empty(),
            "a clamped node gets no force boundary condition"
        );
        // Ten times the stiffest touchable node: |F| = |u| / clamp_compliance.
        assert!((f.length() - 1e-3 / c.clamp_compliance()).abs() < 1e-9 * f.length());
    }
    assert_eq!(
        saturate(DVec3::new(30.0, 40.0, 0.0), 10.0),
        DVec3::new(6.0, 8.0, 0.0)
    );
    assert_eq!(saturate(DVec3::new(f64::NAN, 0.0, 0.0), 10.0), DVec3::ZERO);
}

#[test]
fn coupled_fingers_each_point_follows_its_finger() {
    let (_m, s, c) = scene();
    let top: Vec<u32> = (0..s.tris.len() as u32)
        .filter(|&t| s.normals[t as usize].z > 0.99)
        .collect();
    let side: Vec<u32> = (0..s.tris.len() as u32)
        .filter(|&t| s.normals[t as usize].x < -0.99)
        .collect();
    let a = contact_at(&s, top[5], [0.5, 0.25, 0.25], mm(0.0, 0.0, -2.0));
    let b = contact_at(&s, side[20], [0.1, 0.6, 0.3], mm(1.5, 0.0, 0.0));
    // One finger: the coupled solve equals the exact variant.
    let mut out = [DVec3::ZERO; 2];
    let mut bc = ForceBc::default();
    assert!(coupled_force(&c, &[a], &mut bc, &mut out));
    let fe = finger_force(&c, &a, ForceModel::Exact, &mut ForceBc::default()).feedback;
    assert!((out[0] - fe).length() < 1e-12 * fe.length());
    // Two fingers: both contact points move by their own u, which independent solves miss.
    let mut bc = ForceBc::default();
    assert!(coupled_force(&c, &[a, b], &mut bc, &mut out));
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    c.displace(bc.entries(), &mut u);
    for cp in [a, b] {
        let moved: DVec3 = (0..3)
            .map(|k| u[c.row_of(cp.nodes[k]).unwrap()] * cp.alpha[k])
            .sum();
        assert!((moved - cp.displacement()).length() < 1e-12 * cp.displacement().length());
    }
    let w = point_compliance(&c, &a);
    assert!(w.determinant() > 0.0);
    // Too many fingers are refused, not mis-solved.
    let many = [a; 5];
    let mut out5 = [DVec3::ZERO; 5];
    assert!(!coupled_force(
        &c,
        &many,
        &mut ForceBc::default(),
        &mut out5
    ));
}
