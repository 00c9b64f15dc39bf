//! The GPU pass from a hierarchical `L` ([`LStorage::Hier`]): read-back positions
//! against the CPU's [`HMatrix::displace`] (f64) on the mouse, with the values in one buffer,
//! split over several, and in half floats; typed errors. Needs an adapter (lavapipe works).
//!
//! Tolerances: f32 `|x_gpu − (x_rest + u_H)| ≤ 1e-5·max|u_H| + 4·ulp_f32(max|x_rest|)`; f16
//! `≤ 2e-3·max|u_H|` (as `gpu_f16.rs` for the dense layouts).

use std::sync::OnceLock;

use crate::common::cpu_normals;
use glam::DVec3;
use touchfem::compliance::correction::Correction;
use touchfem::compliance::hmatrix::{HMatrix, HOptions};
use touchfem::compliance::{Compliance, Selection};
use touchfem::gpu::{
    hier_gpu_bytes, Deformer, DeformerOptions, Gpu, GpuError, LStorage, HIER_VALUE_BINDINGS,
    MAX_ACTIVE,
};
use touchfem::mesh::Mesh;
use touchfem::wgpu;

fn gpu() -> &'static Gpu {
    static GPU: OnceLock<Gpu> = OnceLock::new();
    GPU.get_or_init(|| {
        Gpu::new_headless()
            .unwrap_or_else(|e| panic!("GPU tests need an adapter and must not be skipped: {e}"))
    })
}

struct Mouse {
    mesh: Mesh,
    dense: Compliance,
    /// Hierarchical compliances at 1e-3 and 1e-6.
    h3: Compliance,
    h6: Compliance,
}

fn mouse() -> &'static Mouse {
    static M: OnceLock<Mouse> = OnceLock::new();
    M.get_or_init(|| {
        let mesh = touchfem::mesh::mouse();
        let dense = Compliance::compute(&mesh, &Selection::default()).expect("mouse L");
        let hier = |eps: f64| {
            let h = dense.compress(&mesh, &HOptions::new(eps)).expect("H");
            Compliance::from_hier(
                dense.rows().to_vec(),
                dense.l_rows(),
                dense.cols().to_vec(),
                h,
                mesh.nodes.len(),
            )
            .expect("hierarchical compliance")
        };
        let (h3, h6) = (hier(1e-3), hier(1e-6));
        Mouse {
            mesh,
            dense,
            h3,
            h6,
        }
    })
}

fn hmat(c: &Compliance) -> &HMatrix {
    c.hier().expect("hierarchical")
}

fn deformer(c: &Compliance, opts: &DeformerOptions) -> Result<Deformer, GpuError> {
    let (g, m) = (gpu(), mouse());
    Deformer::new(&g.device, &g.queue, c, &m.mesh.nodes, &m.mesh.surface, opts)
}

/// Forces of 50 .. 250 mN in mixed directions on `cols` (millimetre displacements).
fn forces_on(cols: &[u32]) -> Vec<(u32, [f32; 3])> {
    let e = mouse().mesh.material.young_pa / 1000.0;
    cols.iter()
        .enumerate()
        .map(|(k, &col)| {
            let s = (0.05 * (1.0 + (k % 5) as f64) * e) as f32;
            let sign = if k % 2 == 0 { 1.0 } else { -0.7 };
            (col, [0.3 * s * sign, -0.5 * s, -s])
        })
        .collect()
}

/// Runs one frame with `forces` and returns (max |x_gpu − (rest + u_H)|, max|u_H|, max |x_rest|)
/// over every displayed row; with `normals`, also checks the normals against the CPU's.
fn frame(c: &Compliance, d: &mut Deformer, forces: &[(u32, [f32; 3])], normals: bool) -> [f64; 3] {
    let (g, m) = (gpu(), mouse());
    d.set_forces(&g.queue, forces).expect("forces");
    let mut enc = g
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
    d.encode(&mut enc);
    g.queue.submit([enc.finish()]);
    let (pos, nrm) = d.read_back(&g.device, &g.queue).expect("read back");
    let f64s: Vec<(u32, DVec3)> = forces
        .iter()
        .map(|&(col, f)| (col, DVec3::from(f.map(f64::from))))
        .collect();
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    hmat(c).displace(&f64s, &mut u);
    let x: Vec<DVec3> = c
        .rows()
        .iter()
        .zip(&u)
        .map(|(&node, u)| m.mesh.nodes[node as usize] + *u)
        .collect();
    let umax = u.iter().fold(0.0f64, |a, v| a.max(v.abs().max_element()));
    let xmax = c.rows().iter().fold(0.0f64, |a, &n| {
        a.max(m.mesh.nodes[n as usize].abs().max_element())
    });
    let err = pos.iter().zip(&x).fold(0.0f64, |a, (p, w)| {
        a.max((DVec3::from(p.map(f64::from)) - *w).abs().max_element())
    });
    if normals {
        let want = cpu_normals(&x, d.triangles());
        let got = nrm.expect("normals written");
        let worst = got.iter().zip(&want).fold(0.0f64, |a, (g, w)| {
            a.max((DVec3::from(g.map(f64::from)) - *w).length())
        });
        assert!(worst <= 1e-4, "normals: max error {worst:e}");
    }
    [err, umax, xmax]
}

fn f32_tol(umax: f64, xmax: f64) -> f64 {
    1e-5 * umax + 4.0 * f64::from(f32::EPSILON) * xmax
}

/// Test cases: one column; a 9-column finger patch (a column and its 8 nearest); columns
/// spread over different leaves; two sibling leaves (their far blocks are shared); and the 64
/// columns of the first leaves, one repeated.
fn cases(c: &Compliance) -> Vec<(&'static str, Vec<u32>)> {
    let (h, mesh) = (hmat(c), &mouse().mesh);
    let nc = c.cols().len();
    let at = |col: usize| mesh.nodes[c.cols()[col] as usize];
    let mid = nc / 2;
    let mut near: Vec<usize> = (0..nc).collect();
    near.sort_by(|&a, &b| at(a).distance(at(mid)).total_cmp(&at(b).distance(at(mid))));
    let patch: Vec<u32> = near[..9].iter().map(|&c| c as u32).collect();
    let leaf = |col: usize| h.leaf_of(h.col_pos(col).expect("column"));
    let mut seen = vec![false; h.col_leaves()];
    let mut spread = Vec::new();
    for col in (0..nc).step_by(5) {
        if !seen[leaf(col)] && spread.len() < 12 {
            seen[leaf(col)] = true;
            spread.push(col as u32);
        }
    }
    assert!(spread.len() >= 4, "the mouse has {} leaves", h.col_leaves());
    let perm = h.col_perm();
    let first: Vec<u32> = perm
        .iter()
        .take_while(|&&p| leaf(p as usize) <= 1)
        .copied()
        .collect();
    let mut many: Vec<u32> = perm.iter().take(64).copied().collect();
    many.push(many[3]);
    vec![
        ("one column", vec![c.cols().len() as u32 / 3]),
        ("9-column patch", patch),
        ("spread over leaves", spread),
        ("two sibling leaves", first),
        ("64 columns, one twice", many),
        // Every column leaf: tables over several uniform windows.
        ("every column", (0..nc.min(MAX_ACTIVE) as u32).collect()),
    ]
}

#[test]
fn hier_positions_match_the_cpu_product() {
    let m = mouse();
    for (name, c) in [("1e-3", &m.h3), ("1e-6", &m.h6)] {
        let h = hmat(c);
        let mut d = deformer(c, &DeformerOptions::default()).expect("deformer");
        assert_eq!(d.stats().storage, LStorage::Hier);
        assert_eq!(d.stats().chunks, 1);
        assert_eq!(d.stats().l_bytes, hier_gpu_bytes(h, false));
        // The rest pose first.
        let [e0, u0, x0] = frame(c, &mut d, &[], false);
        assert_eq!(u0, 0.0);
        assert!(e0 <= 4.0 * f64::from(f32::EPSILON) * x0, "rest: {e0:e}");
        for (i, (case, cols)) in cases(c).into_iter().enumerate() {
            let [err, umax, xmax] = frame(c, &mut d, &forces_on(&cols), i == 1);
            let tol = f32_tol(umax, xmax);
            println!(
                "ε {name}, {case} ({} columns): max error {err:.3e} m = {:.2e}·max|u| \
                 (max|u| {umax:.3e} m, tol {tol:.3e})",
                cols.len(),
                err / umax
            );
            assert!(umax > 1e-5, "{case}: max|u| {umax:e}");
            assert!(err <= tol, "ε {name}, {case}: error {err:e} > {tol:e}");
            let windows = d.stats().frame_windows.expect("hierarchical");
            if case == "every column" {
                assert!(windows >= 2, "{case}: {windows} window(s)");
            } else if case == "one column" {
                assert_eq!(windows, 1);
            }
        }
        // Back to rest: nothing stale from the last frame.
        let [e, _, x] = frame(c, &mut d, &[], false);
        assert!(e <= 4.0 * f64::from(f32::EPSILON) * x, "rest again: {e:e}");
    }
}

#[test]
fn hier_values_split_over_several_buffers_match() {
    let c = &mouse().h3;
    let h = hmat(c);
    // The largest block's and all values' bytes (f32).
    let largest = h
        .blocks()
        .map(|b| {
            let (m, n) = (3 * b.rows.len(), 3 * b.cols.len());
            4 * b.rank.map_or(m * n, |k| (m + n) * k) as u64
        })
        .max()
        .unwrap();
    let total = 4 * unique_values(h) as u64;
    let cap = largest.max(total * 2 / 7);
    let opts = DeformerOptions {
        max_binding_bytes: Some(cap),
        ..Default::default()
    };
    let mut d = deformer(c, &opts).expect("deformer");
    let n = d.stats().chunks;
    println!("values {total} bytes, cap {cap}: {n} buffers");
    assert!((3..=HIER_VALUE_BINDINGS).contains(&n), "{n} buffers");
    // Only the per-buffer padding beside the one-buffer figure.
    let one = hier_gpu_bytes(h, false);
    assert!(d.stats().l_bytes >= one && d.stats().l_bytes <= one + 16 * n as u64);
    for (case, cols) in cases(c) {
        let [err, umax, xmax] = frame(c, &mut d, &forces_on(&cols), false);
        println!("split, {case}: max error {:.2e}·max|u|", err / umax);
        assert!(err <= f32_tol(umax, xmax), "{case}: {err:e}");
    }
}

#[test]
fn hier_half_floats_stay_within_2e_3() {
    let m = mouse();
    let c = &m.h3;
    let h = hmat(c);
    let opts = DeformerOptions {
        storage: LStorage::HierF16,
        ..Default::default()
    };
    let mut d16 = deformer(c, &opts).expect("f16 deformer");
    assert_eq!(d16.stats().storage, LStorage::HierF16);
    assert_eq!(d16.stats().l_bytes, hier_gpu_bytes(h, true));
    // A half-float option for a dense layout asks for half floats here too.
    let d = deformer(
        c,
        &DeformerOptions {
            storage: LStorage::BuffersF16,
            ..Default::default()
        },
    )
    .expect("deformer");
    assert_eq!(d.stats().storage, LStorage::HierF16);
    let mut d32 = deformer(c, &DeformerOptions::default()).expect("f32 deformer");
    for (case, cols) in cases(c) {
        let f = forces_on(&cols);
        let [e16, umax, _] = frame(c, &mut d16, &f, false);
        let [e32, _, _] = frame(c, &mut d32, &f, false);
        let (r16, r32) = (e16 / umax, e32 / umax);
        println!("f16, {case}: max error {r16:.2e}·max|u| (f32 {r32:.2e})");
        assert!(r16 <= 2e-3, "{case}: f16 error {r16:e}");
        // It is the half floats' rounding, well above f32's.
        assert!(r16 > 10.0 * r32, "{case}: f16 {r16:e} vs f32 {r32:e}");
    }
}

#[test]
fn hier_stores_less_than_the_dense_l() {
    let m = mouse();
    let nl = m.dense.l_rows() as u64;
    let nc = m.dense.cols().len() as u64;
    let dense_f32 = 36 * nl * nc;
    let dense = deformer(
        &m.dense,
        &DeformerOptions {
            storage: LStorage::Buffers,
            ..Default::default()
        },
    )
    .expect("dense deformer");
    assert_eq!(dense.stats().l_bytes, dense_f32);
    for (name, c) in [("1e-3", &m.h3), ("1e-6", &m.h6)] {
        let h = hmat(c);
        let (b32, b16) = (hier_gpu_bytes(h, false), hier_gpu_bytes(h, true));
        println!(
            "mouse ({nl} rows × {nc} columns), ε {name}: GPU bytes f32 {b32} ({:.1}% of the \
             dense f32 L's {dense_f32}), f16 {b16}; {} blocks",
            100.0 * b32 as f64 / dense_f32 as f64,
            h.blocks().count()
        );
        assert!(b16 < b32);
        assert!(b32 >= 4 * unique_values(h) as u64);
        // One triangle on the GPU: each mirror is read as its source's transpose.
        let mirrors = h.blocks().filter(|b| b.mirror_of.is_some()).count();
        assert!(mirrors > 0);
        assert!(
            (unique_values(h) as f64) < 0.6 * h.stored_values() as f64,
            "{} of {} values uploaded",
            unique_values(h),
            h.stored_values()
        );
    }
    assert!(hier_gpu_bytes(hmat(&m.h3), false) < dense_f32);
}

#[test]
fn hier_bad_cases_are_typed_errors() {
    let (g, m) = (gpu(), mouse());
    let c = &m.h3;
    let mut d = deformer(c, &DeformerOptions::default()).expect("deformer");
    let nc = c.cols().len();
    let too_many: Vec<(u32, [f32; 3])> = (0..=MAX_ACTIVE)
        .map(|i| ((i % nc) as u32, [0.0, 0.0, -0.01]))
        .collect();
    assert!(matches!(
        d.set_forces(&g.queue, &too_many),
        Err(GpuError::TooManyActive { count, max }) if count == MAX_ACTIVE + 1 && max == MAX_ACTIVE
    ));
    assert!(matches!(
        d.set_forces(&g.queue, &[(nc as u32, [0.0; 3])]),
        Err(GpuError::ColumnOutOfRange { .. })
    ));
    // Exactly MAX_ACTIVE entries (columns repeat) still match.
    let full: Vec<(u32, [f32; 3])> = (0..MAX_ACTIVE)
        .map(|i| ((i * 7 % nc) as u32, [1e-3, -2e-3, -1e-2]))
        .collect();
    let [err, umax, xmax] = frame(c, &mut d, &full, false);
    println!("{MAX_ACTIVE} entries: max error {:.2e}·max|u|", err / umax);
    assert!(err <= f32_tol(umax, xmax), "{err:e}");
    // A cut's correction: not on a hierarchical L.
    let r = d.set_correction(&g.device, &g.queue, Some(&Correction::default()));
    assert!(matches!(r, Err(GpuError::Unsupported(_))), "{r:?}");
    assert!(d.set_correction(&g.device, &g.queue, None).is_ok());
    assert_eq!(d.stats().correction_rank, 0);
    // The hierarchical layout asked for with a dense L.
    let r = deformer(
        &m.dense,
        &DeformerOptions {
            storage: LStorage::Hier,
            ..Default::default()
        },
    );
    assert!(matches!(r, Err(GpuError::Unsupported(_))), "{:?}", r.err());
    // Values that need more buffers than there are bindings, or a block above the cap.
    let total = 4 * unique_values(hmat(c)) as u64;
    for cap in [total / 8, 64] {
        let r = deformer(
            c,
            &DeformerOptions {
                max_binding_bytes: Some(cap),
                ..Default::default()
            },
        );
        assert!(
            matches!(r, Err(GpuError::BufferTooLarge { .. })),
            "cap {cap}: {:?}",
            r.err()
        );
    }
}

/// A measurement, not a check (`cargo test --features app --test it gpu_hier::frame_time --
/// --ignored --nocapture`): µs per frame (set_forces, encode, submit, wait) of each layout on
/// the mouse, median of 30.
#[test]
#[ignore]
fn frame_time() {
    let (g, m) = (gpu(), mouse());
    let time = |c: &Compliance, storage: LStorage, f: &[(u32, [f32; 3])]| {
        let opts = DeformerOptions {
            storage,
            ..Default::default()
        };
        let mut d = deformer(c, &opts).expect("deformer");
        let mut t = Vec::new();
        for _ in 0..31 {
            let t0 = std::time::Instant::now();
            d.set_forces(&g.queue, f).expect("forces");
            let mut enc = g.device.create_command_encoder(&Default::default());
            d.encode(&mut enc);
            let i = g.queue.submit([enc.finish()]);
            g.device
                .poll(wgpu::PollType::Wait {
                    submission_index: Some(i),
                    timeout: None,
                })
                .expect("poll");
            t.push(t0.elapsed().as_secs_f64() * 1e6);
        }
        t.sort_by(f64::total_cmp);
        t[15]
    };
    for (case, cols) in cases(&m.h3) {
        let f = forces_on(&cols);
        let row = [
            ("dense buffers", &m.dense, LStorage::Buffers),
            ("dense texture", &m.dense, LStorage::Texture),
            ("hier 1e-3", &m.h3, LStorage::Hier),
            ("hier 1e-3 f16", &m.h3, LStorage::HierF16),
            ("hier 1e-6", &m.h6, LStorage::Hier),
        ]
        .map(|(n, c, s)| format!("{n} {:.0} µs", time(c, s, &f)));
        println!("{case} ({} columns): {}", cols.len(), row.join(", "));
    }
}

/// The visual path draws a hierarchical compliance: on the GPU (the hierarchical layout) and,
/// without one, on the CPU (its compressed product).
#[test]
fn visual_path_draws_a_hierarchical_compliance() {
    use touchfem::runtime::WorldSample;
    use touchfem_app::visual::Visual;
    let g = gpu();
    let mut w = crate::common::world_from_text(
        "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"pointer\"\n",
    )
    .expect("cube scene");
    let body = &mut w.objects[0].body;
    let c = &body.compliance;
    let h = c.compress(&body.mesh, &HOptions::new(1e-3)).expect("H");
    body.compliance = Compliance::from_hier(
        c.rows().to_vec(),
        c.l_rows(),
        c.cols().to_vec(),
        h,
        body.mesh.nodes.len(),
    )
    .expect("hierarchical compliance");
    let (mesh, c) = (&w.objects[0].body.mesh, &w.objects[0].body.compliance);
    let mut sample = WorldSample {
        n_objects: 1,
        ..Default::default()
    };
    let nc = c.cols().len() as u32;
    for col in [0, nc / 2, nc - 1] {
        sample.bcs[0].add(col, DVec3::new(0.1, -0.2, -1.0));
    }
    let mut want = vec![DVec3::ZERO; c.rows().len()];
    c.displace(sample.bc(0).entries(), &mut want);
    let umax = want
        .iter()
        .fold(0.0f64, |a, v| a.max(v.abs().max_element()));
    assert!(umax > 1e-6, "{umax}");

    let mut visual = Visual::new(&w, Some(g));
    visual.update(&sample);
    assert_eq!(visual.backend(), "gpu", "{:?}", visual.failure());
    let d = &visual.deformers().expect("gpu")[0];
    assert_eq!(d.stats().storage, LStorage::Hier);
    let pos = d.read_back(&g.device, &g.queue).expect("read back").0;
    let err = c
        .rows()
        .iter()
        .zip(&pos)
        .zip(&want)
        .fold(0.0f64, |a, ((&n, p), u)| {
            let x = mesh.nodes[n as usize] + *u;
            a.max((DVec3::from(p.map(f64::from)) - x).abs().max_element())
        });
    println!("visual, GPU: max error {:.2e}·max|u|", err / umax);
    assert!(err <= f32_tol(umax, 0.05), "{err:e}");

    let mut cpu = Visual::new(&w, None);
    cpu.update(&sample);
    assert_eq!(cpu.backend(), "cpu-f64");
    assert_eq!(cpu.cpu_displacement(0), &want[..]);
}

/// Values the GPU holds for `h`: every block's but the mirrors'.
fn unique_values(h: &HMatrix) -> usize {
    h.blocks()
        .filter(|b| b.mirror_of.is_none())
        .map(|b| {
            let (m, n) = (3 * b.rows.len(), 3 * b.cols.len());
            b.rank.map_or(m * n, |k| (m + n) * k)
        })
        .sum()
}
