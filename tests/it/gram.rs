//! The Gram method of the precompute (sparse forward solves and their products) against the
//! column method (a full forward and back substitution per column), on whole surfaces and on
//! partial selections.

use touchfem::compliance::{Compliance, Method, NodeSet, Selection};
use touchfem::mesh::{cube_with, mouse};
use touchfem::{Material, Mesh};

/// max over displayed × touchable entries of |a − b| / max |a|, matched by node.
fn difference(a: &Compliance, b: &Compliance) -> f64 {
    let mut ra = a.rows().to_vec();
    let mut rb = b.rows().to_vec();
    ra.sort_unstable();
    rb.sort_unstable();
    assert_eq!(ra, rb, "the same displayed nodes");
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
        for (r, &node) in a.rows().iter().enumerate() {
            let e = (a.block(r, ca) - b.block(b.row_of(node).unwrap(), cb))
                .abs()
                .to_cols_array();
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
    assert_eq!(
        g.stats.phases.method, "gram",
        "the mouse's factor is supernodal"
    );
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
    assert_eq!(g.stats.phases.method, "gram");
    let d = difference(&c, &g);
    assert!(d < 1e-12, "relative difference {d:.2e}");
}

#[test]
fn precomputed_files_mirror_the_gram_tiles_exactly_whole_and_sharded() {
    use touchfem::cache;
    use touchfem::precompute::precompute_to_file;
    let m = mouse();
    let sel = Selection::default();
    let key = cache::key(&m, &sel);
    let c = Compliance::compute_with_method(&m, &sel, Method::Columns, &mut |_, _| {}).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Whole: the second pass fills every batch's upper rows from the file's earlier batches.
    let whole = dir.path().join("whole.tfc");
    let r = precompute_to_file(
        &m,
        &sel,
        &whole,
        (1, 1),
        &mut |_, _| {},
        &Default::default(),
    )
    .unwrap();
    assert_eq!(r.phases.method, "gram");
    let g = cache::load(&whole, key, m.nodes.len()).unwrap();
    let d = difference(&c, &g);
    assert!(d < 1e-12, "whole file: relative difference {d:.2e}");
    // Three shards: each mirrors only inside its own columns and computes the rows above.
    let parts: Vec<_> = (1..=3)
        .map(|i| {
            let p = dir.path().join(format!("p{i}.tfc"));
            precompute_to_file(&m, &sel, &p, (i, 3), &mut |_, _| {}, &Default::default()).unwrap();
            p
        })
        .collect();
    let merged = dir.path().join("merged.tfc");
    cache::merge(&parts, &merged).unwrap();
    assert_eq!(
        std::fs::read(&merged).unwrap(),
        std::fs::read(&whole).unwrap()
    );
}

#[test]
fn pruned_columns_equal_full_solves_for_a_ball_of_columns() {
    // A few touchable nodes near one end of the mouse, every surface node displayed: the
    // pruned sweeps must give faer's full solve on every displayed row.
    let m = mouse();
    let free = m.free_surface_nodes();
    let x_min = free
        .iter()
        .map(|&n| m.nodes[n as usize].x)
        .fold(f64::INFINITY, f64::min);
    let ball: Vec<u32> = free
        .into_iter()
        .filter(|&n| m.nodes[n as usize].x < x_min + 0.015)
        .collect();
    assert!(ball.len() > 10 && ball.len() < 200, "{}", ball.len());
    let sel = Selection {
        rows: NodeSet::Surface,
        cols: NodeSet::Nodes(ball),
    };
    let full = Compliance::compute_with_method(&m, &sel, Method::Full, &mut |_, _| {}).unwrap();
    let pruned =
        Compliance::compute_with_method(&m, &sel, Method::Columns, &mut |_, _| {}).unwrap();
    assert_eq!(pruned.stats.phases.method, "columns");
    let d = difference(&full, &pruned);
    assert!(d < 1e-12, "relative difference {d:.2e}");
}
