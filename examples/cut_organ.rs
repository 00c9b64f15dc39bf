//! What cutting costs on a large body: an organ mesh (from `scripts/make_organ.py`, mm), a
//! ball-shaped cuttable region, the touchable nodes those near it; prints the precompute, the
//! factor a cut keeps, removing tets one by one up to the fold rank, the cut body's
//! correction, the CPU product with it, the fold and the rebase (medians of a few runs where
//! cheap). Measurement for docs/measurements/2026-12-04-cutting.md.
//!
//! `cargo run --release --example cut_organ -- out/organ17k.msh [CX,CY,CZ] [RADIUS_MM] [TOUCH_MM] [RANK]`
//!
//! Missing or bad arguments: the usage on stderr, exit status 2.

use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use touchfem::compliance::{Compliance, NodeSet, Selection};
use touchfem::cut::Cut;
use touchfem::mesh::units::LengthUnit;
use touchfem::scene::{load_mesh, LoadOptions};

const USAGE: &str = "usage: cut_organ MESH [CX,CY,CZ] [RADIUS_MM] [TOUCH_MM] [RANK]   \
     (MESH: an organ mesh in mm, e.g. out/organ17k.msh from scripts/make_organ.py; \
     defaults 0,0,60 15 40 160)";

/// Prints `error: {msg}` and the usage to stderr and exits with status 2 (bad input).
fn usage_error(msg: &str) -> ! {
    eprintln!("error: {msg}");
    eprintln!("{USAGE}");
    std::process::exit(2)
}

/// A positive, finite number for argument `what`.
fn positive(s: &str, what: &str) -> f64 {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => v,
        _ => usage_error(&format!("{what} '{s}' is not a positive number")),
    }
}

fn parse3(s: &str) -> DVec3 {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .unwrap_or_default();
    if v.len() != 3 || v.iter().any(|x| !x.is_finite()) {
        usage_error(&format!("centre '{s}' is not CX,CY,CZ"));
    }
    DVec3::new(v[0], v[1], v[2])
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 2 || args.len() > 6 || args.iter().skip(1).any(|a| a.starts_with('-')) {
        usage_error("expected MESH [CX,CY,CZ] [RADIUS_MM] [TOUCH_MM] [RANK]");
    }
    let path = args[1].as_str();
    let centre = args
        .get(2)
        .map_or(DVec3::new(0.0, 0.0, 60.0), |s| parse3(s))
        * 1e-3;
    let radius = args.get(3).map_or(15.0, |s| positive(s, "RADIUS_MM")) * 1e-3;
    let touch = args.get(4).map_or(40.0, |s| positive(s, "TOUCH_MM")) * 1e-3;
    let fold_rank: usize = args.get(5).map_or(160, |s| match s.parse() {
        Ok(r) if r > 0 => r,
        _ => usage_error(&format!("RANK '{s}' is not a positive whole number")),
    });
    let opts = LoadOptions {
        unit: Some(LengthUnit::Millimetre),
        ..Default::default()
    };
    let (mesh, _) = load_mesh(path, &opts).unwrap_or_else(|e| {
        eprintln!("error: {path}: {e}");
        std::process::exit(2)
    });
    // The cuttable ball: tets whose centroid is inside; touchable: its free nodes and the
    // free surface nodes within `touch` of the centre (what a scene would name).
    let ball: Vec<usize> = (0..mesh.tets.len())
        .filter(|&t| {
            let c = mesh.tets[t]
                .iter()
                .map(|&v| mesh.nodes[v as usize])
                .sum::<DVec3>()
                / 4.0;
            c.distance(centre) <= radius
        })
        .collect();
    let mut cols: Vec<u32> = ball
        .iter()
        .flat_map(|&t| mesh.tets[t])
        .chain(
            mesh.surface_nodes
                .iter()
                .copied()
                .filter(|&v| mesh.nodes[v as usize].distance(centre) <= touch),
        )
        .filter(|&v| !mesh.fixed[v as usize])
        .collect();
    cols.sort_unstable();
    cols.dedup();
    println!(
        "{path}: {} nodes, {} tets; cuttable ball {} tets; {} touchable nodes",
        mesh.nodes.len(),
        mesh.tets.len(),
        ball.len(),
        cols.len()
    );
    let sel = Selection {
        rows: NodeSet::Surface,
        cols: NodeSet::Nodes(cols),
    };
    let t = Instant::now();
    let base = Compliance::compute(&mesh, &sel).expect("precompute");
    println!(
        "precompute: {:.2} s ({} rows x {} columns, {:.0} MB of f64)",
        t.elapsed().as_secs_f64(),
        base.rows().len(),
        base.cols().len(),
        base.l_f64().len() as f64 * 8e-6
    );
    let t = Instant::now();
    let mut cut = Cut::new(&mesh).expect("factor");
    println!("the factor a cut keeps: {:.2} s", t.elapsed().as_secs_f64());
    // Tets from the ball's top down (a blade entering from above), one at a time.
    let mut order = ball.clone();
    order.sort_by(|&a, &b| {
        let z = |t: usize| -> f64 { mesh.tets[t].iter().map(|&v| mesh.nodes[v as usize].z).sum() };
        z(b).total_cmp(&z(a))
    });
    let mut first = None;
    let t_all = Instant::now();
    let mut n = 0;
    for &tet in &order {
        let t = Instant::now();
        cut.remove(&mesh, &[tet]).expect("remove");
        first.get_or_insert(t.elapsed().as_secs_f64());
        n += 1;
        if cut.rank() >= fold_rank {
            break;
        }
    }
    println!(
        "remove: the first tet {:.1} ms; {n} tets one by one to rank {}: {:.2} s",
        first.unwrap_or(0.0) * 1e3,
        cut.rank(),
        t_all.elapsed().as_secs_f64()
    );
    let mut times = Vec::new();
    let mut carried = None;
    for _ in 0..3 {
        let t = Instant::now();
        let k = cut.correction(&base).expect("correction");
        carried = Some(base.with_correction(Arc::new(k)).unwrap());
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    println!(
        "the cut body's correction at rank {}: {:.1} ms",
        cut.rank(),
        times[1] * 1e3
    );
    let carried = carried.unwrap();
    let forces = [(0u32, DVec3::new(0.0, 0.0, -0.05))];
    let mut u = vec![DVec3::ZERO; base.rows().len()];
    let mut times = Vec::new();
    for _ in 0..5 {
        let t = Instant::now();
        carried.displace(&forces, &mut u);
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    let mut plain = Vec::new();
    for _ in 0..5 {
        let t = Instant::now();
        base.displace(&forces, &mut u);
        plain.push(t.elapsed().as_secs_f64());
    }
    plain.sort_by(f64::total_cmp);
    println!(
        "CPU product, one column: {:.2} ms with the correction, {:.3} ms without",
        times[2] * 1e3,
        plain[2] * 1e3
    );
    let t = Instant::now();
    let folded = cut.fold(&base).expect("fold");
    println!(
        "fold (correction and L + U Vᵀ): {:.2} s",
        t.elapsed().as_secs_f64()
    );
    let t = Instant::now();
    let _next = cut.rebase(&mesh).expect("rebase");
    println!(
        "rebase (the remaining tets factored): {:.2} s",
        t.elapsed().as_secs_f64()
    );
    // The fold is exact: a block against the carried one.
    let c = folded.cols().len() / 2;
    let d = folded.touch_block(c, c) - carried.touch_block(c, c);
    println!(
        "folded against carried, a diagonal block: {:.1e} relative",
        d.abs().to_cols_array().iter().cloned().fold(0.0, f64::max)
            / carried
                .touch_block(c, c)
                .abs()
                .to_cols_array()
                .iter()
                .cloned()
                .fold(0.0, f64::max)
    );
}
