//! Scene files: the bundled scenes, what they precompute, units, relative mesh paths, and a
//! typed error naming the key and line for every bad file.

use glam::DVec3;
use touchfem::compliance::{Compliance, NodeSet, Selection};
use touchfem::force::ForceModel;
use touchfem::scene::{DeviceSpec, SceneSource, World};

fn load(text: &str, dir: &std::path::Path) -> Result<World, touchfem::Error> {
    World::from_source_with(
        &SceneSource {
            name: "t".into(),
            text: text.into(),
            dir: dir.into(),
            label: "t.toml".into(),
        },
        None,
    )
}

fn err(text: &str) -> String {
    match load(text, std::path::Path::new(".")) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn the_bundled_scenes_load_with_only_what_they_need() {
    let fig1 = World::load_with("fig1", "script", None).unwrap();
    let o = &fig1.objects[0];
    assert_eq!((o.name.as_str(), o.scene.mesh.nodes.len()), ("cube", 125));
    assert_eq!(o.scene.compliance.rows().len(), 98);
    assert_eq!(o.scene.compliance.cols().len(), 73);
    assert_eq!(fig1.fingers.len(), 1);
    let DeviceSpec::Script(keys) = &fig1.fingers[0].device else {
        panic!()
    };
    // mm in the file, metres inside.
    assert_eq!(keys[1], (1.0, DVec3::new(0.015, 0.015, 0.025)));
    assert_eq!(fig1.haptics.rate_hz, 1000.0);

    let pinch = World::load_with("pinch", "script", None).unwrap();
    let m = &pinch.objects[0].scene.mesh;
    let c = &pinch.objects[0].scene.compliance;
    // The ball's free-surface nodes, counted independently.
    let centre = DVec3::new(0.015, 0.015, 0.018);
    let want: Vec<u32> = m
        .free_surface_nodes()
        .into_iter()
        .filter(|&n| m.nodes[n as usize].distance(centre) <= 0.018)
        .collect();
    assert_eq!(c.cols(), &want[..]);
    assert!(want.len() < 73 && want.len() > 10, "{}", want.len());
    assert_eq!(c.rows().len(), 98, "every displayed surface node");
    // The columns it has equal those of the full precompute (same L, fewer columns).
    let full = Compliance::compute(m, &Selection::default()).unwrap();
    for (j, &node) in c.cols().iter().enumerate() {
        let jf = full.col_of(node).unwrap();
        for r in 0..c.rows().len() {
            let d = c.block(r, j) - full.block(r, jf);
            assert!(d.abs().to_cols_array().iter().all(|v| *v < 1e-15), "{d}");
        }
    }
    assert_eq!(pinch.fingers.len(), 2);
    let fig2 = World::load_with("fig2", "script", None).unwrap();
    assert_eq!(fig2.objects[0].scene.mesh.nodes.len(), 1699);
    assert_ne!(
        fig1.hash, pinch.hash,
        "the selection is part of the scene hash"
    );
}

#[test]
fn the_cache_key_includes_the_selection() {
    let m = touchfem::mesh::cube();
    let all = Selection::default();
    let some = Selection {
        rows: NodeSet::Surface,
        cols: NodeSet::Nodes(m.free_surface_nodes()[..5].to_vec()),
    };
    assert_ne!(
        touchfem::cache::key(&m, &all),
        touchfem::cache::key(&m, &some)
    );
}

#[test]
fn metres_and_millimetres_give_the_same_scene() {
    let mm = load(
        r#"unit = "mm"
[[object]]
mesh = "cube"
touchable = { center = [115, 15, 30], radius = 10 }
offset = [100, 0, 0]
[[finger]]
device = "script"
path = [[0, 115, 15, 40], [1, 115, 15, 25]]
"#,
        ".".as_ref(),
    )
    .unwrap();
    let m = load(
        r#"[[object]]
mesh = "cube"
touchable = { center = [0.115, 0.015, 0.030], radius = 0.010 }
offset = [0.1, 0, 0]
[[finger]]
device = "script"
model = "exact"
path = [[0, 0.115, 0.015, 0.040], [1, 0.115, 0.015, 0.025]]
"#,
        ".".as_ref(),
    )
    .unwrap();
    assert_eq!(mm.objects[0].offset, DVec3::new(0.1, 0.0, 0.0));
    assert_eq!(
        mm.objects[0].scene.compliance.cols(),
        m.objects[0].scene.compliance.cols()
    );
    assert_eq!(m.fingers[0].model, ForceModel::Exact);
    let (DeviceSpec::Script(a), DeviceSpec::Script(b)) =
        (&mm.fingers[0].device, &m.fingers[0].device)
    else {
        panic!()
    };
    for (x, y) in a.iter().zip(b) {
        assert!((x.1 - y.1).length() < 1e-15);
    }
}

#[test]
fn a_mesh_path_is_relative_to_the_scene_file() {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("meshes");
    std::fs::create_dir(&sub).unwrap();
    let here = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::copy(here.join("tests/data/box_v41.msh"), sub.join("box.msh")).unwrap();
    let text = r#"unit = "mm"
[[object]]
name = "box"
mesh = "meshes/box.msh"
mesh_unit = "mm"
young = 3000.0
poisson = 0.45
touchable = "all"
[[finger]]
device = "pointer"
[haptics]
rate_hz = 500.0
max_force_n = 3.0
"#;
    std::fs::write(dir.path().join("s.toml"), text).unwrap();
    let w = World::load_with(dir.path().join("s.toml").to_str().unwrap(), "script", None).unwrap();
    let o = &w.objects[0];
    assert_eq!(o.name, "box");
    assert_eq!(o.scene.mesh.material.young_pa, 3000.0);
    let (lo, hi) = o.scene.mesh.bounds();
    assert!((hi - lo).max_element() < 0.1, "mm converted: {lo} {hi}");
    assert_eq!((w.haptics.rate_hz, w.haptics.max_force_n), (500.0, 3.0));
    assert_eq!(w.fingers[0].device, DeviceSpec::Pointer);
}

#[test]
fn bad_scene_files_name_the_key_and_the_line() {
    let cases: &[(&str, &[&str])] = &[
        // unknown key
        (
            "[[object]]\nmesh = \"cube\"\ncolour = \"red\"\n",
            &["line 3", "colour"],
        ),
        // wrong type
        (
            "[[object]]\nmesh = \"cube\"\nyoung = \"soft\"\n",
            &["line 3", "young"],
        ),
        ("unit = 3\n[[object]]\nmesh = \"cube\"\n", &["line 1", "unit"]),
        // missing mesh file
        (
            "\n[[object]]\nmesh = \"no/such.msh\"\n",
            &["line 3", "`mesh`", "no/such.msh"],
        ),
        // no mesh key at all
        ("[[object]]\nname = \"x\"\n", &["mesh"]),
        // a ball that holds no free-surface node (the cube's centre, 5 mm)
        (
            "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\ntouchable = { center = [15, 15, 15], radius = 5 }\n",
            &["line 4", "`touchable`", "no free-surface node"],
        ),
        // a path whose times do not increase
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"script\"\npath = [[0, 0, 0, 1], [1, 0, 0, 0.9], [1, 0, 0, 0.8]]\n",
            &["line 5", "`path`", "increase", "keyframe 3"],
        ),
        // device limits: an unknown preset, a bad number, an unknown key
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"udp\"\nlimits = \"phantom\"\n",
            &["line 5", "`limits`", "'phantom' is not a device preset", "falcon"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"udp\"\nlimits = { max_force_n = 5.0, max_stiffness_n_per_m = -1.0, max_damping_ns_per_m = 5.0, workspace_radius_m = 0.1 }\n",
            &["line 5", "`limits`", "max_stiffness_n_per_m must be finite and positive"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"udp\"\nlimits = { max_force = 5.0 }\n",
            &["line 5", "limits"],
        ),
        // unknown device, model, unit, group
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"joystick\"\n",
            &["line 4", "`device`", "joystick"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"pointer\"\nmodel = \"magic\"\n",
            &["line 5", "`model`"],
        ),
        ("unit = \"inch\"\n[[object]]\nmesh = \"cube\"\n", &["line 1", "`unit`", "inch"]),
        (
            "[[object]]\nmesh = \"cube\"\nfixed = \"base\"\n",
            &["line 3", "`fixed`", "base"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\ntouchable = \"lid\"\n",
            &["line 3", "`touchable`", "lid"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\npoisson = 0.5\n",
            &["line 3", "`poisson`"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[haptics]\nmax_force_n = -1\n",
            &["line 4", "`max_force_n`"],
        ),
        // a script finger without a path; a path on a pointer
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"script\"\n",
            &["line 4", "`path`"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"pointer\"\npath = [[0, 0, 0, 0]]\n",
            &["line 5", "`path`"],
        ),
        ("unit = \"mm\"\n", &["no [[object]]"]),
        ("[[object]\nmesh = \"cube\"\n", &["line 1"]),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"pointer\"\n[[finger]]\ndevice = \"pointer\"\n[[finger]]\ndevice = \"pointer\"\n[[finger]]\ndevice = \"pointer\"\n[[finger]]\ndevice = \"pointer\"\n",
            &["line 11", "at most 4 fingers"],
        ),
    ];
    for (text, wants) in cases {
        let e = err(text);
        for w in *wants {
            assert!(e.contains(w), "error for\n{text}\nlacks '{w}':\n{e}");
        }
        assert!(e.starts_with("t.toml"), "names the file: {e}");
    }
}

#[test]
fn a_bad_scene_on_the_command_line_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("bad.toml");
    std::fs::write(&f, "[[object]]\nmesh = \"cube\"\nyoung = -5\n").unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(["demo", f.to_str().unwrap(), "--seconds", "0.1"])
        .env("TOUCHFEM_CACHE_DIR", "")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("line 3") && err.contains("`young`"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let missing = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(["demo", "nothere.toml"])
        .output()
        .unwrap();
    assert_eq!(missing.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("nothere.toml"));
}
