//! What the locking-free stiffness costs, side by side in one run:
//! `cargo run --release --example locking_free_cost MESH [m|mm] [precompute]`.
//! For the standard stiffness, both locking-free smoothings assembled, and the mixed system
//! the formulation factorises: the matrix's non-zeros, the factor's non-zeros and the
//! factorisation's time; with `precompute`, the whole-surface precompute
//! (the surface displayed, the free surface touchable) of the standard and the
//! `locking-free` formulation, alternated, two rounds.
//!
//! Missing or bad arguments: the usage on stderr, exit status 2.

use touchfem::compliance::{Compliance, Selection};
use touchfem::fem::locking_free::{self, Smoothing};
use touchfem::fem::Stiffness;
use touchfem::Formulation;

const USAGE: &str = "usage: locking_free_cost MESH [m|mm] [precompute]";

fn fail(msg: &str) -> ! {
    eprintln!("error: {msg}");
    eprintln!("{USAGE}");
    std::process::exit(2)
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 2 || a.len() > 4 || a.iter().skip(1).any(|s| s == "-h" || s == "--help") {
        fail("expected MESH [UNIT] [precompute]");
    }
    let unit = a.get(2).map(|u| {
        u.parse::<touchfem::LengthUnit>()
            .unwrap_or_else(|e| fail(&format!("unit '{u}': {e}")))
    });
    let precompute = match a.get(3).map(String::as_str) {
        None => false,
        Some("precompute") => true,
        Some(o) => fail(&format!("'{o}' is not 'precompute'")),
    };
    let opts = touchfem::scene::LoadOptions {
        unit,
        ..Default::default()
    };
    let (mut mesh, _) =
        touchfem::scene::load_mesh(&a[1], &opts).unwrap_or_else(|e| fail(&e.to_string()));
    println!(
        "{} nodes, {} tets, E {} Pa, nu {}",
        mesh.nodes.len(),
        mesh.tets.len(),
        mesh.material.young_pa,
        mesh.material.poisson
    );
    println!(
        "{:>18} {:>12} {:>14} {:>10} {:>10}",
        "stiffness", "K nnz", "factor nnz", "assemble_s", "factor_s"
    );
    // None: the standard stiffness; Some((s, false)): the assembled locking-free stiffness;
    // Some((s, true)): the mixed system the formulation factorises.
    let methods: [(&str, Option<(Smoothing, bool)>); 5] = [
        ("standard", None),
        ("nodal (assembled)", Some((Smoothing::Nodal, false))),
        ("nodal (mixed)", Some((Smoothing::Nodal, true))),
        ("projection (mixed)", Some((Smoothing::Projection, true))),
        (
            "element-averaged",
            Some((Smoothing::ElementAveraged, false)),
        ),
    ];
    for (name, s) in methods {
        let t = std::time::Instant::now();
        let k = match s {
            None => Stiffness::assemble(&mesh),
            Some((s, true)) => locking_free::mixed(&mesh, s),
            Some((s, false)) => locking_free::stiffness(&mesh, s),
        }
        .unwrap_or_else(|e| fail(&e.to_string()));
        let assemble = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let f = k.factorize().unwrap_or_else(|e| fail(&e.to_string()));
        let factor = t.elapsed().as_secs_f64();
        println!(
            "{:>18} {:>12} {:>14} {:>10.3} {:>10.3}",
            name,
            k.k.compute_nnz(),
            f.nonzeros(),
            assemble,
            factor
        );
    }
    if precompute {
        // Two rounds, alternated, so that a busy machine weighs on both alike.
        for f in [Formulation::Standard, Formulation::LockingFree].repeat(2) {
            mesh.formulation = f;
            let t = std::time::Instant::now();
            let c = Compliance::compute(&mesh, &Selection::default())
                .unwrap_or_else(|e| fail(&e.to_string()));
            println!(
                "precompute {f}: {:.2} s ({} rows x {} cols, {:.2} GB)",
                t.elapsed().as_secs_f64(),
                c.rows().len(),
                c.cols().len(),
                c.stats.bytes as f64 / 1e9
            );
        }
    }
}
