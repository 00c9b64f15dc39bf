//! `touchfem bench`: speed against error, every method on the same meshes in one run.
//!
//! Visual update `u = L·F` (error relative to the f64 precomputed product, which itself matches
//! a direct sparse solve to round-off): `cpu-f64`, `cpu-f32`, `direct-sparse` (a fresh
//! factorisation-free solve with the kept Cholesky factor, per frame), and the GPU pass where the
//! caller adds it. Haptic force (error = how far the contact point misses the finger, relative to
//! the finger's displacement): `force-paper` (eq. 9–12), `force-exact`, and `force-coupled`
//! (two fingers solved together, as the runtime does). The iterative
//! alternative: `cg-TOL`, block-Jacobi conjugate gradient warm-started from the previous frame
//! ([`crate::cg`]), at tolerances 1e-2 … 1e-10.

use glam::{DVec3, Vec3};
use std::time::Instant;

use touchfem_core::compliance::precision::rel_err;
use touchfem_core::compliance::{Compliance, Selection};
use touchfem_core::contact::finger::Finger;
use touchfem_core::contact::force::{finger_force, ForceBc, ForceModel};
use touchfem_core::runtime::pacer::percentile;
use touchfem_core::scene::Body;
use touchfem_core::Mesh;

/// One row of the report.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    /// Method name.
    pub method: String,
    /// Mesh name.
    pub mesh: String,
    /// Mesh nodes.
    pub nodes: usize,
    /// Active columns (nodes with a force).
    pub active_columns: usize,
    /// Median time per call, µs.
    pub time_us: f64,
    /// Relative error (see the module doc for each method's reference).
    pub rel_error: f64,
}

/// Times `f` `reps` times and returns the median in µs.
pub(crate) fn median_us(reps: usize, mut f: impl FnMut()) -> f64 {
    let mut t = Vec::with_capacity(reps);
    for _ in 0..reps {
        let s = Instant::now();
        f();
        t.push(s.elapsed().as_secs_f64() * 1e6);
    }
    t.sort_by(|a, b| a.total_cmp(b));
    percentile(&t, 0.5)
}

/// A force boundary condition on `k` spread-out columns.
pub(crate) fn spread_forces(c: &Compliance, k: usize) -> Vec<(u32, DVec3)> {
    let n = c.cols().len();
    (0..k.min(n))
        .map(|i| {
            let col = (i * n / k.min(n).max(1)) as u32;
            let s = i as f64;
            (col, DVec3::new(0.01 * s.sin(), 0.02 * s.cos(), -0.05))
        })
        .collect()
}

/// The CPU rows for one mesh: displacement methods at each active-column count, force methods.
pub fn cpu_rows(
    name: &str,
    scene: &Body,
    active: &[usize],
    reps: usize,
) -> Result<Vec<Row>, crate::error::Error> {
    let c = &scene.compliance;
    let nodes = scene.mesh.nodes.len();
    let mut rows = Vec::new();
    let nr = c.rows().len();
    let stiff = touchfem_core::fem::Stiffness::assemble(&scene.mesh)?;
    let factor = stiff.factorize()?;
    let mut seen = Vec::new();
    for &k in active {
        let forces = spread_forces(c, k);
        let k = forces.len();
        if seen.contains(&k) {
            continue;
        }
        seen.push(k);
        let mut reference = vec![DVec3::ZERO; nr];
        let t64 = median_us(reps, || c.displace(&forces, &mut reference));
        rows.push(Row {
            method: "cpu-f64".into(),
            mesh: name.into(),
            nodes,
            active_columns: k,
            time_us: t64,
            rel_error: 0.0,
        });
        let mut u32v = vec![Vec3::ZERO; nr];
        let t32 = median_us(reps, || c.displace_f32(&forces, &mut u32v));
        let as64: Vec<DVec3> = u32v.iter().map(|v| v.as_dvec3()).collect();
        rows.push(Row {
            method: "cpu-f32".into(),
            mesh: name.into(),
            nodes,
            active_columns: k,
            time_us: t32,
            rel_error: rel_err(&as64, &reference),
        });
        // The alternative to precomputing L: a forward/back substitution per frame.
        let mut direct = vec![DVec3::ZERO; nr];
        let tds = median_us(reps.clamp(3, 50), || {
            let mut b = faer::Mat::<f64>::zeros(stiff.n(), 1);
            for &(col, f) in &forces {
                let node = c.cols()[col as usize];
                for a in 0..3 {
                    if let Some(d) = stiff.dofs.free(node, a) {
                        b[(d, 0)] += f[a];
                    }
                }
            }
            factor.solve_in_place(&mut b);
            for (r, &node) in c.rows().iter().enumerate() {
                direct[r] = DVec3::from_array(std::array::from_fn(|a| {
                    stiff.dofs.free(node, a).map(|d| b[(d, 0)]).unwrap_or(0.0)
                }));
            }
        });
        rows.push(Row {
            method: "direct-sparse".into(),
            mesh: name.into(),
            nodes,
            active_columns: k,
            time_us: tds,
            rel_error: rel_err(&direct, &reference),
        });
        // Conjugate gradients need K itself (symmetric positive definite), not a mixed system.
        if stiff.n_aux() == 0 {
            rows.extend(cg_rows(name, scene, &stiff, &forces, reps));
        }
    }
    rows.extend(force_rows(name, scene, reps)?);
    Ok(rows)
}

/// Force-step rows: time per haptic step and how far the contact point misses the finger.
fn force_rows(name: &str, scene: &Body, reps: usize) -> Result<Vec<Row>, crate::error::Error> {
    // A circle pressed 1 mm into the rest surface below it (the demo's path, frozen at full
    // depth and radius).
    let (lo, hi) = scene.mesh.bounds();
    let r = 0.2 * (hi.x - lo.x).min(hi.y - lo.y);
    let c0 = (lo + hi) * 0.5;
    let path: Vec<DVec3> = (0..256)
        .filter_map(|i| {
            let a = i as f64 / 256.0 * std::f64::consts::TAU;
            let (x, y) = (c0.x + r * a.cos(), c0.y + r * a.sin());
            let hit = scene
                .surface
                .first_entry(DVec3::new(x, y, hi.z + 0.01), DVec3::new(x, y, lo.z - 0.01))?;
            Some(hit.1 - DVec3::new(0.0, 0.0, 1e-3))
        })
        .collect();
    if path.len() < 128 {
        return Err(crate::error::Error::Study(format!(
            "{name}: no surface under the benchmark path"
        )));
    }
    let c = &scene.compliance;
    let mut out = Vec::new();
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    for model in [ForceModel::Paper, ForceModel::Exact] {
        let mut finger = Finger::new(DVec3::new(path[0].x, path[0].y, hi.z + 1e-3));
        finger.step(&scene.surface, c, path[0], model, f64::INFINITY);
        let mut i = 0;
        let t = median_us(reps.max(1000), || {
            i = (i + 1) % path.len();
            std::hint::black_box(finger.step(&scene.surface, c, path[i], model, f64::INFINITY));
        });
        // Error: the contact point's displacement against the finger's, over the path.
        let mut worst: f64 = 0.0;
        for &x in &path {
            let Some(cp) = scene.surface_contact(x) else {
                continue;
            };
            let mut bc = ForceBc::default();
            finger_force(c, &cp, model, &mut bc);
            c.displace(bc.entries(), &mut u);
            worst = worst.max(miss(c, &u, &cp));
        }
        out.push(Row {
            method: format!("force-{}", format!("{model:?}").to_lowercase()),
            mesh: name.into(),
            nodes: scene.mesh.nodes.len(),
            active_columns: 3,
            time_us: t,
            rel_error: worst,
        });
    }
    // The coupled model: two fingers on opposite sides of the circle, solved together
    // (`force::coupled_point_forces`, the runtime's fingertip compliance); error: how far each
    // contact point misses its finger.
    let half = path.len() / 2;
    let pairs: Vec<[touchfem_core::contact::ContactPoint; 2]> = (0..half)
        .filter_map(|i| {
            Some([
                scene.surface_contact(path[i])?,
                scene.surface_contact(path[i + half])?,
            ])
        })
        .collect();
    if !pairs.is_empty() {
        let skin = touchfem_core::runtime::haptic::SKIN;
        let mut g = [DVec3::ZERO; 2];
        let mut i = 0;
        let t = median_us(reps.max(1000), || {
            i = (i + 1) % pairs.len();
            std::hint::black_box(touchfem_core::contact::force::coupled_point_forces(
                c, &pairs[i], skin, &mut g,
            ));
        });
        let mut worst: f64 = 0.0;
        for pair in &pairs {
            if !touchfem_core::contact::force::coupled_point_forces(c, pair, skin, &mut g) {
                continue;
            }
            let mut bc = ForceBc::default();
            for (cp, f) in pair.iter().zip(&g) {
                touchfem_core::contact::force::add_point_force(c, cp, *f, &mut bc);
            }
            c.displace(bc.entries(), &mut u);
            for cp in pair {
                worst = worst.max(miss(c, &u, cp));
            }
        }
        out.push(Row {
            method: "force-coupled".into(),
            mesh: name.into(),
            nodes: scene.mesh.nodes.len(),
            active_columns: 6,
            time_us: t,
            rel_error: worst,
        });
    }
    Ok(out)
}

/// How far contact point `cp` moved under the rows' displacement `u` misses its finger,
/// relative to the finger's displacement.
fn miss(
    c: &touchfem_core::compliance::Compliance,
    u: &[DVec3],
    cp: &touchfem_core::contact::ContactPoint,
) -> f64 {
    let moved: DVec3 = (0..3)
        .filter_map(|k| c.row_of(cp.nodes[k]).map(|row| u[row] * cp.alpha[k]))
        .sum();
    let want = cp.displacement();
    (moved - want).length() / want.length().max(1e-300)
}

/// A ~2k-node box (12³ cells, 2197 nodes) with the paper's mouse material, for size scaling.
pub fn box_2k() -> Mesh {
    touchfem_core::mesh::cube_with(
        [12, 12, 12],
        [30.0; 3],
        touchfem_core::Material {
            young_pa: 1000.0,
            poisson: 0.3,
        },
    )
    .expect("valid box")
}

/// The meshes `touchfem bench` runs: the paper's cube and mouse, and a ~2k-node box.
pub fn bench_scenes() -> Result<Vec<(String, Body)>, crate::error::Error> {
    Ok(vec![
        (
            "cube".to_string(),
            Body::new(touchfem_core::mesh::cube(), &Selection::default())?,
        ),
        (
            "mouse".to_string(),
            Body::new(touchfem_core::mesh::mouse(), &Selection::default())?,
        ),
        (
            "box2k".to_string(),
            Body::new(box_2k(), &Selection::default())?,
        ),
    ])
}

/// Peak resident memory of this process so far, bytes (`getrusage`; 0 if unavailable).
pub fn peak_rss_bytes() -> u64 {
    // SAFETY: getrusage only writes the struct it is given.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) } != 0 {
        return 0;
    }
    u.ru_maxrss.max(0) as u64 * 1024
}

/// What [`scene_objects`] gives: rows, table rows (JSON) and the named scenes.
pub(crate) type SceneObjects = (Vec<Row>, Vec<serde_json::Value>, Vec<(String, Body)>);

/// `bench --scene`: for each object of the scene `spec`, one `precompute` row (time of the
/// in-memory precompute, `rel_error` = its residual max |K·x − e|) and the table row
/// (nodes, surface and free-surface nodes, rows × cols, precompute seconds, bytes of `L` held
/// (f64), peak RSS so far, phases); returns the objects' scenes for the other rows.
pub fn scene_objects(spec: &str) -> Result<SceneObjects, crate::error::Error> {
    let src = match touchfem_core::scene::SceneSource::find(spec)? {
        Some(s) => s,
        None => touchfem_core::scene::SceneSource::for_mesh(spec, "udp"),
    };
    let mut rows = Vec::new();
    let mut table = Vec::new();
    let mut scenes = Vec::new();
    for o in touchfem_core::scene::World::plan(&src)? {
        let t = Instant::now();
        let c = Compliance::compute(&o.mesh, &o.selection)?;
        let seconds = t.elapsed().as_secs_f64();
        rows.push(Row {
            method: "precompute".into(),
            mesh: o.name.clone(),
            nodes: o.mesh.nodes.len(),
            active_columns: c.cols().len(),
            time_us: seconds * 1e6,
            rel_error: c.stats.residual,
        });
        table.push(serde_json::json!({
            "object": o.name,
            "nodes": o.mesh.nodes.len(),
            "surface_nodes": o.mesh.surface_nodes.len(),
            "free_surface_nodes": o.mesh.free_surface_nodes().len(),
            "rows": c.rows().len(),
            "cols": c.cols().len(),
            "precompute_s": seconds,
            "bytes_l": c.stats.bytes,
            "peak_rss_bytes": peak_rss_bytes(),
            "phases": c.stats.phases,
        }));
        scenes.push((o.name.clone(), Body::with_compliance(o.mesh, c)));
    }
    Ok((rows, table, scenes))
}

/// The GPU pass's rows for one mesh, for each layout of `L` (`gpu-f32-texture`,
/// `gpu-f32-buffers`, `gpu-f16-buffers`, `gpu-f16-texture`): `set_forces` + `encode` + submit +
/// wait, and the error of the read-back positions against the f64 CPU product, relative to
/// max |u|.
pub fn gpu_rows(
    name: &str,
    scene: &Body,
    gpu: &touchfem_gpu::Gpu,
    active: &[usize],
    reps: usize,
) -> Result<Vec<Row>, crate::error::Error> {
    use touchfem_gpu::LStorage;
    let mut rows = Vec::new();
    for (method, storage) in [
        ("gpu-f32-texture", LStorage::Texture),
        ("gpu-f32-buffers", LStorage::Buffers),
        ("gpu-f16-buffers", LStorage::BuffersF16),
        ("gpu-f16-texture", LStorage::TextureF16),
    ] {
        let c = &scene.compliance;
        let mut d = touchfem_gpu::Deformer::new(
            &gpu.device,
            &gpu.queue,
            c,
            &scene.mesh.nodes,
            &scene.mesh.surface,
            &touchfem_gpu::DeformerOptions {
                storage,
                ..Default::default()
            },
        )?;
        let mut seen = Vec::new();
        for &k in active {
            let forces = spread_forces(c, k);
            if seen.contains(&forces.len()) {
                continue;
            }
            seen.push(forces.len());
            let f32s: Vec<(u32, [f32; 3])> = forces
                .iter()
                .map(|&(col, f)| (col, f.as_vec3().to_array()))
                .collect();
            let mut failed = None;
            // Frames for about 0.3 s (at least 5, at most 2000, fewer with --quick), after a few
            // warm-up frames: each frame is timed on its own, so the median is a typical frame's.
            let mut frame_us = 0.0;
            let mut reps = reps;
            for warm in 0..3 {
                let s = Instant::now();
                gpu_frame(gpu, &mut d, &f32s)?;
                if warm == 2 {
                    frame_us = s.elapsed().as_secs_f64() * 1e6;
                }
            }
            if reps >= 200 {
                reps = ((0.3e6 / frame_us.max(1.0)) as usize).clamp(5, 2000);
            }
            let t = median_us(reps.clamp(5, 2000), || {
                if let Err(e) = gpu_frame(gpu, &mut d, &f32s) {
                    failed = Some(e);
                }
            });
            if let Some(e) = failed {
                return Err(e);
            }
            let (pos, _) = d.read_back(&gpu.device, &gpu.queue)?;
            let mut reference = vec![DVec3::ZERO; c.rows().len()];
            c.displace(&forces, &mut reference);
            let got: Vec<DVec3> = pos
                .iter()
                .zip(c.rows())
                .map(|(p, &node)| glam::Vec3::from(*p).as_dvec3() - scene.mesh.nodes[node as usize])
                .collect();
            rows.push(Row {
                method: method.into(),
                mesh: name.into(),
                nodes: scene.mesh.nodes.len(),
                active_columns: forces.len(),
                time_us: t,
                rel_error: rel_err(&got, &reference),
            });
        }
    }
    Ok(rows)
}

/// The frame size [`frame_ms`] draws at.
pub const FRAME_SIZE: [u32; 2] = [640, 480];

/// One live frame of `scene` on `gpu`, in ms (median of `reps`): one contact triangle pressed
/// (the first surface triangle whose three nodes are touchable, 0.1 N each), its deformation
/// pass and the draw at [`FRAME_SIZE`], coloured by |u|, the wireframe as a live view would
/// draw it by default ([`touchfem_gpu::render::wireframe_by_default`]), the adapter's live sample
/// count; submit and wait, no read-back, no present. `None` when no triangle is touchable.
pub fn frame_ms(
    scene: &Body,
    gpu: &touchfem_gpu::Gpu,
    reps: usize,
) -> Result<Option<f64>, crate::error::Error> {
    use touchfem_gpu::render::{
        Camera, Coloring, Edges, Frame, FrameObject, RenderOptions, Renderer,
    };
    let c = &scene.compliance;
    let Some(tri) = scene
        .mesh
        .surface
        .iter()
        .find(|t| t.iter().all(|&v| c.col_of(v).is_some()))
    else {
        return Ok(None);
    };
    let forces: Vec<(u32, [f32; 3])> = tri
        .iter()
        .filter_map(|&v| c.col_of(v))
        .map(|col| (col as u32, [0.0, 0.0, -0.1]))
        .collect();
    let mut d = touchfem_gpu::Deformer::new(
        &gpu.device,
        &gpu.queue,
        c,
        &scene.mesh.nodes,
        &scene.mesh.surface,
        &Default::default(),
    )?;
    d.set_forces(&gpu.queue, &forces)?;
    let options = RenderOptions {
        samples: touchfem_gpu::render::live_samples(&gpu.adapter.get_info()),
        ..Default::default()
    };
    let r = Renderer::with_options(&gpu.device, FRAME_SIZE, options)?;
    let [w, h] = FRAME_SIZE;
    let target = touchfem_gpu::render::frame_texture(
        &gpu.device,
        "touchfem bench frame",
        FRAME_SIZE,
        options.format,
        wgpu::TextureUsages::RENDER_ATTACHMENT,
    );
    let view = target.create_view(&Default::default());
    let wireframe =
        touchfem_gpu::render::wireframe_by_default(scene.mesh.surface.len(), FRAME_SIZE);
    let edges = wireframe.then(|| Edges::new(&gpu.device, &d));
    let bounds = scene.mesh.bounds();
    let scale = (bounds.1 - bounds.0).length();
    let objects = [FrameObject {
        deformer: &d,
        offset: DVec3::ZERO,
        bounds,
        edges: edges.as_ref(),
        deformed: false,
    }];
    let frame = Frame {
        objects: &objects,
        camera: Camera::framing(bounds.0, bounds.1, f64::from(w) / f64::from(h)),
        fingers: &[],
        finger_radii: &[],
        patch: &[],
        proxies: &[],
        scale,
        wireframe,
        overlay: None,
        coloring: Coloring::displacement(0.1 * scale),
        arrows: &[],
        legend: None,
    };
    let mut failed = None;
    let draw = || -> Result<(), crate::error::Error> {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        r.draw(&gpu.device, &gpu.queue, &mut enc, &view, &frame)?;
        gpu.queue.submit([enc.finish()]);
        gpu.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(crate::error::Error::from)
    };
    for _ in 0..3 {
        draw()?;
    }
    let t = median_us(reps.clamp(5, 200), || {
        if let Err(e) = draw() {
            failed = Some(e);
        }
    });
    match failed {
        Some(e) => Err(e),
        None => Ok(Some(t / 1e3)),
    }
}

/// One GPU frame: upload the forces, record, submit, wait for completion.
pub(crate) fn gpu_frame(
    gpu: &touchfem_gpu::Gpu,
    d: &mut touchfem_gpu::Deformer,
    forces: &[(u32, [f32; 3])],
) -> Result<(), crate::error::Error> {
    d.set_forces(&gpu.queue, forces)?;
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    d.encode(&mut enc);
    gpu.queue.submit([enc.finish()]);
    gpu.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map(|_| ())
        .map_err(crate::error::Error::from)
}

/// Conjugate-gradient rows: a finger pressing a little deeper each frame (the forces grow by
/// 0.5 % a frame), each frame solved by block-Jacobi CG warm-started from the last, at
/// tolerances 1e-2 … 1e-10. Time: median per frame; error: the last frame against its
/// precomputed f64 product.
fn cg_rows(
    name: &str,
    scene: &Body,
    stiff: &touchfem_core::fem::Stiffness,
    forces: &[(u32, DVec3)],
    reps: usize,
) -> Vec<Row> {
    let c = &scene.compliance;
    let nr = c.rows().len();
    let frames = reps.clamp(5, 40);
    let mut out = Vec::new();
    for tol in [1e-2, 1e-4, 1e-6, 1e-8, 1e-10] {
        let mut cg = crate::cg::CgSolver::new(stiff);
        let mut b = vec![0.0; stiff.dofs.n_free];
        let mut u = vec![DVec3::ZERO; nr];
        let mut times = Vec::with_capacity(frames);
        let mut last = Vec::new();
        for frame in 0..frames {
            let s = 1.0 + 0.005 * frame as f64;
            last = forces
                .iter()
                .map(|&(col, f)| (col, f * s))
                .collect::<Vec<_>>();
            let t = std::time::Instant::now();
            b.fill(0.0);
            for &(col, f) in &last {
                let node = c.cols()[col as usize];
                for a in 0..3 {
                    if let Some(d) = stiff.dofs.free(node, a) {
                        b[d] += f[a];
                    }
                }
            }
            cg.solve(&b, tol, 20_000);
            let x = cg.solution();
            for (r, &node) in c.rows().iter().enumerate() {
                u[r] = DVec3::from_array(std::array::from_fn(|a| {
                    stiff.dofs.free(node, a).map(|d| x[d]).unwrap_or(0.0)
                }));
            }
            times.push(t.elapsed().as_secs_f64() * 1e6);
        }
        let mut reference = vec![DVec3::ZERO; nr];
        c.displace(&last, &mut reference);
        times.sort_by(|a, b| a.total_cmp(b));
        out.push(Row {
            method: format!("cg-{tol:e}"),
            mesh: name.into(),
            nodes: scene.mesh.nodes.len(),
            active_columns: forces.len(),
            time_us: times[times.len() / 2],
            rel_error: rel_err(&u, &reference),
        });
    }
    out
}

/// Writes `v` as pretty JSON to `path`.
pub fn write_json(
    path: &std::path::Path,
    v: &serde_json::Value,
) -> Result<(), crate::error::Error> {
    std::fs::write(path, serde_json::to_string_pretty(v).expect("serialisable")).map_err(|source| {
        crate::error::Error::Write {
            path: path.to_path_buf(),
            source,
        }
    })
}

/// Whether a row times a visual update (`u = L·F` or its alternatives), not a force step or
/// a precompute.
pub(crate) fn is_visual(r: &Row) -> bool {
    !r.method.starts_with("force-") && r.method != "precompute"
}

/// The fastest visual-update row of `mesh` at the active-column count nearest `active` whose
/// error is at most `max_error`.
pub fn fastest<'a>(rows: &'a [Row], mesh: &str, active: usize, max_error: f64) -> Option<&'a Row> {
    let here = || rows.iter().filter(|r| r.mesh == mesh && is_visual(r));
    let k = here()
        .map(|r| r.active_columns)
        .min_by_key(|&k| k.abs_diff(active))?;
    here()
        .filter(|r| r.active_columns == k && r.rel_error <= max_error)
        .min_by(|a, b| a.time_us.total_cmp(&b.time_us))
}
