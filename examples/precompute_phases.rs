//! Where the precompute time goes: `cargo run --release --example precompute_phases MESH [UNIT]`.
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let opts = touchfem::scene::LoadOptions {
        unit: a.get(2).map(|u| u.parse().expect("unit")),
        ..Default::default()
    };
    let (mesh, _) = touchfem::scene::load_mesh(&a[1], &opts).expect("mesh");
    let sel = touchfem::compliance::Selection::default();
    let c = touchfem::compliance::Compliance::compute(&mesh, &sel).expect("compute");
    let s = &c.stats;
    println!(
        "{}",
        serde_json::json!({"nodes": mesh.nodes.len(), "rows": c.rows().len(), "cols": c.cols().len(),
        "seconds": s.seconds, "bytes": s.bytes, "free_dofs": s.free_dofs, "k_nnz": s.k_nonzeros, "phases": s.phases})
    );
}
