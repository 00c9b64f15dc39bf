//! The compressed cache format (version 4): a hierarchical compliance saved and
//! loaded bit for bit, shards merged byte for byte, and every kind of hostile file refused
//! with a typed error.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use glam::DVec3;
use touchfem::cache::{self, hier, CacheError, CacheOutcome};
use touchfem::compliance::hmatrix::HOptions;
use touchfem::compliance::{shard_panels, Compliance, HierParts, Selection};
use touchfem::fem::FactorStore;
use touchfem::precompute::precompute_to_file_with;
use touchfem::Mesh;
use xxhash_rust::xxh3::xxh3_64;

const EPS: f64 = 1e-3;

fn opts() -> HOptions {
    HOptions {
        panel_size: 128,
        ..HOptions::new(EPS)
    }
}

/// The mouse's hierarchical parts (every panel), computed once, the complete file written from
/// them, and its three shards as the sharded precompute writes them (each its own run).
struct Fixture {
    mesh: Mesh,
    parts: HierParts,
    key: u64,
    _dir: tempfile::TempDir,
    full: PathBuf,
    shards: Vec<PathBuf>,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let mesh = touchfem::mesh::mouse();
        let sel = Selection::default();
        let parts = Compliance::compute_hier_parts(
            &mesh,
            &sel,
            touchfem::compliance::method(),
            &FactorStore::Heap,
            &opts(),
            (1, 1),
            &mut |_, _| {},
        )
        .expect("mouse parts");
        let key = cache::key_hier(&mesh, &sel, &opts());
        let dir = tempfile::tempdir().expect("temp dir");
        let n = mesh.nodes.len();
        let full = dir.path().join("mouse.tfc");
        hier::write_parts(&full, &parts, key, n, (1, 1)).expect("complete file");
        let shards = (1..=3)
            .map(|i| {
                let p = dir.path().join(format!("mouse.part-{i}-of-3"));
                let r = precompute_to_file_with(
                    &mesh,
                    &sel,
                    Some(&opts()),
                    &p,
                    (i, 3),
                    &mut |_, _| {},
                    &Default::default(),
                )
                .expect("shard");
                let want = shard_panels(parts.plan.panels(), i, 3);
                assert_eq!(r.panels, Some([want.start, want.end, parts.plan.panels()]));
                assert_eq!(r.tolerance, Some(EPS));
                assert_eq!(r.bytes, std::fs::metadata(&p).unwrap().len());
                p
            })
            .collect();
        Fixture {
            mesh,
            parts,
            key,
            _dir: dir,
            full,
            shards,
        }
    })
}

/// A small compressed file for the hostile-file checks: the cube with leaves of 8 nodes and
/// panels of 32 (several panels), precomputed once.
struct Small {
    _dir: tempfile::TempDir,
    path: PathBuf,
    key: u64,
    nodes: usize,
    rows: usize,
    cols: usize,
    l_rows: usize,
    panels: usize,
}

/// The compression options the small cube's file is made with.
fn small_options() -> HOptions {
    HOptions {
        leaf_size: 8,
        panel_size: 32,
        ..HOptions::new(EPS)
    }
}

fn small() -> &'static Small {
    static S: OnceLock<Small> = OnceLock::new();
    S.get_or_init(|| {
        let m = touchfem::mesh::cube();
        let sel = Selection::default();
        let o = small_options();
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("cube.tfc");
        precompute_to_file_with(
            &m,
            &sel,
            Some(&o),
            &path,
            (1, 1),
            &mut |_, _| {},
            &Default::default(),
        )
        .expect("cube file");
        let c = cache::load(&path, cache::key_hier(&m, &sel, &o), m.nodes.len()).expect("loads");
        Small {
            _dir: dir,
            path,
            key: cache::key_hier(&m, &sel, &o),
            nodes: m.nodes.len(),
            rows: c.rows().len(),
            cols: c.cols().len(),
            l_rows: c.l_rows(),
            panels: c.hier().unwrap().panels(),
        }
    })
}

/// A few point loads over the columns: one, two, and many at once.
fn loads(cols: usize) -> Vec<Vec<(u32, DVec3)>> {
    let f = |c: usize, k: f64| (c as u32, DVec3::new(0.3 * k, -1.0, 0.7 - 0.1 * k));
    vec![
        vec![f(0, 1.0)],
        vec![f(cols / 2, 2.0), f(cols - 1, -1.5)],
        (0..cols)
            .step_by(37)
            .map(|c| f(c, c as f64 * 0.01))
            .collect(),
    ]
}

/// The exact bytes of `u = L·F` for each of [`loads`].
fn products(c: &Compliance) -> Vec<Vec<u64>> {
    loads(c.cols().len())
        .iter()
        .map(|f| {
            let mut out = vec![DVec3::splat(f64::NAN); c.rows().len()];
            c.displace(f, &mut out);
            out.iter()
                .flat_map(|v| v.to_array().map(f64::to_bits))
                .collect()
        })
        .collect()
}

/// Whether two files' bytes are equal; on a difference, where (never the bytes themselves).
fn same_bytes(a: &Path, b: &Path) {
    let (x, y) = (std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
    let first = x.iter().zip(&y).position(|(p, q)| p != q);
    assert!(
        x.len() == y.len() && first.is_none(),
        "{} ({} B) and {} ({} B) differ first at byte {first:?}",
        a.display(),
        x.len(),
        b.display(),
        y.len()
    );
}

fn tmp(name: &str) -> (tempfile::TempDir, PathBuf) {
    let d = tempfile::tempdir().expect("temp dir");
    let p = d.path().join(name);
    (d, p)
}

/// `touchfem precompute OBJECT --tolerance 1e-3 --out FILE` (asserted to succeed) into a
/// temporary folder: the folder and FILE.
fn cli_compressed(object: &str) -> (tempfile::TempDir, PathBuf) {
    let (dir, file) = tmp(&format!("{object}.tfc"));
    let f = file.to_str().unwrap();
    let (code, _, err) =
        crate::common::touchfem_status(&["precompute", object, "--tolerance", "1e-3", "--out", f]);
    assert_eq!(code, 0, "{err}");
    (dir, file)
}

/// Re-seals the header checksum and the file checksum after an edit of the header (so that a
/// crafted header passes both).
fn seal(b: &mut [u8]) {
    let s = xxh3_64(&b[..96]);
    b[96..104].copy_from_slice(&s.to_le_bytes());
    let n = b.len() - 8;
    let s = xxh3_64(&b[..n]);
    b[n..].copy_from_slice(&s.to_le_bytes());
}

fn load(p: &Path, f: &Fixture) -> Result<Compliance, CacheError> {
    cache::load(p, f.key, f.mesh.nodes.len())
}

/// Saved and loaded, a hierarchical compliance is the same bit for bit: `u = L·F` for several
/// loads, `L_ii⁻¹`, the stored values; `save` writes what the precompute writes.
#[test]
fn round_trip_is_bitwise() {
    let f = fixture();
    let n = f.mesh.nodes.len();
    let c = Compliance::from_hier_parts(f.parts.clone(), n).expect("compliance");
    let back = load(&f.full, f).expect("loads");
    let h = back.hier().expect("a hierarchical compliance");
    assert_eq!(h.options(), &opts());
    assert_eq!(
        h.values().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        c.hier()
            .unwrap()
            .values()
            .iter()
            .map(|v| v.to_bits())
            .collect::<Vec<_>>()
    );
    assert_eq!(products(&back), products(&c));
    assert!(products(&c)[2].iter().any(|&b| f64::from_bits(b) != 0.0));
    for j in [0, 100, c.cols().len() - 1] {
        assert_eq!(back.diag_inv(j), c.diag_inv(j));
    }
    assert_eq!(back.rows(), c.rows());
    assert_eq!(back.cols(), c.cols());
    assert_eq!(back.l_rows(), c.l_rows());
    assert_eq!(back.stats.residual.to_bits(), c.stats.residual.to_bits());
    assert_eq!(back.stats.free_dofs, c.stats.free_dofs);
    assert_eq!(h.truncation_error(), c.hier().unwrap().truncation_error());
    // save() of the compliance writes the precompute's file, byte for byte; so does a save
    // of the loaded one.
    let (_d, saved) = tmp("saved.tfc");
    cache::save(&saved, &c, f.key, n).expect("saves");
    same_bytes(&saved, &f.full);
    cache::save(&saved, &back, f.key, n).expect("saves again");
    same_bytes(&saved, &f.full);
    let full = std::fs::read(&f.full).unwrap();
    // The numbers: panels, and the file against the dense one (format 3) of the same L.
    let (r, lr, cc) = (c.rows().len(), c.l_rows(), c.cols().len());
    let dense = 72 + 4 * (r + cc) + 72 * lr * cc + 8 * cc.div_ceil(64) + 8;
    eprintln!(
        "mouse at {EPS:e}, panels of 128: {} panels, {} blocks, compressed file {} B, dense file {dense} B ({:.3})",
        h.panels(),
        h.blocks().count(),
        full.len(),
        full.len() as f64 / dense as f64
    );
    assert!(h.panels() >= 8, "{} panels", h.panels());
    assert!(
        full.len() * 2 < dense,
        "{} B compressed, {dense} B dense",
        full.len()
    );
}

/// Shards 1..3 of 3, each from its own precompute run, merge (in any order) into the complete
/// file of one run, byte for byte.
#[test]
fn shards_merge_byte_equal_to_the_whole() {
    let f = fixture();
    let full = std::fs::read(&f.full).unwrap();
    let (_d, out) = tmp("merged.tfc");
    let order = [
        f.shards[2].clone(),
        f.shards[0].clone(),
        f.shards[1].clone(),
    ];
    let m = cache::merge(&order, &out).expect("merges");
    same_bytes(&out, &f.full);
    assert_eq!(m.bytes, full.len() as u64);
    assert_eq!(m.tolerance, Some(EPS));
    assert_eq!((m.rows, m.cols), (f.parts.rows.len(), f.parts.cols.len()));
    // Every shard holds panels; a shard is not a complete file.
    for (i, s) in f.shards.iter().enumerate() {
        let h = hier::header(s).expect("header");
        assert!(h.panel_end > h.panel_begin, "shard {} is empty", i + 1);
        assert!(matches!(
            load(s, f),
            Err(CacheError::Partial { index, count: 3, .. }) if index as usize == i + 1
        ));
    }
}

/// Merges that must be refused: a missing part, a repeated one, parts of other options, a
/// dense part among compressed ones, no parts.
#[test]
fn mismatched_merges_are_refused() {
    let f = fixture();
    let (_d, out) = tmp("merged.tfc");
    let mismatch = |r: Result<cache::MergeInfo, CacheError>, what: &str| {
        assert!(
            matches!(r, Err(CacheError::Mismatch { .. })),
            "{what}: {r:?}"
        );
    };
    mismatch(cache::merge(&f.shards[..2], &out), "two of three");
    mismatch(
        cache::merge(
            &[
                f.shards[0].clone(),
                f.shards[1].clone(),
                f.shards[1].clone(),
            ],
            &out,
        ),
        "part 2 twice",
    );
    // Part 3 with its header edited (and resealed): refused as `what`.
    let (_e, other) = tmp("other.tfc");
    let edited_part_3 = |edit: &dyn Fn(&mut Vec<u8>), what: &str| {
        let mut b = std::fs::read(&f.shards[2]).unwrap();
        edit(&mut b);
        seal(&mut b);
        std::fs::write(&other, &b).unwrap();
        mismatch(
            cache::merge(
                &[f.shards[0].clone(), f.shards[1].clone(), other.clone()],
                &out,
            ),
            what,
        );
    };
    // Made with another tolerance (and so another key).
    edited_part_3(
        &|b| b[64..72].copy_from_slice(&1e-2f64.to_bits().to_le_bytes()),
        "another tolerance",
    );
    edited_part_3(&|b| b[32] ^= 1, "another key");
    // The complete file given as a part of three.
    mismatch(
        cache::merge(
            &[f.shards[0].clone(), f.shards[1].clone(), f.full.clone()],
            &out,
        ),
        "a complete file among parts",
    );
    mismatch(cache::merge(&[], &out), "no parts");
    // A dense (version 3) part: a typed error either way round.
    let (_g, dense) = tmp("dense.tfc");
    let cube = touchfem::mesh::cube();
    let sel = Selection::default();
    let c = Compliance::compute(&cube, &sel).unwrap();
    cache::save(&dense, &c, cache::key(&cube, &sel), cube.nodes.len()).unwrap();
    let r = cache::merge(&[f.shards[0].clone(), dense.clone()], &out);
    assert!(matches!(r, Err(CacheError::Format { .. })), "{r:?}");
    let r = cache::merge(&[dense.clone(), f.shards[0].clone()], &out);
    assert!(matches!(r, Err(CacheError::Format { .. })), "{r:?}");
    assert!(!out.exists(), "a refused merge writes nothing");
}

/// The hierarchical key differs from the dense one and from that of any other option; a file
/// is stale for the other kind's key; load_or_compute_with loads what it saved.
#[test]
fn keys_tell_the_kinds_and_options_apart() {
    let f = fixture();
    let sel = Selection::default();
    let m = &f.mesh;
    let dense = cache::key(m, &sel);
    let o = opts();
    let keys = [
        cache::key_hier(m, &sel, &o),
        cache::key_hier(
            m,
            &sel,
            &HOptions {
                tolerance: 1e-4,
                ..o
            },
        ),
        cache::key_hier(m, &sel, &HOptions { eta: 1.0, ..o }),
        cache::key_hier(m, &sel, &HOptions { leaf_size: 16, ..o }),
        cache::key_hier(
            m,
            &sel,
            &HOptions {
                panel_size: 256,
                ..o
            },
        ),
    ];
    for (i, a) in keys.iter().enumerate() {
        assert_ne!(*a, dense);
        for b in &keys[i + 1..] {
            assert_ne!(a, b);
        }
    }
    assert_eq!(keys[0], f.key);
    // The compressed file under the dense key, another option's key or another node count.
    assert!(matches!(
        cache::load(&f.full, dense, m.nodes.len()),
        Err(CacheError::Stale { .. })
    ));
    assert!(matches!(
        cache::load(&f.full, keys[1], m.nodes.len()),
        Err(CacheError::Stale { .. })
    ));
    assert!(matches!(
        cache::load_near(&f.full, dense, m.nodes.len(), &m.surface),
        Err(CacheError::Stale { .. })
    ));
    assert!(cache::load_near(&f.full, f.key, m.nodes.len(), &m.surface)
        .unwrap()
        .hier()
        .is_some());
    // A dense file under a hierarchical key; load_or_compute_with on the cube, both kinds.
    let cube = touchfem::mesh::cube();
    let (_d, p) = tmp("cube.tfc");
    let (c0, o0) = cache::load_or_compute(&p, &cube, &sel).unwrap();
    assert!(matches!(
        o0,
        CacheOutcome::Recomputed(CacheError::Io { .. })
    ));
    assert!(c0.hier().is_none());
    let small = HOptions::new(EPS);
    let hk = cache::key_hier(&cube, &sel, &small);
    assert!(matches!(
        cache::load(&p, hk, cube.nodes.len()),
        Err(CacheError::Stale { .. })
    ));
    // A dense file where a compressed one is asked for: recomputed, the note saying so.
    let (c1, o1) = cache::load_or_compute_with(&p, &cube, &sel, Some(&small)).unwrap();
    assert!(
        matches!(
            o1,
            CacheOutcome::Recomputed(CacheError::Compression {
                found: None,
                asked: Some(_),
                ..
            })
        ),
        "{o1:?}"
    );
    assert!(
        o1.message()
            .unwrap()
            .contains("is dense, but one compressed to tolerance 1e-3"),
        "{o1:?}"
    );
    assert!(c1.hier().is_some());
    assert!(hier::is_compressed(&p));
    let (c2, o2) = cache::load_or_compute_with(&p, &cube, &sel, Some(&small)).unwrap();
    assert!(matches!(o2, CacheOutcome::Hit), "{o2:?}");
    assert_eq!(products(&c1), products(&c2));
    // Asked for the dense L again: the compressed file is stale, and is replaced.
    let (c3, o3) = cache::load_or_compute_with(&p, &cube, &sel, None).unwrap();
    assert!(
        matches!(
            o3,
            CacheOutcome::Recomputed(CacheError::Compression {
                found: Some(_),
                asked: None,
                ..
            })
        ),
        "{o3:?}"
    );
    assert_eq!(c3.l_f64(), c0.l_f64());
    assert!(!hier::is_compressed(&p));
    // Bad options are a typed error, not a panic.
    let bad = HOptions {
        tolerance: 2.0,
        ..small
    };
    assert!(cache::load_or_compute_with(&p, &cube, &sel, Some(&bad)).is_err());
}

/// Every kind of hostile file is a typed error: truncation at each header field and in each
/// section, a flipped byte anywhere, crafted counts that would ask for huge allocations, and
/// headers whose sizes contradict each other.
#[test]
fn hostile_files_are_typed_errors() {
    let f = small();
    assert!(f.panels >= 3, "{} panels", f.panels);
    let good = std::fs::read(&f.path).unwrap();
    let (_d, p) = tmp("bad.tfc");
    let try_load = |b: &[u8]| {
        std::fs::write(&p, b).unwrap();
        cache::load(&p, f.key, f.nodes)
    };
    let (r, c, lr) = (f.rows, f.cols, f.l_rows);
    let lists_end = 104 + 4 * (r + c) + 24 * (lr + c) + 8;
    // Truncated at every header field, and inside each later section.
    let mut cuts = vec![
        0, 4, 8, 10, 12, 16, 20, 24, 28, 32, 36, 40, 44, 48, 52, 56, 60, 64, 72, 80, 84, 88, 96,
        100, 103, 104,
    ];
    cuts.extend([
        104 + 4 * r,
        lists_end - 9,
        lists_end - 1,
        lists_end,
        lists_end + 20,
        lists_end + 40,
        good.len() / 2,
        good.len() - 9,
        good.len() - 8,
        good.len() - 1,
    ]);
    for cut in cuts {
        let e = try_load(&good[..cut]);
        assert!(
            matches!(e, Err(CacheError::Truncated { .. })),
            "cut at {cut}: {e:?}"
        );
    }
    // A byte after the checksum.
    let mut b = good.clone();
    b.push(0);
    assert!(matches!(try_load(&b), Err(CacheError::Corrupt { .. })));
    // A flipped byte in the header (after magic and version), the lists, the points, a
    // panel's head, ranks and values, a panel's checksum, the file checksum.
    let panel0 = lists_end;
    let blocks0 = u32::from_le_bytes(good[panel0 + 4..panel0 + 8].try_into().unwrap()) as usize;
    let mut at = vec![
        16,
        28,
        33,
        50,
        66,
        90,
        97,
        104 + 2,
        104 + 4 * r + 1,
        104 + 4 * (r + c) + 5,
        104 + 4 * (r + c) + 24 * lr + 7,
        lists_end - 3,
    ];
    at.extend([
        panel0,
        panel0 + 5,
        panel0 + 9,
        panel0 + 17,
        panel0 + 25,
        panel0 + 32 + 4 * blocks0 / 2,
        panel0 + 32 + 4 * blocks0 + 8 * 10,
        good.len() / 2,
        good.len() - 12,
        good.len() - 3,
    ]);
    for pos in at {
        for bit in [0x01, 0x80] {
            let mut b = good.clone();
            b[pos] ^= bit;
            let e = try_load(&b);
            assert!(
                matches!(
                    e,
                    Err(CacheError::Corrupt { .. }) | Err(CacheError::Truncated { .. })
                ),
                "byte {pos} ^ {bit:#x}: {e:?}"
            );
            // A flipped count in a panel's head may point past the end: truncated.
            if pos >= 104 && ![panel0 + 5, panel0 + 9].contains(&pos) {
                assert!(
                    matches!(e, Err(CacheError::Corrupt { .. })),
                    "byte {pos}: {e:?}"
                );
            }
        }
    }
    // Not a cache; another version; another precision.
    let mut b = good.clone();
    b[0] = b'X';
    assert!(matches!(try_load(&b), Err(CacheError::Format { .. })));
    let mut b = good.clone();
    b[8..12].copy_from_slice(&5u32.to_le_bytes());
    assert!(matches!(try_load(&b), Err(CacheError::Format { .. })));
    let mut b = good.clone();
    b[12..16].copy_from_slice(&4u32.to_le_bytes());
    seal(&mut b);
    assert!(matches!(try_load(&b), Err(CacheError::Format { .. })));
    // Crafted headers with a valid checksum: huge counts are bounded by the file's length
    // before anything is allocated; contradictory sizes and options are corrupt.
    let crafted = |edits: &[(usize, &[u8])]| {
        let mut b = good.clone();
        for (o, v) in edits {
            b[*o..*o + v.len()].copy_from_slice(v);
        }
        seal(&mut b);
        try_load(&b)
    };
    let max = u32::MAX.to_le_bytes();
    for (what, edits) in [
        ("rows", vec![(20, &max[..])]),
        ("cols", vec![(24, &max[..])]),
        ("rows and held rows", vec![(20, &max[..]), (28, &max[..])]),
        ("panels", vec![(48, &max[..]), (56, &max[..])]),
    ] {
        let e = crafted(&edits);
        assert!(
            matches!(e, Err(CacheError::Truncated { .. })),
            "huge {what}: {e:?}"
        );
    }
    for (what, edits) in [
        (
            "held rows > rows",
            vec![(28, &(r as u32 + 1).to_le_bytes()[..])],
        ),
        ("part 0", vec![(40, &0u32.to_le_bytes()[..])]),
        ("part 2 of 1", vec![(40, &2u32.to_le_bytes()[..])]),
        ("panel end > panels", vec![(56, &max[..])]),
        ("panel begin > end", vec![(52, &max[..])]),
        (
            "NaN tolerance",
            vec![(64, &f64::NAN.to_bits().to_le_bytes()[..])],
        ),
        ("tolerance 1", vec![(64, &1f64.to_bits().to_le_bytes()[..])]),
        ("eta 0", vec![(72, &0f64.to_bits().to_le_bytes()[..])]),
        ("leaf 0", vec![(80, &0u32.to_le_bytes()[..])]),
        ("panel < leaf", vec![(84, &1u32.to_le_bytes()[..])]),
    ] {
        let e = crafted(&edits);
        assert!(
            matches!(e, Err(CacheError::Corrupt { .. })),
            "{what}: {e:?}"
        );
    }
    // A panel whose counts are huge (its checksum follows them, so the bound is what stops
    // it): 2^61 values, 2^32 − 1 blocks, a value count whose byte count overflows.
    for (o, v) in [
        (panel0 + 8, (1u64 << 61).to_le_bytes().to_vec()),
        (panel0 + 4, max.to_vec()),
        (panel0 + 8, u64::MAX.to_le_bytes().to_vec()),
    ] {
        let mut b = good.clone();
        b[o..o + v.len()].copy_from_slice(&v);
        let e = try_load(&b);
        assert!(
            matches!(
                e,
                Err(CacheError::Truncated { .. }) | Err(CacheError::Corrupt { .. })
            ),
            "panel count at {o}: {e:?}"
        );
    }
    // Well-formed headers whose options do not fit the panels (the plan rebuilt from the
    // points differs): every checksum right, still refused.
    for (what, edits) in [
        ("leaf 16", vec![(80, &16u32.to_le_bytes()[..])]),
        ("eta 1", vec![(72, &1f64.to_bits().to_le_bytes()[..])]),
        ("panel 256", vec![(84, &256u32.to_le_bytes()[..])]),
    ] {
        let e = crafted(&edits);
        assert!(matches!(e, Err(CacheError::Format { .. })), "{what}: {e:?}");
    }
    // The good file still loads (nothing above touched it).
    assert!(cache::load(&f.path, f.key, f.nodes).is_ok());
}

fn run(args: &[String]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(args)
        .output()
        .expect("runs")
}

fn ok_json(o: &std::process::Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).expect("one JSON object")
}

/// `touchfem precompute --tolerance EPS`: the JSON's `tolerance` (null when dense), a file the
/// library loads under `key_hier`, and `--shard`/`--merge` byte-equal to the unsharded file;
/// bad tolerances are clear errors.
#[test]
fn cli_precompute_with_a_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    let args = |extra: &[&str]| -> Vec<String> {
        ["precompute", "mouse", "--tolerance", "1e-3", "--json"]
            .iter()
            .chain(extra)
            .map(|s| s.to_string())
            .collect()
    };
    // The unsharded file and both shards at once (separate processes).
    let runs = [
        args(&["--out", &d("full.tfc")]),
        args(&["--shard", "1/2", "--out", &d("p1.tfc")]),
        args(&["--shard", "2/2", "--out", &d("p2.tfc")]),
    ];
    let outs: Vec<_> = std::thread::scope(|s| {
        let hs: Vec<_> = runs.iter().map(|a| s.spawn(move || run(a))).collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let v = ok_json(&outs[0]);
    assert_eq!(v["tolerance"].as_f64(), Some(1e-3));
    assert_eq!(v["objects"][0]["tolerance"].as_f64(), Some(1e-3));
    // What the GPU holds: measured 6 853 164 B against 38 118 276 B dense f32 (0.180; both
    // triangles were 12 766 756 B, 0.335).
    let (gb, db) = (
        v["gpu_bytes"].as_f64().unwrap(),
        v["dense_gpu_bytes"].as_f64().unwrap(),
    );
    assert_eq!(db, 4.0 * 9.0 * 1029.0 * 1029.0);
    assert!(gb > 0.12 * db && gb < 0.24 * db, "gpu {gb} of {db}");
    let full = Path::new(&d("full.tfc")).to_path_buf();
    let len = std::fs::metadata(&full).unwrap().len();
    assert_eq!(v["bytes"].as_u64(), Some(len));
    let panels = v["objects"][0]["panels"][2].as_u64().unwrap();
    assert!(panels >= 2, "{panels} panels");
    for (i, o) in outs[1..].iter().enumerate() {
        let v = ok_json(o);
        assert_eq!(v["shard"], serde_json::json!([i + 1, 2]));
        assert_eq!(v["tolerance"].as_f64(), Some(1e-3));
    }
    // The library reads it under the hierarchical key of the default options.
    let m = touchfem::mesh::mouse();
    let sel = Selection::default();
    let k = cache::key_hier(&m, &sel, &HOptions::new(1e-3));
    let c = cache::load(&full, k, m.nodes.len()).expect("loads");
    assert!(c.hier().is_some());
    assert_eq!(v["rows"].as_u64(), Some(c.rows().len() as u64));
    assert_eq!(v["cols"].as_u64(), Some(c.cols().len() as u64));
    // Merged (parts in any order): byte for byte the unsharded file.
    let o = run(&[
        "precompute".into(),
        "--merge".into(),
        d("p2.tfc"),
        d("p1.tfc"),
        "--out".into(),
        d("merged.tfc"),
        "--json".into(),
    ]);
    let v = ok_json(&o);
    assert_eq!(v["tolerance"].as_f64(), Some(1e-3));
    assert_eq!(v["bytes"].as_u64(), Some(len));
    same_bytes(Path::new(&d("merged.tfc")), &full);
    // Dense: `tolerance` is null.
    let o = run(&[
        "precompute".into(),
        "cube".into(),
        "--out".into(),
        d("cube.tfc"),
        "--json".into(),
    ]);
    let v = ok_json(&o);
    assert!(v["tolerance"].is_null(), "{v}");
    assert!(v["objects"][0]["tolerance"].is_null(), "{v}");
    // Bad tolerances: exit 2, the flag named, no panic.
    for bad in ["0", "1", "-1e-3", "nan", "abc", "1e400"] {
        let o = run(&[
            "precompute".into(),
            "cube".into(),
            "--tolerance".into(),
            bad.into(),
            "--out".into(),
            d("x.tfc"),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{bad}: {err}");
        assert!(err.contains("--tolerance"), "{bad}: {err}");
        assert!(!err.contains("panicked"), "{bad}: {err}");
    }
}

/// `poke --cache FILE` reads a compressed file as it reads a dense one (no recompute, its
/// tolerance reported), and the force equals the dense poke's: the haptic path reads exact
/// near blocks.
#[test]
fn poke_reads_a_compressed_cache() {
    use crate::common::touchfem_status;
    let (_dir, file) = cli_compressed("mouse");
    let f = file.to_str().unwrap();
    let poke = [
        "poke", "mouse", "--at", "0,0,100", "--push", "0,0,-5", "--json",
    ];
    let (code, out, err) = touchfem_status(&[&poke[..], &["--cache", f]].concat());
    assert_eq!(code, 0, "{err}");
    assert!(
        !err.contains("recomputed"),
        "the compressed file was not used: {err}"
    );
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["precompute"]["tolerance"].as_f64(), Some(1e-3));
    let (code, out, err) = touchfem_status(&poke);
    assert_eq!(code, 0, "{err}");
    let d: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(d["precompute"]["tolerance"].is_null());
    for k in 0..3 {
        let (a, b) = (
            v["force"][k].as_f64().unwrap(),
            d["force"][k].as_f64().unwrap(),
        );
        assert!(
            (a - b).abs() <= 1e-12 * b.abs().max(1e-9),
            "force {k}: {a} vs {b}"
        );
    }
    assert!(d["force"][2].as_f64().unwrap() > 1e-3, "no contact");
}

/// A compressed file made for another tolerance is named so, with both tolerances (not "made
/// for another mesh, material or selection"); a header whose tolerance was changed, its
/// checksums fixed, is refused under the tolerance asked for though its key still matches,
/// and recomputed to that tolerance.
#[test]
fn another_or_a_crafted_tolerance_is_named_and_never_used() {
    let f = small();
    let m = touchfem::mesh::cube();
    let sel = Selection::default();
    let made = small_options();
    assert_eq!(cache::key_hier(&m, &sel, &made), f.key);
    // Another tolerance: its own error and message.
    let other = HOptions {
        tolerance: 1e-2,
        ..made
    };
    let e = cache::load_made_with(
        &f.path,
        cache::key_hier(&m, &sel, &other),
        f.nodes,
        Some(&other),
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            CacheError::Compression {
                found: Some(a),
                asked: Some(b),
                ..
            } if a.tolerance == EPS && b.tolerance == 1e-2
        ),
        "{e:?}"
    );
    let msg = e.to_string();
    assert!(
        msg.contains("was made for tolerance 1e-3, not 1e-2"),
        "{msg}"
    );
    assert!(!msg.contains("mesh"), "{msg}");
    // The crafted header: tolerance 0.999999, header and file checksums fixed.
    let mut b = std::fs::read(&f.path).unwrap();
    b[64..72].copy_from_slice(&0.999999f64.to_bits().to_le_bytes());
    seal(&mut b);
    let (_d, crafted) = tmp("crafted.tfc");
    std::fs::write(&crafted, &b).unwrap();
    assert_eq!(hier::header(&crafted).unwrap().opts.tolerance, 0.999999);
    // Its key still matches: the plain loader (key only) cannot tell; the options can.
    let e = cache::load_made_with(&crafted, f.key, f.nodes, Some(&made)).unwrap_err();
    assert!(
        e.to_string()
            .contains("was made for tolerance 9.99999e-1, not 1e-3"),
        "{e}"
    );
    let (c, o) = cache::load_or_compute_with(&crafted, &m, &sel, Some(&made)).unwrap();
    assert!(
        matches!(o, CacheOutcome::Recomputed(CacheError::Compression { .. })),
        "{o:?}"
    );
    assert_eq!(c.hier().unwrap().options().tolerance, EPS);
    assert_eq!(hier::header(&crafted).unwrap().opts.tolerance, EPS);
    // Rewritten to the tolerance asked for: the very bytes of the file it was crafted from.
    same_bytes(&crafted, &f.path);
    let (_, o) = cache::load_or_compute_with(&crafted, &m, &sel, Some(&made)).unwrap();
    assert!(matches!(o, CacheOutcome::Hit), "{o:?}");
}

/// A compressed file whose header is damaged (any one byte of it) is never rewritten dense
/// when no tolerance is asked for: [`cache::load_or_compute_file`] stops with
/// `CacheError::Unreadable` and leaves the file as it was; the same file asked for by its
/// tolerance is recomputed compressed.
#[test]
fn a_damaged_compressed_file_stays_compressed() {
    let f = small();
    let m = touchfem::mesh::cube();
    let sel = Selection::default();
    let good = std::fs::read(&f.path).unwrap();
    let (_d, p) = tmp("damaged.tfc");
    assert_eq!(
        cache::stored_compression(&f.path)
            .unwrap()
            .map(|o| o.tolerance),
        Some(EPS)
    );
    for at in 0..hier::HEADER {
        let mut b = good.clone();
        b[at] ^= 0x5a;
        std::fs::write(&p, &b).unwrap();
        let e = cache::load_or_compute_file(&p, &m, &sel, None).unwrap_err();
        assert!(
            matches!(e, CacheError::Unreadable { .. }),
            "byte {at}: {e:?}"
        );
        let msg = e.to_string();
        assert!(
            msg.contains("damaged.tfc") && msg.contains("not replaced by a dense one"),
            "byte {at}: {msg}"
        );
        assert_eq!(
            std::fs::read(&p).unwrap(),
            b,
            "byte {at}: the file was touched"
        );
    }
    // Asked for by its options, it is recomputed compressed (the same bytes as before).
    let made = small_options();
    let (c, o) = cache::load_or_compute_file(&p, &m, &sel, Some(&made)).unwrap();
    assert!(matches!(o, CacheOutcome::Recomputed(_)), "{o:?}");
    assert!(c.hier().is_some());
    same_bytes(&p, &f.path);
    // A dense file, a missing one and a file that is no cache at all go on as before.
    let (_e, q) = tmp("dense.tfc");
    assert!(cache::stored_compression(&q).unwrap().is_none());
    let (c, o) = cache::load_or_compute_file(&q, &m, &sel, None).unwrap();
    assert!(
        matches!(o, CacheOutcome::Recomputed(CacheError::Io { .. })),
        "{o:?}"
    );
    assert!(c.hier().is_none());
    assert!(cache::stored_compression(&q).unwrap().is_none());
    let (_, o) = cache::load_or_compute_file(&q, &m, &sel, None).unwrap();
    assert!(matches!(o, CacheOutcome::Hit), "{o:?}");
}

/// A cache reads from bytes in memory as from its file: both formats, the same compliance;
/// hostile bytes are the same typed errors.
#[test]
fn caches_load_from_bytes() {
    let f = small();
    let bytes = std::fs::read(&f.path).unwrap();
    let a = cache::load(&f.path, f.key, f.nodes).unwrap();
    let b = cache::load_bytes(&bytes, f.key, f.nodes).unwrap();
    assert_eq!(products(&a), products(&b));
    for cut in [0, 7, 50, 104, bytes.len() / 2, bytes.len() - 1] {
        assert!(matches!(
            cache::load_bytes(&bytes[..cut], f.key, f.nodes),
            Err(CacheError::Truncated { .. } | CacheError::Format { .. })
        ));
    }
    let m = touchfem::mesh::cube();
    let sel = Selection::default();
    let (_d, p) = tmp("dense.tfc");
    let c = Compliance::compute(&m, &sel).unwrap();
    let k = cache::key(&m, &sel);
    cache::save(&p, &c, k, m.nodes.len()).unwrap();
    let mut dense = std::fs::read(&p).unwrap();
    let back = cache::load_bytes(&dense, k, m.nodes.len()).unwrap();
    assert_eq!(back.l_f64(), c.l_f64());
    assert!(matches!(
        cache::load_bytes(&dense, k ^ 1, m.nodes.len()),
        Err(CacheError::Stale { .. })
    ));
    let mid = dense.len() / 2;
    dense[mid] ^= 1;
    let e = cache::load_bytes(&dense, k, m.nodes.len()).unwrap_err();
    assert!(matches!(e, CacheError::Corrupt { .. }), "{e:?}");
    assert!(e.to_string().contains("(bytes)"), "{e}");
}

/// The path on the command line: a compressed mouse cache with one header byte
/// damaged, `poke --cache` without `--tolerance`: exit 2 with one `error:` line, the file
/// untouched (not rewritten dense); with a crafted tolerance and `--tolerance 1e-3`, the
/// note names both tolerances and the poke reports 1e-3.
#[test]
fn cli_poke_keeps_a_damaged_compressed_cache_and_names_a_crafted_tolerance() {
    use crate::common::touchfem_status;
    let (_dir, file) = cli_compressed("cube");
    let f = file.to_str().unwrap();
    let good = std::fs::read(&file).unwrap();
    let poke = crate::common::poke_cube(&["--json", "--cache", f]);
    let mut b = good.clone();
    b[70] ^= 1;
    std::fs::write(&file, &b).unwrap();
    let (code, _, err) = touchfem_status(&poke);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.starts_with("error:") && err.trim_end().lines().count() == 1,
        "{err}"
    );
    assert!(err.contains("not replaced by a dense one"), "{err}");
    assert_eq!(
        std::fs::read(&file).unwrap(),
        b,
        "the damaged file was rewritten"
    );
    // The crafted tolerance under --tolerance 1e-3: recomputed, both tolerances named.
    let mut b = good.clone();
    b[64..72].copy_from_slice(&0.999999f64.to_bits().to_le_bytes());
    seal(&mut b);
    std::fs::write(&file, &b).unwrap();
    let (code, out, err) = touchfem_status(&[&poke[..], &["--tolerance", "1e-3"]].concat());
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("was made for tolerance 9.99999e-1, not 1e-3"),
        "{err}"
    );
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["precompute"]["tolerance"].as_f64(), Some(1e-3));
    assert!(
        std::fs::read(&file).unwrap() == good,
        "not rewritten as the precompute wrote it"
    );
}

/// The one precompute call, compressed: its key and file, and the hierarchical `L` it returns
/// is the one its file holds (what the GPU byte count is computed from, without reading the
/// file again); a shard returns none.
#[test]
fn the_precompute_call_returns_the_l_it_wrote() {
    use touchfem::precompute::{precompute, Destination, Job};
    let m = touchfem::mesh::cube();
    let sel = Selection::default();
    let o = small_options();
    let (_d, p) = tmp("job.tfc");
    let job = Job {
        name: "cube",
        mesh: &m,
        selection: &sel,
        compression: Some(o),
        shard: (1, 1),
        out: Destination::File(&p),
    };
    let done = precompute(&job, &mut |_, _| {}, &Default::default()).unwrap();
    assert_eq!(done.key, cache::key_hier(&m, &sel, &o));
    assert_eq!(done.report.file, p);
    assert_eq!(done.report.tolerance, Some(EPS));
    same_bytes(&p, &small().path);
    let h = done
        .hier()
        .expect("a complete compressed precompute returns its L");
    let c = cache::load(&p, done.key, m.nodes.len()).unwrap();
    let back = c.hier().unwrap();
    assert_eq!(h.panels(), back.panels());
    assert_eq!(h.dense_values(), back.dense_values());
    assert_eq!(h.stored_values(), back.stored_values());
    #[cfg(feature = "gpu")]
    assert_eq!(
        touchfem::gpu::hier_gpu_bytes(h, false),
        touchfem::gpu::hier_gpu_bytes(back, false)
    );
    for f in loads(c.cols().len()) {
        let mut a = vec![DVec3::ZERO; h.out_rows()];
        let mut b = vec![DVec3::ZERO; back.out_rows()];
        h.displace(&f, &mut a);
        back.displace(&f, &mut b);
        assert_eq!(a, b);
    }
    let shard = Job {
        shard: (1, 2),
        ..job
    };
    assert!(precompute(&shard, &mut |_, _| {}, &Default::default())
        .unwrap()
        .hier()
        .is_none());
}
