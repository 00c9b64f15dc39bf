//! The web page in a real headless Chromium (Debian's, driven over the DevTools protocol by
//! `scripts/web-driver.mjs`, which serves the built page on 127.0.0.1): the same engine and
//! shaders compiled to wasm32, on the browser's WebGPU (SwiftShader on a machine without a GPU).
//!
//! `scripts/test.sh` builds the page (`scripts/web.sh --build-only`) and points
//! `TOUCHFEM_WEB_DIR` at it; without that variable (a plain `cargo test`) these tests print
//! that they are skipped. Each test copies the built page and writes the compliance caches
//! the page reads, from the native engine, beside it.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::DVec3;
use touchfem::compliance::{Compliance, Selection};

/// The built page, or `None` (with a note) outside `scripts/test.sh`.
fn web_dir() -> Option<PathBuf> {
    match std::env::var_os("TOUCHFEM_WEB_DIR") {
        Some(d) if Path::new(&d).join("touchfem_web_bg.wasm").is_file() => Some(PathBuf::from(d)),
        Some(d) => panic!(
            "TOUCHFEM_WEB_DIR={} holds no built page (scripts/web.sh --build-only --out DIR)",
            Path::new(&d).display()
        ),
        None => {
            eprintln!("SKIPPED: TOUCHFEM_WEB_DIR is not set (scripts/test.sh builds the page and sets it)");
            None
        }
    }
}

/// A copy of the built page in a fresh directory, with `caches` written beside it
/// (`cache/NAME.tfc` from the native engine, as `scripts/web.sh` precomputes them).
fn served(dir: &Path, caches: &[&str]) -> tempfile::TempDir {
    let t = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_file() {
            std::fs::copy(e.path(), t.path().join(e.file_name())).unwrap();
        }
    }
    std::fs::create_dir_all(t.path().join("cache")).unwrap();
    for name in caches {
        let o = Command::new(env!("CARGO_BIN_EXE_touchfem"))
            .args(["precompute", name, "--out"])
            .arg(t.path().join("cache").join(format!("{name}.tfc")))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    t
}

/// What the driver reported, and its exit status.
struct Run {
    code: i32,
    json: serde_json::Value,
}

fn drive(dir: &Path, page: &str, extra: &[&str]) -> Run {
    let o = Command::new("node")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scripts/web-driver.mjs"
        ))
        .arg("--dir")
        .arg(dir)
        .args(["--page", page, "--size", "640x480", "--timeout-s", "240"])
        .args(extra)
        .output()
        .expect("node runs scripts/web-driver.mjs");
    let code = o.status.code().unwrap_or(-1);
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| {
        panic!(
            "driver gave no JSON ({e}), exit {code}: {}",
            String::from_utf8_lossy(&o.stderr)
        )
    });
    Run { code, json }
}

fn vec3(v: &serde_json::Value) -> DVec3 {
    let a: Vec<f64> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    DVec3::new(a[0], a[1], a[2])
}

/// `touchfem poke MESH --at AT --push PUSH --json`'s force.
fn native_poke(mesh: &str, at: &str, push: &str) -> DVec3 {
    let o = Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(["poke", mesh, "--at", at, "--push", push, "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    vec3(&v["force"])
}

/// The page's scripted press of `mesh`, checked against native `poke` (force, 1e-9 relative)
/// and against the native f64 displacement (the vertices read back from the browser's GPU, to
/// the native GPU tests' tolerance). Returns the run.
fn press_matches_native(dir: &Path, mesh: &str, at: &str, push: &str, shot: Option<&Path>) -> Run {
    let page = format!("index.html?scene={mesh}&press={at}:{push}");
    let mut extra = Vec::new();
    let shot_s;
    if let Some(p) = shot {
        shot_s = p.to_string_lossy().to_string();
        extra.extend(["--screenshot", shot_s.as_str()]);
    }
    let run = drive(dir, &page, &extra);
    let j = &run.json;
    assert_eq!(run.code, 0, "{mesh}: {j}");
    assert_eq!(j["title"], "touchfem:done", "{mesh}: {j}");
    let errors = j["errors"].as_array().unwrap();
    assert!(
        errors.is_empty(),
        "{mesh}: the page logged errors: {errors:?}"
    );
    let r = &j["result"];
    assert!(
        !r["adapter"].as_str().unwrap().is_empty(),
        "{mesh}: no adapter named"
    );
    assert_eq!(r["compliance_source"], "cache", "{mesh}: {r}");
    for k in ["compliance_ms", "step_us", "frame_ms"] {
        let v = r[k].as_f64().unwrap();
        assert!(v.is_finite() && v > 0.0, "{mesh}: {k} = {v}");
    }
    // The force: the same press as native `poke`, f64 on both sides.
    let web = vec3(&r["force"]);
    let native = native_poke(mesh, at, push);
    let rel = (web - native).length() / native.length();
    eprintln!("{mesh}: web {web:?} N, native {native:?} N, relative difference {rel:e}");
    assert!(
        native.length() > 1e-3,
        "{mesh}: the press touches ({native:?})"
    );
    assert!(
        rel <= 1e-9,
        "{mesh}: web {web:?} vs native {native:?} ({rel:e})"
    );
    // The vertices the browser's GPU wrote, against rest + L·F in f64 (forces rounded to f32
    // as the pass takes them).
    let (m, _) = touchfem::scene::load_mesh(mesh, &Default::default()).unwrap();
    let c = Compliance::compute(&m, &Selection::default()).unwrap();
    let body = touchfem::scene::Body::with_compliance(m, c);
    let s = 1e-3; // the bundled meshes are in millimetres
    let p = |t: &str| -> DVec3 {
        let v: Vec<f64> = t.split(',').map(|x| x.parse().unwrap()).collect();
        DVec3::new(v[0], v[1], v[2]) * s
    };
    let poke = body
        .poke(
            p(at),
            p(push),
            touchfem::contact::force::ForceModel::Paper,
            50,
        )
        .unwrap();
    let forces: Vec<(u32, DVec3)> = poke
        .bc
        .entries()
        .iter()
        .map(|&(col, f)| (col, f.as_vec3().as_dvec3()))
        .collect();
    gpu_matches_f64(mesh, r, &body.mesh.nodes, &body.compliance, &forces);
    run
}

/// The page's displayed rows (`r["rows"]`) are `c`'s, and the vertices the browser's GPU wrote
/// (`r["positions"]`, x y z per displayed row) match `rest + c·forces` in f64 (the forces as
/// the pass takes them), to the native GPU tests' tolerance.
fn gpu_matches_f64(
    what: &str,
    r: &serde_json::Value,
    rest: &[DVec3],
    c: &Compliance,
    forces: &[(u32, DVec3)],
) {
    let rows = c.rows();
    let page_rows: Vec<u32> = r["rows"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_u64().unwrap() as u32)
        .collect();
    assert_eq!(page_rows, rows, "{what}: the displayed rows");
    let mut u = vec![DVec3::ZERO; rows.len()];
    c.displace(forces, &mut u);
    let pos: Vec<f64> = r["positions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert_eq!(pos.len(), 3 * rows.len(), "{what}: positions");
    let (tol, umax) = crate::common::gpu_tolerance(&u, rest);
    let mut worst = 0.0f64;
    for (i, (&node, u)) in rows.iter().zip(&u).enumerate() {
        let want = rest[node as usize] + *u;
        let got = DVec3::new(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]);
        worst = worst.max((got - want).abs().max_element());
    }
    eprintln!("{what}: browser GPU vs f64: max error {worst:e} m (tol {tol:e}, max|u| {umax:e})");
    assert!(umax > 1e-4, "{what}: the press deforms ({umax:e} m)");
    assert!(worst <= tol, "{what}: {worst:e} > {tol:e}");
}

#[test]
fn the_page_presses_the_mouse_and_the_cube_as_native_poke_does_on_the_browsers_gpu() {
    let Some(dir) = web_dir() else { return };
    let t = served(&dir, &["cube", "mouse"]);
    press_matches_native(t.path(), "cube", "15,15,30", "0,0,-3", None);
    let shot = t.path().join("mouse.png");
    let run = press_matches_native(t.path(), "mouse", "-10,0,60", "0,0,-8", Some(&shot));
    eprintln!("mouse page: {}", {
        let mut r = run.json["result"].clone();
        r["positions"] = serde_json::Value::Null;
        r["rows"] = serde_json::Value::Null;
        r
    });
    // The pressed mouse as SwiftShader draws it, against its own golden (SwiftShader is not
    // lavapipe), with the native goldens' perceptual comparison.
    let img = image::open(&shot).unwrap().to_rgba8();
    assert_eq!(img.dimensions(), (640, 480));
    crate::golden::check_golden("web_mouse_pressed", &img);
}

#[test]
fn the_page_computes_the_compliance_itself_when_asked_and_equals_the_cache() {
    let Some(dir) = web_dir() else { return };
    let t = served(&dir, &["cube"]);
    let press = "index.html?scene=cube&press=10,12,30:0,0,-2";
    let cached = drive(t.path(), press, &[]);
    let computed = drive(t.path(), &format!("{press}&compliance=compute"), &[]);
    for (what, r) in [("cache", &cached), ("compute", &computed)] {
        assert_eq!(r.code, 0, "{what}: {}", r.json);
    }
    assert_eq!(cached.json["result"]["compliance_source"], "cache");
    assert_eq!(computed.json["result"]["compliance_source"], "computed");
    let (a, b) = (
        vec3(&cached.json["result"]["force"]),
        vec3(&computed.json["result"]["force"]),
    );
    assert!((a - b).length() <= 1e-12 * a.length(), "{a:?} vs {b:?}");
}

/// The incision in the page: the scene's own scripts for 5.5 s (the blade drawn 20 mm through
/// the cuttable ball, then the fingertip pressing beside the open cut), the page's cutter
/// between passes. The browser's blade parts the ball as the same run does natively (the same
/// copies and slivers; [`touchfem_web::page::PageWorld::run_scripts`], f64 on both sides, the
/// compliance computed on each), its fingertip's force agrees to 1e-9, and the vertices its GPU wrote (the folded
/// `L` and the correction's pass on WebGPU) match the cut compliance's f64 displacement.
#[test]
fn the_page_cuts_the_incision_as_the_engine_does_natively() {
    let Some(dir) = web_dir() else { return };
    let t = served(&dir, &[]);
    let seconds = 5.5;
    let run = drive(
        t.path(),
        &format!("index.html?scene=incision&compliance=compute&run={seconds}"),
        &[],
    );
    let j = &run.json;
    assert_eq!(run.code, 0, "{j}");
    let errors = j["errors"].as_array().unwrap();
    assert!(errors.is_empty(), "the page logged errors: {errors:?}");
    let r = &j["result"];
    let mut native = touchfem_web::page::PageWorld::load("incision", None).unwrap();
    native.run_scripts(seconds).unwrap();
    let tets = r["tets_removed"].as_u64().unwrap() as usize;
    let split = r["nodes_split"].as_u64().unwrap() as usize;
    let bodies = r["cut_bodies"].as_u64().unwrap();
    eprintln!(
        "incision page: {split} copies made, {tets} tets dropped in {bodies} cut bodies (native {} and {} in {}), \
         run {:.0} ms, compliance and cutter {:.0} ms",
        native.nodes_split,
        native.tets_removed,
        native.cut_bodies,
        r["run_ms"].as_f64().unwrap(),
        r["compliance_ms"].as_f64().unwrap()
    );
    // The blade separates, as natively: the same copies, the same slivers dropped.
    assert!(split >= 20, "the blade parted {split} nodes");
    assert!(tets <= 3 * split, "{tets} tets dropped for {split} copies");
    assert_eq!(split, native.nodes_split);
    assert_eq!(tets, native.tets_removed);
    assert_eq!(bodies, native.cut_bodies);
    let forces = r["forces"].as_array().unwrap();
    let tip = vec3(&forces[0]);
    let want = native.finger_forces()[0];
    assert!(
        want.z > 0.01,
        "the fingertip presses beside the cut: {want:?}"
    );
    let rel = (tip - want).length() / want.length();
    eprintln!("incision fingertip: page {tip:?} N, native {want:?} N ({rel:e})");
    assert!(rel <= 1e-9, "{tip:?} vs {want:?} ({rel:e})");
    // The GPU's vertices against rest + the cut compliance's f64 displacement.
    let body = native.cut_body(0).expect("the native run cut");
    let bc: Vec<(u32, DVec3)> = native.sample().bcs[0]
        .entries()
        .iter()
        .map(|&(c, f)| (c, f.as_vec3().as_dvec3()))
        .collect();
    gpu_matches_f64("incision", r, &body.rest, &body.compliance, &bc);
}

#[test]
fn without_webgpu_the_page_says_so() {
    let Some(dir) = web_dir() else { return };
    let t = served(&dir, &[]);
    let run = drive(
        t.path(),
        "index.html?scene=cube&press=15,15,30:0,0,-3",
        &["--no-webgpu"],
    );
    let title = run.json["title"].as_str().unwrap();
    assert_eq!(run.code, 3, "{}", run.json);
    assert!(title.starts_with("touchfem:error:"), "{title}");
    let body = run.json["body_text"].as_str().unwrap();
    assert!(
        body.contains("no WebGPU") && body.contains("--enable-unsafe-webgpu"),
        "{body}"
    );
}

#[test]
fn a_bad_press_or_scene_is_an_error_on_the_page() {
    let Some(dir) = web_dir() else { return };
    let t = served(&dir, &[]);
    for page in [
        "index.html?scene=cube&press=1,2:3,4,5",
        "index.html?scene=nosuch&press=15,15,30:0,0,-3",
    ] {
        let run = drive(t.path(), page, &[]);
        let title = run.json["title"].as_str().unwrap();
        assert_eq!(run.code, 3, "{page}: {}", run.json);
        assert!(title.starts_with("touchfem:error:"), "{page}: {title}");
    }
}
