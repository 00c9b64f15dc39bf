//! The mesh-resolution ladder on the paper's cube (4³, 8³, 16³ cells): the paper's point press
//! has no mesh-independent force (it halves with each refinement), a finger of finite size
//! (a 5 mm punch) converges, and the displacement field converges.

use touchfem::ladder;

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
