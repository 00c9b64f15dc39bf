//! A separating cut on the GPU (`Deformer::set_correction_at`, `touchfem_gpu::install_cut`):
//! the rows the cut snapped drawn from their new rest positions, the copies of split nodes as
//! the vertices reserved after the rows (`rest + U_x z + w_p(x)`), forces on the copies'
//! columns taken, and the opened slit's faces shaded. Checked against the f64 CPU path of the
//! grown compliance (`Compliance::displace` and `displace_extra`, themselves checked against a
//! recompute in `cut_grown.rs`), with `gpu.rs`'s tolerances: positions `≤ 1e-5·max|u| +
//! 4·ulp_f32(max|x|)`, normals `≤ 1e-4`.

use std::sync::Arc;

use glam::DVec3;
use touchfem::compliance::{Compliance, Selection};
use touchfem::cut::Cut;
use touchfem::gpu::{install_cut, Deformer, DeformerOptions, GpuError, LStorage};
use touchfem::Mesh;

use crate::common::{cpu_normals, gpu_tolerance};
use crate::cut_split::{quad, MOUSE_BLADE};
use crate::gpu_cut::{gpu, run, to_f64};

/// Forces on a separated body's grown compliance `g`: on the first copies (extra columns),
/// pulling them apart from their originals, and on the columns of `L` nearest to them.
fn forces_at_the_slit(g: &Compliance, cut: &Cut, n0: u32) -> Vec<(u32, [f32; 3])> {
    let x = cut.nodes();
    let copies: Vec<u32> = (n0..cut.node_count() as u32)
        .filter(|&v| g.col_of(v).is_some())
        .collect();
    assert!(!copies.is_empty(), "no touchable copy");
    let at = x[copies[0] as usize];
    let mut near: Vec<(f64, usize)> = (0..g.cols().len())
        .filter(|&c| g.col_of(g.cols()[c]) == Some(c))
        .map(|c| (x[g.cols()[c] as usize].distance(at), c))
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut f: Vec<(u32, [f32; 3])> = (copies.iter().take(3))
        .map(|&v| (g.col_of(v).unwrap() as u32, [0.03, -0.02, -0.04]))
        .collect();
    f.extend((near.iter().take(3)).map(|&(_, c)| (c as u32, [-0.03, 0.01, -0.02])));
    f
}

/// Installs the separated body of `cut` (its grown compliance over `c`) on a deformer of
/// `c` in `storage` reserving `reserve` extra vertices, sets `forces`, and checks every row
/// and every drawn copy against the CPU, and the normals of every vertex on the opened
/// surface. Returns (worst position error over the tolerance, largest copy displacement m,
/// how many rows the cut moved, extra vertices drawn, the deformer).
fn check_separated(
    name: &str,
    mesh: &Mesh,
    c: &Compliance,
    cut: &Cut,
    storage: LStorage,
    reserve: usize,
) -> (f64, f64, usize, u32, Deformer) {
    let gp = gpu();
    let n0 = mesh.nodes.len() as u32;
    let g = c
        .with_correction(Arc::new(cut.grown_correction(c).unwrap()))
        .unwrap();
    let opts = DeformerOptions {
        storage,
        extra_vertices: reserve,
        ..Default::default()
    };
    let mut d = Deformer::new(&gp.device, &gp.queue, c, &mesh.nodes, &mesh.surface, &opts)
        .expect("deformer");
    let sep = cut.separated_mesh(mesh);
    let rest = cut.nodes();
    install_cut(
        &gp.device,
        &gp.queue,
        &mut d,
        c,
        &g,
        &sep.surface,
        rest,
        &opts,
    )
    .expect("install");
    // Every face of the separated surface is drawn: the copies are vertices now.
    assert_eq!(d.triangles().len(), sep.surface.len(), "{name}");
    let forces = forces_at_the_slit(&g, cut, n0);
    d.set_forces(&gp.queue, &forces).unwrap();
    let (pos, nrm) = run(&d);
    let f64_forces: Vec<(u32, DVec3)> = forces.iter().map(|&(c, f)| (c, to_f64(f))).collect();
    // The CPU: rows, then the extra nodes without a row, at the body's rest positions.
    let mut u = vec![DVec3::ZERO; g.rows().len()];
    g.displace(&f64_forces, &mut u);
    let mut ue = vec![DVec3::ZERO; g.extra_nodes().len()];
    g.displace_extra(&f64_forces, &mut ue);
    let k = g.correction().unwrap();
    let mut want = vec![None; cut.node_count()];
    for (r, &v) in g.rows().iter().enumerate() {
        want[v as usize] = Some(rest[v as usize] + u[r]);
    }
    let mut copy_u = 0.0f64;
    for (e, &v) in g.extra_nodes().iter().enumerate() {
        if k.extra_row[e] == u32::MAX {
            want[v as usize] = Some(rest[v as usize] + ue[e]);
            copy_u = copy_u.max(ue[e].length());
        }
    }
    let all_u: Vec<DVec3> = u.iter().chain(&ue).copied().collect();
    let (tol, umax) = gpu_tolerance(&all_u, rest);
    assert!(umax > 0.0 && copy_u > 0.0, "{name}: nothing moved");
    let mut worst = 0.0f64;
    let mut seen = 0;
    for (v, w) in want.iter().enumerate() {
        let Some(w) = w else { continue };
        let vert =
            d.row_of(v as u32)
                .unwrap_or_else(|| panic!("{name}: node {v} has no vertex")) as usize;
        let err = (to_f64(pos[vert]) - *w).abs().max_element();
        worst = worst.max(err / tol);
        assert!(
            err <= tol,
            "{name}: node {v} (vertex {vert}): gpu {:?} vs cpu {w}: {err:e} > {tol:e}",
            pos[vert]
        );
        seen += 1;
    }
    assert_eq!(
        seen,
        pos.len(),
        "{name}: a vertex read back that no node owns"
    );
    // The rows the cut snapped are drawn where it moved them.
    let moved = (g.rows().iter())
        .filter(|&&v| rest[v as usize] != mesh.nodes[v as usize])
        .count();
    // Normals of the opened surface, from the CPU's deformed positions.
    let x: Vec<DVec3> = (0..cut.node_count())
        .map(|v| want[v].unwrap_or(rest[v]))
        .collect();
    let n_cpu = cpu_normals(&x, &sep.surface);
    let mut on = vec![false; cut.node_count()];
    for t in &sep.surface {
        for &v in t {
            on[v as usize] = true;
        }
    }
    let mut worst_n = 0.0f64;
    for v in (0..cut.node_count()).filter(|&v| on[v]) {
        let vert = d.row_of(v as u32).unwrap() as usize;
        worst_n = worst_n.max((to_f64(nrm[vert]) - n_cpu[v]).abs().max_element());
    }
    assert!(worst_n <= 1e-4, "{name}: normals {worst_n:e}");
    eprintln!(
        "{name} ({storage:?}): {} rows + {} copies drawn, {moved} rows snapped, worst position \
         {worst:.3} of the tolerance, normals {worst_n:.1e}, the copies move up to {copy_u:.2e} m",
        d.vertex_count(),
        d.extra_vertex_count()
    );
    let drawn = d.extra_vertex_count();
    (worst, copy_u, moved, drawn, d)
}

#[test]
fn a_separated_cube_is_drawn_on_the_gpu_as_the_cpu_displaces_it() {
    let (mesh, c, mut cut) = crate::cut_grown::cube_cut_ending_inside();
    for storage in [LStorage::Buffers, LStorage::Texture] {
        let (_, copy_u, moved, drawn, _) =
            check_separated("cube, a cut ending inside", &mesh, &c, &cut, storage, 32);
        assert!(copy_u > 1e-6 && drawn >= 1, "{copy_u} {drawn}");
        assert!(moved >= 1, "no row snapped");
    }
    // A second cut across the first: more copies, more rank, the same deformer's room.
    cut.split(
        &mesh,
        &[quad(&mesh, [2.0, 15.0, 30.0], [28.0, 15.0, 30.0], 16.0)],
    )
    .unwrap();
    for storage in [LStorage::Buffers, LStorage::Texture] {
        let (_, _, _, drawn, _) =
            check_separated("cube, a second cut across", &mesh, &c, &cut, storage, 32);
        assert!(drawn >= 10, "{drawn}");
    }
}

#[test]
fn a_separated_mouse_is_drawn_on_the_gpu_as_the_cpu_displaces_it() {
    let mesh = touchfem::mesh::mouse();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let mut cut = Cut::new(&mesh).unwrap();
    let (a, b) = MOUSE_BLADE;
    cut.split(&mesh, &[quad(&mesh, a, b, 8.0)]).unwrap();
    let (_, _, moved, drawn, _) =
        check_separated("mouse, one blade", &mesh, &c, &cut, LStorage::Texture, 64);
    assert!(drawn >= 5 && moved >= 5, "{drawn} {moved}");
}

#[test]
fn a_deformer_with_too_little_room_refuses_and_install_cut_makes_room() {
    let gp = gpu();
    let (mesh, c, cut) = crate::cut_grown::cube_cut_ending_inside();
    let g = c
        .with_correction(Arc::new(cut.grown_correction(&c).unwrap()))
        .unwrap();
    let k = g.correction().unwrap();
    let added = k.extra_row.iter().filter(|&&r| r == u32::MAX).count();
    assert!(added >= 1);
    let opts = DeformerOptions::default();
    let mut d = Deformer::new(&gp.device, &gp.queue, &c, &mesh.nodes, &mesh.surface, &opts)
        .expect("deformer");
    assert_eq!(d.extra_capacity(), 0);
    d.set_forces(&gp.queue, &[(0, [0.0, 0.0, -0.05])]).unwrap();
    let (before, _) = run(&d);
    // Without room, and without rest positions: typed errors, nothing changed.
    for e in [
        d.set_correction_at(&gp.device, &gp.queue, Some(k), cut.nodes()),
        d.set_correction(&gp.device, &gp.queue, Some(k)),
    ] {
        match e {
            Err(GpuError::BadInput(m)) => assert!(m.contains("without a row"), "{m}"),
            other => panic!("{other:?}"),
        }
    }
    let (after, _) = run(&d);
    assert_eq!(before, after);
    // A force on an extra column is refused while no correction adds it.
    let extra_col = c.cols().len() as u32;
    assert!(matches!(
        d.set_forces(&gp.queue, &[(extra_col, [0.0; 3])]),
        Err(GpuError::ColumnOutOfRange { .. })
    ));
    // install_cut makes room (twice what is needed) and draws every face.
    let sep = cut.separated_mesh(&mesh);
    install_cut(
        &gp.device,
        &gp.queue,
        &mut d,
        &c,
        &g,
        &sep.surface,
        cut.nodes(),
        &opts,
    )
    .unwrap();
    assert_eq!(d.extra_capacity(), 2 * added);
    assert_eq!(d.extra_vertex_count() as usize, added);
    assert_eq!(d.triangles().len(), sep.surface.len());
    d.set_forces(&gp.queue, &[(extra_col, [0.0, 0.0, -0.05])])
        .unwrap();
    // A sample of a newer body's columns: `keep_known` leaves them out, the others in order.
    assert_eq!(d.column_count(), c.cols().len() + k.extra.len());
    let beyond = d.column_count() as u32;
    let mut f = [
        (beyond, [0.0, 0.0, -0.05]),
        (extra_col, [0.0, 0.0, -0.05]),
        (beyond + 7, [0.0; 3]),
        (0, [0.01, 0.0, 0.0]),
    ];
    let n = d.keep_known(&mut f);
    assert_eq!(n, 2);
    assert_eq!((f[0].0, f[1].0), (extra_col, 0));
    d.set_forces(&gp.queue, &f[..n]).unwrap();
    // Back to no correction: the copies are no longer drawn, the rows at their old rest.
    d.set_correction(&gp.device, &gp.queue, None).unwrap();
    assert_eq!(d.extra_vertex_count(), 0);
    assert!(d.set_forces(&gp.queue, &[(extra_col, [0.0; 3])]).is_err());
}
