//! Cutting, measured (`touchfem bench --cut`): on the mouse (and the cube), cuts of 1 and 50
//! tets near the back (25 on the cube), each against a full precompute of the remaining tets (the reference,
//! and what a cut avoids): the cut pass a blade's stroke costs (removal, the correction, the
//! opened surface), the fold into a new `L`, the haptic tick on the cut body, and, with a GPU,
//! the blade-to-vertex-buffer latency (the cut pass, the body put on the GPU pass, one pass).
//! Errors are relative max-norm displacement errors under a press beside the cut, against the
//! recompute.

use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use touchfem_core::compliance::{Compliance, Selection};
use touchfem_core::contact::finger::Finger;
use touchfem_core::contact::force::ForceModel;
use touchfem_core::contact::Surface;
use touchfem_core::runtime::cutting::{CutBody, Cutter};
use touchfem_core::scene::{SceneSource, World};

use crate::error::Error;
use crate::tradeoff::median_us;

/// One row of `touchfem bench --cut`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CutRow {
    /// What was timed: `recompute`, `cut-pass`, `fold`, `tick-point-exact`,
    /// `gpu-install-and-pass`, `blade-to-vertex-buffer`; for a blade that separates
    /// (`CutMode::Separate`, a 3 mm chord continuing one before it), `separate-pass`,
    /// `separate-gpu-install-and-pass` and `separate-blade-to-vertex-buffer`.
    pub method: String,
    /// Mesh name.
    pub mesh: String,
    /// Mesh nodes.
    pub nodes: usize,
    /// Tets the cut removed.
    pub tets_removed: usize,
    /// The correction's rank after the cut.
    pub rank: usize,
    /// Median time, µs.
    pub time_us: f64,
    /// Relative displacement error against the recompute (0 for the recompute itself); for
    /// the separating GPU rows, the GPU's vertices (rows and copies) against the f64 CPU
    /// product of the same body (0 for `separate-pass`).
    pub rel_error: f64,
}

/// A scene of a bundled mesh or a mesh file in mm, cuttable in a ball of `radius_mm` around `at_mm`.
fn world(mesh: &str, at_mm: DVec3, radius_mm: f64) -> Result<World, Error> {
    // (A mesh file is in mm too.)
    let file_unit = if matches!(mesh, "cube" | "mouse") {
        ""
    } else {
        "mesh_unit = \"mm\"\n"
    };
    let text = format!(
        "unit = \"mm\"\n[[object]]\nmesh = \"{mesh}\"\n{file_unit}cuttable = {{ center = [{}, {}, {}], radius = {radius_mm} }}\n[[finger]]\ndevice = \"script\"\npath = [[0.0, 0.0, 0.0, 200.0]]\n",
        at_mm.x, at_mm.y, at_mm.z
    );
    Ok(World::from_source_with(
        &SceneSource {
            name: mesh.into(),
            text,
            dir: ".".into(),
            label: format!("{mesh}, cuttable"),
        },
        None,
    )?)
}

/// The median of `v` (the upper one of an even count, as the other rows take it).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Max-norm relative difference of `a` (rows of `ca`) against `b` (rows of `cb`) over the
/// rows both display.
fn rel_err(ca: &Compliance, a: &[DVec3], cb: &Compliance, b: &[DVec3]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (r, &v) in ca.rows().iter().enumerate() {
        if let Some(rb) = cb.row_of(v) {
            num = num.max((a[r] - b[rb]).length());
            den = den.max(b[rb].length());
        }
    }
    if den > 0.0 {
        num / den
    } else {
        f64::INFINITY
    }
}

/// The displacement of `c`'s rows under `f` at mesh node `node` (zero when not touchable).
fn press(c: &Compliance, node: u32, f: DVec3) -> Vec<DVec3> {
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    if let Some(col) = c.col_of(node) {
        c.displace(&[(col as u32, f)], &mut u);
    }
    u
}

/// The rows of `touchfem bench --cut` (`gpu`: add the GPU rows; `quick`: the mouse's 1-tet cut
/// only, fewer repetitions).
pub fn rows(gpu: Option<&touchfem_gpu::Gpu>, quick: bool) -> Result<Vec<CutRow>, Error> {
    let mut rows = Vec::new();
    let cases: &[(&str, DVec3, f64, &[usize])] = if quick {
        &[("mouse", DVec3::new(-10.0, 0.0, 40.0), 12.0, &[1])]
    } else {
        &[
            ("cube", DVec3::new(15.0, 15.0, 26.0), 12.0, &[1, 25]),
            ("mouse", DVec3::new(-10.0, 0.0, 40.0), 12.0, &[1, 50]),
        ]
    };
    let reps = if quick { 3 } else { 5 };
    for &(name, at_mm, radius_mm, sizes) in cases {
        let w = world(name, at_mm, radius_mm)?;
        let obj = &w.objects[0];
        let mesh = &obj.body.mesh;
        let at = at_mm * 1e-3;
        for &n in sizes {
            let tets = touchfem_core::cut::tets_near_keeping_nodes(mesh, at, n);
            // The cut pass, on a fresh cutter each time (the factor is the precompute's).
            let mut times = Vec::new();
            let mut body: Option<Arc<CutBody>> = None;
            let mut gone = Vec::new();
            for _ in 0..reps {
                let mut cutter = Cutter::new(&w)?;
                let t = Instant::now();
                body = cutter.remove_tets(0, &tets)?;
                times.push(t.elapsed().as_secs_f64() * 1e6);
                gone = cutter.removed(0).unwrap_or_default().to_vec();
            }
            times.sort_by(f64::total_cmp);
            let body = body.ok_or_else(|| Error::Study("the cut removed nothing".into()))?;
            let (removed, rank) = (body.tets_removed, body.report.rank);
            let row = |method: &str, time_us: f64, rel_error: f64| CutRow {
                method: method.into(),
                mesh: name.into(),
                nodes: mesh.nodes.len(),
                tets_removed: removed,
                rank,
                time_us,
                rel_error,
            };
            // The reference: a full precompute of the remaining tets.
            if body.report.nodes_pinned > 0 {
                return Err(Error::Study(format!(
                    "the {name}'s cut of {n} tets pinned nodes: no recompute to compare with"
                )));
            }
            let cut_mesh = mesh.without_tets(&gone);
            let t = Instant::now();
            let full = Compliance::compute(&cut_mesh, &Selection::default())?;
            let recompute_us = t.elapsed().as_secs_f64() * 1e6;
            // A press beside the cut: the touchable surface node nearest 6 mm above it.
            let node = *full
                .cols()
                .iter()
                .filter(|&&v| body.compliance.col_of(v).is_some())
                .min_by(|&&a, &&b| {
                    let d = |v: u32| mesh.nodes[v as usize].distance(at + DVec3::Z * 6e-3);
                    d(a).total_cmp(&d(b))
                })
                .ok_or_else(|| Error::Study("no touchable node beside the cut".into()))?;
            let f = DVec3::new(0.0, 0.0, -0.05);
            let reference = press(&full, node, f);
            let carried = press(&body.compliance, node, f);
            rows.push(row("recompute", recompute_us, 0.0));
            rows.push(row(
                "cut-pass",
                times[times.len() / 2],
                rel_err(&body.compliance, &carried, &full, &reference),
            ));
            let t = Instant::now();
            let folded = body.compliance.folded()?;
            let fold_us = t.elapsed().as_secs_f64() * 1e6;
            let u = press(&folded, node, f);
            rows.push(row(
                "fold",
                fold_us,
                rel_err(&folded, &u, &full, &reference),
            ));
            // The point finger's exact tick pressing 0.5 mm at that node, on the cut body.
            let p = mesh.nodes[node as usize];
            let what = format!("the {name}'s press beside the cut");
            let tick = tick_us(&body, node, p, &what, quick)?;
            rows.push(row("tick-point-exact", tick, 0.0));
            if let Some(g) = gpu {
                let opts = touchfem_gpu::DeformerOptions::default();
                let col = body.compliance.col_of(node).unwrap_or(0) as u32;
                let forces = [(col, f.as_vec3().to_array())];
                let mut times = Vec::new();
                let mut err = 0.0;
                for _ in 0..reps {
                    let (us, d) = install_timed(g, obj, &body, &opts, &forces, &forces, None)?;
                    times.push(us);
                    let (pos, _) = d.read_back(&g.device, &g.queue)?;
                    let c = &body.compliance;
                    let got: Vec<DVec3> = pos
                        .iter()
                        .zip(c.rows())
                        .map(|(q, &v)| glam::Vec3::from(*q).as_dvec3() - mesh.nodes[v as usize])
                        .collect();
                    // (No node is pinned: the cut keeps every node a tet.)
                    err = rel_err(c, &got, &full, &reference);
                }
                times.sort_by(f64::total_cmp);
                let install = times[times.len() / 2];
                rows.push(row("gpu-install-and-pass", install, err));
                let cut_pass = rows
                    .iter()
                    .rev()
                    .find(|r| r.method == "cut-pass")
                    .map_or(0.0, |r| r.time_us);
                rows.push(row("blade-to-vertex-buffer", cut_pass + install, err));
            }
        }
    }
    if let Some(&(name, at_mm, radius_mm, _)) = cases.iter().find(|c| c.0 == "mouse") {
        separate_rows(
            gpu,
            name,
            at_mm,
            radius_mm,
            [-6.0, -3.0, 0.0],
            reps,
            &mut rows,
        )?;
    }
    Ok(rows)
}

/// The separating blade's rows on a mesh file (`mesh`, in mm: an organ from
/// `scripts/make_organ.py`): a 3 mm chord after the one before it, along x to its highest
/// node, 8 mm deep, cuttable within 15 mm of a point 10 mm below that node.
pub fn scene_rows(
    gpu: Option<&touchfem_gpu::Gpu>,
    mesh: &str,
    quick: bool,
) -> Result<Vec<CutRow>, Error> {
    let (m, _) = touchfem_core::scene::load_mesh(
        mesh,
        &touchfem_core::scene::LoadOptions {
            unit: Some(touchfem_core::mesh::units::LengthUnit::Millimetre),
            ..Default::default()
        },
    )?;
    let top = (m.nodes.iter())
        .copied()
        .max_by(|a, b| a.z.total_cmp(&b.z))
        .ok_or_else(|| Error::Study(format!("{mesh} has no node")))?
        * 1e3;
    let at_mm = top - DVec3::Z * 10.0;
    let xs = [top.x - 6.0, top.x - 3.0, top.x];
    let mut rows = Vec::new();
    separate_rows(
        gpu,
        mesh,
        at_mm,
        15.0,
        xs,
        if quick { 3 } else { 5 },
        &mut rows,
    )?;
    Ok(rows)
}

/// The median time (µs, of 200 ticks when `quick`, else 2000) of a point finger's exact tick
/// on `body` pressing 0.5 mm at `node` (at `p`, along its normal); an error naming `what` when
/// the press does not touch.
fn tick_us(body: &CutBody, node: u32, p: DVec3, what: &str, quick: bool) -> Result<f64, Error> {
    let nrm = body.surface.vertex_normal(node);
    let (surf, c) = (&body.surface, &body.compliance);
    let mut finger = Finger::new(p + nrm * 1e-3);
    let mut first = DVec3::ZERO;
    for _ in 0..4 {
        first = finger.step(surf, c, p - nrm * 5e-4, ForceModel::Exact, 8.5);
    }
    if first.length() < 1e-6 {
        return Err(Error::Study(format!("{what} does not touch ({first})")));
    }
    let mut i = 0usize;
    Ok(median_us(if quick { 200 } else { 2000 }, || {
        i = (i + 1) & 63;
        let x = p - nrm * 5e-4 + DVec3::X * (1e-6 * i as f64 / 64.0);
        std::hint::black_box(finger.step(surf, c, x, ForceModel::Exact, 8.5));
    }))
}

/// A deformer of `obj`'s uncut compliance (holding `before` where given: the cut body of the
/// blade's step before), one frame of `warm` forces, then the time (µs) to put `body` on it
/// ([`touchfem_gpu::install_cut`]) and draw one frame of `forces`.
fn install_timed(
    g: &touchfem_gpu::Gpu,
    obj: &touchfem_core::scene::Object,
    body: &CutBody,
    opts: &touchfem_gpu::DeformerOptions,
    warm: &[(u32, [f32; 3])],
    forces: &[(u32, [f32; 3])],
    before: Option<&CutBody>,
) -> Result<(f64, touchfem_gpu::Deformer), Error> {
    let mesh = &obj.body.mesh;
    let uncut = &obj.body.compliance;
    let mut d =
        touchfem_gpu::Deformer::new(&g.device, &g.queue, uncut, &mesh.nodes, &mesh.surface, opts)?;
    if let Some(b) = before {
        let c = &b.compliance;
        touchfem_gpu::install_cut(
            &g.device,
            &g.queue,
            &mut d,
            uncut,
            c,
            &b.triangles,
            &b.rest,
            opts,
        )?;
    }
    crate::tradeoff::gpu_frame(g, &mut d, warm)?;
    let t = Instant::now();
    touchfem_gpu::install_cut(
        &g.device,
        &g.queue,
        &mut d,
        uncut,
        &body.compliance,
        &body.triangles,
        &body.rest,
        opts,
    )?;
    crate::tradeoff::gpu_frame(g, &mut d, forces)?;
    Ok((t.elapsed().as_secs_f64() * 1e6, d))
}

/// The separating blade's rows on `name`: a 3 mm chord along the top (from `xs[1]` to
/// `xs[2]`, mm, at `at_mm`'s y), 8 mm deep, after the 3 mm chord before it (a blade moving at 3 mm a pass), on a
/// fresh cutter each time; then, with a GPU, the body put on a deformer (with room for its
/// copies) and one pass.
fn separate_rows(
    gpu: Option<&touchfem_gpu::Gpu>,
    name: &str,
    at_mm: DVec3,
    radius_mm: f64,
    xs: [f64; 3],
    reps: usize,
    rows: &mut Vec<CutRow>,
) -> Result<(), Error> {
    use touchfem_core::runtime::cutting::{CutMode, Stroke};
    let w = world(name, at_mm, radius_mm)?;
    let obj = &w.objects[0];
    let mesh = &obj.body.mesh;
    let surf = Surface::new(mesh);
    let on = |x_mm: f64| {
        let (_, p) = surf.closest_global(DVec3::new(x_mm, at_mm.y, at_mm.z + 20.0) * 1e-3);
        p
    };
    let stroke = |a: f64, b: f64| Stroke {
        object: 0,
        from: on(a),
        to: on(b),
        inward: DVec3::NEG_Z,
        depth: 8e-3,
    };
    let (first, second) = (stroke(xs[0], xs[1]), stroke(xs[1], xs[2]));
    // The pass with the region's columns of `L₀` solved up front (as the live cutter does)
    // and without (every column solved as the cut goes), alternated; and the cutter's
    // preparation each way.
    let (mut times, mut solving) = (Vec::new(), Vec::new());
    let (mut ready, mut ready_solving) = (Vec::new(), Vec::new());
    let (mut body, mut first_body): (Option<Arc<CutBody>>, Option<Arc<CutBody>>) = (None, None);
    for _ in 0..reps {
        for up_front in [true, false] {
            let t = Instant::now();
            let plan = Cutter::plan(&w)?;
            let mut cutter = if up_front {
                Cutter::from_plan(plan)?
            } else {
                Cutter::from_plan(plan.without_columns())?
            };
            let prep = t.elapsed().as_secs_f64() * 1e6;
            cutter.set_cut_mode(CutMode::Separate);
            let a = cutter.apply(&first)?;
            let t = Instant::now();
            let b = cutter.apply(&second)?;
            let us = t.elapsed().as_secs_f64() * 1e6;
            if up_front {
                times.push(us);
                ready.push(prep);
                body = b.or(body);
                first_body = a.or(first_body);
            } else {
                solving.push(us);
                ready_solving.push(prep);
            }
        }
    }
    let body = body.ok_or_else(|| Error::Study("the separating blade cut nothing".into()))?;
    let first_body = first_body
        .ok_or_else(|| Error::Study("the separating blade's first chord cut nothing".into()))?;
    let row = |method: &str, time_us: f64, rel_error: f64| CutRow {
        method: method.into(),
        mesh: name.into(),
        nodes: mesh.nodes.len(),
        tets_removed: body.tets_removed,
        rank: body.report.rank,
        time_us,
        rel_error,
    };
    let pass = median(times);
    rows.push(row("separate-pass", pass, 0.0));
    rows.push(row("separate-pass-solving", median(solving), 0.0));
    rows.push(row("separate-cutter-ready", median(ready), 0.0));
    rows.push(row(
        "separate-cutter-ready-solving",
        median(ready_solving),
        0.0,
    ));
    // The point finger's exact tick pressing 0.5 mm at the touchable node nearest the blade's
    // end, on the separated body (its correction carried: rank above, copies as columns).
    let c = &body.compliance;
    let end = on(xs[2]);
    let node = (c.cols().iter().copied())
        .min_by(|&a, &b| {
            let d = |v: u32| body.rest[v as usize].distance(end);
            d(a).total_cmp(&d(b))
        })
        .ok_or_else(|| Error::Study("no column".into()))?;
    let what = format!("the {name}'s press beside the slit");
    let tick = tick_us(&body, node, body.rest[node as usize], &what, reps < 5)?;
    rows.push(row("separate-tick-point-exact", tick, 0.0));
    let Some(g) = gpu else {
        return Ok(());
    };
    let c = &body.compliance;
    let node = *c
        .cols()
        .first()
        .ok_or_else(|| Error::Study("no column".into()))?;
    let copy = (mesh.nodes.len() as u32..body.rest.len() as u32).find(|&v| c.col_of(v).is_some());
    let mut forces = vec![(c.col_of(node).unwrap_or(0) as u32, [0.0f32, 0.0, -0.05])];
    if let Some(v) = copy {
        forces.push((c.col_of(v).unwrap_or(0) as u32, [0.0, 0.02, -0.02]));
    }
    let opts = touchfem_gpu::DeformerOptions {
        extra_vertices: 256,
        ..Default::default()
    };
    let mut times = Vec::new();
    let mut err = 0.0;
    for _ in 0..reps {
        // (On a deformer that holds the chord before's body, as a live blade's step finds it.)
        let (us, d) = install_timed(g, obj, &body, &opts, &[], &forces, Some(&first_body))?;
        times.push(us);
        // The GPU's vertices against the f64 product: rows, then the copies drawn.
        let (pos, _) = d.read_back(&g.device, &g.queue)?;
        let f64f: Vec<(u32, DVec3)> = (forces.iter())
            .map(|&(c, f)| (c, glam::Vec3::from(f).as_dvec3()))
            .collect();
        let mut u = vec![DVec3::ZERO; c.rows().len()];
        c.displace(&f64f, &mut u);
        let mut ue = vec![DVec3::ZERO; c.extra_nodes().len()];
        c.displace_extra(&f64f, &mut ue);
        let (mut num, mut den) = (0.0f64, 0.0f64);
        let no_row = |v: u32| c.row_of(v).is_none();
        let want = (c.rows().iter().zip(&u))
            .chain((c.extra_nodes().iter().zip(&ue)).filter(|p| no_row(*p.0)))
            .filter_map(|(&v, &du)| Some((d.row_of(v)?, body.rest[v as usize] + du, du)));
        for (vert, x, du) in want {
            num = num.max((glam::Vec3::from(pos[vert as usize]).as_dvec3() - x).length());
            den = den.max(du.length());
        }
        err = if den > 0.0 { num / den } else { f64::INFINITY };
    }
    times.sort_by(f64::total_cmp);
    let install = times[times.len() / 2];
    rows.push(row("separate-gpu-install-and-pass", install, err));
    rows.push(row("separate-blade-to-vertex-buffer", pass + install, err));
    Ok(())
}

/// `touchfem bench --cut`: the rows as a table (and as JSON `{"rows": [...]}` into `json`);
/// with `scene` (a mesh file in mm), only that mesh's separating rows ([`scene_rows`]).
pub fn bench(
    gpu: Option<&touchfem_gpu::Gpu>,
    quick: bool,
    json: Option<&std::path::Path>,
    scene: Option<&str>,
) -> Result<String, Error> {
    let rows = match scene {
        Some(mesh) => scene_rows(gpu, mesh, quick)?,
        None => rows(gpu, quick)?,
    };
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<32} {:<6} {:>6} {:>5} {:>5} {:>12} {:>10}",
        "method", "mesh", "nodes", "tets", "rank", "time_us", "rel_error"
    );
    for r in &rows {
        let _ = writeln!(
            out,
            "{:<32} {:<6} {:>6} {:>5} {:>5} {:>12.2} {:>10.1e}",
            r.method, r.mesh, r.nodes, r.tets_removed, r.rank, r.time_us, r.rel_error
        );
    }
    if let Some(path) = json {
        let text = serde_json::to_string_pretty(&serde_json::json!({ "rows": rows }))
            .map_err(|e| Error::Study(e.to_string()))?;
        std::fs::write(path, text).map_err(|source| Error::Write {
            path: path.to_path_buf(),
            source,
        })?;
    }
    Ok(out)
}
