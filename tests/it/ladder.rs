//! The mesh-resolution ladder on the paper's cube (4³, 8³, 16³ cells): the paper's point press
//! has no mesh-independent force (it halves with each refinement), a finger of finite size
//! (a 5 mm punch) converges, and the displacement field converges.

use touchfem_lab::ladder;

#[test]
fn the_point_press_halves_with_refinement_and_the_punch_converges() {
    let (rungs, limit, _) = ladder::cube_ladder(&[4, 8, 16], 0).unwrap();
    for r in &rungs {
        eprintln!(
            "{}: nodes {}, point {:.4} N, punch {:.4} N ({} nodes), punch error {:.2e}, field error {:.2e}",
            r.label, r.nodes, r.point_force_n, r.punch_force_n, r.punch_nodes, r.punch_error, r.field_error
        );
        assert!(r.point_force_n.is_finite() && r.punch_force_n.is_finite());
    }
    for w in rungs.windows(2) {
        let ratio = w[0].point_force_n / w[1].point_force_n;
        assert!((1.7..2.3).contains(&ratio), "point press ratio {ratio}");
    }
    // A sphere (R = 10 mm, 5 mm deep) keeps its force: each refinement changes it by less
    // than 10 % (measured 0.676, 0.658, 0.609 N: on 4³ it touches one node, a point), while
    // the point halves; its contact spreads over more nodes.
    let s: Vec<f64> = rungs.iter().map(|r| r.sphere_force_n).collect();
    eprintln!(
        "sphere: {s:?} N on {:?} nodes",
        rungs.iter().map(|r| r.sphere_nodes).collect::<Vec<_>>()
    );
    for w in s.windows(2) {
        assert!((w[1] / w[0] - 1.0).abs() < 0.1, "{s:?}");
    }
    assert!(rungs[2].sphere_nodes > 3 * rungs[0].sphere_nodes.max(1));
    for r in &rungs {
        assert!(
            (r.punch_force_n - limit).abs() < 0.05 * limit,
            "{}: punch {} vs {limit}",
            r.label,
            r.punch_force_n
        );
    }
    assert!(
        rungs[0].field_error > 2.0 * rungs[1].field_error,
        "{rungs:?}"
    );
    assert_eq!(rungs[2].field_error, 0.0);
}

/// The ladder's f64 path against an independent solve: the 8³ rung's punch forces applied
/// through a dense LU factorisation (nalgebra) move the punched nodes by exactly the push and
/// the probes as the precomputed compliance says, to 1e-10.
#[test]
fn the_ladders_punch_agrees_with_a_dense_lu_solve() {
    use glam::DVec3;
    let mesh = touchfem::mesh::cube_with(
        [8; 3],
        [30.0; 3],
        touchfem::mesh::units::Material {
            young_pa: 10_000.0,
            poisson: 0.49,
        },
    )
    .unwrap();
    let push = DVec3::new(0.0, 0.0, -0.005);
    let s = ladder::punch_nodes(&mesh, DVec3::new(0.015, 0.015, 0.03), 0.005);
    assert_eq!(s.len(), 5);
    let probes: Vec<u32> = (0..mesh.nodes.len() as u32).step_by(7).collect();
    let p = ladder::press_nodes(&mesh, &s, push, &probes).unwrap();
    let lu = touchfem_lab::hard::dense_lu_solve(&mesh, &p.forces).unwrap();
    let scale = push.length();
    for &n in &s {
        let e = (lu[n as usize] - push).length() / scale;
        assert!(e < 1e-10, "punched node {n}: {e:e}");
    }
    for (k, &n) in probes.iter().enumerate() {
        let e = (lu[n as usize] - p.probes[k]).length() / scale;
        assert!(e < 1e-10, "probe {n}: {e:e}");
    }
}
