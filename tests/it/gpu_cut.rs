//! A cut on the GPU: the deformer carries the cut's correction (`Deformer::set_correction`)
//! and draws the opened surface (`Deformer::set_triangles`); the visual path follows the
//! cutter's feed (`Visual::follow_cuts`). Needs a GPU adapter (lavapipe:
//! `WGPU_BACKEND=vulkan`), and fails without one.
//!
//! Tolerances as `tests/it/gpu.rs`: positions `|x_gpu − (x_rest + u_cpu)| ≤ 1e-5·max|u_cpu| +
//! 4·ulp_f32(max|x_rest|)` against `Compliance::displace` of the compliance that carries the
//! correction (f64); normals `≤ 1e-4` against the area-weighted normals of the f64 surface.

use std::sync::{Arc, OnceLock};

use crate::common::cpu_normals;
use glam::DVec3;
use touchfem::compliance::{Compliance, Selection};
use touchfem::cut::{tets_near, Cut};
use touchfem::gpu::{Deformer, DeformerOptions, Gpu, GpuError, LStorage};
use touchfem::runtime::cutting::{CutBody, CutFeed};
use touchfem::runtime::WorldSample;
use touchfem::scene::World;
use touchfem::Mesh;

/// The layouts of `L` the correction is checked in (the half-float ones carry it in f32 too;
/// their own error is `tests/it/gpu_f16.rs`'s).
const LAYOUTS: [LStorage; 2] = [LStorage::Buffers, LStorage::Texture];

pub(crate) fn gpu() -> &'static Gpu {
    static GPU: OnceLock<Gpu> = OnceLock::new();
    GPU.get_or_init(|| {
        Gpu::new_headless()
            .unwrap_or_else(|e| panic!("GPU tests need an adapter and must not be skipped: {e}"))
    })
}

fn deformer(c: &Compliance, mesh: &Mesh, storage: LStorage) -> Deformer {
    let g = gpu();
    let opts = DeformerOptions {
        storage,
        ..Default::default()
    };
    Deformer::new(&g.device, &g.queue, c, &mesh.nodes, &mesh.surface, &opts).expect("deformer")
}

pub(crate) fn run(d: &Deformer) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let g = gpu();
    let mut enc = g.device.create_command_encoder(&Default::default());
    d.encode(&mut enc);
    g.queue.submit([enc.finish()]);
    let (p, n) = d.read_back(&g.device, &g.queue).expect("readback");
    (p, n.expect("normals"))
}

/// Median time of one frame of `d` (its forces set, encode, submit, wait), µs.
fn frame_us(d: &mut Deformer, forces: &[(u32, [f32; 3])]) -> f64 {
    let g = gpu();
    let mut t: Vec<f64> = (0..30)
        .map(|_| {
            let t0 = std::time::Instant::now();
            d.set_forces(&g.queue, forces).unwrap();
            let mut enc = g.device.create_command_encoder(&Default::default());
            d.encode(&mut enc);
            let idx = g.queue.submit([enc.finish()]);
            g.device
                .poll(touchfem::wgpu::PollType::Wait {
                    submission_index: Some(idx),
                    timeout: None,
                })
                .unwrap();
            t0.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

pub(crate) fn to_f64(v: [f32; 3]) -> DVec3 {
    DVec3::from(v.map(f64::from))
}

/// Compares the GPU's positions with `rest + c.displace(forces)` (f64, with `c`'s correction),
/// row by row (every row: the pass holds pinned rows at rest, as `displace` does); returns
/// the worst error over the tolerance and the CPU positions.
fn check_positions(
    c: &Compliance,
    rest: &[DVec3],
    forces: &[(u32, [f32; 3])],
    pos: &[[f32; 3]],
) -> (f64, Vec<DVec3>) {
    let f64_forces: Vec<(u32, DVec3)> = forces.iter().map(|&(c, f)| (c, to_f64(f))).collect();
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    c.displace(&f64_forces, &mut u);
    let x: Vec<DVec3> = c
        .rows()
        .iter()
        .zip(&u)
        .map(|(&node, u)| rest[node as usize] + *u)
        .collect();
    let (tol, umax) = crate::common::gpu_tolerance(&u, rest);
    let mut worst = 0.0f64;
    for (i, (g, want)) in pos.iter().zip(&x).enumerate() {
        let err = (to_f64(*g) - *want).abs().max_element();
        worst = worst.max(err / tol);
        assert!(
            err <= tol,
            "row {i}: gpu {g:?} vs cpu {want:?}: error {err:e} > tol {tol:e} (max|u| {umax:e})"
        );
    }
    assert!(umax > 0.0);
    (worst, x)
}

/// Forces on a few live columns near `at` (m): a push down and a shear.
fn forces_near(c: &Compliance, mesh: &Mesh, at: DVec3) -> Vec<(u32, [f32; 3])> {
    let mut cols: Vec<(f64, usize)> = (0..c.cols().len())
        .filter(|&k| c.col_of(c.cols()[k]) == Some(k))
        .map(|k| (mesh.nodes[c.cols()[k] as usize].distance(at), k))
        .collect();
    cols.sort_by(|a, b| a.0.total_cmp(&b.0));
    cols.iter()
        .take(5)
        .enumerate()
        .map(|(i, &(_, k))| {
            let f = if i % 2 == 0 {
                [0.0, 0.0, -0.05]
            } else {
                [0.02, -0.01, -0.03]
            };
            (k as u32, f)
        })
        .collect()
}

/// Cuts `mesh` at `at` in two steps (`first` tets, then `more`), and checks each step's GPU
/// pass (both layouts, one deformer through both steps: the rank grows) against `displace`.
fn correction_matches_displace(mesh: &Mesh, at: DVec3, first: &[usize], more: &[usize]) {
    let g = gpu();
    let base = Compliance::compute(mesh, &Selection::default()).unwrap();
    let forces = forces_near(&base, mesh, at + DVec3::new(0.004, 0.004, 0.0));
    for storage in LAYOUTS {
        let mut d = deformer(&base, mesh, storage);
        d.set_forces(&g.queue, &forces).unwrap();
        let (uncut, _) = run(&d);
        let mut cut = Cut::new(mesh).unwrap();
        let mut ranks = Vec::new();
        for step in [first, more] {
            let rep = cut.remove(mesh, step).unwrap();
            let carried = base
                .with_correction(Arc::new(cut.correction(&base).unwrap()))
                .unwrap();
            let k = carried.correction().unwrap();
            d.set_correction(&g.device, &g.queue, Some(k)).unwrap();
            assert_eq!(d.stats().correction_rank, k.rank);
            ranks.push(k.rank);
            // The weights follow the forces set before the correction; set them again anyway.
            d.set_forces(&g.queue, &forces).unwrap();
            let (pos, _) = run(&d);
            let (worst, _) = check_positions(&carried, &mesh.nodes, &forces, &pos);
            // The cut shows: some row moved by more than the tolerance's scale.
            let moved = pos
                .iter()
                .zip(&uncut)
                .map(|(a, b)| (to_f64(*a) - to_f64(*b)).length())
                .fold(0.0, f64::max);
            for (r, &dead) in k.dead_rows.iter().enumerate() {
                if dead {
                    let node = carried.rows()[r] as usize;
                    assert_eq!(to_f64(pos[r]), mesh.nodes[node].as_vec3().as_dvec3());
                }
            }
            eprintln!(
                "{storage:?}: rank {} ({} pinned), worst error {worst:.3} of the tolerance, \
                 the cut moves a vertex by {moved:.2e} m",
                k.rank, rep.nodes_pinned
            );
            assert!(moved > 1e-7, "{moved}");
        }
        assert!(ranks[1] > ranks[0], "{ranks:?}");
        // Without the correction, the uncut pass again.
        d.set_correction(&g.device, &g.queue, None).unwrap();
        assert_eq!(d.stats().correction_rank, 0);
        let (pos, _) = run(&d);
        assert_eq!(pos, uncut);
    }
}

#[test]
fn the_gpu_pass_with_a_cut_cube_equals_displace() {
    let mesh = touchfem::mesh::cube();
    let at = DVec3::new(0.015, 0.015, 0.026);
    let near = tets_near(&mesh, at, 25);
    // Then every tet around a top node: it is pinned (no tet left), its row held at rest.
    let v = (0..mesh.nodes.len())
        .find(|&v| {
            let p = mesh.nodes[v];
            p.z > 0.029 && (p.x - 0.007).abs() < 0.004 && (p.y - 0.007).abs() < 0.004
        })
        .unwrap() as u32;
    let around: Vec<usize> = (0..mesh.tets.len())
        .filter(|&t| mesh.tets[t].contains(&v) && !near[..3].contains(&t))
        .collect();
    let mut more = near[3..].to_vec();
    more.extend(around.iter().filter(|t| !near.contains(t)));
    correction_matches_displace(&mesh, at, &near[..3], &more);
}

#[test]
fn the_gpu_pass_with_a_cut_mouse_equals_displace() {
    let mesh = touchfem::mesh::mouse();
    let at = DVec3::new(-0.01, 0.0, 0.04);
    let near = tets_near(&mesh, at, 12);
    correction_matches_displace(&mesh, at, &near[..2], &near[2..]);
}

#[test]
fn a_correction_that_does_not_fit_is_refused_and_changes_nothing() {
    let g = gpu();
    let mesh = touchfem::mesh::cube();
    let base = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let mut d = deformer(&base, &mesh, LStorage::Buffers);
    let bad = touchfem::compliance::correction::Correction {
        rank: 1,
        ..Default::default()
    };
    match d.set_correction(&g.device, &g.queue, Some(&bad)) {
        Err(GpuError::BadInput(m)) => assert!(m.contains("rank 1"), "{m}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(d.stats().correction_rank, 0);
    // Triangles on a node that is not a displayed row: refused, the surface kept.
    let interior = (0..mesh.nodes.len() as u32)
        .find(|&v| base.row_of(v).is_none())
        .expect("an interior node");
    let n = d.index_count();
    let e = d
        .set_triangles(&g.device, &g.queue, &[[0, 1, interior]])
        .unwrap_err();
    assert!(matches!(e, GpuError::BadInput(_)), "{e}");
    assert_eq!(d.index_count(), n);
    assert_eq!(d.surface_generation(), 0);
}

/// The bundled `incision` scene run through the haptic path with the cutter applied in step
/// (a pass every 20 ms): the world, the sample at t = 6 s (the fingertip pressing beside the
/// open cut), the final cut body and the tets it removed.
use crate::common::IncisionRun as Incision;

/// The incision, its correction carried whole (not folded), with a blade that separates the
/// material (`common::separated_incision`).
fn incision() -> &'static Incision {
    crate::common::separated_incision()
}

/// [`incision`] with a blade that removes the tets it sweeps (rank 357).
fn incision_removing() -> &'static Incision {
    crate::common::removing_incision()
}

#[test]
fn the_opened_incision_is_drawn_with_outward_normals() {
    // (A blade that removes: its faces are the remaining tets'. A separating blade's copies
    // are drawn in `gpu_split.rs`.)
    let g = gpu();
    let inc = incision_removing();
    let obj = &inc.world.objects[0];
    let (mesh, base) = (&obj.body.mesh, &obj.body.compliance);
    let body = &inc.body;
    assert!(body.compliance.shares_l(base));
    let forces: Vec<(u32, [f32; 3])> = {
        let (f, n) = inc.sample.bc(0).to_f32();
        f[..n].to_vec()
    };
    assert!(!forces.is_empty(), "the fingertip presses at t = 6 s");
    let uncut: std::collections::BTreeSet<[u32; 3]> = mesh
        .surface
        .iter()
        .map(|t| {
            let mut k = *t;
            k.sort_unstable();
            k
        })
        .collect();
    for storage in LAYOUTS {
        let mut d = deformer(base, mesh, storage);
        let uncut_us = frame_us(&mut d, &forces);
        let before = d.index_count();
        // Every node of the opened surface is a displayed row (the cuttable region's are).
        d.set_triangles(&g.device, &g.queue, &body.triangles)
            .expect("the opened surface's nodes are rows");
        assert_eq!(d.index_count() as usize, 3 * body.triangles.len());
        assert_ne!(d.index_count(), before);
        assert_eq!(d.surface_generation(), 1);
        d.set_correction(&g.device, &g.queue, body.compliance.correction())
            .unwrap();
        d.set_forces(&g.queue, &forces).unwrap();
        let cut_us = frame_us(&mut d, &forces);
        let (pos, nrm) = run(&d);
        let (worst, x) = check_positions(&body.compliance, &mesh.nodes, &forces, &pos);
        // The normals are those of the opened surface, deformed.
        let want = cpu_normals(&x, d.triangles());
        for (i, (g, w)) in nrm.iter().zip(&want).enumerate() {
            let err = (to_f64(*g) - *w).length();
            assert!(err <= 1e-4, "normal {i}: gpu {g:?} vs cpu {w:?} ({err:e})");
        }
        // Each new face points out of the tet it bounds (away from its fourth node), and so
        // do the GPU's normals at its corners.
        let (mut new_faces, mut shaded_out) = (0, 0);
        for (t, tri) in body.triangles.iter().enumerate() {
            let mut key = *tri;
            key.sort_unstable();
            if uncut.contains(&key) {
                continue;
            }
            new_faces += 1;
            let tet = (0..mesh.tets.len())
                .find(|&k| !inc.removed[k] && tri.iter().all(|v| mesh.tets[k].contains(v)))
                .expect("a face of a remaining tet");
            let fourth = *mesh.tets[tet].iter().find(|v| !tri.contains(v)).unwrap();
            let rows = d.triangles()[t];
            let [a, b, c] = rows.map(|r| to_f64(pos[r as usize]));
            let n = (b - a).cross(c - a);
            let inward = mesh.nodes[fourth as usize] - (a + b + c) / 3.0;
            assert!(n.dot(inward) < 0.0, "face {tri:?} points into its tet");
            // The shading normals at its corners average its neighbours' (at the slit's
            // edges, the other wall's too): most lean out with it.
            let corners: DVec3 = rows.iter().map(|&r| to_f64(nrm[r as usize])).sum();
            if corners.dot(n) > 0.0 {
                shaded_out += 1;
            }
        }
        eprintln!(
            "{storage:?}: {} triangles ({new_faces} new, {shaded_out} of them shaded outward) \
             against {}, rank {}, worst position error {worst:.3} of the tolerance; a frame \
             {uncut_us:.0} µs uncut, {cut_us:.0} µs with the correction ({} forces)",
            body.triangles.len(),
            before / 3,
            d.stats().correction_rank,
            forces.len()
        );
        assert!(new_faces > 10, "{new_faces}");
        assert!(
            10 * shaded_out >= 9 * new_faces,
            "{shaded_out} of {new_faces}"
        );
    }
}

/// The incision's frame at t = 6 s through the visual path: uncut, or following a feed that
/// holds the cut body. Returns the image and the camera.
fn incision_frame(cut: bool) -> (image::RgbaImage, touchfem::render::Camera) {
    incision_frame_of(incision_removing(), cut)
}

/// [`incision_frame`] of `inc`.
fn incision_frame_of(inc: &Incision, cut: bool) -> (image::RgbaImage, touchfem::render::Camera) {
    use touchfem::render::{Camera, Coloring, Edges, Frame, FrameObject, Renderer};
    use touchfem_app::visual::{frame_objects, SampleMarks, Visual};
    let g = gpu();
    let w = &inc.world;
    let mut visual = Visual::new(w, Some(g));
    if cut {
        let feed = Arc::new(CutFeed::default());
        feed.publish(0, inc.body.clone());
        visual.follow_cuts(feed);
    }
    visual.update(&inc.sample);
    assert_eq!(visual.backend(), "gpu", "{:?}", visual.failure());
    assert_eq!(visual.cut_body(0).is_some(), cut);
    assert_eq!(visual.surface_generation(), u64::from(cut));
    let ds = visual.deformers().unwrap();
    if cut {
        assert_eq!(ds[0].index_count() as usize, 3 * inc.body.triangles.len());
        assert_eq!(ds[0].stats().correction_rank, inc.body.report.rank);
    }
    let edges: Vec<Edges> = ds.iter().map(|d| Edges::new(&g.device, d)).collect();
    let objects: Vec<FrameObject<'_>> = frame_objects(w, ds, &edges);
    let size = [480, 360];
    // Framed on the top face around the cut and the press, seen from above and in front.
    let centre = DVec3::new(-0.015, 0.0, 0.02);
    let pts: Vec<DVec3> = w.objects[0]
        .body
        .mesh
        .surface
        .iter()
        .flatten()
        .map(|&i| w.objects[0].body.mesh.nodes[i as usize] + w.objects[0].offset)
        .filter(|p| p.distance(centre) < 0.018)
        .collect();
    let camera = Camera::fit(
        &pts,
        DVec3::new(-0.35, -0.8, 1.0),
        f64::from(size[0]) / f64::from(size[1]),
        touchfem::render::region_beside_legend(size, None),
    );
    let marks = SampleMarks::of(&inc.sample, 0.01).with_tools(w);
    let (lo, hi) = w.bounds();
    let n = marks.n;
    let frame = Frame {
        objects: &objects,
        camera,
        fingers: &marks.fingers[..n],
        finger_radii: &marks.radii[..n],
        patch: &[],
        proxies: &marks.proxies[..n],
        scale: (hi - lo).length(),
        wireframe: true,
        overlay: None,
        coloring: Coloring::displacement(2e-3),
        arrows: &marks.arrows[..n],
        legend: None,
    };
    let renderer = Renderer::new(&g.device, size).unwrap();
    let img = renderer
        .render_to_image(&g.device, &g.queue, &frame)
        .unwrap();
    (img, camera)
}

/// `golden/incision_open.png`: the incision after its cut, the fingertip pressing beside it;
/// the cut's line differs from the uncut frame's.
#[test]
fn golden_incision_open() {
    let (open, camera) = incision_frame(true);
    let (uncut, _) = incision_frame(false);
    crate::golden::check_golden("incision_open", &open);
    let in_cut = line_differs(&open, &uncut, &camera);
    assert!(in_cut.0 > 0.3, "{in_cut:?}");
}

/// `golden/incision_separated.png`: the incision after a blade that separates the material
/// (`CutMode::Separate`), through the visual path (the copies drawn as the deformer's extra
/// vertices), the fingertip pressing beside it. The closed slit is drawn as a line: the edges
/// where the cut's faces meet the top face, on the blade's path and nowhere else.
#[test]
fn golden_incision_separated() {
    let inc = incision();
    // The slit's edges (both lips'), at rest: on the blade's plane y = 0; those on the top
    // face along the blade's path (x from −25 to −5 mm, within an edge of its ends). (The
    // others are inside the closed slit, where a sliver dropped opened a pocket: hidden.)
    let slit = touchfem::mesh::slit_edges(&inc.body.triangles, &inc.body.rest);
    let ends: Vec<DVec3> = (slit.iter().flatten())
        .map(|&v| inc.body.rest[v as usize])
        .collect();
    let on_top = ends.iter().filter(|p| (p.z - 0.02).abs() < 1e-9).count();
    let off_plane = ends.iter().map(|p| p.y.abs()).fold(0.0, f64::max);
    let top = ends.iter().filter(|p| (p.z - 0.02).abs() < 1e-9);
    let (x_lo, x_hi) = (top.map(|p| p.x)).fold((f64::INFINITY, f64::NEG_INFINITY), |a, x| {
        (a.0.min(x), a.1.max(x))
    });
    eprintln!(
        "the slit: {} edges, {on_top} of their {} ends on the top face (x {:.1}..{:.1} mm), \
         at most {off_plane:.1e} m off the blade's plane",
        slit.len(),
        ends.len(),
        1e3 * x_lo,
        1e3 * x_hi
    );
    // The line on the top face runs unbroken from one end to the other (it had a gap of an
    // edge, x = −17.6 to −15.5 mm, beside a dropped sliver's pocket).
    let mut spans: Vec<(f64, f64)> = (slit.iter())
        .map(|e| e.map(|v| inc.body.rest[v as usize]))
        .filter(|[a, b]| (a.z - 0.02).abs() < 1e-9 && (b.z - 0.02).abs() < 1e-9)
        .map(|[a, b]| (a.x.min(b.x), a.x.max(b.x)))
        .collect();
    spans.sort_by(|a, b| a.0.total_cmp(&b.0));
    let gaps: Vec<(f64, f64)> = (spans.iter())
        .scan(f64::NEG_INFINITY, |reach, &(lo, hi)| {
            let gap = (*reach > f64::NEG_INFINITY && lo > *reach + 1e-9).then_some((*reach, lo));
            *reach = reach.max(hi);
            Some(gap)
        })
        .flatten()
        .collect();
    assert!(gaps.is_empty(), "the slit's line breaks at (m) {gaps:?}");
    assert!(slit.len() >= 8, "{}", slit.len());
    assert!(off_plane < 1e-9, "{off_plane}");
    assert!(on_top >= 24, "{on_top} of {}", ends.len());
    assert!(
        x_lo > -0.029 && x_hi < -0.001 && x_hi - x_lo > 0.012,
        "{x_lo} {x_hi}"
    );
    let (open, camera) = incision_frame_of(inc, true);
    let (uncut, _) = incision_frame_of(inc, false);
    crate::golden::check_golden("incision_separated", &open);
    // The line shows where the cut's faces meet the surface; away from it the frame is the
    // uncut one (the lips part only where pressed).
    let (in_cut, elsewhere) = line_differs(&open, &uncut, &camera);
    assert!(
        in_cut > 0.12 && in_cut > 10.0 * elsewhere,
        "{in_cut} {elsewhere}"
    );
}

/// The fractions of the pixels within 4 px of the blade's line (scene frame: x from −25 to −5
/// mm at y = 0, z = 20 mm, projected by `camera`) and beyond 40 px of it where `open` differs
/// from `uncut`.
fn line_differs(
    open: &image::RgbaImage,
    uncut: &image::RgbaImage,
    camera: &touchfem::render::Camera,
) -> (f64, f64) {
    // The cut's line on the top face (the blade's path, scene frame: x from −25 to −5 mm at
    // y = 0, z = 20 mm), projected: the pixels within 4 px of it differ from the uncut frame.
    let size = [open.width(), open.height()];
    let a = camera.project(DVec3::new(-0.025, 0.0, 0.02), size).unwrap();
    let b = camera.project(DVec3::new(-0.005, 0.0, 0.02), size).unwrap();
    let (ab, len2) = (
        [b[0] - a[0], b[1] - a[1]],
        (b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2),
    );
    let (mut near, mut differ, mut far, mut far_differ) = (0usize, 0usize, 0usize, 0usize);
    for (x, y, p) in open.enumerate_pixels() {
        let q = [f64::from(x) + 0.5 - a[0], f64::from(y) + 0.5 - a[1]];
        let t = ((q[0] * ab[0] + q[1] * ab[1]) / len2).clamp(0.0, 1.0);
        let d = ((q[0] - t * ab[0]).powi(2) + (q[1] - t * ab[1]).powi(2)).sqrt();
        let u = uncut.get_pixel(x, y);
        let differs = (0..3).any(|c| p[c].abs_diff(u[c]) > 24);
        if d <= 4.0 {
            near += 1;
            differ += usize::from(differs);
        } else if d > 40.0 {
            far += 1;
            far_differ += usize::from(differs);
        }
    }
    let in_cut = differ as f64 / near.max(1) as f64;
    let elsewhere = far_differ as f64 / far.max(1) as f64;
    eprintln!(
        "the cut's line {a:?}..{b:?}: {differ} of the {near} pixels within 4 px differ from \
         the uncut frame, {far_differ} of the {far} beyond 40 px"
    );
    assert!(near > 200, "{near}");
    (in_cut, elsewhere)
}

/// A cuttable cube of Young's modulus `young` (Pa) and a point finger.
fn cube_world(young: f64) -> World {
    crate::common::world_from_text(&format!(
        "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\nyoung = {young}\ncuttable = \"all\"\n\
         [[finger]]\ndevice = \"pointer\"\n"
    ))
    .expect("cube scene")
}

/// The visual path follows a feed, on the GPU and on the CPU, and uploads `L` again for a
/// body whose `L` is not the one on the GPU (here: another material's, same rows and columns,
/// as a cut folded into `L` would be).
#[test]
fn the_visual_path_follows_a_feed_and_uploads_a_new_l() {
    use touchfem_app::visual::Visual;
    let g = gpu();
    let w = cube_world(5.0e4);
    let other = cube_world(1.0e5);
    let (mesh, base) = (&w.objects[0].body.mesh, &other.objects[0].body.compliance);
    assert_eq!(base.rows(), w.objects[0].body.compliance.rows());
    assert!(!base.shares_l(&w.objects[0].body.compliance));
    let at = DVec3::new(0.015, 0.015, 0.026);
    let removed_tets = tets_near(mesh, at, 8);
    let mut cut = Cut::new(&other.objects[0].body.mesh).unwrap();
    let rep = cut.remove(mesh, &removed_tets).unwrap();
    let compliance = base
        .with_correction(Arc::new(cut.correction(base).unwrap()))
        .unwrap();
    let mut open = mesh.clone();
    open.surface = mesh.open_surface(cut.removed());
    let body = Arc::new(CutBody {
        compliance,
        surface: touchfem::contact::Surface::new(&open),
        triangles: open.surface.clone(),
        rest: Arc::new(open.nodes.clone()),
        report: rep,
        tets_removed: removed_tets.len(),
        pieces_removed: 0,
        nodes_split: 0,
        generation: 1,
        strokes: Vec::new(),
        folds: 0,
        fold_adopted: false,
    });
    let mut sample = WorldSample {
        n_objects: 1,
        ..Default::default()
    };
    let forces = forces_near(&body.compliance, mesh, DVec3::new(0.02, 0.02, 0.03));
    for &(c, f) in &forces {
        sample.bcs[0].add(c, to_f64(f));
    }
    let feed = Arc::new(CutFeed::default());
    feed.publish(0, body.clone());
    // On the GPU: the new L, its correction and the opened surface.
    let mut visual = Visual::new(&w, Some(g));
    visual.update(&sample);
    let before = visual.deformers().unwrap()[0]
        .read_back(&g.device, &g.queue)
        .unwrap()
        .0;
    visual.follow_cuts(feed.clone());
    visual.update(&sample);
    assert_eq!(visual.backend(), "gpu", "{:?}", visual.failure());
    assert_eq!(visual.surface_generation(), 1);
    assert!(visual.compliance(0).shares_l(&body.compliance));
    let d = &visual.deformers().unwrap()[0];
    assert_eq!(d.index_count() as usize, 3 * body.triangles.len());
    let pos = d.read_back(&g.device, &g.queue).unwrap().0;
    let (worst, _) = check_positions(&body.compliance, &mesh.nodes, &forces, &pos);
    let moved = pos
        .iter()
        .zip(&before)
        .map(|(a, b)| (to_f64(*a) - to_f64(*b)).length())
        .fold(0.0, f64::max);
    eprintln!(
        "gpu: worst error {worst:.3} of the tolerance; the new body moves a vertex {moved:.2e} m"
    );
    assert!(moved > 1e-6, "{moved}");
    // The same generation again takes nothing new.
    visual.update(&sample);
    assert_eq!(visual.surface_generation(), 1);
    // On the CPU: the body's displace.
    let mut cpu = Visual::new(&w, None);
    cpu.follow_cuts(feed);
    cpu.update(&sample);
    let mut want = vec![DVec3::ZERO; body.compliance.rows().len()];
    body.compliance.displace(sample.bc(0).entries(), &mut want);
    assert_eq!(cpu.cpu_displacement(0), &want[..]);
    assert!(cpu.cut_body(0).is_some());
}

/// In the half-float layouts too (`U` stays f32): the cut cube's pass is within the layouts'
/// own bound of the f64 `displace` with the correction (2·10⁻³ of max |u|, `tests/it/gpu_f16.rs`).
#[test]
fn the_half_float_layouts_carry_the_correction_too() {
    let g = gpu();
    let mesh = touchfem::mesh::cube();
    let base = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let at = DVec3::new(0.015, 0.015, 0.026);
    let mut cut = Cut::new(&mesh).unwrap();
    cut.remove(&mesh, &tets_near(&mesh, at, 20)).unwrap();
    let carried = base
        .with_correction(Arc::new(cut.correction(&base).unwrap()))
        .unwrap();
    let forces = forces_near(&base, &mesh, at + DVec3::new(0.004, 0.004, 0.0));
    let f64_forces: Vec<(u32, DVec3)> = forces.iter().map(|&(c, f)| (c, to_f64(f))).collect();
    let mut u = vec![DVec3::ZERO; carried.rows().len()];
    carried.displace(&f64_forces, &mut u);
    let mut plain = vec![DVec3::ZERO; base.rows().len()];
    base.displace(&f64_forces, &mut plain);
    let max_u = u.iter().map(|v| v.length()).fold(0.0, f64::max);
    let cut_shows = u
        .iter()
        .zip(&plain)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f64::max);
    for storage in [LStorage::BuffersF16, LStorage::TextureF16] {
        let mut d = deformer(&base, &mesh, storage);
        d.set_correction(&g.device, &g.queue, carried.correction())
            .unwrap();
        d.set_forces(&g.queue, &forces).unwrap();
        let (pos, _) = run(&d);
        let err = pos
            .iter()
            .zip(carried.rows())
            .zip(&u)
            .map(|((p, &node), u)| (to_f64(*p) - mesh.nodes[node as usize] - *u).length())
            .fold(0.0, f64::max)
            / max_u;
        eprintln!(
            "{storage:?}: error {err:.1e} of max |u| {max_u:.2e} (the cut changes u by {cut_shows:.2e})"
        );
        assert!(err <= 2e-3, "{storage:?}: {err}");
        assert!(cut_shows > 100.0 * err * max_u);
    }
}
