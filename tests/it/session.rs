//! Recorded sessions and the demo end to end: the committed session of a bundled scene replays
//! exactly (a regression check of the whole haptic path), a fresh recording replays to zero
//! difference, tampered and broken files are caught, and the demo's report, traces, plots, GIF
//! and cache behaviour.

use std::path::{Path, PathBuf};
use std::process::Command;
use touchfem::runtime::session;

fn touchfem(args: &[&str], envs: &[(&str, &str)]) -> (i32, String, String) {
    let mut c = Command::new(env!("CARGO_BIN_EXE_touchfem"));
    c.args(args).env(
        "WGPU_BACKEND",
        std::env::var("WGPU_BACKEND").unwrap_or("vulkan".into()),
    );
    for (k, v) in envs {
        c.env(k, v);
    }
    let o = c.output().unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn json(s: &str) -> serde_json::Value {
    serde_json::from_str(s.trim()).unwrap_or_else(|e| panic!("{e}: {s}"))
}

fn committed() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fig1.tfsession")
}

#[test]
fn the_committed_fig1_session_replays_exactly() {
    let (code, out, err) = touchfem(
        &["replay", committed().to_str().unwrap(), "--json"],
        &[("TOUCHFEM_CACHE_DIR", "")],
    );
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    assert_eq!(v["ticks"], 1000);
    // The whole haptic path (god-object, force model, saturation) against the recording.
    assert!(v["max_force_diff_n"].as_f64().unwrap() <= 1e-12, "{v}");
    // The recording presses the top and the side: a real force to compare.
    assert!(v["max_force_n"].as_f64().unwrap() > 0.3, "{v}");
}

#[test]
fn a_session_file_is_self_describing() {
    let s = session::read(&committed()).unwrap();
    let h = &s.header;
    assert_eq!((h.format.as_str(), h.version), ("touchfem-session", 1));
    assert_eq!((h.fingers, h.record_bytes, h.rate_hz), (1, 48, 1000.0));
    assert!(h.scene_toml.contains("[[finger]]") && h.layout.contains("position"));
    assert_eq!(h.scene_hash.len(), 16);
    assert_eq!(s.trailing_bytes, 0);
    // The fig1 path: starts 10 mm above the top, reaches 5 mm into it.
    let z: Vec<f64> = s.ticks.iter().map(|t| t.positions[0].z).collect();
    assert!((z[0] - 0.040).abs() < 1e-3);
    assert!(z.iter().cloned().fold(1.0, f64::min) < 0.0251);
}

#[test]
fn a_fresh_two_finger_recording_replays_to_zero_and_tampering_is_seen() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("pinch.tfsession");
    let out = dir.path().join("out");
    let (code, _, err) = touchfem(
        &[
            "demo",
            "pinch",
            "--seconds",
            "0.4",
            "--out",
            out.to_str().unwrap(),
            "--record",
            rec.to_str().unwrap(),
        ],
        &[("TOUCHFEM_CACHE_DIR", "")],
    );
    assert_eq!(code, 0, "{err}");
    // No cache on either side: a cache written by an older build holds the same compliance to
    // round-off, not to the bit.
    let (code, o, err) = touchfem(
        &["replay", rec.to_str().unwrap(), "--json"],
        &[("TOUCHFEM_CACHE_DIR", "")],
    );
    assert_eq!(code, 0, "{err}");
    let v = json(&o);
    assert_eq!(v["max_force_diff_n"].as_f64(), Some(0.0), "{v}");
    assert_eq!(v["ticks"], 400);

    // Change one recorded force component by 0.25 N: replay finds exactly that.
    let s = session::read(&rec).unwrap();
    let k = s
        .ticks
        .iter()
        .position(|t| t.forces[1].length() > 0.1)
        .expect("the second finger pressed");
    let mut bytes = std::fs::read(&rec).unwrap();
    // Records: dt, then 2 positions, then 2 forces (8 + 96 bytes).
    let body = bytes.len() - 400 * 104;
    let at = body + k * 104 + 8 + 48 + 24; // tick k, forces, finger 2, fx
    let fx = f64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    bytes[at..at + 8].copy_from_slice(&(fx + 0.25).to_le_bytes());
    let bad = dir.path().join("tampered.tfsession");
    std::fs::write(&bad, &bytes).unwrap();
    let (_, o, _) = touchfem(&["replay", bad.to_str().unwrap(), "--json"], &[]);
    let v = json(&o);
    assert!(
        (v["max_force_diff_n"].as_f64().unwrap() - 0.25).abs() < 1e-12,
        "{v}"
    );
    assert_eq!(v["worst_tick"], k);

    // Cut off mid-record: the whole ticks replay, the rest is reported.
    let cut = dir.path().join("cut.tfsession");
    std::fs::write(&cut, &std::fs::read(&rec).unwrap()[..body + 10 * 104 + 50]).unwrap();
    let (code, o, _) = touchfem(&["replay", cut.to_str().unwrap(), "--json"], &[]);
    assert_eq!(code, 0);
    let v = json(&o);
    assert_eq!(
        (v["ticks"].as_u64(), v["trailing_bytes"].as_u64()),
        (Some(10), Some(50))
    );

    // The recorded scene no longer matches (a different material in the embedded scene).
    let mut s2 = session::read(&rec).unwrap();
    s2.header.scene_toml = s2
        .header
        .scene_toml
        .replace("mesh = \"cube\"", "mesh = \"cube\"\nyoung = 20000.0");
    let src = touchfem::scene::SceneSource {
        name: "pinch".into(),
        text: s2.header.scene_toml.clone(),
        dir: ".".into(),
        label: "x".into(),
    };
    let w = touchfem::scene::World::from_source_with(&src, None).unwrap();
    let e = session::replay(&w, &s2).unwrap_err().to_string();
    assert!(e.contains("differs from the recorded one"), "{e}");
}

#[test]
fn broken_session_files_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cases: &[(&str, &[u8], &str)] = &[
        ("empty", b"", "no header"),
        ("magic", b"PNG\nxx\n", "not a touchfem session"),
        ("header", b"TFSESSION 1\n{\"format\": 3}\n", "bad header"),
        ("noline", b"TFSESSION 1\n{", "truncated header"),
    ];
    for (name, bytes, want) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        let (code, _, err) = touchfem(&["replay", p.to_str().unwrap()], &[]);
        assert_eq!(code, 2, "{name}: {err}");
        assert!(
            err.contains(want) && !err.contains("panicked"),
            "{name}: {err}"
        );
    }
    // A header that claims 9 fingers.
    let s = session::read(&committed()).unwrap();
    let mut h = serde_json::to_value(&s.header).unwrap();
    h["fingers"] = 9.into();
    h["record_bytes"] = (9 * 48).into();
    let p = dir.path().join("nine");
    std::fs::write(&p, format!("TFSESSION 1\n{h}\n")).unwrap();
    let (code, _, err) = touchfem(&["replay", p.to_str().unwrap()], &[]);
    assert_eq!(code, 2);
    assert!(err.contains("unsupported header"), "{err}");
}

#[test]
fn the_demo_reports_table_2_with_contacts_and_floor_and_writes_its_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    // The cache directory is a file: nothing can be written there.
    let blocker = dir.path().join("not-a-dir");
    std::fs::write(&blocker, b"x").unwrap();
    let (code, _, err) = touchfem(
        &[
            "demo",
            "fig1",
            "pinch",
            "--seconds",
            "0.5",
            "--out",
            out.to_str().unwrap(),
        ],
        &[("TOUCHFEM_CACHE_DIR", blocker.to_str().unwrap())],
    );
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("could not be written") && err.contains("going on"),
        "the session goes on with a warning: {err}"
    );
    let r = json(&std::fs::read_to_string(out.join("report.json")).unwrap());
    let objs = r["objects"].as_array().unwrap();
    assert_eq!(objs.len(), 2);
    for o in objs {
        for k in [
            "name",
            "nodes",
            "rows",
            "cols",
            "force_us_median",
            "displacement_us_median",
            "draw_hz",
            "max_contacts",
        ] {
            assert!(!o[k].is_null(), "objects[].{k} missing: {o}");
        }
    }
    assert_eq!(
        (objs[0]["name"].as_str(), objs[0]["max_contacts"].as_u64()),
        (Some("cube"), Some(1))
    );
    assert_eq!(
        (objs[1]["name"].as_str(), objs[1]["max_contacts"].as_u64()),
        (Some("block"), Some(2))
    );
    assert_eq!(
        (objs[0]["rows"].as_u64(), objs[0]["cols"].as_u64()),
        (Some(98), Some(73))
    );
    assert!(
        objs[1]["cols"].as_u64().unwrap() < 73,
        "the ball's columns only"
    );
    for key in ["haptic", "floor"] {
        for k in [
            "haptic_rate_hz",
            "period_error_us_p999",
            "missed_deadlines",
            "seconds",
        ] {
            assert!(r[key][k].is_number(), "{key}.{k}: {r}");
        }
    }
    assert_eq!(r["haptic"]["ticks"], 1000);
    assert!(r["haptic"]["max_force_n"].as_f64().unwrap() > 0.1);
    for f in [
        "fig1_00.png",
        "fig1.gif",
        "fig1.tfsession",
        "fig1_cube_force.csv",
        "fig1_cube_force.png",
        "pinch_block_force.csv",
        "pinch.gif",
    ] {
        let m = std::fs::metadata(out.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
        assert!(m.len() > 100, "{f}");
    }
    // The force trace: 500 ticks, the press reaches a real force, two contacts in the pinch.
    let csv = std::fs::read_to_string(out.join("pinch_block_force.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 500);
    assert!(rows.iter().any(|r| r[5] == 2.0));
    let gif = image::open(out.join("fig1.gif")).unwrap();
    assert!(gif.width() >= 100);
}

/// `touchfem` run in `cwd`.
fn touchfem_in(cwd: &Path, args: &[&str]) -> (i32, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(args)
        .current_dir(cwd)
        .env("TOUCHFEM_CACHE_DIR", "")
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Byte offset of tick `k`'s record in a one-finger session file of `ticks` ticks.
fn tick_at(bytes: &[u8], ticks: usize, k: usize) -> usize {
    bytes.len() - ticks * 48 + k * 48
}

#[test]
fn a_nan_force_fails_the_replay_and_is_never_null() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = std::fs::read(committed()).unwrap();
    // Tick 500's recorded fz is NaN.
    let at = tick_at(&bytes, 1000, 500) + 24 + 16;
    bytes[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
    let p = dir.path().join("nan.tfsession");
    std::fs::write(&p, &bytes).unwrap();
    let (code, out, err) = touchfem(
        &["replay", p.to_str().unwrap(), "--json"],
        &[("TOUCHFEM_CACHE_DIR", "")],
    );
    assert_eq!(code, 2, "{out} {err}");
    assert!(
        err.starts_with("error:") && err.contains("nan.tfsession") && err.contains("non-finite"),
        "{err}"
    );
    let v = json(&out);
    assert_eq!(v["max_force_diff_n"].as_f64(), Some(f64::MAX), "{v}");
    assert_eq!(
        (v["non_finite_ticks"].as_u64(), v["worst_tick"].as_u64()),
        (Some(1), Some(500))
    );
    assert!(!out.contains("null"), "{out}");
    // The library gives the same report: an infinite difference.
    let s = session::read(&p).unwrap();
    let w = session::world(&s, "x").unwrap();
    let r = session::replay(&w, &s).unwrap();
    assert_eq!((r.max_force_diff_n, r.non_finite_ticks), (f64::INFINITY, 1));
    assert!(r.max_force_n > 0.3 && r.max_force_n.is_finite());
}

#[test]
fn a_session_without_ticks_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(committed()).unwrap();
    let head = bytes.len() - 1000 * 48;
    for (name, cut) in [("header-only", head), ("half-a-tick", head + 20)] {
        let p = dir.path().join(format!("{name}.tfsession"));
        std::fs::write(&p, &bytes[..cut]).unwrap();
        let (code, out, err) = touchfem(&["replay", p.to_str().unwrap(), "--json"], &[]);
        assert_eq!(code, 2, "{name}: {out} {err}");
        assert!(
            err.starts_with("error:") && err.contains(name) && err.contains("no tick"),
            "{err}"
        );
        assert!(out.is_empty(), "{out}");
        // The library refuses it too.
        let s = session::read(&p).unwrap();
        assert!(s.ticks.is_empty());
        let src = touchfem::scene::SceneSource::find("fig1").unwrap().unwrap();
        let w = touchfem::scene::World::from_source_with(&src, None).unwrap();
        let e = session::replay(&w, &s).unwrap_err().to_string();
        assert!(e.contains("no tick"), "{e}");
    }
}

#[test]
fn the_scene_hash_is_checked_before_anything_is_precomputed() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    std::fs::create_dir(&cache).unwrap();
    let s = session::read(&committed()).unwrap();
    let mut h = serde_json::to_value(&s.header).unwrap();
    h["scene_hash"] = "0123456789abcdef".into();
    let mut bytes = format!("TFSESSION 1\n{h}\n").into_bytes();
    let all = std::fs::read(committed()).unwrap();
    bytes.extend_from_slice(&all[all.len() - 1000 * 48..]);
    let p = dir.path().join("rehashed.tfsession");
    std::fs::write(&p, &bytes).unwrap();
    let (code, _, err) = touchfem(
        &["replay", p.to_str().unwrap()],
        &[("TOUCHFEM_CACHE_DIR", cache.to_str().unwrap())],
    );
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("differs from the recorded one"), "{err}");
    // Nothing was precomputed: the cache directory is as empty as before.
    let left: Vec<_> = std::fs::read_dir(&cache).unwrap().collect();
    assert!(
        left.is_empty(),
        "precomputed before the hash check: {left:?}"
    );
}

#[test]
fn a_session_recorded_from_a_mesh_path_replays_from_any_directory() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    std::fs::create_dir_all(a.join("meshes")).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/box_v41.msh");
    std::fs::copy(data, a.join("meshes/box.msh")).unwrap();
    let (code, _, err) = touchfem_in(
        &a,
        &[
            "serve",
            "meshes/box.msh",
            "--udp",
            "127.0.0.1:0",
            "--seconds",
            "0.2",
            "--record",
            "s.tfsession",
            "--report",
            "r.json",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let rec = a.join("s.tfsession");
    let s = session::read(&rec).unwrap();
    assert!(s.header.scene_dir.is_absolute(), "{:?}", s.header.scene_dir);
    // From another directory, by an absolute and by a relative session path.
    for (cwd, file) in [
        (&b, rec.to_str().unwrap().to_string()),
        (&dir.path().to_path_buf(), "a/s.tfsession".to_string()),
    ] {
        let (code, out, err) = touchfem_in(cwd, &["replay", &file, "--json"]);
        assert_eq!(code, 0, "{err}");
        let v = json(&out);
        assert_eq!(v["ticks"], 200, "{v}");
        assert_eq!(v["max_force_diff_n"].as_f64(), Some(0.0), "{v}");
    }
    // An older file's relative directory is tried from the session file's directory too.
    let mut h = serde_json::to_value(&s.header).unwrap();
    h["scene_dir"] = "meshes".into();
    let mut bytes = format!("TFSESSION 1\n{h}\n").into_bytes();
    let all = std::fs::read(&rec).unwrap();
    bytes.extend_from_slice(&all[all.len() - 200 * s.header.record_bytes..]);
    let old = a.join("old.tfsession");
    std::fs::write(&old, &bytes).unwrap();
    let (code, out, err) = touchfem_in(&b, &["replay", old.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(json(&out)["ticks"], 200);
}

#[cfg(unix)]
#[test]
fn recording_from_a_non_utf8_directory_keeps_the_old_file_until_done_and_stores_the_path() {
    use glam::DVec3;
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().unwrap();
    let odd = dir
        .path()
        .join(std::ffi::OsStr::from_bytes(b"sc\xffene\xfe"));
    std::fs::create_dir(&odd).unwrap();
    let mut src = touchfem::scene::SceneSource::find("fig1").unwrap().unwrap();
    src.dir = odd.clone();
    let world = touchfem::scene::World::from_source_with(&src, None).unwrap();
    let path = odd.join("s.tfsession");
    std::fs::write(&path, b"the previous recording").unwrap();
    let (mut rec, writer) = session::record(&path, &world).unwrap();
    let mut hw = touchfem::runtime::HapticWorld::new(&world);
    let mut sample = Default::default();
    for k in 0..50 {
        let p = [DVec3::new(0.015, 0.015, 0.032 - 0.0002 * k as f64)];
        let mut f = [DVec3::ZERO];
        hw.step(&p, &mut f, &mut sample);
        rec.push(&session::TickRecord::new(1e-3, &p, &f));
    }
    std::thread::sleep(std::time::Duration::from_millis(50));
    // While recording, the old file is whole: nothing truncated it.
    assert_eq!(std::fs::read(&path).unwrap(), b"the previous recording");
    drop(rec);
    assert_eq!(writer.join().unwrap().unwrap(), 50);
    let s = session::read(&path).unwrap();
    assert_eq!(s.ticks.len(), 50);
    assert_eq!(s.header.scene_dir, odd.canonicalize().unwrap());
    let w = session::world(&s, "x").unwrap();
    let r = session::replay(&w, &s).unwrap();
    // (The replay may read a compliance cached by another build: equal to round-off.)
    assert_eq!(r.ticks, 50);
    assert!(r.max_force_diff_n < 1e-9, "{r:?}");
    assert!(r.max_force_n > 0.0, "it pressed");
    // No temporary left beside it.
    let names: Vec<_> = std::fs::read_dir(&odd)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");
}

#[cfg(target_os = "linux")]
#[test]
fn a_failed_serve_recording_keeps_the_report() {
    let dir = tempfile::tempdir().unwrap();
    let rep = dir.path().join("r.json");
    let (code, _, err) = touchfem(
        &[
            "serve",
            "cube",
            "--udp",
            "127.0.0.1:0",
            "--seconds",
            "0.3",
            "--record",
            "/dev/full",
            "--report",
            rep.to_str().unwrap(),
        ],
        &[("TOUCHFEM_CACHE_DIR", "")],
    );
    assert_eq!(code, 2, "{err}");
    assert!(
        err.lines()
            .any(|l| l.starts_with("error:") && l.contains("/dev/full")),
        "{err}"
    );
    let v = json(&std::fs::read_to_string(&rep).expect("the report is written"));
    assert_eq!(v["ticks"], 300, "{v}");
    assert_eq!(v["records_dropped"], 300, "{v}");
    assert!(
        v["recording_error"].as_str().unwrap().contains("/dev/full"),
        "{v}"
    );
    // A recording that works drops nothing, and says so.
    let ok = dir.path().join("ok.tfsession");
    let (code, _, err) = touchfem(
        &[
            "serve",
            "cube",
            "--udp",
            "127.0.0.1:0",
            "--seconds",
            "0.2",
            "--record",
            ok.to_str().unwrap(),
            "--report",
            rep.to_str().unwrap(),
        ],
        &[("TOUCHFEM_CACHE_DIR", "")],
    );
    assert_eq!(code, 0, "{err}");
    let v = json(&std::fs::read_to_string(&rep).unwrap());
    assert_eq!(
        (v["ticks"].as_u64(), v["records_dropped"].as_u64()),
        (Some(200), Some(0))
    );
    assert!(v.get("recording_error").is_none(), "{v}");
    assert_eq!(session::read(&ok).unwrap().ticks.len(), 200);
}

#[test]
fn fuzzed_session_files_give_typed_errors_or_valid_replays_never_a_panic() {
    use proptest::test_runner::TestCaseError;
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read(committed()).unwrap();
    let body_at = good.len() - 1000 * 48;
    let header: serde_json::Value =
        serde_json::from_slice(&good[12..body_at - 1]).expect("the header line");
    let src = touchfem::scene::SceneSource::find("fig1").unwrap().unwrap();
    let world = touchfem::scene::World::from_source_with(&src, None).unwrap();
    let mut runner = crate::common::fuzz_runner(400);
    let counts = std::cell::RefCell::new(std::collections::BTreeMap::<String, usize>::new());
    let case = std::cell::Cell::new(0usize);
    let keys: Vec<String> = header.as_object().unwrap().keys().cloned().collect();
    let values = [
        serde_json::json!(null),
        serde_json::json!(-1),
        serde_json::json!(0),
        serde_json::json!(1),
        serde_json::json!(2),
        serde_json::json!(4),
        serde_json::json!(96),
        serde_json::json!(u64::MAX),
        serde_json::json!(1e308),
        serde_json::json!(-0.5),
        serde_json::json!(""),
        serde_json::json!("zz"),
        serde_json::json!([null, {"name": "x", "max_force_n": -1.0}]),
        serde_json::json!({"os_bytes": [255, 0, 47]}),
    ];
    runner
        .run(
            &(
                0u8..6,
                proptest::prelude::any::<u64>(),
                proptest::collection::vec(proptest::prelude::any::<u8>(), 0..64),
            ),
            |(kind, seed, noise)| {
                case.set(case.get() + 1);
                let mut x = crate::common::Xorshift(seed | 1);
                let mut next = move |n: usize| x.below(n);
                let mut b = good.clone();
                match kind {
                    // Bytes flipped anywhere.
                    0 => {
                        for _ in 0..1 + next(16) {
                            let i = next(b.len());
                            b[i] ^= 1 << next(8);
                        }
                    }
                    // Random bytes over the records: positions and forces of any bits
                    // (NaN, infinities, subnormals).
                    1 => {
                        for (k, v) in noise.iter().enumerate() {
                            let i = body_at + next(1000 * 48);
                            b[i] = v.wrapping_add(k as u8);
                        }
                    }
                    // A header key set to an odd value (or removed, or an unknown one added).
                    2 | 3 => {
                        let mut h = header.clone();
                        let k = &keys[next(keys.len())];
                        match next(8) {
                            0 => {
                                h.as_object_mut().unwrap().remove(k);
                            }
                            1 => {
                                h["surprise"] = 1.into();
                            }
                            _ => h[k] = values[next(values.len())].clone(),
                        }
                        let mut nb = format!("TFSESSION 1\n{h}\n").into_bytes();
                        nb.extend_from_slice(&b[body_at..]);
                        b = nb;
                    }
                    // Cut at a random length.
                    4 => b.truncate(next(b.len())),
                    // Noise appended, or put in place of the header line.
                    _ => {
                        if next(2) == 0 {
                            b.extend_from_slice(&noise);
                        } else {
                            let mut nb = b"TFSESSION 1\n".to_vec();
                            nb.extend_from_slice(&noise);
                            nb.extend_from_slice(&b[body_at - 1..]);
                            b = nb;
                        }
                    }
                }
                let p = dir.path().join(format!("fuzz{}.tfsession", case.get()));
                std::fs::write(&p, &b).unwrap();
                let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    session::read(&p).map(|s| {
                        // A changed header also goes through the scene's load (its hash
                        // check first); the records through the loaded fig1 world.
                        if matches!(kind, 2 | 3) {
                            let w = session::world(&s, "fuzz");
                            *counts
                                .borrow_mut()
                                .entry(format!("world: {}", if w.is_ok() { "Ok" } else { "Err" }))
                                .or_default() += 1;
                        }
                        (session::replay(&world, &s), s.ticks.len())
                    })
                }));
                let tag = match outcome {
                    Err(_) => {
                        return Err(TestCaseError::fail(format!(
                            "panic on case {} (mutation {kind})",
                            case.get()
                        )))
                    }
                    Ok(Err(_)) => "read: Err".to_string(),
                    Ok(Ok((Err(_), _))) => "read: Ok, replay: Err".to_string(),
                    Ok(Ok((Ok(r), ticks))) => {
                        // A valid replay: every tick, and a finite difference or a count of
                        // the non-finite ticks behind an infinite one.
                        if r.ticks != ticks
                            || r.max_force_diff_n.is_nan()
                            || (r.max_force_diff_n.is_infinite() != (r.non_finite_ticks > 0))
                        {
                            return Err(TestCaseError::fail(format!("{r:?}")));
                        }
                        if r.non_finite_ticks > 0 {
                            "read: Ok, replay: Ok (non-finite)".to_string()
                        } else {
                            "read: Ok, replay: Ok".to_string()
                        }
                    }
                };
                *counts.borrow_mut().entry(tag).or_default() += 1;
                let _ = std::fs::remove_file(&p);
                Ok(())
            },
        )
        .unwrap();
    eprintln!(
        "session fuzz: {} cases, outcomes {:?}",
        case.get(),
        counts.borrow()
    );
    assert_eq!(case.get(), 400);
}
