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
    let body = bytes.len() - 400 * 96;
    let at = body + k * 96 + 48 + 24; // tick k, forces, finger 2, fx
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
    std::fs::write(&cut, &std::fs::read(&rec).unwrap()[..body + 10 * 96 + 50]).unwrap();
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
