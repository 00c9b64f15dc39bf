//! The hierarchical compliance on a large organ: an organ mesh from
//! `scripts/make_organ.py` (mm), its whole free surface touchable. Builds the hierarchical `L`
//! from the factor's solves (timed), checks point loads against an independent precompute of
//! a sample of columns, and, unless `--no-dense`, computes the dense `L` in the same run (timed)
//! and times one finger's GPU pass through both (lavapipe). Prints one JSON object.
//! Measurement for docs/measurements/2026-12-04-hierarchical.md.
//!
//! `cargo run --release --example hier_organ -- out/organ46k.msh [EPS] [SAMPLE] [--no-dense]`
//!
//! Missing or bad arguments: the usage on stderr, exit status 2.

use std::time::Instant;

use glam::DVec3;
use touchfem::compliance::{Compliance, Selection};
use touchfem::mesh::units::LengthUnit;
use touchfem::scene::{load_mesh, Body, LoadOptions};

const USAGE: &str = "usage: hier_organ MESH [EPS] [SAMPLE] [--no-dense]   \
     (MESH: an organ mesh in mm, e.g. out/organ46k.msh from scripts/make_organ.py; \
     EPS in (0, 1), default 1e-3; SAMPLE columns checked, default 300)";

/// Prints `error: {msg}` and the usage to stderr and exits with status 2 (bad input).
fn usage_error(msg: &str) -> ! {
    eprintln!("error: {msg}");
    eprintln!("{USAGE}");
    std::process::exit(2)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dense = !args.iter().any(|a| a == "--no-dense");
    let rest: Vec<&str> = args
        .iter()
        .skip(1)
        .map(String::as_str)
        .filter(|a| *a != "--no-dense")
        .collect();
    if rest.is_empty() || rest.len() > 3 || rest.iter().any(|a| a.starts_with('-')) {
        usage_error("expected MESH [EPS] [SAMPLE] [--no-dense]");
    }
    let path = rest[0];
    let eps: f64 = rest.get(1).map_or(1e-3, |s| match s.parse::<f64>() {
        Ok(e) if e > 0.0 && e < 1.0 => e,
        _ => usage_error(&format!("EPS '{s}' is not in (0, 1)")),
    });
    let sample: usize = rest.get(2).map_or(300, |s| match s.parse() {
        Ok(n) if n > 0 => n,
        _ => usage_error(&format!("SAMPLE '{s}' is not a positive whole number")),
    });
    let opts = LoadOptions {
        unit: Some(LengthUnit::Millimetre),
        ..Default::default()
    };
    let (mesh, _) = load_mesh(path, &opts).unwrap_or_else(|e| {
        eprintln!("error: {path}: {e}");
        std::process::exit(2)
    });
    let (row, hc) =
        touchfem_lab::hmatrix_study::sampled_row(path, &mesh, eps, sample).expect("hierarchical");
    let h = hc.hier().expect("hierarchical");
    let mut out = serde_json::to_value(&row).expect("json");
    out["gpu_bytes"] = touchfem::gpu::hier_gpu_bytes(h, false).into();
    out["gpu_bytes_f16"] = touchfem::gpu::hier_gpu_bytes(h, true).into();
    // One finger: the middle column and its 8 nearest columns.
    let cols = hc.cols();
    let finger = touchfem_lab::hmatrix_study::finger_forces(&mesh, cols);
    let gpu = touchfem::gpu::Gpu::new_headless().ok();
    let body = Body::with_compliance(mesh.clone(), hc.clone());
    if let Some(g) = &gpu {
        out["gpu_pass_us"] = touchfem_lab::hmatrix_study::pass_us(g, &body, &hc, &finger, 50)
            .expect("pass")
            .into();
    }
    if dense {
        let t = Instant::now();
        let dc = Compliance::compute(&mesh, &Selection::default()).expect("dense");
        out["dense_precompute_s"] = t.elapsed().as_secs_f64().into();
        out["dense_bytes_f64"] = (8 * dc.l_f64().len()).into();
        if let Some(g) = &gpu {
            // The same finger's columns in the dense compliance's order.
            let f: Vec<(u32, DVec3)> = finger
                .iter()
                .map(|&(k, f)| (dc.col_of(cols[k as usize]).expect("col") as u32, f))
                .collect();
            let db = Body::with_compliance(mesh.clone(), dc.clone());
            out["gpu_dense_pass_us"] = touchfem_lab::hmatrix_study::pass_us(g, &db, &dc, &f, 50)
                .expect("dense pass")
                .into();
        }
    }
    println!("{out}");
}
