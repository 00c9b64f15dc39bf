//! `touchfem precompute`: streamed cache files, shards and their merge (equal byte for byte to
//! the unsharded file), refused merges, and cache robustness.

use std::path::{Path, PathBuf};
use touchfem::cache::{self, CacheError, CacheOutcome};
use touchfem::compliance::{Compliance, NodeSet, Selection};
use touchfem::mesh::{cube, mouse};
use touchfem::precompute::precompute_to_file;
use touchfem::Mesh;

fn shards(mesh: &Mesh, sel: &Selection, dir: &Path, n: usize) -> Vec<PathBuf> {
    (1..=n)
        .map(|i| {
            let p = dir.join(format!("part-{i}-of-{n}.tfc"));
            let r = precompute_to_file(mesh, sel, &p, (i, n), &mut |_, _| {}, &Default::default())
                .unwrap();
            assert_eq!(r.file, p);
            p
        })
        .collect()
}

#[test]
fn merged_shards_equal_the_unsharded_file_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    for (name, mesh) in [("cube", cube()), ("mouse", mouse())] {
        let sel = Selection::default();
        let full = dir.path().join(format!("{name}.tfc"));
        let r = precompute_to_file(
            &mesh,
            &sel,
            &full,
            (1, 1),
            &mut |_, _| {},
            &Default::default(),
        )
        .unwrap();
        let full_bytes = std::fs::read(&full).unwrap();
        assert_eq!(r.bytes as usize, full_bytes.len());
        // The same bytes as saving an in-memory compliance.
        let c = Compliance::compute(&mesh, &sel).unwrap();
        let saved = dir.path().join(format!("{name}.saved.tfc"));
        cache::save(&saved, &c, cache::key(&mesh, &sel), mesh.nodes.len()).unwrap();
        assert_eq!(std::fs::read(&saved).unwrap(), full_bytes, "{name}");
        // It loads, bit for bit the direct compute.
        let back = cache::load(&full, cache::key(&mesh, &sel), mesh.nodes.len()).unwrap();
        assert_eq!(back.l_f64(), c.l_f64());
        assert_eq!(back.rows(), c.rows());
        assert_eq!(back.cols(), c.cols());
        for n in [2, 3, 5] {
            let mut parts = shards(&mesh, &sel, dir.path(), n);
            parts.reverse(); // any order
            let merged = dir.path().join(format!("{name}.merged{n}.tfc"));
            let m = cache::merge(&parts, &merged).unwrap();
            assert_eq!(m.bytes as usize, full_bytes.len());
            assert_eq!(
                std::fs::read(&merged).unwrap(),
                full_bytes,
                "{name} in {n} parts"
            );
        }
    }
}

#[test]
fn wrong_merges_are_refused_with_a_typed_error() {
    let dir = tempfile::tempdir().unwrap();
    let m = cube();
    let sel = Selection::default();
    let parts = shards(&m, &sel, dir.path(), 2);
    let out = dir.path().join("out.tfc");
    let mismatch = |r: Result<cache::MergeInfo, CacheError>| {
        assert!(matches!(r, Err(CacheError::Mismatch { .. })), "{r:?}");
        assert!(!out.exists(), "nothing written");
    };
    // Another material.
    let mut soft = cube();
    soft.material.young_pa *= 2.0;
    let soft_dir = dir.path().join("soft");
    let soft_parts = shards(&soft, &sel, &soft_dir, 2);
    mismatch(cache::merge(
        &[parts[0].clone(), soft_parts[1].clone()],
        &out,
    ));
    // Another selection (fewer touchable nodes).
    let sel2 = Selection {
        cols: NodeSet::Nodes(m.free_surface_nodes()[..70].to_vec()),
        ..Selection::default()
    };
    let sel_dir = dir.path().join("sel");
    let sel_parts = shards(&m, &sel2, &sel_dir, 2);
    mismatch(cache::merge(
        &[parts[0].clone(), sel_parts[1].clone()],
        &out,
    ));
    // A missing, a repeated part.
    mismatch(cache::merge(&parts[..1], &out));
    mismatch(cache::merge(&[parts[1].clone(), parts[1].clone()], &out));
    mismatch(cache::merge(&[], &out));
    // Parts of another split.
    let three = shards(&m, &sel, &dir.path().join("three"), 3);
    mismatch(cache::merge(&[parts[0].clone(), three[1].clone()], &out));
    // A corrupt part.
    let mut b = std::fs::read(&parts[1]).unwrap();
    let mid = b.len() / 2;
    b[mid] ^= 1;
    let bad = dir.path().join("bad.tfc");
    std::fs::write(&bad, &b).unwrap();
    let r = cache::merge(&[parts[0].clone(), bad], &out);
    assert!(matches!(r, Err(CacheError::Corrupt { .. })), "{r:?}");
    assert!(!out.exists());
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(names.is_empty(), "temporaries left: {names:?}");
}

#[test]
fn a_shard_is_not_loaded_as_a_cache() {
    let dir = tempfile::tempdir().unwrap();
    let m = cube();
    let sel = Selection::default();
    let parts = shards(&m, &sel, dir.path(), 2);
    let r = cache::load(&parts[1], cache::key(&m, &sel), m.nodes.len());
    assert!(
        matches!(
            r,
            Err(CacheError::Partial {
                index: 2,
                count: 2,
                ..
            })
        ),
        "{:?}",
        r.err()
    );
    // load_or_compute recomputes and replaces it with a complete file.
    let (c, o) = cache::load_or_compute(&parts[1], &m, &sel).unwrap();
    assert!(matches!(
        o,
        CacheOutcome::Recomputed(CacheError::Partial { .. })
    ));
    assert_eq!(c.l_f64(), Compliance::compute(&m, &sel).unwrap().l_f64());
    assert!(cache::load(&parts[1], cache::key(&m, &sel), m.nodes.len()).is_ok());
}

#[test]
fn a_cache_from_another_selection_is_never_loaded() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cube.tfc");
    let m = cube();
    let all = Selection::default();
    let some = Selection {
        cols: NodeSet::Nodes(m.free_surface_nodes()[..10].to_vec()),
        ..Selection::default()
    };
    let (_, o) = cache::load_or_compute(&path, &m, &all).unwrap();
    assert!(matches!(o, CacheOutcome::Recomputed(CacheError::Io { .. })));
    let (c, o) = cache::load_or_compute(&path, &m, &some).unwrap();
    assert!(
        matches!(o, CacheOutcome::Recomputed(CacheError::Stale { .. })),
        "{o:?}"
    );
    assert_eq!(c.cols().len(), 10);
    assert_eq!(c.l_f64(), Compliance::compute(&m, &some).unwrap().l_f64());
    // Same node set in another order is another selection too (another column layout).
    let mut rev = m.free_surface_nodes()[..10].to_vec();
    rev.reverse();
    let some_rev = Selection {
        cols: NodeSet::Nodes(rev),
        ..Selection::default()
    };
    assert!(matches!(
        cache::load(&path, cache::key(&m, &some_rev), m.nodes.len()),
        Err(CacheError::Stale { .. })
    ));
}

#[test]
fn a_failed_save_removes_its_temporary_and_leaves_the_old_file() {
    let dir = tempfile::tempdir().unwrap();
    let m = cube();
    let sel = Selection::default();
    let path = dir.path().join("cube.tfc");
    let c = Compliance::compute(&m, &sel).unwrap();
    cache::save(&path, &c, cache::key(&m, &sel), m.nodes.len()).unwrap();
    let before = std::fs::read(&path).unwrap();
    // The target name is a non-empty directory now: the rename fails.
    let blocked = dir.path().join("blocked.tfc");
    std::fs::create_dir(&blocked).unwrap();
    std::fs::write(blocked.join("x"), b"x").unwrap();
    let r = cache::save(&blocked, &c, cache::key(&m, &sel), m.nodes.len());
    assert!(matches!(r, Err(CacheError::Io { .. })), "{r:?}");
    let tmps: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(tmps.is_empty(), "{tmps:?}");
    assert_eq!(std::fs::read(&path).unwrap(), before);
}

fn touchfem(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn cli_precompute_shards_and_merge() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    let out = touchfem(&["precompute", "cube", "--out", &d("full.tfc"), "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["rows"], 98);
    assert_eq!(v["cols"], 73);
    assert!(v["seconds"].as_f64().unwrap() >= 0.0);
    let full = std::fs::read(d("full.tfc")).unwrap();
    assert_eq!(v["bytes"].as_u64().unwrap() as usize, full.len());
    for i in 1..=2 {
        let o = touchfem(&[
            "precompute",
            "cube",
            "--shard",
            &format!("{i}/2"),
            "--out",
            &d(&format!("p{i}.tfc")),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let o = touchfem(&[
        "precompute",
        "--merge",
        &d("p2.tfc"),
        &d("p1.tfc"),
        "--out",
        &d("merged.tfc"),
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["bytes"].as_u64().unwrap() as usize, full.len());
    assert_eq!(std::fs::read(d("merged.tfc")).unwrap(), full);
    // Bad shard specs and a wrong merge: clear errors, no panic.
    for spec in ["0/2", "3/2", "a/b", "2", "1/0"] {
        let o = touchfem(&["precompute", "cube", "--shard", spec, "--out", &d("x.tfc")]);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("I/N"), "{err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    let o = touchfem(&["precompute", "--merge", &d("p1.tfc"), "--out", &d("x.tfc")]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("1 of 2") || err.contains("parts"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn an_interrupted_precompute_resumes_to_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let m = mouse();
    let sel = Selection::default();
    let full = dir.path().join("full.tfc");
    precompute_to_file(&m, &sel, &full, (1, 1), &mut |_, _| {}, &Default::default()).unwrap();
    let out = dir.path().join("resumed.tfc");
    // Stop after 3 batches, then after 5 more, then run to the end.
    for stop_at in [3, 8] {
        let r =
            touchfem::precompute::precompute_until(&m, &sel, &out, (1, 1), &mut |_, _| {}, &|w| {
                w >= stop_at
            });
        match r {
            Err(touchfem::Error::Interrupted {
                partial,
                done,
                total,
            }) => {
                assert_eq!(partial, touchfem::precompute::partial_path(&out));
                assert!(done >= stop_at && done < total, "{done} of {total}");
                assert!(partial.exists() && !out.exists());
            }
            other => panic!("expected an interruption, got {other:?}"),
        }
    }
    // A partial file of another selection is refused, not mixed in.
    let other = Selection {
        cols: NodeSet::Nodes(m.free_surface_nodes()[..100].to_vec()),
        ..Selection::default()
    };
    let r = precompute_to_file(
        &m,
        &other,
        &out,
        (1, 1),
        &mut |_, _| {},
        &Default::default(),
    );
    assert!(
        matches!(r, Err(touchfem::Error::Cache(CacheError::Mismatch { .. }))),
        "{r:?}"
    );
    let mut seen = 0;
    precompute_to_file(
        &m,
        &sel,
        &out,
        (1, 1),
        &mut |d, _| seen = seen.max(d),
        &Default::default(),
    )
    .unwrap();
    assert_eq!(seen, m.free_surface_nodes().len());
    assert!(!touchfem::precompute::partial_path(&out).exists());
    assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(&full).unwrap());
    let tmps = std::fs::read_dir(dir.path())
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".tmp")
        })
        .count();
    assert_eq!(tmps, 0);
}

#[test]
fn bench_scene_gives_the_precompute_row_of_each_object() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bench.json");
    let o = touchfem(&[
        "bench",
        "--quick",
        "--scene",
        "pinch",
        "--json",
        path.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let t = &v["scene"][0];
    // pinch: the cube with a ball of 33 touchable nodes.
    assert_eq!(t["nodes"], 125);
    assert_eq!(t["surface_nodes"], 98);
    assert_eq!(t["free_surface_nodes"], 73);
    assert_eq!(t["rows"], 98);
    assert_eq!(t["cols"], 33);
    assert!(t["precompute_s"].as_f64().unwrap() > 0.0);
    // L holds only the 73 free rows (the 25 clamped ones are zero), plus the 33 inverses.
    assert_eq!(t["bytes_l"].as_u64().unwrap(), 8 * 9 * 73 * 33 + 72 * 33);
    assert!(t["peak_rss_bytes"].as_u64().unwrap() > 1 << 20);
    // One live frame (a contact triangle deformed and drawn at 640×480) on lavapipe: a
    // measured time, not a placeholder (a frame of the 125-node cube takes well over 10 µs and
    // well under a second).
    let frame = t["frame_ms"].as_f64().expect("frame_ms on lavapipe");
    assert!(frame > 0.01 && frame < 1000.0, "{frame}");
    let rows = v["rows"].as_array().unwrap();
    let pre = rows
        .iter()
        .find(|r| r["method"] == "precompute")
        .expect("a precompute row");
    assert_eq!(pre["active_columns"], 33);
    assert!(pre["rel_error"].as_f64().unwrap() < 1e-9);
    let name = pre["mesh"].as_str().unwrap();
    assert!(rows
        .iter()
        .any(|r| r["mesh"] == name && r["method"] != "precompute"));
}

#[test]
fn precompute_without_out_fills_the_cache_the_scene_loader_reads() {
    let dir = tempfile::tempdir().unwrap();
    let cache_dir = dir.path().join("cache");
    for spec in ["pinch", "mouse"] {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
            .args(["precompute", spec, "--json"])
            .env("TOUCHFEM_CACHE_DIR", &cache_dir)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let file = PathBuf::from(v["objects"][0]["file"].as_str().unwrap());
        assert!(file.starts_with(&cache_dir) && file.exists(), "{file:?}");
        // The loader finds it: nothing is recomputed (a loaded compliance reports 0 s) and it
        // equals a fresh computation bit for bit.
        let w = touchfem::scene::World::load_with(spec, "udp", Some(&cache_dir)).unwrap();
        let c = &w.objects[0].body.compliance;
        assert_eq!(c.stats.seconds, 0.0, "{spec} was recomputed");
        let fresh = touchfem::scene::World::load_with(spec, "udp", None).unwrap();
        assert_eq!(c.l_f64(), fresh.objects[0].body.compliance.l_f64());
    }
}

#[test]
fn the_factor_is_the_same_bit_for_bit_on_any_number_of_threads() {
    // Shards made on machines with different core counts must merge into the unsharded file.
    // A 15³-cell cube: its top fronts (≈700 DOFs) are big enough for faer to split.
    let m = touchfem::mesh::cube_with(
        [15, 15, 15],
        [40.0, 40.0, 40.0],
        touchfem::Material::DEFAULT,
    )
    .unwrap();
    let k = touchfem::fem::Stiffness::assemble(&m).unwrap();
    let n = k.dofs.n_free;
    let solve = |par| {
        let (f, _, _) = k
            .factorize_with(touchfem::fem::Ordering::Metis, par)
            .unwrap();
        let mut b = faer::Mat::<f64>::zeros(n, 1);
        for i in 0..n {
            b[(i, 0)] = ((i * 7919) % 101) as f64 - 50.0;
        }
        f.solve_in_place(&mut b);
        (0..n).map(|i| b[(i, 0)].to_bits()).collect::<Vec<u64>>()
    };
    let one = solve(faer::Par::Seq);
    for t in [1, 2, 3, 8] {
        assert!(one == solve(faer::Par::rayon(t)), "{t} threads");
    }
}

#[test]
fn clamped_rows_are_not_stored() {
    let dir = tempfile::tempdir().unwrap();
    for (name, mesh) in [("cube", cube()), ("mouse", mouse())] {
        let sel = Selection::default();
        let c = Compliance::compute(&mesh, &sel).unwrap();
        let (nr, nl, nc) = (c.rows().len(), c.l_rows(), c.cols().len());
        // Free rows first, then the clamped ones, which hold nothing.
        let clamped = c.rows().iter().filter(|&&r| mesh.fixed[r as usize]).count();
        assert!(clamped > 0, "{name} has a clamped surface");
        assert_eq!(nl, nr - clamped, "{name}");
        assert!(c.rows()[..nl].iter().all(|&r| !mesh.fixed[r as usize]));
        assert!(c.rows()[nl..].iter().all(|&r| mesh.fixed[r as usize]));
        assert_eq!(c.l_f64().len(), 9 * nl * nc);
        // A clamped row reads zero and stays at rest under any load.
        let forces: Vec<(u32, glam::DVec3)> = (0..nc as u32)
            .step_by(7)
            .map(|j| (j, glam::DVec3::new(0.3, -1.0, 0.5)))
            .collect();
        let mut u = vec![glam::DVec3::splat(9.0); nr];
        c.displace(&forces, &mut u);
        assert!(u[nl..].iter().all(|v| *v == glam::DVec3::ZERO));
        assert!(u[..nl].iter().any(|v| v.length() > 0.0));
        assert_eq!(c.block(nr - 1, 0), glam::DMat3::ZERO);
        // The file holds 9·R'·C values: 72·clamped·C bytes less than every row would.
        let path = dir.path().join(format!("{name}.tfc"));
        let r = precompute_to_file(
            &mesh,
            &sel,
            &path,
            (1, 1),
            &mut |_, _| {},
            &Default::default(),
        )
        .unwrap();
        let batches = nc.div_ceil(touchfem::compliance::BATCH_COLS);
        let expected = 72 + 4 * (nr + nc) + 72 * nl * nc + 8 * batches + 8;
        assert_eq!(r.bytes as usize, expected, "{name}");
        assert_eq!(std::fs::metadata(&path).unwrap().len() as usize, expected);
        let back = cache::load(&path, cache::key(&mesh, &sel), mesh.nodes.len()).unwrap();
        assert_eq!(back.l_rows(), nl);
        assert_eq!(back.rows(), c.rows());
    }
}

/// A cache header (format 3) with the given sizes, its other fields plausible.
fn header_bytes(
    rows: u32,
    cols: u32,
    batch: u32,
    col_begin: u32,
    col_end: u32,
    l_rows: u32,
) -> Vec<u8> {
    let mut h = b"TFEMCMP\0".to_vec();
    for v in [3u32, 8, 125, rows, cols, batch] {
        h.extend_from_slice(&v.to_le_bytes());
    }
    h.extend_from_slice(&0x1234_5678_9abc_def0u64.to_le_bytes());
    for v in [1u32, 1, col_begin, col_end, 0, l_rows] {
        h.extend_from_slice(&v.to_le_bytes());
    }
    h.extend_from_slice(&0u64.to_le_bytes());
    assert_eq!(h.len(), 72);
    h
}

/// The crafted file of the issue: 80 bytes whose header sizes' product wraps to exactly 80
/// bytes (72·l_rows·2³¹ + 8·2³¹ ≡ 0 mod 2⁶⁴ for l_rows = (2³⁰ − 1)/9), so that a loader
/// that trusts the wrapped length allocates 16 GiB for the checksum table (debug builds
/// panic on the overflow first).
fn wrapping_cache_file(path: &Path) {
    let l_rows = ((1u64 << 30) - 1) / 9;
    assert_eq!(
        (72 * l_rows)
            .wrapping_mul(1 << 31)
            .wrapping_add(8 << 31)
            .wrapping_add(80),
        80
    );
    let mut b = header_bytes(0, 0, 1, 0, 1 << 31, l_rows as u32);
    b.extend_from_slice(&[0u8; 8]);
    std::fs::write(path, b).unwrap();
}

#[test]
fn a_crafted_header_whose_sizes_wrap_is_a_typed_error_before_any_allocation() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("wrap.tfc");
    wrapping_cache_file(&bad);
    let m = cube();
    let key = cache::key(&m, &Selection::default());
    let named = |e: &CacheError| {
        let s = e.to_string();
        assert!(s.contains("wrap.tfc") && s.contains("corrupt"), "{s}");
    };
    // Every loader: a typed error naming the file.
    let e = cache::load(&bad, key, 125).unwrap_err();
    assert!(matches!(e, CacheError::Corrupt { .. }), "{e:?}");
    named(&e);
    let e = cache::load_near(&bad, key, 125, &m.surface).unwrap_err();
    assert!(matches!(e, CacheError::Corrupt { .. }), "{e:?}");
    named(&e);
    let e = cache::Part::open(&bad).err().expect("refused");
    named(&e);
    let out = dir.path().join("merged.tfc");
    let e = cache::merge(std::slice::from_ref(&bad), &out).unwrap_err();
    assert!(matches!(e, CacheError::Corrupt { .. }), "{e:?}");
    named(&e);
    assert!(!out.exists());
    // Also sizes that overflow u64 outright, and a column range that runs backwards.
    for (rows, cols, batch, b0, b1, lr) in [
        (u32::MAX, u32::MAX, 1, 0, u32::MAX, u32::MAX),
        (10, 10, 64, 5, 3, 10),
        (10, 10, 0, 0, 10, 10),
        (10, 10, 4, 2, 10, 10),
    ] {
        let p = dir.path().join("sizes.tfc");
        let mut b = header_bytes(rows, cols, batch, b0, b1, lr);
        b.extend_from_slice(&[0u8; 8]);
        std::fs::write(&p, b).unwrap();
        let e = cache::load(&p, key, 125).unwrap_err();
        assert!(matches!(e, CacheError::Corrupt { .. }), "{e:?}");
    }

    // The command line: `precompute --merge` fails with status 2 and one `error:` line naming
    // the file; `poke --cache` recomputes and rewrites the file.
    let o = touchfem(&[
        "precompute",
        "--merge",
        bad.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.starts_with("error:") && err.contains("wrap.tfc"),
        "{err}"
    );
    let o = touchfem(&crate::common::poke_cube(&[
        "--json",
        "--cache",
        bad.to_str().unwrap(),
    ]));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(err.contains("corrupt"), "{err}");
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["force"][2].as_f64().unwrap() > 0.0, "{v}");
    assert!(cache::load(&bad, key, 125).is_ok(), "rewritten");
}

// An xorshift generator for the fuzz cases' choices (the cases themselves come from
// proptest's deterministic ChaCha runner).
use crate::common::Xorshift as Bits;

/// The layout a (possibly mutated) header implies, computed as the format says, or `None` if
/// it overflows or is absurd: (lists bytes, L bytes, held batches).
fn implied_layout(b: &[u8]) -> Option<(u64, u64, u64)> {
    let u = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as u64;
    let (rows, cols, batch, c0, c1, lr) = (u(20), u(24), u(28), u(48), u(52), u(60));
    let held = c1.checked_sub(c0)?;
    let nb = held.div_ceil(batch.max(1));
    Some((
        4 * (rows + cols),
        72u64.checked_mul(lr)?.checked_mul(held)?,
        nb,
    ))
}

/// Rewrites `b`'s length and checksums to match its (mutated) header, when the header
/// implies a file of at most 4 MiB: the file then passes the checksum and reaches the deeper
/// checks (a crafted file, not a damaged one).
fn rechecksum(b: &mut Vec<u8>) -> bool {
    use xxhash_rust::xxh3::{xxh3_64, Xxh3};
    if b.len() < 72 {
        return false;
    }
    let Some((lists, l, nb)) = implied_layout(b) else {
        return false;
    };
    let Some(total) = (72 + lists)
        .checked_add(l)
        .and_then(|v| v.checked_add(8 * nb + 8))
    else {
        return false;
    };
    if total > 4 << 20 {
        return false;
    }
    b.resize(total as usize, 0);
    let batch = u32::from_le_bytes(b[28..32].try_into().unwrap()).max(1) as u64;
    let lr = u32::from_le_bytes(b[60..64].try_into().unwrap()) as u64;
    let c0 = u32::from_le_bytes(b[48..52].try_into().unwrap()) as u64;
    let c1 = u32::from_le_bytes(b[52..56].try_into().unwrap()) as u64;
    let data = 72 + lists as usize;
    let table = data + l as usize;
    for i in 0..nb as usize {
        let first = c0 + i as u64 * batch;
        let n = (c1 - first).min(batch) * 72 * lr;
        let s = data + 72 * lr as usize * i * batch as usize;
        let sum = xxh3_64(&b[s..s + n as usize]);
        b[table + 8 * i..table + 8 * i + 8].copy_from_slice(&sum.to_le_bytes());
    }
    let mut h = Xxh3::new();
    h.update(&b[..data]);
    h.update(&b[table..table + 8 * nb as usize]);
    let end = table + 8 * nb as usize;
    b[end..end + 8].copy_from_slice(&h.digest().to_le_bytes());
    true
}

#[test]
fn fuzzed_cache_files_give_typed_errors_or_valid_loads_never_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let m = cube();
    let sel = Selection::default();
    let key = cache::key(&m, &sel);
    let full = dir.path().join("full.tfc");
    precompute_to_file(&m, &sel, &full, (1, 1), &mut |_, _| {}, &Default::default()).unwrap();
    let parts = shards(&m, &sel, dir.path(), 2);
    let originals = [
        std::fs::read(&full).unwrap(),
        std::fs::read(&parts[0]).unwrap(),
        std::fs::read(&parts[1]).unwrap(),
    ];
    let mut runner = crate::common::fuzz_runner(512);
    let counts = std::cell::RefCell::new(std::collections::BTreeMap::<String, usize>::new());
    let extremes = [
        0u64,
        1,
        2,
        63,
        64,
        65,
        1 << 31,
        u32::MAX as u64 - 1,
        u32::MAX as u64,
    ];
    let case = std::cell::Cell::new(0usize);
    runner
        .run(
            &(0usize..3, 0u8..5, proptest::prelude::any::<u64>()),
            |(which, kind, seed)| {
                case.set(case.get() + 1);
                let mut rng = Bits(seed | 1);
                let mut b = originals[which].clone();
                let crafted = match kind {
                    // Bits flipped anywhere.
                    0 => {
                        for _ in 0..1 + rng.below(8) {
                            let i = rng.below(b.len());
                            b[i] ^= 1 << rng.below(8);
                        }
                        false
                    }
                    // A header field set to a random or extreme value (checksum left stale).
                    1 | 2 => {
                        let o = 8 + 4 * rng.below(16);
                        let v = if rng.below(2) == 0 {
                            extremes[rng.below(extremes.len())]
                        } else {
                            rng.next()
                        };
                        if o == 32 || o == 64 {
                            b[o..o + 8].copy_from_slice(&v.to_le_bytes());
                        } else {
                            b[o..o + 4].copy_from_slice(&(v as u32).to_le_bytes());
                        }
                        // Half of them with length and checksums made to match: crafted.
                        kind == 2 && rechecksum(&mut b)
                    }
                    // Cut at a random length.
                    3 => {
                        b.truncate(rng.below(b.len()));
                        false
                    }
                    // Random list entries or L values, re-checksummed.
                    _ => {
                        for _ in 0..1 + rng.below(4) {
                            let i = 72 + rng.below(b.len() - 80);
                            b[i] = rng.next() as u8;
                        }
                        rechecksum(&mut b)
                    }
                };
                let p = dir.path().join(format!("fuzz{}.tfc", case.get()));
                std::fs::write(&p, &b).unwrap();
                let out = dir.path().join(format!("fuzz{}.merged.tfc", case.get()));
                let other = if which == 1 { &parts[1] } else { &parts[0] };
                let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    [
                        cache::load(&p, key, 125).map(|_| ()),
                        cache::load_near(&p, key, 125, &m.surface).map(|_| ()),
                        cache::merge(&[p.clone(), other.clone()], &out).map(|_| ()),
                    ]
                }));
                let Ok(results) = outcome else {
                    return Err(proptest::test_runner::TestCaseError::fail(format!(
                        "panic on case {} (file {which}, mutation {kind})",
                        case.get()
                    )));
                };
                let mut c = counts.borrow_mut();
                for (entry, r) in ["load", "load_near", "merge"].iter().zip(results) {
                    let tag = match r {
                        Ok(()) => "ok".to_string(),
                        Err(e) => format!("{e:?}")
                            .split([' ', '{'])
                            .next()
                            .unwrap()
                            .to_string(),
                    };
                    *c.entry(format!("{entry} {tag}")).or_default() += 1;
                }
                *c.entry(format!("crafted {crafted}")).or_default() += 1;
                let _ = std::fs::remove_file(&p);
                let _ = std::fs::remove_file(&out);
                Ok(())
            },
        )
        .unwrap();
    eprintln!(
        "cache fuzz: {} cases, outcomes {:?}",
        case.get(),
        counts.borrow()
    );
    assert_eq!(case.get(), 512);
}

/// A dense file is the documented layout, byte for byte, rebuilt here from the format's
/// description alone (header fields at their offsets, the lists, `L`'s f64 bytes, one xxh3 per
/// batch, the checksum): what the format module writes cannot drift from the description.
/// The one precompute call writes it under its key and file name.
#[test]
fn a_dense_file_is_the_documented_layout_byte_for_byte() {
    use touchfem::precompute::{precompute, Destination, Job};
    use xxhash_rust::xxh3::{xxh3_64, Xxh3};
    let dir = tempfile::tempdir().unwrap();
    let m = cube();
    let sel = Selection::default();
    let job = Job {
        name: "the cube",
        mesh: &m,
        selection: &sel,
        compression: None,
        shard: (1, 1),
        out: Destination::Dir(dir.path()),
    };
    let key = cache::key(&m, &sel);
    let done = precompute(&job, &mut |_, _| {}, &Default::default()).unwrap();
    assert_eq!(done.key, key);
    assert_eq!(job.key(), key);
    assert!(done.hier().is_none());
    let file = dir.path().join(format!("the_cube-{key:016x}.tfc"));
    assert_eq!(done.report.file, file);
    let bytes = std::fs::read(&file).unwrap();
    assert_eq!(done.report.bytes as usize, bytes.len());
    let c = cache::load(&file, key, m.nodes.len()).unwrap();
    let (nr, nc, lr) = (c.rows().len(), c.cols().len(), c.l_rows());
    let batch = cache::Part::open(&file).unwrap().head.batch as usize;
    let mut want = b"TFEMCMP\0".to_vec();
    for v in [3u32, 8, 125, nr as u32, nc as u32, batch as u32] {
        want.extend_from_slice(&v.to_le_bytes());
    }
    want.extend_from_slice(&key.to_le_bytes());
    let free = c.stats.free_dofs as u32;
    for v in [1u32, 1, 0, nc as u32, free, lr as u32] {
        want.extend_from_slice(&v.to_le_bytes());
    }
    want.extend_from_slice(&c.stats.residual.to_bits().to_le_bytes());
    assert_eq!(want.len(), 72);
    for &v in c.rows().iter().chain(c.cols()) {
        want.extend_from_slice(&v.to_le_bytes());
    }
    let head_and_lists = want.len();
    let l: Vec<u8> = c.l_f64().iter().flat_map(|v| v.to_le_bytes()).collect();
    assert_eq!(l.len(), 72 * lr * nc);
    want.extend_from_slice(&l);
    let sums: Vec<u8> = l
        .chunks(72 * lr * batch)
        .flat_map(|b| xxh3_64(b).to_le_bytes())
        .collect();
    want.extend_from_slice(&sums);
    let mut h = Xxh3::new();
    h.update(&want[..head_and_lists]);
    h.update(&sums);
    want.extend_from_slice(&h.digest().to_le_bytes());
    assert_eq!(bytes.len(), want.len());
    assert!(bytes == want, "the file differs from the documented layout");
    // From bytes in memory, the same compliance; and written to bytes in memory (the web
    // page's worker), the file byte for byte.
    let back = cache::load_bytes(&bytes, key, m.nodes.len()).unwrap();
    assert_eq!(back.l_f64(), c.l_f64());
    let mem = cache::to_bytes(&c, key, m.nodes.len()).unwrap();
    assert!(mem == bytes, "to_bytes differs from the file");
    // A shard of the one call gets the part suffix.
    let job = Job {
        shard: (2, 3),
        ..job
    };
    let done = precompute(&job, &mut |_, _| {}, &Default::default()).unwrap();
    assert_eq!(
        done.report.file,
        dir.path()
            .join(format!("the_cube-{key:016x}.tfc.part-2-of-3"))
    );
}
