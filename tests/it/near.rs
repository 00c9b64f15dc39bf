//! A live session that holds only the haptic path's near blocks (`scene::file::Hold`): the
//! same forces, bit for bit, as the dense `L`; the same GPU vertices, bit for bit, from the
//! cache file; a fraction of the host memory; dense again for several fingers, and a corrupt
//! file is recomputed. Needs an adapter for the GPU part (lavapipe works).

use glam::DVec3;
use touchfem::contact::force::ForceModel;
use touchfem::gpu::{Deformer, DeformerOptions, Gpu, LStorage};
use touchfem::scene::file::Hold;
use touchfem::scene::{SceneSource, World};

fn mouse_worlds(dir: &std::path::Path, fingers: usize) -> (World, World) {
    let mut src = SceneSource::for_mesh("mouse", "udp");
    for _ in 1..fingers {
        src.text.push_str("\n[[finger]]\ndevice = \"udp\"\n");
    }
    // The first load computes and saves the cache; the second holds only the near blocks.
    let dense = World::from_source_holding(&src, Some(dir), Hold::Dense).expect("dense");
    let near = World::from_source_holding(&src, Some(dir), Hold::Near).expect("near");
    (dense, near)
}

#[test]
fn near_blocks_give_the_dense_forces_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let (dense, near) = mouse_worlds(dir.path(), 1);
    let (d, n) = (&dense.objects[0].body, &near.objects[0].body);
    assert!(d.compliance.holds_l());
    assert!(!n.compliance.holds_l());
    assert!(n.compliance.l_f64().is_empty());
    assert_eq!(d.compliance.rows(), n.compliance.rows());
    assert_eq!(d.compliance.cols(), n.compliance.cols());
    // Every held block equals the dense one exactly, and each column has its triangles'
    // neighbours (a closed surface: at least 3 besides itself).
    let nb = n.compliance.near().unwrap();
    let nc = n.compliance.cols().len();
    for i in 0..nc {
        assert!(nb.neighbours(i).len() >= 4, "column {i}");
        for &j in nb.neighbours(i) {
            let j = j as usize;
            assert_eq!(
                n.compliance.touch_block(i, j),
                d.compliance.touch_block(i, j)
            );
        }
        assert_eq!(n.compliance.diag_inv(i), d.compliance.diag_inv(i));
    }
    assert_eq!(
        n.compliance.clamp_compliance(),
        d.compliance.clamp_compliance()
    );
    // K⁻¹ is symmetric to round-off in the held pairs too.
    assert!(n.compliance.stats.symmetry < 1e-12);
    // Host bytes: the mouse's dense L (≈ 1 000 rows × 800 columns) against the blocks.
    let (bd, bn) = (d.compliance.stats.bytes, n.compliance.stats.bytes);
    assert!(bn * 100 < bd, "near {bn} B, dense {bd} B");
    // Pokes all over the surface, both models: the same forces and nodal forces, bit for bit.
    let (lo, hi) = d.mesh.bounds();
    let mut touched = 0;
    for k in 0..40 {
        let t = k as f64 / 40.0;
        let at = lo + (hi - lo) * DVec3::new(t, (3.7 * t).fract(), (7.3 * t).fract());
        let push = (lo + hi) * 0.5 - at;
        let push = push.normalize() * 2e-3;
        for model in [ForceModel::Paper, ForceModel::Exact] {
            let a = d.poke(at, push, model, 10).unwrap();
            let b = n.poke(at, push, model, 10).unwrap();
            assert_eq!(a.feedback, b.feedback);
            assert_eq!(a.feedback_paper, b.feedback_paper);
            assert_eq!(a.feedback_exact, b.feedback_exact);
            assert_eq!(a.bc.entries(), b.bc.entries());
            touched += usize::from(a.feedback.length() > 0.0);
        }
    }
    assert!(touched >= 40, "{touched} pokes touched");
}

#[test]
fn the_deformer_reads_the_cache_file_into_the_same_vertices() {
    let dir = tempfile::tempdir().unwrap();
    let (dense, near) = mouse_worlds(dir.path(), 1);
    let g = match Gpu::new_headless() {
        Ok(g) => g,
        Err(e) => panic!("no adapter ({e}); set WGPU_BACKEND=vulkan with lavapipe installed"),
    };
    let (d, n) = (&dense.objects[0].body, &near.objects[0].body);
    let nc = d.compliance.cols().len() as u32;
    let forces: Vec<(u32, [f32; 3])> = [0, nc / 3, nc - 1]
        .iter()
        .map(|&c| (c, [0.01, -0.02, -0.05]))
        .collect();
    for storage in [
        LStorage::Texture,
        LStorage::Buffers,
        LStorage::BuffersF16,
        LStorage::TextureF16,
    ] {
        // Small chunks, so the file is read in many ranges.
        let opts = DeformerOptions {
            storage,
            max_binding_bytes: Some(1 << 20),
            ..Default::default()
        };
        let mut out = Vec::new();
        for s in [d, n] {
            let mut def = Deformer::new(
                &g.device,
                &g.queue,
                &s.compliance,
                &s.mesh.nodes,
                &s.mesh.surface,
                &opts,
            )
            .expect("deformer");
            def.set_forces(&g.queue, &forces).unwrap();
            let mut enc = g.device.create_command_encoder(&Default::default());
            def.encode(&mut enc);
            g.queue.submit([enc.finish()]);
            out.push(def.read_back(&g.device, &g.queue).expect("read back"));
        }
        // `AutoF16` is the auto layout in half floats: the f16 texture on lavapipe.
        if storage == LStorage::TextureF16 {
            let auto16 = Deformer::new(
                &g.device,
                &g.queue,
                &n.compliance,
                &n.mesh.nodes,
                &n.mesh.surface,
                &DeformerOptions {
                    storage: LStorage::AutoF16,
                    ..opts.clone()
                },
            )
            .expect("deformer");
            assert_eq!(auto16.stats().storage, LStorage::TextureF16);
        }
        assert_eq!(out[0].0, out[1].0, "{storage:?} positions");
        assert_eq!(out[0].1, out[1].1, "{storage:?} normals");
        // And the press moved something.
        let moved = out[0]
            .0
            .iter()
            .zip(d.compliance.rows())
            .map(|(p, &r)| (glam::Vec3::from(*p).as_dvec3() - d.mesh.nodes[r as usize]).length())
            .fold(0.0, f64::max);
        assert!(moved > 1e-5, "{storage:?}: {moved} m");
    }
}

#[test]
fn several_fingers_keep_the_dense_l_and_a_corrupt_file_is_recomputed() {
    let dir = tempfile::tempdir().unwrap();
    let (_, two) = mouse_worlds(dir.path(), 2);
    assert!(two.objects[0].body.compliance.holds_l());
    // Corrupt the cache file's last batch: a near-only load refuses it and recomputes.
    let file = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "tfc"))
        .expect("a cache file");
    let mut bytes = std::fs::read(&file).unwrap();
    let at = bytes.len() - 100;
    bytes[at] ^= 0xff;
    std::fs::write(&file, &bytes).unwrap();
    let src = SceneSource::for_mesh("mouse", "udp");
    let w = World::from_source_holding(&src, Some(dir.path()), Hold::Near).expect("recomputed");
    let c = &w.objects[0].body.compliance;
    assert!(!c.holds_l());
    assert!(c.stats.residual < 1e-9);
    let fresh = std::fs::read(&file).unwrap();
    assert_ne!(fresh[at], bytes[at], "the file was rewritten");
}
