//! The command line as scripts use it (docs/reference/cli.md): keys, units, files, errors.

use std::process::Command;

fn touchfem(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(args)
        .output()
        .expect("runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A JSON array of numbers.
fn numbers(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn json(s: &str) -> serde_json::Value {
    serde_json::from_str(s.trim()).unwrap_or_else(|e| panic!("not JSON ({e}): {s}"))
}

#[test]
fn info_cube_json_is_table_1() {
    let (code, out, err) = touchfem(&["info", "cube", "--json"]);
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    assert_eq!(v["nodes"], 125);
    assert_eq!(v["surface_nodes"], 98);
    assert_eq!(v["free_surface_nodes"], 73);
    assert_eq!(v["surface_triangles"], 192);
    assert_eq!(v["tets"], 320);
    assert_eq!(v["young_pa"], 10000.0);
    assert_eq!(v["poisson"], 0.49);
    // Early warning: K's condition (the cube's dense eigenvalues give 4.55e3), the worst
    // element (the five-tet cell's corner tets: 6V/l³ = 1/(2√2)), and the storage errors.
    let kappa = v["condition_estimate"].as_f64().unwrap();
    assert!((kappa / 4.55e3 - 1.0).abs() < 0.05, "{kappa}");
    assert!((v["worst_quality"].as_f64().unwrap() - 0.3536).abs() < 1e-3);
    assert!(v["f32_storage_error"].as_f64().unwrap() < 1e-6);
    assert!(v["f16_storage_error"].as_f64().unwrap() < 1e-3);
}

#[test]
fn poke_top_centre_matches_eq_7_and_writes_a_vtu() {
    let dir = tempfile::tempdir().unwrap();
    let vtu = dir.path().join("poke.vtu");
    let (code, out, err) = touchfem(&crate::common::poke_cube(&[
        "--json",
        "--vtu",
        vtu.to_str().unwrap(),
    ]));
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    let f = numbers(&v["force"]);
    // The top centre is a node: the force is L_ii⁻¹·u there, pushing the finger back up, and
    // by the cube's symmetry about x = 15 and y = 15 mm it has no sideways part.
    assert!(f[2] > 0.1 && f[2] < 10.0, "{f:?}");
    assert!(
        f[0].abs() < 1e-9 * f[2] && f[1].abs() < 1e-9 * f[2],
        "{f:?}"
    );
    // The node under the finger moves by exactly 5 mm, and nothing moves more.
    let u = v["max_displacement"].as_f64().unwrap();
    assert!((u - 0.005).abs() < 1e-12, "{u}");
    assert_eq!(v["paper_exact_difference"].as_f64().unwrap(), 0.0);
    // The VTU has the tets and the three arrays.
    let text = std::fs::read_to_string(&vtu).unwrap();
    assert!(text.contains("NumberOfPoints=\"125\" NumberOfCells=\"320\""));
    for name in ["displacement", "force", "fixed"] {
        assert!(text.contains(&format!("Name=\"{name}\"")), "{name}");
    }
    let fixed_block = text
        .split("Name=\"fixed\" format=\"ascii\">\n")
        .nth(1)
        .unwrap();
    let ones = fixed_block.lines().take(125).filter(|l| *l == "1").count();
    assert_eq!(ones, 25);
    // The force array holds the applied nodal force: one node, equal and opposite to the feedback.
    let force_block = text
        .split("Name=\"force\" NumberOfComponents=\"3\" format=\"ascii\">\n")
        .nth(1)
        .unwrap();
    let rows: Vec<Vec<f64>> = force_block
        .lines()
        .take(125)
        .map(|l| l.split_whitespace().map(|x| x.parse().unwrap()).collect())
        .collect();
    let loaded: Vec<&Vec<f64>> = rows
        .iter()
        .filter(|r| r.iter().any(|x| *x != 0.0))
        .collect();
    assert_eq!(loaded.len(), 1);
    assert!((loaded[0][2] + f[2]).abs() < 1e-12);
}

#[test]
fn poke_side_face_pushes_back_along_x() {
    let (code, out, err) = touchfem(&[
        "poke", "cube", "--at", "0,15,15", "--push", "5,0,0", "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    let f = numbers(&v["force"]);
    assert!(f[0] < -0.1, "{f:?}");
    assert!(f[1].abs() < 1e-9 * f[0].abs());
    // Paper and exact differ off the nodes; --exact is selectable.
    let (_, out2, _) = touchfem(&[
        "poke", "cube", "--at", "10,12,30", "--push", "0,0,-2", "--json", "--exact",
    ]);
    let (_, out3, _) = touchfem(&[
        "poke", "cube", "--at", "10,12,30", "--push", "0,0,-2", "--json",
    ]);
    let (e, p) = (json(&out2), json(&out3));
    assert_eq!(e["model"], "exact");
    assert_eq!(e["force"], e["force_exact"]);
    assert_eq!(p["force"], p["force_paper"]);
    assert!(e["paper_exact_difference"].as_f64().unwrap() > 1e-3);
    // Stiffer material, stiffer response: twice E, twice the force (linear elasticity).
    let (_, out4, _) = touchfem(&[
        "poke", "cube", "--at", "0,15,15", "--push", "5,0,0", "--json", "--young", "20000",
    ]);
    let f4 = json(&out4)["force"][0].as_f64().unwrap();
    assert!((f4 - 2.0 * f[0]).abs() < 1e-9 * f4.abs());
}

#[test]
fn pulling_away_from_the_surface_gives_no_force() {
    let (code, out, _) = touchfem(&[
        "poke", "cube", "--at", "15,15,30", "--push", "0,0,3", "--json",
    ]);
    assert_eq!(code, 0);
    let v = json(&out);
    assert_eq!(v["force"], serde_json::json!([0.0, 0.0, 0.0]));
    assert_eq!(v["max_displacement"], 0.0);
    assert!(v["contact"].is_null());
}

#[test]
fn bad_input_is_a_clear_error_not_a_panic() {
    let cases: &[&[&str]] = &[
        &["info", "no-such-mesh"],
        &["info", "cube", "--fixed", "nope"],
        &["poke", "cube", "--at", "nan,0,0", "--push", "0,0,-1"],
        &["poke", "cube", "--at", "1,2", "--push", "0,0,-1"],
        &[
            "poke", "cube", "--at", "15,15,30", "--push", "0,0,-1", "--young", "-5",
        ],
        &[
            "poke",
            "cube",
            "--at",
            "15,15,30",
            "--push",
            "0,0,-1",
            "--poisson",
            "0.5",
        ],
        &[
            "poke", "cube", "--at", "15,15,30", "--push", "0,0,-1", "--unit", "furlong",
        ],
        &["demo", "--seconds", "-1"],
    ];
    for args in cases {
        let (code, _, err) = touchfem(args);
        assert_ne!(code, 0, "{args:?} should fail");
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
        assert!(err.contains("error"), "{args:?}: {err}");
    }
}

#[test]
fn poke_cache_is_written_reused_and_a_corrupt_one_recomputed() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cube.tfc");
    let c = cache.to_str().unwrap();
    let args = [
        "poke", "cube", "--at", "10,12,30", "--push", "0,0,-2", "--json", "--cache", c,
    ];
    let (code, out1, err1) = touchfem(&args);
    assert_eq!(code, 0, "{err1}");
    assert!(err1.contains("recomputed"), "{err1}");
    let (_, out2, err2) = touchfem(&args);
    assert!(
        !err2.contains("recomputed"),
        "a valid cache is used: {err2}"
    );
    assert_eq!(json(&out1)["force"], json(&out2)["force"]);
    let mut bytes = std::fs::read(&cache).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 1;
    std::fs::write(&cache, &bytes).unwrap();
    let (code, out3, err3) = touchfem(&args);
    assert_eq!(code, 0);
    assert!(err3.contains("corrupt"), "{err3}");
    assert_eq!(json(&out1)["force"], json(&out3)["force"]);
    let p = &json(&out3)["precompute"];
    assert!(p["residual"].as_f64().unwrap() < 1e-12);
    assert_eq!(p["cols"], 73);
}

#[test]
fn bench_json_has_the_contract_keys_and_sane_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bench.json");
    let (code, _, err) = touchfem(&["bench", "--quick", "--json", path.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let v = json(&std::fs::read_to_string(&path).unwrap());
    let rows = v["rows"].as_array().unwrap();
    let find = |method: &str, mesh: &str| {
        rows.iter()
            .find(|r| r["method"] == method && r["mesh"] == mesh)
            .unwrap_or_else(|| panic!("no {method} row for {mesh}"))
    };
    for r in rows {
        for key in [
            "method",
            "mesh",
            "nodes",
            "active_columns",
            "time_us",
            "rel_error",
        ] {
            assert!(!r[key].is_null(), "{key} missing in {r}");
        }
        assert!(r["time_us"].as_f64().unwrap() > 0.0);
    }
    for mesh in ["cube", "mouse"] {
        assert_eq!(find("cpu-f64", mesh)["rel_error"], 0.0);
        assert!(find("cpu-f32", mesh)["rel_error"].as_f64().unwrap() < 1e-5);
        assert!(find("direct-sparse", mesh)["rel_error"].as_f64().unwrap() < 1e-12);
        for layout in ["gpu-f32-texture", "gpu-f32-buffers"] {
            assert!(find(layout, mesh)["rel_error"].as_f64().unwrap() < 1e-5);
        }
        assert!(find("force-exact", mesh)["rel_error"].as_f64().unwrap() < 1e-12);
        // The paper's interpolation misses the finger inside triangles by tens of percent.
        let paper = find("force-paper", mesh)["rel_error"].as_f64().unwrap();
        assert!(paper > 0.05 && paper < 1.0, "{paper}");
    }
    assert_eq!(find("cpu-f64", "mouse")["nodes"], 1699);
    // The hierarchical L at 1e-3: a point load's worst error a few ε (3.9e-3 measured).
    let h = find("hmatrix-f64-1e-3", "mouse")["rel_error"]
        .as_f64()
        .unwrap();
    assert!(h > 1e-4 && h < 1e-2, "{h}");
}

/// `touchfem` with `args`, the environment as a user without a window system has it: no
/// `XDG_RUNTIME_DIR` (libwayland's complaint came from there), no device-select settings.
fn touchfem_headless(args: &[&str], extra_env: &[(&str, &str)]) -> (i32, String, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_touchfem"));
    cmd.args(args)
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("NODEVICE_SELECT")
        .env_remove("MESA_VK_DEVICE_SELECT");
    for (k, v) in extra_env {
        cmd.env(k, v);
    }
    let out = cmd.output().expect("runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A healthy `poke --png` run prints nothing on stderr (no `error: XDG_RUNTIME_DIR …` from the
/// Vulkan device-select layer's window-system probing), and its picture is the documented
/// one: the size asked for, the mouse spanning more than half its width, the legend's colour
/// bar (viridis' two ends) in the top-right corner. Needs a GPU adapter (lavapipe works).
#[test]
fn healthy_poke_png_is_quiet_and_frames_the_object() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("m.png");
    let (code, out, err) = touchfem_headless(
        &[
            "poke",
            "mouse",
            "--at",
            "-10,0,60",
            "--push",
            "0,0,-8",
            "--png",
            png.to_str().unwrap(),
            "--size",
            "640x480",
        ],
        &[],
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("force fed back"), "{out}");
    assert_eq!(err, "", "a healthy run printed on stderr");
    let img = image::open(&png).unwrap().to_rgba8();
    assert_eq!(img.dimensions(), (640, 480));
    let bg = *img.get_pixel(2, 477);
    let differs =
        |p: &image::Rgba<u8>| (0..3).any(|k| (i32::from(p[k]) - i32::from(bg[k])).abs() > 12);
    // The object's columns, left of the legend (which sits in the top-right corner).
    let cols: Vec<u32> = (0..640)
        .filter(|&x| (0..480).any(|y| !(x >= 480 && y < 260) && differs(img.get_pixel(x, y))))
        .collect();
    let span = f64::from(cols.last().unwrap() - cols.first().unwrap() + 1) / 640.0;
    eprintln!("the mouse spans {:.1} % of the width", 100.0 * span);
    assert!(
        span >= 0.5,
        "the mouse spans only {:.1} % of the width",
        100.0 * span
    );
    let has = |c: [u8; 3]| {
        img.enumerate_pixels()
            .any(|(x, y, p)| x >= 480 && y < 260 && [p[0], p[1], p[2]] == c)
    };
    let v = touchfem::render::VIRIDIS;
    assert!(
        has(v[0]) && has(v[9]),
        "no legend colour bar in the top-right corner"
    );
}

/// Turning the window-system probing off hides no adapter error: a missing adapter is still
/// reported, on stderr, with a non-zero exit.
#[test]
fn adapter_errors_still_reach_stderr() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("x.png");
    let (code, _, err) = touchfem_headless(
        &crate::common::poke_cube(&["--png", png.to_str().unwrap()]),
        &[("WGPU_ADAPTER_NAME", "no-such-adapter-anywhere")],
    );
    assert_ne!(code, 0);
    assert!(err.contains("no GPU adapter"), "{err}");
    assert!(!png.exists());
}

/// `--color` and `--view` take only their documented values.
#[test]
fn poke_png_flags_reject_unknown_values() {
    for (flag, value) in [("--color", "rainbow"), ("--view", "top")] {
        let (code, _, err) = touchfem(&[
            "poke", "cube", "--at", "15,15,30", "--push", "0,0,-5", "--png", "x.png", flag, value,
        ]);
        assert_eq!(code, 2, "{flag} {value}: {err}");
        assert!(err.contains(value), "{err}");
    }
}

/// Every numeric flag rejects non-finite, negative and out-of-range values at parse time:
/// exit status 2, one `error:` naming the flag, never a panic (`serve --watchdog-ms 1e300` and
/// `serve --seconds 1e20` used to panic converting to a `Duration`).
#[test]
fn numeric_flags_out_of_range_name_the_flag_and_exit_2() {
    let serve = |flag: &'static str, v: &'static str| -> Vec<&'static str> {
        vec!["serve", "cube", "--udp", "127.0.0.1:0", flag, v]
    };
    let poke = |flag: &'static str, v: &'static str| -> Vec<&'static str> {
        vec![
            "poke", "cube", "--at", "15,15,30", "--push", "0,0,-1", flag, v,
        ]
    };
    let mut cases: Vec<(Vec<&str>, &str)> = Vec::new();
    for v in ["1e300", "1e20", "inf", "nan", "-1", "0", "abc"] {
        cases.push((serve("--watchdog-ms", v), "--watchdog-ms"));
        cases.push((serve("--seconds", v), "--seconds"));
        cases.push((vec!["demo", "--seconds", v], "--seconds"));
    }
    for v in ["1e300", "inf", "nan", "-1", "7200"] {
        cases.push((serve("--floor-seconds", v), "--floor-seconds"));
    }
    cases.push((serve("--watchdog-ms", "60001"), "--watchdog-ms"));
    cases.push((serve("--seconds", "1000001"), "--seconds"));
    for v in ["1e300", "inf", "nan", "-5", "0", "1e14"] {
        cases.push((poke("--young", v), "--young"));
        cases.push((vec!["info", "cube", "--young", v], "--young"));
    }
    for v in ["0.5", "0.7", "-1", "-2", "nan", "inf"] {
        cases.push((poke("--poisson", v), "--poisson"));
    }
    for v in ["0", "-1", "1e12", "1000000000000", "18446744073709551615"] {
        cases.push((poke("--steps", v), "--steps"));
    }
    for v in ["1e300,0,0", "0,inf,0", "0,0,1e10"] {
        cases.push((vec!["poke", "cube", "--at", v, "--push", "0,0,-1"], "--at"));
        cases.push((
            vec!["poke", "cube", "--at", "15,15,30", "--push", v],
            "--push",
        ));
    }
    for v in ["0x0", "99999x10", "12"] {
        cases.push((poke("--size", v), "--size"));
    }
    for v in ["0/4", "5/4", "1/0", "1/99999999"] {
        cases.push((vec!["precompute", "cube", "--shard", v], "--shard"));
    }
    for (args, flag) in &cases {
        let (code, _, err) = touchfem(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
        assert!(
            err.starts_with("error:") && err.contains(flag),
            "{args:?}: the error should name {flag}: {err}"
        );
    }
    // The documented ranges are in the help.
    let (_, out, _) = touchfem(&["serve", "--help"]);
    assert!(out.contains("60000") && out.contains("1e6"), "{out}");
}

/// The window's environment hooks are checked before anything loads: a bad value is an
/// `error:` naming the variable, exit status 2 (`TOUCHFEM_VIEW_SECONDS=1e20` used to panic
/// converting to a `Duration`, or was silently ignored).
#[test]
fn bad_view_environment_variables_name_the_variable() {
    for (var, v) in [
        ("TOUCHFEM_VIEW_SECONDS", "1e20"),
        ("TOUCHFEM_VIEW_SECONDS", "inf"),
        ("TOUCHFEM_VIEW_SECONDS", "-1"),
        ("TOUCHFEM_VIEW_SECONDS", "soon"),
        ("TOUCHFEM_VIEW_SAMPLES", "3"),
        ("TOUCHFEM_VIEW_SAMPLES", "many"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_touchfem"))
            .args(["view", "cube"])
            .env(var, v)
            .env("TOUCHFEM_CACHE_DIR", "")
            .env_remove("DISPLAY")
            .env_remove("WAYLAND_DISPLAY")
            .output()
            .expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{var}={v}: {err}");
        assert!(
            err.starts_with("error:") && err.contains(var),
            "{var}={v}: {err}"
        );
        assert!(!err.contains("panicked"), "{var}={v}: {err}");
    }
}

/// The example names: every `examples/NAME.rs` and `examples/NAME/main.rs`.
fn example_names() -> Vec<String> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .expect("examples/")
        .filter_map(|e| {
            let p = e.ok()?.path();
            if p.is_dir() {
                p.join("main.rs")
                    .exists()
                    .then(|| p.file_name()?.to_str().map(String::from))?
            } else if p.extension()? == "rs" {
                p.file_stem()?.to_str().map(String::from)
            } else {
                None
            }
        })
        .collect();
    names.sort();
    names
}

/// Every example (found in `examples/`, so a new one cannot escape) prints its usage and exits 2
/// on missing or bad arguments instead of panicking on `args[1]`: run bare, and with a few bad
/// arguments. The binaries are built by `cargo test --all-targets` or `cargo build --examples`;
/// one not built is skipped with a note.
#[test]
fn examples_print_their_usage_on_missing_arguments() {
    let names = example_names();
    assert!(names.len() >= 7, "{names:?}");
    // target/<profile>/deps/it-HASH → target/<profile>/examples/NAME
    let exe = std::env::current_exe().unwrap();
    let Some(examples) = exe
        .parent()
        .and_then(|d| d.parent())
        .map(|d| d.join("examples"))
    else {
        eprintln!("skipped: no examples directory next to {}", exe.display());
        return;
    };
    let mut cases: Vec<(String, Vec<&str>)> = names.iter().map(|n| (n.clone(), vec![])).collect();
    for (name, args) in [
        ("frame_cost", &["cube", "axb"][..]),
        ("frame_cost", &["cube", "640x480", "extra"]),
        ("precompute_phases", &["cube", "furlong"]),
        ("precompute_phases", &["cube", "mm", "nonsense"]),
        ("precompute_phases", &["cube", "mm", "frontal", "0"]),
        ("embed", &["a.png", "b.png"]),
        ("embed", &["--help"]),
        ("cut_organ", &["cube", "1,2"]),
        ("cut_organ", &["cube", "0,0,60", "-3"]),
        ("hier_organ", &["cube", "2"]),
        ("hier_organ", &["cube", "1e-3", "many"]),
        ("locking_free_cost", &["--help"]),
    ] {
        cases.push((name.to_string(), args.to_vec()));
    }
    let mut ran = 0;
    for (name, args) in &cases {
        let bin = examples.join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
        if !bin.exists() {
            eprintln!(
                "skipped {name}: {} not built (cargo build --examples)",
                bin.display()
            );
            continue;
        }
        let out = Command::new(&bin).args(args).output().expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name} {args:?}: {err}");
        assert!(err.contains("usage"), "{name} {args:?}: {err}");
        assert!(!err.contains("panicked"), "{name} {args:?}: {err}");
        ran += 1;
    }
    eprintln!("{ran} of {} example runs checked", cases.len());
}

/// A tiny poke's picture labels read right: the legend of `poke cube --push 0,0,-0.0001`
/// (|u| ≈ 1e-7 m) is in nm with distinct labels and no `-0`, and the arrow's scale is not
/// `100000000 mm/N`. The labels are built from the same functions `poke --png` uses; with a GPU
/// adapter the command itself is run too.
#[test]
fn a_tiny_poke_has_readable_picture_labels() {
    use touchfem::compliance::Selection;
    use touchfem::render::{arrow_label, arrow_scale, length_ticks, Coloring};
    let (mesh, _) = touchfem::scene::load_mesh("cube", &Default::default()).unwrap();
    let scene = touchfem::scene::Body::new(mesh, &Selection::default()).unwrap();
    let p = scene
        .poke(
            glam::DVec3::new(15e-3, 15e-3, 30e-3),
            glam::DVec3::new(0.0, 0.0, -1e-7),
            touchfem::contact::force::ForceModel::Paper,
            50,
        )
        .unwrap();
    let mut shown = vec![glam::DVec3::ZERO; scene.compliance.rows().len()];
    scene.compliance.displace(p.bc.entries(), &mut shown);
    let max_u = shown.iter().map(|v| v.length()).fold(0.0, f64::max);
    assert!(max_u > 5e-8 && max_u < 2e-7, "{max_u}");
    let Coloring::Displacement {
        full_scale_m,
        step_m,
    } = Coloring::displacement(max_u)
    else {
        unreachable!()
    };
    let t = length_ticks(full_scale_m, step_m);
    let labels: Vec<&str> = t.ticks.iter().map(|(_, s)| s.as_str()).collect();
    assert_eq!(t.unit, "nm", "{labels:?}");
    let distinct: std::collections::BTreeSet<&str> = labels.iter().copied().collect();
    assert_eq!(distinct.len(), labels.len(), "{labels:?}");
    assert!(labels.iter().all(|l| !l.starts_with('-')), "{labels:?}");
    assert_eq!(labels[0], "0");
    let arrow = arrow_label(arrow_scale(p.feedback.length(), 0.25 * 0.03 * 3f64.sqrt()));
    assert!(!arrow.contains("00000"), "{arrow}");
    assert!(arrow.len() < 20, "{arrow}");

    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("tiny.png");
    let (code, _, err) = touchfem_headless(
        &[
            "poke",
            "cube",
            "--at",
            "15,15,30",
            "--push",
            "0,0,-0.0001",
            "--png",
            png.to_str().unwrap(),
        ],
        &[],
    );
    if err.contains("no GPU adapter") {
        eprintln!("skipped the command: {err}");
        return;
    }
    assert_eq!(code, 0, "{err}");
    assert!(png.exists());
}

/// `--formulation`: `locking-free` softens the press on the paper's cube at ν = 0.4999 (the
/// locking table's 1.32 N standard, 0.56 N locking-free), `info --json` names it, an unknown
/// value and `--poisson 0.5` are errors with status 2 that say why.
#[test]
fn the_formulation_flag_selects_the_stiffness() {
    let force = |f: &str| {
        let (code, out, err) = touchfem(&crate::common::poke_cube(&[
            "--poisson",
            "0.4999",
            "--formulation",
            f,
            "--json",
        ]));
        assert_eq!(code, 0, "{err}");
        numbers(&json(&out)["force"])
            .iter()
            .map(|x| x * x)
            .sum::<f64>()
            .sqrt()
    };
    let (s, l) = (force("standard"), force("locking-free"));
    assert!(
        l < 0.6 * s && l > 0.2 * s,
        "standard {s} N, locking-free {l} N"
    );
    let (code, out, err) = touchfem(&["info", "cube", "--formulation", "locking-free", "--json"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(json(&out)["formulation"], "locking-free");
    let (code, _, err) = touchfem(&crate::common::poke_cube(&["--formulation", "mixed"]));
    assert_eq!(code, 2);
    assert!(
        err.contains("--formulation") && err.contains("locking-free"),
        "{err}"
    );
    let (code, _, err) = touchfem(&crate::common::poke_cube(&["--poisson", "0.5"]));
    assert_eq!(code, 2);
    assert!(
        err.contains("--poisson") && err.contains("incompressible"),
        "{err}"
    );
}

/// What the help and the docs say follows the code: `demo --help` names every bundled scene
/// (listed from `BUNDLED_SCENES`), as do the CLI reference and the commands guide; `serve
/// --help` points to `docs/contracts.md`, which the repository has, restating each contract;
/// `docs/README.md` names both cache formats and the session versions.
#[test]
fn help_and_docs_name_what_the_code_does() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let read = |p: &str| std::fs::read_to_string(root.join(p)).unwrap();
    let names: Vec<&str> = touchfem::scene::BUNDLED_SCENES
        .iter()
        .map(|(n, _)| *n)
        .collect();
    assert!(names.len() >= 6, "{names:?}");
    let (code, help, err) = touchfem(&["demo", "--help"]);
    assert_eq!(code, 0, "{err}");
    assert!(help.contains(&names.join(", ")), "{help}");
    let cli = read("docs/reference/cli.md");
    let listed = names
        .iter()
        .map(|n| format!("`{n}`"))
        .collect::<Vec<_>>()
        .join(", ");
    let cli_flat = cli.replace('\n', " ");
    assert!(cli_flat.contains(&listed), "cli.md lacks {listed}");
    let guide = read("docs/guide/commands.md");
    assert!(
        guide.contains(&format!("every bundled scene: {}", names.join(", "))),
        "commands.md lacks {names:?}"
    );
    let (code, help, err) = touchfem(&["serve", "--help"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        help.contains("docs/contracts.md") && !help.contains("CONTRACTS.md"),
        "{help}"
    );
    let contracts = read("docs/contracts.md");
    for section in [
        "## Command line",
        "## Scene files (TOML)",
        "## The Haply Inverse3 (through the Haply Inverse Service)",
        "## The web page",
        "## UDP device protocol, version 1",
        "## Errors and exit status",
        "## Environment",
    ] {
        assert!(contracts.contains(section), "contracts.md lacks {section}");
    }
    assert!(contracts.contains("(2 for bad input)"));
    let readme = read("docs/README.md");
    for want in ["format 3", "format 4", "version 2, and 4", "contracts.md"] {
        assert!(readme.contains(want), "docs/README.md lacks {want}");
    }
}

/// `demo` writes its report (the per-scene haptic line, the objects' rows, where the JSON
/// went) to stdout, as every other command writes its result; stderr keeps warnings only.
#[test]
fn demo_writes_its_report_to_stdout() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(["demo", "fig1", "--seconds", "0.2", "--out"])
        .arg(dir.path())
        .env("TOUCHFEM_CACHE_DIR", "")
        .env(
            "WGPU_BACKEND",
            std::env::var("WGPU_BACKEND").unwrap_or("vulkan".into()),
        )
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert!(
        stdout.contains("fig1   haptic ")
            && stdout.contains(" nodes ")
            && stdout.contains("report: "),
        "stdout: {stdout}"
    );
    assert!(
        !stderr.contains("report:") && !stderr.contains(" haptic "),
        "stderr: {stderr}"
    );
    assert!(dir.path().join("report.json").exists());
}

/// The window's status overlay: a notice (the `B` key on a scene with nothing to cut) reads
/// `warning: …` and, at 800 pixels, ends before the legend in the other corner instead of
/// running under it; a narrow window cuts it with `…`.
#[test]
fn the_window_warning_is_prefixed_and_clears_the_legend() {
    use touchfem::render::{legend_image, LegendSpec};
    use touchfem_app::window::status_overlay;
    let [w, h] = [800u32, 600u32];
    let legend = legend_image(&LegendSpec {
        bar_px: LegendSpec::bar_for(h),
        displacement: Some((0.01, 0.002)),
        arrow_m_per_n: Some(0.01),
        force_n: None,
    })
    .unwrap();
    let legend_w = legend.width();
    assert!(legend_w > 50 && legend_w < 400, "{legend_w}");
    let status = "|F|  0.00 N  haptic 1000 Hz  frame  16.7 ms ( 60 fps)";
    let notice = "blade: no object in this scene is cuttable";
    let shown = status_overlay(status, Some(notice), w, legend_w);
    assert_eq!(shown, format!("warning: {notice}"));
    // DejaVu Sans Mono at 15 px: 9.03 px a character, a 4 px pad each side, 8 px from the
    // left edge; the legend 8 px from the right.
    let right = 8.0 + 8.0 + shown.chars().count() as f64 * 15.0 * 1233.0 / 2048.0;
    assert!(
        right + 8.0 <= (w - 8 - legend_w) as f64,
        "{right} vs legend at {}",
        w - 8 - legend_w
    );
    assert_eq!(status_overlay(status, None, w, legend_w), status);
    let narrow = status_overlay(status, Some(notice), 480, legend_w);
    assert!(
        narrow.starts_with("warning: ") && narrow.ends_with('…'),
        "{narrow}"
    );
    let right = 16.0 + narrow.chars().count() as f64 * 15.0 * 1233.0 / 2048.0;
    assert!(right + 8.0 <= (480 - 8 - legend_w) as f64, "{narrow}");
}
