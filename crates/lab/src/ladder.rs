//! The mesh-resolution ladder: the same body at growing resolution, the paper's press on each,
//! and how far each rung is from the converged answer — "which mesh do I need for 5 % force
//! error?", with its precompute cost and frame time.
//!
//! Two presses on each rung, both `push` at `at`:
//! * **point** — the paper's finger, a point: the touched node moves by `push` (its force is
//!   the paper's at a vertex). A point displacement has no finite-force limit in 3D
//!   elasticity, so this force falls with every refinement (about ∝ h): the mesh sets the
//!   finger's effective size.
//! * **punch** — a finger of radius `radius`: every surface node within it moves by `push`
//!   (a rigid, bonded flat punch). This has a limit; its error is measured against a
//!   Richardson extrapolation of the finest three rungs.
//! * **sphere** — a frictionless rigid sphere of radius `2·radius` pressed `|push|` deep
//!   (the fingertip, [`touchfem_core::contact::Patch`]): the contact decides its own area,
//!   so this force converges too.

use glam::{DVec3, Vec3};
use std::fmt::Write as _;

use touchfem_core::compliance::{Compliance, NodeSet, Selection};
use touchfem_core::mesh::units::Formulation;
use touchfem_core::mesh::Mesh;

/// One rung of the ladder.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Rung {
    /// The rung's label (e.g. cells per edge).
    pub label: String,
    /// Mesh nodes.
    pub nodes: usize,
    /// Mean surface edge length, m.
    pub h_m: f64,
    /// Force of the point press, N.
    pub point_force_n: f64,
    /// Force of the sphere press, N.
    pub sphere_force_n: f64,
    /// Nodes in contact under the sphere.
    pub sphere_nodes: usize,
    /// Force of the punch, N.
    pub punch_force_n: f64,
    /// Nodes under the punch.
    pub punch_nodes: usize,
    /// `|punch − extrapolated| / extrapolated` (filled by [`finish`]).
    pub punch_error: f64,
    /// Displacement under the punch at the probe points against the finest rung, relative to
    /// the largest (filled by [`finish`]; NaN where there are no common probes).
    pub field_error: f64,
    /// Precompute of the whole free surface (rows: surface; columns: free surface), s
    /// (`None`: skipped, too large for this run).
    pub precompute_s: Option<f64>,
    /// Bytes that precompute holds (f64 L and blocks).
    pub bytes: Option<usize>,
    /// `u = L·F` for one contact triangle (3 columns) over every surface row, f32, µs.
    pub frame_us: Option<f64>,
    /// Punch displacements at the probe points (m), for [`finish`].
    #[serde(skip)]
    probes: Vec<DVec3>,
}

/// Surface nodes within `radius` of `at`.
fn under(mesh: &Mesh, at: DVec3, radius: f64) -> Vec<u32> {
    mesh.free_surface_nodes()
        .into_iter()
        .filter(|&n| mesh.nodes[n as usize].distance(at) <= radius)
        .collect()
}

/// The nearest free-surface node to `at`.
fn nearest(mesh: &Mesh, at: DVec3) -> Option<u32> {
    mesh.free_surface_nodes().into_iter().min_by(|&a, &b| {
        mesh.nodes[a as usize]
            .distance(at)
            .total_cmp(&mesh.nodes[b as usize].distance(at))
    })
}

/// What moving a set of nodes takes.
pub struct Press {
    /// The reaction the finger feels, N.
    pub reaction: DVec3,
    /// The nodal forces applied (mesh node, N).
    pub forces: Vec<(u32, DVec3)>,
    /// The displacement at the probe nodes, m.
    pub probes: Vec<DVec3>,
}

/// Nodes `s` all moved by `push`: the nodal forces (N) that do it, and the displacement at
/// `probe_nodes` (m). Solves `L_SS f = u_S` with the precomputed columns of `s`.
pub fn press_nodes(
    mesh: &Mesh,
    s: &[u32],
    push: DVec3,
    probe_nodes: &[u32],
) -> Result<Press, crate::error::Error> {
    // Rows once each (two probes may share a node), the punched nodes not among them (they
    // are added as columns' rows anyway).
    let mut rows: Vec<u32> = probe_nodes
        .iter()
        .copied()
        .filter(|p| !s.contains(p))
        .collect();
    rows.sort_unstable();
    rows.dedup();
    let sel = Selection {
        rows: NodeSet::Nodes(rows),
        cols: NodeSet::Nodes(s.to_vec()),
    };
    let c = Compliance::compute(mesh, &sel)?;
    let n = s.len();
    let mut a = nalgebra::DMatrix::<f64>::zeros(3 * n, 3 * n);
    for i in 0..n {
        for j in 0..n {
            let b = c.touch_block(i, j);
            for r in 0..3 {
                for k in 0..3 {
                    a[(3 * i + r, 3 * j + k)] = b.col(k)[r];
                }
            }
        }
    }
    let mut rhs = nalgebra::DVector::<f64>::zeros(3 * n);
    for i in 0..n {
        for r in 0..3 {
            rhs[3 * i + r] = push[r];
        }
    }
    let f = a
        .cholesky()
        .ok_or_else(|| crate::error::Error::Study("the punch's compliance is not positive".into()))?
        .solve(&rhs);
    let forces: Vec<(u32, DVec3)> = (0..n)
        .map(|i| (i as u32, DVec3::new(f[3 * i], f[3 * i + 1], f[3 * i + 2])))
        .collect();
    let total = forces.iter().map(|p| p.1).sum::<DVec3>();
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    c.displace(&forces, &mut u);
    let probes = probe_nodes
        .iter()
        .map(|&p| c.row_of(p).map(|r| u[r]).unwrap_or(DVec3::NAN))
        .collect();
    Ok(Press {
        // The finger feels the reaction.
        reaction: -total,
        forces: forces.iter().map(|&(i, f)| (s[i as usize], f)).collect(),
        probes,
    })
}

/// The surface nodes a punch of `radius` at the free-surface node nearest `at` moves.
pub fn punch_nodes(mesh: &Mesh, at: DVec3, radius: f64) -> Vec<u32> {
    match nearest(mesh, at) {
        Some(n) => under(mesh, mesh.nodes[n as usize], radius),
        None => Vec::new(),
    }
}

/// Measures one rung. `probe_nodes`: nodes where the field is compared across rungs (the
/// same physical points on every rung, e.g. the coarsest grid's nodes); `precompute`: also
/// time the whole-surface precompute.
pub fn rung(
    label: &str,
    mesh: &Mesh,
    at: DVec3,
    push: DVec3,
    radius: f64,
    probe_nodes: &[u32],
    precompute: bool,
) -> Result<Rung, crate::error::Error> {
    let node =
        nearest(mesh, at).ok_or_else(|| crate::error::Error::Study("no free surface".into()))?;
    let point = press_nodes(mesh, &[node], push, &[node])?.reaction;
    // The sphere: columns for the free-surface nodes it can reach.
    let (sphere_force_n, sphere_nodes) = {
        let r = 2.0 * radius;
        let reach = (2.0 * r * push.length()).sqrt() * 1.5 + 1e-9;
        let centre = mesh.nodes[node as usize];
        let cols: Vec<u32> = mesh
            .free_surface_nodes()
            .into_iter()
            .filter(|&v| mesh.nodes[v as usize].distance(centre) <= reach)
            .collect();
        let sel = Selection {
            rows: NodeSet::Nodes(cols.clone()),
            cols: NodeSet::Nodes(cols),
        };
        let body = touchfem_core::scene::Body::new(mesh.clone(), &sel)?;
        let p = body.poke_sphere(centre, push, r, None, None)?;
        (p.feedback.length(), p.contact_nodes.len())
    };
    let s = under(mesh, mesh.nodes[node as usize], radius);
    let punch = press_nodes(mesh, &s, push, probe_nodes)?;
    let (punch, probes) = (punch.reaction, punch.probes);
    let mut edge = 0.0;
    for t in &mesh.surface {
        for k in 0..3 {
            edge += mesh.nodes[t[k] as usize].distance(mesh.nodes[t[(k + 1) % 3] as usize]);
        }
    }
    let h = edge / (3 * mesh.surface.len().max(1)) as f64;
    let (mut precompute_s, mut bytes, mut frame_us) = (None, None, None);
    if precompute {
        let t = std::time::Instant::now();
        let c = Compliance::compute(mesh, &Selection::default())?;
        precompute_s = Some(t.elapsed().as_secs_f64());
        bytes = Some(c.stats.bytes);
        let nr = c.rows().len();
        let nc = c.cols().len() as u32;
        let col0 = c.col_of(node).unwrap_or(0) as u32;
        let forces: Vec<(u32, DVec3)> = (0..3)
            .map(|k| ((col0 + k) % nc, DVec3::splat(0.1)))
            .collect();
        let mut u = vec![Vec3::ZERO; nr];
        frame_us = Some(crate::tradeoff::median_us(30, || {
            c.displace_f32(&forces, &mut u);
            std::hint::black_box(&u);
        }));
    }
    Ok(Rung {
        label: label.into(),
        nodes: mesh.nodes.len(),
        h_m: h,
        point_force_n: point.length(),
        sphere_force_n,
        sphere_nodes,
        punch_force_n: punch.length(),
        punch_nodes: s.len(),
        punch_error: f64::NAN,
        field_error: f64::NAN,
        precompute_s,
        bytes,
        frame_us,
        probes,
    })
}

/// Richardson extrapolation of the last three values, taken at sizes shrinking by the same
/// ratio `r`: the limit and the observed order. `None` if they do not converge monotonically.
pub fn richardson(f: [f64; 3], r: f64) -> Option<(f64, f64)> {
    let (a, b, c) = (f[0], f[1], f[2]);
    let d1 = a - b;
    let d2 = b - c;
    if d1 == 0.0 || d2 == 0.0 || d1.signum() != d2.signum() || d2.abs() >= d1.abs() {
        return None;
    }
    let p = (d1 / d2).ln() / r.ln();
    Some((c - d2 / (r.powf(p) - 1.0), p))
}

/// Fills each rung's errors: the punch against the Richardson limit of the last three rungs
/// (sizes shrinking by `ratio`; else against the finest rung), the field against the finest
/// rung's. Returns the limit and the observed order (NaN when it fell back).
pub fn finish(rungs: &mut [Rung], ratio: f64) -> (f64, f64) {
    let n = rungs.len();
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let (limit, order) = if n >= 3 {
        richardson(
            [
                rungs[n - 3].punch_force_n,
                rungs[n - 2].punch_force_n,
                rungs[n - 1].punch_force_n,
            ],
            ratio,
        )
        .unwrap_or((rungs[n - 1].punch_force_n, f64::NAN))
    } else {
        (rungs[n - 1].punch_force_n, f64::NAN)
    };
    let finest = rungs[n - 1].probes.clone();
    let scale = finest.iter().map(|v| v.length()).fold(0.0, f64::max);
    for r in rungs.iter_mut() {
        r.punch_error = (r.punch_force_n - limit).abs() / limit;
        if r.probes.len() == finest.len() && scale > 0.0 {
            r.field_error = r
                .probes
                .iter()
                .zip(&finest)
                .map(|(a, b)| (*a - *b).length())
                .fold(0.0, f64::max)
                / scale;
        }
    }
    (limit, order)
}

/// The paper's cube (30 mm, E = 10 kPa, ν = 0.49) at `cells` per edge (each a multiple of
/// the first, so the first grid's nodes are on every rung): Fig. 1b's press, 5 mm down at the
/// top centre, as a point and as a 5 mm-radius punch; the field compared at the first grid's
/// nodes. Precompute timed up to `precompute_max_nodes`.
pub fn cube_ladder(
    cells: &[usize],
    precompute_max_nodes: usize,
) -> Result<(Vec<Rung>, f64, f64), crate::error::Error> {
    cube_ladder_with(cells, precompute_max_nodes, Formulation::Standard)
}

/// [`cube_ladder`] with the stiffness of `formulation`.
pub fn cube_ladder_with(
    cells: &[usize],
    precompute_max_nodes: usize,
    formulation: Formulation,
) -> Result<(Vec<Rung>, f64, f64), crate::error::Error> {
    let base = cells.first().copied().unwrap_or(4);
    let mut rungs = Vec::new();
    for &n in cells {
        let mut mesh = touchfem_core::mesh::cube_with(
            [n; 3],
            [30.0; 3],
            touchfem_core::mesh::units::Material {
                young_pa: 10_000.0,
                poisson: 0.49,
            },
        )?;
        mesh.formulation = formulation;
        // The base grid's nodes, found on this rung by position.
        let probes: Vec<u32> = (0..=base)
            .flat_map(|k| (0..=base).flat_map(move |j| (0..=base).map(move |i| (i, j, k))))
            .map(|(i, j, k)| {
                let s = n / base;
                ((k * s * (n + 1) + j * s) * (n + 1) + i * s) as u32
            })
            .collect();
        let r = rung(
            &format!("{n}^3"),
            &mesh,
            DVec3::new(0.015, 0.015, 0.03),
            DVec3::new(0.0, 0.0, -0.005),
            0.005,
            &probes,
            mesh.nodes.len() <= precompute_max_nodes,
        )?;
        rungs.push(r);
    }
    let ratio = if cells.len() >= 2 {
        cells[cells.len() - 1] as f64 / cells[cells.len() - 2] as f64
    } else {
        2.0
    };
    let (limit, order) = finish(&mut rungs, ratio);
    Ok((rungs, limit, order))
}

/// The mouse regenerated by `scripts/make_mouse.py` at several surface sizes, files
/// `mouse_h{H}.msh` in `dir` (H in mm; the bundled mouse is H = 4.4), finest last: Fig. 2's
/// press, 8 mm down at (−10, 0, 60) mm, as a point and as a 5 mm punch, the field compared
/// at the coarsest rung's surface nodes away from the press. Sizes shrink by √2 per rung, so
/// the punch is extrapolated with that ratio. Precompute timed up to
/// `precompute_max_nodes`.
pub(crate) fn mouse_ladder(
    dir: &std::path::Path,
    precompute_max_nodes: usize,
) -> Result<Option<(Vec<Rung>, f64, f64)>, crate::error::Error> {
    let mut files: Vec<(f64, std::path::PathBuf)> = std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .filter_map(|e| {
                    let name = e.file_name().to_string_lossy().to_string();
                    let h = name.strip_prefix("mouse_h")?.strip_suffix(".msh")?;
                    Some((h.parse::<f64>().ok()?, e.path()))
                })
                .collect()
        })
        .unwrap_or_default();
    if files.is_empty() {
        return Ok(None);
    }
    files.push((4.4, std::path::PathBuf::from("mouse")));
    files.sort_by(|a, b| b.0.total_cmp(&a.0));
    let opts = touchfem_core::scene::LoadOptions {
        unit: Some(touchfem_core::mesh::units::LengthUnit::Millimetre),
        fixed_group: "fixed".into(),
        ..Default::default()
    };
    let at = DVec3::new(-0.010, 0.0, 0.060);
    let mut rungs = Vec::new();
    // The field is compared at fixed points: the coarsest rung's free-surface nodes more than
    // 25 mm from the press (where the field is smooth), found on each rung as the nearest
    // surface node (so the comparison also carries a position error of about h/2 × ∇u).
    let mut points: Vec<DVec3> = Vec::new();
    for (h, path) in &files {
        let (mesh, _) = touchfem_core::scene::load_mesh(&path.to_string_lossy(), &opts)?;
        if points.is_empty() {
            points = mesh
                .free_surface_nodes()
                .into_iter()
                .map(|n| mesh.nodes[n as usize])
                .filter(|p| p.distance(at) > 0.025)
                .collect();
        }
        let free = mesh.free_surface_nodes();
        let probes: Vec<u32> = points
            .iter()
            .filter_map(|p| {
                free.iter().copied().min_by(|&a, &b| {
                    mesh.nodes[a as usize]
                        .distance(*p)
                        .total_cmp(&mesh.nodes[b as usize].distance(*p))
                })
            })
            .collect();
        rungs.push(rung(
            &format!("h {h} mm"),
            &mesh,
            at,
            DVec3::new(0.0, 0.0, -0.008),
            0.005,
            &probes,
            mesh.nodes.len() <= precompute_max_nodes,
        )?);
    }
    let (limit, order) = finish(&mut rungs, std::f64::consts::SQRT_2);
    Ok(Some((rungs, limit, order)))
}

fn print_rungs(out: &mut String, rungs: &[Rung], limit: f64, order: f64) {
    let _ = writeln!(
        out,
        "{:>10} {:>6} {:>7} {:>9} {:>9} {:>9} {:>6} {:>9} {:>9} {:>10} {:>9} {:>9}",
        "rung",
        "nodes",
        "h_mm",
        "point_N",
        "sphere_N",
        "punch_N",
        "under",
        "punch_err",
        "field_err",
        "precomp_s",
        "L_MB",
        "frame_us"
    );
    for r in rungs {
        let opt = |v: Option<f64>, k: f64| v.map_or("-".to_string(), |v| format!("{:.3}", v * k));
        let _ = writeln!(
            out,
            "{:>10} {:>6} {:>7.3} {:>9.4} {:>9.4} {:>9.4} {:>6} {:>9.2e} {:>9.2e} {:>10} {:>9} {:>9}",
            r.label,
            r.nodes,
            r.h_m * 1e3,
            r.point_force_n,
            r.sphere_force_n,
            r.punch_force_n,
            r.punch_nodes,
            r.punch_error,
            r.field_error,
            opt(r.precompute_s, 1.0),
            opt(r.bytes.map(|b| b as f64), 1e-6),
            opt(r.frame_us, 1.0)
        );
    }
    let _ = writeln!(
        out,
        "punch limit {limit:.4} N (Richardson order {order:.2}; NaN: the finest rung)"
    );
}

/// `touchfem bench --ladder`: the table of the cube's ladder (returned, for the caller to print) and, where `dir` holds them, the
/// mouse's; with `json`, writes `{"cube": {...}, "cube_locking_free": {...}, "mouse": {...},
/// "machine"}` (the cube also with the locking-free stiffness), each with
/// `ladder` ([`Rung`]s), `punch_limit_n` and `order`.
pub fn bench(
    cells: &[usize],
    dir: &std::path::Path,
    json: Option<&std::path::Path>,
) -> Result<String, crate::error::Error> {
    let mut out = String::new();
    let (rungs, limit, order) = cube_ladder(cells, 6000)?;
    let _ = writeln!(
        out,
        "the paper's cube (30 mm, 10 kPa, ν 0.49), Fig. 1b: 5 mm down at the top centre"
    );
    print_rungs(&mut out, &rungs, limit, order);
    let cube = serde_json::json!({"ladder": rungs, "punch_limit_n": limit, "order": order});
    let (rungs, limit, order) = cube_ladder_with(cells, 6000, Formulation::LockingFree)?;
    let _ = writeln!(
        out,
        "\nthe same with formulation = \"locking-free\" (each rung against its own finest)"
    );
    print_rungs(&mut out, &rungs, limit, order);
    let cube_lf = serde_json::json!({"ladder": rungs, "punch_limit_n": limit, "order": order});
    let mouse = match mouse_ladder(dir, 6000)? {
        Some((rungs, limit, order)) => {
            let _ = writeln!(out, "\nthe mouse (1 kPa, ν 0.3) by scripts/make_mouse.py, Fig. 2: 8 mm down at (-10, 0, 60) mm");
            print_rungs(&mut out, &rungs, limit, order);
            serde_json::json!({"ladder": rungs, "punch_limit_n": limit, "order": order})
        }
        None => {
            let _ = writeln!(
        out,
                "\n(no mouse ladder: make it with MOUSE_H=H MOUSE_OUT={}/mouse_hH.msh python3 scripts/make_mouse.py)",
                dir.display()
            );
            serde_json::Value::Null
        }
    };
    if let Some(path) = json {
        let v = serde_json::json!({
            "cube": cube, "cube_locking_free": cube_lf, "mouse": mouse, "machine": crate::report::machine(),
        });
        crate::tradeoff::write_json(path, &v)?;
    }
    Ok(out)
}
