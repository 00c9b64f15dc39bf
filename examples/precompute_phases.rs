//! Where the precompute time goes:
//! `cargo run --release --example precompute_phases MESH [UNIT] [factor]`
//! (`factor`: only the factorisation, both orderings, with the factor's non-zeros; `forward`:
//! the Gram method's forward solves on 1 and 2 threads, with their flop rate; `frontal`,
//! `faer` or `both` `[THREADS]`: the out-of-core factorisation into a file on THREADS threads
//! (default 2), faer's in memory, or both and their largest difference).
//!
//! Missing or bad arguments: the usage on stderr, exit status 2.

const USAGE: &str =
    "usage: precompute_phases MESH [m|mm] [factor|forward|frontal|faer|both [THREADS]]";

/// Prints `error: {msg}` and the usage to stderr and exits with status 2 (bad input).
fn usage_error(msg: &str) -> ! {
    eprintln!("error: {msg}");
    eprintln!("{USAGE}");
    std::process::exit(2)
}

fn main() {
    // The program's name first, as the phases below index them.
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 2 || a.len() > 5 || a.iter().skip(1).any(|s| s == "-h" || s == "--help") {
        usage_error("expected MESH [UNIT] [PHASE [THREADS]]");
    }
    if let Some(m) = a.get(3) {
        if !["factor", "forward", "frontal", "faer", "both"].contains(&m.as_str()) {
            usage_error(&format!("'{m}' is not a phase"));
        }
    }
    if let Some(t) = a.get(4) {
        if !(a[3] == "frontal" || a[3] == "both")
            || !t.parse::<usize>().is_ok_and(|n| (1..=1024).contains(&n))
        {
            usage_error(&format!(
                "THREADS '{t}': a whole number in 1..=1024, after frontal or both"
            ));
        }
    }
    let unit = a.get(2).map(|u| {
        u.parse::<touchfem::LengthUnit>()
            .unwrap_or_else(|e| usage_error(&format!("unit '{u}': {e}")))
    });
    let opts = touchfem::scene::LoadOptions {
        unit,
        ..Default::default()
    };
    let (mesh, _) = touchfem::scene::load_mesh(&a[1], &opts).unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(2)
    });
    if a.get(3).is_some_and(|s| s == "factor") {
        let k = touchfem::fem::Stiffness::assemble(&mesh).expect("K");
        for o in [
            touchfem::fem::Ordering::Amd,
            touchfem::fem::Ordering::NestedDissection,
            touchfem::fem::Ordering::Metis,
        ] {
            let (f, sym, num) = k.factorize_timed(o).expect("factor");
            println!(
                "{}",
                serde_json::json!({"nodes": mesh.nodes.len(), "ordering": format!("{o:?}"),
                "factor_nonzeros": f.nonzeros(), "symbolic_s": sym, "numeric_s": num})
            );
        }
        return;
    }
    if a.get(3)
        .is_some_and(|s| s == "frontal" || s == "faer" || s == "both")
    {
        let k = touchfem::fem::Stiffness::assemble(&mesh).expect("K");
        let mode = a[3].as_str();
        let o = touchfem::fem::Ordering::Metis;
        let ooc = (mode != "faer").then(|| {
            let (f, sym, num) = k
                .factorize_in(
                    o,
                    &touchfem::fem::FactorStore::File {
                        dir: std::env::temp_dir(),
                        threads: a.get(4).and_then(|v| v.parse().ok()).unwrap_or(2),
                    },
                )
                .expect("frontal");
            println!(
                "{}",
                serde_json::json!({"method": "frontal", "symbolic_s": sym, "numeric_s": num,
                "factor_bytes": 8 * f.nonzeros(), "front_peak_bytes": f.front_bytes()})
            );
            f
        });
        let mem = (mode != "frontal").then(|| {
            let (f, sym, num) = k.factorize_timed(o).expect("faer");
            println!(
                "{}",
                serde_json::json!({"method": "faer", "symbolic_s": sym, "numeric_s": num})
            );
            f
        });
        if let Some(f) = &ooc {
            let shown = mesh.free_surface_nodes();
            let u = touchfem::fem::gram::UnitSolver::new(f, {
                let d = &k.dofs;
                shown
                    .iter()
                    .flat_map(move |&r| (0..3).filter_map(move |a| d.free(r, a)))
            })
            .expect("units");
            println!(
                "{}",
                serde_json::json!({"kept_supernodes": u.kept(), "kept_values": u.kept_values(f)})
            );
        }
        if let (Some(a), Some(b)) = (ooc, mem) {
            let (x, y) = (a.supernodal().unwrap().1, b.supernodal().unwrap().1);
            let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let diff = x
                .iter()
                .zip(y)
                .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
            println!(
                "{}",
                serde_json::json!({"max_abs": scale, "max_diff": diff, "rel": diff / scale})
            );
        }
        return;
    }
    if a.get(3).is_some_and(|s| s == "forward") {
        let k = touchfem::fem::Stiffness::assemble(&mesh).expect("K");
        let f = k.factorize().expect("factor");
        let shown = mesh.free_surface_nodes();
        let g =
            touchfem::fem::gram::GramPlan::new(&f, &k.dofs, &shown, &shown).expect("supernodal");
        for threads in [1, 2] {
            let t = std::time::Instant::now();
            let w = g.forward(&f, threads).expect("W");
            let s = t.elapsed().as_secs_f64();
            println!(
                "{}",
                serde_json::json!({"threads": threads, "forward_s": s, "forward_flops": g.forward_flops,
                "gram_flops": g.gram_flops, "factor_nonzeros": f.nonzeros(),
                "gflops": g.forward_flops / s * 1e-9, "w_bytes": 8 * w.len()})
            );
        }
        return;
    }
    let sel = touchfem::compliance::Selection::default();
    let c = touchfem::compliance::Compliance::compute(&mesh, &sel).expect("compute");
    let s = &c.stats;
    println!(
        "{}",
        serde_json::json!({"nodes": mesh.nodes.len(), "rows": c.rows().len(), "cols": c.cols().len(),
        "seconds": s.seconds, "bytes": s.bytes, "free_dofs": s.free_dofs, "k_nnz": s.k_nonzeros, "phases": s.phases})
    );
}
