//! The Gram method of the precompute (sparse forward solves and their products) against the
//! column method (a full forward and back substitution per column), on whole surfaces and on
//! partial selections.

use touchfem::compliance::{Compliance, Method, NodeSet, Selection};
use touchfem::mesh::{cube_with, mouse};
use touchfem::{Material, Mesh};

/// max over displayed × touchable entries of |a − b| / max |a|, matched by node.
fn difference(a: &Compliance, b: &Compliance) -> f64 {
    assert_eq!(a.rows(), b.rows());
    let mut sa = a.cols().to_vec();
    let mut sb = b.cols().to_vec();
    sa.sort_unstable();
    sb.sort_unstable();
    assert_eq!(sa, sb, "the same touchable nodes");
    let max = a.l_f64().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(max > 0.0);
    let mut d = 0.0f64;
    for &n in a.cols() {
        let (ca, cb) = (a.col_of(n).unwrap(), b.col_of(n).unwrap());
        for r in 0..a.rows().len() {
            let e = (a.block(r, ca) - b.block(r, cb)).abs().to_cols_array();
            d = d.max(e.iter().fold(0.0f64, |m, v| m.max(*v)));
        }
    }
    d / max
}

fn both(mesh: &Mesh, sel: &Selection) -> (Compliance, Compliance) {
    let c = Compliance::compute_with_method(mesh, sel, Method::Columns, &mut |_, _| {}).unwrap();
    let g = Compliance::compute_with_method(mesh, sel, Method::Gram, &mut |_, _| {}).unwrap();
    assert_eq!(c.stats.phases.method, "columns");
    (c, g)
}

#[test]
fn gram_equals_columns_on_the_mouse_surface() {
    let m = mouse();
    let (c, g) = both(&m, &Selection::default());
    assert_eq!(g.stats.phases.method, "gram", "the mouse's factor is supernodal");
    assert!(g.stats.phases.w_bytes > 0);
    let d = difference(&c, &g);
    assert!(d < 1e-12, "relative difference {d:.2e}");
    assert!(g.stats.residual < 1e-9, "residual {}", g.stats.residual);
    // Estimated work: the Gram method does less than the column method here.
    let p = &g.stats.phases;
    assert!(p.gram_flops > 0.0 && p.gram_flops < p.column_flops, "{p:?}");
}

#[test]
fn gram_equals_columns_for_a_patch_and_every_row() {
    let m = cube_with([6, 6, 6], [40.0, 40.0, 40.0], Material::DEFAULT).unwrap();
    // Touchable: free surface nodes on the top face (z = 40 mm); displayed: every node.
    let top: Vec<u32> = m
        .free_surface_nodes()
        .into_iter()
        .filter(|&n| (m.nodes[n as usize].z - 0.040).abs() < 1e-9)
        .collect();
    assert!(top.len() > 20);
    let sel = Selection {
        rows: NodeSet::All,
        cols: NodeSet::Nodes(top),
    };
    let (c, g) = both(&m, &sel);
    let d = difference(&c, &g);
    assert!(d < 1e-12, "relative difference {d:.2e} ({})", g.stats.phases.method);
}
